"""``udf-ndc``: the ``udf`` method's unsigned distance field extracted by UNDC (unsigned Neural Dual
Contouring, Chen et al., SIGGRAPH 2022) with our own weights.

The field is the ``udf`` method's: the same targets and loss, and in neural mode the same fitted
network (``fit_of = 'udf'``). Extraction: :func:`methods.extractors.undc.unsigned_neural_dual_contouring`
on the UDF in voxel units (``d / h``): the bool network flags the grid edges that cross the surface (only edges whose end points
both have UDF < 1 voxel are considered), the float network places a vertex in every cell around a
flagged edge, a quad (two unoriented triangles) joins the 4 cells of each flagged edge. NDC's optional
post-processing of the flags is not applied.
Weights: trained by :mod:`methods.training.undc` (``python -m methods.training.undc --budget cpu``),
read from ``$SALSBENCH_UNDC_WEIGHTS`` or ``methods/weights/undc_cpu.pt``; without them the method is
unavailable.
Oracle: the exact narrow-band UDF on the grid (as ``udf-dualmesh``; its band, >= 2h, covers the input
clip of 2 voxels). Neural: the sparse query of :mod:`methods.core.query`, fine wherever a block may hold a
point within the input clip of the surface (some corner has ``f < sqrt(3) S h / 2 + 2h``), so the
networks see the fitted values wherever they are not clipped; d = max(f, 0).
"""

from __future__ import annotations

import numpy as np

from foundation.grid import spacing
from foundation.params import Param
from methods.core import query
from methods.extractors import undc
from methods.core.weights import WeightsError, load_cached
from methods.base import Extraction, register_method
from methods.core.training_record import TrainingRecord
from methods.fields.udf import UDFMethod


def _load():
    """The weights file's networks and info, read once per process while the file is unchanged."""
    return load_cached(undc.weights_path(), undc.load_weights)


@register_method(order=36, color="#a0522d")
class UDFNDCMethod(UDFMethod):
    name = "udf-ndc"
    description = "the udf method's field + unsigned Neural Dual Contouring (UNDC) with our trained networks"
    extractor = "UNDC (our weights)"
    fit_of = "udf"
    components = ()
    parameters = {
        "stride": Param(query.DEFAULT_STRIDE, "coarse stride of the sparse query", ge=1, neural_only=True),
    }

    @classmethod
    def unavailable(cls):
        try:
            _load()
        except WeightsError as exc:
            return str(exc)
        return None

    def oracle_grid(self, fields, N, cache):
        d, _ = cache.get(fields, N, "udf_grad")
        return {"udf": d}, {}

    def neural_grid(self, model, N, device=None):
        stride = self.params["stride"]
        margin = query.block_half_diagonal(N, stride) + undc.INPUT_CLIP * spacing(N)
        values, _, info = query.sparse_grid_points(model, N, query.near_below(margin), device, stride=stride)
        return {"udf": np.maximum(values[..., 0], 0.0)}, {"query_fraction": info.fraction}

    def extraction_data_digest(self) -> str:
        return _load()[2]["sha256"]

    def training_record(self) -> TrainingRecord:
        info = _load()[2]
        hashes = info.get("training_hashes")  # weights trained before it was recorded: unknown
        return TrainingRecord(f"our UNDC weights ({info['sha256'][:12]}), training set {info.get('training_set')}",
                              content_hashes=None if hashes is None else frozenset(hashes))

    def extract(self, grid_field, N) -> Extraction:
        bool_network, float_network, info = _load()
        mesh = undc.unsigned_neural_dual_contouring(grid_field["udf"], bool_network, float_network)
        return Extraction(mesh.vertices, mesh.faces, {**mesh.info, "undc_weights": info["sha256"][:12]})
