"""Reference sets: the per-shape rows of finished runs, kept with the protocol they were made under,
joined to a user's run (``--reference NAME``) instead of being re-run.

A set is a folder ``references/<name>/`` (:data:`REFERENCES_DIR`; ``--reference`` also takes the
path of a set's folder) holding

* ``rows.csv``: one row per job, :data:`ROW_COLUMNS` (raw metric units, 9 significant digits;
  ``commit``: the commit whose code computed the row);
* ``manifest.json``: ``name``, ``description``, ``protocol`` (:data:`PROTOCOL_KEYS`: what a joined
  run must share), ``shapes`` ({shape: the digest of its bytes,
  :func:`datasets.manifest.shape_bytes_digest`}), ``budget`` (name and every value) or null,
  ``seeds``, ``methods``, ``dataset_options`` (how its runs built the dataset), and ``sources``: per commit that computed rows, the CPU, the date, the
  command and the code digests of what computed them (``metrics``, ``sampler``, per method ``fit`` and
  ``extraction``; :mod:`tasks.cache`, computed on that commit's files).

A run joins a set only under the same protocol (:func:`check_reference`, before any work): the same
task, mode, input, grid, metric points and preset, dataset, and bytes of every shape both have. A
set whose rows were scored by other metric code than this checkout's is stale and refused with the
command that re-makes it (its meshes are not kept, so re-making is re-running). A row name both in
the run and in the set is refused unless the user says which to keep.

Joined rows are labelled ``<method> (ref)`` and carry the set's name in column ``reference``; the
tables pair them with the run's rows over the shapes both have (:func:`joined_results`). Nothing
of a reference row is recomputed.
"""

from __future__ import annotations

import datetime as _dt
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from foundation.errors import one_line
from runner.config import ConfigError
from runner.provenance import REPO

#: The shipped sets.
REFERENCES_DIR = REPO / "references"

#: The columns of a set's rows.csv.
ROW_COLUMNS = ["shape", "method", "seed", "mode", "budget", "input", "cd", "nc", "f1_005", "f1_01", "ecd", "ef1",
               "n_faces", "status", "error", "seen_in_training", "commit"]

#: What a run must share with a set to be joined to it (those of its protocol that the run has:
#: a score run's meshes were made elsewhere, so it has no task, mode, input or grid of its own).
PROTOCOL_KEYS = ("task", "mode", "input", "pc_points", "pc_noise", "grid", "eval_points", "metric_preset", "dataset")

#: How joined rows are labelled in the tables.
LABEL_SUFFIX = " (ref)"

#: ``--reference-keep``: which rows stay where a row name is in both the run and the set.
KEEP_CHOICES = ("run", "reference")


def run_input(config: dict) -> str:
    """What a run's jobs read: ``mesh`` (encode) or its reconstruct input (``pc_corruption``)."""
    return "mesh" if config.get("task", "encode") != "reconstruct" else str(config.get("pc_corruption", "uniform"))


def budget_label(budget, budget_params: dict) -> str | None:
    """A job's budget as a row names it: the budget's name and the run's ``--budget-param`` changes
    (``cpu steps=2400``), so that a row fitted under a changed budget never reads as the named one."""
    if budget is None or (isinstance(budget, float) and np.isnan(budget)):  # oracle rows: nothing fitted
        return None
    return " ".join([str(budget), *(f"{k}={v}" for k, v in sorted(budget_params.items()))])


def run_protocol(config: dict, resolved: dict) -> dict[str, Any]:
    """The protocol of a run (its config.json's ``config`` and ``resolved``) as :data:`PROTOCOL_KEYS`
    it has."""
    task = config.get("task", "encode")
    protocol: dict[str, Any] = {} if task == "score" else {"task": task}
    if task == "encode":
        protocol.update(mode=config.get("mode", "neural"), input="mesh")
    elif task == "reconstruct":
        protocol.update(input=run_input(config), pc_points=config.get("pc_points"), pc_noise=config.get("pc_noise"))
    if task != "score":
        protocol["grid"] = config.get("grid")
    protocol.update(eval_points=resolved.get("eval_points"), metric_preset=config.get("metric_preset"),
                    dataset=config.get("dataset"))
    return protocol


