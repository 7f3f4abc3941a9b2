"""UNDC (methods.extractors.undc, methods.training.undc): the exact labels of a cube contour it exactly, the
edge flags of the sparse path are the dense sigmoid on the masked edges, the augmentation moves labels with the grid, and the tiny
training budget runs, is deterministic and lowers both losses."""

import numpy as np
import pytest
import torch
import trimesh

from foundation.fields import ExactFields
from foundation.grid import index_to_world
from methods.extractors import undc
from methods.training import undc as undc_training

CUBE_HALF = 0.55  # side 1.1
CUBE_CENTRE = np.array([0.013, -0.021, 0.0071])  # off the grid planes


def _cube():
    box = trimesh.creation.box(extents=(2 * CUBE_HALF,) * 3)
    return np.asarray(box.vertices) + CUBE_CENTRE, np.asarray(box.faces, dtype=np.int64)


def _contour(flags, offsets):
    cells = undc.vertex_cells(flags)
    return undc.dual_contour_edges(flags, cells, offsets[cells[:, 0], cells[:, 1], cells[:, 2]])


def test_exact_labels_of_a_cube_contour_the_cube_with_its_corners_and_no_boundary():
    N = 32
    V, F = _cube()
    fields = ExactFields(V, F)
    labels = undc.ground_truth(fields, N)
    # the flags are the grid edges the exact segment field hits
    edges = fields.grid_edges(N)
    ijk = np.argwhere(labels.edge_flags)
    from foundation.grid import ijk_axis_to_edge_index
    assert np.array_equal(np.sort(ijk_axis_to_edge_index(N, ijk[:, :3], ijk[:, 3])), np.flatnonzero(edges.hit))
    assert not (labels.edge_flags & ~labels.edge_mask).any()  # a crossing edge is always inside the loss mask
    vertices, faces = _contour(labels.edge_flags, labels.cell_offsets)
    world = index_to_world(vertices, N)
    # every vertex on the cube's surface: its largest |coordinate - centre| is the half side
    assert np.abs(np.abs(world - CUBE_CENTRE).max(axis=1) - CUBE_HALF).max() < 1e-4
    corners = CUBE_CENTRE + CUBE_HALF * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    assert np.linalg.norm(world[:, None] - corners[None], axis=2).min(axis=0).max() < 1e-4  # sharp corners kept
    # 2 triangles per crossing edge (none on the grid's boundary here), every mesh edge in exactly 2 triangles
    assert len(faces) == 2 * int(labels.edge_flags.sum())
    pairs = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, uses = np.unique(pairs, axis=0, return_counts=True)
    assert set(uses.tolist()) == {2}
    assert len(np.unique(faces)) == len(vertices)


def test_qef_vertex_is_pulled_into_its_cell():
    """Two nearly parallel planes through one cell: their least-squares point lies far outside it; the
    regularised search (NDC's) returns a point inside the cell, nearer to both planes than the mass point."""
    N = 4
    # plane x = 0.30 through the cell's x edges at y = 0, plane x - 0.01 y = 0.31 through those at
    # y = 1: they meet at y = -1, a cell away
    start = np.array([[1, 1, 1], [1, 1, 2], [1, 2, 1], [1, 2, 2]])
    axis = np.zeros(4, dtype=np.int64)
    t = np.array([0.30, 0.30, 0.32, 0.32])
    normal = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, -0.01, 0.0], [1.0, -0.01, 0.0]])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    cells, offsets = undc.qef_cell_vertices(N, undc.EdgeHits(start, axis, t, normal))
    cell = np.flatnonzero((cells == [1, 1, 1]).all(axis=1))[0]
    points = (start - [1, 1, 1]).astype(float)
    points[:, 0] += t
    b = np.einsum("ij,ij->i", normal, points)
    least_squares = np.linalg.lstsq(normal, b, rcond=None)[0]
    assert not ((least_squares >= 0) & (least_squares <= 1)).all()  # the unregularised point leaves the cell
    x = offsets[cell].astype(float)
    assert ((x >= 0) & (x <= 1)).all()
    residual = lambda p: float(np.sum((normal @ p - b) ** 2))
    assert residual(x) < 0.5 * residual(points.mean(axis=0))


