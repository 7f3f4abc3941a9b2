"""When the report subcommand draws a run's shapes on a pool of processes, and when in the process itself."""

from __future__ import annotations

from runner.report_cli import POOL_MIN_SHAPES, pooled_when_many


def test_a_pool_draws_only_from_the_set_number_of_shapes():
    calls = []

    def pool_map(fn, items):
        calls.append(list(items))
        return [fn(x) for x in items]

    draw = pooled_when_many(pool_map, min_shapes=3)
    assert draw(lambda x: 2 * x, iter([1, 2])) == [2, 4] and calls == []
    assert draw(lambda x: 2 * x, [1, 2, 3]) == [2, 4, 6] and calls == [[1, 2, 3]]
    assert POOL_MIN_SHAPES > 4  # the default run's 4 built-in shapes are drawn in the process

