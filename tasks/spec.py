"""The specs of a run's tasks: plain, picklable descriptions that any executor can run anywhere.

A run is ``shapes x methods x seeds`` jobs, each of its task's job type (:data:`JOB_TYPES`:
:class:`EncodeJob`, :class:`ReconstructJob`, :class:`ScoreJob`, each carrying only the settings its
task reads), plus one :class:`FloorSpec` per shape (the GT scored against a resample of itself; it
also exports ``meshes/<shape>/gt.ply``).
A task's :attr:`key` is the digest of its :meth:`identity` (everything that defines its result):
the results database's primary key, so a finished task is never run twice. Its :attr:`body` names
the module whose ``run(context)`` computes it (:mod:`tasks`).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any, ClassVar

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
    """One (shape, method, seed) job; each task's job type (:class:`EncodeJob`,
    :class:`ReconstructJob`, :class:`ScoreJob`) adds the settings that task reads and its part of
    the key (:meth:`task_identity`).

    method, params : the row's name and its full, typed parameters. cache_dir : cache root (None:
    off). device : torch device (None: automatic). sweep, variant : the sweep point's values and
    its tag in the tables (not identity: a job shared by several sweep points runs once).
    """

    method: str = ""
    params: dict = field(default_factory=dict)
    cache_dir: str | None = None
    device: str | None = None
    sweep: dict = field(default_factory=dict)
    variant: str = ""

    kind = "job"
    #: The task whose body computes the job (``tasks.<task>``).
    task: ClassVar[str] = ""
    #: A reconstruction job run block by block (:mod:`runner.blocks` runs its blocks first).
    block_wise: ClassVar[bool] = False

    @property
    def body(self) -> str:
        """The module that computes the job: ``tasks.<task>``."""
        return f"tasks.{self.task}"

    def identity(self) -> dict:
        return {**super().identity(), "method": self.method, "params": self.params, **self.task_identity()}

    @classmethod
    def run_settings(cls, config, row, train_dirs: tuple[str, ...]) -> dict[str, Any]:
        """The settings of this job type for a job of ``row`` (:class:`tasks.rows.RowKind`) in a run
        of ``config`` (a :class:`runner.config.RunConfig`, read by attribute), beside the ones every
        job has; ``train_dirs``: the run's training folders of learned methods."""
        raise NotImplementedError

    def task_identity(self) -> dict:
        """The task's part of the key: the settings of this job type that define its result."""
        raise NotImplementedError

    def table_fields(self) -> dict:
        """The job's ``mode``, ``budget`` and ``grid`` columns of the results table."""
        raise NotImplementedError

    def fit_identity(self) -> str | None:
        """What the job's network depends on (its cache key without the code): jobs that share it fit
        or train it once; None for a job that fits and trains nothing, or whose fit no other job
        shares."""
        return None

    @property
    def uses_fitting(self) -> bool:
        """True when the job trains a network (asks an executor for a GPU when there is one)."""
        return False

    @property
    def label(self) -> str:
        return f"{self.shape}/{self.method}{f'[{self.variant}]' if self.variant else ''}/s{self.seed}"


@dataclass(frozen=True)
class EncodeJob(JobSpec):
    """A job of the encode task: a field fitted to the shape (``neural``) or exact (``oracle``),
    extracted on a grid.

    mode : 'neural' or 'oracle'. budget : the fitting budget's name (None in oracle mode).
    budget_params : the budget settings the run changes that the method reads. grid : N.
    checkpoints : fractions of the fit at which the network is scored too (anytime curves).
    decompose : the fitted field is also extracted with each set of its components taken from the
    exact field (a neural job of a method with components).
    """

    mode: str = "neural"
    budget: str | None = None
    budget_params: dict = field(default_factory=dict)
    grid: int = 128
    checkpoints: tuple[float, ...] = ()
    decompose: bool = False

    task = "encode"

    @classmethod
    def run_settings(cls, config, row, train_dirs: tuple[str, ...]) -> dict[str, Any]:
        neural = config.mode == "neural"
        return dict(mode=config.mode, **_budget_settings(config, row), grid=config.grid,
                    checkpoints=config.checkpoints, decompose=config.decompose and neural and bool(row.components))

    def task_identity(self) -> dict:
        ident = {"mode": self.mode, "budget": self.budget, "grid": self.grid, "checkpoints": list(self.checkpoints)}
        if self.budget_params:  # only when given: a job without overrides has a key without this field
            ident["budget_params"] = dict(sorted(self.budget_params.items()))
        if self.decompose:  # likewise
            ident["decompose"] = True
        return ident

    def table_fields(self) -> dict:
        return {"mode": self.mode, "budget": self.budget, "grid": self.grid}

    @property
    def uses_fitting(self) -> bool:
        return self.mode == "neural" and self.budget is not None

    def fit_identity(self) -> str | None:
        """The shape's fit: jobs of a sweep that differ only in extraction settings share it, and so
        do methods that extract another's field (``Method.fit_name``). None in oracle mode."""
        if not self.uses_fitting:
            return None
        from tasks.rows import row_kind

        return digest({"dataset": self.dataset, "dataset_options": identity_options(self.dataset_options),
                       "shape": self.shape, "method": row_kind(self.task, self.method).fit_name, "budget": self.budget,
                       "budget_params": self.budget_params, "seed": self.seed})


