"""The grid's flat edge numbering (foundation/grid.py): hand-worked ids, round trips, endpoint layout."""

import numpy as np
import pytest

from foundation.grid import (
    EdgeField,
    edge_axes,
    edge_endpoint_values,
    edge_endpoints,
    edge_index_to_ijk_axis,
    edge_offsets,
    edge_shape,
    grid_points,
    ijk_axis_to_edge_index,
    num_edges,
    spacing,
)


def test_hand_worked_ids_at_N3():
    """N = 3: 2*3*3 = 18 edges per axis. x-edges (2, 3, 3), y-edges (3, 2, 3), z-edges (3, 3, 2)."""
    N = 3
    assert num_edges(N) == 54 and edge_offsets(N).tolist() == [0, 18, 36, 54]
    ijk = np.array([[0, 0, 0], [0, 0, 1], [0, 1, 0], [1, 2, 2],   # x: id = (i 3 + j) 3 + k
                    [0, 0, 0], [0, 1, 2], [2, 1, 2],              # y: 18 + (i 2 + j) 3 + k
                    [0, 0, 1], [1, 0, 0], [2, 2, 1]])             # z: 36 + (i 3 + j) 2 + k
    axis = np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 2])
    ids = [0, 1, 3, 17, 18, 23, 35, 37, 42, 53]
    assert ijk_axis_to_edge_index(N, ijk, axis).tolist() == ids
    got_ijk, got_axis = edge_index_to_ijk_axis(N, np.array(ids))
    assert got_ijk.tolist() == ijk.tolist() and got_axis.tolist() == axis.tolist()


@pytest.mark.parametrize("N", [2, 5, 16])
def test_decoder_is_c_order_per_axis_block_and_encoder_inverts_it(N):
    ijk, axis = edge_index_to_ijk_axis(N)  # every edge, in flat order
    ref = np.concatenate([np.indices(edge_shape(N, a)).reshape(3, -1).T for a in range(3)])
    assert np.array_equal(ijk, ref) and np.array_equal(axis, edge_axes(N))
    assert np.array_equal(ijk_axis_to_edge_index(N, ijk, axis), np.arange(num_edges(N)))
    # one axis for all edges (as the rasteriser bins the hits of one axis)
    block = slice(edge_offsets(N)[1], edge_offsets(N)[2])
    assert np.array_equal(ijk_axis_to_edge_index(N, ijk[block], 1), np.arange(num_edges(N))[block])


def test_decoder_rejects_ids_outside_the_grid():
    with pytest.raises(ValueError, match=r"edge ids must lie in \[0, 54\) for N=3"):
        edge_index_to_ijk_axis(3, np.array([0, 54]))
    with pytest.raises(ValueError, match="edge ids must lie"):
        edge_index_to_ijk_axis(3, np.array([-1]))
    ijk, axis = edge_index_to_ijk_axis(3, np.zeros(0, dtype=np.int64))
    assert ijk.shape == (0, 3) and axis.shape == (0,)


def test_endpoints_and_endpoint_values_agree():
    N = 6
    h = spacing(N)
    u, v = edge_endpoints(N, dtype=np.float64)
    lower, upper = edge_endpoint_values(grid_points(N))
    assert np.array_equal(lower, u) and np.allclose(upper, v, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(v - u, axis=1), h)
    assert np.array_equal((v - u).argmax(axis=1), edge_axes(N))
    ids = np.array([7, 250, num_edges(N) - 1])
    su, sv = edge_endpoints(N, ids, dtype=np.float64)
    assert np.array_equal(su, u[ids]) and np.array_equal(sv, v[ids])
    with pytest.raises(ValueError, match=r"shape \(N, N, N, \.\.\.\)"):
        edge_endpoint_values(np.zeros((4, 4, 3)))


def test_edge_field_hit_points_and_shape_check():
    N = 4
    E = num_edges(N)
    hit = np.zeros(E, dtype=bool)
    s = np.zeros(E, dtype=np.float32)
    hit[[0, E - 1]] = True
    s[[0, E - 1]] = [1.0, 0.25]  # at u of the first edge, 3/4 of the way to v on the last
    field = EdgeField(N, hit, s, np.zeros((E, 3), dtype=np.float32))
    ids, p = field.hit_points()
    h = spacing(N)
    assert ids.tolist() == [0, E - 1]
    np.testing.assert_allclose(p, [[-1, -1, -1], [1, 1, 1 - 0.25 * h]], atol=1e-12)
    with pytest.raises(ValueError, match="EdgeField arrays must have shapes"):
        EdgeField(N, hit[:-1], s, np.zeros((E, 3), dtype=np.float32))
