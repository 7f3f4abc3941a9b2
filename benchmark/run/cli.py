"""The command line: ``run_benchmark.py [options]`` and ``run_benchmark.py report RUN_DIR ...``.

Exit status: 0 every task ok; 2 refused before any work (bad option, path or name, a run directory
holding another protocol or in use by another run); 3 the run finished with failed tasks (their
errors are in the tables and ``results.db``; "N ok, M failed" is the last line).

Where a run's configuration comes from, in order (later wins): the defaults of
:class:`benchmark.run.config.RunConfig`; ``--config FILE`` (TOML/JSON settings, or a run's
``config.json``: ``--config runs/X/config.json --out runs/Y`` reproduces run X); with ``--resume``,
the run directory's saved ``config.json`` instead; the options given on the command line.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import sys
from pathlib import Path
from typing import Any, Sequence

from benchmark.run.config import (DEFAULT_PC_POINTS, MIN_EVAL_POINTS, MIN_GRID, MIN_PC_POINTS, MODES, TASKS, ConfigError,
                                  RunConfig, import_plugins)
from benchmark.run.parsing import EXIT_FAILED_TASKS, EXIT_OK, EXIT_REFUSED, OneLineParser
from benchmark.run.plan import resolve
from benchmark.run.records import SchemaMismatch
from benchmark.run.rundir import RunDirectory, check_writable_dir, saved_config

RUNS_ROOT = Path("runs")

#: Command-line destination -> RunConfig field (where the names differ).
_FIELD_OF = {"list": "list_file", "seed": "seeds", "plugin": "plugins", "method_param": "method_params",
             "budget_param": "budget_params", "train_dir": "train_dirs"}
#: Shipped recipes: ``benchmark/recipes/<name>.toml`` (``--recipe NAME``).
RECIPES_DIR = Path(__file__).resolve().parent.parent / "recipes"


def recipe_names() -> list[str]:
    return sorted(p.stem for p in RECIPES_DIR.glob("*.toml"))


def recipe_path(name: str) -> Path:
    path = RECIPES_DIR / f"{name}.toml"
    if not path.is_file():
        raise ConfigError(f"--recipe: unknown recipe '{name}'; known recipes: {', '.join(recipe_names())}")
    return path


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="run_benchmark.py",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Benchmark neural implicit surface representations on CAD meshes.\n"
            "Jobs = shapes x methods x seeds. Results go to OUT/results.db (SQLite, one row per job,\n"
            "committed as each job ends), OUT/results.csv, OUT/summary.md|tex, OUT/timing.csv|md,\n"
            "OUT/report.html and OUT/meshes/<shape>/{gt,<method>}.ply (canonical frame [-1,1]^3).\n"
            "Re-running into the same --out (or --resume) skips finished jobs and retries failed ones;\n"
            "a run directory holds one protocol: other settings are refused.\n\n"
            "Exit status: 0 all ok; 2 refused before any work; 3 finished with failed jobs.\n\n"
            "Regenerate tables/report from finished runs (several side by side):\n"
            "  run_benchmark.py report RUN_DIR [RUN_DIR ...] [--out DIR]\n"
            "Train the learned reconstruction methods' networks without evaluating:\n"
            "  run_benchmark.py train --task reconstruct [--methods sals-knn ...] [--budget cpu]"
        ),
        epilog="Caches (exact fields, fitted weights, extracted meshes) live in $SALSBENCH_CACHE or "
               "~/.cache/salsbench. SALSBENCH_DEVICE=cpu|cuda forces the torch device.",
    )
    a = p.add_argument
    a("--config", metavar="FILE", help="settings from a TOML/JSON file or a run's config.json (options given "
                                       "here override it); with --out NEW it reproduces that run")
    a("--task", choices=TASKS, help="encode (default): fit a field per shape from its mesh and extract it; "
                                    "reconstruct: a mesh from a raw point cloud sampled from the GT (no normals)")
    a("--pc-points", dest="pc_points", type=int, metavar="P",
      help=f"reconstruct task: points of the input cloud (default {DEFAULT_PC_POINTS:,}, the paper's; "
           f">= {MIN_PC_POINTS})")
    a("--pc-noise", dest="pc_noise", type=float, metavar="SIGMA",
      help="reconstruct task: Gaussian noise sigma added to the input points, canonical units (default 0)")
    a("--train-dir", dest="train_dir", action="append", metavar="DIR",
      help="reconstruct task: a folder of extra training meshes for the learned methods (repeatable; default: "
           "../shared/data/thingi10k where it exists); the built-in training parts are always included")
    a("--methods", nargs="+", metavar="METHOD", help="methods to run (default: every registered method)")
    a("--dataset", metavar="NAME", help="dataset: builtin (default; 4 generated CAD-like shapes, no download), "
                                        "abc, abc-nonmanifold, meshes (any folder of mesh files)")
    a("--data-dir", dest="data_dir", metavar="DIR", help="folder of mesh files (abc, abc-nonmanifold, meshes)")
    a("--list", metavar="FILE", help="text file of shape names, one per line (e.g. the SALS ABC test lists)")
    a("--limit", type=int, metavar="N", help="use only the first N shapes of the dataset")
    a("--mode", choices=MODES, help="neural (default): fit a network per shape and method, extract from it; "
                                    "oracle: extract from the exact field (no fitting; isolates extraction error)")
    a("--budget", metavar="NAME", help="fitting budget, the same for every method: cpu (default; feature-grid "
                                       "backbone, 3,000 steps: a fit in under a minute on one CPU core), quick (a small MLP, "
                                       "the CPU reference without the grid), paper (the paper's 9 x 512 MLP, 100k "
                                       "steps: a GPU budget), tiny and tiny-grid (tests and CI)")
    a("--grid", type=int, metavar="N", help=f"grid points per axis on [-1,1] (default 128; >= {MIN_GRID}, bounded "
                                            "by this machine's memory); spacing 2/(N-1) canonical units")
    a("--eval-points", dest="eval_points", type=int, metavar="N",
      help=f"surface samples per mesh for the metrics (>= {MIN_EVAL_POINTS}; default: the preset's n, 1,000,000 "
           "for 'default', 100,000 for 'ndc'); stated in every table caption")
    a("--metric-preset", dest="metric_preset", metavar="NAME",
      help="metric protocol: default (canonical frame, Chamfer-L1, F1@0.005/0.01, ECD/EF1) or ndc (NDC's script)")
    a("--seed", nargs="+", type=int, metavar="S", help="seeds in [0, 2^63) (default 0); each seed is a separate job "
                                                       "per shape and method (sampling, network init, metric samples)")
    a("--out", metavar="DIR", help="run directory (default runs/<YYYYmmdd-HHMMSS>); an existing one is continued")
    a("--resume", action="store_true", help="continue a run with its saved configuration (OUT/config.json; "
                                            "without --out: the latest run under runs/); options given may add "
                                            "methods or seeds or change how it runs, never what it computes")
    a("--executor", help="auto (default: on a CPU, one process per physical core with one torch thread each when "
                         "there are two or more tasks; else local), local (in-process, sequential), process "
                         "(--workers local processes), ray (Ray tasks, local instance or --address cluster)")
    a("--workers", type=int, metavar="K", help="parallel jobs for auto and process (default: physical cores for "
                                               "auto, CPU cores for process) and for a local ray instance (its CPU "
                                               "count); torch threads per job: auto 1, process max(1, cores // K)")
    a("--address", metavar="ADDR", help="ray cluster to join: 'auto' (a cluster started with `ray start`) or "
                                        "host:port; without it a local ray instance is started")
    a("--gpus-per-job", dest="gpus_per_job", type=float, metavar="F",
      help="ray: GPUs a fitting job asks for when the cluster has GPUs (default 1; fractions allowed, e.g. 0.5)")
    a("--cpus-per-job", dest="cpus_per_job", type=float, metavar="C", help="ray: CPUs per job (default 1)")
    a("--threads", type=int, metavar="T",
      help="torch CPU threads per job (default: 1 for auto's process workers, torch's own (all cores) for local "
           "and for auto with one task; cores // workers for process; --cpus-per-job for ray)")
    a("--retries", type=int, metavar="R", help="times a job whose worker died is retried (default 1); "
                                               "jobs that raise are recorded failed at once")
    a("--checkpoints", type=_fractions, metavar="F1,F2,...",
      help="neural mode: also score the network at these fractions of the fit budget, e.g. 0.25,0.5,1 "
           "(anytime curves: one row per checkpoint in results.db/checkpoints.csv and a plot of each "
           "metric against fit seconds in the report); off by default; jobs with checkpoints always fit")
    a("--method-param", dest="method_param", action="append", metavar="METHOD.NAME=VALUE",
      help="override an extractor parameter, e.g. sals.o_threshold=0.2 or sals.normals=no (repeatable); "
           "typed and range-checked against the method's parameters")
    a("--budget-param", dest="budget_param", action="append", metavar="NAME=VALUE",
      help="override a value of the budget, e.g. num_samples=500000 or iterations=2000 (repeatable; "
           "typed and range-checked; recorded in config.json and every table caption)")
    a("--sweep", action="append", metavar="KEY=V1,V2,...",
      help="run every value of a setting in one run directory (repeatable: the cross product). KEY: grid, "
           "eval_points, budget, seed, budget.NAME (e.g. budget.num_samples) or METHOD.NAME (e.g. "
           "sals.o_threshold); values typed like --method-param. Each row records its values in columns "
           "sweep.KEY; jobs that differ only in extraction settings share one fit; a neural sweep also "
           "runs its oracle ceiling (see --no-ceiling)")
    a("--no-ceiling", dest="ceiling", action="store_const", const=False,
      help="a neural sweep without its oracle ceiling (the same sweep on the exact field)")
    a("--recipe", metavar="NAME", help="a shipped sweep reproducing one of the paper's ablations "
                                       f"({', '.join(recipe_names())}); options given here override it")
    a("--cache-dir", dest="cache_dir", metavar="DIR", help="cache root (default $SALSBENCH_CACHE or ~/.cache/salsbench)")
    a("--no-cache", dest="no_cache", action="store_const", const=True,
      help="do not read or write the weights/mesh/field caches")
    a("--plugin", action="append", metavar="MODULE",
      help="import MODULE (or MODULE:FUNCTION, then call it) first, in the driver and every worker, "
           "to register extra methods or datasets (repeatable)")
    a("--quiet", action="store_const", const=True, help="no progress bar; one line per finished job (CI logs)")
    a("--recompute-stale", dest="recompute_stale", action="store_const", const=True,
      help="in an existing run directory, recompute the finished tasks whose code changed since "
           "(without it such a run is refused: one directory never mixes two code versions)")
    return p


def _fractions(text: str) -> tuple[float, ...]:
    """'0.25,0.5,1' -> (0.25, 0.5, 1.0) (argparse type: a bad value is one line, exit 2)."""
    try:
        return tuple(float(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated fractions like 0.25,0.5,1, got '{text}'") from None


def parse_method_params(items: Sequence[str] | None, plugins: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``['sals.o_threshold=0.2']`` -> ``{'sals': {'o_threshold': 0.2}}``, typed by the method's
    :class:`methods.params.Param` (ConfigError naming the bad item otherwise)."""
    if not items:
        return {}
    import_plugins(plugins)
    from methods.base import METHODS

    out: dict[str, dict[str, Any]] = {}
    for item in items:
        lhs, eq, raw = item.partition("=")
        method, dot, name = lhs.partition(".")
        if not (eq and dot and method and name):
            raise ConfigError(f"--method-param '{item}': use METHOD.NAME=VALUE (e.g. sals.o_threshold=0.2)")
        try:
            cls = METHODS.get(method)
            if name not in cls.parameters:
                raise ConfigError(f"--method-param '{item}': method '{method}' has no parameter '{name}'; known: "
                                  f"{', '.join(sorted(cls.parameters)) or 'none'}")
            out.setdefault(method, {})[name] = cls.parameters[name].parse(raw, f"--method-param {method}.{name}")
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    return out


