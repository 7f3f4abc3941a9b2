"""Resolution of a run configuration: :func:`resolve` turns a :class:`runner.config.RunConfig`
into a :class:`Plan` (plugins imported, each row of the task looked up (:func:`tasks.rows.row_kind`:
a registered method, or the score task's predictions) and its parameters checked,
budgets looked up, the sweep typed and expanded into validated :class:`Variant` points, the dataset
built and its shapes listed). Every check raises :class:`runner.config.ConfigError` with one
line, before any work starts.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from foundation.errors import one_line
from runner.config import ConfigError, RunConfig, import_plugins
from tasks import FloorSpec, JobSpec
from tasks.spec import JOB_TYPES
from tasks.rows import RowKind, row_kind


@dataclass(frozen=True)
class Variant:
    """One point of a sweep (or the whole run when nothing is swept).

    values : {sweep key: value} of this point (empty without a sweep). config : the run's config
    with those values applied (and validated by :class:`RunConfig` itself); for a ceiling variant
    the same in oracle mode. method_params : full, typed parameters per method. keys : the
    :class:`runner.sweep.SweepKey` of each swept key. first : the sweep's first point in the
    run's own mode (its meshes keep the plain file names the gallery reads).
    """

    values: dict[str, Any]
    config: RunConfig
    method_params: dict[str, dict[str, Any]]
    keys: dict[str, Any]
    first: bool

    def applicable(self, method: str) -> dict[str, Any]:
        """The values of the keys a job of ``method`` in this variant's mode depends on."""
        return {k: v for k, v in self.values.items() if self.keys[k].applies_to(method, self.config.mode)}


@dataclass(frozen=True)
class Plan:
    """A resolved run: every name looked up, every parameter typed, the shapes listed.

    methods : names in display order. method_params : full, typed parameters per method.
    rows : the :class:`tasks.rows.RowKind` of each method (what the run layer knows of its row).
    budgets : the budget record of each budget family whose methods fit or train in this run
        (``{family: record}``; empty in oracle mode and for classic reconstruction). preset : the
        metric preset.
    eval_points : effective metric samples per mesh. dataset_options : how workers build the dataset.
    shapes : shape names in dataset order. train_dirs : the extra training folders of the learned
    methods (resolved: ``--train-dir``, else the default); training_set : {folder: digest of its mesh
    files} (:func:`tasks.trained_networks.training_folders_digest`), part of the run's identity.
    """

    config: RunConfig
    methods: tuple[str, ...]
    method_params: dict[str, dict[str, Any]]
    budgets: dict[str, Any]
    preset: Any
    eval_points: int
    dataset_options: dict[str, Any]
    shapes: tuple[str, ...]
    sweep: dict[str, tuple] = field(default_factory=dict)
    variants: tuple["Variant", ...] = ()
    train_dirs: tuple[str, ...] = ()
    training_set: dict[str, str] = field(default_factory=dict)
    rows: dict[str, RowKind] = field(default_factory=dict)

    def workers_that_fit(self, workers: int) -> int:
        """At most ``workers``, and no more jobs at once than this machine's memory holds by the
        largest measured need of the run's jobs (:func:`runner.memory_need.workers_that_fit`)."""
        from runner.config import machine_memory_bytes
        from runner.memory_need import workers_that_fit

        return workers_that_fit(job_kinds(self.methods, self.variants), machine_memory_bytes(), workers)

    def record(self) -> dict[str, Any]:
        """The resolved facts for config.json (JSON-ready)."""
        from methods.core.budgets import budget_values

        return {"methods": list(self.methods), "method_params": self.method_params,
                "sweep": {k: list(v) for k, v in self.sweep.items()}, "sweep_keys": list(self.sweep),
                "train_dirs": list(self.train_dirs), "training_set": dict(self.training_set),
                "budget": {f: budget_values(b) for f, b in self.budgets.items()} or None,
                "metric_preset": self.preset.to_dict(), "eval_points": self.eval_points,
                "protocol": self.preset.describe(self.eval_points),
                "dataset_options": self.dataset_options, "shapes": list(self.shapes)}


