"""Learning-rate schedules (methods.core.schedules) at hand-worked steps."""

import math

import pytest

from methods.core.schedules import cosine_lr, warmup_cosine_lr, warmup_then_cosine


def test_cosine_schedule_endpoints_and_midpoint():
    assert cosine_lr(0, 100, 1e-3, 1e-5) == pytest.approx(1e-3)
    assert cosine_lr(50, 100, 1e-3, 1e-5) == pytest.approx(0.5 * (1e-3 + 1e-5))
    assert cosine_lr(100, 100, 1e-3, 1e-5) == pytest.approx(1e-5)


def test_warmup_ramps_linearly_then_follows_the_cosine():
    assert warmup_cosine_lr(0, 100, 1e-2, 1e-4, warmup_steps=10) == pytest.approx(1e-3)  # 1/10 of cosine(0)
    assert warmup_cosine_lr(4, 100, 1e-2, 1e-4, warmup_steps=10) == pytest.approx(0.5 * cosine_lr(4, 100, 1e-2, 1e-4))
    for step in (10, 50, 100):
        assert warmup_cosine_lr(step, 100, 1e-2, 1e-4, warmup_steps=10) == cosine_lr(step, 100, 1e-2, 1e-4)
    assert warmup_cosine_lr(0, 100, 1e-2, 1e-4) == cosine_lr(0, 100, 1e-2, 1e-4)  # no warm-up


def test_warmup_then_cosine_rises_from_zero_and_falls_to_zero():
    assert warmup_then_cosine(0, 100, 10) == 0.0 and warmup_then_cosine(5, 100, 10) == 0.5
    assert warmup_then_cosine(10, 100, 10) == 1.0 and warmup_then_cosine(100, 100, 10) == pytest.approx(0.0)
    assert warmup_then_cosine(55, 100, 10) == pytest.approx(0.5)  # half way through the cosine
    assert warmup_then_cosine(30, 100, 10) == pytest.approx(0.5 * (math.cos(20 / 90 * math.pi) + 1))
