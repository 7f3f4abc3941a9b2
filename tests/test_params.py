"""foundation.params: one parser for every setting (scalars, tuples, tables), and dataclasses declared by it."""

from __future__ import annotations

import dataclasses

import pytest

from foundation.params import REQUIRED, Param, ParamError, check_fields, params_of, setting, with_overrides


@pytest.mark.parametrize("param, value, expected", [
    (Param(True), "no", False), (Param(True), "YES", True), (Param(False), 1, True), (Param(True), "off", False),
    (Param(3), "4", 4), (Param(3), 4.0, 4), (Param(3), " 12 ", 12),
    (Param(0.5), "1e-3", 1e-3), (Param(0.5), 2, 2.0),
    (Param("fan4", choices=("fan4", "quad2")), "quad2", "quad2"),
    (Param((), item=int), ["1", 2], (1, 2)), (Param((), item=str), "a", ("a",)),
    (Param((), item=float), (0.25, "1"), (0.25, 1.0)),
    (Param(None, kind=int), None, None), (Param("cpu", optional=True), None, None),
    (Param({}, kind=dict, item=dict), {"sals": {"normals": "no"}}, {"sals": {"normals": "no"}}),
    (Param({}, kind=dict, item=tuple), {"grid": [32, 64]}, {"grid": (32, 64)}),
])
def test_values_parse_to_the_settings_type(param, value, expected):
    out = param.parse(value, "x")
    assert out == expected and type(out) is type(expected)


@pytest.mark.parametrize("param, value, message", [
    (Param(True), "False!", "x='False!': expected bool"),
    (Param(True), 2, "x=2: expected bool"),
    (Param(3), "4.5", "x='4.5': expected int"),
    (Param(3), True, "x=True: expected int"),
    (Param(0.5, gt=0, lt=1), "1", "x='1': expected float in (0, 1)"),
    (Param(0.5), "nan", "x='nan': expected float"),
    (Param(8, ge=8), 4, "x=4: expected int in [8, inf)"),
    (Param("fan4", choices=("fan4", "quad2")), "tri", "x='tri': expected str, one of 'fan4', 'quad2'"),
    (Param("a"), 3, "x=3: expected str"),
    (Param(0), None, "x=None: expected int"),
    (Param((), item=int, ge=0, le=2**63 - 1), [1, -1], "x=-1: expected tuple of int in [0, 2^63-1]"),
    (Param({}, kind=dict), {"a": [1]}, "x={'a': [1]}: expected table"),
    (Param({}, kind=dict, item=dict), {"a": 1}, "x={'a': 1}: expected table"),
])
def test_bad_values_are_one_line_naming_the_setting_and_its_type(param, value, message):
    with pytest.raises(ParamError) as err:
        param.parse(value, "x")
    assert str(err.value) == message


def test_a_setting_without_a_default_states_its_type():
    with pytest.raises(TypeError, match="needs kind="):
        Param(None)
    with pytest.raises(TypeError, match="needs item="):
        Param((), kind=tuple)
    assert Param(kind=int).default is REQUIRED
    assert Param((0,), item=int, ge=0).scalar() == Param(REQUIRED, kind=int, ge=0)
    assert Param("cpu", optional=True).scalar().nullable is False


@dataclasses.dataclass(frozen=True)
class Schedule:
    name: str = setting(Param(kind=str))
    steps: int = setting(Param(kind=int, ge=1), override=True)
    lr: float = setting(Param(1e-3, gt=0), override=True)
    levels: tuple[int, ...] = setting(Param((16, 32), item=int, ge=2))

    def __post_init__(self):
        check_fields(self, f"schedule '{self.name}'")


def test_a_dataclass_declared_by_params_types_its_fields_when_built():
    s = Schedule("a", steps="10", levels=[8])
    assert (s.steps, s.lr, s.levels) == (10, 1e-3, (8,))
    with pytest.raises(ParamError, match=r"schedule 'a': steps=0: expected int in \[1, inf\)"):
        Schedule("a", steps=0)
    assert list(params_of(Schedule)) == ["name", "steps", "lr", "levels"]
    assert list(params_of(Schedule, override=True)) == ["steps", "lr"]


def test_overrides_are_typed_and_unknown_names_list_the_known_ones():
    base = Schedule("a", steps=10)
    allowed = params_of(Schedule, override=True)
    assert with_overrides(base, {"lr": "0.5", "steps": 3}, allowed, "budget") == Schedule("a", steps=3, lr=0.5)
    assert with_overrides(base, {}, allowed, "budget") is base
    with pytest.raises(ParamError, match="budget has no setting 'levels' that a run may change; known: lr, steps"):
        with_overrides(base, {"levels": (4,)}, allowed, "budget")
    with pytest.raises(ParamError, match=r"budget.lr='-1': expected float in \(0, inf\)"):
        with_overrides(base, {"lr": "-1"}, allowed, "budget")
