"""Sweeps: one run over the cross product of setting values (``--sweep KEY=V1,V2,...``).

A sweep key names one setting of a job:

* a run setting: ``grid``, ``eval_points``, ``budget`` (a budget name), ``seed``, and for the
  reconstruct task ``pc_points`` and ``pc_noise``;
* a budget value: ``budget.NAME`` for NAME a field of the budget family of some method of the run
  (:func:`budget_parameters`: ``budget.num_samples``, ``budget.steps``, ...);
* a method parameter: ``METHOD.NAME`` (``sals.o_threshold``, ``sals.normals``, ``sals.faces``).

Values are typed and range-checked by the key's :class:`foundation.params.Param`, exactly as
``--method-param`` and ``--budget-param`` values are. Several keys give their cross product, in the
order given (:func:`variants`). A key applies to a job or not (:meth:`SweepKey.applies_to`): a
method parameter only to that method's jobs (and, if only the neural query reads it, e.g.
``sals.o_threshold``, only to its neural jobs), a budget name only to jobs that fit or train
(encoding methods in neural mode, the learned reconstruction methods, CAP-UDF's optimisation), and
a budget value only to the jobs of methods whose budget family has that field
(:meth:`methods.base.Method.budget_fields`). A job that a
key does not apply to is the same job for every value of the key and runs once (its row has no value
in that key's column; the sweep reports show it as a constant reference).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Sequence

from foundation.params import Param, ParamError
from runner.config import ConfigError, RunConfig

#: Run settings a sweep may vary, typed by their RunConfig fields' Params.
RUN_KEYS: dict[str, Param] = RunConfig.sweep_params()


@dataclass(frozen=True)
class SweepKey:
    """One sweep key. kind: 'run', 'budget' or 'method'; target: the RunConfig field, budget
    setting or method parameter it sets; method: the method of a 'method' key."""

    name: str
    kind: str
    target: str
    param: Param
    method: str | None = None

    def applies_to(self, method: str, mode: str) -> bool:
        """Whether a job of ``method`` in ``mode`` depends on this key (a budget value: only the
        methods whose budget family has that field)."""
        from methods.base import METHODS

        if self.kind == "method":  # a parameter of the neural query only: the exact field ignores it
            return method == self.method and (mode == "neural" or not self.param.neural_only)
        if self.kind == "budget":
            return mode == "neural" and self.target in METHODS.get(method).budget_fields()
        if self.target == "budget":
            return mode == "neural" and trains(method)
        return True


def trains(method: str) -> bool:
    """Whether a job of ``method`` reads a budget (it has a budget family: every encoding method in
    neural mode; the learned reconstruction methods and those that optimise per shape)."""
    from methods.base import METHODS

    return METHODS.get(method).budget_family is not None


#: Budget settings renamed since runs were saved with them: old name -> new name.
RENAMED_BUDGET_SETTINGS = {"iterations": "steps"}


def readable_budget_parameters(methods: Sequence[str], keys: Iterable[str]) -> dict[str, Param]:
    """:func:`budget_parameters` of ``methods``, after checking that each of ``keys`` (the budget
    settings a run changes) is one of them: ConfigError (one line) naming a renamed setting's new
    name, or the settings these methods read."""
    readable = budget_parameters(methods)
    for key in keys:
        if key in RENAMED_BUDGET_SETTINGS:
            raise ConfigError(f"--budget-param {key}: this budget setting is now called "
                              f"'{RENAMED_BUDGET_SETTINGS[key]}' (a run directory saved before the rename: pass "
                              f"--budget-param {RENAMED_BUDGET_SETTINGS[key]}=... into another --out)")
        if key not in readable:
            raise ConfigError(f"--budget-param {key}: no method of this run ({', '.join(methods)}) reads a budget "
                              f"setting '{key}'; the settings they read: {', '.join(sorted(readable)) or 'none'}")
    return readable


def budget_parameters(methods: Sequence[str]) -> dict[str, Param]:
    """The budget fields a run of ``methods`` may change: those of the methods' budget families (a
    field of several families typed by the first; each family parses it again by its own)."""
    from methods.base import METHODS, budget_family

    params: dict[str, Param] = {}
    for family in dict.fromkeys(METHODS.get(m).budget_family for m in methods if trains(m)):
        for key, param in budget_family(family).params.items():
            params.setdefault(key, param)
    return params


def known_keys(methods: Sequence[str]) -> list[str]:
    """Every sweep key for these methods (for error messages and ``--help``)."""
    from methods.base import METHODS

    keys = list(RUN_KEYS) + [f"budget.{k}" for k in sorted(budget_parameters(methods))]
    return keys + [f"{m}.{p}" for m in methods for p in sorted(METHODS.get(m).parameters)]


def sweep_key(name: str, methods: Sequence[str], mode: str) -> SweepKey:
    """The key ``name`` for a run of ``methods`` in ``mode``; ConfigError listing the known keys."""
    from methods.base import METHODS

    budget_params = budget_parameters(methods)
    head, dot, tail = name.partition(".")
    key = None
    if not dot and name in RUN_KEYS:
        key = SweepKey(name, "run", name, RUN_KEYS[name])
    elif dot and head == "budget" and tail in budget_params:
        key = SweepKey(name, "budget", tail, budget_params[tail])
    elif dot and head in methods and tail in METHODS.get(head).parameters:
        key = SweepKey(name, "method", tail, METHODS.get(head).parameters[tail], method=head)
    if key is None:
        raise ConfigError(f"--sweep: unknown key '{name}'; known keys: {', '.join(known_keys(methods))}")
    if mode == "oracle" and not key.applies_to(key.method or "", "oracle"):
        raise ConfigError(f"--sweep {name}: oracle mode fits nothing, so it has no budget to sweep")
    return key


def split_items(items: Iterable[str]) -> dict[str, list[str]]:
    """``['sals.o_threshold=0.1,0.5', 'grid=64,128']`` -> ``{key: [raw values]}`` (ConfigError on a
    malformed item or a key given twice)."""
    out: dict[str, list[str]] = {}
    for item in items:
        key, eq, values = item.partition("=")
        raw = [v.strip() for v in values.split(",") if v.strip()]
        if not (eq and key.strip() and raw):
            raise ConfigError(f"--sweep '{item}': use KEY=V1,V2,... (e.g. sals.o_threshold=0.05,0.1)")
        if key.strip() in out:
            raise ConfigError(f"--sweep {key.strip()} is given twice; give all its values in one --sweep")
        out[key.strip()] = raw
    return out


def typed_sweep(sweep: Mapping[str, Sequence[Any]], methods: Sequence[str], mode: str) -> dict[str, tuple]:
    """Each key's values typed and checked (ConfigError naming the key or value; a budget name that
    the budget family of a method of the run lacks names that family's budgets)."""
    from methods.base import METHODS, budget_family

    families = [budget_family(f) for f in dict.fromkeys(METHODS.get(m).budget_family for m in methods if trains(m))]
    typed: dict[str, tuple] = {}
    for name, values in sweep.items():
        key = sweep_key(name, methods, mode)
        try:
            parsed = tuple(key.param.parse(v, f"--sweep {name}") for v in values)
        except ParamError as exc:
            raise ConfigError(str(exc)) from None
        if not parsed:
            raise ConfigError(f"--sweep {name}: no values")
        if len(set(parsed)) != len(parsed):
            raise ConfigError(f"--sweep {name}: values must not repeat, got {list(values)}")
        if name == "budget":
            for b in parsed:
                for family in families:
                    if b not in family.budgets:
                        raise ConfigError(f"--sweep budget: {family.budgets.unknown(b)}")
        typed[name] = parsed
    return typed


def variants(sweep: Mapping[str, tuple]) -> list[dict[str, Any]]:
    """The cross product of the sweep's values, first key slowest: ``[{key: value, ...}, ...]``
    (one empty variant when nothing is swept)."""
    names = list(sweep)
    return [dict(zip(names, combo)) for combo in itertools.product(*(sweep[n] for n in names))]


def variant_tag(values: Mapping[str, Any]) -> str:
    """A short readable name of a variant for file names: ``o_threshold=0.05,grid=64``."""
    return ",".join(f"{k.rpartition('.')[2]}={v}" for k, v in values.items())
