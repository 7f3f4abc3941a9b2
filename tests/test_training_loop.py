"""The shared optimisation loop: steps, schedule, NaN check, checkpoints (hand-worked cases)."""

import numpy as np
import pytest
import torch

from methods.core.training_loop import FittingError, checked_loss, run_steps, window_means


def _scalar_model(start: float = 4.0) -> torch.nn.Module:
    model = torch.nn.Module()
    model.w = torch.nn.Parameter(torch.tensor(start, dtype=torch.float64))
    return model


def test_sgd_on_a_quadratic_follows_the_hand_worked_steps():
    """loss = w^2 with SGD at lr 0.25: w <- w - 0.25 * 2 w = w / 2, so w_t = 4 / 2^t and the loss
    of step t (before its update) is (4 / 2^t)^2; the schedule sets lr per step before the update."""
    model = _scalar_model()
    optimizer = torch.optim.SGD(model.parameters(), lr=1.0)
    result = run_steps(model, optimizer, 5, lambda step: model.w ** 2, log_every=2, where=str,
                       learning_rate=lambda group, step: 0.25)
    assert model.w.item() == 4.0 / 2 ** 5
    np.testing.assert_array_equal(result.losses, np.float32([(4.0 / 2 ** t) ** 2 for t in range(5)]))
    assert result.final_loss == pytest.approx(np.mean([(4.0 / 2 ** t) ** 2 for t in (3, 4)]))
    assert not model.training and result.seconds > 0


def test_non_finite_loss_names_its_step():
    model = _scalar_model()
    optimizer = torch.optim.SGD(model.parameters(), lr=0.1)
    with pytest.raises(FittingError, match="non-finite loss at step 3 of the test"):
        run_steps(model, optimizer, 8, lambda step: model.w * (float("nan") if step == 3 else 1.0), log_every=4,
                  where=lambda i: f"step {i} of the test")
    losses = torch.tensor([1.0, float("inf"), 2.0])
    with pytest.raises(FittingError, match="at 1$"):
        checked_loss(losses, 3, 3, str)


def test_checkpoints_pause_in_eval_mode_and_change_nothing():
    def run(checkpoints):
        model = _scalar_model()
        optimizer = torch.optim.Adam(model.parameters(), lr=0.1)
        seen = []
        result = run_steps(model, optimizer, 6, lambda step: (model.w - 1.0) ** 2, log_every=3, where=str,
                           checkpoints=checkpoints, on_checkpoint=lambda s, sec, m: seen.append((s, m.training)))
        return model.w.item(), result.losses, seen

    w0, l0, _ = run(())
    w1, l1, seen = run((2, 6))
    assert w0 == w1 and np.array_equal(l0, l1)
    assert seen == [(2, False), (6, False)]
    with pytest.raises(ValueError, match="checkpoints must be steps in"):
        run((7,))


def test_window_means_are_the_mean_of_each_window_and_of_the_shorter_last_one():
    assert window_means(np.array([1.0, 3.0, 2.0, 4.0, 10.0]), 2) == [2.0, 3.0, 10.0]
    assert window_means(np.array([5.0]), 100) == [5.0] and window_means(np.array([]), 3) == []