def _overrides(args: argparse.Namespace, plugins: Sequence[str]) -> dict[str, Any]:
    """The RunConfig fields given on the command line (paths made absolute)."""
    cli_only = {"config", "out", "resume", "recipe"}
    given = {_FIELD_OF.get(k, k): v for k, v in vars(args).items() if v is not None and k not in cli_only}
    for key in ("data_dir", "list_file", "cache_dir"):
        if key in given:
            given[key] = str(Path(given[key]).expanduser().resolve())
    if "train_dirs" in given:
        given["train_dirs"] = tuple(str(Path(d).expanduser().resolve()) for d in given["train_dirs"])
    if "method_params" in given:
        given["method_params"] = parse_method_params(given["method_params"], given.get("plugins", plugins))
    if "budget_params" in given:
        given["budget_params"] = _key_values(given["budget_params"], "--budget-param", "NAME=VALUE (e.g. iterations=2000)")
    if "sweep" in given:
        from benchmark.run.sweep import split_items

        given["sweep"] = split_items(given["sweep"])
    for key in ("methods", "seeds", "plugins"):
        if key in given:
            given[key] = tuple(dict.fromkeys(given[key]))
    return given


def _key_values(items: Sequence[str], flag: str, form: str) -> dict[str, str]:
    """``['a=1', 'b=x']`` -> ``{'a': '1', 'b': 'x'}`` (typed later, against the registry)."""
    out = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not (eq and key.strip() and value.strip()):
            raise ConfigError(f"{flag} '{item}': use {form}")
        out[key.strip()] = value.strip()
    return out


