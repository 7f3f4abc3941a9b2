"""The MLP every method fits (SPEC section 5) and a denormal-free, value-identical Softplus(beta).

*paper* network: 9 linear layers of width 512 (input -> 512, 7 x (512 -> 512), 512 -> out),
Softplus(beta = 100) after every layer but the last, no positional encoding. ``depth`` counts the
linear layers; ``width`` is the hidden width.

Clamped Softplus
----------------
``softplus_beta(x) = log(1 + exp(beta x)) / beta``. torch's kernel evaluates ``exp(beta x)`` for all x,
which underflows to denormal floats wherever ``beta x < -87`` (slow on x86) and its backward does the
same. The identity used here::

    softplus_beta(x) = relu(x) + log1p(exp(-beta |x|)) / beta

has an exponent argument <= 0 and we clamp it to ``>= -CLAMP`` (``CLAMP = 30``): the dropped term is
below ``log1p(exp(-30)) / beta = 9.4e-14 / beta``, so values equal torch's to ~1e-13 (float64) or to
float32 rounding. The derivative ``sigmoid(beta x)`` is evaluated on ``beta x`` clamped to
``[-CLAMP, CLAMP]`` (error < 1e-13). The backward is written with differentiable torch ops, so second
derivatives (``create_graph=True``, needed by the UDF gradient loss) work.
"""

from __future__ import annotations

import torch
from torch import nn

#: Clamp of the exponent argument |beta x| (see module docstring).
CLAMP = 30.0
#: torch's default linear-regime threshold of beta x (softplus(x) = x above it; error < 2e-9 / beta).
THRESHOLD = 20.0
#: Scale of the output layer's default initial weights (bias 0): outputs start near 0.
OUTPUT_INIT_SCALE = 0.01


class _FastSoftplus(torch.autograd.Function):
    """torch's softplus kernels on x clamped to >= -CLAMP / beta (no denormal exp(beta x))."""

    @staticmethod
    def forward(ctx, x, beta: float):
        ctx.save_for_backward(x)
        ctx.beta = beta
        return torch.nn.functional.softplus(x.clamp(min=-CLAMP / beta), beta, THRESHOLD)

    @staticmethod
    def backward(ctx, grad):
        (x,) = ctx.saved_tensors
        # Differentiable ops (not once_differentiable): under create_graph the double backward goes
        # through aten's softplus_backward derivative and the clamp.
        xc = x.clamp(min=-CLAMP / ctx.beta)
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


#: Activation names. ``'softplus'`` (default) is torch's kernel: on this project's 2-core AMD EPYC
#: machines it measured as fast as or faster than the clamped form (benchmarks/bench_network.py;
#: no denormal penalty showed up there). ``'softplus-clamped'`` gives the same values with no
#: denormal exp, for CPUs where torch's kernel hits the slow path.
ACTIVATIONS = {
    "softplus": lambda beta: nn.Softplus(beta=beta),
    "softplus-clamped": lambda beta: FastSoftplus(beta),
    "relu": lambda beta: nn.ReLU(),
}


class MLP(nn.Module):
    """Plain MLP: ``depth`` linear layers (``depth >= 2``), hidden ``width``, activation after every
    layer but the last, no positional encoding. Inputs (B, in_dim) -> outputs (B, out_dim).

    Initialisation: torch's default for every layer, except the output layer, whose weights are
    scaled by ``OUTPUT_INIT_SCALE`` (0.01) and bias zeroed, so every method starts from outputs ~0
    (SDF/UDF 0 inside their +-0.1 loss clamps, where a clamped prediction has a gradient; occupancy
    and SALS probabilities 0.5). SPEC section 5 does not fix an initialisation.
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
        return self.layers(x)


def make_network(in_dim: int, out_dim: int, depth: int = 9, width: int = 512, beta: float = 100.0,
                 activation: str = "softplus") -> MLP:
    """The network of SPEC section 5 (defaults = *paper*: 9 layers, width 512, Softplus(100))."""
    return MLP(in_dim, out_dim, depth=depth, width=width, beta=beta, activation=activation)
