"""The run configuration as typed data: :class:`RunConfig`, what the user asked (what it resolves
to, the methods, their full parameters, the budget, the preset and the shape list, is a
:class:`runner.plan.Plan`).

A ``RunConfig`` is frozen and checks its own values when built (:meth:`RunConfig.__post_init__`),
from the command line, from a file (``--config`` TOML or JSON, or a run's ``config.json``) or from
Python. Every field has a *role*:

* ``identity``: defines what a job computes (task, dataset, data_dir, list_file, limit, shapes, mode, budget,
  grid, metric_preset, eval_points, method_params). A run directory holds one protocol: a second
  command into it with a different identity is refused (:meth:`RunConfig.identity_diff`).
* ``scope``: which jobs exist (methods, seeds). A later command into the same run directory may add
  methods or seeds; the saved configuration becomes the union.
* ``execution``: how this invocation runs (executor, workers, threads, caches, ...). Recorded,
  never part of a result's identity.

A setting that only some tasks read names them (its ``tasks`` metadata: the input cloud's settings
and ``--train-dir`` the reconstruct task, ``--mode``, ``--checkpoints``, ``--decompose`` and
``--no-ceiling`` the encode task, budget overrides and sweeps both); a run of another task refuses
it, given away from its default, in one line naming the setting and its tasks.

:func:`runner.plan.resolve` turns a config into a :class:`runner.plan.Plan` (imports
plugins, checks method and parameter names against the registry, builds the dataset and lists its
shapes). Every check raises :class:`ConfigError` with one line, before any work starts.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from foundation.corruptions import CORRUPTIONS
from foundation.params import Param, ParamError, check_fields, params_of, setting
from foundation.seeding import MAX_SEED

MODES = ("neural", "oracle")
TASKS = ("encode", "reconstruct", "score")
#: Fewest points of an input cloud (reconstruct task).
MIN_PC_POINTS = 100
DEFAULT_PC_POINTS = 40_000
MIN_GRID = 8
MIN_EVAL_POINTS = 1000
class ConfigError(ValueError):
    """A bad option, path or name: one line, reported before any work starts."""


def machine_memory_bytes() -> int | None:
    """Physical memory of this machine (None where the OS does not say)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


#: The entry-point group through which an installed package registers methods or datasets.
ENTRY_POINT_GROUP = "salsbench.plugins"


#: RunConfig fields whose option is not ``--`` + the field name with dashes.
_FLAGS = {"list_file": "--list", "seeds": "--seed", "plugins": "--plugin", "train_dirs": "--train-dir",
          "method_params": "--method-param", "budget_params": "--budget-param",
          "dataset_params": "--dataset-option", "ceiling": "--no-ceiling"}


def flag_of(field: str) -> str:
    """The command-line option of a RunConfig field."""
    return _FLAGS.get(field, "--" + field.replace("_", "-"))


def _setting(role: str, default, help: str, sweep: str | None = None, tasks: tuple[str, ...] | None = None, **param):
    """A RunConfig field: its :class:`Param` (type, bounds, the ``--help`` text), its role, for a
    setting a sweep may vary the sweep key's name, and for a setting of some tasks only, those
    tasks (another task's run refuses it away from its default: :meth:`RunConfig._check`)."""
    return setting(Param(default, help, **param), role=role, sweep=sweep, tasks=tasks)


