"""The run configuration as typed data: :class:`RunConfig` (what the user asked) and :class:`Plan`
(what it resolves to: methods, their full parameters, the budget, the preset, the shape list).

A ``RunConfig`` is frozen and checks its own values when built (:meth:`RunConfig.__post_init__`),
from the command line, from a file (``--config`` TOML or JSON, or a run's ``config.json``) or from
Python. Every field has a *role*:

* ``identity``: defines what a job computes (task, dataset, data_dir, list_file, limit, mode, budget,
  grid, metric_preset, eval_points, method_params). A run directory holds one protocol: a second
  command into it with a different identity is refused (:meth:`RunConfig.identity_diff`).
* ``scope``: which jobs exist (methods, seeds). A later command into the same run directory may add
  methods or seeds; the saved configuration becomes the union.
* ``execution``: how this invocation runs (executor, workers, threads, caches, ...). Recorded,
  never part of a result's identity.

:func:`benchmark.run.plan.resolve` turns a config into a :class:`benchmark.run.plan.Plan` (imports
plugins, checks method and parameter names against the registry, builds the dataset and lists its
shapes). Every check raises :class:`ConfigError` with one line, before any work starts.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from benchmark.seeding import MAX_SEED

MODES = ("neural", "oracle")
TASKS = ("encode", "reconstruct")
#: Fewest points of an input cloud (reconstruct task).
MIN_PC_POINTS = 100
DEFAULT_PC_POINTS = 40_000
MIN_GRID = 8
MIN_EVAL_POINTS = 1000
#: Bytes per N^3 of the dense buffers of one job at grid N (see :func:`grid_memory_bytes`).
GRID_BYTES_PER_POINT = 240


class ConfigError(ValueError):
    """A bad option, path or name: one line, reported before any work starts."""


def grid_memory_bytes(N: int) -> int:
    """Estimated peak bytes of one job's dense grid buffers at resolution N.

    Per grid edge (3 (N-1) N^2 ~ 3 N^3 edges): hit flag 1 B, s 4 B, normal 12 B, sparse-query
    values 8 B, endpoint inputs 24 B, ids 8 B (~57 B, rounded to 64); per grid point: UDF 4 B,
    gradient 12 B, SDF 4 B, occupancy 1 B, upsampled coarse values in float64 8 B and query masks
    (~48 B). 3 x 64 + 48 = 240 B per N^3: 0.5 GB at 128, 4 GB at 256, 32 GB at 512. The true peak
    of the lighter methods is lower; the estimate is a guard against requests that cannot fit.
    """
    return GRID_BYTES_PER_POINT * int(N) ** 3


def machine_memory_bytes() -> int | None:
    """Physical memory of this machine (None where the OS does not say)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


def _f(default, role: str, help: str = ""):
    if isinstance(default, dict):
        return field(default_factory=dict, metadata={"role": role, "help": help})
    return field(default=default, metadata={"role": role, "help": help})


