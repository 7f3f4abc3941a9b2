"""runner/memory_need.py: a job's memory need from measured models, the guard that refuses a grid
that cannot fit and admits one that can, and the workers that fit at once."""

from __future__ import annotations

import pytest

from runner.memory_need import (MIB, MemoryModel, fit_models, lightest_refusal, read_models, refusal,
                                workers_that_fit, write_models)

GIB = 2**30


def _model(method="sals", mode="neural", base=500.0, per_point=60.0, task="encode") -> MemoryModel:
    return MemoryModel(task, method, mode, base, per_point, "64 128 256", 3, 0.0)


def test_a_model_is_fitted_to_the_largest_peak_at_each_grid():
    """Peaks of 200 MiB + 48 B x N^3 at three grids (a smaller peak of another shape at 128 does not
    count): the fit gives back 200 MiB and 48 B per point."""
    jobs = [{"task": "encode", "method": "sdf", "mode": "oracle", "grid": N, "peak_rss_mib": 200 + 48 * N**3 / MIB}
            for N in (64, 128, 256)]
    jobs.append({"task": "encode", "method": "sdf", "mode": "oracle", "grid": 128, "peak_rss_mib": 10.0})
    jobs.append({"task": "encode", "method": "bof", "mode": "oracle", "grid": 64, "peak_rss_mib": 300.0})  # one grid
    (model,) = fit_models(jobs, cpu="test CPU", commit="abc")
    assert (model.method, model.mode, model.grids, model.jobs) == ("sdf", "oracle", "64 128 256", 4)
    assert model.base_mib == pytest.approx(200, abs=0.1) and model.bytes_per_point == pytest.approx(48, abs=0.01)
    assert model.need_bytes(512) == pytest.approx(200 * MIB + 48 * 512**3, rel=1e-6)


def test_the_models_round_trip_through_their_file(tmp_path):
    path = tmp_path / "measured.csv"
    write_models([_model(), _model("sdf", "oracle", 300.0, 20.0)], path)
    read_models.cache_clear()
    models = read_models(path)
    assert models[("encode", "sdf", "oracle")] == _model("sdf", "oracle", 300.0, 20.0)


def test_a_grid_that_cannot_fit_is_refused_in_one_line_and_one_that_fits_is_admitted():
    models = {("encode", "sals", "neural"): _model(base=500.0, per_point=60.0)}
    memory = 23 * GIB
    assert refusal({("encode", "sals", "neural", 512)}, memory, 1, models) is None  # 0.5 + 7.5 GiB
    line = refusal({("encode", "sals", "neural", 768)}, memory, 1, models)  # 0.5 + 25.3 GiB
    assert line.startswith("--grid 768: sals (neural) needs ~25.8 GiB per job (measured on grids 64 128 256")
    largest = int(((memory - 500 * MIB) / 60.0) ** (1 / 3))
    assert line.endswith(f"more than this machine's 23.0 GiB; its largest grid here is {largest}") and "\n" not in line
    assert refusal({("encode", "sals", "neural", largest)}, memory, 1, models) is None
    assert refusal({("encode", "sals", "neural", largest + 1)}, memory, 1, models) is not None


def test_an_unmeasured_method_is_held_to_the_largest_measured_need_of_its_task_and_mode():
    models = {("encode", "sdf", "neural"): _model("sdf", per_point=20.0),
              ("encode", "sals", "neural"): _model("sals", per_point=60.0),
              ("encode", "sals", "oracle"): _model("sals", "oracle", per_point=500.0)}
    line = refusal({("encode", "my-plugin", "neural", 768)}, 23 * GIB, 1, models)
    assert "my-plugin (neural) needs ~25.8 GiB per job (not measured: held to sals's" in line
    assert refusal({("reconstruct", "poisson", "neural", 4096)}, 23 * GIB, 1, models) is None  # nothing measured


def test_workers_are_held_to_what_fits_at_once():
    models = {("encode", "sals", "neural"): _model(base=500.0, per_point=60.0)}  # 8 GiB at 512
    kinds = {("encode", "sals", "neural", 512), ("encode", "sals", "neural", 128)}
    assert workers_that_fit(kinds, 23 * GIB, 4, models) == 2 and workers_that_fit(kinds, 7 * GIB, 4, models) == 1
    line = refusal(kinds, 23 * GIB, 3, models)
    assert line.startswith("--grid 512: 3 workers of sals (neural) need ~24.0 GiB at once") and line.endswith(
        "use --workers 2")
    assert refusal(kinds, 23 * GIB, 2, models) is None


def test_a_grid_no_job_can_fit_is_refused_whatever_the_methods():
    models = {("encode", "sdf", "oracle"): _model("sdf", "oracle", 300.0, 20.0),
              ("encode", "sals", "neural"): _model(per_point=60.0)}
    assert lightest_refusal(1024, 23 * GIB, models) is None  # 20 B x 1024^3 = 20 GiB fits
    line = lightest_refusal(2048, 23 * GIB, models)
    assert line.startswith("--grid 2048: even the lightest measured job (sdf, oracle) needs ~160.3 GiB")
    assert lightest_refusal(10**4000, 23 * GIB, models).startswith("--grid 1")  # any size: one line, no overflow


def test_a_run_is_refused_or_admitted_by_the_shipped_measurements(monkeypatch):
    """The plan's guard on this project's own table, on a machine of 23.4 GiB: NDC's dense CNN at
    512^3 is refused before any work in one line; sals and sdf at 512^3 are admitted, and the
    automatic executor is held to the workers that fit."""
    import runner.config as config_module
    from runner.config import ConfigError, RunConfig
    from runner.plan import resolve

    monkeypatch.setattr(config_module, "machine_memory_bytes", lambda: int(23.4 * GIB))
    base = dict(dataset="builtin", limit=1, grid=512)
    with pytest.raises(ConfigError, match=r"^--grid 512: sdf-ndc \(oracle\) needs ~23\.7 GiB per job \(measured on grids"):
        resolve(RunConfig(mode="oracle", methods=("sdf", "sdf-ndc"), **base))
    plan = resolve(RunConfig(methods=("sals", "sdf"), **base))
    assert plan.workers_that_fit(8) == 2  # ~8.9 GiB a sals job: two at once
    with pytest.raises(ConfigError, match=r"3 workers of sals \(neural\) need .* use --workers 2$"):
        resolve(RunConfig(methods=("sals",), executor="process", workers=3, **base))
