"""``bof``: neural binary occupancy field + marching cubes at probability 0.5.

Network x (3) -> occupancy logit l(x); probability sigmoid(l). Target: ``ExactFields.occupancy``
(|winding number| > 0.5), as 0/1. Loss: binary cross-entropy with logits.
Extraction: marching cubes on the probability at ``level`` (0.5) with inside = high values, faces
flipped to point outward (``methods.extractors.marching_cubes``).
Oracle: the exact occupancy on the grid as 0/1 (marching cubes then puts vertices at edge midpoints).
Neural: the sparse query of :mod:`methods.core.query`; criterion "corner logits straddle 0 or some corner
probability is in (eps, 1 - eps)" with eps = ``near_eps`` (0.01); far points hold the trilinear
upsampling of the coarse logits.
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit
import torch.nn.functional as F

from foundation.params import Param
from methods.core import query
from methods.base import Extraction, FieldMethod, register_method, signed_hybrid, wrong_side_points
from methods.extractors.marching_cubes import marching_cubes_grid


@register_method(order=10, color="#29a37a")
class BOFMethod(FieldMethod):
    name = "bof"
    description = "neural binary occupancy field + marching cubes at probability 0.5"
    input_kind = "points"
    output_dim = 1
    extractor = "marching cubes"
    components = ("sign", "magnitude")
    parameters = {
        "level": Param(0.5, "occupancy probability of the extracted level set", gt=0, lt=1),
        "near_eps": Param(0.01, "blocks with a corner probability in (eps, 1 - eps) are queried finely",
                          gt=0, lt=0.5, neural_only=True),
        "stride": Param(query.DEFAULT_STRIDE, "coarse stride of the sparse query", ge=1, neural_only=True),
    }

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        return {"occupancy": fields.occupancy(samples.points).astype(np.float32)}

    def loss(self, prediction, targets):
        return F.binary_cross_entropy_with_logits(prediction[:, 0], targets["occupancy"])

    def oracle_grid(self, fields, N, cache):
        return cache.get(fields, N, "occupancy").astype(np.float32), {}

    def neural_grid(self, model, N, device=None):
        level = float(np.log(self.params["level"] / (1.0 - self.params["level"])))  # logit of the level
        eps = self.params["near_eps"]
        near = query.near_level(level, float(np.log((1.0 - eps) / eps)))
        logits, _, info = query.sparse_grid_points(model, N, near, device, stride=self.params["stride"])
        prob = expit(logits[..., 0].astype(np.float64))
        return prob.astype(np.float32), {"query_fraction": info.fraction}

    def hybrid_grid(self, fitted, exact, exact_parts, model, N, device=None):
        hybrid = signed_hybrid(exact if "sign" in exact_parts else fitted,
                               exact if "magnitude" in exact_parts else fitted, self.params["level"])
        return np.clip(hybrid, 0.0, 1.0)

    def component_errors(self, fitted, exact, N):
        return {"wrong_side_points": wrong_side_points(fitted, exact, self.params["level"])}

    def extract(self, grid_field, N) -> Extraction:
        return marching_cubes_grid(np.asarray(grid_field), level=self.params["level"], inside="high")
