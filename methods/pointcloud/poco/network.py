"""POCO's network (Boulch & Marlet, CVPR 2022): an FKAConv point-convolution U-Net that gives every
input point a latent vector, and an attention decoder that turns the latents of a query's K nearest
input points into its occupancy logits.

Written after the authors' code (github.com/valeoai/POCO: ``networks/network.py``,
``networks/backbone/fkaconv_network.py``, ``lightconvpoint/nn/conv_fkaconv.py``,
``networks/decoder/interp_attention_Kheads.py``); tensors are channel-last here.

Spatial structure (:func:`cloud_structure`, numpy, no weights)
--------------------------------------------------------------
Level 0 is the input cloud; level l + 1 is a subset of level l of ``int(ratio n_l)`` points
(:func:`quantized_subsample`, ratio 1/4). Per level: the ``conv_k`` nearest level-l points of every
level-l point (``same``), of every level-(l + 1) point among the level-l points (``down``), and the
nearest level-(l + 1) point of every level-l point (``up``). K-NN by KD-tree
(:func:`methods.pointcloud.knn.network.knn_neighbourhoods`); K is clipped to the level's size.

FKAConv (:class:`FKAConv`)
--------------------------
For a support point s with neighbours q_1..q_K (features f_k, Cin values): local coordinates
``p_k = (q_k - s) / r`` with r a running mean (momentum 0.1, training only) of the largest neighbour
distance; distance weights ``w_k = sigmoid(-alpha |q_k - s| + beta)`` rescaled to sum to K; an
alignment matrix A (K x M, M = 16 kernel elements) from p by three point-wise layers, each seeing the
w-weighted max over the neighbourhood of the previous one (``fc1``: 3 -> M, instance norm, ReLU;
``fc2``: 2M -> M, instance norm, ReLU; ``fc3``: 2M -> M, ReLU, times w); then the output
``W vec(F^T A)`` with F the K x Cin neighbour features and W a learned (Cout, Cin M) kernel. The
instance norm runs over all support points and neighbours of one cloud, per channel. Sums and
maxima over the neighbours make the output independent of their order.

Backbone (:class:`FKAConvUNet`)
-------------------------------
Widths ``w_l = hidden 2^l`` for levels 0..L. Level 0: FKAConv(1 -> w_0) + batch norm + ReLU, then a
residual block; level l >= 1: a residual block from level l - 1 to level l (its FKAConv gathers the
level-(l - 1) neighbours of each level-l point; the shortcut is max-pooled over them), then a
residual block at level l. A residual block: 1x1 in -> in/2, FKAConv in/2 -> in/2, 1x1 in/2 -> out,
each with batch norm (ReLU after the first two), plus a 1x1 + batch norm shortcut when in != out,
ReLU of the sum. Decoder: from level L down, each level-l point takes the features of its nearest
level-(l + 1) point, concatenated with its own skip features, through 1x1 + batch norm + ReLU to
w_l; a last 1x1 layer gives the ``latent``-wide vector of every input point. The input feature is
the constant 1 (the authors feed three constant channels, the same function of fewer weights).
Paper: hidden 64, L = 4 (widths 64 .. 1024), conv_k 16, latent 32.

Decoder (:class:`AttentionDecoder`)
-----------------------------------
For a query x and its ``decoder_k`` nearest input points q_k with latents z_k: ``h_k`` = three
1x1 layers + ReLU on ``[z_k, x - q_k]``; ``heads`` scores per neighbour, a softmax over the
neighbours per head, averaged over the heads: weights a_k >= 0 summing to 1; the value
``sum_k a_k V h_k`` through a last layer to two logits (outside, inside). Paper: K = 64, 64 heads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
import torch.nn.functional as F

from methods.pointcloud.neighbourhoods import knn_neighbourhoods

__all__ = ["quantized_subsample", "CloudStructure", "cloud_structure", "batch_structures", "gather_rows",
           "FKAConv", "ResidualBlock", "FKAConvUNet", "AttentionDecoder", "POCONetwork", "make_poco_network",
           "SUBSAMPLING_RATIO"]

#: Each backbone level keeps this fraction of the previous level's points (the authors' 0.25).
SUBSAMPLING_RATIO = 0.25


# --------------------------------------------------------------------------------------------------
# Spatial structure
# --------------------------------------------------------------------------------------------------

def quantized_subsample(points: np.ndarray, count: int) -> np.ndarray:
    """Indices of ``count`` points of ``points`` (n, 3) spread over space by voxel quantisation.

    Voxels of side ``diagonal / sqrt(count)`` over the points' bounding box keep one point each, the
    point nearest the voxel's centre; while the kept points are fewer than ``count`` they are all
    taken, removed, and the voxel side halves; the pass that would overflow keeps its voxels'
    points nearest their centres first. The choice depends on the positions only, not on the order
    of the rows (the authors' version randomly rotates the cloud before each pass and draws the
    overflowing pass's points at random). Returns (count,) int64 indices, all of them when
    ``count >= n``.
    """
    points = np.asarray(points, dtype=np.float64)
    n, count = len(points), int(count)
    if count >= n:
        return np.arange(n, dtype=np.int64)
    if count < 1:
        raise ValueError(f"a subsample needs at least one point, got count {count}")
    lower = points.min(axis=0)
    size = max(float(np.linalg.norm(points.max(axis=0) - lower)), 1e-12) / np.sqrt(count)
    remaining = np.arange(n, dtype=np.int64)
    chosen: list[np.ndarray] = []
    taken = 0
    while True:
        p = points[remaining]
        cells = np.floor((p - lower) / size).astype(np.int64)
        dist = np.linalg.norm(p - (lower + (cells + 0.5) * size), axis=1)
        span = cells.max(axis=0) + 1
        key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
        order = np.lexsort((dist, key))
        first = order[np.r_[True, key[order][1:] != key[order][:-1]]]  # nearest to its centre, per voxel
        if taken + len(first) < count:
            chosen.append(remaining[first])
            taken += len(first)
            remaining = np.delete(remaining, first)
            size /= 2.0
            continue
        keep = first[np.argsort(dist[first], kind="stable")[:count - taken]]
        chosen.append(remaining[keep])
        return np.concatenate(chosen)


@dataclass
class CloudStructure:
    """The levels of one cloud and their neighbourhoods (module docstring), numpy int64 indices.

    positions : per level l = 0..L, (n_l, 3) float32 points (level 0: the cloud).
    same : per level l, (n_l, k_l) indices into level l of each level-l point's neighbours.
    down : per level l = 1..L (entry l - 1), (n_l, k) indices into level l - 1.
    up : per level l = 0..L-1, (n_l,) index into level l + 1 of each level-l point's nearest.
    """

    positions: list[np.ndarray]
    same: list[np.ndarray]
    down: list[np.ndarray]
    up: list[np.ndarray]


def cloud_structure(points: np.ndarray, levels: int, conv_k: int) -> CloudStructure:
    """The :class:`CloudStructure` of ``points`` (n, 3) with ``levels`` subsampled levels."""
    points = np.asarray(points, dtype=np.float32)
    if len(points) == 0:
        raise ValueError("the cloud has no points")
    positions = [points]
    for _ in range(int(levels)):
        previous = positions[-1]
        positions.append(previous[quantized_subsample(previous, max(1, int(len(previous) * SUBSAMPLING_RATIO)))])
    same = [knn_neighbourhoods(p, p, min(conv_k, len(p))) for p in positions]
    down = [knn_neighbourhoods(positions[l - 1], positions[l], min(conv_k, len(positions[l - 1])))
            for l in range(1, len(positions))]
    up = [knn_neighbourhoods(positions[l + 1], positions[l], 1)[:, 0] for l in range(len(positions) - 1)]
    return CloudStructure(positions, same, down, up)


def batch_structures(structures: list[CloudStructure], device) -> dict[str, list[torch.Tensor]]:
    """Stack the structures of clouds of equal size into tensors on ``device``: ``positions`` (B, n_l, 3)
    float32, ``same`` / ``down`` (B, n_l, k) and ``up`` (B, n_l) int64."""
    out = {}
    for key in ("positions", "same", "down", "up"):
        per_level = zip(*(getattr(s, key) for s in structures))
        out[key] = [torch.from_numpy(np.stack(arrays)).to(device) for arrays in per_level]
    return out


def gather_rows(x: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """Rows of a batch of tables: ``x`` (B, n, C), ``index`` (B, ...) int64 into n -> (B, ..., C)."""
    B, n, C = x.shape
    offsets = (torch.arange(B, device=x.device) * n).view(B, *([1] * (index.ndim - 1)))
    return x.reshape(B * n, C)[(index + offsets).reshape(-1)].reshape(*index.shape, C)


# --------------------------------------------------------------------------------------------------
# Layers
# --------------------------------------------------------------------------------------------------

def _instance_norm(h: torch.Tensor, norm: nn.InstanceNorm2d) -> torch.Tensor:
    """Instance norm of (B, S, K, C) features over the S K positions of each cloud, per channel
    (``norm``: ``nn.InstanceNorm2d`` with affine weights; none when K = 1, as the authors)."""
    if h.shape[2] == 1:
        return h
    return norm(h.permute(0, 3, 1, 2)).permute(0, 2, 3, 1)


def _with_weighted_max(a: torch.Tensor, w: torch.Tensor, layer: nn.Linear) -> torch.Tensor:
    """``layer([a_k, max_j w_j a_j])`` for every neighbour k of (B, S, K, M) features ``a`` and
    weights ``w`` (B, S, K, 1), without building the concatenation: the weight's second half acts
    once per support point on the max."""
    m = a.shape[-1]
    pooled = (a * w).amax(dim=2, keepdim=True)
    return F.linear(a, layer.weight[:, :m]) + F.linear(pooled, layer.weight[:, m:])


def _batch_norm(h: torch.Tensor, norm: nn.BatchNorm1d) -> torch.Tensor:
    """Batch norm over every point of the batch: (B, n, C) -> (B, n, C)."""
    return norm(h.reshape(-1, h.shape[-1])).reshape(h.shape)


class FKAConv(nn.Module):
    """The FKAConv point convolution with adaptive normalisation (module docstring).

    ``forward(x (B, n, Cin), positions (B, n, 3), support (B, S, 3), index (B, S, K)) -> (B, S, Cout)``.
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int = 16, momentum: float = 0.1):
        super().__init__()
        self.in_channels, self.out_channels, self.kernel_size = int(in_channels), int(out_channels), int(kernel_size)
        self.momentum = float(momentum)
        self.kernel = nn.Linear(self.in_channels * self.kernel_size, self.out_channels, bias=False)
        self.fc1 = nn.Linear(3, self.kernel_size, bias=False)
        self.fc2 = nn.Linear(2 * self.kernel_size, self.kernel_size, bias=False)
        self.fc3 = nn.Linear(2 * self.kernel_size, self.kernel_size, bias=False)
        self.norm1 = nn.InstanceNorm2d(self.kernel_size, affine=True)
        self.norm2 = nn.InstanceNorm2d(self.kernel_size, affine=True)
        self.alpha = nn.Parameter(torch.ones(1))
        self.beta = nn.Parameter(torch.ones(1))
        self.register_buffer("norm_radius", torch.ones(1))

    def alignment(self, local: torch.Tensor) -> torch.Tensor:
        """The weighted alignment matrices (B, S, K, M) of the local coordinates ``q_k - s`` (B, S, K, 3)."""
        dist = torch.linalg.vector_norm(local.detach(), dim=-1)  # (B, S, K)
        if self.training:
            with torch.no_grad():
                radius = dist.amax(dim=2).mean()
                self.norm_radius.mul_(1.0 - self.momentum).add_(self.momentum * radius)
        p = local / self.norm_radius
        w = torch.sigmoid(-self.alpha * dist + self.beta)
        total = w.sum(dim=2, keepdim=True)
        w = (w / (total + (total == 0).to(w.dtype) + 1e-6) * dist.shape[2]).unsqueeze(-1)  # (B, S, K, 1)
        a = F.relu(_instance_norm(self.fc1(p), self.norm1))
        a = F.relu(_instance_norm(_with_weighted_max(a, w, self.fc2), self.norm2))
        return F.relu(_with_weighted_max(a, w, self.fc3)) * w

    def forward(self, x: torch.Tensor, positions: torch.Tensor, support: torch.Tensor,
                index: torch.Tensor) -> torch.Tensor:
        local = gather_rows(positions, index) - support.unsqueeze(2)  # (B, S, K, 3)
        a = self.alignment(local)
        f = torch.matmul(gather_rows(x, index).transpose(-1, -2), a)  # (B, S, Cin, M) = F^T A
        return self.kernel(f.reshape(*f.shape[:2], -1))