def _existing(flag: str, value: str, kind: str) -> str:
    path = Path(value).expanduser()
    if not (path.is_dir() if kind == "directory" else path.is_file()):
        raise ConfigError(f"{flag} {value}: {'not a ' + kind if path.exists() else 'does not exist'}")
    return str(path.resolve())


def _named_shapes(shapes: list[str], names: tuple[str, ...], dataset: str) -> list[str]:
    """The shapes of ``shapes`` named in ``names`` (all of them when ``names`` is empty), in the
    dataset's order; ConfigError naming the first name the dataset lacks."""
    if not names:
        return shapes
    wanted = set(names)
    unknown = wanted - set(shapes)
    if unknown:
        raise ConfigError(f"--shapes {next(n for n in names if n in unknown)}: not a shape of dataset '{dataset}' "
                          f"with these options ({len(shapes)} shapes, e.g. {', '.join(shapes[:3])})")
    return [s for s in shapes if s in wanted]


def resolve(config: RunConfig) -> Plan:
    """Look up every name of ``config`` and list the shapes (no mesh is read); ConfigError on a problem."""
    for name in config.plugins:
        try:
            import_plugins([name])
        except (ImportError, AttributeError) as exc:
            raise ConfigError(f"--plugin {name}: cannot load ({type(exc).__name__}: {exc})") from None
    from foundation.metrics import PRESETS
    from methods.base import available_methods
    from foundation.params import ParamError

    try:
        methods = tuple(config.methods) or tuple(available_methods(config.task))
        if not methods:
            raise ConfigError(f"--task {config.task} has no method to run here: name its rows with --methods (a "
                              f"score run: run_benchmark.py score --name NAME --pred-dir DIR)")
        rows = {m: row_kind(config.task, m, config.method_params.get(m)) for m in methods}
        for m, row in rows.items():
            if row.task != config.task:
                raise ConfigError(f"method '{m}' belongs to the {row.task} task, not to --task "
                                  f"{config.task} (its methods: {', '.join(available_methods(config.task))})")
            if row.unavailable is not None:
                raise ConfigError(f"method '{m}' cannot run here: {row.unavailable}")
        for m in config.method_params:
            if m not in methods:
                raise ConfigError(f"--method-param names method '{m}', which is not in --methods ({', '.join(methods)})")
        params = {m: rows[m].checked_params(config.method_params.get(m, {})) for m in methods}
        budgets = _budgets(config, rows)
        if config.metric_preset not in PRESETS:
            raise ConfigError(f"unknown metric preset '{config.metric_preset}'; known metric presets: "
                              f"{', '.join(PRESETS)}")
        preset = PRESETS[config.metric_preset]
    except (ParamError, ValueError) as exc:
        raise ConfigError(one_line(exc, with_type=False)) from None
    if config.executor == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ConfigError("--executor ray needs the optional package ray: pip install '.[ray]'") from None
    options: dict[str, Any] = dict(config.dataset_params)
    if config.data_dir is not None:
        options["data_dir"] = _existing("--data-dir", config.data_dir, "directory")
    if config.list_file is not None:
        options["list_file"] = _existing("--list", config.list_file, "file")
    from tasks.load import load_dataset

    try:
        shapes = list(load_dataset(config.dataset, options).names())
    except (ValueError, OSError) as exc:  # DatasetError is a ValueError
        raise ConfigError(one_line(exc, with_type=False)) from None
    shapes = _named_shapes(shapes, config.shapes, config.dataset)[: config.limit]
    if not shapes:
        raise ConfigError(f"dataset '{config.dataset}' has no shapes with these options ({options or 'none'})")
    if load_dataset(config.dataset, options).point_clouds:
        from runner.config import DEFAULT_PC_POINTS

        if config.task != "reconstruct":
            raise ConfigError(f"dataset '{config.dataset}' holds point clouds: use --task reconstruct")
        if config.pc_points != DEFAULT_PC_POINTS:
            raise ConfigError(f"--pc-points does not apply to dataset '{config.dataset}': its files give the points")
        if config.pc_corruption != "uniform" or "pc_corruption" in config.sweep:
            raise ConfigError(f"--pc-corruption does not apply to dataset '{config.dataset}': its files are the "
                              f"clouds (a scan file carries its own sensors)")
    n = config.eval_points if config.eval_points is not None else preset.n_points
    sweep, variants = _variants(config, rows)
    _check_memory(config, job_kinds(methods, variants))
    learned = any(row.learned for row in rows.values())
    train_dirs = _train_dirs(config, methods) if budgets and learned else ()
    from tasks.trained_networks import training_folders_digest

    return Plan(config, methods, params, budgets, preset, int(n), options, tuple(shapes), sweep, variants, train_dirs,
                training_folders_digest(train_dirs), rows)


