"""What one job needs in memory, from measurements: the guard that admits a grid or refuses it.

A job's peak resident memory (its worker's, ``peak_rss_mib`` in the job's info) grows with the cube
of the grid: dense N^3 fields, edge arrays of 3 N^3, the query's batches. For each (task, method,
mode) the file :data:`MEASURED` holds a model fitted to finished jobs,
``peak = base + bytes_per_point * N^3`` (:func:`fit_models`; ``python -m benchmarks.bench_memory
RUN_DIR ...`` writes it), with the grids, CPU and commit it was measured on. A run is admitted when
every job fits this machine's memory with the run's workers beside it (:func:`check_plan`), else
refused before any work in one line naming the method, the mode, the grid and the measured need.
A method without a measurement of its own (a plugin, a new method) is held to the largest model of
its task and mode, and the line says so.
"""

from __future__ import annotations

import csv
import math
from dataclasses import asdict, dataclass, fields
from functools import lru_cache
from pathlib import Path
from typing import Iterable

import numpy as np

#: The measured models, one row per (task, method, mode).
MEASURED = Path(__file__).with_name("measured_memory.csv")
MIB = 2**20


@dataclass(frozen=True)
class MemoryModel:
    """``peak = base_mib MiB + bytes_per_point * N^3`` for the jobs of one (task, method, mode),
    fitted to the largest peak at each of ``grids`` over ``jobs`` jobs (the worst residual:
    ``max_residual_mib``)."""

    task: str
    method: str
    mode: str
    base_mib: float
    bytes_per_point: float
    grids: str
    jobs: int
    max_residual_mib: float
    cpu: str = ""
    commit: str = ""

    def need_bytes(self, N: int) -> float:
        """Peak bytes of one job at grid N (a float, inf past 10^100: any N, never an overflow)."""
        n = float(N) if N < 10**100 else math.inf
        return self.base_mib * MIB + self.bytes_per_point * n**3

    def largest_grid(self, memory: float) -> int:
        """The largest N whose need fits ``memory`` bytes (0 when none does)."""
        room = memory - self.base_mib * MIB
        return int((room / self.bytes_per_point) ** (1 / 3)) if room > 0 and self.bytes_per_point > 0 else 0


def fit_models(jobs: Iterable[dict], cpu: str = "", commit: str = "") -> list[MemoryModel]:
    """Models fitted to finished jobs (dicts with task, method, mode, grid, peak_rss_mib): per (task,
    method, mode) with at least two grids, the largest peak at each grid, then the least-squares line
    of peak against N^3 (slope and intercept held >= 0)."""
    peaks: dict[tuple[str, str, str], dict[int, float]] = {}
    count: dict[tuple[str, str, str], int] = {}
    for job in jobs:
        peak = job.get("peak_rss_mib")
        if peak is None or not np.isfinite(peak):
            continue
        key = (job["task"], job["method"], job["mode"])
        grids = peaks.setdefault(key, {})
        grids[int(job["grid"])] = max(grids.get(int(job["grid"]), 0.0), float(peak))
        count[key] = count.get(key, 0) + 1
    models = []
    for key, grids in sorted(peaks.items()):
        if len(grids) < 2:
            continue
        n = np.array(sorted(grids), dtype=float)
        mib = np.array([grids[int(g)] for g in n])
        slope, intercept = np.polyfit(n**3, mib, 1)
        slope, intercept = max(slope, 0.0), max(intercept, 0.0)
        residual = float(np.max(np.abs(intercept + slope * n**3 - mib)))
        models.append(MemoryModel(*key, base_mib=round(float(intercept), 1), bytes_per_point=round(slope * MIB, 2),
                                  grids=" ".join(str(int(g)) for g in n), jobs=count[key],
                                  max_residual_mib=round(residual, 1), cpu=cpu, commit=commit))
    return models


def write_models(models: list[MemoryModel], path: Path = MEASURED) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, [field.name for field in fields(MemoryModel)])
        writer.writeheader()
        writer.writerows(asdict(m) for m in models)


