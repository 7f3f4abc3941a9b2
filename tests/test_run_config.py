"""RunConfig and Plan (runner.config): typed, frozen, self-checking, round-trips through JSON."""

from __future__ import annotations

import dataclasses
import json

import pytest

from runner.config import ConfigError, RunConfig, grid_memory_bytes, machine_memory_bytes
from runner.plan import resolve


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


def test_grid_bound_comes_from_the_machine_memory():
    memory = machine_memory_bytes()
    assert memory is not None and grid_memory_bytes(128) < memory
    too_big = int((memory / 240) ** (1 / 3)) + 1
    with pytest.raises(ConfigError, match=r"GiB of grid buffers per job, more than this machine's"):
        RunConfig(grid=too_big)


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
    with pytest.raises(ConfigError, match="unknown encode budget 'huge'; known encode budgets: paper, quick, tiny, cpu, cpu-mlp, tiny-grid"):
        resolve(RunConfig(budget="huge"))


def test_a_settings_file_with_a_budget_in_oracle_mode_is_refused():
    with pytest.raises(ConfigError, match="run.toml: budget needs mode neural"):
        RunConfig.from_mapping({"mode": "oracle", "budget": "paper"}, where="run.toml")
    assert RunConfig.from_mapping({"mode": "oracle", "budget": None}).budget is None  # a saved oracle run
