"""The networks every method fits: the paper's MLP and a feature-grid backbone.

Backbones (:data:`BACKBONES`, chosen by the budget, :mod:`methods.core.fitting`):

* ``'mlp'``: *paper* network: 9 linear layers of width 512 (input -> 512, 7 x (512 -> 512),
  512 -> out), Softplus(beta = 100) after every layer but the last, no positional encoding.
  ``depth`` counts the linear layers; ``width`` is the hidden width.
* ``'grid'``: :class:`GridNetwork`, a multi-resolution dense feature grid (:class:`FeatureGrid`) in
  front of a small MLP of the same kind (the Instant-NGP / NGLOD / NeuS2 family of per-shape fits,
  with dense levels instead of a hash table). Every input point p of the canonical cube is
  encoded as ``[enc(p), p]``; a segment (u, v) is encoded as ``[enc(u), u, enc(v), v]`` with the
  *same* grid, so the field stays a function of the segment (see :class:`GridNetwork`).

Networks of single methods (:data:`NETWORKS`): NGLOD's :class:`LODNetwork` (``'nglod'``) and
:class:`StackedNetworks` (``'stack'``: independent networks of any of these kinds side by side, e.g.
UODF's one per axis).

Clamped Softplus
----------------
``softplus_beta(x) = log(1 + exp(beta x)) / beta``. torch's kernel evaluates ``exp(beta x)`` for all x,
which underflows to denormal floats wherever ``beta x < -87`` (slow on x86) and its backward does the
same. The identity used here::

    softplus_beta(x) = relu(x) + log1p(exp(-beta |x|)) / beta

has an exponent argument <= 0 and we clamp it to ``>= -EXP_CLAMP`` (``EXP_CLAMP = 30``): the dropped term is
below ``log1p(exp(-30)) / beta = 9.4e-14 / beta``, so values equal torch's to ~1e-13 (float64) or to
float32 rounding. The derivative ``sigmoid(beta x)`` is evaluated on ``beta x`` clamped to
``[-EXP_CLAMP, EXP_CLAMP]`` (error < 1e-13). The backward is written with differentiable torch ops, so second
derivatives (``create_graph=True``, needed by the UDF gradient loss) work.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

import torch
from torch import nn

from methods.core import grid_lookup, head_gradient

#: Clamp of the exponent argument |beta x| (see module docstring).
EXP_CLAMP = 30.0
#: torch's default linear-regime threshold of beta x (softplus(x) = x above it; error < 2e-9 / beta).
THRESHOLD = 20.0
#: Scale of the output layer's default initial weights (bias 0): outputs start near 0.
OUTPUT_INIT_SCALE = 0.01
#: Feature-grid values start uniform in [-GRID_INIT_SCALE, GRID_INIT_SCALE] (Instant-NGP's 1e-4):
#: the network starts as the MLP of the raw coordinates, and the grid learns the detail.
GRID_INIT_SCALE = 1e-4


class _FastSoftplus(torch.autograd.Function):
    """torch's softplus kernels on x clamped to >= -EXP_CLAMP / beta (no denormal exp(beta x))."""

    @staticmethod
    def forward(ctx, x, beta: float):
        ctx.save_for_backward(x)
        ctx.beta = beta
        return torch.nn.functional.softplus(x.clamp(min=-EXP_CLAMP / beta), beta, THRESHOLD)

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        # Differentiable ops (not once_differentiable): under create_graph the double backward goes
        # through aten's softplus_backward derivative and the clamp.
        xc = x.clamp(min=-EXP_CLAMP / ctx.beta)
        return torch.ops.aten.softplus_backward(grad, xc, ctx.beta, THRESHOLD), None


def fast_softplus(x: torch.Tensor, beta: float = 100.0) -> torch.Tensor:
    """Softplus with slope ``beta``: the same values as ``torch.nn.functional.softplus(x, beta)`` (to 1e-6
    in float32, 1e-12 in float64) without denormal slow paths. See the module docstring."""
    return _FastSoftplus.apply(x, float(beta))


