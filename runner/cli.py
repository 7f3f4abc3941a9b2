"""The command line: ``run_benchmark.py [options]`` and ``run_benchmark.py report RUN_DIR ...``.

Exit status: 0 every task ok; 2 refused before any work (bad option, path or name, a run directory
holding another protocol or in use by another run); 3 the run finished with failed tasks (their
errors are in the tables and ``results.db``; "N ok, M failed" is the last line).

Where a run's configuration comes from, in order (later wins): the defaults of
:class:`runner.config.RunConfig`; ``--config FILE`` (TOML/JSON settings, or a run's
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

from foundation.params import ParamError
from runner.config import ConfigError, RunConfig, flag_of, import_plugins
from runner.parsing import EXIT_FAILED_TASKS, EXIT_OK, EXIT_REFUSED, OneLineParser
from runner.plan import resolve
from runner.records import SchemaMismatch
from runner.rundir import RunDirectory, check_writable_dir, saved_config

RUNS_ROOT = Path("runs")

#: Shipped recipes: ``runner/recipes/<name>.toml`` (``--recipe NAME``).
RECIPES_DIR = Path(__file__).resolve().parent / "recipes"


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
            "List the reference sets (published rows to join with --reference), or make one from a run:\n"
            "  run_benchmark.py references [make RUN_DIR --name NAME]\n"
            "Train the learned reconstruction methods' networks without evaluating:\n"
            "  run_benchmark.py train --task reconstruct [--methods sals-knn ...] [--budget cpu]"
        ),
        epilog="Caches (exact fields, fitted weights, extracted meshes) live in $SALSBENCH_CACHE or "
               "~/.cache/salsbench. SALSBENCH_DEVICE=cpu|cuda forces the torch device.",
    )
    a = p.add_argument
    settings = RunConfig.params()

    def setting(name: str, **kwargs):
        """The option of RunConfig field ``name``: its help is the field's Param, which also parses
        its value (:func:`_overrides`), as it parses the same setting from a file or a sweep."""
        a(flag_of(name), dest=name, help=settings[name].help, **kwargs)

    a("--config", metavar="FILE", help="settings from a TOML/JSON file or a run's config.json (options given "
                                       "here override it); with --out NEW it reproduces that run")
    setting("task", choices=settings["task"].choices)
    setting("pc_points", metavar="P")
    setting("pc_noise", metavar="SIGMA")
    setting("pc_corruption", metavar="NAME")
    setting("pc_blocks", metavar="B")
    setting("pc_scene_grid", metavar="N")
    setting("train_dirs", action="append", metavar="DIR")
    setting("methods", nargs="+", metavar="METHOD")
    setting("dataset", metavar="NAME")
    setting("data_dir", metavar="DIR")
    setting("list_file", metavar="FILE")
    setting("dataset_params", action="append", metavar="NAME=VALUE")
    setting("limit", metavar="N")
    setting("shapes", nargs="+", metavar="NAME")
    setting("mode", choices=settings["mode"].choices)
    setting("budget", metavar="NAME")
    setting("grid", metavar="N")
    setting("eval_points", metavar="N")
    setting("metric_preset", metavar="NAME")
    setting("seeds", nargs="+", metavar="S")
    a("--out", metavar="DIR", help="run directory (default runs/<YYYYmmdd-HHMMSS>); an existing one is continued")
    a("--resume", action="store_true", help="continue a run with its saved configuration (OUT/config.json; "
                                            "without --out: the latest run under runs/); options given may add "
                                            "methods or seeds or change how it runs, never what it computes")
    setting("executor")
    setting("workers", metavar="K")
    setting("address", metavar="ADDR")
    setting("gpus_per_job", metavar="F")
    setting("cpus_per_job", metavar="C")
    setting("threads", metavar="T")
    setting("retries", metavar="R")
    setting("max_faces", metavar="N")
    setting("max_points", metavar="N")
    setting("worker_memory", metavar="GIB")
    setting("checkpoints", type=_comma_list, metavar="F1,F2,...")
    setting("decompose", action="store_const", const=True)
    setting("method_params", action="append", metavar="METHOD.NAME=VALUE")
    setting("budget_params", action="append", metavar="NAME=VALUE")
    setting("sweep", action="append", metavar="KEY=V1,V2,...")
    a("--no-ceiling", dest="ceiling", action="store_const", const=False,
      help="a neural sweep without its oracle ceiling (the same sweep on the exact field)")
    a("--recipe", metavar="NAME", help="a shipped sweep reproducing one of the paper's ablations "
                                       f"({', '.join(recipe_names())}); options given here override it")
    setting("cache_dir", metavar="DIR")
    setting("no_cache", action="store_const", const=True)
    setting("plugins", action="append", metavar="MODULE")
    setting("quiet", action="store_const", const=True)
    setting("gallery", metavar="N")
    setting("recompute_stale", action="store_const", const=True)
    setting("reference", metavar="NAME")
    setting("reference_keep", choices=settings["reference_keep"].choices)
    return p


def _comma_list(text: str) -> tuple[str, ...]:
    """'0.25,0.5,1' -> ('0.25', '0.5', '1') (typed by the setting's Param when the config is built)."""
    return tuple(t.strip() for t in text.split(",") if t.strip())


def parse_method_params(items: Sequence[str] | None, plugins: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``['sals.o_threshold=0.2']`` -> ``{'sals': {'o_threshold': 0.2}}``, typed by the method's
    :class:`foundation.params.Param` (ConfigError naming the bad item otherwise). A name that is no
    registered method keeps its values as text: the run's task types them by its row
    (:func:`tasks.rows.row_kind`: a score run's predictions) or refuses the name."""
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
        if method not in METHODS:
            out.setdefault(method, {})[name] = raw
            continue
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
    given = {k: v for k, v in vars(args).items() if v is not None and k not in cli_only}
    settings = RunConfig.params()
    try:  # typed here too, so that a bad value is named by the option the user typed
        given.update({k: settings[k].parse(v, flag_of(k)) for k, v in given.items() if settings[k].kind is not dict})
    except ParamError as exc:
        raise ConfigError(str(exc)) from None
    for key in ("data_dir", "list_file", "cache_dir"):
        if key in given:
            given[key] = str(Path(given[key]).expanduser().resolve())
    if "train_dirs" in given:
        given["train_dirs"] = tuple(str(Path(d).expanduser().resolve()) for d in given["train_dirs"])
    if "method_params" in given:
        given["method_params"] = parse_method_params(given["method_params"], given.get("plugins", plugins))
    if "budget_params" in given:
        given["budget_params"] = _key_values(given["budget_params"], "--budget-param", "NAME=VALUE (e.g. steps=2000)")
    if "dataset_params" in given:
        given["dataset_params"] = _key_values(given["dataset_params"], "--dataset-option", "NAME=VALUE (e.g. length=100)")
    if "sweep" in given:
        from runner.sweep import split_items

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
    from runner.sweep import readable_budget_parameters, typed_sweep
    from methods.base import METHODS, available_methods

    methods = config.methods or tuple(available_methods(config.task))
    for m in methods:
        if m not in METHODS:
            raise ConfigError(f"--methods: {METHODS.unknown(m)}")
    readable = readable_budget_parameters(methods, config.budget_params)
    budget_params = {}
    for key, value in config.budget_params.items():
        try:
            budget_params[key] = readable[key].parse(value, f"--budget-param {key}")
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    sweep = typed_sweep(config.sweep, methods, config.mode)
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
    flags = _overrides(args, base.plugins)
    if "budget" in flags and {**base.to_dict(), **flags}["mode"] == "oracle":
        raise ConfigError("--budget needs --mode neural (oracle mode fits nothing)")
    try:
        config = typed_settings(RunConfig(**{**base.to_dict(), **flags}))
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
        from runner.report_cli import report_main

        return report_main(argv[1:])
    if argv and argv[0] == "train":
        return train_main(argv[1:])
    if argv and argv[0] == "export-inputs":
        return export_inputs_main(argv[1:])
    if argv and argv[0] == "score":
        return score_main(argv[1:])
    if argv and argv[0] == "references":
        from runner.references_cli import references_main

        return references_main(argv[1:])
    args = build_parser().parse_args(argv)
    try:
        out = out_dir_of(args)
        plan = _plan(args, out)  # every check before the directory is created
        if plan.config.task == "score":
            _say_unmatched(plan)
        run_dir = RunDirectory(check_writable_dir(out, "--out"))
        with run_dir.lock():
            plan = _plan(args, out)  # again under the lock: another run may have written config.json meanwhile
            from runner.driver import run
            from runner.provenance import environment_record

            record = {"config": plan.config.to_dict(), "resolved": plan.record(),
                      "environment": environment_record(),
                      "command": " ".join([Path(sys.argv[0]).name] + list(argv))}
            outcome = run(plan, run_dir, record)
    except (ConfigError, SchemaMismatch) as exc:
        print(f"run_benchmark.py: error: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    return EXIT_OK if outcome.failed == 0 else EXIT_FAILED_TASKS


def _take(argv: list[str], flag: str, default: str | None = None) -> str | None:
    """The value of ``flag`` in ``argv``, removed from it (``default`` when absent; '' when it ends argv)."""
    if flag not in argv:
        return default
    at = argv.index(flag)
    value = argv[at + 1] if at + 1 < len(argv) else ""
    del argv[at:at + 2]
    return value


def score_main(argv: Sequence[str]) -> int:
    """``run_benchmark.py score --pred-dir DIR --name NAME [--pred-frame original|canonical] [--dataset ...
    --out ...]``: score a folder of meshes made elsewhere as the method NAME of a run of ``--task
    score`` (:mod:`tasks.score`); every other setting as for a run."""
    from tasks.rows import predictions_row
    from tasks.score import FRAMES

    argv = list(argv)
    pred_dir, name, frame = _take(argv, "--pred-dir"), _take(argv, "--name"), _take(argv, "--pred-frame", "original")
    try:
        if not pred_dir or not name:
            raise ConfigError("score needs --pred-dir DIR (the predicted meshes) and --name NAME (their method's row)")
        if frame not in FRAMES:
            raise ConfigError(f"--pred-frame must be one of {', '.join(FRAMES)}, got {frame!r}")
        folder = Path(pred_dir).expanduser().resolve()
        if not folder.is_dir():
            raise ConfigError(f"--pred-dir {pred_dir}: not a folder")
        predictions_row(name)
    except (ConfigError, ValueError) as exc:
        print(f"run_benchmark.py: error: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    return main(["--task", "score", "--methods", name, "--method-param", f"{name}.pred_dir={folder}",
                 "--method-param", f"{name}.pred_frame={frame}", *argv])


def _say_unmatched(plan) -> None:
    """One line listing the predictions of a score run that match none of its shapes (ignored)."""
    from tasks.score import unmatched_predictions

    for name in plan.methods:
        extra = unmatched_predictions(plan.method_params[name]["pred_dir"], plan.shapes, name)
        if extra:
            shown = ", ".join(extra[:10]) + (f" and {len(extra) - 10} more" if len(extra) > 10 else "")
            print(f"salsbench: {name}: {len(extra)} prediction(s) match no shape of the dataset, ignored: {shown}",
                  file=sys.stderr)


def export_inputs_main(argv: Sequence[str]) -> int:
    """``run_benchmark.py export-inputs --out DIR [--cloud-format ply|npz] [run settings]``: write the
    inputs a run with these settings gives its methods (:mod:`runner.export_inputs`)."""
    from runner.export_inputs import FORMATS, export_inputs

    argv = list(argv)
    fmt = _take(argv, "--cloud-format", "ply")
    args = build_parser().parse_args(argv)
    try:
        if fmt not in FORMATS:
            raise ConfigError(f"--cloud-format must be one of {', '.join(FORMATS)}, got {fmt!r}")
        if not args.out or args.resume:
            raise ConfigError("export-inputs writes its files under --out DIR (and continues no run: --resume does "
                              "not apply)")
        plan = resolve(configure(args, None))
        out = check_writable_dir(Path(args.out), "--out")
    except ConfigError as exc:
        print(f"run_benchmark.py: error: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    folders = export_inputs(plan, out, fmt, progress=None if plan.config.quiet else print)
    print(f"salsbench: inputs of {len(plan.shapes)} shape(s) in {', '.join(map(str, folders))}")
    return EXIT_OK


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

    from runner.plan import cache_root_of
    from tasks.trained_networks import trained_network

    if plan.config.threads:
        from runner.executors import pin_threads

        pin_threads(int(plan.config.threads))
    for name in learned:
        method = get_method(name, **plan.method_params[name])
        budget = plan.budgets[method.budget_family]
        bar = tqdm(total=None, desc=f"train {name} ({budget.name})", disable=plan.config.quiet)

        def progress(step, loss, total=None, bar=bar):
            if total is not None and bar.total != total:
                bar.total = total
            bar.update(step - bar.n)
            bar.set_postfix(loss=f"{loss:.4g}")

        _, facts = trained_network(method, budget, plan.train_dirs, cache_root_of(plan.config), progress=progress)
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
        from foundation.storage import cache_root

        check_writable_dir(cache_root(config.cache_dir), "--cache-dir")
    plan = resolve(config)
    saved, now = RunDirectory(out).read_record().get("resolved", {}), plan.record()
    for key in ("train_dirs", "training_set"):  # compared where both invocations train learned methods
        if saved.get(key) and now[key] and saved[key] != now[key]:
            raise ConfigError(f"--out {out} holds a run trained on another training set ({key} {saved[key]} there, "
                              f"{now[key]} now); use another --out")
    if config.reference:
        from runner.references import check_reference, find_reference

        check_reference(find_reference(config.reference), config.to_dict(), now, config.reference_keep)
    elif config.reference_keep:
        raise ConfigError("--reference-keep says which rows of --reference to keep: give --reference NAME")
    return dataclasses.replace(plan, config=dataclasses.replace(config, methods=plan.methods))
