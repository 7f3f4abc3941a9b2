"""RunConfig and Plan (runner.config): typed, frozen, self-checking, round-trips through JSON."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from runner.config import ConfigError, RunConfig, machine_memory_bytes
from runner.plan import resolve
from tests.loader_fuzz import FLOATS, loads_or_refuses, mutated


def test_defaults_round_trip_through_json():
    config = RunConfig()
    again = RunConfig.from_mapping(json.loads(json.dumps(config.to_dict())))
    assert again == config and again.seeds == (0,) and again.methods == ()


def test_config_is_frozen_and_typed():
    config = RunConfig(grid=64, seeds=[1, 2], methods=["sals"])
    assert config.seeds == (1, 2) and config.methods == ("sals",)
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.grid = 32



def test_config_values_parse_as_their_params_whatever_their_source():
    """Text (the command line) and typed values (a TOML file) give the same config; a value that is
    not of the setting's type or lies outside its range is refused, naming the setting."""
    assert RunConfig(grid="64", seeds=["1", 2], no_cache="yes", pc_noise="0") == RunConfig(
        grid=64, seeds=(1, 2), no_cache=True, pc_noise=0.0)
    assert RunConfig(grid=64.0).grid == 64 and isinstance(RunConfig(grid=64.0).grid, int)
    for bad, message in [({"grid": "64.5"}, "grid='64.5': expected int in [8, inf)"),
                         ({"grid": 4}, "grid=4: expected int in [8, inf)"),
                         ({"seeds": [-1]}, "seeds=-1: expected tuple of int in [0, 2^63-1]"),
                         ({"no_cache": "maybe"}, "no_cache='maybe': expected bool"),
                         ({"mode": "exact"}, "mode='exact': expected str, one of 'neural', 'oracle'"),
                         ({"method_params": {"sals": 1}}, "method_params={'sals': 1}: expected table"),
                         ({"checkpoints": [0.5, 1.5]}, "checkpoints=1.5: expected tuple of float in (0, 1]"),
                         ({"pc_noise": 1.0}, "pc_noise=1.0: expected float in [0, 1)")]:
        with pytest.raises(ConfigError) as err:
            RunConfig(**bad)
        assert str(err.value) == message


def test_oracle_mode_has_no_budget():
    assert RunConfig(mode="oracle", budget="paper").budget is None
    assert RunConfig(mode="neural", budget=None).budget == "cpu" == RunConfig().budget


def test_a_grid_no_measured_job_can_fit_is_refused_by_the_config():
    """The shipped measurements (runner/measured_memory.csv): a grid past the largest the lightest
    measured job fits in this machine's memory is refused in one line; that grid itself is a config."""
    from runner.memory_need import read_models

    memory = machine_memory_bytes()
    lightest = min(read_models().values(), key=lambda m: m.need_bytes(1024))
    largest = lightest.largest_grid(memory)
    assert RunConfig(grid=largest).grid == largest
    with pytest.raises(ConfigError, match=rf"^--grid {largest + 1}: even the lightest measured job .* its largest "
                                          rf"grid here is {largest}$"):
        RunConfig(grid=largest + 1)


def test_identity_diff_names_each_differing_setting():
    a, b = RunConfig(grid=64), RunConfig(grid=32, budget="tiny", executor="process", workers=2, seeds=(0, 1))
    assert a.identity_diff(b) == ["budget='cpu' there, 'tiny' now", "grid=64 there, 32 now"]  # not executor/workers/seeds
    assert a.merged_scope(b).seeds == (0, 1)


def test_resolve_types_method_params_and_lists_shapes():
    plan = resolve(RunConfig(mode="oracle", methods=("sals",), method_params={"sals": {"normals": "no"}}, limit=2))
    assert plan.method_params["sals"]["normals"] is False and plan.method_params["sals"]["o_threshold"] == 0.5
    assert len(plan.shapes) == 2 and plan.budgets == {} and plan.eval_points == 1_000_000
    with pytest.raises(ConfigError, match=r"sals.o_threshold='2': expected float in \(0, 1\)"):
        resolve(RunConfig(mode="oracle", methods=("sals",), method_params={"sals": {"o_threshold": "2"}}))
    with pytest.raises(ConfigError, match="unknown encode budget 'huge'; known encode budgets: paper, quick, tiny, cpu, cpu-mlp, mlp, tiny-grid"):
        resolve(RunConfig(budget="huge"))


def test_shapes_pick_rows_by_name_in_the_datasets_order_and_an_unknown_name_is_refused():
    every = resolve(RunConfig(mode="oracle", methods=("sals",))).shapes
    picked = resolve(RunConfig(mode="oracle", methods=("sals",), shapes=(every[2], every[0]))).shapes
    assert picked == (every[0], every[2])
    assert resolve(RunConfig(mode="oracle", methods=("sals",), shapes=(every[2], every[0]), limit=1)).shapes == (every[0],)
    with pytest.raises(ConfigError, match=rf"--shapes teapot: not a shape of dataset 'builtin' with these options "
                                          rf"\({len(every)} shapes, e.g. {every[0]}, "):
        resolve(RunConfig(mode="oracle", methods=("sals",), shapes=(every[0], "teapot")))
    assert RunConfig(shapes=(every[0],)).identity_diff(RunConfig()) == [f"shapes=['{every[0]}'] there, [] now"]