@dataclass(frozen=True)
class ReferenceSet:
    """One set: its folder, its manifest and its rows."""

    folder: Path
    manifest: dict[str, Any]
    rows: pd.DataFrame

    @property
    def name(self) -> str:
        return self.manifest["name"]

    @property
    def protocol(self) -> dict[str, Any]:
        return self.manifest["protocol"]

    def stale_sources(self) -> list[dict[str, Any]]:
        """The sources whose metric code differs from this checkout's."""
        from tasks.cache import metric_code_digest

        today = metric_code_digest()
        return [s for s in self.manifest["sources"] if s["code"]["metrics"] != today]


def reference_names(folder: Path = REFERENCES_DIR) -> list[str]:
    """The names of the sets in ``folder``, sorted."""
    return sorted(p.parent.name for p in folder.glob("*/manifest.json")) if folder.is_dir() else []


def read_reference(folder: Path) -> ReferenceSet:
    """The set in ``folder``; ConfigError (one line) when its files are missing or unreadable."""
    try:
        manifest = json.loads((folder / "manifest.json").read_text(encoding="utf-8"))
        rows = pd.read_csv(folder / "rows.csv", dtype={"shape": str, "method": str, "commit": str})
    except (OSError, ValueError) as exc:
        raise ConfigError(f"reference set {folder}: not readable ({one_line(exc, limit=200)})") from None
    missing = [c for c in ("name", "protocol", "shapes", "sources") if c not in manifest]
    if missing or set(ROW_COLUMNS) - set(rows.columns):
        what = f"manifest.json lacks {', '.join(missing)}" if missing else \
            f"rows.csv lacks {', '.join(sorted(set(ROW_COLUMNS) - set(rows.columns)))}"
        raise ConfigError(f"reference set {folder}: {what}")
    unknown = set(rows["commit"]) - {s["commit"] for s in manifest["sources"]}
    if unknown:
        raise ConfigError(f"reference set {folder}: rows of commit {sorted(unknown)[0]}, which its manifest does not "
                          "describe")
    return ReferenceSet(folder, manifest, rows)


def find_reference(name: str) -> ReferenceSet:
    """The shipped set ``name``, or the set in folder ``name``; ConfigError naming the known sets."""
    folder = Path(name).expanduser()
    if not (folder / "manifest.json").is_file():
        folder = REFERENCES_DIR / name
    if not (folder / "manifest.json").is_file():
        raise ConfigError(f"--reference {name}: no such reference set; known: {', '.join(reference_names())} "
                          "(run_benchmark.py references lists them)")
    return read_reference(folder)


def remake_command(ref: ReferenceSet, methods: list[str]) -> str:
    """The commands that re-make ``methods`` of ``ref`` under its protocol and make the set again."""
    p = ref.protocol
    options = ref.manifest.get("dataset_options") or {}
    flags = [f"--dataset {p['dataset']}"] + [f"{'--list' if k == 'list_file' else '--' + k.replace('_', '-')} {v}"
                                             for k, v in options.items() if k in ("data_dir", "list_file")]
    flags.append(f"--methods {' '.join(methods)}")
    if p.get("task", "encode") != "encode":
        flags.insert(0, f"--task {p['task']}")
    if p.get("task") == "reconstruct":
        flags.append(f"--pc-corruption {p['input']}" if p["input"] != "uniform" else "")
        flags += [f"--pc-points {p['pc_points']}"] + ([f"--pc-noise {p['pc_noise']}"] if p.get("pc_noise") else [])
    if p.get("mode") == "oracle":
        flags.append("--mode oracle")
    budget = ref.manifest.get("budget")
    if budget and budget.get("name") and budget["name"] != "cpu":
        flags.append(f"--budget {budget['name']}")
    flags += [f"--grid {p['grid']}", f"--eval-points {p['eval_points']}", f"--metric-preset {p['metric_preset']}",
              f"--seed {' '.join(map(str, ref.manifest.get('seeds', [0])))}", f"--out runs/ref-{ref.name}"]
    run = "python run_benchmark.py " + " ".join(f for f in flags if f)
    return f"{run} && python run_benchmark.py references make runs/ref-{ref.name} --name {ref.name} --replace"


