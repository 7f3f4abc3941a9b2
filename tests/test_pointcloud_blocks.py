"""methods/pointcloud/blocks.py: one global grid, blocks that own disjoint parts of it."""

import numpy as np
import pytest
import torch

from foundation.grid import LOWER, edge_index_to_ijk_axis, num_edges, spacing
from foundation.surface import sample_surface
from datasets.rooms import room_shape
from methods.base import get_method
from methods.pointcloud.blocks import (
    Block,
    HaloTooSmall,
    band_edges_in_block,
    block_edges,
    blocks,
    clip_to_box,
    crop,
    density_scale,
    halo_is_enough,
    mean_neighbour_distance,
    occupied_blocks,
    owned_box,
    reconstruct_by_edges,
    reconstruct_by_windows,
)
from methods.pointcloud.knn.network import make_knn_network
from methods.pointcloud.knn.training import KNN_BUDGETS
from methods.pointcloud.neighbourhoods import band_edges

TINY = KNN_BUDGETS.get("tiny")


def test_blocks_partition_the_grid_points():
    N, size = 10, 4
    owner = np.zeros((N, N, N), dtype=int)
    for b in blocks(N, size):
        owner[b.lo[0]:b.hi[0], b.lo[1]:b.hi[1], b.lo[2]:b.hi[2]] += 1
    assert len(blocks(N, size)) == 27 and (owner == 1).all()
    assert blocks(N, size)[-1] == Block(N, (8, 8, 8), (10, 10, 10))


def test_owned_box_and_crop():
    b = Block(9, (4, 0, 0), (8, 4, 9))
    lo, hi = owned_box(b)
    h = spacing(9)  # 0.25
    np.testing.assert_allclose(lo, [LOWER + 4 * h, -1, -1])
    np.testing.assert_allclose(hi, [LOWER + 8 * h, LOWER + 4 * h, 1.0])  # z: the grid's last point
    points = np.array([[0.0, -1.0, 0.0], [-0.05, 0.0, 0.0], [0.5, 0.1, 0.0], [0.5, 0.2, 0.0]])
    np.testing.assert_array_equal(crop(points, (lo, hi), 0.1), [0, 1, 2])


def test_the_blocks_band_edges_are_the_whole_grids_band_split_without_overlap():
    rng = np.random.default_rng(3)
    cloud = rng.uniform(-0.9, 0.9, (400, 3))
    N, radius = 17, 1.5 * spacing(17)
    parts = [band_edges_in_block(cloud[crop(cloud, owned_box(b), radius + 1e-9)], b, radius) for b in blocks(N, 5)]
    merged = np.concatenate(parts)
    np.testing.assert_array_equal(np.sort(merged), band_edges(cloud, N, radius))
    assert len(np.unique(merged)) == len(merged)
    for b, ids in zip(blocks(N, 5), parts):  # each block's edges start at its own points
        ijk, _ = edge_index_to_ijk_axis(N, ids)
        assert ((ijk >= b.lo) & (ijk < b.hi)).all()


def test_every_edge_belongs_to_exactly_one_block():
    N = 7
    cloud = np.stack(np.meshgrid(*[np.linspace(-1, 1, 25)] * 3, indexing="ij"), -1).reshape(-1, 3)
    ids = np.concatenate([band_edges_in_block(cloud, b, 1.0) for b in blocks(N, 3)])
    np.testing.assert_array_equal(np.sort(ids), np.arange(num_edges(N)))


def test_halo_is_enough_names_the_halo_a_k_nearest_query_needs():
    # points on the x axis at 0, 1, ..., 9; the crop [2, 6] (box [3, 5] grown by 1)
    line = np.stack([np.arange(10.0), np.zeros(10), np.zeros(10)], axis=1)
    box = (np.array([3.0, -1, -1]), np.array([5.0, 1, 1]))
    inside = line[crop(line, box, 1.0)]
    np.testing.assert_array_equal(inside[:, 0], [2, 3, 4, 5, 6])
    query = np.array([[4.0, 0, 0]])
    assert halo_is_enough(inside, query, 3, box, 1.0) is None  # 3, 4, 5: 1 from the query < 2 to the boundary
    needed = halo_is_enough(inside, np.array([[3.0, 0, 0]]), 3, box, 1.0)  # 2, 3, 4: 1 away; the boundary at 1
    assert needed is not None and needed > 1.0
    assert halo_is_enough(line[crop(line, box, needed)], np.array([[3.0, 0, 0]]), 3, box, needed) is None


@pytest.fixture(scope="module")
def room_cloud():
    shape = room_shape(0)
    points, _ = sample_surface(shape.vertices, shape.faces, 6000, np.random.default_rng(0))
    return shape, points


def _segment_network():
    """A K-NN segment network with seeded random weights whose o varies across edges (the output
    layer not scaled down, its bias set so o > 0.5 on part of the band): block-wise equality is a property of the procedure,
    not of the weights."""
    torch.manual_seed(0)
    net = make_knn_network("segment", out_dim=2, **TINY.network_config())
    last = net.head.mlp[-1]
    torch.nn.init.normal_(last.weight, std=100.0)
    with torch.no_grad():
        last.bias.copy_(torch.tensor([2.6, 6.2]))  # o about 0.5 on a third of the band, s about 0.5
    net.eval().knn_k = TINY.k
    return net


