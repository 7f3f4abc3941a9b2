"""The K-NN local networks of point-cloud reconstruction, shared by the learned methods.

The reconstruction task trains each learned method *once* across many shapes and then
reconstructs a surface from a raw point cloud (no normals). The learned methods share one encoder
design, one training set and one training budget (:class:`methods.pointcloud.knn.training.KNNBudget`), so a comparison between them
is about the representation, not the network:

* ``sals-knn``: a segment (u, v) -> two logits (o, s)  (:class:`SegmentKNNNetwork`);
* ``udf-knn``: a point x -> its unsigned distance        (:class:`PointKNNNetwork`, ``out_dim = 1``);
* ``occ-knn``: a point x -> its occupancy logit          (:class:`PointKNNNetwork`, ``out_dim = 1``).

Neighbourhoods
--------------
:func:`methods.pointcloud.neighbourhoods.knn_neighbourhoods` gives the K nearest input points of each query by one exact KD-tree query
(a point's query is the point; a segment's is its midpoint m = (u + v) / 2, :func:`methods.pointcloud.neighbourhoods.segment_neighbourhoods`).
The network sees only those K points: there is no global feature, the networks are purely local.

Local encoder
-------------
:class:`LocalEncoder` encodes an anchor a (u, v or x) and its neighbours q_1..q_K: the point features
``[q_k - a, |q_k - a|]`` (4 values), a point-wise MLP (paper: 4 -> 256, then 4 x 256 -> 256, each
linear layer followed by batch norm and LeakyReLU(0.2), then 256 -> 256 without activation) and a max
over the K neighbours: (B, 3), (B, K, 3) -> (B, width). The max makes the code invariant to the order
of the neighbours by construction (the paper's ablation: max beats mean pooling, CD 4.560 vs 4.852).

Normalisation
-------------
Batch norm as in the paper: ``BatchNorm1d`` over the B K point features of the batch, flattened, in
the encoders, and over the B samples in the head. A training batch is several shapes x thousands of
segments (paper 4 x 5,120: 409,600 point features per encoder), so batch statistics are well defined;
inference must run in ``eval()`` mode, where each layer applies its running statistics and a
sample's output depends on it alone (in train mode it depends on the rest of the batch, and a batch
of 1 raises in the head). Because the first linear layer is followed by batch norm, the scale of the
relative coordinates (a neighbourhood of 40k points spans ~0.01-0.05 canonical units) needs no
constant: the norm rescales it.

Segments are ordered
--------------------
:class:`SegmentKNNNetwork` encodes u and v with *separate* encoders (their own weights, the paper: "each
goes through its own point-wise MLP") and concatenates ``[enc_u(u), enc_v(v)]``, so it is a function of
the ordered triple (u, v, neighbours): swapping u and v gives a different input and, in general, a
different output. The exact field is symmetric in the sense ``o(v, u) = o(u, v)`` and
``s(v, u) = 1 - s(u, v)`` (hit point ``s u + (1 - s) v``); the paper does not enforce it and neither
do we: the network learns it only as far as its training segments come in both orientations.

Initialisation: torch's default for every layer, except the head's output layer, whose weights are
scaled by :data:`methods.core.network.OUTPUT_INIT_SCALE` (0.01) and bias zeroed, as for the per-shape MLP
(:class:`methods.core.network.MLP`): outputs start near 0 (probabilities 0.5, UDF 0).

``make_knn_network(**net.config)`` rebuilds any network of this module (cached weights load into it).
"""

from __future__ import annotations

import torch
from torch import nn

from methods.core.network import OUTPUT_INIT_SCALE

__all__ = ["NEGATIVE_SLOPE", "KINDS", "LocalEncoder",
           "RegressionHead", "SegmentKNNNetwork", "PointKNNNetwork", "make_knn_network"]

#: Slope of the LeakyReLU after every hidden layer (the paper's 0.2).
NEGATIVE_SLOPE = 0.2