class FastSoftplus(nn.Module):
    """Module form of :func:`fast_softplus` (drop-in for ``nn.Softplus(beta)``)."""

    def __init__(self, beta: float = 100.0):
        super().__init__()
        self.beta = float(beta)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return fast_softplus(x, self.beta)

    def extra_repr(self) -> str:
        return f"beta={self.beta}"


#: Activation names. ``'softplus'`` (default) is torch's kernel. ``'softplus-clamped'`` gives the
#: same values with no denormal exp, for CPUs where torch's kernel hits the slow path
#: (benchmarks/bench_network.py compares them).
ACTIVATIONS = {
    "softplus": lambda beta: nn.Softplus(beta=beta),
    "softplus-clamped": lambda beta: FastSoftplus(beta),
    "relu": lambda beta: nn.ReLU(),
}


class MLP(nn.Module):
    """Plain MLP: ``depth`` linear layers (``depth >= 2``), hidden ``width``, activation after every
    layer but the last, no positional encoding. Inputs (B, in_dim) -> outputs (B, out_dim).

    Under a bfloat16 autocast (a fit's ``precision``) the input layer still runs in float32: bfloat16
    rounds a coordinate in [-1, 1] to 2^-8 of itself (up to 0.004), which puts a floor under an SDF
    fit's loss; the hidden and output layers' products run in bfloat16.

    Initialisation: torch's default for every layer, except the output layer, whose weights are
    scaled by ``OUTPUT_INIT_SCALE`` (0.01) and bias zeroed, so every method starts from outputs ~0
    (SDF/UDF 0 inside their +-0.1 loss clamps, where a clamped prediction has a gradient; occupancy
    and SALS probabilities 0.5). The paper does not fix an initialisation.
    """

    def __init__(self, in_dim: int, out_dim: int, depth: int = 9, width: int = 512, beta: float = 100.0,
                 activation: str = "softplus"):
        super().__init__()
        if depth < 2:
            raise ValueError(f"MLP depth (number of linear layers) must be >= 2, got {depth}")
        if activation not in ACTIVATIONS:
            raise ValueError(f"unknown activation '{activation}'; known: {', '.join(ACTIVATIONS)}")
        self.config = dict(in_dim=int(in_dim), out_dim=int(out_dim), depth=int(depth), width=int(width),
                           beta=float(beta), activation=activation)
        dims = [in_dim] + [width] * (depth - 1) + [out_dim]
        layers: list[nn.Module] = []
        for i in range(depth):
            layers.append(nn.Linear(dims[i], dims[i + 1]))
            if i < depth - 1:
                layers.append(ACTIVATIONS[activation](beta))
        with torch.no_grad():  # output layer starts near zero (see class docstring)
            layers[-1].weight.mul_(OUTPUT_INIT_SCALE)
            layers[-1].bias.zero_()
        self.layers = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if torch.is_autocast_enabled(x.device.type):  # the input layer on the raw coordinates in float32
            with torch.autocast(device_type=x.device.type, enabled=False):
                x = self.layers[0](x.float())
            return self.layers[1:](x)
        return self.layers(x)