class ResidualBlock(nn.Module):
    """The bottleneck residual block of the backbone (module docstring); a downsampling block when
    the support points are fewer than the input points.

    ``forward(x (B, n, in), positions (B, n, 3), support (B, S, 3), index (B, S, K)) -> (B, S, out)``.
    """

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int = 16):
        super().__init__()
        mid = max(1, in_channels // 2)
        self.reduce, self.norm0 = nn.Linear(in_channels, mid), nn.BatchNorm1d(mid)
        self.conv, self.norm1 = FKAConv(mid, mid, kernel_size), nn.BatchNorm1d(mid)
        self.expand, self.norm2 = nn.Linear(mid, out_channels), nn.BatchNorm1d(out_channels)
        self.shortcut = nn.Linear(in_channels, out_channels) if in_channels != out_channels else None
        self.norm_shortcut = nn.BatchNorm1d(out_channels) if in_channels != out_channels else None

    def forward(self, x, positions, support, index):
        h = F.relu(_batch_norm(self.reduce(x), self.norm0))
        h = F.relu(_batch_norm(self.conv(h, positions, support, index), self.norm1))
        h = _batch_norm(self.expand(h), self.norm2)
        short = x if self.shortcut is None else _batch_norm(self.shortcut(x), self.norm_shortcut)
        if support.shape[1] != positions.shape[1]:  # downsampling: max-pool the shortcut
            short = gather_rows(short, index).amax(dim=2)
        return F.relu(h + short)


class FKAConvUNet(nn.Module):
    """The FKAConv U-Net backbone: a latent vector per input point (module docstring).

    ``forward(structure)`` with ``structure`` from :func:`batch_structures` -> (B, n_0, latent).
    """

    def __init__(self, hidden: int = 64, levels: int = 4, conv_k: int = 16, latent: int = 32):
        super().__init__()
        widths = [int(hidden) * 2 ** l for l in range(int(levels) + 1)]
        self.levels, self.conv_k = int(levels), int(conv_k)
        self.conv0, self.norm0 = FKAConv(1, widths[0], self.conv_k), nn.BatchNorm1d(widths[0])
        self.blocks_same = nn.ModuleList([ResidualBlock(w, w, self.conv_k) for w in widths])
        self.blocks_down = nn.ModuleList([ResidualBlock(widths[l - 1], widths[l], self.conv_k)
                                          for l in range(1, len(widths))])
        self.merge = nn.ModuleList([nn.Linear(widths[l + 1] + widths[l], widths[l]) for l in range(self.levels)])
        self.merge_norm = nn.ModuleList([nn.BatchNorm1d(widths[l]) for l in range(self.levels)])
        self.out = nn.Linear(widths[0], int(latent))

    def forward(self, structure: dict[str, list[torch.Tensor]]) -> torch.Tensor:
        pos, same, down, up = structure["positions"], structure["same"], structure["down"], structure["up"]
        ones = torch.ones(*pos[0].shape[:2], 1, dtype=pos[0].dtype, device=pos[0].device)
        x = F.relu(_batch_norm(self.conv0(ones, pos[0], pos[0], same[0]), self.norm0))
        skips = [self.blocks_same[0](x, pos[0], pos[0], same[0])]
        for l in range(1, self.levels + 1):
            x = self.blocks_down[l - 1](skips[-1], pos[l - 1], pos[l], down[l - 1])
            skips.append(self.blocks_same[l](x, pos[l], pos[l], same[l]))
        x = skips[-1]
        for l in range(self.levels - 1, -1, -1):
            lifted = gather_rows(x, up[l].unsqueeze(-1)).squeeze(2)
            x = F.relu(_batch_norm(self.merge[l](torch.cat([lifted, skips[l]], dim=-1)), self.merge_norm[l]))
        return self.out(x)


class AttentionDecoder(nn.Module):
    """POCO's attention-weighted interpolation of the neighbours' latents (module docstring):
    ``forward(latents (..., K, C), offsets (..., K, 3)) -> logits (..., 2)``."""

    def __init__(self, latent: int = 32, heads: int = 64, out_dim: int = 2):
        super().__init__()
        self.fc1 = nn.Linear(int(latent) + 3, int(latent))
        self.fc2 = nn.Linear(int(latent), int(latent))
        self.fc3 = nn.Linear(int(latent), int(latent))
        self.query = nn.Linear(int(latent), int(heads))
        self.value = nn.Linear(int(latent), int(latent))
        self.out = nn.Linear(int(latent), int(out_dim))

    def weights_and_values(self, latents: torch.Tensor, offsets: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Attention weights (..., K), summing to 1 over the K neighbours, and values (..., K, C) of
        neighbour latents (..., K, C) at offsets ``x - q_k`` (..., K, 3)."""
        h = F.relu(self.fc1(torch.cat([latents, offsets], dim=-1)))
        h = F.relu(self.fc3(F.relu(self.fc2(h))))
        weights = torch.softmax(self.query(h), dim=-2).mean(dim=-1)  # softmax over K per head, mean of heads
        return weights, self.value(h)

    def forward(self, latents: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
        """Logits (..., 2) [outside, inside] from the neighbours' latents (..., K, C) and offsets (..., K, 3)."""
        weights, values = self.weights_and_values(latents, offsets)
        return self.out((weights.unsqueeze(-1) * values).sum(dim=-2))


class POCONetwork(nn.Module):
    """Backbone + decoder. ``config``: the constructor's arguments (``make_poco_network(**config)``
    rebuilds it). ``input_points``: the cloud size of a training item and of an inference view;
    ``views``: how many times every input point's latent is computed (and averaged) at inference."""

    def __init__(self, hidden: int = 64, levels: int = 4, conv_k: int = 16, latent: int = 32, decoder_k: int = 64,
                 heads: int = 64, input_points: int = 3000, views: int = 10):
        super().__init__()
        self.backbone = FKAConvUNet(hidden, levels, conv_k, latent)
        self.decoder = AttentionDecoder(latent, heads)
        self.decoder_k, self.input_points, self.views = int(decoder_k), int(input_points), int(views)
        self.config = dict(hidden=int(hidden), levels=int(levels), conv_k=int(conv_k), latent=int(latent),
                           decoder_k=int(decoder_k), heads=int(heads), input_points=int(input_points), views=int(views))

    def latents(self, structure: dict[str, list[torch.Tensor]]) -> torch.Tensor:
        """(B, n, latent) latent vectors of the input points of ``structure``."""
        return self.backbone(structure)

    def decode(self, latents: torch.Tensor, points: torch.Tensor, queries: torch.Tensor,
               index: torch.Tensor) -> torch.Tensor:
        """Logits (B, Q, 2) of ``queries`` (B, Q, 3) from the latents (B, n, C) of ``points`` (B, n, 3),
        ``index`` (B, Q, K) the queries' nearest input points."""
        offsets = queries.unsqueeze(2) - gather_rows(points, index)
        return self.decoder(gather_rows(latents, index), offsets)

    def forward(self, structure, queries, index):
        """Training pass: logits (B, Q, 2) of ``queries`` (B, Q, 3) over the clouds of ``structure``."""
        latents = self.latents(structure)
        return self.decode(latents, structure["positions"][0], queries, index)


def make_poco_network(**config) -> POCONetwork:
    """A :class:`POCONetwork` from its ``config`` (``make_poco_network(**net.config)``)."""
    return POCONetwork(**config)
