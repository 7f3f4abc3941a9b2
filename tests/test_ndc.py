"""NDC (methods.extractors.ndc): the sparse network against a dense conv3d of the same layers, its output
against NDC's own inference code with the published weights, and the dual contouring on hand-worked
sign grids."""

import itertools
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
import trimesh

from methods.extractors import ndc

REFERENCE = Path(__file__).parent / "data" / "ndc_reference_box33.npz"


def _random_state(seed: int = 0) -> dict[str, torch.Tensor]:
    """A state dict of NDC's layout with random weights (no file needed)."""
    g = torch.Generator().manual_seed(seed)
    shapes = {"conv_0": (64, 1, 3, 3, 3), "conv_1": (64, 64, 3, 3, 3), "conv_2": (64, 64, 3, 3, 3),
              "conv_3": (64, 64, 1, 1, 1), "conv_4": (64, 64, 1, 1, 1), "conv_out_float": (3, 64, 1, 1, 1)}
    shapes.update({f"res_{i}.conv_{j}": (64, 64, 1, 1, 1) for i in range(1, 9) for j in (1, 2)})
    state = {}
    for name, shape in shapes.items():
        fan_in = int(np.prod(shape[1:]))
        state[f"{name}.weight"] = torch.randn(shape, generator=g) / np.sqrt(fan_in)
        state[f"{name}.bias"] = 0.1 * torch.randn(shape[0], generator=g)
    return state


def _dense_offsets(state, sdf_voxels):
    """NDC's network as NDC runs it: conv3d over the whole padded grid."""
    def conv(name, x):
        return F.conv3d(x, state[f"{name}.weight"], state[f"{name}.bias"])

    def res(name, x):
        return F.leaky_relu(conv(f"{name}.conv_2", F.leaky_relu(conv(f"{name}.conv_1", x), 0.01)) + x, 0.01)

    x = torch.from_numpy(ndc.network_input(sdf_voxels))[None, None]
    x = res("res_1", F.leaky_relu(conv("conv_0", x), 0.01))
    x = res("res_2", F.leaky_relu(conv("conv_1", x), 0.01))
    x = F.leaky_relu(conv("conv_2", x), 0.01)
    for i in range(3, 9):
        x = res(f"res_{i}", x)
    x = F.leaky_relu(conv("conv_4", F.leaky_relu(conv("conv_3", x), 0.01)), 0.01)
    return np.clip(conv("conv_out_float", x)[0].permute(1, 2, 3, 0).numpy(), 0, 1)


def _sphere_sdf_voxels(N=20, radius=6.3, centre=(9.4, 10.1, 9.8)):
    ijk = np.stack(np.meshgrid(*[np.arange(N)] * 3, indexing="ij"), -1)
    return (np.linalg.norm(ijk - np.array(centre), axis=-1) - radius).astype(np.float32)


def test_network_input_is_padded_with_the_corner_sign_and_clipped():
    sdf = _sphere_sdf_voxels()
    grid = ndc.network_input(sdf)
    assert grid.shape == (26, 26, 26) and grid.dtype == np.float32
    assert grid[0, 0, 0] == 2.0 and grid.min() == -2.0  # outside corner: +10 clipped to 2
    np.testing.assert_array_equal(grid[3:-3, 3:-3, 3:-3], np.clip(sdf, -2, 2))
    assert ndc.network_input(-sdf)[0, 0, 0] == -2.0  # inside corner: -10 clipped to -2


def test_sparse_network_equals_dense_conv3d_at_every_active_cell():
    state = _random_state()
    sdf = _sphere_sdf_voxels()
    cells = ndc.active_cells(sdf < 0)
    with torch.no_grad():
        dense = _dense_offsets(state, sdf)
    sparse = ndc.ndc_vertex_offsets(sdf, cells, state)
    np.testing.assert_allclose(sparse, dense[cells[:, 0], cells[:, 1], cells[:, 2]], atol=2e-5)
    assert len(ndc.ndc_vertex_offsets(sdf, np.zeros((0, 3), dtype=int), state)) == 0


def _renumbered_hidden_channels(state, seed=1):
    """The same network with its 64 hidden channels renumbered: the same function, but every
    matrix product sums its terms in another order (what another CPU's kernels do)."""
    perm = torch.from_numpy(np.random.default_rng(seed).permutation(64))
    out = {}
    for name, value in state.items():
        if value.shape[0] == 64:
            value = value[perm]
        if name.endswith("weight") and value.shape[1] == 64:
            value = value[:, perm]
        out[name] = value
    return out


