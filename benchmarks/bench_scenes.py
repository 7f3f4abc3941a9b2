"""How block-wise reconstruction scales with the scene: seconds and peak memory against scene area.

    .venv/bin/python -m benchmarks.bench_scenes [--methods poisson sals-knn] [--budget cpu]
        [--block 48] [--grid 64] [--out /tmp/bench_scenes] [--cache-dir DIR] [--ray]

Scenes: rooms of 1, 4 and 16 room-units (``--dataset rooms --dataset-option tiles=1|2|4``, room 0,
10,000 input points per room-unit, so the density is the same) and streets of 25, 50 and 100 m
(``--dataset street --dataset-option length=L``, street 0: the LiDAR's own density). Each scene is one
run of ``run_benchmark.py --task reconstruct --pc-blocks BLOCK --grid GRID`` on the process pool (2
workers, one thread each) with a scene grid of a fixed cell size, so the work per unit of area is
the same in every scene: a room-unit spans GRID - 1 cells (``--pc-scene-grid (GRID - 1) tiles + 1``),
a street's cell is ``--cell`` metres (default 0.25). Rooms are scored with the ``default`` preset,
streets with ``scene`` (metres).

Printed per (scene, method): blocks (all / with points near), the blocks' seconds summed and the
slowest block's, the merge's seconds, the largest peak resident memory of a block task, the run's
wall seconds, CD; then per method the ratios to the smallest scene of its kind: area (room-units;
a street's GT area in m^2), blocks' seconds, peak memory. The targets: the blocks' seconds grow about like the area, the peak memory
stays flat. ``--ray``: the 50 m street again on 2 Ray workers, its meshes compared with the process
pool's vertex for vertex.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pandas as pd
import trimesh

from datasets import get_dataset
from benchmarks.bench_score import run_timed

ROOM_TILES = (1, 2, 4)
STREET_LENGTHS = (25, 50, 100)
ROOM_POINTS = 10_000


def _rows(out: Path, scene: str, area: float, wall: float) -> list[dict]:
    with sqlite3.connect(out / "results.db") as con:
        rows = con.execute("SELECT method, status, cd, n_faces, reconstruct_s, blocks_s, info FROM jobs").fetchall()
    table = []
    for method, status, cd, faces, merge_s, blocks_s, info in rows:
        info = json.loads(info or "{}")
        table.append({"scene": scene, "method": method, "area": area, "status": status, "blocks": info.get("blocks"),
                      "scene grid": info.get("scene_grid"), "blocks s": blocks_s, "slowest block s": info.get("block_s_max"),
                      "merge s": merge_s, "peak MiB": info.get("block_peak_rss_mib"), "wall s": wall, "CD": cd,
                      "faces": faces})
    return table


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_scenes")
    parser.add_argument("--methods", nargs="+", default=["poisson", "sals-knn"])
    parser.add_argument("--budget", default="cpu")
    parser.add_argument("--block", type=int, default=48)
    parser.add_argument("--grid", type=int, default=64)
    parser.add_argument("--eval-points", default="200000")
    parser.add_argument("--cell", type=float, default=0.25, help="a street's grid cell (m)")
    parser.add_argument("--out", default="/tmp/bench_scenes")
    parser.add_argument("--cache-dir", default="", help="the runs' cache (default: the user's, where trained "
                                                       "networks already are)")
    parser.add_argument("--ray", action="store_true")
    args = parser.parse_args(argv)
    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    common = ["--task", "reconstruct", "--methods", *args.methods, "--budget", args.budget, "--grid", str(args.grid),
              "--pc-blocks", str(args.block), "--eval-points", args.eval_points, "--quiet", "--gallery", "0",
              "--dataset-option", "count=1", *(["--cache-dir", args.cache_dir] if args.cache_dir else [])]
    pool = ["--executor", "process", "--workers", "2", "--threads", "1"]
    table, street_grids = [], {}
    for tiles in ROOM_TILES:
        run = out / f"rooms-{tiles * tiles}"
        wall = run_timed([*common, *pool, "--dataset", "rooms", "--dataset-option", f"tiles={tiles}",
                     "--pc-points", str(ROOM_POINTS * tiles * tiles), "--pc-scene-grid", str((args.grid - 1) * tiles + 1),
                     "--out", str(run)])
        table += _rows(run, f"rooms x{tiles * tiles}", float(tiles * tiles), wall)
    for length in STREET_LENGTHS:
        run = out / f"street-{length}"
        street = get_dataset("street", count=1, length=length).load("street_000")
        grid = street_grids[length] = int(round(2.0 * street.meta["metres_per_unit"] / args.cell)) + 1  # 2 units
        wall = run_timed([*common, *pool, "--dataset", "street", "--dataset-option", f"length={length}",
                     "--pc-scene-grid", str(grid), "--metric-preset", "scene", "--out", str(run)])
        table += _rows(run, f"street {length} m", street.meta["street"]["gt_area_m2"], wall)
    frame = pd.DataFrame(table)
    print(frame.round(3).to_markdown(index=False))
    ratios = []
    for (kind, method), group in frame.assign(kind=frame["scene"].str.split().str[0]).groupby(["kind", "method"]):
        base = group.iloc[0]
        for _, row in group.iterrows():
            ratios.append({"scene": row["scene"], "method": method, "area ratio": row["area"] / base["area"],
                           "blocks s ratio": row["blocks s"] / base["blocks s"],
                           "peak memory ratio": row["peak MiB"] / base["peak MiB"]})
    print()
    print(pd.DataFrame(ratios).round(2).to_markdown(index=False))
    if args.ray:
        run = out / "street-50-ray"
        run_timed([*common, "--executor", "ray", "--workers", "2", "--threads", "1", "--dataset", "street",
              "--dataset-option", "length=50", "--pc-scene-grid", str(street_grids[50]), "--metric-preset",
              "scene", "--out", str(run)])
        for mesh in sorted((out / "street-50" / "meshes").glob("*/*.ply")):
            if mesh.name == "gt.ply":
                continue
            a = trimesh.load(mesh, process=False)
            b = trimesh.load(run / "meshes" / mesh.parent.name / mesh.name, process=False)
            same = a.faces.shape == b.faces.shape and np.array_equal(a.faces, b.faces) and np.allclose(
                a.vertices, b.vertices, rtol=0, atol=1e-6)
            print(f"ray vs process pool, {mesh.parent.name}/{mesh.stem}: {'same mesh' if same else 'DIFFERENT'} "
                  f"({len(a.faces)} vs {len(b.faces)} faces)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