def stale_reason(ref: ReferenceSet) -> str | None:
    """One line saying which rows of ``ref`` were scored by other metric code than this checkout's
    and how to re-make them; None when none were."""
    stale = ref.stale_sources()
    if not stale:
        return None
    from tasks.cache import metric_code_digest

    commits = {s["commit"] for s in stale}
    rows = ref.rows[ref.rows["commit"].isin(commits)]
    methods = list(dict.fromkeys(rows["method"]))
    scored = ", ".join(f"{s['code']['metrics']} (commit {s['commit']})" for s in stale)
    return (f"reference set {ref.name} is stale: {len(rows)} of its {len(ref.rows)} rows ({', '.join(methods)}) were "
            f"scored by metric code {scored}, this checkout's is {metric_code_digest()}; re-make them: "
            f"{remake_command(ref, methods)}")


def shape_digests(config: dict, resolved: dict, shapes) -> dict[str, str]:
    """{shape: :func:`datasets.manifest.shape_bytes_digest`} of a run's ``shapes``."""
    from datasets.manifest import shape_bytes_digest
    from tasks.load import load_dataset

    dataset = load_dataset(config["dataset"], resolved.get("dataset_options") or {})
    return {s: shape_bytes_digest(dataset, s) for s in shapes}


def check_reference(ref: ReferenceSet, config: dict, resolved: dict, keep: str | None = None) -> None:
    """ConfigError (one line) when a run (its config.json's ``config`` and ``resolved``) cannot be
    joined to ``ref``: another protocol (naming the setting and both values), a sweep, a stale set,
    the bytes of a shared shape, or a row name in both without ``keep``."""
    if resolved.get("sweep"):
        raise ConfigError(f"--reference {ref.name}: a sweep's rows are several protocols; join a set to a run of one")
    mine = run_protocol(config, resolved)
    for key in PROTOCOL_KEYS:
        if key in mine and key in ref.protocol and mine[key] != ref.protocol[key]:
            raise ConfigError(f"--reference {ref.name}: {key} differs: {ref.protocol[key]!r} in the reference, "
                              f"{mine[key]!r} in this run")
    reason = stale_reason(ref)
    if reason:
        raise ConfigError(reason)
    shared = [s for s in resolved.get("shapes", []) if s in ref.manifest["shapes"]]
    if not shared:
        raise ConfigError(f"--reference {ref.name}: none of this run's {len(resolved.get('shapes', []))} shapes is in "
                          f"the reference (its {len(ref.manifest['shapes'])} shapes, e.g. "
                          f"{', '.join(list(ref.manifest['shapes'])[:2])})")
    for shape, digest in shape_digests(config, resolved, shared).items():
        if digest != ref.manifest["shapes"][shape]:
            raise ConfigError(f"--reference {ref.name}: shape {shape} differs: its bytes are {digest[:16]}... here, "
                              f"{ref.manifest['shapes'][shape][:16]}... in the reference")
    both = [m for m in resolved.get("methods", []) if m in set(ref.rows["method"])]
    if both and keep not in KEEP_CHOICES:
        raise ConfigError(f"--reference {ref.name}: row(s) {', '.join(both)} are both in this run and in the "
                          "reference; say which to keep: --reference-keep run or --reference-keep reference")


def reference_label(method: str) -> str:
    return method + LABEL_SUFFIX