@dataclass(frozen=True)
class RunConfig:
    """What a run computes and how (module docstring). Field types are checked when built."""

    task: str = _f("encode", "identity", "benchmark task")
    dataset: str = _f("builtin", "identity", "dataset registry name")
    data_dir: str | None = _f(None, "identity", "folder of mesh files")
    list_file: str | None = _f(None, "identity", "text file of shape names")
    limit: int | None = _f(None, "identity", "first N shapes of the dataset")
    mode: str = _f("neural", "identity", "neural (fit) or oracle (exact field)")
    budget: str | None = _f("cpu", "identity", "fitting budget (neural mode)")
    grid: int = _f(128, "identity", "grid points per axis on [-1, 1]")
    metric_preset: str = _f("default", "identity", "metric protocol")
    eval_points: int | None = _f(None, "identity", "metric samples per mesh (None: the preset's)")
    method_params: Mapping[str, Mapping[str, Any]] = _f({}, "identity", "extractor parameters per method")
    checkpoints: tuple[float, ...] = _f((), "identity", "fractions of the fit at which the network is scored too")
    pc_points: int = _f(DEFAULT_PC_POINTS, "identity", "points of the input cloud (reconstruct task)")
    pc_noise: float = _f(0.0, "identity", "Gaussian noise sigma of the input points, canonical units (reconstruct)")
    train_dirs: tuple[str, ...] | None = _f(None, "identity", "extra training meshes of the learned reconstruction "
                                                         "methods (None: the shared Thingi10K folder if present)")
    budget_params: Mapping[str, Any] = _f({}, "identity", "overrides of the budget's values (neural mode)")
    sweep: Mapping[str, tuple] = _f({}, "identity", "swept settings, {key: values} (cross product)")
    ceiling: bool = _f(True, "identity", "a neural sweep also runs the same sweep in oracle mode")
    methods: tuple[str, ...] = _f((), "scope", "methods (empty: all registered)")
    seeds: tuple[int, ...] = _f((0,), "scope", "seeds")
    executor: str = _f("auto", "execution", "auto, local, process or ray")
    workers: int | None = _f(None, "execution", "parallel jobs")
    address: str | None = _f(None, "execution", "ray cluster address")
    gpus_per_job: float = _f(1.0, "execution", "ray: GPUs per fitting job")
    cpus_per_job: float = _f(1.0, "execution", "ray: CPUs per job")
    threads: int | None = _f(None, "execution", "torch threads per job")
    retries: int = _f(1, "execution", "retries of a job whose worker died")
    cache_dir: str | None = _f(None, "execution", "cache root")
    no_cache: bool = _f(False, "execution", "caches off")
    plugins: tuple[str, ...] = _f((), "execution", "modules imported first")
    quiet: bool = _f(False, "execution", "one line per finished job")
    recompute_stale: bool = _f(False, "execution", "recompute finished tasks whose code changed")

    def __post_init__(self):
        for f in dataclasses.fields(self):
            object.__setattr__(self, f.name, _coerce(f, getattr(self, f.name)))
        if self.task == "reconstruct":
            if self.budget is None:
                object.__setattr__(self, "budget", "cpu")  # the training budget of the learned methods
        elif self.mode == "oracle" and self.budget is not None:
            object.__setattr__(self, "budget", None)  # oracle mode fits nothing: no budget in the protocol
        elif self.mode == "neural" and self.budget is None:
            object.__setattr__(self, "budget", "cpu")
        self._check()

    def _check(self) -> None:
        from benchmark.run.executors import EXECUTORS

        def choice(name, value, allowed):
            if value not in allowed:
                raise ConfigError(f"{name} must be one of {', '.join(allowed)}, got '{value}'")

        choice("--task", self.task, TASKS)
        choice("--mode", self.mode, MODES)
        if self.executor not in EXECUTORS:
            raise ConfigError(f"--executor: {EXECUTORS.unknown(self.executor)}")
        if self.grid < MIN_GRID:
            raise ConfigError(f"--grid must be >= {MIN_GRID} points per axis, got {self.grid}")
        memory = machine_memory_bytes()
        if memory is not None and grid_memory_bytes(self.grid) > memory:
            largest = int((memory / GRID_BYTES_PER_POINT) ** (1 / 3))
            raise ConfigError(f"--grid {self.grid} needs ~{grid_memory_bytes(self.grid) / 2**30:.0f} GiB of grid "
                              f"buffers per job, more than this machine's {memory / 2**30:.0f} GiB; "
                              f"use --grid <= {largest}")
        if self.eval_points is not None and self.eval_points < MIN_EVAL_POINTS:
            raise ConfigError(f"--eval-points must be >= {MIN_EVAL_POINTS}, got {self.eval_points}")
        if not self.seeds:
            raise ConfigError("--seed needs at least one value")
        bad = [s for s in self.seeds if not 0 <= s <= MAX_SEED]
        if bad:
            raise ConfigError(f"--seed values must lie in [0, 2^63), got {bad[0]}")
        if len(set(self.seeds)) != len(self.seeds) or len(set(self.methods)) != len(self.methods):
            raise ConfigError("--seed and --methods values must not repeat")
        if self.checkpoints:
            c = self.checkpoints
            if self.mode != "neural":
                raise ConfigError("--checkpoints needs --mode neural (oracle mode fits nothing)")
            if not all(0 < f <= 1 for f in c) or any(b <= a for a, b in zip(c, c[1:])):
                raise ConfigError(f"--checkpoints must be increasing fractions of the budget in (0, 1], got {list(c)}")
        if self.task == "encode" and (self.pc_points != DEFAULT_PC_POINTS or self.pc_noise != 0):
            raise ConfigError("--pc-points and --pc-noise apply to --task reconstruct")
        if self.task == "reconstruct":
            if self.mode != "neural" or self.checkpoints:
                raise ConfigError("--mode oracle and --checkpoints apply to --task encode")
            if self.pc_points < MIN_PC_POINTS:
                raise ConfigError(f"--pc-points must be >= {MIN_PC_POINTS}, got {self.pc_points}")
            if not 0 <= self.pc_noise < 1:
                raise ConfigError(f"--pc-noise must be a sigma in [0, 1) canonical units, got {self.pc_noise}")
        if self.budget_params and self.mode != "neural":
            raise ConfigError("--budget-param needs --mode neural (oracle mode fits nothing)")
        swept = tuple(self.sweep.get("seed", ()))
        if swept and all(isinstance(v, int) and not isinstance(v, bool) for v in swept):  # else not typed yet
            if self.seeds not in ((0,), swept):
                raise ConfigError("--seed and --sweep seed=... both give the seeds: give one")
            object.__setattr__(self, "seeds", swept)
        if self.limit is not None and self.limit < 1:
            raise ConfigError(f"--limit must be >= 1, got {self.limit}")
        for name in ("workers", "threads"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ConfigError(f"--{name} must be >= 1, got {value}")
        if self.retries < 0:
            raise ConfigError(f"--retries must be >= 0, got {self.retries}")
        if self.gpus_per_job < 0 or self.cpus_per_job <= 0:
            raise ConfigError("--gpus-per-job must be >= 0 and --cpus-per-job > 0")
        if self.address is not None and self.executor != "ray":
            raise ConfigError("--address only applies to --executor ray")
        if self.workers is not None and self.executor == "local":
            raise ConfigError("--workers applies to --executor auto, process or ray; the local executor runs one job at a time")

    # -- roles ------------------------------------------------------------------------------
    @classmethod
    def field_names(cls, role: str | None = None) -> list[str]:
        return [f.name for f in dataclasses.fields(cls) if role is None or f.metadata["role"] == role]

    def identity(self) -> dict[str, Any]:
        """The identity fields (what a run directory's results depend on)."""
        return {k: _plain(getattr(self, k)) for k in self.field_names("identity")}

    def identity_diff(self, other: "RunConfig") -> list[str]:
        """Identity fields whose values differ, as 'name: mine -> other' texts."""
        mine, theirs = self.identity(), other.identity()
        return [f"{k}={mine[k]!r} there, {theirs[k]!r} now" for k in mine if mine[k] != theirs[k]]

    def merged_scope(self, other: "RunConfig") -> "RunConfig":
        """``other`` with the methods and seeds of both (this config's first, in order)."""
        methods = tuple(dict.fromkeys(self.methods + other.methods)) if self.methods and other.methods else ()
        seeds = tuple(dict.fromkeys(self.seeds + other.seeds))
        return dataclasses.replace(other, methods=methods, seeds=seeds)

    # -- (de)serialisation ------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {f.name: _plain(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], where: str = "config") -> "RunConfig":
        """A config from a mapping of field values; unknown keys are refused (a typo is not ignored)."""
        known = cls.field_names()
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise ConfigError(f"{where}: unknown setting(s) {', '.join(unknown)}; known: {', '.join(known)}")
        return cls(**dict(values))

    @classmethod
    def load(cls, path: str | os.PathLike) -> "RunConfig":
        """A config from a file: a run's ``config.json`` (its ``config`` entry), or a JSON/TOML file
        of settings (top-level keys = field names; TOML may also put them in a ``[run]`` table)."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"--config {path}: cannot read ({exc.strerror or exc})") from None
        try:
            data = tomllib.loads(text) if path.suffix.lower() == ".toml" else json.loads(text)
        except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
            raise ConfigError(f"--config {path}: not valid {path.suffix.lstrip('.').upper() or 'JSON'} ({exc})") from None
        if not isinstance(data, dict):
            raise ConfigError(f"--config {path}: expected a table of settings")
        if "config" not in data and "environment" in data and "options" in data:
            raise ConfigError(f"{path}: written by an older salsbench (before typed run configurations); "
                              f"start a new --out")
        data = data.get("config", data.get("run", data))
        return cls.from_mapping(data, where=f"--config {path}")


def _plain(value):
    if isinstance(value, tuple):
        return list(value)
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _is_scalar(value) -> bool:
    return isinstance(value, (str, int, float, bool))


def _coerce(f: dataclasses.Field, value):
    """``value`` as the field's declared type; ConfigError naming the setting otherwise."""
    kind = f.type
    name = f.name
    if value is None and "None" in kind:
        return None
    try:
        if kind.startswith("tuple[str"):
            items = [value] if isinstance(value, str) else list(value)
            if not all(isinstance(v, str) for v in items):
                raise TypeError
            return tuple(items)
        if kind.startswith("tuple[float"):
            items = [value] if isinstance(value, (int, float)) else list(value)
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in items):
                raise TypeError
            return tuple(float(v) for v in items)
        if kind.startswith("tuple[int"):
            items = [value] if isinstance(value, int) else list(value)
            if not all(isinstance(v, int) and not isinstance(v, bool) for v in items):
                raise TypeError
            return tuple(int(v) for v in items)
        if kind.startswith("Mapping[str, Mapping"):
            if not isinstance(value, Mapping) or not all(isinstance(v, Mapping) for v in value.values()):
                raise TypeError
            return {str(m): dict(p) for m, p in value.items()}
        if kind.startswith("Mapping[str, tuple"):
            if not isinstance(value, Mapping) or not all(
                    isinstance(v, (list, tuple)) and all(_is_scalar(x) for x in v) for v in value.values()):
                raise TypeError
            return {str(k): tuple(v) for k, v in value.items()}
        if kind.startswith("Mapping"):
            if not isinstance(value, Mapping) or not all(_is_scalar(v) for v in value.values()):
                raise TypeError
            return {str(k): v for k, v in value.items()}
        if kind.startswith("bool"):
            if not isinstance(value, bool):
                raise TypeError
            return value
        if kind.startswith("int"):
            if isinstance(value, bool) or not isinstance(value, int):
                raise TypeError
            return value
        if kind.startswith("float"):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise TypeError
            return float(value)
        if kind.startswith("str"):
            if not isinstance(value, str):
                raise TypeError
            return value
    except TypeError:
        pass
    raise ConfigError(f"setting '{name}' must be {kind}, got {value!r}")


def import_plugins(plugins) -> None:
    """Import each plugin: ``module`` (registers on import) or ``module:function`` (then calls it)."""
    import importlib

    for name in plugins:
        module, _, func = name.partition(":")
        mod = importlib.import_module(module)
        if func:
            getattr(mod, func)()