@dataclass(frozen=True)
class RunConfig:
    """What a run computes and how (module docstring). Every field is parsed by its Param when built."""

    task: str = _setting(
        "identity", "encode", "encode (default): fit a field per shape from its mesh and extract it; reconstruct: "
        "a mesh from a raw point cloud sampled from the GT (no normals); score: meshes made elsewhere, read from a "
        "folder (run_benchmark.py score)", choices=TASKS)
    dataset: str = _setting(
        "identity", "builtin", "dataset: builtin (default; 4 generated CAD-like shapes, no download), abc, "
        "abc-nonmanifold, meshes (any folder of mesh files)")
    data_dir: str | None = _setting("identity", None, "folder of mesh files (abc, abc-nonmanifold, meshes)", kind=str)
    list_file: str | None = _setting(
        "identity", None, "text file of shape names, one per line (e.g. the SALS ABC test lists)", kind=str)
    limit: int | None = _setting("identity", None, "use only the first N shapes of the dataset", kind=int, ge=1)
    shapes: tuple[str, ...] = _setting(
        "identity", (), "use only these shapes of the dataset, by name, in the dataset's order (e.g. the shape of "
        "a row of a per-job CSV, to re-run it); a name the dataset lacks is refused", item=str)
    mode: str = _setting(
        "identity", "neural", "neural (default): fit a network per shape and method, extract from it; oracle: "
        "extract from the exact field (no fitting; isolates extraction error)", choices=MODES, tasks=("encode",))
    budget: str | None = _setting(
        "identity", "cpu", "fitting budget, the same for every method: cpu (default; feature-grid backbone, 3,000 "
        "steps: a fit in under a minute on one CPU core), quick (a small MLP, the CPU reference without the grid), "
        "mlp (the paper's kind of network at 2-core size: a plain 5 x 256 Softplus MLP, 16k steps; add "
        "--budget-param precision=bfloat16 where the CPU has bfloat16), cpu-mlp (the cpu budget's seconds on a "
        "plain 5 x 128 MLP), paper (the paper's 9 x 512 MLP, 100k steps: a GPU budget), tiny and tiny-grid "
        "(tests and CI)",
        sweep="budget", optional=True)
    grid: int = _setting(
        "identity", 128, f"grid points per axis on [-1,1] (default 128; >= {MIN_GRID}, bounded by this machine's "
        "memory); spacing 2/(N-1) canonical units", sweep="grid", ge=MIN_GRID)
    metric_preset: str = _setting(
        "identity", "default", "metric protocol: default (canonical frame, Chamfer-L1, F1@0.005/0.01, ECD/EF1), "
        "ndc (NDC's script) or scene (metres: CD in cm, F1@2/5/10 cm; the street dataset)")
    eval_points: int | None = _setting(
        "identity", None, f"surface samples per mesh for the metrics (>= {MIN_EVAL_POINTS}; default: the preset's "
        "n, 1,000,000 for 'default' and 'scene', 100,000 for 'ndc'); stated in every table caption", sweep="eval_points",
        kind=int, ge=MIN_EVAL_POINTS)
    method_params: Mapping[str, Mapping[str, Any]] = _setting(
        "identity", {}, "override an extractor parameter, e.g. sals.o_threshold=0.2 or sals.normals=no "
        "(repeatable); typed and range-checked against the method's parameters", kind=dict, item=dict)
    checkpoints: tuple[float, ...] = _setting(
        "identity", (), "neural mode: also score the network at these increasing fractions of the fit budget, "
        "e.g. 0.25,0.5,1 (anytime curves: one row per checkpoint in results.db/checkpoints.csv and a plot of each "
        "metric against fit seconds in the report); off by default; jobs with checkpoints always fit",
        item=float, gt=0, le=1, tasks=("encode",))
    pc_points: int = _setting(
        "identity", DEFAULT_PC_POINTS, f"reconstruct task: points of the input cloud (default {DEFAULT_PC_POINTS:,}, "
        f"the paper's; >= {MIN_PC_POINTS})", sweep="pc_points", ge=MIN_PC_POINTS, tasks=("reconstruct",))
    pc_noise: float = _setting(
        "identity", 0.0, "reconstruct task: Gaussian noise sigma added to the input points, canonical units "
        "(default 0)", sweep="pc_noise", ge=0, lt=1, tasks=("reconstruct",))
    pc_corruption: str = _setting(
        "identity", "uniform", "reconstruct task: how the input cloud is made: uniform (default: area-uniform "
        "samples, the paper's), scan (a clean virtual range scan: 10 sensors, per-point sensor positions), or a "
        "scan corrupted at level 1-3: noise-L, outliers-L, missing-L, density-L, misalign-L (docs/PROTOCOL.md, "
        "'Input clouds')", sweep="pc_corruption", choices=CORRUPTIONS, tasks=("reconstruct",))
    pc_blocks: int = _setting(
        "identity", 0, "reconstruct task: reconstruct block by block, blocks of B grid points per axis, one task "
        "per block on the executor, finished blocks kept across runs (0: the whole grid at once, default). "
        "sals-knn by edges (its mesh equals the whole grid's); any other method by the window of --grid points "
        "centred on each block (docs/PROTOCOL.md, 'Block-wise reconstruction')", sweep="pc_blocks", ge=0,
        tasks=("reconstruct",))
    pc_scene_grid: int = _setting(
        "identity", 0, "reconstruct task with --pc-blocks: points per axis of the scene's grid over the canonical "
        "cube. 0 (default): POCO's rule for a learned method (the grid on which the cloud has its training "
        "clouds' density: the network sees the cloud scaled by (N-1)/(grid-1)), --grid for any other method",
        sweep="pc_scene_grid", ge=0, tasks=("reconstruct",))
    train_dirs: tuple[str, ...] | None = _setting(
        "identity", None, "reconstruct task: a folder of extra training meshes for the learned methods (repeatable; "
        "default: ../shared/data/thingi10k where it exists); the built-in training parts are always included",
        kind=tuple, item=str, tasks=("reconstruct",))
    dataset_params: Mapping[str, Any] = _setting(
        "identity", {}, "an option of the dataset, e.g. length=100 for street or count=20 for rooms (repeatable; "
        "the dataset checks the name and the value)", kind=dict)
    budget_params: Mapping[str, Any] = _setting(
        "identity", {}, "override a value of the budget, e.g. num_samples=500000 or steps=2000 (repeatable; "
        "typed and range-checked; recorded in config.json and every table caption)", kind=dict,
        tasks=("encode", "reconstruct"))
    sweep: Mapping[str, tuple] = _setting(
        "identity", {}, "run every value of a setting in one run directory (repeatable: the cross product). KEY: "
        "grid, eval_points, budget, seed, budget.NAME (e.g. budget.num_samples) or METHOD.NAME (e.g. "
        "sals.o_threshold); values typed like --method-param. Each row records its values in columns sweep.KEY; "
        "jobs that differ only in extraction settings share one fit; a neural sweep also runs its oracle ceiling "
        "(see --no-ceiling)", kind=dict, item=tuple, tasks=("encode", "reconstruct"))
    ceiling: bool = _setting(
        "identity", True, "a neural sweep also runs the same sweep on the exact field (its oracle ceiling)",
        tasks=("encode",))
    decompose: bool = _setting(
        "identity", False, "neural mode: also extract each fitted field with parts of it taken from the exact field "
        "(SALS: intersection flags, hit positions s, normals; UDF: values, gradients; SDF and BOF: sign, "
        "magnitude), each set scored as a row of its own (results.db table components, components.csv, the "
        "decomposition tables of summary.md and report.html), and record the fitted components' errors "
        "(false-hit and missed edges, s and normal errors, ...) in the job's row", tasks=("encode",))
    methods: tuple[str, ...] = _setting("scope", (), "methods to run (default: every registered method)", item=str)
    seeds: tuple[int, ...] = _setting(
        "scope", (0,), "seeds in [0, 2^63) (default 0); each seed is a separate job per shape and method "
        "(sampling, network init, metric samples)", sweep="seed", item=int, ge=0, le=MAX_SEED)
    executor: str = _setting(
        "execution", "auto", "auto (default: on a CPU, one process per physical core with one torch thread each "
        "when there are two or more tasks; else local), local (in-process, sequential), process (--workers local "
        "processes), ray (Ray tasks, local instance or --address cluster)")
    workers: int | None = _setting(
        "execution", None, "parallel jobs for auto and process (default: physical cores for auto, CPU cores for "
        "process) and for a local ray instance (its CPU count); torch threads per job: auto 1, process "
        "max(1, cores // K)", kind=int, ge=1)
    address: str | None = _setting(
        "execution", None, "ray cluster to join: 'auto' (a cluster started with `ray start`) or host:port; "
        "without it a local ray instance is started", kind=str)
    gpus_per_job: float = _setting(
        "execution", 1.0, "ray: GPUs a fitting job asks for when the cluster has GPUs (default 1; fractions "
        "allowed, e.g. 0.5)", ge=0)
    cpus_per_job: float = _setting("execution", 1.0, "ray: CPUs per job (default 1)", gt=0)
    threads: int | None = _setting(
        "execution", None, "torch CPU threads per job (default: 1 for auto's process workers, torch's own (all "
        "cores) for local and for auto with one task; cores // workers for process; --cpus-per-job for ray)",
        kind=int, ge=1)
    max_faces: int = _setting(
        "execution", 5_000_000, "a shape whose mesh has more faces fails its jobs with one line naming the file "
        "and its size, before any work (a job's memory grows with the faces; default 5,000,000)", ge=1)
    max_points: int = _setting(
        "execution", 10_000_000, "a point cloud with more points (a file of the pointclouds dataset, or "
        "--pc-points) is refused likewise (default 10,000,000)", ge=1)
    worker_memory: float | None = _setting(
        "execution", None, "GiB of memory a job's process may allocate (its data segment, RLIMIT_DATA); an "
        "allocation past it fails that job with 'out of memory' and the run goes on (default: no limit: a job "
        "over the machine's memory is killed by the kernel and recorded as a worker killed by SIGKILL)",
        kind=float, gt=0)
    retries: int = _setting(
        "execution", 1, "times a job whose worker died is retried (default 1); jobs that raise are recorded "
        "failed at once", ge=0)
    cache_dir: str | None = _setting(
        "execution", None, "cache root (default $SALSBENCH_CACHE or ~/.cache/salsbench)", kind=str)
    no_cache: bool = _setting("execution", False, "do not read or write the weights/mesh/field caches")
    plugins: tuple[str, ...] = _setting(
        "execution", (), "import MODULE or a file PATH.py (either optionally :FUNCTION, then called) first, in the "
        "driver and every worker, to register extra methods or datasets (repeatable); installed packages register "
        f"through the entry-point group {ENTRY_POINT_GROUP!r}", item=str)
    quiet: bool = _setting("execution", False, "no progress bar; one line per finished job (CI logs)")
    gallery: int | None = _setting(
        "execution", None, "shapes with thumbnails in report.html's gallery (default 24; 0: none, the quickest "
        "report: a thumbnail renders a mesh)", kind=int, ge=0)
    reference: str | None = _setting(
        "execution", None, "join a reference set's rows to this run's tables (a set's name, run_benchmark.py "
        "references lists them, or its folder): marked (ref), paired with the run's rows over the shapes both "
        "have, never recomputed; refused before any work where its protocol (task, mode, input, grid, metric "
        "points, preset, dataset and its shapes' bytes) differs or its metric code is stale", kind=str)
    reference_keep: str | None = _setting(
        "execution", None, "where a row name is both in this run and in --reference: keep the run's rows (run) "
        "or the reference's (reference); without it such a run is refused", kind=str, choices=("run", "reference"))
    recompute_stale: bool = _setting(
        "execution", False, "in an existing run directory, recompute the finished tasks whose code changed since "
        "(without it such a run is refused: one directory never mixes two code versions)")

    def __post_init__(self):
        try:
            check_fields(self, "")
        except ParamError as exc:
            raise ConfigError(str(exc)) from None
        self._check()
        for name, value in self._completed().items():  # a frozen record: the values it stands for, once
            object.__setattr__(self, name, value)

    def _completed(self) -> dict[str, Any]:
        """The values the given ones stand for: plugins as absolute paths (the workers import them
        from anywhere), the budget (``cpu`` where something is fitted or trained and none was named;
        none where nothing is: a named one is refused where the user gave it, :func:`runner.cli.main`
        and :meth:`from_mapping`), and the seeds a sweep over ``seed`` gives."""
        done = {"plugins": tuple(_absolute_plugin(p) for p in self.plugins)}
        fits = self.task == "reconstruct" or (self.task == "encode" and self.mode == "neural")
        done["budget"] = (self.budget or "cpu") if fits else None  # oracle mode and scoring fit nothing
        swept = tuple(self.sweep.get("seed", ()))
        if swept and all(isinstance(v, int) and not isinstance(v, bool) for v in swept):  # else not typed yet
            done["seeds"] = swept
        return done

    def _check(self) -> None:
        from runner.executors import EXECUTORS


        if self.executor not in EXECUTORS:
            raise ConfigError(f"--executor: {EXECUTORS.unknown(self.executor)}")
        from runner.memory_need import lightest_refusal

        reason = lightest_refusal(self.grid, machine_memory_bytes())
        if reason:
            raise ConfigError(reason)
        if not self.seeds:
            raise ConfigError("--seed needs at least one value")
        if len(set(self.seeds)) != len(self.seeds) or len(set(self.methods)) != len(self.methods):
            raise ConfigError("--seed and --methods values must not repeat")
        if self.checkpoints:
            c = self.checkpoints
            if self.mode != "neural":
                raise ConfigError("--checkpoints needs --mode neural (oracle mode fits nothing)")
            if any(b <= a for a, b in zip(c, c[1:])):
                raise ConfigError(f"--checkpoints must be increasing fractions of the budget in (0, 1], got {list(c)}")
        if self.pc_points > self.max_points:
            raise ConfigError(f"--pc-points {self.pc_points} is over the limit of {self.max_points} points a job "
                              f"may hold (--max-points)")
        self._check_task_settings()
        if self.pc_scene_grid and not self.pc_blocks:
            raise ConfigError("--pc-scene-grid is the grid of a block-wise reconstruction: give --pc-blocks too")
        if self.pc_scene_grid == 1:
            raise ConfigError("--pc-scene-grid needs at least 2 points per axis (or 0: chosen by the method)")
        if self.pc_noise != 0 and (self.pc_corruption != "uniform" or "pc_corruption" in self.sweep):
            raise ConfigError("--pc-noise adds Gaussian noise to uniform samples; for a scan use --pc-corruption "
                              "noise-1, noise-2 or noise-3 (noise along the sensor's rays)")
        if self.decompose and self.mode != "neural":
            raise ConfigError("--decompose needs --mode neural (it splits a fitted field's error)")
        if self.budget_params and self.mode != "neural":
            raise ConfigError("--budget-param needs --mode neural (oracle mode fits nothing)")
        swept = tuple(self.sweep.get("seed", ()))
        if swept and all(isinstance(v, int) and not isinstance(v, bool) for v in swept):  # else not typed yet
            if self.seeds not in ((0,), swept):
                raise ConfigError("--seed and --sweep seed=... both give the seeds: give one")
        if self.address is not None and self.executor != "ray":
            raise ConfigError("--address only applies to --executor ray")
        if self.workers is not None and self.executor == "local":
            raise ConfigError("--workers applies to --executor auto, process or ray; the local executor runs one job at a time")

    def _check_task_settings(self) -> None:
        """ConfigError (one line) naming the settings of other tasks that this run gives away from
        their defaults (each field's ``tasks`` metadata)."""
        foreign = [f for f in dataclasses.fields(self) if f.metadata.get("tasks") and self.task not in f.metadata["tasks"]
                   and getattr(self, f.name) != f.metadata["param"].default]
        if foreign:
            tasks = " or ".join(f"--task {t}" for t in foreign[0].metadata["tasks"])
            flags = " and ".join(flag_of(f.name) + ("" if f.name != "mode" else f" {self.mode}") for f in foreign)
            raise ConfigError(f"{flags} appl{'ies' if len(foreign) == 1 else 'y'} to {tasks}, not to --task {self.task}")

    @classmethod
    def params(cls) -> dict[str, Param]:
        """Every setting's :class:`Param` (type, bounds, help), in field order."""
        return params_of(cls)

    @classmethod
    def sweep_params(cls) -> dict[str, Param]:
        """The run settings a sweep may vary: ``{sweep key: the Param of one value}``."""
        return {f.metadata["sweep"]: f.metadata["param"].scalar() for f in dataclasses.fields(cls)
                if f.metadata.get("sweep")}

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
            shown = ", ".join(n if n.isprintable() else repr(n) for n in unknown)  # a line break stays escaped
            raise ConfigError(f"{where}: unknown setting(s) {shown}; known: {', '.join(known)}")
        if values.get("mode") == "oracle" and values.get("budget") is not None:
            raise ConfigError(f"{where}: budget needs mode neural (oracle mode fits nothing)")
        return cls(**dict(values))

    @classmethod
    def load(cls, path: str | os.PathLike) -> "RunConfig":
        """A config from a file: a run's ``config.json`` (its ``config`` entry), or a JSON/TOML file
        of settings (top-level keys = field names; TOML may also put them in a ``[run]`` table)."""
        path = Path(path)
        kind = "TOML" if path.suffix.lower() == ".toml" else "JSON"
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"--config {path}: cannot read ({exc.strerror or exc})") from None
        except UnicodeDecodeError as exc:
            raise ConfigError(f"--config {path}: not valid {kind} (not UTF-8 text: byte {exc.object[exc.start]:#04x} "
                              f"at offset {exc.start})") from None
        try:
            data = tomllib.loads(text) if kind == "TOML" else json.loads(text)
        except RecursionError:
            raise ConfigError(f"--config {path}: not valid {kind} (nested too deeply)") from None
        except ValueError as exc:  # the decode errors, and integers of more digits than Python converts
            reason = " ".join(str(exc).split())[:200]
            raise ConfigError(f"--config {path}: not valid {kind} ({reason})") from None
        if not isinstance(data, dict):
            raise ConfigError(f"--config {path}: expected a table of settings")
        if "config" not in data and "environment" in data and "options" in data:
            raise ConfigError(f"{path}: written by an older salsbench (before typed run configurations); "
                              f"start a new --out")
        key = "config" if "config" in data else "run" if "run" in data else None
        data = data[key] if key else data
        if not isinstance(data, dict):
            raise ConfigError(f"--config {path}: expected a table of settings under '{key}', got {type(data).__name__}")
        return cls.from_mapping(data, where=f"--config {path}")


