"""Tasks of a run: plain, picklable descriptions that any executor can run anywhere.

A run is ``shapes x methods x seeds`` :class:`JobSpec` (one per job) plus one :class:`FloorSpec`
per shape (the GT scored against a resample of itself; it also exports ``meshes/<shape>/gt.ply``).
A task's :attr:`key` is the digest of its :meth:`identity` (everything that defines its result):
the results database's primary key, so a finished task is never run twice.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

from benchmark.serialize import dumps


def digest(obj: Any) -> str:
    """SHA-256 (hex, 16 chars) of a JSON-able object with sorted keys."""
    return hashlib.sha256(dumps(obj).encode()).hexdigest()[:16]


@lru_cache(maxsize=8)
def _dataset_cached(name: str, options_json: str):
    from datasets import get_dataset

    return get_dataset(name, **json.loads(options_json))


def load_dataset(name: str, options: dict):
    """The dataset ``name`` built with ``options`` (cached per process)."""
    return _dataset_cached(name, json.dumps(options, sort_keys=True))


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
        from methods.base import METHODS

        if self.task == "reconstruct":
            if not METHODS.get(self.method).learned:
                return None
            return digest({"task": self.task, "method": self.method, "budget": self.budget,
                           "budget_params": self.budget_params, "train_dirs": list(self.train_dirs)})
        return digest({"dataset": self.dataset, "dataset_options": identity_options(self.dataset_options),
                       "shape": self.shape, "method": METHODS.get(self.method).fit_name, "budget": self.budget,
                       "budget_params": self.budget_params, "seed": self.seed})

    @property
    def uses_fitting(self) -> bool:
        """True when the job trains a network (asks an executor for a GPU when there is one)."""
        return self.mode == "neural" and self.budget is not None

    @property
    def label(self) -> str:
        return f"{self.shape}/{self.method}{f'[{self.variant}]' if self.variant else ''}/s{self.seed}"


def build_tasks(plan) -> tuple[list[FloorSpec], list[JobSpec]]:
    """Floor tasks (one per shape and evaluation sample count, first seed) and jobs (shapes x sweep
    points x methods x seeds, table order; a job that several sweep points share appears once)."""
    from methods.base import METHODS
    from runner.sweep import trains as method_trains, variant_tag

    c = plan.config
    common = dict(dataset=c.dataset, dataset_options=plan.dataset_options, metric_preset=c.metric_preset,
                  plugins=c.plugins, threads=c.threads, max_faces=c.max_faces, max_points=c.max_points,
                  worker_memory=c.worker_memory)
    cache_dir = None if c.no_cache else str(cache_root_of(c))
    floors: dict[str, FloorSpec] = {}
    jobs: dict[str, JobSpec] = {}
    for s in plan.shapes:
        for v in plan.variants:
            vc = v.config
            floor = FloorSpec(shape=s, seed=c.seeds[0], eval_points=vc.eval_points, **common)
            reconstruct = ({"pc_points": vc.pc_points, "pc_noise": vc.pc_noise, "pc_corruption": vc.pc_corruption,
                            "pc_blocks": vc.pc_blocks, "pc_scene_grid": vc.pc_scene_grid}
                           if vc.task == "reconstruct" else {})
            floors.setdefault(floor.key, floor)
            for m in plan.methods:
                values = v.applicable(m)
                tag = "" if v.first or not values else variant_tag(values)
                if vc.mode != c.mode:
                    tag = f"{vc.mode}" + (f",{tag}" if tag else "")
                for seed in vc.seeds:
                    trains = method_trains(m)
                    extra = {**reconstruct, "train_dirs": plan.train_dirs} if reconstruct and trains else reconstruct
                    reads = METHODS.get(m).budget_fields()
                    job = JobSpec(shape=s, seed=seed, method=m, params=v.method_params[m], mode=vc.mode,
                                  budget=vc.budget if trains else None,
                                  budget_params={k: x for k, x in vc.budget_params.items() if k in reads}, grid=vc.grid,
                                  eval_points=vc.eval_points, checkpoints=vc.checkpoints, cache_dir=cache_dir,
                                  decompose=vc.decompose and vc.mode == "neural" and bool(METHODS.get(m).components),
                                  sweep=values, variant=tag, task=vc.task, **extra, **common)
                    jobs.setdefault(job.key, job)
    return list(floors.values()), list(jobs.values())


def cache_root_of(config):
    """The cache root of a config (``--cache-dir``, else ``$SALSBENCH_CACHE``, else the home default)."""
    from benchmark.storage import cache_root

    return cache_root(config.cache_dir)