@dataclass(frozen=True)
class ReconstructJob(JobSpec):
    """A job of the reconstruct task: a mesh from a point cloud of the shape.

    budget : the budget a learned or per-cloud-optimising method reads (None for the others).
    budget_params : the budget settings the run changes that the method reads. grid : N.
    pc_points, pc_noise, pc_corruption : the input cloud (:mod:`foundation.corruptions`).
    pc_blocks, pc_scene_grid : block-wise reconstruction of a scene (0: the whole grid at once).
    train_dirs : the extra training folders of a learned method. blocks_dir : where a block-wise
    job's blocks are (:mod:`tasks.blocks`; not identity).
    """

    budget: str | None = None
    budget_params: dict = field(default_factory=dict)
    grid: int = 128
    pc_points: int | None = None
    pc_noise: float | None = None
    pc_corruption: str = "uniform"
    pc_blocks: int = 0
    pc_scene_grid: int = 0
    train_dirs: tuple[str, ...] = ()
    blocks_dir: str | None = None

    task = "reconstruct"

    @classmethod
    def run_settings(cls, config, row, train_dirs: tuple[str, ...]) -> dict[str, Any]:
        budget = _budget_settings(config, row)
        return dict(**budget, grid=config.grid, pc_points=config.pc_points, pc_noise=config.pc_noise,
                    pc_corruption=config.pc_corruption, pc_blocks=config.pc_blocks, pc_scene_grid=config.pc_scene_grid,
                    train_dirs=train_dirs if budget["budget"] is not None else ())

    @property
    def block_wise(self) -> bool:  # type: ignore[override]
        return bool(self.pc_blocks)

    @property
    def body(self) -> str:
        """``tasks.reconstruct``, or ``tasks.blocks`` for a block-wise job (whose blocks are computed
        there too, so that their code is the job's code digest)."""
        return "tasks.blocks" if self.pc_blocks else "tasks.reconstruct"

    def task_identity(self) -> dict:
        # mode and checkpoints: the key layout of the single job type of earlier versions, kept so
        # that their run directories keep their keys
        ident = {"mode": "neural", "budget": self.budget, "grid": self.grid, "checkpoints": []}
        if self.budget_params:
            ident["budget_params"] = dict(sorted(self.budget_params.items()))
        ident.update(task=self.task, pc_points=self.pc_points, pc_noise=self.pc_noise)
        if self.pc_corruption != "uniform":  # only when given: a job on uniform samples keeps its key
            ident["pc_corruption"] = self.pc_corruption
        if self.pc_blocks:  # likewise: a job on the whole grid keeps its key
            ident.update(pc_blocks=self.pc_blocks, pc_scene_grid=self.pc_scene_grid)
        if self.budget is not None:  # a learned method: its training set is part of what it computes
            ident["train_dirs"] = list(self.train_dirs)
        return ident

    def table_fields(self) -> dict:
        return {"mode": "neural", "budget": self.budget, "grid": self.grid}  # the only mode of the task

    @property
    def uses_fitting(self) -> bool:
        return self.budget is not None

    def fit_identity(self) -> str | None:
        """The network a learned method trains across shapes (method, budget, its overrides, training
        set: every shape's job shares it); None for a method that optimises per cloud."""
        if not self.uses_fitting:
            return None
        from tasks.rows import row_kind

        if not row_kind(self.task, self.method).learned:
            return None
        return digest({"task": self.task, "method": self.method, "budget": self.budget,
                       "budget_params": self.budget_params, "train_dirs": list(self.train_dirs)})


@dataclass(frozen=True)
class ScoreJob(JobSpec):
    """A job of the score task: a mesh made elsewhere, read and scored (:mod:`tasks.score`; its
    parameters name the folder and the frame).

    grid : the run's ``--grid``, which a score job does not read: it stays in the key (and the table)
    only so that score run directories of earlier versions, whose single job type keyed it, keep
    their keys.
    """

    grid: int = 128

    task = "score"

    @classmethod
    def run_settings(cls, config, row, train_dirs: tuple[str, ...]) -> dict[str, Any]:
        return dict(grid=config.grid)

    def task_identity(self) -> dict:
        return {"mode": "neural", "budget": None, "grid": self.grid, "checkpoints": [], "task": self.task,
                "pc_points": None, "pc_noise": None}

    def table_fields(self) -> dict:
        return {"mode": "neural", "budget": None, "grid": self.grid}  # as the run's config states them


def _budget_settings(config, row) -> dict[str, Any]:
    """A job's budget (only for a row with a budget family) and the run's budget settings that row reads."""
    return dict(budget=config.budget if row.budget_family is not None else None,
                budget_params={k: v for k, v in config.budget_params.items() if k in row.budget_fields})


#: The job type of each task.
JOB_TYPES: dict[str, type[JobSpec]] = {"encode": EncodeJob, "reconstruct": ReconstructJob, "score": ScoreJob}
