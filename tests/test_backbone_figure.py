"""scripts/backbone_figure.py: each row's mean over the parts every step count has, at the mean
seconds of the fit it extracts, beside the grid backbone's 128^3 row of the same parts."""

import pandas as pd
import pytest

from tests.scripts import load_script


def _jobs(rows):
    return pd.DataFrame(rows, columns=["shape", "method", "status", "mode", "steps", "grid", "fit_s", "cd", "ecd", "ef1"])


@pytest.fixture
def script(tmp_path):
    module = load_script("backbone_figure")
    mlp = []
    for steps, seconds in ((4000, 100.0), (8000, 200.0)):
        for shape, ef1 in (("a", 0.4), ("b", 0.6)):
            mlp += [(shape, "sals", "ok", "neural", steps, 128, seconds, 0.002, 0.03, ef1 + steps / 1e5),
                    (shape, "sals-ndc", "ok", "neural", steps, 128, 0.0, 0.002, 0.02, 0.9),
                    (shape, "sdf", "ok", "neural", steps, 128, seconds / 2, 0.002, 0.05, 0.3),
                    (shape, "sdf-ndc", "ok", "neural", steps, 128, 0.0, 0.002, 0.01, 0.95)]
    mlp.append(("c", "sals", "ok", "neural", 4000, 128, 90.0, 0.002, 0.03, 0.0))  # c lacks 8,000 steps
    grid = [(shape, m, "ok", "neural", None, n, 40.0 if n == 64 and m in ("sals", "sdf") else None, 0.002, 0.02, 0.7)
            for shape in ("a", "b", "c") for m in ("sals", "sals-ndc", "sdf", "sdf-ndc") for n in (64, 128)]
    module.MLP_CSV, module.GRID_CSV = tmp_path / "mlp.csv", tmp_path / "grid.csv"
    _jobs(mlp).to_csv(module.MLP_CSV, index=False)
    _jobs(grid).to_csv(module.GRID_CSV, index=False)
    return module


def test_curves_are_over_the_parts_every_step_count_has_at_the_seconds_of_the_fit_extracted(script):
    points = script.curves().set_index(["method", "backbone", "steps"])
    assert (points["parts"] == 2).all()  # part c lacks a step count: left out everywhere
    assert points.loc[("sals", "MLP", 8000), "ef1"] == pytest.approx(0.58)
    assert points.loc[("sals-ndc", "MLP", 4000), "fit_seconds"] == 100.0  # the sals fit it extracts
    assert points.loc[("sdf-ndc", "MLP", 8000), "fit_seconds"] == 100.0
    assert points.loc[("sdf", "grid", 3000), "fit_seconds"] == 40.0  # the grid's fit, made by its 64^3 job
    assert points.loc[("sdf", "grid", 3000), "ef1"] == pytest.approx(0.7)


def test_the_figure_is_an_svg_with_both_backbones(script, tmp_path):
    out = tmp_path / "figure.svg"
    assert script.main(["--out", str(out)]) == 0
    text = out.read_text()
    assert text.startswith("<?xml") and "sals (MLP)" in text and "sdf-ndc (grid)" in text
