"""``nglod``: NGLOD's network (Takikawa et al., CVPR 2021) fitted to the signed distance, marching
cubes at level 0 on its finest level of detail.

Network: :class:`methods.core.network.LODNetwork` (NGLOD's ``OctreeSDF``): ``lods`` dense feature
volumes of 2^(l + 2) cells per axis (5, 9, 17, 33, 65 points at the authors' 5 LODs), ``feature_dim``
features each, summed up to each LOD, one ``Linear(3 + C, hidden) -> ReLU -> Linear(hidden, 1)``
decoder per LOD on ``[x, z_l]``; one output column per LOD. The method's own network under every
budget (the budget gives the steps, batch, samples and learning rates; with an MLP budget the feature
volumes train at the budget's ``lr``).
Targets: ``ExactFields.sdf`` (as ``sdf``). Loss: NGLOD's, the squared error summed over the LODs,
``mean_b sum_l (f_l(x_b) - d_b)^2`` (unclamped).
Extraction, oracle field and decomposition: ``sdf``'s (marching cubes at ``level``); the neural grid
is the finest LOD's column, by the sparse query with ``sdf``'s criterion on that column.
"""

from __future__ import annotations

from foundation.params import Param
from methods.core import query
from methods.base import register_method
from methods.fields.sdf import SDFMethod


def lod_resolutions(lods: int, base_lod: int = 2) -> tuple[int, ...]:
    """Points per axis of NGLOD's feature volumes: 2^(base_lod + l) cells + 1, l = 0 .. lods - 1."""
    return tuple(2 ** (base_lod + level) + 1 for level in range(lods))


@register_method(order=27, color="#6a51a3")
class NGLODMethod(SDFMethod):
    name = "nglod"
    description = "NGLOD (summed multi-LOD feature volumes, a decoder per LOD) fitted to the SDF + marching cubes"
    extractor = "marching cubes"
    parameters = {
        **SDFMethod.parameters,
        "lods": Param(5, "levels of detail (feature volumes of 4, 8, ... cells per axis)", ge=1, le=7, fit=True,
                      neural_only=True),
        "feature_dim": Param(32, "features per volume point", ge=1, fit=True, neural_only=True),
        "hidden": Param(128, "hidden width of each LOD's decoder", ge=1, fit=True, neural_only=True),
    }

    @property
    def output_dim(self) -> int:
        return self.params["lods"]

    def network_config(self, budget) -> dict:
        return {"backbone": "nglod", "width": self.params["hidden"],
                "grid_resolutions": lod_resolutions(self.params["lods"]), "grid_channels": self.params["feature_dim"]}

    def loss(self, prediction, targets):
        return (prediction - targets["sdf"][:, None]).square().sum(dim=1).mean()

    def neural_grid(self, model, N, device=None):
        near = query.near_level(self.level, query.block_half_diagonal(N, self.params["stride"]))
        values, _, info = query.sparse_grid_points(model, N, lambda corners: near(corners[..., -1:]), device,
                                                   stride=self.params["stride"])
        return values[..., -1], {"query_fraction": info.fraction}