@lru_cache(maxsize=4)
def read_models(path: Path = MEASURED) -> dict[tuple[str, str, str], MemoryModel]:
    """{(task, method, mode): model} of the measured file ({} where there is none)."""
    if not Path(path).is_file():
        return {}
    types = {field.name: {"float": float, "int": int}.get(field.type, str) for field in fields(MemoryModel)}
    with open(path, newline="") as f:
        models = [MemoryModel(**{k: types[k](v) for k, v in row.items()}) for row in csv.DictReader(f)]
    return {(m.task, m.method, m.mode): m for m in models}


def model_of(task: str, method: str, mode: str, models: dict | None = None) -> tuple[MemoryModel | None, bool]:
    """(the model of a method's jobs, whether it is the method's own): the method's measurement,
    else the largest of its task and mode (by need at 512^3), else None (nothing measured)."""
    models = read_models() if models is None else models
    own = models.get((task, method, mode))
    if own is not None:
        return own, True
    same = [m for (t, _, md), m in models.items() if t == task and md == mode]
    return (max(same, key=lambda m: m.need_bytes(512)), False) if same else (None, False)


def refusal(jobs: Iterable[tuple[str, str, str, int]], memory: float | None, workers: int,
            models: dict | None = None) -> str | None:
    """The one-line reason a run of these (task, method, mode, grid) jobs cannot run on ``memory``
    bytes with ``workers`` jobs at once, or None when every job fits. Each job must fit alone; with
    several workers, the largest need times the workers must fit too (else: fewer workers)."""
    if memory is None:
        return None
    needs = []
    for task, method, mode, N in sorted(set(jobs)):
        model, own = model_of(task, method, mode, models)
        if model is None:
            continue
        need = model.need_bytes(N)
        how = (f"measured on grids {model.grids}" if own else
               f"not measured: held to {model.method}'s, the largest measured {task} {mode} need")
        if need > memory:
            largest = model.largest_grid(memory)
            return (f"--grid {N}: {method} ({mode}) needs ~{_gib(need)} GiB per job ({how}: {model.base_mib:.0f} MiB + "
                    f"{model.bytes_per_point:.1f} B x N^3), more than this machine's {memory / 2**30:.1f} GiB; "
                    f"its largest grid here is {largest}")
        needs.append((need, method, mode, N))
    if workers > 1 and needs:
        need, method, mode, N = max(needs)
        if need * workers > memory:
            fit = max(1, int(memory // need))
            return (f"--grid {N}: {workers} workers of {method} ({mode}) need ~{_gib(need * workers)} GiB at once "
                    f"(~{_gib(need)} GiB each, measured), more than this machine's {memory / 2**30:.1f} GiB; "
                    f"use --workers {fit}")
    return None


def lightest_refusal(N: int, memory: float | None, models: dict | None = None) -> str | None:
    """The one-line reason no job of any kind can run at grid ``N`` (the lightest measured need is
    more than ``memory`` bytes), or None. What a run's own methods need is :func:`refusal`'s."""
    models = read_models() if models is None else models
    if memory is None or not models:
        return None
    lightest = min(models.values(), key=lambda m: m.need_bytes(N))
    if lightest.need_bytes(N) <= memory:
        return None
    return (f"--grid {N}: even the lightest measured job ({lightest.method}, {lightest.mode}) needs "
            f"~{_gib(lightest.need_bytes(N))} GiB, more than this machine's {memory / 2**30:.1f} GiB; "
            f"its largest grid here is {lightest.largest_grid(memory)}")


def workers_that_fit(jobs: Iterable[tuple[str, str, str, int]], memory: float | None, workers: int,
                     models: dict | None = None) -> int:
    """At most ``workers``, and as many as the largest measured need of these jobs lets run at once."""
    if memory is None:
        return workers
    needs = [m.need_bytes(N) for task, method, mode, N in set(jobs)
             for m in [model_of(task, method, mode, models)[0]] if m is not None]
    return max(1, min(workers, int(memory // max(needs)))) if needs else workers


def _gib(value: float) -> str:
    gib = value / 2**30
    if not math.isfinite(gib):
        return "more than 10^300"
    return f"{gib:.1f}" if gib < 1e6 else f"10^{int(math.log10(gib))}"
