"""The run context the reports are given, and what they say about the protocol.

The run layer passes ``context``, a flat dict with the keys of :data:`CONTEXT_KEYS`:

========== =====================================================================
dataset     dataset name (str)
task        'encode', 'reconstruct' or 'score'
mode        'neural' or 'oracle' (stated for the encode task only)
budget      budget name (str), None in oracle mode; budget_values {budget family: its values}, or None
            when no method of the run fits or trains under a budget (then no budget is stated)
grid        N, the extraction grid has N³ points on [-1, 1]³
seeds       list of int (stated as 'seed 0' or 'seeds 0, 1, 2')
methods     method names in display order; shapes: shape names in dataset order
metric_preset  a key of ``foundation.metrics.PRESETS``
eval_points the effective number of metric samples per mesh (int)
device      e.g. 'cpu (<CPU model>)'; cpu_model, gpu: str or None
git_commit  str or None
execution   {'executor', 'workers', 'threads_per_job'} or None: how the jobs ran (:func:`execution_text`)
sessions    optional: [{'started', 'execution', 'git_commit', 'tasks'}], one per invocation that ran tasks
            in the run directory (named in :func:`execution_text` where their executions differ)
sweep       optional: {key: [values in the user's order]} of a sweep run (:mod:`reports.sweep`);
            empty or missing when the run is not a sweep
method_notes optional: {method: sentence} every caption carries (what a row is, where its name
            could mislead; ``methods.base.Presentation.note``)
========== =====================================================================

The metric protocol (which metrics, their multipliers, the protocol text) comes from the preset
itself: ``PRESETS[name].headline_metrics()`` and ``PRESETS[name].describe_items(n_points)``.
"""

from __future__ import annotations

import re

from foundation.metrics import PRESETS

CONTEXT_KEYS = ("dataset", "task", "mode", "budget", "budget_values", "grid", "seeds", "methods", "shapes",
                "metric_preset", "eval_points", "device", "cpu_model", "gpu", "git_commit", "execution")


def check_context(context) -> dict:
    """``context`` as a dict, checked: every key of :data:`CONTEXT_KEYS` and a known metric preset.

    Raises
    ------
    ValueError
        One line naming the missing keys or the unknown preset.
    """
    if not isinstance(context, dict):
        raise ValueError(f"context must be a dict, got {type(context).__name__}")
    missing = [k for k in CONTEXT_KEYS if k not in context]
    if missing:
        raise ValueError(f"context lacks key(s) {', '.join(missing)}")
    if context["metric_preset"] not in PRESETS:
        raise ValueError(f"unknown metric preset '{context['metric_preset']}'; known: {', '.join(PRESETS)}")
    return context


def headline_metrics(context: dict, columns) -> list:
    """The preset's ``HeadlineMetric`` s (paper order: CD, NC, F1@tau..., ECD, EF1) whose column is
    in ``columns``."""
    columns = set(columns)
    return [m for m in PRESETS[context["metric_preset"]].headline_metrics() if m.column in columns]


def sweep_spec(context: dict) -> dict[str, list]:
    """The context's sweep {key: values}, keys without values dropped; {} when it is not a sweep."""
    return {str(k): list(v) for k, v in (context.get("sweep") or {}).items() if len(v)}


def device_text(context: dict) -> str:
    """The device, with the GPU and CPU model when the device text does not already name them. The
    torch threads a CPU device text names ('cpu (2 threads)') are the driver process's: where the
    execution record states the jobs' own (:func:`execution_text`), they are left out."""
    text = str(context["device"] or "device not recorded")
    if (context.get("execution") or {}).get("threads_per_job"):
        text = re.sub(r"\s*\(\d+ threads?\)$", "", text)
    extra = [str(context[k]) for k in ("gpu", "cpu_model") if context[k] and str(context[k]) not in text]
    return text + (f" ({'; '.join(extra)})" if extra else "")


