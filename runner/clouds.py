"""``run_benchmark.py clouds``: write the reconstruct task's input clouds as files.

The clouds are the very ones a run with the same settings gives its methods
(:func:`runner.job.input_point_cloud` on the job's sampler stream): one folder per (corruption,
seed), ``<out>/<corruption>-s<seed>/``, laid out as the ``pointclouds`` dataset reads it: per shape
``<shape>.<ply|npz>`` (the points and, for a scan, each point's sensor position) and
``<shape>.gt.off`` (the GT mesh, coordinates printed with 17 significant digits: read back exactly,
where a PLY written by trimesh holds float32), both in the shape's source frame (the mesh file's own units and
position), so the files can go to another program as they are, and
``run_benchmark.py --task reconstruct --dataset pointclouds --data-dir <folder>`` reads them back.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["export_clouds"]

#: Cloud file formats the export writes.
FORMATS = ("ply", "npz")


def export_clouds(plan, out: str | Path, fmt: str = "ply", progress=None) -> list[Path]:
    """Write every (corruption, seed, shape) input cloud of ``plan`` (a reconstruct plan on a mesh
    dataset; its swept ``pc_corruption`` values, or its one) under ``out``; returns the folders.
    A shape that cannot be loaded is skipped with its one-line error passed to ``progress``."""
    from datasets import MeshError
    from datasets.pointclouds import write_point_cloud
    from runner.job import input_point_cloud
    from runner.tasks import load_dataset

    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    config = plan.config
    corruptions = list(config.sweep.get("pc_corruption", ())) or [config.pc_corruption]
    dataset = load_dataset(config.dataset, plan.dataset_options)
    folders = {(c, s): Path(out) / f"{c}-s{s}" for c in corruptions for s in config.seeds}
    for folder in folders.values():
        folder.mkdir(parents=True, exist_ok=True)
    for name in plan.shapes:
        try:
            shape = dataset.load(name)
        except MeshError as exc:
            if progress is not None:
                progress(f"{name}: skipped ({exc})")
            continue
        for (corruption, seed), folder in folders.items():
            points, sensors = input_point_cloud(shape, config.pc_points, config.pc_noise, seed, corruption)
            invert = shape.transform.invert
            write_point_cloud(folder / f"{name}.{fmt}", invert(points), None if sensors is None else invert(sensors))
            write_off(folder / f"{name}.gt.off", invert(shape.vertices), shape.faces)
            if progress is not None:
                progress(f"{folder / name}.{fmt}: {len(points):,} points")
    return list(folders.values())


def write_off(path: Path, vertices, faces) -> None:
    """An OFF file of a triangle mesh whose float64 coordinates read back exactly (``%.17g``),
    written atomically."""
    import io

    import numpy as np

    from benchmark.storage import atomic_write

    vertices, faces = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    text = io.StringIO()
    text.write(f"OFF\n{len(vertices)} {len(faces)} 0\n")
    np.savetxt(text, vertices, fmt="%.17g")
    np.savetxt(text, np.hstack([np.full((len(faces), 1), 3), faces]), fmt="%d")
    atomic_write(path, text.getvalue().encode("ascii"))
