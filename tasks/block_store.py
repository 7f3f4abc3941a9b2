"""Block-wise jobs' stored blocks (:mod:`tasks.blocks` computes them, :mod:`runner.blocks` schedules
them): what a block task is and where its result is kept.

Each block's result is ``OUT/blocks/<job key>_<code>/<block>.npz`` (written atomically by the
driver as it arrives): an edge-field method's intersected edges (``ids``, ``s``, ``normals``), any other
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


def blocks_folder(run_dir: Path, job: JobSpec, code: str) -> Path:
    """Where a block-wise job's cloud, scene and blocks are kept: ``blocks/<job key>_<code>`` of the
    run directory, ``code`` the job's code digest (:func:`tasks.cache.task_code_digest`), so that
    blocks computed by other code are never merged."""
    return Path(run_dir) / "blocks" / f"{job.key}_{code}"


def other_code_folders(run_dir: Path, job: JobSpec, code: str) -> list[Path]:
    """The job's blocks folders of other code than ``code`` (:func:`blocks_folder`), and the one of
    earlier versions, which named no code (``blocks/<job key>``)."""
    keep, root = blocks_folder(run_dir, job, code), Path(run_dir) / "blocks"
    found = [*root.glob(f"{job.key}_*"), root / job.key]
    return sorted(p for p in found if p != keep and p.is_dir())


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