def job_kinds(methods: tuple[str, ...], variants: tuple["Variant", ...]) -> set[tuple[str, str, str, int]]:
    """The (task, method, mode, grid) of the run's jobs, what their memory needs depend on (the
    score task reads no grid: none)."""
    return {(v.config.task, m, v.config.mode, v.config.grid) for v in variants for m in methods
            if v.config.task != "score"}


def _check_memory(config: RunConfig, kinds: set[tuple[str, str, str, int]]) -> None:
    """Refuse a run whose jobs cannot fit this machine's memory by the measured needs
    (:func:`runner.memory_need.refusal`): each job alone, and with ``--executor process``, its
    workers at once (the automatic executor runs as many as fit: :meth:`Plan.workers_that_fit`)."""
    from runner.config import machine_memory_bytes
    from runner.executors import physical_cores
    from runner.memory_need import refusal

    workers = int(config.workers or physical_cores()) if config.executor == "process" else 1
    reason = refusal(kinds, machine_memory_bytes(), workers)
    if reason:
        raise ConfigError(reason)


def _train_dirs(config: RunConfig, methods: tuple[str, ...]) -> tuple[str, ...]:
    """The extra training folders of a run with learned reconstruction methods (checked)."""
    from tasks.trained_networks import default_train_dirs

    if config.no_cache:
        raise ConfigError("--no-cache: the learned reconstruction methods keep their trained networks in the "
                          "cache (a training takes minutes); use --cache-dir DIR for a fresh one")
    dirs = default_train_dirs() if config.train_dirs is None else tuple(
        _existing("--train-dir", d, "directory") for d in config.train_dirs)
    from datasets import get_dataset

    for d in dirs:
        try:
            get_dataset("meshes", data_dir=d).names()
        except (ValueError, OSError) as exc:
            raise ConfigError(f"--train-dir {d}: {one_line(exc, with_type=False)}") from None
    return dirs


def _budgets(config: RunConfig, rows: dict[str, RowKind]) -> dict[str, Any]:
    """The budget record named ``config.budget`` of each budget family whose methods fit or train in
    this run, each with the overrides its family reads: ``{family: record}`` (empty in oracle mode
    and when no method trains). A family without that name refuses it, naming its budgets."""
    from methods.base import family_budget
    from methods.core.device import precision_unavailable
    from runner.sweep import readable_budget_parameters

    training = [m for m, row in rows.items() if row.budget_family is not None] if config.budget is not None else []
    if config.budget_params and not training:
        raise ConfigError(f"--budget-param: none of {', '.join(rows)} fits or trains under a budget")
    readable_budget_parameters(training, config.budget_params)
    budgets: dict[str, Any] = {}
    for m in training:
        family = rows[m].budget_family
        if family not in budgets:
            budgets[family] = family_budget(family, config.budget, config.budget_params)
            precision = getattr(budgets[family], "precision", None)  # a field of the encode fit's records only
            unavailable = precision_unavailable(precision) if precision else None
            if unavailable:
                raise ConfigError(f"budget '{config.budget}' with precision={precision}: {unavailable}")
    return budgets


