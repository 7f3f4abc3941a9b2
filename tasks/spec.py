"""The specs of a run's tasks: plain, picklable descriptions that any executor can run anywhere.

A run is ``shapes x methods x seeds`` :class:`JobSpec` (one per job) plus one :class:`FloorSpec`
per shape (the GT scored against a resample of itself; it also exports ``meshes/<shape>/gt.ply``).
A task's :attr:`key` is the digest of its :meth:`identity` (everything that defines its result):
the results database's primary key, so a finished task is never run twice. Its :attr:`body` names
the module whose ``run(context)`` computes it (:mod:`tasks`).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

from foundation.serialize import dumps


def digest(obj: Any) -> str:
    """SHA-256 (hex, 16 chars) of a JSON-able object with sorted keys."""
    return hashlib.sha256(dumps(obj).encode()).hexdigest()[:16]


def identity_options(options: dict) -> dict:
    """Dataset options that change which mesh a shape name denotes (not limit/list_file)."""
    return {k: v for k, v in sorted(options.items()) if k not in ("limit", "list_file")}


@dataclass(frozen=True)
class TaskSpec:
    """What every task carries: the dataset and shape, the metric protocol, worker settings."""

    dataset: str
    dataset_options: dict
    shape: str
    eval_points: int | None
    metric_preset: str
    seed: int
    plugins: tuple[str, ...] = ()
    threads: int | None = None
    max_faces: int | None = None
    max_points: int | None = None
    worker_memory: float | None = None

    kind = "task"
    uses_fitting = False

    def identity(self) -> dict:
        return {"kind": self.kind, "dataset": self.dataset, "dataset_options": identity_options(self.dataset_options),
                "shape": self.shape, "eval_points": self.eval_points, "metric_preset": self.metric_preset,
                "seed": self.seed}

    @property
    def key(self) -> str:
        return digest(self.identity())


@dataclass(frozen=True)
class FloorSpec(TaskSpec):
    """The floor task of one shape: GT vs a resample of itself (first seed); exports the GT mesh."""

    kind = "floor"
    body = "tasks.floor"

    @property
    def label(self) -> str:
        return f"{self.shape}/floor"


@dataclass(frozen=True)
class JobSpec(TaskSpec):
    """One (shape, method, seed) job.

    method, params : registry name and full, typed extractor parameters. mode : 'neural' or 'oracle'.
    budget : fitting budget name (None in oracle mode). grid : N. checkpoints : fractions of the fit at
    which the network is scored too (anytime curves). decompose : the fitted field is also extracted
    with each set of its components taken from the exact field (a neural job of a method with
    components). cache_dir : cache root (None: off).
    device : torch device (None: automatic).
    """

    method: str = ""
    params: dict = field(default_factory=dict)
    mode: str = "neural"
    budget: str | None = None
    grid: int = 128
    checkpoints: tuple[float, ...] = ()
    decompose: bool = False
    cache_dir: str | None = None
    device: str | None = None
    budget_params: dict = field(default_factory=dict)
    sweep: dict = field(default_factory=dict)
    variant: str = ""
    task: str = "encode"
    pc_points: int | None = None
    pc_noise: float | None = None
    pc_corruption: str = "uniform"
    pc_blocks: int = 0
    pc_scene_grid: int = 0
    train_dirs: tuple[str, ...] = ()
    blocks_dir: str | None = None  # where a block-wise job's blocks are (runner.blocks); not identity

    kind = "job"

    @property
    def body(self) -> str:
        """The module that computes the job: ``tasks.<task>``."""
        return f"tasks.{self.task}"

    def identity(self) -> dict:
        ident = {**super().identity(), "method": self.method, "params": self.params, "mode": self.mode,
                 "budget": self.budget, "grid": self.grid, "checkpoints": list(self.checkpoints)}
        if self.budget_params:  # only when given: a job without overrides has a key without this field
            ident["budget_params"] = dict(sorted(self.budget_params.items()))
        if self.decompose:  # likewise
            ident["decompose"] = True
        if self.task != "encode":  # likewise: an encode job's key holds no reconstruct field
            ident.update(task=self.task, pc_points=self.pc_points, pc_noise=self.pc_noise)
            if self.pc_corruption != "uniform":  # likewise: a job on uniform samples keeps its key
                ident["pc_corruption"] = self.pc_corruption
            if self.pc_blocks:  # likewise: a job on the whole grid keeps its key
                ident.update(pc_blocks=self.pc_blocks, pc_scene_grid=self.pc_scene_grid)
            if self.budget is not None:  # a learned method: its training set is part of what it computes
                ident["train_dirs"] = list(self.train_dirs)
        return ident

    def fit_identity(self) -> str | None:
        """What the job's network depends on (its cache key without the code): jobs that share it fit
        or train it once. Encode: the shape's fit (jobs of a sweep that differ only in extraction
        settings share it, and methods that extract another's field: ``Method.fit_name``); reconstruct:
        the network a learned method trains across shapes (method, budget, its overrides, training
        set: every shape's job shares it). None for an oracle job, a method without a network and
        a reconstruction method that optimises per cloud (its jobs share nothing)."""
        if not self.uses_fitting:
            return None
        from tasks.rows import row_kind

        row = row_kind(self.task, self.method)
        if self.task == "reconstruct":
            if not row.learned:
                return None
            return digest({"task": self.task, "method": self.method, "budget": self.budget,
                           "budget_params": self.budget_params, "train_dirs": list(self.train_dirs)})
        return digest({"dataset": self.dataset, "dataset_options": identity_options(self.dataset_options),
                       "shape": self.shape, "method": row.fit_name, "budget": self.budget,
                       "budget_params": self.budget_params, "seed": self.seed})

    @property
    def uses_fitting(self) -> bool:
        """True when the job trains a network (asks an executor for a GPU when there is one)."""
        return self.mode == "neural" and self.budget is not None

    @property
    def label(self) -> str:
        return f"{self.shape}/{self.method}{f'[{self.variant}]' if self.variant else ''}/s{self.seed}"
