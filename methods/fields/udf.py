"""``udf``: neural unsigned distance field + MeshUDF-style extraction.

Network x (3) -> f(x), the unsigned distance (raw output; the grid and ``udf_at`` read max(f, 0)).
Targets: ``ExactFields.udf(x, return_grad=True)``: d and the exact unit gradient g = (x - c)/|x - c|.
Loss::

    mean |min(f, 0.1) - min(d, 0.1)|  +  0.1 * mean_{d < 0.1, g != 0} (1 - cos(grad_x f, g))

(``grad_x f`` differentiable in the weights, :func:`methods.core.network.value_and_input_gradient`, from
:meth:`UDFMethod.predict`).
Extraction: :func:`methods.extractors.meshudf.meshudf_marching_cubes` on (d, unit gradient) with the
vertex UDF for the face filter read from the continuous field (``udf_at``: the network, or the exact
UDF in oracle mode) when ``vertex_udf='field'`` (default), else MeshUDF's first-order estimate.
Oracle: exact narrow-band UDF + exact gradient on the grid (``foundation.fields``).
Neural: sparse query of f (criterion: some block corner has f < sqrt(3) S h / 2; far points hold the
trilinear upsampling of the coarse values), then the autograd gradient only where f < 2 h,
normalised; 0 elsewhere.
"""

from __future__ import annotations

import numpy as np
import torch.nn.functional as F

from foundation.grid import point_inputs, spacing
from foundation.params import Param
from foundation.timing import stage
from methods.core import query
from methods.base import Extraction, FieldMethod, median_angle_deg, register_method
from methods.core.network import value_and_input_gradient
from methods.extractors.meshudf import meshudf_marching_cubes

#: Loss clamp of the distance, canonical units.
DISTANCE_CLAMP = 0.1
#: Weight of the gradient-direction term.
GRAD_WEIGHT = 0.1


@register_method(order=30, color="#f2a541")
class UDFMethod(FieldMethod):
    name = "udf"
    description = "neural unsigned distance field + MeshUDF-style extraction"
    input_kind = "points"
    output_dim = 1
    extractor = "MeshUDF"
    components = ("values", "gradients")
    parameters = {
        "face_filter": Param(1.0 / 6.0, "faces whose largest vertex UDF is >= this x h are removed", gt=0),
        "mean_factor": Param(1.05, "candidate cubes: mean corner UDF < this x h", gt=0),
        "max_factor": Param(1.74, "candidate cubes: max corner UDF <= this x h", gt=0),
        "sign_rule": Param("hybrid", "pseudo-sign rule of a cube's corners", choices=("hybrid", "anchor")),
        "vertex_udf": Param("field", "vertex UDF of the face filter: the continuous field or MeshUDF's estimate",
                            choices=("field", "estimate")),
        "stride": Param(query.DEFAULT_STRIDE, "coarse stride of the sparse query", ge=1, neural_only=True),
    }

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        d, g = fields.udf(samples.points, return_grad=True)
        return {"udf": d.astype(np.float32), "grad": g.astype(np.float32)}

    def predict(self, model, inputs):
        """(f (B, 1), grad_x f (B, 3)), the gradient differentiable in the weights."""
        return value_and_input_gradient(model, inputs)

    def loss(self, prediction, targets):
        values, grad_f = prediction
        f = values[:, 0]
        d = targets["udf"]
        l1 = (f.clamp(max=DISTANCE_CLAMP) - d.clamp(max=DISTANCE_CLAMP)).abs().mean()
        g = targets["grad"]
        band = ((d < DISTANCE_CLAMP) & (g.abs().sum(dim=1) > 0)).float()
        cos = F.cosine_similarity(grad_f, g, dim=1, eps=1e-8)
        return l1 + GRAD_WEIGHT * ((1.0 - cos) * band).sum() / band.sum().clamp(min=1.0)

    def oracle_grid(self, fields, N, cache):
        d, g = cache.get(fields, N, "udf_grad")
        return {"udf": d, "grad": g, "udf_at": fields.udf}, {}

    def neural_grid(self, model, N, device=None):
        stride = self.params["stride"]
        near = query.near_below(query.block_half_diagonal(N, stride))
        with stage("values"):
            values, _, info = query.sparse_grid_points(model, N, near, device, stride=stride)
            d = np.maximum(values[..., 0], 0.0)
        with stage("grad"):
            grad = np.zeros(d.shape + (3,), dtype=np.float32)
            ijk = np.argwhere(d < 2.0 * spacing(N))
            if len(ijk):
                grad[tuple(ijk.T)] = query.network_udf_and_gradient(model, point_inputs(N, ijk), device)[1]
        return {"udf": d, "grad": grad, "udf_at": query.network_udf(model, device)}, {"query_fraction": info.fraction}

    def hybrid_grid(self, fitted, exact, exact_parts, model, N, device=None):
        source = exact if "values" in exact_parts else fitted
        if "gradients" in exact_parts:
            grad = exact["grad"]
        else:  # the network's gradients where these values need them (band < 2h) and it has none yet
            grad = fitted["grad"].copy()
            ijk = np.argwhere((source["udf"] < 2.0 * spacing(N)) & (fitted["udf"] >= 2.0 * spacing(N)))
            if len(ijk):
                grad[tuple(ijk.T)] = query.network_udf_and_gradient(model, point_inputs(N, ijk), device)[1]
        return {"udf": source["udf"], "grad": grad, "udf_at": source["udf_at"]}

    def component_errors(self, fitted, exact, N):
        h = spacing(N)
        band = exact["udf"] < 2.0 * h
        if not band.any():
            return {"udf_error_h": np.nan, "gradient_error_deg": np.nan}
        return {"udf_error_h": float(np.abs(fitted["udf"][band] - exact["udf"][band]).mean() / h),
                "gradient_error_deg": median_angle_deg(fitted["grad"][band], exact["grad"][band], oriented=True)}

    def extract(self, grid_field, N) -> Extraction:
        udf_at = grid_field.get("udf_at") if self.params["vertex_udf"] == "field" else None
        return meshudf_marching_cubes(grid_field["udf"], grid_field["grad"], udf_at=udf_at,
                                      mean_factor=self.params["mean_factor"], max_factor=self.params["max_factor"],
                                      face_factor=self.params["face_filter"], sign_rule=self.params["sign_rule"])
