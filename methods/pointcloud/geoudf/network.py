"""GeoUDF's two networks (Ren et al., ICCV 2023), written after the authors' ``model.py``
(github.com/rsy6318/GeoUDF), not copied from it.

Both run in the authors' frame (a shape's bounding box centred, largest side 1); the caller maps
coordinates in and out (:mod:`methods.pointcloud.geoudf.method`).

LGR-Net (:class:`LGRNet`, the authors' ``PUGeo``): local geometry representation by upsampling
-------------------------------------------------------------------------------------------------
A DGCNN encoder: three EdgeConv blocks, each on a K-NN graph (K = ``knn``, the point itself among
its neighbours) of its input features (the coordinates, then the previous block's output: a
*dynamic* graph), edge features ``[f_j - f_i, f_i]`` through shared layers (two in the first block,
one in the others; each a linear map + batch norm + LeakyReLU(0.2)), the max and the mean over the
K edges, then ``[max, mean] -> width`` (linear + batch norm + LeakyReLU). The nine vectors (max,
mean, output of each block) concatenated (9 ``width``) go through ``9 width -> 256 -> 128 -> 64 ->
18`` (batch norm + LeakyReLU after each hidden layer; every weight of this head scaled by 1e-5 at
initialisation, the biases left at torch's default) to the coefficients ``C`` (6, 3) of a quadratic
patch around the point p:

    x(u, v) = p + [1, u, v, u^2, u v, v^2] C,     n(u, v) = normalise(x_u x x_v),

with ``x_u = [0, 1, 0, 2u, v, 0] C``, ``x_v = [0, 0, 1, 0, u, 2v] C``. Each point is upsampled
to ``R = up_ratio`` points at R parameters (u, v): one of the R^2 sets of :func:`uv_sets` (the
farthest-point samples of an R x R grid on [-0.1, 0.1]^2, one set per starting grid point), drawn
at random per point (the caller passes the choice, so a seeded draw is reproducible).

Geometry-guided UDF (:class:`GeometryGuidedUDF`, the authors' ``UDF``)
---------------------------------------------------------------------
A query q with its K = ``udf_k`` nearest upsampled points p_k and their normals n_k:

    s_k = (q - p_k) . n_k,   d_k = |s_k|,   m_k = sign(s_k) n_k,
    UDF(q) = sum_k w_k d_k,  grad UDF(q) = normalise(sum_k w'_k m_k),

the distances to the K tangent planes and the normals turned towards q, weighted by two
softmaxes over the K neighbours. The weights come from ``[q - p_k, m_k]`` (6) through a shared
``6 -> 64 -> 128 -> 128 -> 128`` point MLP (per-neighbour features e_k; batch norm + LeakyReLU
after each hidden layer), its max over K (the patch feature g), and two heads
``[q - p_k, m_k, d_k, e_k, g] (263) -> 256 -> 128 -> 32 -> 1`` (one for w, one for w'). The
UDF and its gradient are thus a function of the local geometry (tangent planes), with learned
weights only.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from pykdtree.kdtree import KDTree
from torch import nn

__all__ = ["NEGATIVE_SLOPE", "UV_EXTENT", "COEFFICIENT_INIT_SCALE", "uv_sets", "knn_graph", "nearest_indices",
           "EdgeConvBlock", "LGRNet", "GeometryGuidedUDF", "GeoUDFNetwork", "make_geoudf_network"]

#: Slope of every LeakyReLU (the authors' 0.2).
NEGATIVE_SLOPE = 0.2
#: Half side of the (u, v) parameter square of the quadratic patches (authors' frame).
UV_EXTENT = 0.1
#: Scale of the coefficient head's initial weights (its outputs start near their biases).
COEFFICIENT_INIT_SCALE = 1e-5
#: Centre points per EdgeConv chunk in eval mode (bounds the (chunk, K, 2C) edge features).
EVAL_CHUNK = 8_192


def _layers(widths: tuple[int, ...], last_plain: bool) -> nn.Sequential:
    """``widths[0] -> widths[1] -> ...``: linear maps, each followed by BatchNorm1d and
    LeakyReLU(0.2), except the last when ``last_plain``."""
    mods: list[nn.Module] = []
    for i in range(len(widths) - 1):
        mods.append(nn.Linear(widths[i], widths[i + 1]))
        if not (last_plain and i == len(widths) - 2):
            mods += [nn.BatchNorm1d(widths[i + 1]), nn.LeakyReLU(NEGATIVE_SLOPE)]
    return nn.Sequential(*mods)


def _apply(mlp: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """A point-wise MLP on the last axis of ``x`` (...,C); batch norm over all leading axes."""
    return mlp(x.reshape(-1, x.shape[-1])).reshape(*x.shape[:-1], -1)


def uv_sets(ratio: int) -> np.ndarray:
    """The (u, v) parameter sets of the upsampling, (ratio^2, ratio, 2) float32.

    Grid: ``ratio x ratio`` points (i, j) / (ratio - 1) on [0, 1]^2. Set s holds ``ratio`` farthest
    point samples of the grid starting at grid point s (each next point maximises its squared
    distance to the chosen ones; ties to the lowest grid index). Mapped to
    ``UV_EXTENT (2 uv - 1)``, i.e. onto [-0.1, 0.1]^2."""
    ratio = int(ratio)
    if ratio < 2:
        raise ValueError(f"up_ratio must be >= 2, got {ratio}")
    axis = np.arange(ratio, dtype=np.float64) / (ratio - 1)
    grid = np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2)  # (G, 2)
    G = len(grid)
    sq = ((grid[:, None, :] - grid[None, :, :]) ** 2).sum(-1)  # (G, G)
    chosen = np.empty((G, ratio), dtype=np.int64)
    chosen[:, 0] = np.arange(G)
    nearest = sq[np.arange(G)]  # (starts, G): squared distance to the chosen set
    for t in range(1, ratio):
        chosen[:, t] = np.argmax(nearest, axis=1)
        nearest = np.minimum(nearest, sq[chosen[:, t]])
    return (UV_EXTENT * (2.0 * grid[chosen] - 1.0)).astype(np.float32)


def knn_graph(features: torch.Tensor, k: int, chunk: int = 1_024) -> torch.Tensor:
    """Indices (B, M, k) int64 of the ``k`` nearest rows of ``features`` (B, M, C) for each row
    (Euclidean, the row itself among them; no gradient). Coordinates (C = 3) on the CPU: a KD-tree
    per item (pykdtree, exact); otherwise the ranking ``|f_j|^2 - 2 f_i . f_j`` (the squared distance
    less the row's constant ``|f_i|^2``) by matrix products in chunks of ``chunk`` rows, then top-k."""
    B, M, C = features.shape
    if M < k:
        raise ValueError(f"a {k}-NN graph needs at least {k} points, got {M}")
    with torch.no_grad():
        f = features.detach()
        if C == 3 and f.device.type == "cpu":
            out = []
            for item in f.numpy():
                item = np.ascontiguousarray(item, dtype=np.float32)
                _, idx = KDTree(item).query(item, k=k)
                out.append(np.asarray(idx, dtype=np.int64).reshape(M, k))
            return torch.from_numpy(np.stack(out))
        norms = (f * f).sum(-1)[:, None, :]  # (B, 1, M)
        out = [(norms - 2.0 * f[:, i:i + chunk] @ f.transpose(1, 2)).topk(k, dim=-1, largest=False).indices
               for i in range(0, M, chunk)]
    return torch.cat(out, dim=1)


def nearest_indices(queries: torch.Tensor, points: torch.Tensor, k: int = 1, chunk: int = 4_096) -> torch.Tensor:
    """Indices (Q, k) int64 of the ``k`` nearest ``points`` (P, 3) of each query (Q, 3), nearest first,
    no gradient: a KD-tree (pykdtree, exact) on the CPU, chunked ``cdist`` on other devices."""
    if len(points) < k:
        raise ValueError(f"{k} nearest points asked among {len(points)}")
    if queries.device.type == "cpu":
        q = np.ascontiguousarray(queries.detach().numpy(), dtype=np.float32)
        p = np.ascontiguousarray(points.detach().numpy(), dtype=np.float32)
        _, idx = KDTree(p).query(q, k=k)
        return torch.from_numpy(np.asarray(idx, dtype=np.int64).reshape(len(q), k))
    with torch.no_grad():
        p = points.detach()
        return torch.cat([torch.cdist(queries[i:i + chunk].detach(), p).topk(k, dim=-1, largest=False).indices
                          for i in range(0, len(queries), chunk)])


class EdgeConvBlock(nn.Module):
    """One DGCNN block: K-NN graph of the input features, edge features ``[f_j - f_i, f_i]``
    through ``edge_widths`` (linear + BN + LeakyReLU each), max and mean over the K edges, then
    ``[max, mean] -> width`` (linear + BN + LeakyReLU). ``forward(f (B, M, C)) -> (max, mean,
    out)``, each (B, M, width). In eval mode the edge features are built in chunks of centre
    points (the same numbers, bounded memory)."""

    def __init__(self, in_dim: int, width: int, edge_layers: int, k: int):
        super().__init__()
        self.k = int(k)
        self.edge_mlp = _layers((2 * in_dim,) + (width,) * edge_layers, last_plain=False)
        self.fuse = _layers((2 * width, width), last_plain=False)

    def forward(self, f: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        B, M, _ = f.shape
        idx = knn_graph(f, self.k)
        batch = torch.arange(B, device=f.device)[:, None, None]
        step = M if self.training else EVAL_CHUNK
        maxes, means = [], []
        for i in range(0, M, step):
            centre = f[:, i:i + step]  # (B, m, C)
            neighbours = f[batch, idx[:, i:i + step]]  # (B, m, k, C)
            centre_k = centre[:, :, None, :].expand_as(neighbours)
            h = _apply(self.edge_mlp, torch.cat([neighbours - centre_k, centre_k], dim=-1))  # (B, m, k, W)
            maxes.append(h.amax(dim=2))
            means.append(h.mean(dim=2))
        pooled_max, pooled_mean = torch.cat(maxes, dim=1), torch.cat(means, dim=1)
        out = _apply(self.fuse, torch.cat([pooled_max, pooled_mean], dim=-1))
        return pooled_max, pooled_mean, out


class LGRNet(nn.Module):
    """LGR-Net (module docstring): ``forward(points (B, M, 3), choice (B, M) int64 in [0, R^2))
    -> (dense (B, M, R, 3), normals (B, M, R, 3))``, authors' frame; ``choice`` picks each point's
    (u, v) set of :func:`uv_sets`."""

    def __init__(self, knn: int = 20, width: int = 128, coefficient_widths: tuple[int, ...] = (256, 128, 64),
                 up_ratio: int = 16):
        super().__init__()
        self.knn, self.width, self.up_ratio = int(knn), int(width), int(up_ratio)
        self.blocks = nn.ModuleList([EdgeConvBlock(3, self.width, 2, self.knn),
                                     EdgeConvBlock(self.width, self.width, 1, self.knn),
                                     EdgeConvBlock(self.width, self.width, 1, self.knn)])
        self.coefficients = _layers((9 * self.width,) + tuple(int(w) for w in coefficient_widths) + (18,),
                                    last_plain=True)
        with torch.no_grad():
            for m in self.coefficients.modules():
                if isinstance(m, nn.Linear):
                    m.weight.mul_(COEFFICIENT_INIT_SCALE)
        self.register_buffer("uv", torch.from_numpy(uv_sets(self.up_ratio)), persistent=False)

    def forward(self, points: torch.Tensor, choice: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if points.ndim != 3 or points.shape[2] != 3:
            raise ValueError(f"LGR-Net takes (B, M, 3) points, got {tuple(points.shape)}")
        features, f = [], points
        for block in self.blocks:
            pooled_max, pooled_mean, f = block(f)
            features += [pooled_max, pooled_mean, f]
        B, M, _ = points.shape
        C = _apply(self.coefficients, torch.cat(features, dim=-1)).reshape(B, M, 6, 3)
        uv = self.uv[choice]  # (B, M, R, 2)
        u, v = uv[..., 0:1], uv[..., 1:2]
        one, zero = torch.ones_like(u), torch.zeros_like(u)
        basis = torch.cat([one, u, v, u * u, u * v, v * v], dim=-1)  # (B, M, R, 6)
        basis_u = torch.cat([zero, one, zero, 2 * u, v, zero], dim=-1)
        basis_v = torch.cat([zero, zero, one, zero, u, 2 * v], dim=-1)
        dense = points[:, :, None, :] + basis @ C
        normals = F.normalize(torch.linalg.cross(basis_u @ C, basis_v @ C, dim=-1), dim=-1)
        return dense, normals


class GeometryGuidedUDF(nn.Module):
    """The geometry-guided UDF (module docstring): ``forward(queries (Q, 3), neighbours (Q, K, 3),
    normals (Q, K, 3)) -> (udf (Q,), gradient (Q, 3) unit)``, authors' frame."""

    def __init__(self, feature_widths: tuple[int, ...] = (64, 128, 128, 128),
                 attention_widths: tuple[int, ...] = (256, 128, 32)):
        super().__init__()
        feature_widths = tuple(int(w) for w in feature_widths)
        self.features = _layers((6,) + feature_widths, last_plain=True)
        head_in = 6 + 1 + 2 * feature_widths[-1]
        head = (head_in,) + tuple(int(w) for w in attention_widths) + (1,)
        self.udf_weights = _layers(head, last_plain=True)
        self.grad_weights = _layers(head, last_plain=True)

    def forward(self, queries: torch.Tensor, neighbours: torch.Tensor, normals: torch.Tensor):
        local = queries[:, None, :] - neighbours  # (Q, K, 3)
        signed = (local * normals).sum(-1, keepdim=True)  # (Q, K, 1)
        dist = signed.abs()
        oriented = torch.sgn(signed) * normals
        geometry = torch.cat([local, oriented], dim=-1)  # (Q, K, 6)
        e = _apply(self.features, geometry)  # (Q, K, W)
        g = e.amax(dim=1, keepdim=True).expand_as(e)
        x = torch.cat([geometry, dist, e, g], dim=-1)
        w = torch.softmax(_apply(self.udf_weights, x)[..., 0], dim=1)  # (Q, K)
        w_grad = torch.softmax(_apply(self.grad_weights, x)[..., 0], dim=1)
        udf = (w * dist[..., 0]).sum(dim=1)
        grad = F.normalize((w_grad[..., None] * oriented).sum(dim=1), dim=-1)
        return udf, grad


class GeoUDFNetwork(nn.Module):
    """LGR-Net (``.lgr``) and the geometry-guided UDF (``.udf``), with ``config`` to rebuild it
    (:func:`make_geoudf_network`); ``patch_points``: the points of the patches LGR-Net was trained
    on (and upsamples at inference)."""

    def __init__(self, knn: int = 20, width: int = 128, coefficient_widths: tuple[int, ...] = (256, 128, 64),
                 up_ratio: int = 16, udf_k: int = 10, feature_widths: tuple[int, ...] = (64, 128, 128, 128),
                 attention_widths: tuple[int, ...] = (256, 128, 32), patch_points: int = 3_000):
        super().__init__()
        self.lgr = LGRNet(knn, width, coefficient_widths, up_ratio)
        self.udf = GeometryGuidedUDF(feature_widths, attention_widths)
        self.udf_k = int(udf_k)
        self.patch_points = int(patch_points)
        self.config = dict(knn=int(knn), width=int(width), coefficient_widths=[int(w) for w in coefficient_widths],
                           up_ratio=int(up_ratio), udf_k=self.udf_k, patch_points=self.patch_points,
                           feature_widths=[int(w) for w in feature_widths],
                           attention_widths=[int(w) for w in attention_widths])


def make_geoudf_network(**config) -> GeoUDFNetwork:
    """A :class:`GeoUDFNetwork` from its ``config`` (the stored weights load into it)."""
    return GeoUDFNetwork(**config)
