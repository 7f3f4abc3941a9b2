"""The optimisation loop every learned method runs: per-shape fits and the K-NN training alike.

:func:`run_steps` owns what both share: the learning-rate schedule per parameter group, zeroing the
gradients, the backward pass and the optimizer step, the per-step loss kept on the device and checked
for NaN/inf once per window (:func:`checked_loss`), progress reports, pauses at checkpoints that are
not counted in the seconds, the denormal flush (:func:`methods.core.device.flush_denormals`: Softplus and
its gradients underflow to denormal floats, a slow path on x86 that changes no number) and the
wall-clock seconds between device synchronisations. What differs between the callers (how a batch
is drawn, the network's call, the loss) is the ``step_loss(step)`` function they pass.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch

from methods.core.device import flush_denormals, synchronize


class FittingError(RuntimeError):
    """A fit or training that cannot go on (non-finite loss, bad targets); the message is one line."""


def checked_loss(losses: torch.Tensor, end: int, every: int, where: Callable[[int], str]) -> float:
    """The loss of step ``end - 1`` after checking steps ``end - every .. end - 1`` of ``losses`` for
    NaN/inf (one device-to-host copy per window); the first non-finite one, step ``i``, raises
    ``FittingError(f"non-finite loss at {where(i)}")``."""
    start = max(0, end - every)
    window = losses[start:end].cpu().numpy()
    if not np.all(np.isfinite(window)):
        raise FittingError(f"non-finite loss at {where(start + int(np.flatnonzero(~np.isfinite(window))[0]))}")
    return float(window[-1])


def window_means(losses: np.ndarray, every: int) -> list[float]:
    """The mean loss of each window of ``every`` consecutive steps (the last window may be shorter):
    a fit's loss curve at the resolution its progress reports, small enough to keep with each job."""
    losses = np.asarray(losses, dtype=np.float64)
    starts = np.arange(0, len(losses), max(1, int(every)))
    return [float(v) for v in np.add.reduceat(losses, starts) / np.diff(np.append(starts, len(losses)))] \
        if len(losses) else []


@dataclass
class StepsResult:
    """Per-step losses (float32, one per step), wall seconds without the checkpoint pauses, and the
    final loss (mean of the last ``log_every`` steps)."""

    losses: np.ndarray
    seconds: float
    final_loss: float


def run_steps(model: torch.nn.Module, optimizer: torch.optim.Optimizer, steps: int,
              step_loss: Callable[[int], torch.Tensor], *, log_every: int, where: Callable[[int], str],
              learning_rate: Callable[[dict, int], float] | None = None,
              progress: Callable[..., None] | None = None, checkpoints: Sequence[int] = (),
              on_checkpoint: Callable[[int, float, torch.nn.Module], None] | None = None,
              device=None) -> StepsResult:
    """Run ``steps`` optimizer steps of ``model`` (in train mode; back in eval mode at the end).

    Parameters
    ----------
    step_loss : ``step_loss(step) -> loss`` for 0-based ``step``: draws the step's batch, runs the
        network and returns the scalar loss (after the gradients were zeroed, before backward).
    log_every : the losses are checked for NaN/inf and ``progress(step=..., loss=...)`` is called every
        so many steps and at the last one.
    where : ``where(i)`` names step ``i`` in the error of a non-finite loss.
    learning_rate : ``learning_rate(group, step)`` sets each parameter group's lr before each step
        (None: the optimizer's lr stays constant).
    checkpoints, on_checkpoint : after each 1-based step in ``checkpoints`` the loop pauses and calls
        ``on_checkpoint(step, seconds_so_far, model)`` with the model in eval mode; the pause is not
        counted in the seconds and changes nothing about the steps.
    device : where ``model`` lives (the timing synchronises it).
    """
    T, every = int(steps), max(1, int(log_every))
    pause_at = {int(c) for c in checkpoints}
    if pause_at and (min(pause_at) < 1 or max(pause_at) > T or on_checkpoint is None):
        raise ValueError(f"checkpoints must be steps in [1, {T}] with an on_checkpoint callback, got {sorted(pause_at)}")
    losses = torch.zeros(T, dtype=torch.float32, device=device)
    model.train()
    paused = 0.0
    synchronize(device)
    t0 = time.perf_counter()
    with flush_denormals():
        for step in range(T):
            if learning_rate is not None:
                for group in optimizer.param_groups:
                    group["lr"] = learning_rate(group, step)
            optimizer.zero_grad(set_to_none=True)
            loss = step_loss(step)
            loss.backward()
            optimizer.step()
            losses[step] = loss.detach()
            if (step + 1) % every == 0 or step + 1 == T:
                last = checked_loss(losses, step + 1, every, where)
                if progress is not None:
                    progress(step=step + 1, loss=last)
            if step + 1 in pause_at:
                synchronize(device)
                t_pause = time.perf_counter()
                model.eval()
                on_checkpoint(step + 1, t_pause - t0 - paused, model)
                model.train()
                paused += time.perf_counter() - t_pause
    synchronize(device)
    seconds = time.perf_counter() - t0 - paused
    model.eval()
    curve = losses.cpu().numpy()
    return StepsResult(losses=curve, seconds=seconds, final_loss=float(np.mean(curve[-every:])))