# --------------------------------------------------------------------------------------------------
# Networks
# --------------------------------------------------------------------------------------------------

def _hidden_layers(in_dim: int, width: int, depth: int) -> list[nn.Module]:
    """``in_dim -> width``, then ``depth`` x ``width -> width``; each linear layer followed by
    BatchNorm1d and LeakyReLU(NEGATIVE_SLOPE)."""
    layers: list[nn.Module] = []
    for i in range(depth + 1):
        layers += [nn.Linear(in_dim if i == 0 else width, width), nn.BatchNorm1d(width),
                   nn.LeakyReLU(NEGATIVE_SLOPE)]
    return layers


def _check_sizes(width: int, depth: int, what: str) -> tuple[int, int]:
    if int(width) < 1 or int(depth) < 0:
        raise ValueError(f"{what} width must be >= 1 and depth >= 0, got width {width}, depth {depth}")
    return int(width), int(depth)


class LocalEncoder(nn.Module):
    """The point-wise MLP + max-pool encoder of one anchor and its K neighbours.

    Layers: ``Linear(4, width)``, then ``depth`` x ``Linear(width, width)``, each followed by
    ``BatchNorm1d`` (over the B K flattened point features) and LeakyReLU(0.2); then
    ``Linear(width, width)`` without activation; then the max over the K neighbours. Paper:
    ``width = 256``, ``depth = 4`` (6 linear layers).

    ``forward(anchors (B, 3), neighbours (B, K, 3)) -> (B, width)``; the point features are
    ``[q_k - a, |q_k - a|]``. Invariant to the order of the K neighbours (max-pool; batch statistics
    are over all B K features). Differentiable in the anchors (the SALS normals are d s / d u).
    """

    def __init__(self, width: int = 256, depth: int = 4):
        super().__init__()
        self.width, self.depth = _check_sizes(width, depth, "encoder")
        self.mlp = nn.Sequential(*_hidden_layers(4, self.width, self.depth), nn.Linear(self.width, self.width))

    def forward(self, anchors: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
        B, K = neighbours.shape[0], neighbours.shape[1]
        rel = neighbours - anchors[:, None, :]  # (B, K, 3)
        features = torch.cat([rel, torch.linalg.vector_norm(rel, dim=-1, keepdim=True)], dim=-1)
        h = self.mlp(features.reshape(B * K, 4)).reshape(B, K, self.width)
        return h.amax(dim=1)


class RegressionHead(nn.Module):
    """The head of every K-NN network: ``Linear(in_dim, width)``, then ``depth`` x ``Linear(width, width)``,
    each followed by BatchNorm1d and LeakyReLU(0.2), then ``Linear(width, out_dim)`` (raw outputs:
    logits or a distance). Paper (segments): ``512 -> 256``, 4 x ``256 -> 256``, ``256 -> 2``. The
    output layer starts near 0 (module docstring)."""

    def __init__(self, in_dim: int, out_dim: int, width: int = 256, depth: int = 4):
        super().__init__()
        width, depth = _check_sizes(width, depth, "head")
        out = nn.Linear(width, int(out_dim))
        with torch.no_grad():
            out.weight.mul_(OUTPUT_INIT_SCALE)
            out.bias.zero_()
        self.mlp = nn.Sequential(*_hidden_layers(int(in_dim), width, depth), out)

    def forward(self, codes: torch.Tensor) -> torch.Tensor:
        return self.mlp(codes)


def _check_neighbours(anchors: torch.Tensor, neighbours: torch.Tensor) -> None:
    if neighbours.ndim != 3 or neighbours.shape[2] != 3 or neighbours.shape[1] < 1:
        raise ValueError(f"neighbours must be (B, K, 3) with K >= 1, got {tuple(neighbours.shape)}")
    if anchors.shape[0] != neighbours.shape[0]:
        raise ValueError(f"{anchors.shape[0]} anchors but {neighbours.shape[0]} neighbourhoods")


class SegmentKNNNetwork(nn.Module):
    """``sals-knn``: a segment (u, v) and the K nearest input points of its midpoint -> (o, s) logits.

    ``head([encoder_u(u, q), encoder_v(v, q)])``: two :class:`LocalEncoder` with their own weights,
    concatenated (2 ``encoder_width``), then a :class:`RegressionHead` to ``out_dim`` (2: o and s
    logits; the method applies the sigmoids). A function of the ordered segment: not symmetric under
    u <-> v (module docstring).

    ``forward(anchors (B, 2, 3) or (B, 6) = [u, v], neighbours (B, K, 3)) -> (B, out_dim)``.
    """

    kind = "segment"

    def __init__(self, out_dim: int = 2, encoder_width: int = 256, encoder_depth: int = 4, head_width: int = 256,
                 head_depth: int = 4):
        super().__init__()
        self.encoder_u = LocalEncoder(encoder_width, encoder_depth)
        self.encoder_v = LocalEncoder(encoder_width, encoder_depth)
        self.head = RegressionHead(2 * self.encoder_u.width, out_dim, head_width, head_depth)
        self.config = dict(kind=self.kind, out_dim=int(out_dim), encoder_width=self.encoder_u.width,
                           encoder_depth=self.encoder_u.depth, head_width=int(head_width), head_depth=int(head_depth))

    def forward(self, anchors: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
        if anchors.ndim == 2 and anchors.shape[1] == 6:
            anchors = anchors.reshape(-1, 2, 3)
        if anchors.ndim != 3 or anchors.shape[1:] != (2, 3):
            raise ValueError(f"segment anchors must be (B, 2, 3) or (B, 6), got {tuple(anchors.shape)}")
        _check_neighbours(anchors, neighbours)
        codes = torch.cat([self.encoder_u(anchors[:, 0], neighbours), self.encoder_v(anchors[:, 1], neighbours)], dim=1)
        return self.head(codes)


class PointKNNNetwork(nn.Module):
    """``udf-knn`` / ``occ-knn``: a point x and its K nearest input points -> ``out_dim`` raw outputs
    (1: the unsigned distance or the occupancy logit). ``head(encoder(x, q))`` with the same
    :class:`LocalEncoder` and :class:`RegressionHead` design as :class:`SegmentKNNNetwork`.

    ``forward(anchors (B, 3), neighbours (B, K, 3)) -> (B, out_dim)``.
    """

    kind = "point"

    def __init__(self, out_dim: int = 1, encoder_width: int = 256, encoder_depth: int = 4, head_width: int = 256,
                 head_depth: int = 4):
        super().__init__()
        self.encoder = LocalEncoder(encoder_width, encoder_depth)
        self.head = RegressionHead(self.encoder.width, out_dim, head_width, head_depth)
        self.config = dict(kind=self.kind, out_dim=int(out_dim), encoder_width=self.encoder.width,
                           encoder_depth=self.encoder.depth, head_width=int(head_width), head_depth=int(head_depth))

    def forward(self, anchors: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
        if anchors.ndim != 2 or anchors.shape[1] != 3:
            raise ValueError(f"point anchors must be (B, 3), got {tuple(anchors.shape)}")
        _check_neighbours(anchors, neighbours)
        return self.head(self.encoder(anchors, neighbours))


#: Network kinds: the input of each network class.
KINDS = {"segment": SegmentKNNNetwork, "point": PointKNNNetwork}


def make_knn_network(kind: str, **config) -> nn.Module:
    """A K-NN network of ``kind`` (``'segment'`` or ``'point'``) with the given sizes (defaults = paper).

    ``config``: ``out_dim``, ``encoder_width``, ``encoder_depth``, ``head_width``, ``head_depth``
    (:meth:`KNNBudget.network_config` gives the last four). ``make_knn_network(**net.config)``
    rebuilds ``net``'s architecture, into which its ``state_dict`` loads.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown K-NN network kind '{kind}'; known: {', '.join(KINDS)}")
    return KINDS[kind](**config)