def trilinear(volume: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Trilinear interpolation of a dense grid of features on the cube [-1, 1]^3.

    Parameters
    ----------
    volume : (R, R, R, C) tensor, ``R >= 2``; ``volume[i, j, k]`` is the feature at the grid point
        ``(-1 + 2 i / (R - 1), -1 + 2 j / (R - 1), -1 + 2 k / (R - 1))`` (corners on the cube's faces).
    points : (P, 3) tensor of (x, y, z) in the same dtype.

    Returns
    -------
    (P, C) tensor: the weighted sum of the features at the 8 corners of each point's cell. Points
    outside the cube take the value at the nearest point of the cube (their coordinates are clamped,
    so the gradient along a clamped axis is 0): the same values as ``grid_sample(...,
    align_corners=True, padding_mode='border')``.

    Notes
    -----
    An explicit gather (one ``index_select`` of the 8 corner rows, then a lerp along x, y and z): its
    backward adds each point's 8 weighted gradients into their rows (``index_add``). Chosen over
    ``torch.nn.functional.grid_sample`` (the same values) for the speed of whole training steps,
    above all with a second-order loss (benchmarks/bench_network.py; docs/PERFORMANCE.md, section 2).
    Differentiable to any order in ``points`` and ``volume`` (the weights are products of the
    fractional coordinates, the features enter linearly); inside a cell the value is linear along
    each axis, so its derivative is piecewise constant.
    """
    R, C = volume.shape[0], volume.shape[-1]
    t = ((points + 1.0) * (0.5 * (R - 1))).clamp(0.0, R - 1.0)
    cell = t.detach().floor().clamp(max=R - 2)  # the last cell owns the upper face
    frac = t - cell  # (P, 3) in [0, 1], carries the gradient in the points
    cell = cell.long()
    base = (cell[:, 0] * R + cell[:, 1]) * R + cell[:, 2]
    corner = torch.tensor([0, 1], device=points.device)
    offsets = (corner[:, None, None] * (R * R) + corner[None, :, None] * R + corner[None, None, :]).reshape(8)
    rows = (base[:, None] + offsets).reshape(-1)
    fx, fy, fz = frac[:, 0, None, None, None], frac[:, 1, None, None], frac[:, 2, None]
    if frac.requires_grad:
        return _lerp_corners(volume.reshape(R * R * R, C).index_select(0, rows), fx, fy, fz)
    return _TrilinearInVolume.apply(volume, rows, fx, fy, fz)


def _lerp_corners(corners: torch.Tensor, fx: torch.Tensor, fy: torch.Tensor, fz: torch.Tensor) -> torch.Tensor:
    """(P 8, C) corner features, rows ordered (x, y, z) bits per point -> (P, C) by a lerp along x, y, z."""
    c = corners.reshape(-1, 2, 2, 2, corners.shape[-1])  # c[p, a, b, d] = volume[i + a, j + b, k + d]
    c = torch.lerp(c[:, 0], c[:, 1], fx)  # along x
    c = torch.lerp(c[:, 0], c[:, 1], fy)  # along y
    return torch.lerp(c[:, 0], c[:, 1], fz)  # along z


class _TrilinearInVolume(torch.autograd.Function):
    """:func:`trilinear` for points that carry no gradient, with its backward to the volume written out.

    The forward is the same lerp chain; the backward forms each corner's weight product in the order
    autograd's lerp backward does (z, then y, then x) and adds the (P 8, C) products into the volume
    with one ``index_add_``, so the gradient is the same bit for bit, without autograd's zero-filled
    tensor per sliced corner block and its bookkeeping per op. Not differentiable twice (the points
    are constants here; a second-order loss takes the autograd path of :func:`trilinear`).
    """

    @staticmethod
    def forward(ctx, volume, rows, fx, fy, fz):
        R, C = volume.shape[0], volume.shape[-1]
        ctx.save_for_backward(rows, fx, fy, fz)
        ctx.volume_shape = volume.shape
        return _lerp_corners(volume.reshape(R * R * R, C).index_select(0, rows), fx, fy, fz)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad):
        rows, fx, fy, fz = ctx.saved_tensors
        shape = ctx.volume_shape
        gz = torch.stack([grad * (1 - fz), grad * fz], dim=1)  # (P, 2, C): the two ends of the z lerp
        gy = torch.stack([gz * (1 - fy), gz * fy], dim=1)  # (P, 2, 2, C)
        gx = torch.stack([gy * (1 - fx), gy * fx], dim=1)  # (P, 2, 2, 2, C)
        volume_grad = grad.new_zeros(shape[0] * shape[1] * shape[2], shape[3])
        volume_grad.index_add_(0, rows, gx.reshape(-1, shape[3]))
        return volume_grad.reshape(shape), None, None, None, None


class FeatureGrid(nn.Module):
    """Multi-resolution dense feature grid on the canonical cube [-1, 1]^3.

    Level l is a learnable (R_l, R_l, R_l, C) volume of ``resolutions[l]`` points per axis (the
    cube's faces included), initialised uniform in +-:data:`GRID_INIT_SCALE`. A point's encoding is
    the :func:`trilinear` feature of every level, concatenated coarse to fine: (P, 3) -> (P, L C).
    On the CPU in float32, for points without a gradient, :func:`methods.core.grid_lookup.lookup` computes
    it (the same numbers, one compiled pass per level).

    Parameters
    ----------
    resolutions : points per axis of each level, each >= 2 (e.g. (16, 32, 64)).
    channels : features per grid point, C >= 1.
    """

    def __init__(self, resolutions: Sequence[int], channels: int):
        super().__init__()
        resolutions = tuple(int(r) for r in resolutions)
        if not resolutions or min(resolutions) < 2:
            raise ValueError(f"grid resolutions must be >= 2 points per axis, got {resolutions}")
        if channels < 1:
            raise ValueError(f"grid channels must be >= 1, got {channels}")
        self.resolutions, self.channels = resolutions, int(channels)
        self.levels = nn.ParameterList(
            nn.Parameter(torch.empty(r, r, r, self.channels).uniform_(-GRID_INIT_SCALE, GRID_INIT_SCALE))
            for r in resolutions)

    @property
    def out_dim(self) -> int:
        """Features per point: levels x channels."""
        return len(self.resolutions) * self.channels

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        levels = list(self.levels)
        if grid_lookup.applies(levels, points):
            return grid_lookup.lookup(levels, points)
        return torch.cat([trilinear(level, points) for level in levels], dim=1)


#: Unit of the segment offset v - u fed to the head (canonical units): the length of the near-surface
#: training segments and of a 128^3 grid edge are ~1-2 of it.
SEGMENT_SCALE = 0.01


class GridNetwork(nn.Module):
    """The ``'grid'`` backbone: a :class:`FeatureGrid` then an :class:`MLP` head.

    The input (B, 3 k) holds k points of the canonical cube per sample (k = 1: a point x; k = 2: a
    segment [u, v]). Each point p is encoded by the one grid as ``[enc(p), p]`` (the raw coordinates
    keep the coarse shape and the field outside the cube) and the k codes are concatenated:
    ``head([enc(x), x])`` for points, ``head([enc(u), u, enc(v), v, (v - u) / SEGMENT_SCALE])`` for
    segments. u and v go through the same grid weights in one call, so there is no second encoder.
    The offset is given explicitly because the head cannot resolve it from the raw endpoints: a grid
    edge at 128^3 is 0.016 long between coordinates of size ~1, so without it the network cannot
    tell an edge from the longer training segments around it and predicts their average hit rate
    (docs/PERFORMANCE.md, section 2). Still a function of the segment: swapping u and v swaps the
    two code blocks and negates the offset.

    The head is ``MLP(k (L C + 3), out_dim, depth, width, beta, activation)``, with the MLP's
    near-zero output initialisation; the grid is built first, then the head (this fixes the
    parameter order, hence the weights a seed gives).
    """

    def __init__(self, in_dim: int, out_dim: int, depth: int, width: int, beta: float, activation: str,
                 grid_resolutions: Sequence[int], grid_channels: int):
        super().__init__()
        if in_dim < 3 or in_dim % 3:
            raise ValueError(f"the grid backbone takes points of 3 coordinates (in_dim 3, 6, ...), got in_dim {in_dim}")
        self.encoder = FeatureGrid(grid_resolutions, grid_channels)
        self.k = in_dim // 3
        offset = 3 if self.k == 2 else 0
        self.head = MLP(self.k * (self.encoder.out_dim + 3) + offset, out_dim, depth=depth, width=width, beta=beta,
                        activation=activation)
        self.config = dict(backbone="grid", in_dim=int(in_dim), out_dim=int(out_dim), depth=int(depth),
                           width=int(width), beta=float(beta), activation=activation,
                           grid_resolutions=self.encoder.resolutions, grid_channels=self.encoder.channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.head_input(self.encoder(x.reshape(-1, 3)), x))

    def head_input(self, features: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """The head's input (B, k (L C + 3) [+ 3]) from the grid features of the input's points
        (B k, L C; u and v of a segment on consecutive rows) and the input x (B, 3 k)."""
        codes = torch.cat([features, x.reshape(-1, 3)], dim=1).reshape(x.shape[0], -1)
        if self.k == 2:
            codes = torch.cat([codes, (x[:, 3:] - x[:, :3]) / SEGMENT_SCALE], dim=1)
        return codes


class LODNetwork(nn.Module):
    """The ``'nglod'`` backbone: NGLOD's network (Takikawa et al., CVPR 2021; its dense training
    form, ``OctreeSDF``): one output per level of detail.

    Level l of a :class:`FeatureGrid` (``grid_resolutions[l]`` points per axis, ``grid_channels``
    features, initialised normal with std :data:`LOD_INIT_STD` as NGLOD's feature volumes) is
    interpolated at x; the features are summed over the levels up to l (z_l = sum_{i <= l} f_i(x)),
    and LOD l's own decoder, ``Linear(3 + C, width) -> ReLU -> Linear(width, 1)`` on ``[x, z_l]``,
    gives output l. Inputs (B, 3) -> outputs (B, L): column l is LOD l's field, the last column the
    finest. The decoders' weights are stacked per level (one batched product for all levels) and
    initialised as ``nn.Linear``'s default.
    """

    def __init__(self, in_dim: int, out_dim: int, width: int, grid_resolutions: Sequence[int], grid_channels: int):
        super().__init__()
        if in_dim != 3:
            raise ValueError(f"the nglod backbone takes points (in_dim 3), got in_dim {in_dim}")
        self.encoder = FeatureGrid(grid_resolutions, grid_channels)
        levels, C = len(self.encoder.resolutions), self.encoder.channels
        if out_dim != levels:
            raise ValueError(f"the nglod backbone has one output per level: out_dim {out_dim} for {levels} levels")
        with torch.no_grad():
            for level in self.encoder.levels:
                level.normal_(0.0, LOD_INIT_STD)
        self.hidden_weight = nn.Parameter(_linear_init((levels, 3 + C, width), 3 + C))
        self.hidden_bias = nn.Parameter(_linear_init((levels, 1, width), 3 + C))
        self.output_weight = nn.Parameter(_linear_init((levels, width, 1), width))
        self.output_bias = nn.Parameter(_linear_init((levels, 1, 1), width))
        self.config = dict(backbone="nglod", in_dim=3, out_dim=int(out_dim), width=int(width),
                           grid_resolutions=self.encoder.resolutions, grid_channels=C)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        levels, C = len(self.encoder.resolutions), self.encoder.channels
        summed = self.encoder(x).reshape(-1, levels, C).cumsum(dim=1)  # (B, L, C): z_l
        inputs = torch.cat([x.unsqueeze(0).expand(levels, -1, -1), summed.transpose(0, 1)], dim=2)  # (L, B, 3 + C)
        hidden = torch.relu(torch.baddbmm(self.hidden_bias, inputs, self.hidden_weight))
        return torch.baddbmm(self.output_bias, hidden, self.output_weight)[..., 0].transpose(0, 1)


#: Standard deviation of the initial NGLOD feature volumes (its ``randn * 0.01``).
LOD_INIT_STD = 0.01


def _linear_init(shape: tuple[int, ...], fan_in: int) -> torch.Tensor:
    """Uniform in +-1/sqrt(fan_in): ``nn.Linear``'s default for its weights and biases."""
    bound = 1.0 / fan_in ** 0.5
    return torch.empty(shape).uniform_(-bound, bound)


class StackedNetworks(nn.Module):
    """The ``'stack'`` network: independent member networks side by side on one input, their outputs
    concatenated in member order (a method that fits one network per output, e.g. UODF's one per axis).

    Member k is ``make_network(in_dim, **members[k])`` (each config names its own ``out_dim``; they
    sum to ``out_dim``) applied to the input with the columns ``zeroed[k]`` set to 0, so a member
    can be a function of some coordinates only (e.g. of the line x + t e_a through a point: zero
    column a). No parameter is shared, so under a per-parameter optimizer (AdamW) one fit of the
    stack on the sum of the members' losses is the members' separate fits with the same steps and
    batches. The members are built in order (this fixes the parameter order, hence the weights a
    seed gives). Inputs (B, in_dim) -> outputs (B, out_dim).
    """

    def __init__(self, in_dim: int, out_dim: int, members: Sequence[dict],
                 zeroed: Sequence[Sequence[int]] | None = None):
        super().__init__()
        members = [dict(m) for m in members]
        zeroed = [[] for _ in members] if zeroed is None else [sorted(int(c) for c in z) for z in zeroed]
        if not members or len(zeroed) != len(members):
            raise ValueError(f"a stack needs >= 1 member and one zeroed list per member, got {len(members)} "
                             f"members and {len(zeroed)} lists")
        if sum(int(m["out_dim"]) for m in members) != out_dim:
            raise ValueError(f"the members' out_dim sum to {sum(int(m['out_dim']) for m in members)}, not {out_dim}")
        if any(c < 0 or c >= in_dim for z in zeroed for c in z):
            raise ValueError(f"zeroed columns must lie in [0, {in_dim}), got {zeroed}")
        self.nets = nn.ModuleList(make_network(in_dim, **m) for m in members)
        self.zeroed = zeroed
        self.config = dict(backbone="stack", in_dim=int(in_dim), out_dim=int(out_dim),
                           members=[net.config | {"out_dim": int(m["out_dim"])} for net, m in zip(self.nets, members)],
                           zeroed=zeroed)
        for m in self.config["members"]:
            m.pop("in_dim", None)

    def member_input(self, k: int, x: torch.Tensor) -> torch.Tensor:
        """Member k's input: ``x`` with the columns ``zeroed[k]`` set to 0 (``x`` itself if none)."""
        if not self.zeroed[k]:
            return x
        return x.index_fill(1, torch.tensor(self.zeroed[k], device=x.device), 0.0)

    def member(self, k: int, x: torch.Tensor) -> torch.Tensor:
        """Member k's outputs (B, its out_dim) for the stack's input ``x`` (B, in_dim)."""
        return self.nets[k](self.member_input(k, x))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.member(k, x) for k in range(len(self.nets))], dim=1)


#: Backbone names (the budget's ``backbone``).
BACKBONES = ("mlp", "grid")
#: Every network :func:`make_network` builds: the backbones and the networks of single methods.
NETWORKS = BACKBONES + ("nglod", "stack")


class EndpointSplit(NamedTuple):
    """A segment network (input ``[u, v]``, 6 values) cut after its first linear layer, whose
    pre-activation is a sum of one term per endpoint (see :func:`endpoint_split`); for inference.

    ``terms(points) -> (A, B)``: (P, W) each, for points (P, 3); ``tail(A[i] + B[j])`` is the
    network's output for the segment (points[i], points[j]).
    """

    terms: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]
    tail: nn.Module