def typed_settings(config: RunConfig) -> RunConfig:
    """The config with its budget overrides and sweep values typed (as the registry declares them),
    so a value given as text on the command line equals the same value from a TOML file."""
    if not (config.budget_params or config.sweep):
        return config
    import_plugins(config.plugins)
    from benchmark.run.sweep import budget_parameters, typed_sweep
    from methods.base import METHODS, available_methods

    BUDGET_PARAMS = budget_parameters(config.task)
    budget_params = {}
    for key, value in config.budget_params.items():
        if key not in BUDGET_PARAMS:
            raise ConfigError(f"--budget-param: the budget has no setting '{key}' a run may change; known: "
                              f"{', '.join(sorted(BUDGET_PARAMS))}")
        try:
            budget_params[key] = BUDGET_PARAMS[key].parse(value, f"--budget-param {key}")
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    methods = config.methods or tuple(available_methods(config.task))
    for m in methods:
        if m not in METHODS:
            raise ConfigError(f"--methods: {METHODS.unknown(m)}")
    sweep = typed_sweep(config.sweep, methods, config.mode, config.task)
    return dataclasses.replace(config, budget_params=budget_params, sweep=sweep)


def latest_run_dir(root: Path = RUNS_ROOT) -> Path | None:
    runs = sorted(p for p in root.iterdir() if (p / "config.json").is_file()) if root.is_dir() else []
    return runs[-1] if runs else None