@pytest.mark.usefixtures("torch_threads")
def test_sals_knn_block_wise_equals_whole_cell_for_cell(room_cloud):
    _, points = room_cloud
    method = get_method("sals-knn", o_threshold=0.5)
    net = _segment_network()
    N = 32
    whole = method.reconstruct(points, N, model=net)
    by_blocks = reconstruct_by_edges(method, points, N, 11, net)
    assert by_blocks.info["blocks"] == 27 and by_blocks.info["halo_retries"] > 0  # the default halo grows
    assert by_blocks.info["intersected_edges"] == whole.info["intersected_edges"] > 100
    assert by_blocks.info["queried_edges"] == whole.info["queried_edges"]
    np.testing.assert_array_equal(by_blocks.faces, whole.faces)
    np.testing.assert_allclose(by_blocks.vertices, whole.vertices, rtol=0, atol=1e-6)
    assert by_blocks.info["block_points_max"] < len(points)


@pytest.mark.usefixtures("torch_threads")
def test_a_block_with_a_short_halo_reports_the_halo_it_needs(room_cloud):
    _, points = room_cloud
    method = get_method("sals-knn", o_threshold=0.5)
    net = _segment_network()
    b = Block(40, (12, 12, 0), (24, 24, 12))
    radius = method.params["band"] * spacing(40)
    with pytest.raises(HaloTooSmall, match="halo must be at least"):
        block_edges(method, points[crop(points, owned_box(b), radius)], b, radius, net)
    with pytest.raises(HaloTooSmall):  # below the band radius, before any query
        block_edges(method, points, b, 0.5 * radius, net)


def test_input_scale_scales_what_the_network_sees(room_cloud):
    """Scaling segments and points alike leaves the K nearest unchanged; the network sees the
    scaled coordinates (its first layer is not scale invariant)."""
    _, points = room_cloud
    method = get_method("sals-knn", o_threshold=0.5)
    net = _segment_network()
    ids = band_edges(points, 24, 4 * spacing(24))[::50]
    a = method.edge_field(points, 24, ids, net, "cpu")
    b = method.edge_field(points, 24, ids, net, "cpu", input_scale=2.0)
    assert not np.array_equal(a[0], b[0]) or not np.allclose(a[1], b[1])


def test_clip_to_box_keeps_the_faces_whose_centroid_is_inside():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], dtype=float)
    F = np.array([[0, 1, 2], [1, 3, 4]])  # centroids (1/3, 1/3, 0) and (5/3, 1/3, 0)
    kept = clip_to_box(V, F, np.array([0.0, 0, -1]), np.array([1.0, 1, 1]))
    np.testing.assert_array_equal(kept, [[0, 1, 2]])


@pytest.mark.slow
def test_windows_tile_the_scene_and_poisson_by_windows_stays_close_to_global(room_cloud):
    from foundation.metrics import evaluate

    shape, points = room_cloud
    poisson = get_method("poisson")
    N = 32
    whole = poisson.reconstruct(points, N)
    tiled = reconstruct_by_windows(poisson, points, N, 16, 24)  # blocks of 16 points in windows of 24: 8
    assert tiled.info["blocks"] == 8
    cd_whole = evaluate(shape.vertices, shape.faces, whole.vertices, whole.faces, n_points=20_000)["cd"]
    cd_tiled = evaluate(shape.vertices, shape.faces, tiled.vertices, tiled.faces, n_points=20_000)["cd"]
    assert cd_tiled < 1.5 * cd_whole, (cd_tiled, cd_whole)


def test_density_scale_follows_the_mean_neighbour_distance():
    lattice = np.stack(np.meshgrid(np.arange(20.0), np.arange(20.0), [0.0], indexing="ij"), -1).reshape(-1, 3)
    assert mean_neighbour_distance(0.01 * lattice) == pytest.approx(0.01)
    n, scale = density_scale(0.01 * lattice, reference_distance=0.02, N=65)  # twice as dense: twice the grid
    assert (n, scale) == (129, 2.0)


def test_occupied_blocks_are_those_a_point_comes_near():
    N, size = 9, 4  # blocks along an axis: points 0-3, 4-7, 8 (h = 0.25: boxes [-1, 0], [0, 1], [1, 1])
    point = np.array([[-0.1, -0.9, -0.9]])  # x 0.1 below the first block's upper face
    assert [b.lo for b in occupied_blocks(point, N, size, 0.05)] == [(0, 0, 0)]
    assert [b.lo for b in occupied_blocks(point, N, size, 0.15)] == [(0, 0, 0), (4, 0, 0)]
    cloud = np.random.default_rng(0).uniform(-1, 1, (50, 3))
    for reach in (0.0, 0.3):
        found = {b.lo for b in occupied_blocks(cloud, N, size, reach)}
        expected = {b.lo for b in blocks(N, size) if len(crop(cloud, owned_box(b), reach))}
        assert found == expected