def endpoint_split(model: nn.Module) -> EndpointSplit | None:
    """The network of a segment field split by endpoint, so that points shared by many segments
    (the grid points of the edges E-DC queries: each is an endpoint of up to 6 edges) are encoded
    once; None for any model this module does not build, or a points network. For inference: the
    terms do not carry gradients to the weights.

    Both backbones' segment networks start with a linear layer over per-endpoint blocks:

    * :class:`MLP` (in_dim 6): ``W [u, v] + b = (W_u u + b) + W_v v``.
    * :class:`GridNetwork` (k = 2): ``W [c(u), c(v), (v - u) / S] + b`` with ``c(p) = [enc(p), p]``
      equals ``(W_u c(u) - W_o u / S + b) + (W_v c(v) + W_o v / S)``: the offset's block ``W_o``
      folds into the blocks of the raw coordinates.

    So ``A(p)`` = the first term at ``p``, ``B(p)`` = the second (both from one product of the code
    with the two blocks side by side), and ``tail`` is every layer after the first. The same
    function as the network's forward, up to float rounding (the sums are ordered differently).
    """
    if isinstance(model, MLP) and model.config["in_dim"] == 6:
        first, tail, encode = model.layers[0], model.layers[1:], None
        with torch.no_grad():
            blocks = [first.weight[:, :3], first.weight[:, 3:]]
    elif isinstance(model, GridNetwork) and model.k == 2:
        first, tail, encode = model.head.layers[0], model.head.layers[1:], model.encoder
        d = model.encoder.out_dim + 3
        with torch.no_grad():
            W = first.weight
            offset = W[:, 2 * d:] / SEGMENT_SCALE  # rows of the raw coordinates get -/+ the offset's block
            blocks = [torch.cat([W[:, :d - 3], W[:, d - 3:d] - offset], dim=1),
                      torch.cat([W[:, d:2 * d - 3], W[:, 2 * d - 3:2 * d] + offset], dim=1)]
    else:
        return None
    with torch.no_grad():
        weight = torch.cat(blocks, dim=0).T.contiguous()  # (code size, 2 W): A's block, then B's
        bias = torch.cat([first.bias, torch.zeros_like(first.bias)])
    width = first.out_features

    def terms(points):
        codes = points if encode is None else torch.cat([encode(points), points], dim=1)
        both = torch.addmm(bias, codes, weight)
        return both[:, :width], both[:, width:]

    return EndpointSplit(terms, tail)