def _plain(value):
    if isinstance(value, tuple):
        return list(value)
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    return value


_ENTRY_POINTS_LOADED = False


def import_plugins(plugins) -> None:
    """Import each plugin, then the installed packages' ``salsbench.plugins`` entry points (once per
    process). A plugin is a module name (it registers on import), a Python file ``path/to/file.py``
    (imported as the module ``salsbench_plugin_<stem>``; its code enters the cache keys like a
    built-in module's), either followed by ``:function`` (then called). An entry point names a
    module or a function (called once loaded)."""
    import importlib

    for name in plugins:
        target, func = split_plugin(name)
        mod = plugin_from_file(target) if target.endswith(".py") else importlib.import_module(target)
        if func:
            getattr(mod, func)()
    load_entry_points()


def _absolute_plugin(name: str) -> str:
    """A plugin file's path made absolute (a worker may start in another folder); a module as given."""
    target, func = split_plugin(name)
    if not target.endswith(".py"):
        return name
    return str(Path(target).expanduser().resolve()) + (f":{func}" if func else "")


def split_plugin(name: str) -> tuple[str, str]:
    """(module or file, function or '') of a ``--plugin`` value."""
    target, colon, func = name.rpartition(":")
    if colon and func.isidentifier() and target:
        return target, func
    return name, ""


def plugin_from_file(path: str):
    """The module of a plugin file, imported once as ``salsbench_plugin_<stem>`` (ImportError, one
    line, when the file is missing or another plugin file already took that name)."""
    import importlib.util
    import re
    import sys

    file = Path(path).expanduser().resolve()
    if not file.is_file():
        raise ImportError(f"no such file {file}")
    name = "salsbench_plugin_" + re.sub(r"\W", "_", file.stem)
    loaded = sys.modules.get(name)
    if loaded is not None:
        if Path(loaded.__file__).resolve() != file:
            raise ImportError(f"{file} and {loaded.__file__} are both plugin module '{name}': rename one")
        return loaded
    spec = importlib.util.spec_from_file_location(name, file)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    return module


def load_entry_points() -> None:
    """Load the ``salsbench.plugins`` entry points of the installed packages, once per process."""
    global _ENTRY_POINTS_LOADED
    if _ENTRY_POINTS_LOADED:
        return
    _ENTRY_POINTS_LOADED = True
    from importlib.metadata import entry_points

    for entry in entry_points(group=ENTRY_POINT_GROUP):
        loaded = entry.load()
        if callable(loaded) and not isinstance(loaded, type):
            loaded()
