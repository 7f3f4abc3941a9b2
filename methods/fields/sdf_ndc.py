"""``sdf-ndc``: the ``sdf`` method's signed distance field extracted by Neural Dual Contouring.

The field is the ``sdf`` method's: the same targets and loss, and in neural mode the same fitted
network (``fit_of = 'sdf'``: one fit serves both). Extraction: NDC with its published SDF-input
network (:mod:`methods.extractors.ndc`): one vertex per cell whose corners change sign, placed by the CNN from
the SDF in voxel units around it; quads across the grid edges whose end points change sign.
Oracle: the exact narrow-band SDF on the grid (its band, >= 2h, covers NDC's input clip of 2 voxels).
Neural: the sparse query of :mod:`methods.core.query`, fine wherever a block may hold a point within
NDC's input clip of the surface (``|f| < sqrt(3) S h / 2 + 2h`` at a corner), so the network sees
the fitted values wherever they are not clipped.
"""

from __future__ import annotations

from foundation.grid import spacing
from foundation.params import Param
from methods.extractors import ndc
from methods.core import query
from methods.core.weights import WeightsError
from methods.base import Extraction, register_method
from methods.core.training_record import TrainingRecord
from methods.fields.sdf import SDFMethod


@register_method(order=25, color="#7a5fc1")
class SDFNDCMethod(SDFMethod):
    name = "sdf-ndc"
    description = "the sdf method's field + Neural Dual Contouring with NDC's published SDF network"
    extractor = "NDC"
    fit_of = "sdf"
    parameters = {
        "stride": Param(query.DEFAULT_STRIDE, "coarse stride of the sparse query", ge=1, neural_only=True),
    }
    #: NDC's cells change sign at 0.
    level = 0.0

    @classmethod
    def unavailable(cls):
        try:
            ndc.load_weights()
        except WeightsError as exc:
            return str(exc)
        return None

    def extraction_data_digest(self) -> str:
        return ndc.WEIGHTS_SHA256

    def training_record(self) -> TrainingRecord:
        return TrainingRecord("NDC's published SDF network: ABC objects 00000002-00007903",
                              abc_ranges=ndc.TRAINING_ABC_IDS)

    def neural_grid(self, model, N, device=None):
        margin = query.block_half_diagonal(N, self.params["stride"]) + ndc.INPUT_CLIP * spacing(N)
        values, _, info = query.sparse_grid_points(model, N, query.near_level(0.0, margin), device,
                                                   stride=self.params["stride"])
        return values[..., 0], {"query_fraction": info.fraction}

    def extract(self, grid_field, N) -> Extraction:
        return ndc.neural_dual_contouring(grid_field)
