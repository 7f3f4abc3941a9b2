"""Learning-rate schedules of the project's optimisations, as functions of the 0-based step.

* :func:`warmup_cosine_lr`: the per-shape fits (:mod:`methods.core.fitting`): a cosine from ``lr`` to
  ``lr_final`` over all the steps, scaled by a linear ramp during the warm-up.
* :func:`warmup_then_cosine`: the schedule of NeuS-style optimisations (CAP-UDF's fit, DCUDF's
  refinement) as a factor of the peak rate: a linear ramp from 0, then a cosine down to 0.
"""

from __future__ import annotations

import math


def cosine_lr(step: int, steps: int, lr: float, lr_final: float) -> float:
    """``lr_final + (lr - lr_final) (1 + cos(pi step / steps)) / 2``."""
    return lr_final + 0.5 * (lr - lr_final) * (1.0 + math.cos(math.pi * step / max(steps, 1)))


def warmup_cosine_lr(step: int, steps: int, lr: float, lr_final: float, warmup_steps: int = 0) -> float:
    """The lr of ``step``: :func:`cosine_lr`, scaled by ``(step + 1) / warmup_steps`` for
    ``step < warmup_steps`` (a linear warm-up; none when 0)."""
    scale = (step + 1) / warmup_steps if step < warmup_steps else 1.0
    return scale * cosine_lr(step, steps, lr, lr_final)


def warmup_then_cosine(step: int, steps: int, warm_up: int) -> float:
    """The factor of the peak rate at ``step``: ``step / warm_up`` during the first ``warm_up``
    steps, then ``(1 + cos(pi (step - warm_up) / (steps - warm_up))) / 2``, from 1 down to 0."""
    if step < warm_up:
        return step / warm_up
    return 0.5 * (math.cos((step - warm_up) / max(steps - warm_up, 1) * math.pi) + 1.0)