def out_dir_of(args: argparse.Namespace) -> Path:
    if args.out:
        return Path(args.out)
    if args.resume:
        latest = latest_run_dir()
        if latest is None:
            raise ConfigError("--resume: no --out given and no earlier run under runs/")
        return latest
    return RUNS_ROOT / _dt.datetime.now().strftime("%Y%m%d-%H%M%S")


def configure(args: argparse.Namespace, run_dir: Path | None) -> RunConfig:
    """The configuration of this invocation (module docstring), checked against the directory's
    (``run_dir`` None: no run directory, as for ``train``).

    Called with the directory locked, so no other driver changes config.json meanwhile.
    """
    saved = saved_config(run_dir) if run_dir is not None else None
    if args.resume and (args.config or args.recipe):
        raise ConfigError("--resume continues a run with its saved config.json; --config/--recipe start a new "
                          "one: give one")
    if args.config and args.recipe:
        raise ConfigError("--config and --recipe both give the settings: give one")
    if args.resume:
        if saved is None:
            raise ConfigError(f"--resume: {run_dir / 'config.json'} does not exist (nothing to resume)")
        base = saved
    else:
        source = args.config or (recipe_path(args.recipe) if args.recipe else None)
        base = RunConfig.load(source) if source else RunConfig()
    try:
        config = typed_settings(RunConfig(**{**base.to_dict(), **_overrides(args, base.plugins)}))
    except TypeError as exc:
        raise ConfigError(str(exc)) from None
    if saved is not None:
        diff = saved.identity_diff(config)
        if diff:
            hint = "" if args.resume else " (--resume continues it with its own settings)"
            raise ConfigError(f"--out {run_dir} holds a run with other settings: {'; '.join(diff)}; "
                              f"use another --out{hint}")
        config = saved.merged_scope(config)
    return config


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "report":
        from benchmark.run.report_cli import report_main

        return report_main(argv[1:])
    if argv and argv[0] == "train":
        return train_main(argv[1:])
    args = build_parser().parse_args(argv)
    try:
        out = out_dir_of(args)
        plan = _plan(args, out)  # every check before the directory is created
        run_dir = RunDirectory(check_writable_dir(out, "--out"))
        with run_dir.lock():
            plan = _plan(args, out)  # again under the lock: another run may have written config.json meanwhile
            from benchmark.run.driver import run
            from benchmark.run.provenance import environment_record

            record = {"config": plan.config.to_dict(), "resolved": plan.record(),
                      "environment": environment_record(),
                      "command": " ".join([Path(sys.argv[0]).name] + list(argv))}
            outcome = run(plan, run_dir, record)
    except (ConfigError, SchemaMismatch) as exc:
        print(f"run_benchmark.py: error: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    return EXIT_OK if outcome.failed == 0 else EXIT_FAILED_TASKS


def train_main(argv: Sequence[str]) -> int:
    """``run_benchmark.py train --task reconstruct [--methods ...] [--budget B]``: train (or find in
    the cache) the network of every learned method of the plan, without evaluating anything."""
    args = build_parser().parse_args(list(argv))
    try:
        if args.out or args.resume:
            raise ConfigError("train writes no run directory: --out/--resume do not apply")
        plan = resolve(configure(args, None))
        from methods.base import get_method

        learned = [m for m in plan.methods if get_method(m).learned]
        if not learned:
            raise ConfigError(f"train: none of {', '.join(plan.methods)} is a learned method "
                              f"(use --task reconstruct and e.g. --methods sals-knn)")
    except ConfigError as exc:
        print(f"run_benchmark.py: error: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    from tqdm import tqdm

    from benchmark.run.tasks import cache_root_of
    from benchmark.run.training import trained_network

    if plan.config.threads:
        from benchmark.run.executors import pin_threads

        pin_threads(int(plan.config.threads))
    for name in learned:
        bar = tqdm(total=plan.budget.steps, desc=f"train {name} ({plan.budget.name})", disable=plan.config.quiet)

        def progress(step, loss, bar=bar):
            bar.update(step - bar.n)
            bar.set_postfix(loss=f"{loss:.4g}")

        _, facts = trained_network(get_method(name, **plan.method_params[name]), plan.budget, plan.train_dirs,
                                   cache_root_of(plan.config), progress=progress)
        bar.close()
        how = (f"trained in {facts['train_loop_s']:.0f} s, final loss {facts['train_final_loss']:.4g}"
               if facts["trained"] else "found in the cache")
        print(f"salsbench: {name}: network {facts['network_key']} on {facts['training_shapes']} training shapes "
              f"{how}", file=sys.stderr, flush=True)
    return EXIT_OK


def _plan(args: argparse.Namespace, out: Path):
    """The resolved plan of this invocation; its config lists the resolved methods explicitly."""
    config = configure(args, out)
    if not config.no_cache:
        from benchmark.storage import cache_root

        check_writable_dir(cache_root(config.cache_dir), "--cache-dir")
    plan = resolve(config)
    return dataclasses.replace(plan, config=dataclasses.replace(config, methods=plan.methods))