def test_the_predicted_flags_are_the_dense_sigmoid_on_the_masked_edges():
    torch.manual_seed(0)
    network = undc.UNDCNetwork(channels=16).eval()
    udf = np.random.default_rng(0).uniform(0.0, 3.0, size=(12, 11, 13)).astype(np.float32)
    with torch.no_grad():
        dense = network(torch.from_numpy(undc.network_input(udf))[None, None])[0].permute(1, 2, 3, 0).numpy()
    flags = undc.predict_edge_flags(network, udf)
    assert np.array_equal(flags, (torch.sigmoid(torch.from_numpy(dense)).numpy() > 0.5) & undc.edge_mask(udf))


def test_augmented_crops_move_the_labels_with_the_grid():
    """The dual contour of a whole-grid crop, permuted and reversed, mapped back, is the original."""
    V, F = _cube()
    item = undc_training.label_items([type("S", (), {"vertices": V * 0.5, "faces": F, "name": "cube"})()], (17,))[0]
    N = item.N
    original = np.unique(np.round(_contour(item.labels.edge_flags, item.labels.cell_offsets)[0], 5), axis=0)
    for permutation in undc_training.PERMUTATIONS:
        for reversal in ((0, 0, 0), (1, 0, 0), (0, 1, 1), (1, 1, 1)):
            crop = undc_training.augmented_crop(item, np.zeros(3, dtype=np.int64), N, permutation, reversal)
            vertices, _ = _contour(np.moveaxis(crop["flags"], 0, -1) > 0.5, np.moveaxis(crop["offsets"], 0, -1))
            back = np.empty_like(vertices)
            back[:, list(permutation)] = vertices
            back = np.where(np.array(reversal, dtype=bool), N - 1 - back, back)
            assert np.allclose(np.unique(np.round(back, 5), axis=0), original, atol=1e-4), (permutation, reversal)


@pytest.fixture(scope="module")
def tiny_shapes():
    return undc_training.undc_training_shapes("tiny")


def test_tiny_budget_is_deterministic_and_lowers_both_losses(tiny_shapes, tmp_path):
    first = undc_training.train(tiny_shapes, "tiny", seed=3)
    second = undc_training.train(tiny_shapes, "tiny", seed=3)
    for a, b in ((first.bool_network, second.bool_network), (first.float_network, second.float_network)):
        sa, sb = a.state_dict(), b.state_dict()
        assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert np.array_equal(first.bool_losses, second.bool_losses)
    for losses in (first.bool_losses, first.float_losses):
        assert np.isfinite(losses).all() and losses[-5:].mean() < losses[:5].mean(), losses
    # the weights file round-trips and refuses a damaged copy
    budget = undc_training.get_undc_budget("tiny")
    path = tmp_path / "undc.pt"
    undc.save_weights(path, first.bool_network, first.float_network, first.info(budget, 3))
    bool_network, float_network, info = undc.load_weights(path)
    assert info["budget"]["name"] == "tiny" and info["training_set"] == first.training_set
    assert all(torch.equal(v, bool_network.state_dict()[k]) for k, v in first.bool_network.state_dict().items())
    data = bytearray(path.read_bytes())
    data[-10] ^= 1
    path.write_bytes(bytes(data))
    with pytest.raises(undc.WeightsError, match="damaged"):
        undc.load_weights(path)


def test_a_weights_file_that_would_run_code_is_refused_unread(tmp_path):
    from tests.test_weights import crafted_weights

    from foundation.storage import write_checked

    path = tmp_path / "undc.pt"
    write_checked(path, crafted_weights(tmp_path / "ran"))  # whoever writes the file writes its checksum
    with pytest.raises(undc.WeightsError) as info:
        undc.load_weights(path)
    assert "refused unread" in str(info.value) and str(path) in str(info.value) and "\n" not in str(info.value)
    assert not (tmp_path / "ran").exists()
