"""NDC's CNN_3d_rec7 (methods.extractors.rec7): the sparse inference equals the dense convolution
for one and for several input channels, and gives the same bits whatever order its products sum in."""

import numpy as np
import pytest
import torch

from methods.extractors.rec7 import RECEPTIVE_PADDING, Rec7Network, sparse_forward


@pytest.mark.parametrize("in_channels,out_channels", [(1, 3), (6, 4)])
def test_sparse_inference_equals_the_dense_convolution(in_channels, out_channels):
    torch.manual_seed(0)
    network = Rec7Network(channels=16, in_channels=in_channels, out_channels=out_channels).eval()
    rng = np.random.default_rng(0)
    shape = (12, 11, 13)
    grid = rng.uniform(-1.0, 2.0, size=(in_channels, *(s + 2 * RECEPTIVE_PADDING for s in shape))).astype(np.float32)
    with torch.no_grad():
        dense = network(torch.from_numpy(grid)[None])[0].permute(1, 2, 3, 0).numpy()
    assert dense.shape == shape + (out_channels,)
    positions = np.argwhere(rng.random(shape) < 0.3)
    sparse = sparse_forward(network, grid if in_channels > 1 else grid[0], positions)
    np.testing.assert_allclose(sparse, dense[tuple(positions.T)], rtol=1e-5, atol=1e-5)
    assert sparse_forward(network, grid, np.zeros((0, 3), dtype=int)).shape == (0, out_channels)


def test_outputs_are_the_same_bits_whatever_order_the_products_sum_in():
    """The network with its hidden channels renumbered is the same function, its matrix products
    summing in another order: float32 outputs change, the sparse inference (float64 rounded to
    float32) gives the same bits, so nothing it decides depends on the CPU's kernels."""
    torch.manual_seed(0)
    network = Rec7Network(channels=16).eval()
    renumbered = Rec7Network(channels=16).eval()
    perm = torch.from_numpy(np.random.default_rng(1).permutation(16))
    state = {}
    for name, value in network.state_dict().items():
        if value.shape[0] == 16:
            value = value[perm]
        if name.endswith("weight") and value.shape[1] == 16:
            value = value[:, perm]
        state[name] = value
    renumbered.load_state_dict(state)
    grid = np.random.default_rng(0).uniform(0.0, 2.0, size=(18, 17, 19)).astype(np.float32)
    with torch.no_grad():
        dense = network(torch.from_numpy(grid)[None, None])
        assert not torch.equal(dense, renumbered(torch.from_numpy(grid)[None, None]))
    positions = np.argwhere(np.ones((12, 11, 13), dtype=bool))
    np.testing.assert_allclose(sparse_forward(renumbered, grid, positions),
                               dense[0].permute(1, 2, 3, 0).reshape(-1, 3).numpy(), rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(sparse_forward(renumbered, grid, positions), sparse_forward(network, grid, positions))


def test_block_by_block_gives_the_whole_grids_bits():
    torch.manual_seed(0)
    network = Rec7Network(channels=16, in_channels=2, out_channels=4).eval()
    rng = np.random.default_rng(0)
    shape = (17, 11, 13)
    grid = rng.uniform(-1.0, 2.0, size=(2, *(s + 2 * RECEPTIVE_PADDING for s in shape))).astype(np.float32)
    positions = np.argwhere(rng.random(shape) < 0.3)
    whole = sparse_forward(network, grid, positions, block=10**6)
    np.testing.assert_array_equal(sparse_forward(network, grid, positions, block=5), whole)
