"""RunConfig and Plan (benchmark.run.config): typed, frozen, self-checking, round-trips through JSON."""

from __future__ import annotations

import dataclasses
import json

import pytest

from benchmark.run.config import ConfigError, RunConfig, grid_memory_bytes, machine_memory_bytes
from benchmark.run.plan import resolve


def test_defaults_round_trip_through_json():
    config = RunConfig()
    again = RunConfig.from_mapping(json.loads(json.dumps(config.to_dict())))
    assert again == config and again.seeds == (0,) and again.methods == ()


def test_config_is_frozen_and_typed():
    config = RunConfig(grid=64, seeds=[1, 2], methods=["sals"])
    assert config.seeds == (1, 2) and config.methods == ("sals",)
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.grid = 32
    for bad in ({"grid": "64"}, {"grid": 64.0}, {"seeds": ["0"]}, {"no_cache": "yes"}, {"method_params": {"sals": 1}}):
        with pytest.raises(ConfigError, match="must be"):
            RunConfig(**bad)


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
    assert plan.method_params["sals"]["normals"] is False and plan.method_params["sals"]["o_threshold"] == 0.1
    assert len(plan.shapes) == 2 and plan.budget is None and plan.eval_points == 1_000_000
    with pytest.raises(ConfigError, match=r"sals.o_threshold='2': expected float in \(0, 1\)"):
        resolve(RunConfig(mode="oracle", methods=("sals",), method_params={"sals": {"o_threshold": "2"}}))
    with pytest.raises(ConfigError, match="unknown budget 'huge'; known budgets: paper, quick, tiny, cpu, tiny-grid"):
        resolve(RunConfig(budget="huge"))