def test_a_settings_file_with_a_budget_in_oracle_mode_is_refused():
    with pytest.raises(ConfigError, match="run.toml: budget needs mode neural"):
        RunConfig.from_mapping({"mode": "oracle", "budget": "paper"}, where="run.toml")
    assert RunConfig.from_mapping({"mode": "oracle", "budget": None}).budget is None  # a saved oracle run


# -- property-based: any --config file gives a RunConfig or one ConfigError line (issue 41, item 2) ----
# tests/loader_fuzz.py: the contract each call is held to and the strategies; the example counts are
# the Hypothesis profile's (tests/conftest.py).

#: Any JSON value, nested a little; text without lone surrogates (a file holds UTF-8).
JSON_VALUES = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), FLOATS, st.text(st.characters(exclude_categories=["Cs"]),
                                                                       max_size=12)),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=8)
#: A few settings: known names (most often) or unknown ones, each with any value.
SETTINGS = st.dictionaries(st.one_of(st.sampled_from(RunConfig.field_names()), st.text(max_size=10)), JSON_VALUES,
                           max_size=4)


def _toml(value) -> str:
    """``value`` as a TOML value (None has no TOML form: the caller leaves its key out)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else "inf" if value > 0 else "-inf"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value if v is not None) + "]"
    return "{" + ", ".join(f"{json.dumps(k, ensure_ascii=False)} = {_toml(v)}" for k, v in value.items()
                           if v is not None) + "}"


def _settings_file(values: dict, form: str) -> tuple[str, bytes]:
    """(extension, bytes) of a settings file holding ``values``: JSON, a run's config.json, TOML at
    the top level or in a [run] table."""
    if form == "json":
        return ".json", json.dumps(values).encode()
    if form == "config.json":
        return ".json", json.dumps({"config": values, "resolved": {}, "environment": {}}).encode()
    lines = "".join(f"{json.dumps(k, ensure_ascii=False)} = {_toml(v)}\n" for k, v in values.items() if v is not None)
    return ".toml", (("[run]\n" if form == "toml [run]" else "") + lines).encode("utf-8")


def _config_or_one_line(folder, extension: str, data: bytes):
    path = folder / f"settings{extension}"
    path.write_bytes(data)
    config = loads_or_refuses(RunConfig.load, path, ConfigError, names_file=False)
    if config is not None:  # a valid config: typed, and the same again through its JSON form (NaN included)
        assert isinstance(config, RunConfig) and isinstance(config.grid, int) and isinstance(config.seeds, tuple)
        again = RunConfig.from_mapping(json.loads(json.dumps(config.to_dict())))
        assert json.dumps(again.to_dict()) == json.dumps(config.to_dict())
    return config


@pytest.fixture(scope="module")
def config_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("configs")


FORMS = ["json", "config.json", "toml", "toml [run]"]


@given(values=SETTINGS, form=st.sampled_from(FORMS))
def test_settings_of_any_type_give_a_config_or_one_config_error_line(config_dir, values, form):
    _config_or_one_line(config_dir, *_settings_file(values, form))


VALID_SETTINGS = {"mode": "oracle", "grid": 64, "seeds": [0, 1], "methods": ["sals", "sdf"],
                  "method_params": {"sals": {"o_threshold": 0.2}}, "sweep": {"grid": [32, 64]}, "eval_points": 5000}


@given(form=st.sampled_from(FORMS), data=st.data())
def test_a_damaged_settings_file_gives_a_config_or_one_config_error_line(config_dir, form, data):
    """A valid settings file truncated, with bytes flipped, inserted or deleted, numbers made huge,
    NaN or infinite, text in a wrong encoding."""
    extension, valid = _settings_file(VALID_SETTINGS, form)
    damaged = data.draw(mutated(valid, [(b"64", b"%d"), (b"5000", b"%d")], [b"0.2", b"64", b"1]"]))
    _config_or_one_line(config_dir, extension, damaged)


@given(extension=st.sampled_from([".json", ".toml", ".txt"]),
       data=st.one_of(st.binary(max_size=300), st.integers(1, 3000).map(lambda n: b"[" * n + b"]" * n),
                      st.integers(4000, 5000).map(lambda n: b'{"grid": ' + b"9" * n + b"}"),
                      st.integers(4000, 5000).map(lambda n: b"grid = " + b"9" * n + b"\n")))
def test_any_bytes_give_a_config_or_one_config_error_line(config_dir, extension, data):
    """Random bytes, nesting deeper than Python recurses, integers longer than it converts."""
    _config_or_one_line(config_dir, extension, data)
