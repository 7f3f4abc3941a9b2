"""NDC's ``CNN_3d_rec7``: the grid network of UNDC and of ``sals-ndc``, and its sparse inference.

Layers: conv 3x3x3 (C_in -> C), two conv 3x3x3 (C -> C), all unpadded, two conv 1x1x1 (C -> C),
each followed by leaky ReLU 0.01, and a conv 1x1x1 (C -> C_out) output. Output position p of a
(C_in, D + 6, H + 6, W + 6) input reads its input points p .. p + 6 per axis (the receptive field
of the three unpadded 3x3x3 convolutions: :data:`RECEPTIVE_PADDING` each side).

:func:`sparse_forward` evaluates the network only at given output positions (and at the positions
of the earlier layers their receptive fields need), in float64 rounded to float32 as NDC's network
is (:func:`methods.extractors.ndc.inference_state`): the same bits on every CPU.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from methods.extractors.ndc import (BLOCK, INFERENCE_DTYPE, KERNEL_OFFSETS, block_input, inference_state, leaky,
                                    pointwise_conv, position_blocks, receptive_positions, sparse_conv3)

#: Grid points of padding each side: the receptive field of the three unpadded 3x3x3 convolutions.
RECEPTIVE_PADDING = 3
LEAKY_SLOPE = 0.01
#: Channels of NDC's CNN_3d_rec7.
DEFAULT_CHANNELS = 64


class Rec7Network(nn.Module):
    """NDC's ``CNN_3d_rec7`` (module docstring) with ``in_channels`` input and ``out_channels``
    output channels and ``channels`` in between. Input (B, C_in, D, H, W); output (B, C_out, D - 6,
    H - 6, W - 6), raw (logits or values: the caller's)."""

    def __init__(self, channels: int = DEFAULT_CHANNELS, in_channels: int = 1, out_channels: int = 3):
        super().__init__()
        self.config = {"channels": int(channels)}
        if in_channels != 1 or out_channels != 3:  # UNDC's files hold only the channels
            self.config.update(in_channels=int(in_channels), out_channels=int(out_channels))
        c = int(channels)
        self.conv_0 = nn.Conv3d(int(in_channels), c, 3)
        self.conv_1 = nn.Conv3d(c, c, 3)
        self.conv_2 = nn.Conv3d(c, c, 3)
        self.conv_3 = nn.Conv3d(c, c, 1)
        self.conv_4 = nn.Conv3d(c, c, 1)
        self.conv_out = nn.Conv3d(c, int(out_channels), 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for layer in (self.conv_0, self.conv_1, self.conv_2, self.conv_3, self.conv_4):
            x = F.leaky_relu(layer(x), LEAKY_SLOPE)
        return self.conv_out(x)


def sparse_forward(network: Rec7Network, grid: np.ndarray, positions: np.ndarray, block: int = BLOCK) -> np.ndarray:
    """``network(grid)`` at output ``positions`` only, without the dense convolution.

    Parameters
    ----------
    network : a :class:`Rec7Network`.
    grid : (D + 6, H + 6, W + 6) (one input channel) or (C_in, D + 6, H + 6, W + 6) float input.
    positions : (M, 3) int output positions, each in [0, D) x [0, H) x [0, W).
    block : positions per axis evaluated at once (:func:`methods.extractors.ndc.position_blocks`: the
        memory follows a block; the values do not depend on it).

    Returns
    -------
    (M, C_out) float32 raw outputs, the values of the dense pass ``network(grid)[0, :, p]`` (to float
    rounding): each 3x3x3 layer is evaluated only where a later layer reads it (5^3 and 7^3
    neighbourhoods of ``positions``), in :data:`~methods.extractors.ndc.INFERENCE_DTYPE` and rounded
    to float32, as :func:`methods.extractors.ndc.ndc_vertex_offsets` does: the same bits on every CPU.
    """
    grid = np.asarray(grid)
    if grid.ndim == 3:
        grid = grid[None]
    positions = np.asarray(positions, dtype=np.int64).reshape(-1, 3)
    state = inference_state(network.state_dict())
    out = np.zeros((len(positions), state["conv_out.bias"].shape[0]), dtype=np.float32)
    for rows, origin in position_blocks(positions, block):
        out[rows] = _block_forward(state, block_input(grid, origin, block), positions[rows] - origin)
    return out


def _block_forward(state: dict, grid: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """:func:`sparse_forward` of ``positions`` on the input ``grid`` (C_in, ...) that holds their
    receptive fields."""
    shape = np.array(grid.shape[1:], dtype=np.int64) - 2 * RECEPTIVE_PADDING
    at_conv1, index_conv1 = receptive_positions(positions, tuple(int(s) for s in shape + 2))
    at_conv0, index_conv0 = receptive_positions(at_conv1, tuple(int(s) for s in shape + 4))
    with torch.no_grad():
        patches = at_conv0[:, None, :] + KERNEL_OFFSETS[None]  # (M0, 27, 3): kernel offset, then channel
        values = grid[:, patches[..., 0], patches[..., 1], patches[..., 2]]  # (C_in, M0, 27)
        x = torch.from_numpy(np.ascontiguousarray(values.transpose(1, 2, 0).reshape(len(at_conv0), -1),
                                                  dtype=np.float64)).to(INFERENCE_DTYPE)
        w0 = state["conv_0.weight"]
        x = leaky(torch.addmm(state["conv_0.bias"], x, w0.permute(2, 3, 4, 1, 0).reshape(-1, w0.shape[0])))
        x = sparse_conv3(state, "conv_1", x, index_conv0, at_conv1)
        x = sparse_conv3(state, "conv_2", x, index_conv1, positions)
        x = leaky(pointwise_conv(state, "conv_3", x))
        x = leaky(pointwise_conv(state, "conv_4", x))
        out = pointwise_conv(state, "conv_out", x).to(torch.float32)
    return out.numpy()