def joined_results(results: pd.DataFrame, ref: ReferenceSet, shapes: list[str], keep: str | None
                   ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The run's ``results`` with the set's rows of ``shapes`` (labelled ``<method> (ref)``, column
    ``reference`` the set's name, ``mode`` empty: they belong to every table of the run), and what
    the reports say of them: ``{'name', 'labels', 'note'}``."""
    own = set(results["method"])
    rows = ref.rows[ref.rows["shape"].isin(shapes)]
    if keep == "run":
        rows = rows[~rows["method"].isin(own)]
    elif keep == "reference":
        results = results[~results["method"].isin(set(rows["method"]))]
    rows = rows.assign(method=rows["method"].map(reference_label), reference=ref.name, mode=np.nan,
                       ref_commit=rows["commit"]).drop(columns=["commit", "input"])
    labels = list(dict.fromkeys(rows["method"]))
    has = set(rows["shape"])
    lacking = [s for s in shapes if s not in has]
    sources = []
    for s in ref.manifest["sources"]:
        n = int((rows["ref_commit"] == s["commit"]).sum())
        if n:
            sources.append(f"{n} rows computed at commit {s['commit']} on {s.get('cpu') or 'an unrecorded CPU'}")
    note = (f"Rows marked{LABEL_SUFFIX}: reference set {ref.name}"
            + (f" ({ref.manifest['description']})" if ref.manifest.get("description") else "")
            + f", not recomputed: {'; '.join(sources) or 'no rows'}; over the {len(has)} of this run's {len(shapes)} "
            "shapes it has" + (f"; it lacks {len(lacking)}: {', '.join(lacking)}" if lacking else "") + ".")
    joined = pd.concat([results, rows], ignore_index=True) if len(rows) else results
    return joined, {"name": ref.name, "labels": labels, "note": note}


def join_reference(results: pd.DataFrame, context: dict[str, Any], record: dict[str, Any], name: str,
                   keep: str | None) -> tuple[pd.DataFrame, dict[str, Any]]:
    """A run's report frame and context (:func:`runner.export.report_context`) with set ``name`` joined,
    after :func:`check_reference` against the run's config.json ``record``."""
    ref = find_reference(name)
    resolved = {**record.get("resolved", {}), "methods": list(dict.fromkeys(results["method"]))}
    check_reference(ref, record.get("config", {}), resolved, keep)
    joined, facts = joined_results(results, ref, list(context["shapes"]), keep)
    methods = [m for m in context["methods"] if m in set(joined["method"])] + facts["labels"]
    return joined, {**context, "methods": methods, "reference": facts}


# -- making a set ------------------------------------------------------------------------------

def code_digests(commit: str, methods: list[str]) -> dict[str, Any]:
    """The code digests of what computes rows of ``methods`` at ``commit`` (:mod:`tasks.cache`): the
    metrics, the sampler, and per method its fit and its extraction (None where the method's code
    is not in the project's packages at that commit, e.g. a plugin file)."""
    from methods.base import get_method
    from tasks.cache import code_digest, commit_tree, fit_code_modules, metric_code_digest

    with commit_tree(commit, REPO) as tree:
        out: dict[str, Any] = {"metrics": metric_code_digest(tree), "sampler": code_digest("foundation.sampler", root=tree),
                               "methods": {}}
        for name in methods:
            try:
                method = get_method(name)
                fit = code_digest(*fit_code_modules(method), root=tree) if method.fit_name else None
                extraction = code_digest(type(method).__module__, root=tree)
            except (ModuleNotFoundError, ValueError, AttributeError):
                fit = extraction = None
            out["methods"][name] = {"fit": fit, "extraction": extraction}
    return out


def write_reference(folder: Path, manifest: dict[str, Any], rows: pd.DataFrame) -> Path:
    """Write a set (rows.csv, manifest.json) into ``folder``, each file atomically."""
    from foundation.storage import atomic_write

    folder.mkdir(parents=True, exist_ok=True)
    rows = rows.reindex(columns=ROW_COLUMNS).sort_values(["method", "shape", "seed"], kind="stable")
    atomic_write(folder / "rows.csv", rows.to_csv(index=False, float_format="%.9g").encode())
    atomic_write(folder / "manifest.json", (json.dumps(manifest, indent=1, sort_keys=False) + "\n").encode())
    return folder


def make_reference(run_dir: Path, name: str, into: Path = REFERENCES_DIR, description: str = "",
                   leave_out: tuple[str, ...] = (), replace: bool = False) -> ReferenceSet:
    """A set named ``name`` in ``into`` from the finished run ``run_dir``: its rows, protocol, shapes'
    bytes and the code digests of the commit that ran it. ConfigError (one line) for a run that
    cannot be one set: a sweep, tasks run at several commits or from a modified checkout, a failed
    job not named in ``leave_out`` (``METHOD`` or ``SHAPE/METHOD``: left out of the set), or a name
    taken (unless ``replace``)."""
    from runner.records import open_run_db
    from runner.rundir import RunDirectory

    if not name or "/" in name or name.startswith("."):
        raise ConfigError(f"references make: --name {name!r}: a set's name is a folder name")
    folder = into / name
    if (folder / "manifest.json").exists() and not replace:
        raise ConfigError(f"references make: a set named {name} exists in {into}; --replace replaces it")
    record = RunDirectory(run_dir).read_record()
    if not (run_dir / "results.db").is_file() or not record:
        raise ConfigError(f"references make: {run_dir}: not a finished salsbench run directory")
    config, resolved, env = record["config"], record["resolved"], record.get("environment", {})
    if resolved.get("sweep"):
        raise ConfigError(f"references make: {run_dir} is a sweep: its rows are several protocols (one set is one)")
    commits = {s.get("git_commit") for s in record.get("sessions") or [] if s.get("tasks") != 0} or \
        {env.get("git_commit")}
    if None in commits or len(commits) != 1:
        raise ConfigError(f"references make: {run_dir}: its tasks ran at "
                          + (f"{len(commits)} commits ({', '.join(sorted(map(str, commits)))})" if len(commits) > 1
                             else "an unrecorded commit") + "; a set records the one commit whose code made its rows")
    if env.get("git_dirty"):
        raise ConfigError(f"references make: {run_dir} ran from a modified checkout of {env.get('git_commit')}: the "
                          "code that made its rows is not a commit")
    (commit,) = commits
    with open_run_db(run_dir, must_exist=True) as db:
        jobs = db.frame("jobs")
    named = set(leave_out)
    left = jobs["method"].isin(named) | (jobs["shape"] + "/" + jobs["method"]).isin(named)
    failed = jobs[(jobs["status"] != "ok") & ~left]
    if len(failed):
        listed = ", ".join(failed["shape"].head(3) + "/" + failed["method"].head(3))
        raise ConfigError(f"references make: {run_dir} has {len(failed)} failed job(s) ({listed}"
                          f"{', ...' if len(failed) > 3 else ''}); name them with --leave-out SHAPE/METHOD or METHOD")
    jobs = jobs[~left]
    if not len(jobs):
        raise ConfigError(f"references make: {run_dir}: no job left to make a set of")
    rows = jobs.assign(input=run_input(config), commit=commit[:7],
                       budget=[budget_label(b, config.get("budget_params") or {}) for b in jobs.get("budget", [None] * len(jobs))])
    methods = list(dict.fromkeys(rows["method"]))
    shapes = list(dict.fromkeys(rows["shape"]))
    try:
        code = code_digests(commit, methods)
    except ValueError as exc:
        raise ConfigError(f"references make: {exc}") from None
    budget = resolved.get("budget")
    manifest = {
        "name": name, "description": description, "protocol": run_protocol(config, resolved),
        "budget": {"name": config.get("budget"), "values": budget} if config.get("budget") else None,
        "seeds": sorted({int(s) for s in rows["seed"]}), "methods": methods,
        "dataset_options": resolved.get("dataset_options") or {}, "shapes": shape_digests(config, resolved, shapes),
        "sources": [{"commit": commit[:7], "cpu": env.get("cpu_model"), "python": env.get("python"),
                     "date": (record.get("started") or "")[:10] or _dt.date.today().isoformat(),
                     "command": record.get("command"), "code": code}],
    }
    write_reference(folder, manifest, rows)
    return read_reference(folder)


def listing(folder: Path = REFERENCES_DIR) -> pd.DataFrame:
    """One row per set of ``folder``: name, protocol, rows, methods, shapes, commits, CPUs, and
    whether its metric code is this checkout's (``current``) or not (``stale``)."""
    out = []
    for name in reference_names(folder):
        ref = read_reference(folder / name)
        p = ref.protocol
        what = " ".join(str(p[k]) for k in ("task", "mode", "input") if p.get(k) not in (None, "mesh"))
        out.append({"name": name, "protocol": f"{what}, {p['dataset']}, grid {p.get('grid')}, "
                                              f"{p['eval_points']:,} points, {p['metric_preset']}",
                    "rows": len(ref.rows), "methods": ref.rows["method"].nunique(), "shapes": len(ref.manifest["shapes"]),
                    "commits": " ".join(s["commit"] for s in ref.manifest["sources"]),
                    "cpu": "; ".join(dict.fromkeys(str(s.get("cpu")) for s in ref.manifest["sources"])),
                    "metric code": "stale" if ref.stale_sources() else "current"})
    return pd.DataFrame(out)
