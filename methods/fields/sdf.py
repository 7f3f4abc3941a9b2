"""``sdf``: neural signed distance field + marching cubes at level 0.

Network x (3) -> f(x), the signed distance (negative inside). Target: ``ExactFields.sdf`` (UDF
signed by the winding number; on open meshes the |w| = 0.5 membranes are kept: the expected
failure of signed fields). Loss: ``mean |clamp(f, -0.1, 0.1) - clamp(d, -0.1, 0.1)|``.
Extraction: marching cubes at ``level`` (0) with inside = low values, faces outward.
Oracle: the exact narrow-band SDF on the grid (``foundation.fields``, |d| clamped to the band).
Neural: the sparse query of :mod:`methods.core.query` with the criterion "corners straddle 0 or
min |f| < sqrt(3) S h / 2"; far points hold the trilinear upsampling of the coarse values.
"""

from __future__ import annotations

import numpy as np

from foundation.grid import spacing
from foundation.params import Param
from methods.core import query
from methods.base import Extraction, FieldMethod, register_method, signed_hybrid, wrong_side_points
from methods.extractors.marching_cubes import marching_cubes_grid

#: Loss clamp of the signed distance, canonical units.
DISTANCE_CLAMP = 0.1


@register_method(order=20, color="#3a7fc1")
class SDFMethod(FieldMethod):
    name = "sdf"
    description = "neural signed distance field + marching cubes at level 0"
    input_kind = "points"
    output_dim = 1
    extractor = "marching cubes"
    components = ("sign", "magnitude")
    parameters = {
        "level": Param(0.0, "iso level of marching cubes (canonical units)", gt=-DISTANCE_CLAMP, lt=DISTANCE_CLAMP),
        "stride": Param(query.DEFAULT_STRIDE, "coarse stride of the sparse query", ge=1, neural_only=True),
    }

    @property
    def level(self) -> float:
        """The extracted level of the signed distance (canonical units)."""
        return self.params["level"]

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        return {"sdf": fields.sdf(samples.points).astype(np.float32)}

    def loss(self, prediction, targets):
        return (prediction[:, 0].clamp(-DISTANCE_CLAMP, DISTANCE_CLAMP) - targets["sdf"].clamp(-DISTANCE_CLAMP, DISTANCE_CLAMP)).abs().mean()

    def oracle_grid(self, fields, N, cache):
        return cache.get(fields, N, "sdf"), {}

    def neural_grid(self, model, N, device=None):
        near = query.near_level(self.level, query.block_half_diagonal(N, self.params["stride"]))
        values, _, info = query.sparse_grid_points(model, N, near, device, stride=self.params["stride"])
        return values[..., 0], {"query_fraction": info.fraction}

    def hybrid_grid(self, fitted, exact, exact_parts, model, N, device=None):
        return signed_hybrid(exact if "sign" in exact_parts else fitted,
                             exact if "magnitude" in exact_parts else fitted, self.level)

    def component_errors(self, fitted, exact, N):
        h = spacing(N)
        band = np.abs(exact) < 2.0 * h
        return {"wrong_side_points": wrong_side_points(fitted, exact, self.level),
                "sdf_error_h": float(np.abs(fitted[band] - exact[band]).mean() / h) if band.any() else np.nan}

    def extract(self, grid_field, N) -> Extraction:
        return marching_cubes_grid(np.asarray(grid_field), level=self.level, inside="low")