def _variants(config: RunConfig, rows: dict[str, RowKind]) -> tuple[dict[str, tuple], tuple[Variant, ...]]:
    """The typed sweep and its points: every combination in the run's mode, then (a neural sweep
    with ``ceiling``) the same combinations in oracle mode. Each point's config is rebuilt, so the
    RunConfig checks (grid memory, ranges) and the method/budget checks apply to every value."""
    from runner import sweep as sweeps
    from foundation.params import ParamError

    methods = tuple(rows)
    typed = sweeps.typed_sweep(config.sweep, methods, config.mode) if config.sweep else {}
    keys = {k: sweeps.sweep_key(k, methods, config.mode) for k in typed}
    for name, key in keys.items():
        given = config.method_params.get(key.method, {}) if key.kind == "method" else (
            config.budget_params if key.kind == "budget" else {})
        if key.target in given:
            raise ConfigError(f"--sweep {name} and a fixed value of the same setting are both given: give one")
    ceiling = typed and config.ceiling and config.mode == "neural" and config.task == "encode"
    modes = [config.mode] + (["oracle"] if ceiling else [])
    out = []
    for mode in modes:
        for i, values in enumerate(sweeps.variants(typed)):
            run = {keys[k].target: v for k, v in values.items() if keys[k].kind == "run" and k != "seed"}
            if "seed" in values:
                run["seeds"] = (values["seed"],)
            budget_params = {**config.budget_params,
                             **{keys[k].target: v for k, v in values.items() if keys[k].kind == "budget"}}
            method_params = {m: dict(p) for m, p in config.method_params.items()}
            for k, v in values.items():
                if keys[k].kind == "method" and keys[k].applies_to(keys[k].method, mode):
                    method_params.setdefault(keys[k].method, {})[keys[k].target] = v
            neural = mode == "neural"
            if not neural:
                run.update(budget=None, budget_params={}, checkpoints=())
            cfg = dataclasses.replace(config, **{"sweep": {}, "mode": mode, "method_params": method_params,
                                                 "budget_params": budget_params, **run})
            try:
                _budgets(cfg, rows)
                params = {m: rows[m].checked_params(cfg.method_params.get(m, {})) for m in methods}
            except (ParamError, ValueError) as exc:
                where = f"--sweep point {sweeps.variant_tag(values)}: " if values else ""
                raise ConfigError(where + one_line(exc, with_type=False)) from None
            out.append(Variant(values, cfg, params, keys, first=(i == 0 and mode == config.mode)))
    return typed, tuple(out)


def build_tasks(plan: Plan) -> tuple[list[FloorSpec], list[JobSpec]]:
    """Floor tasks (one per shape and evaluation sample count, first seed) and jobs (shapes x sweep
    points x methods x seeds, table order; a job that several sweep points share appears once)."""
    from runner.sweep import variant_tag

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
            floors.setdefault(floor.key, floor)
            for m in plan.methods:
                values = v.applicable(m)
                tag = "" if v.first or not values else variant_tag(values)
                if vc.mode != c.mode:
                    tag = f"{vc.mode}" + (f",{tag}" if tag else "")
                job_type = JOB_TYPES[vc.task]
                settings = job_type.run_settings(vc, plan.rows[m], plan.train_dirs)
                for seed in vc.seeds:
                    job = job_type(shape=s, seed=seed, method=m, params=v.method_params[m], cache_dir=cache_dir,
                                   eval_points=vc.eval_points, sweep=values, variant=tag, **settings, **common)
                    jobs.setdefault(job.key, job)
    return list(floors.values()), list(jobs.values())


def cache_root_of(config):
    """The cache root of a config (``--cache-dir``, else ``$SALSBENCH_CACHE``, else the home default)."""
    from foundation.storage import cache_root

    return cache_root(config.cache_dir)
