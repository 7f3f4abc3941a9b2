"""Block-wise jobs' stored blocks (:mod:`runner.blocks`): what a block task is, where its result is
kept, and the merge of a job's blocks into its mesh.

Each block's result is ``OUT/blocks/<job key>/<block>.npz`` (written atomically by the driver as
it arrives): an edge-field method's intersected edges (``ids``, ``s``, ``normals``), any other
method's piece (``vertices``, ``faces``), the points it read and ``meta`` (its seconds, peak
resident memory and halo).
"""

from __future__ import annotations

import io
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from foundation.storage import atomic_write
from methods.pointcloud.blocks import Block, blocks
from tasks.spec import JobSpec, digest

CLOUD_FILE = "cloud.npz"
SCENE_FILE = "scene.json"


@dataclass(frozen=True)
class Scene:
    """The grid a block-wise job reconstructs its scene on: ``grid`` points per axis over the
    canonical cube, seen by the networks scaled by ``input_scale`` = (grid - 1) / (training grid - 1),
    and how it was chosen (``rule``; the cloud's and the training clouds' mean neighbour distances
    for POCO's rule)."""

    grid: int
    input_scale: float
    rule: str
    cloud_neighbour_distance: float | None = None
    training_neighbour_distance: float | None = None


def write_scene(folder: Path, scene: Scene) -> None:
    atomic_write(Path(folder) / SCENE_FILE, json.dumps(asdict(scene), sort_keys=True).encode())


def read_scene(folder: Path) -> Scene:
    return Scene(**json.loads((Path(folder) / SCENE_FILE).read_text()))


def by_edges(method) -> bool:
    """Whether the method's blocks give edges (it has an edge field) rather than mesh pieces."""
    return callable(getattr(method, "edge_field", None))


def blocks_folder(run_dir: Path, job: JobSpec) -> Path:
    return Path(run_dir) / "blocks" / job.key


@dataclass(frozen=True)
class BlockTask:
    """One block of a block-wise job: what a worker runs."""

    job: JobSpec
    block: Block
    halo: float
    folder: str
    input_scale: float = 1.0

    kind = "block"

    @property
    def key(self) -> str:
        return digest({"job": self.job.key, "N": self.block.N, "lo": list(self.block.lo), "hi": list(self.block.hi)})

    @property
    def label(self) -> str:
        return f"{self.job.label}/{self.block.name}"

    @property
    def uses_fitting(self) -> bool:
        return self.job.uses_fitting

    @property
    def result_path(self) -> Path:
        return Path(self.folder) / f"{self.block.name}.npz"


@dataclass
class BlockResult:
    """What a block task returns: its arrays (``status`` 'ok'), the halo it needs ('halo'), or a
    one-line error ('failed')."""

    task: BlockTask
    status: str = "failed"
    arrays: dict = field(default_factory=dict)
    seconds: float = 0.0
    peak_rss_mib: float | None = None
    needed_halo: float | None = None
    error: str | None = None
    traceback: str | None = None


def write_block(result: BlockResult) -> None:
    """Store an ok block's arrays with its seconds and peak memory (atomically)."""
    buffer = io.BytesIO()
    meta = {"seconds": result.seconds, "peak_rss_mib": result.peak_rss_mib, "halo": result.task.halo}
    np.savez(buffer, meta=np.array(json.dumps(meta)), **result.arrays)
    atomic_write(result.task.result_path, buffer.getvalue())


def read_blocks(job: JobSpec) -> tuple[list[tuple[Block, dict[str, Any]]], list[str]]:
    """((block, its stored arrays and meta) for every stored block, names of the missing blocks)."""
    found, missing = [], []
    for b in blocks(read_scene(job.blocks_dir).grid, job.pc_blocks):
        path = Path(job.blocks_dir) / f"{b.name}.npz"
        if not path.is_file():
            missing.append(b.name)
            continue
        with np.load(path) as data:
            arrays = {k: data[k] for k in data.files}
        arrays["meta"] = json.loads(str(arrays["meta"]))
        found.append((b, arrays))
    return found, missing


class BlocksMissing(RuntimeError):
    """A block-wise job whose blocks did not all finish."""


def merged_extraction(job: JobSpec, method):
    """The job's mesh from its stored blocks (module docstring, step 3), with the blocks' facts."""
    from methods.base import Extraction
    from methods.pointcloud.blocks import BlockEdges, merge_edges, merge_pieces

    if job.blocks_dir is None:
        raise BlocksMissing("a block-wise job needs its blocks run first (runner.blocks.run_blocks)")
    found, missing = read_blocks(job)
    if missing:
        raise BlocksMissing(f"{len(missing)} of {len(missing) + len(found)} blocks did not finish "
                            f"(first: {missing[0]}; see the run's log)")
    scene = read_scene(job.blocks_dir)
    N = scene.grid
    if by_edges(method):
        parts = [BlockEdges(b, a["ids"], a["s"], a.get("normals"), int(a["queried"]), int(a["points"]))
                 for b, a in found]
        out = merge_edges(parts, N, qef_cutoff=method.params["qef_cutoff"], faces=method.params["faces"])
    else:
        V, F = merge_pieces((a["vertices"], a["faces"]) for _, a in found)
        out = Extraction(V, F, info={"blocks": len(found)})
    with np.load(Path(job.blocks_dir) / CLOUD_FILE, mmap_mode="r") as cloud:
        out.info.update(input_points=int(cloud["points"].shape[0]), used_sensors=bool(
            method.uses_sensors and "sensors" in cloud.files))
    seconds = [a["meta"]["seconds"] for _, a in found]
    peaks = [a["meta"]["peak_rss_mib"] for _, a in found if a["meta"]["peak_rss_mib"] is not None]
    out.info.update(blocks=len(found), block_points_max=int(max((int(a["points"]) for _, a in found), default=0)),
                    blocks_s=float(sum(seconds)), block_s_max=float(max(seconds, default=0.0)),
                    block_peak_rss_mib=float(max(peaks)) if peaks else float("nan"),
                    scene_grid=N, input_scale=scene.input_scale, scene_rule=scene.rule)
    return out