def seeds_item(seeds) -> tuple[str, str]:
    """('seed', '0') for one seed, ('seeds', '0, 1, 2') for several: the values, never a count."""
    seeds = list(seeds)
    return ("seed" if len(seeds) == 1 else "seeds"), ", ".join(str(s) for s in seeds)


def execution_text(context: dict) -> str:
    """How the jobs ran: 'executor process, 2 workers x 1 torch thread'; where the invocations that
    ran the tasks of one directory ran them differently (``sessions``), each with its task count:
    'executor process, 2 workers x 1 torch thread (18 tasks); executor local, 1 worker x 2 torch
    threads (2 tasks)'. '' where not recorded."""
    counts: dict[str, list] = {}  # how the tasks ran -> task counts of the sessions that ran them so
    for s in context.get("sessions") or ():
        if s.get("tasks") != 0 and (s.get("execution") or {}).get("executor"):
            counts.setdefault(_execution_words(s["execution"]), []).append(s["tasks"])
    if len(counts) > 1:
        return "; ".join(f"{kind} ({'tasks of an earlier run' if None in n else f'{sum(n)} tasks'})"
                         for kind, n in counts.items())
    execution = context["execution"] or {}
    return _execution_words(execution) if execution.get("executor") else ""


def _execution_words(execution: dict) -> str:
    workers, threads = execution.get("workers"), execution.get("threads_per_job")
    text = f"executor {execution['executor']}"
    if workers:
        text += f", {workers} worker{'s' if workers != 1 else ''}"
    if threads:
        text += f" x {threads} torch thread{'s' if threads != 1 else ''}"
    return text


def protocol_items(context: dict) -> list[tuple[str, str]]:
    """(label, value) pairs stating the run's protocol, for captions and the HTML page: dataset,
    task, mode (the encode task's only: neural fit or oracle field), budget (where a method of the
    run fits or trains under one), grid, seed(s), then the metric preset's own description."""
    shapes = f"{len(context['shapes'])} shape{'' if len(context['shapes']) == 1 else 's'}"
    if context.get("planned_shapes") not in (None, len(context["shapes"])):
        shapes += f" of the run's {context['planned_shapes']}: those whose every job finished"
    items = [("dataset", f"{context['dataset']} ({shapes})"), ("task", str(context["task"]))]
    if context["task"] == "score":  # meshes made elsewhere: no mode, budget or grid of this run applies
        return items + [seeds_item(context["seeds"])] + PRESETS[context["metric_preset"]].describe_items(
            context["eval_points"])
    if context["task"] == "encode":  # the reconstruct task has no oracle: its mode says nothing
        items.append(("mode", str(context["mode"])))
    if context["budget"] is not None and (context["budget_values"] or context["task"] == "encode"):
        families = context["budget_values"] or {}
        if not all(isinstance(v, dict) for v in families.values()):  # flat values, not keyed by family
            families = {"": families}
        described = "; ".join((f"{family}: " if len(families) > 1 else "") + ", ".join(f"{k} {v}" for k, v in values.items())
                              for family, values in families.items())
        items.append(("budget", str(context["budget"]) + (f" ({described})" if described else "")))
    grid = int(context["grid"])
    items += [("grid", f"{grid}³ points on [-1, 1]³"), seeds_item(context["seeds"])]
    if sweep_spec(context):
        items.append(("sweep", " × ".join(f"{k} ({', '.join(map(str, v))})" for k, v in sweep_spec(context).items())))
    return items + PRESETS[context["metric_preset"]].describe_items(context["eval_points"])


def protocol_caption(context: dict) -> str:
    """'Protocol: dataset: ...; mode: ...; ... .' (one line)."""
    notes = [note for m, note in (context.get("method_notes") or {}).items() if m in context["methods"]]
    return " ".join(["Protocol: " + "; ".join(f"{k}: {v}" for k, v in protocol_items(context)) + "."] + notes)


def report_title(context: dict, what: str = "summary") -> str:
    """'salsbench summary: <dataset>'."""
    return f"salsbench {what}: {context['dataset']}"