def value_and_input_gradient(model: nn.Module, x: torch.Tensor, output_index: int = 0,
                              create_graph: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
    """A network's outputs and the gradient of one output with respect to its input:
    ``(model(x) (B, out_dim), d model(x)[:, output_index] / dx (B, in_dim))``.
    :func:`value_and_input_gradients` of the one output."""
    out, grads = value_and_input_gradients(model, x, (output_index,), create_graph)
    return out, grads[0]


def value_and_input_gradients(model: nn.Module, x: torch.Tensor, output_indices: Sequence[int],
                               create_graph: bool = True) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """A network's outputs and the gradients of some of its outputs with respect to its input, from
    one evaluation of the network.

    Parameters
    ----------
    model : a network taking (B, in_dim) inputs (points, segments, ...).
    x : (B, in_dim) inputs (their own ``requires_grad`` is not used).
    output_indices : the outputs whose gradients are returned, in this order.
    create_graph : keep the gradients differentiable in the weights (a loss on them, as UDF's).

    Returns
    -------
    ``(model(x) (B, out_dim), [d model(x)[:, i] / dx (B, in_dim) for i in output_indices])``.

    A :class:`GridNetwork` on the CPU in float32 takes the grid's derivative from
    :func:`methods.core.grid_lookup.lookup_with_jacobian` (the features and their Jacobian in one pass,
    linear in the grid values) and differentiates only the head, by the chain rule: for each
    point p of the input, ``d f / dp = (d f / d enc(p)) (d enc(p) / dp) + d f / d[raw p]`` (a
    segment's offset ``(v - u) / SEGMENT_SCALE`` adds its block to v's and subtracts it from u's),
    without the second-order autograd graph of the grid lookup; the one lookup serves every output.
    A Softplus :class:`MLP` (the head, or the whole network) is differentiated by
    :mod:`methods.core.head_gradient`, whose backward is written out; any other network by
    autograd. All agree to float32 rounding.
    """
    if isinstance(model, GridNetwork):
        levels = list(model.encoder.levels)
        points = x.reshape(-1, 3)
        if grid_lookup.applies(levels, points):
            features, jacobian = grid_lookup.lookup_with_jacobian(levels, points)
            if not create_graph:
                jacobian = jacobian.detach()
            out, head_grads = _mlp_value_and_input_gradients(model.head, model.head_input(features, x),
                                                             output_indices, create_graph)
            n, k = features.shape[1], model.k
            grads = []
            for d_in in head_grads:
                d_points = d_in[:, :k * (n + 3)].reshape(-1, n + 3)  # (B k, L C + 3): per point, its code and p
                grad = (grid_lookup.jacobian_transpose_product(jacobian, d_points[:, :n]) + d_points[:, n:]).reshape(x.shape)
                if k == 2:
                    d_offset = d_in[:, k * (n + 3):] / SEGMENT_SCALE
                    grad = grad + torch.cat([-d_offset, d_offset], dim=1)
                grads.append(grad)
            return out, grads
    return _mlp_value_and_input_gradients(model, x.detach(), output_indices, create_graph)


def _mlp_value_and_input_gradients(model: nn.Module, x: torch.Tensor, output_indices: Sequence[int],
                                   create_graph: bool) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """``model(x)`` and the gradients of some outputs in ``x``: for a Softplus :class:`MLP`,
    :func:`methods.core.head_gradient.value_and_input_gradients` (the second-order backward written
    out); otherwise autograd (``create_graph`` for a loss on the gradients)."""
    if _softplus_mlp(model):
        linear = [m for m in model.layers if isinstance(m, nn.Linear)]
        out, grads = head_gradient.value_and_input_gradients([m.weight for m in linear], [m.bias for m in linear],
                                                             model.config["beta"], x, output_indices)
        return out, grads if create_graph else [g.detach() for g in grads]
    if not x.requires_grad:
        x = x.detach().requires_grad_(True)
    out = model(x)
    last = len(output_indices) - 1
    grads = [torch.autograd.grad(out[:, index].sum(), x, create_graph=create_graph,
                                 retain_graph=create_graph or j < last)[0]
             for j, index in enumerate(output_indices)]
    return out, grads


def _softplus_mlp(model: nn.Module) -> bool:
    """An :class:`MLP` whose activations are Softplus with torch's threshold (torch's or the clamped kernel)."""
    return isinstance(model, MLP) and model.config["activation"] in ("softplus", "softplus-clamped") \
        and THRESHOLD == head_gradient.SOFTPLUS_THRESHOLD


def make_network(in_dim: int, out_dim: int, depth: int = 9, width: int = 512, beta: float = 100.0,
                 activation: str = "softplus", backbone: str = "mlp",
                 grid_resolutions: Sequence[int] | None = None, grid_channels: int | None = None,
                 members: Sequence[dict] | None = None, zeroed: Sequence[Sequence[int]] | None = None) -> nn.Module:
    """The network a budget names (defaults = *paper*: the paper's 9 x 512 Softplus(100) MLP).

    Parameters
    ----------
    in_dim, out_dim : input size (3: points, 6: segments) and output size.
    depth, width, beta, activation : the MLP (``'mlp'``) or the grid backbone's head (``'grid'``).
    backbone : ``'mlp'`` (:class:`MLP`), ``'grid'`` (:class:`GridNetwork`) or ``'nglod'``
        (:class:`LODNetwork`: ``width`` its decoders' hidden width; depth, beta and activation unused).
    grid_resolutions, grid_channels : the :class:`FeatureGrid` (``'grid'`` and ``'nglod'``; required
        there, refused for ``'mlp'``).
    members, zeroed : the ``'stack'`` network (:class:`StackedNetworks`: each member's own keyword
        arguments, its ``out_dim`` included, and its zeroed input columns; depth, width, beta,
        activation and the grid settings unused); refused for the other networks.

    ``make_network(**model.config)`` rebuilds any network made here (a config without ``backbone``,
    as every MLP's, is an MLP).
    """
    if backbone not in NETWORKS:
        raise ValueError(f"unknown backbone '{backbone}'; known: {', '.join(NETWORKS)}")
    if backbone == "stack":
        if members is None:
            raise ValueError("the 'stack' network needs members")
        return StackedNetworks(in_dim, out_dim, members, zeroed)
    if members is not None or zeroed is not None:
        raise ValueError(f"members/zeroed are settings of the 'stack' network, not of '{backbone}'")
    grid_given = grid_resolutions is not None or grid_channels is not None
    if backbone == "mlp":
        if grid_given:
            raise ValueError("grid_resolutions/grid_channels are settings of the 'grid' backbone, not of 'mlp'")
        return MLP(in_dim, out_dim, depth=depth, width=width, beta=beta, activation=activation)
    if grid_resolutions is None or grid_channels is None:
        raise ValueError(f"the '{backbone}' backbone needs grid_resolutions and grid_channels")
    if backbone == "nglod":
        return LODNetwork(in_dim, out_dim, width, grid_resolutions, grid_channels)
    return GridNetwork(in_dim, out_dim, depth, width, beta, activation, grid_resolutions, grid_channels)
