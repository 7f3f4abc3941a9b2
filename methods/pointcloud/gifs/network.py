"""The GIFS network (Ye, Chen, Wang & Wang, CVPR 2022), written here after the authors' code
(github.com/jianglongye/gifs, ``models/local_model.py``), not copied from it.

Input: the point cloud as a binary voxel grid (:func:`voxelize_cloud`): ``resolution`` grid points
per axis spanning [-1, 1]^3 (point ``[i, j, k]`` at ``-1 + 2 (i, j, k) / (resolution - 1)``), a
voxel is 1 where it is the nearest grid point of some input point (the authors'
``voxelized_pointcloud_sampling``).

Encoder (IF-Net, :class:`VoxelEncoder`): a 3x3x3 convolution 1 -> ``channels[0]`` at full
resolution (ReLU, then batch norm), then for every further width ``channels[l]`` a max-pool by 2
and two 3x3x3 convolutions (each followed by ReLU) with batch norm after the second. The features
are the input grid itself and every block's output: ``1 + channels[0] + ... + channels[-1]``
channels at resolutions ``resolution / 2^l``. The authors: resolution 256, channels
16, 32, 64, 128, 128, 128.

Point feature (:meth:`GIFSNetwork.point_features`): every feature grid sampled trilinearly at the
point (``grid_sample``, ``align_corners=True``: the grid's end points lie at -1 and 1, zero outside),
concatenated with the point's coordinates: ``feature_dim = 1 + sum(channels) + 3`` values.

Decoders (:class:`Decoder`, one for the UDF, one for the pair flag, same shape): ``feature_dim ->
2 hidden -> hidden``, then two residual layers ``hidden -> hidden`` (``x + relu(W x)``), then
``hidden -> 1``; ReLU after every layer, the output too (so both outputs are >= 0, as the
authors'). Initialisation: torch's default (the authors'), except the flag output's bias,
:data:`FLAG_BIAS_INIT`. A pair (u, v): the UDF decoder on each endpoint's feature, the flag decoder on their
element-wise maximum (symmetric in u and v): the flag is ~1 where the surface separates u from v.

Frames: points in the canonical frame [-1, 1]^3; the UDF in canonical units.
``make_gifs_network(**net.config)`` rebuilds a network of this module.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["FLAG_BIAS_INIT", "voxelize_cloud", "VoxelEncoder", "Decoder", "GIFSNetwork", "make_gifs_network"]

#: Initial bias of the flag decoder's output layer: the mean of the balanced labels, so the output
#: ReLU starts active for every pair (with torch's default bias, ~0, a step that pushes every
#: pre-activation below 0 leaves the flag head at 0 for good; docs/PROTOCOL.md, "gifs").
FLAG_BIAS_INIT = 0.5


def voxelize_cloud(points: np.ndarray, resolution: int) -> np.ndarray:
    """(resolution,)^3 float32 binary grid over [-1, 1]^3: 1 at the nearest grid point of every
    input point (coordinates outside [-1, 1] clamp to the border), ``'ij'`` indexing (x first).

    ``points``: (P, 3) canonical frame, P >= 1."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be a (P, 3) array, got shape {points.shape}")
    if len(points) == 0:
        raise ValueError("cannot voxelize a cloud with no points")
    R = int(resolution)
    ijk = np.clip(np.rint((points + 1.0) * 0.5 * (R - 1)), 0, R - 1).astype(np.int64)
    grid = np.zeros((R, R, R), dtype=np.float32)
    grid[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = 1.0
    return grid


class VoxelEncoder(nn.Module):
    """IF-Net encoder (module docstring): (B, R, R, R) voxels -> the list of feature grids
    ``[input (B, 1, R^3), (B, channels[0], R^3), (B, channels[1], (R/2)^3), ...]``."""

    def __init__(self, channels: Sequence[int]):
        super().__init__()
        channels = [int(c) for c in channels]
        self.conv_in = nn.Conv3d(1, channels[0], 3, padding=1)
        self.bn_in = nn.BatchNorm3d(channels[0])
        self.blocks = nn.ModuleList()
        for c_in, c_out in zip(channels[:-1], channels[1:]):
            self.blocks.append(nn.ModuleDict({
                "conv_a": nn.Conv3d(c_in, c_out, 3, padding=1),
                "conv_b": nn.Conv3d(c_out, c_out, 3, padding=1),
                "bn": nn.BatchNorm3d(c_out),
            }))

    def forward(self, voxels: torch.Tensor) -> list[torch.Tensor]:
        x = voxels.unsqueeze(1)
        features = [x]
        net = self.bn_in(F.relu(self.conv_in(x)))
        features.append(net)
        for block in self.blocks:
            net = F.max_pool3d(net, 2)
            net = F.relu(block["conv_a"](net))
            net = block["bn"](F.relu(block["conv_b"](net)))
            features.append(net)
        return features


class Decoder(nn.Module):
    """``in_dim -> 2 hidden -> hidden -> (+ hidden) -> (+ hidden) -> 1``, ReLU after every layer
    (module docstring): (..., in_dim) -> (...,) non-negative."""

    def __init__(self, in_dim: int, hidden: int):
        super().__init__()
        self.fc_0 = nn.Linear(in_dim, 2 * hidden)
        self.fc_1 = nn.Linear(2 * hidden, hidden)
        self.fc_2 = nn.Linear(hidden, hidden)
        self.fc_3 = nn.Linear(hidden, hidden)
        self.fc_out = nn.Linear(hidden, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        net = F.relu(self.fc_1(F.relu(self.fc_0(x))))
        net = F.relu(self.fc_2(net)) + net
        net = F.relu(self.fc_3(net)) + net
        return F.relu(self.fc_out(net)).squeeze(-1)


class GIFSNetwork(nn.Module):
    """GIFS (module docstring). ``resolution``: voxel grid points per axis (a multiple of
    ``2^(len(channels) - 1)``); ``channels``: encoder widths; ``hidden``: decoder width."""

    def __init__(self, resolution: int, channels: Sequence[int], hidden: int):
        super().__init__()
        channels = tuple(int(c) for c in channels)
        if len(channels) < 1 or min(channels) < 1:
            raise ValueError(f"channels must be >= 1 positive widths, got {channels}")
        if int(resolution) % (2 ** (len(channels) - 1)):
            raise ValueError(f"resolution {resolution} is not a multiple of 2^{len(channels) - 1}")
        self.config = {"resolution": int(resolution), "channels": list(channels), "hidden": int(hidden)}
        self.resolution = int(resolution)
        self.feature_dim = 1 + sum(channels) + 3
        self.encoder = VoxelEncoder(channels)
        self.udf_decoder = Decoder(self.feature_dim, int(hidden))
        self.flag_decoder = Decoder(self.feature_dim, int(hidden))
        nn.init.constant_(self.flag_decoder.fc_out.bias, FLAG_BIAS_INIT)

    def encode(self, voxels: torch.Tensor) -> list[torch.Tensor]:
        """Feature grids of (B, R, R, R) voxel grids (:class:`VoxelEncoder`)."""
        return self.encoder(voxels)

    @staticmethod
    def point_features(points: torch.Tensor, grids: list[torch.Tensor]) -> torch.Tensor:
        """(B, Q, feature_dim) features of ``points`` (B, Q, 3), canonical frame (module docstring).

        ``grid_sample`` reads its last coordinate along the grid's first spatial axis, so the
        points enter as (z, y, x) to address the ``'ij'`` grids (x first)."""
        where = points[..., [2, 1, 0]].unsqueeze(1).unsqueeze(1)  # (B, 1, 1, Q, 3)
        sampled = [F.grid_sample(g, where, mode="bilinear", padding_mode="zeros", align_corners=True)
                   for g in grids]
        features = torch.cat(sampled, dim=1)[:, :, 0, 0, :]  # (B, C, Q)
        return torch.cat([features.transpose(1, 2), points], dim=-1)

    def udf(self, points: torch.Tensor, grids: list[torch.Tensor]) -> torch.Tensor:
        """(B, Q) unsigned distances (canonical units) of ``points`` (B, Q, 3)."""
        return self.udf_decoder(self.point_features(points, grids))

    def flag_from_features(self, feature_u: torch.Tensor, feature_v: torch.Tensor) -> torch.Tensor:
        """(...,) flags of pairs from their endpoint features (..., feature_dim)."""
        return self.flag_decoder(torch.maximum(feature_u, feature_v))

    def forward(self, pairs: torch.Tensor, voxels: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``pairs`` (B, Q, 6) = [u, v], ``voxels`` (B, R, R, R) -> (udf (B, Q, 2) of u and v,
        flag (B, Q): ~1 where the surface separates u from v)."""
        grids = self.encode(voxels)
        fu = self.point_features(pairs[..., :3], grids)
        fv = self.point_features(pairs[..., 3:], grids)
        udf = torch.stack([self.udf_decoder(fu), self.udf_decoder(fv)], dim=-1)
        return udf, self.flag_from_features(fu, fv)


def make_gifs_network(resolution: int, channels: Sequence[int], hidden: int) -> GIFSNetwork:
    """A :class:`GIFSNetwork`; ``make_gifs_network(**net.config)`` rebuilds ``net``'s architecture."""
    return GIFSNetwork(resolution, channels, hidden)
