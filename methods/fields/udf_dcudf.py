"""``udf-dcudf``: the ``udf`` method's unsigned distance field extracted by DCUDF.

The field is the ``udf`` method's: the same targets and loss, and in neural mode the same fitted
network (``fit_of = 'udf'``). Extraction: :mod:`methods.extractors.dcudf` (marching cubes of the grid UDF at a
small level r, the double cover; its vertices optimised toward d = 0; a min-cut keeps one of its two
sheets). Oracle: the exact narrow-band UDF on the grid and the exact UDF with its unit gradient
``(x - c) / |x - c|`` at the moving vertices and face centroids. Neural: the sparse query of the UDF
on the grid, then d = max(f, 0) and its autograd gradient (0 where f <= 0) at the moving points, as
the authors differentiate their network.
"""

from __future__ import annotations

import numpy as np

from foundation.params import Param
from methods.core import query
from methods.base import Extraction, register_method
from methods.extractors.dcudf import AUTHORS_ITERATIONS, REGION_RATE, authors_r, dcudf
from methods.core.device import get_device
from methods.fields.udf import UDFMethod

#: Optimisation iterations by default, a tenth of the authors' 400: each iteration queries the UDF at
#: every vertex and face centroid (their cost on one CPU core: docs/PROTOCOL.md, ``udf-dcudf``).
#: With fewer iterations the learning rate grows in proportion (:func:`methods.extractors.dcudf.authors_lr`).
CPU_ITERATIONS = 40


def network_udf_and_raw_gradient(model, points: np.ndarray, device=None) -> tuple[np.ndarray, np.ndarray]:
    """max(f, 0) (P,) and its input gradient (P, 3): the network's autograd gradient, not normalised,
    0 where f <= 0."""
    out, g = query.evaluate_with_input_grad(model, np.asarray(points, dtype=np.float32), 0, device)
    positive = out[:, 0] > 0
    return np.maximum(out[:, 0], 0.0), np.where(positive[:, None], g, 0.0)


@register_method(order=37, color="#8c6d31")
class UDFDCUDFMethod(UDFMethod):
    name = "udf-dcudf"
    description = "the udf method's field + DCUDF (double cover at a small level, optimised to d = 0, min-cut)"
    extractor = "DCUDF"
    fit_of = "udf"
    components = ()
    parameters = {
        "r": Param(None, "level of the double cover, canonical units (None: the authors' 0.005 x 256 / N in "
                         "their frame, x 1.99 here)", kind=float, optional=True, gt=0),
        "iterations": Param(CPU_ITERATIONS, f"vertex optimisation iterations (the authors': {AUTHORS_ITERATIONS})", ge=1),
        "normal_step": Param(None, "end of the Laplacian stage (None: 3/4 of the iterations, the authors' 300 of 400)",
                             kind=int, optional=True, ge=0),
        "laplacian_weight": Param(None, "Laplacian weight (None: the authors' 2000 x N / 256 in their frame, / 1.99 here)",
                                  kind=float, optional=True, ge=0),
        "cut": Param(True, "min-cut the double cover into one sheet (the authors' is_cut)"),
        "region_rate": Param(REGION_RATE, "the cut's seed and sink regions have faces / region_rate faces", gt=1),
        "cut_seed": Param(0, "seed of the cut's random seed faces", ge=0),
        "stride": Param(query.DEFAULT_STRIDE, "coarse stride of the sparse query", ge=1, neural_only=True),
    }

    def oracle_grid(self, fields, N, cache):
        d, _ = cache.get(fields, N, "udf_grad")
        return {"udf": d, "udf_grad_at": lambda p: fields.udf(p, return_grad=True), "udf_at": fields.udf,
                "device": get_device()}, {}

    def neural_grid(self, model, N, device=None):
        stride = self.params["stride"]
        values, _, info = query.sparse_grid_points(model, N, query.near_below(query.block_half_diagonal(N, stride)),
                                                   device, stride=stride)
        return ({"udf": np.maximum(values[..., 0], 0.0),
                 "udf_grad_at": lambda points: network_udf_and_raw_gradient(model, points, device),
                 "udf_at": query.network_udf(model, device), "device": get_device(device)},
                {"query_fraction": info.fraction})

    def extract(self, grid_field, N) -> Extraction:
        p = self.params
        return dcudf(grid_field["udf"], grid_field["udf_grad_at"], grid_field["udf_at"],
                     r=authors_r(N) if p["r"] is None else p["r"], iterations=p["iterations"],
                     normal_step=p["normal_step"], laplacian_weight=p["laplacian_weight"],
                     cut=p["cut"], region_rate=p["region_rate"], seed=p["cut_seed"],
                     device=grid_field.get("device"))
