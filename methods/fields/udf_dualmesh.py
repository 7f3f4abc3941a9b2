"""``udf-dualmesh``: the ``udf`` method's unsigned distance field extracted by DualMesh-UDF.

The field is the ``udf`` method's: the same targets and loss, and in neural mode the same fitted
network (``fit_of = 'udf'``). Extraction: :mod:`methods.extractors.dualmesh` (tangent-plane QEFs on each leaf's
3 x 3 x 3 samples, a quad per grid edge with four dual vertices, the authors' quad validation).
Oracle: the exact narrow-band UDF on the grid (to choose the leaves) and the exact UDF with its unit
gradient ``(x - c) / |x - c|`` at the samples. Neural: the sparse query of the UDF on the grid, then
the network and its normalised autograd gradient at the samples (d = max(f, 0)).
"""

from __future__ import annotations

import numpy as np

from foundation.params import Param
from methods.core import query
from methods.base import Extraction, register_method
from methods.extractors.dualmesh import dualmesh_udf
from methods.fields.udf import UDFMethod


@register_method(order=35, color="#c1633a")
class UDFDualMeshMethod(UDFMethod):
    name = "udf-dualmesh"
    description = "the udf method's field + DualMesh-UDF (octree-free dual contouring with tangent-plane QEFs)"
    extractor = "DualMesh-UDF"
    fit_of = "udf"
    components = ()
    parameters = {
        "stride": Param(query.DEFAULT_STRIDE, "coarse stride of the sparse query", ge=1, neural_only=True),
    }

    def oracle_grid(self, fields, N, cache):
        d, _ = cache.get(fields, N, "udf_grad")
        return {"udf": d, "udf_grad_at": lambda p: fields.udf(p, return_grad=True), "udf_at": fields.udf}, {}

    def neural_grid(self, model, N, device=None):
        stride = self.params["stride"]
        values, _, info = query.sparse_grid_points(model, N, query.near_below(query.block_half_diagonal(N, stride)),
                                                   device, stride=stride)
        return ({"udf": np.maximum(values[..., 0], 0.0),
                 "udf_grad_at": lambda points: query.network_udf_and_gradient(model, points, device),
                 "udf_at": query.network_udf(model, device)},
                {"query_fraction": info.fraction})

    def extract(self, grid_field, N) -> Extraction:
        return dualmesh_udf(grid_field["udf"], grid_field["udf_grad_at"], grid_field["udf_at"])
