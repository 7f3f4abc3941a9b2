"""Budgets as one concept (methods.core.budgets): a family of named, typed, frozen records per family
of methods; a run's --budget / --budget-param / --sweep budget.X reach exactly the methods that read
them, never silently nobody; and a network is keyed by the code and budget of its own family only."""

from dataclasses import dataclass

import pytest

from foundation.params import Param, ParamError, setting
from methods.base import METHODS
from methods.core.budgets import BUDGET_FAMILIES, budget_values, register_budget_family
from tasks.cache import code_modules, fit_code_modules
from runner.config import ConfigError, RunConfig
from runner.plan import resolve
from runner.plan import build_tasks
from tasks.cache import network_code_modules


@dataclass(frozen=True)
class Toy:
    name: str = setting(Param(kind=str, help="budget name"))
    steps: int = setting(Param(kind=int, help="steps", ge=1), override=True)
    width: int = setting(Param(8, "fixed width", ge=1))


@pytest.fixture
def toy_family():
    family = register_budget_family("test-toy", (Toy("small", steps=3), Toy("big", steps=30)))
    yield family
    BUDGET_FAMILIES.unregister("test-toy")


def test_a_family_types_its_overrides_and_refuses_what_it_has_not(toy_family):
    assert toy_family.names() == ["small", "big"] and set(toy_family.params) == {"steps"}
    assert toy_family.get("small", {"steps": "7"}) == Toy("small", steps=7)
    assert toy_family.get("big") is toy_family.budgets.get("big")
    with pytest.raises(ParamError, match="test-toy budget has no setting 'width' that a run may change; known: steps"):
        toy_family.get("small", {"width": 3})
    with pytest.raises(ValueError, match="unknown test-toy budget 'huge'; known test-toy budgets: small, big"):
        toy_family.get("huge")
    assert budget_values(Toy("small", steps=3)) == {"steps": 3, "width": 8}  # the name keys nothing


def test_a_family_holds_one_record_type():
    @dataclass(frozen=True)
    class Other:
        name: str = "b"

    with pytest.raises(TypeError, match="mixes record types"):
        register_budget_family("test-mixed", (Toy("a", steps=1), Other()))
    assert "test-mixed" not in BUDGET_FAMILIES


def reconstruct(methods, **config):
    return resolve(RunConfig(task="reconstruct", methods=tuple(methods), limit=1, **config))


def test_each_method_reads_the_budget_of_its_own_family():
    plan = reconstruct(["sals-knn", "poco", "gifs", "geoudf", "cap-udf", "poisson"], budget="paper")
    assert set(plan.budgets) == {"knn", "poco", "gifs", "geoudf", "cap-udf"}  # poisson trains nothing
    for family, budget in plan.budgets.items():
        assert budget is BUDGET_FAMILIES.get(family).budgets.get("paper")
    assert plan.budgets["cap-udf"].steps == 60_000  # --budget paper reaches cap-udf: the authors' base.conf


def test_a_budget_name_a_family_lacks_is_refused_naming_its_budgets():
    with pytest.raises(ConfigError, match="unknown cap-udf budget 'tiny-grid'; known cap-udf budgets: paper, cpu, tiny"):
        reconstruct(["cap-udf"], budget="tiny-grid")


@pytest.mark.parametrize("method, field", [("poco", "k"), ("gifs", "k"), ("geoudf", "encoder_width"),
                                           ("cap-udf", "num_samples")])
def test_an_override_that_no_method_of_the_run_reads_is_refused(method, field):
    with pytest.raises(ConfigError, match=rf"--budget-param {field}: no method of this run \({method}\) reads a "
                                          rf"budget setting '{field}'"):
        reconstruct([method], budget_params={field: 10})


@pytest.mark.parametrize("method, field, value", [("poco", "steps", 7), ("gifs", "pairs", 64),
                                                  ("geoudf", "rec_steps", 5), ("cap-udf", "steps", 6000)])
def test_an_override_reaches_each_method_that_reads_it(method, field, value):
    plan = reconstruct([method, "sals-knn"], budget_params={field: value})
    assert getattr(plan.budgets[method], field) == value
    knn_has_it = field in METHODS.get("sals-knn").budget_fields()
    assert (getattr(plan.budgets["knn"], field, None) == value) == knn_has_it


def test_a_budget_sweep_multiplies_only_the_jobs_of_methods_that_read_the_field():
    plan = reconstruct(["sals-knn", "poco", "poisson"], sweep={"budget.k": ["10", "20"]})
    jobs = build_tasks(plan)[1]
    per_method = {m: [j for j in jobs if j.method == m] for m in plan.methods}
    assert len(per_method["sals-knn"]) == 2 and {j.budget_params["k"] for j in per_method["sals-knn"]} == {10, 20}
    assert len(per_method["poco"]) == 1 and per_method["poco"][0].budget_params == {}  # poco has no k
    assert len(per_method["poisson"]) == 1 and per_method["poisson"][0].budget is None
    steps = reconstruct(["sals-knn", "poco"], sweep={"budget.steps": ["5", "6"]})
    assert {m: len([j for j in build_tasks(steps)[1] if j.method == m]) for m in steps.methods} == {
        "sals-knn": 2, "poco": 2}  # both read a field named steps: each trains at both values


def families_of_other_methods(method: str) -> set[str]:
    """The modules of every other registered method and of every point-cloud family's own folder
    but this method's (its base classes' modules excepted)."""
    cls = METHODS.get(method)
    own = {c.__module__ for c in cls.__mro__}
    others = {METHODS.get(m).__module__ for m in METHODS.names()} - own
    folder = cls.__module__.rpartition(".")[0]
    return others | {folder} if folder.count(".") == 2 else others  # methods.pointcloud.<family>


@pytest.mark.parametrize("method", ["sals-knn", "udf-knn", "occ-knn", "poco", "gifs", "geoudf"])
def test_a_trained_network_depends_on_no_code_of_another_family(method):
    closure = set(code_modules(*network_code_modules(METHODS.get(method)())))
    own_folder = METHODS.get(method).__module__.rpartition(".")[0]
    foreign = {m for m in closure if m.startswith("methods.fields") or m == "methods.core.fitting"
               or (m.startswith("methods.pointcloud.") and m.count(".") >= 3 and not m.startswith(own_folder))}
    assert not foreign and not (closure & (families_of_other_methods(method) - {own_folder})), sorted(foreign)


@pytest.mark.parametrize("method", ["bof", "sdf", "udf", "sals", "nglod", "uodf"])
def test_a_fit_depends_on_no_code_of_another_method(method):
    closure = set(code_modules(*fit_code_modules(METHODS.get(method)())))
    assert not closure & families_of_other_methods(method), sorted(closure & families_of_other_methods(method))
    assert not any(m.startswith("methods.pointcloud") for m in closure)