def test_offsets_are_the_same_bits_whatever_order_the_products_sum_in(monkeypatch):
    """Renumbered hidden channels, other matrix shapes (row chunks of 7) and two threads change the
    order of every sum: the float32 network's outputs change with it, the offsets do not (float64
    inference rounded to float32), so no CPU's kernels move them."""
    state, sdf = _random_state(), _sphere_sdf_voxels()
    cells = ndc.active_cells(sdf < 0)
    offsets = ndc.ndc_vertex_offsets(sdf, cells, state)
    assert ((offsets > 0) & (offsets < 1)).mean() > 0.9  # not just the clip's bounds
    renumbered = _renumbered_hidden_channels(state)
    with torch.no_grad():
        assert not np.array_equal(_dense_offsets(state, sdf), _dense_offsets(renumbered, sdf))
    np.testing.assert_array_equal(ndc.ndc_vertex_offsets(sdf, cells, renumbered), offsets)
    monkeypatch.setattr(ndc, "_CHUNK", 7)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        np.testing.assert_array_equal(ndc.ndc_vertex_offsets(sdf, cells, state), offsets)
    finally:
        torch.set_num_threads(threads)


def test_active_cells_are_those_around_a_lone_inside_point_in_c_order():
    inside = np.zeros((5, 5, 5), dtype=bool)
    inside[2, 2, 2] = True
    cells = ndc.active_cells(inside)
    np.testing.assert_array_equal(cells, list(itertools.product((1, 2), repeat=3)))


def test_dual_contouring_of_a_lone_inside_point_is_a_closed_outward_unit_cube():
    """One inside point, vertices at the cell centres: its six grid edges each give a quad; the
    quads are the faces of the cube of side 1 around the point, closed and pointing outward."""
    inside = np.zeros((5, 5, 5), dtype=bool)
    inside[2, 2, 2] = True
    cells = ndc.active_cells(inside)
    V, Fc = ndc.dual_contour_signs(inside, np.full((8, 3), 0.5), cells)
    np.testing.assert_array_equal(V, cells + 0.5)
    assert Fc.shape == (12, 3)
    mesh = trimesh.Trimesh(V, Fc, process=False)
    assert mesh.is_watertight and mesh.volume == pytest.approx(1.0)
    # the complement (one outside point in an inside block) flips every face: the same cube, inward
    V2, F2 = ndc.dual_contour_signs(~inside, np.full((8, 3), 0.5), cells)
    assert trimesh.Trimesh(V2, F2, process=False).volume == pytest.approx(-1.0)


def test_same_vertices_and_triangles_as_ndc_own_inference_on_a_turned_box():
    """NDC's own code (tests/data/make_ndc_reference.py) and this module, the same published
    weights and the same SDF grid: the same vertices to float tolerance, the same triangles."""
    try:
        state = ndc.load_weights()
    except ndc.WeightsError as exc:
        pytest.skip(str(exc))
    reference = np.load(REFERENCE)
    sdf = reference["sdf_voxels"]
    cells = ndc.active_cells(sdf < 0)
    V, Fc = ndc.dual_contour_signs(sdf < 0, ndc.ndc_vertex_offsets(sdf, cells, state), cells)
    assert V.shape == reference["vertices"].shape
    np.testing.assert_allclose(V, reference["vertices"], atol=1e-4)  # grid units: 1e-4 of a cell
    np.testing.assert_array_equal(Fc, reference["triangles"])
    assert trimesh.Trimesh(V, Fc, process=False).volume > 0


def test_weights_other_than_the_published_file_are_refused_in_one_line(tmp_path, monkeypatch):
    monkeypatch.setenv(ndc.WEIGHTS_ENV, str(tmp_path / "absent.pth"))
    with pytest.raises(ndc.WeightsError, match="NDC weights not found at .*absent.pth"):
        ndc.load_weights()
    other = tmp_path / "other.pth"
    torch.save(_random_state(), other)
    monkeypatch.setenv(ndc.WEIGHTS_ENV, str(other))
    with pytest.raises(ndc.WeightsError, match="is not NDC's published SDF network"):
        ndc.load_weights()


def test_block_by_block_gives_the_whole_grids_bits():
    """Cells split into blocks of 4 (each block with the grid points its receptive field reads) get
    the offsets of one pass over the whole grid, bit for bit: the blocks bound the memory, not the
    values."""
    state, sdf = _random_state(), _sphere_sdf_voxels()
    cells = ndc.active_cells(sdf < 0)
    whole = ndc.ndc_vertex_offsets(sdf, cells, state, block=10**6)
    assert len(list(ndc.position_blocks(cells, 4))) > 20
    np.testing.assert_array_equal(ndc.ndc_vertex_offsets(sdf, cells, state, block=4), whole)
    rows = np.concatenate([r for r, _ in ndc.position_blocks(cells, 4)])
    np.testing.assert_array_equal(np.sort(rows), np.arange(len(cells)))  # every cell once
