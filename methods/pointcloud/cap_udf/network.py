"""CAP-UDF's network (Zhou et al., NeurIPS 2022 / TPAMI 2024): an MLP to an unsigned distance.

``dims = [3] + [width] * hidden_layers + [1]`` linear layers (the authors: 8 hidden layers of 256,
9 linear layers), ReLU after each but the last, the input concatenated back before layer ``skip``
(4) with the sum scaled by 1/sqrt(2) (the layer before it outputs ``width - 3`` so the concatenation
has ``width`` values), weight normalisation on every layer, geometric initialisation (SAL/IGR: the
hidden weights N(0, sqrt(2 / out)), biases 0, the last layer's weights N(sqrt(pi / width), 1e-4) and
bias -``init_radius``, so the first output is about |x| - r, a sphere of radius r = 0.5), and the
output is ``|x|``: an unsigned distance in the authors' frame (the cloud's bounding box centred with
its largest side 1).

:func:`udf_and_gradient` returns f and grad f (autograd, ``create_graph`` when the result is
differentiated again, as in the fit); :func:`pull` moves queries to ``x - f(x) grad f / |grad f|``.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["WeightNormLinear", "CAPUDFNetwork", "udf_and_gradient", "pull"]


class WeightNormLinear(nn.Module):
    """A linear layer with weight normalisation (Salimans & Kingma 2016): ``W = g v / |v|`` per
    output row; ``g`` starts at the row norms of the initial weights, so the layer starts as the
    plain linear layer with those weights."""

    def __init__(self, weight: torch.Tensor, bias: torch.Tensor):
        super().__init__()
        self.v = nn.Parameter(weight.detach().clone())
        self.g = nn.Parameter(weight.detach().norm(dim=1))
        self.bias = nn.Parameter(bias.detach().clone())

    def weight(self) -> torch.Tensor:
        return self.v * (self.g / self.v.norm(dim=1)).unsqueeze(1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.linear(x, self.weight(), self.bias)


class CAPUDFNetwork(nn.Module):
    """The UDF MLP of the module docstring. Input (B, 3) points in the authors' frame, output (B, 1)
    distances >= 0 in the same units.

    Parameters
    ----------
    width : hidden width (256).
    hidden_layers : number of hidden layers (8); there are ``hidden_layers + 1`` linear layers.
    skip : index of the linear layer whose input is ``[hidden, x] / sqrt(2)`` (4); None: no skip.
    init_radius : radius of the sphere the geometric initialisation starts from (0.5).
    """

    def __init__(self, width: int = 256, hidden_layers: int = 8, skip: int | None = 4, init_radius: float = 0.5):
        super().__init__()
        if skip is not None and not 1 <= skip <= hidden_layers:
            raise ValueError(f"skip must be a layer index in [1, {hidden_layers}], got {skip}")
        self.width, self.hidden_layers, self.skip = int(width), int(hidden_layers), skip
        dims = [3] + [self.width] * self.hidden_layers + [1]
        layers = []
        for l in range(len(dims) - 1):
            out_dim = dims[l + 1] - dims[0] if skip is not None and l + 1 == skip else dims[l + 1]
            if l == len(dims) - 2:
                weight = torch.randn(out_dim, dims[l]) * 1e-4 + math.sqrt(math.pi) / math.sqrt(dims[l])
                bias = torch.full((out_dim,), -float(init_radius))
            else:
                weight = torch.randn(out_dim, dims[l]) * (math.sqrt(2.0) / math.sqrt(out_dim))
                bias = torch.zeros(out_dim)
            layers.append(WeightNormLinear(weight, bias))
        self.layers = nn.ModuleList(layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = x
        last = len(self.layers) - 1
        for l, layer in enumerate(self.layers):
            if l == self.skip:
                h = torch.cat([h, x], dim=1) / math.sqrt(2.0)
            h = layer(h)
            if l < last:
                h = torch.relu(h)
        return h.abs()


def udf_and_gradient(model: nn.Module, x: torch.Tensor, create_graph: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """The network's distances (B,) at ``x`` (B, 3) and their input gradients (B, 3) (autograd;
    ``create_graph=True`` keeps the graph so a loss of the gradient can be differentiated)."""
    x = x.detach().requires_grad_(True)
    with torch.enable_grad():
        d = model(x)[:, 0]
        (g,) = torch.autograd.grad(d.sum(), x, create_graph=create_graph)
    return d, g


def pull(model: nn.Module, x: torch.Tensor, create_graph: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Queries ``x`` (B, 3) moved along the normalised negative gradient by their distance:
    ``x' = x - f(x) grad f / |grad f|`` (B, 3), and ``f(x)`` (B,)."""
    d, g = udf_and_gradient(model, x, create_graph=create_graph)
    return x - F.normalize(g, dim=1) * d.unsqueeze(1), d
