"""Budgets: how much compute a method's fit or training gets, as named, typed, frozen records.

Each family of methods reads one kind of record (a frozen dataclass whose fields are declared with
:func:`foundation.params.setting`): the encode methods' per-shape fit (:class:`methods.core.fitting.Budget`),
the K-NN networks' training, POCO's, GIFS's, GeoUDF's and CAP-UDF's own. A family registers its named
records (``paper``, ``cpu``, ``tiny``, ...) with :func:`register_budget_family`; a method names its
family (``Method.budget_family``). ``--budget NAME`` picks the record of that name in the family of
every method of a run; ``--budget-param FIELD=VALUE`` and ``--sweep budget.FIELD=...`` change that
field in every family of the run that has it (the fields marked ``override=True``), and the run
refuses a field that no method of it reads. A method's fitted or trained network is keyed by the
values of its own record (:func:`budget_values`), so a change to one family's field never
invalidates another family's networks.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

from foundation.params import Param, params_of, with_overrides
from foundation.registry import Registry


@dataclass(frozen=True)
class BudgetFamily:
    """The named budgets of one family of methods: frozen records of one dataclass type (fields
    declared with :func:`foundation.params.setting`), e.g. the encode methods' per-shape fit or the
    K-NN networks' training. ``params``: the fields a run may change (``override=True``):
    ``--budget-param FIELD=VALUE`` and ``--sweep budget.FIELD=...`` set them in every family of the
    run that has them."""

    name: str
    budgets: Registry
    params: dict[str, Param]

    def get(self, budget, overrides: Mapping[str, Any] | None = None):
        """The record named ``budget`` (or the record itself) with ``overrides`` applied (typed,
        range-checked; a field the family lacks raises with the known ones)."""
        base = self.budgets.get(budget) if isinstance(budget, str) else budget
        return with_overrides(base, overrides, self.params, f"{self.name} budget")

    def names(self) -> list[str]:
        return self.budgets.names()


#: Budget families by name, each registered by the module that defines its record type (look one
#: up with :func:`methods.base.budget_family`, which imports every method module first).
BUDGET_FAMILIES: Registry[BudgetFamily] = Registry("budget family")


def register_budget_family(name: str, records: Iterable) -> BudgetFamily:
    """Register the family ``name`` of the frozen ``records`` (one dataclass type, each with a
    unique ``name``); returns it."""
    records = tuple(records)
    kinds = {type(r) for r in records}
    if len(kinds) != 1:
        raise TypeError(f"budget family '{name}' mixes record types {sorted(k.__name__ for k in kinds)}")
    budgets: Registry = Registry(f"{name} budget")
    for record in records:
        budgets.register(record.name, record)
    return BUDGET_FAMILIES.register(name, BudgetFamily(name, budgets, params_of(kinds.pop(), override=True)))


def budget_values(budget) -> dict[str, Any]:
    """Every value of a budget record but its name: what keys the networks fitted or trained
    under it (two records with the same values fit the same networks)."""
    values = dataclasses.asdict(budget)
    values.pop("name", None)
    return values
