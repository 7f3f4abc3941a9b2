"""The shared fitting loop: budgets, cosine schedule, determinism, NaN handling, weight files."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from methods.base import Method
from methods.fitting import BUDGETS, Budget, FittingError, cosine_lr, fit, get_budget, model_from_bytes, model_to_bytes
from methods.query import evaluate

TOY = Budget("toy", depth=3, width=32, iterations=60, batch_size=256, num_samples=2000, log_every=10)


class SphereSDF(Method):
    """A method defined here (not registered): signed distance to the sphere |x| = 0.5."""

    name = "toy-sdf"
    output_dim = 1

    def loss(self, prediction, targets, inputs=None, model=None):
        return (prediction[:, 0] - targets["sdf"]).abs().mean()


def _toy_data(M=2000, seed=0):
    x = np.random.default_rng(seed).uniform(-1, 1, (M, 3)).astype(np.float32)
    return SimpleNamespace(points=x), {"sdf": np.linalg.norm(x, axis=1) - 0.5}


@pytest.fixture(autouse=True)
def one_thread():
    """Fits in tests run on one torch thread (deterministic numbers, no contention on a busy CI box)."""
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


def test_budgets_are_data_and_paper_matches_spec():
    paper = BUDGETS["paper"]
    assert (paper.depth, paper.width, paper.beta) == (9, 512, 100.0)
    assert (paper.iterations, paper.batch_size, paper.num_samples) == (100_000, 10_000, 10_000_000)
    assert (paper.lr, paper.lr_final) == (1e-3, 1e-5)
    assert set(BUDGETS) == {"paper", "quick", "tiny"}
    assert get_budget("tiny") is BUDGETS["tiny"]
    with pytest.raises(ValueError, match="known budgets: paper, quick, tiny"):
        get_budget("huge")
    with pytest.raises(Exception):
        paper.depth = 3  # frozen


def test_cosine_schedule_endpoints_and_midpoint():
    assert cosine_lr(0, 100, 1e-3, 1e-5) == pytest.approx(1e-3)
    assert cosine_lr(50, 100, 1e-3, 1e-5) == pytest.approx(0.5 * (1e-3 + 1e-5))
    assert cosine_lr(100, 100, 1e-3, 1e-5) == pytest.approx(1e-5)


def test_same_seed_same_weights_and_loss_curve_and_it_learns():
    samples, targets = _toy_data()
    a = fit(SphereSDF(), samples, targets, TOY, seed=3, device="cpu")
    b = fit(SphereSDF(), samples, targets, TOY, seed=3, device="cpu")
    c = fit(SphereSDF(), samples, targets, TOY, seed=4, device="cpu")
    assert a.losses.shape == (TOY.iterations,) and a.iterations == TOY.iterations
    np.testing.assert_array_equal(a.losses, b.losses)
    for pa, pb in zip(a.model.parameters(), b.model.parameters()):
        assert torch.equal(pa, pb)
    assert not np.array_equal(a.losses, c.losses)
    # the mean |sdf| of the targets is ~0.26: 60 steps must get clearly below the first loss
    assert a.final_loss < 0.6 * a.losses[0]
    assert a.final_loss == pytest.approx(a.losses[-TOY.log_every:].mean())


def test_progress_is_called_every_log_every_steps():
    samples, targets = _toy_data()
    calls = []
    fit(SphereSDF(), samples, targets, TOY, seed=0, device="cpu", progress=lambda **kw: calls.append(kw))
    assert [c["step"] for c in calls] == list(range(10, 61, 10))


def test_nan_loss_and_bad_targets_raise_fitting_error():
    samples, targets = _toy_data()

    class Exploding(SphereSDF):
        def loss(self, prediction, targets, inputs=None, model=None):
            return prediction.sum() * float("nan")

    with pytest.raises(FittingError, match="non-finite loss at iteration 0"):
        fit(Exploding(), samples, targets, TOY, seed=0, device="cpu")
    bad = {"sdf": targets["sdf"].copy()}
    bad["sdf"][5] = np.nan
    with pytest.raises(FittingError, match="target 'sdf' contains NaN"):
        fit(SphereSDF(), samples, bad, TOY, seed=0, device="cpu")
    with pytest.raises(FittingError, match="rows"):
        fit(SphereSDF(), samples, {"sdf": targets["sdf"][:10]}, TOY, seed=0, device="cpu")


def test_model_bytes_round_trip():
    samples, targets = _toy_data()
    budget = replace(TOY, iterations=5)
    res = fit(SphereSDF(), samples, targets, budget, seed=0, device="cpu")
    data = model_to_bytes(res.model, budget, "toy-sdf", res.final_loss)
    model, loss = model_from_bytes(data, device="cpu", method_name="toy-sdf")
    assert loss == res.final_loss
    x = samples.points[:100]
    np.testing.assert_array_equal(evaluate(model, x), evaluate(res.model, x))
    with pytest.raises(ValueError, match="expected 'sdf'"):
        model_from_bytes(data, device="cpu", method_name="sdf")
