"""``poisson``: screened Poisson surface reconstruction (Kazhdan & Hoppe 2013) by pymeshlab, the
classic non-learned baseline of point-cloud reconstruction (``reconstruct`` task).

Steps, all pymeshlab (MeshLab's filters), on the raw points (no normals given):

1. normals: ``compute_normal_for_point_clouds`` (PCA over the ``normal_k`` nearest points, oriented
   by MeshLab's propagation, or toward each point's sensor when the input is a scan that carries
   them), stage ``reconstruct_normals``;
2. ``generate_surface_reconstruction_screened_poisson`` at octree depth ``depth`` (0: log2 of the
   run's grid, rounded, so grid 128 -> depth 7 -> a 128^3 finest octree level, the resolution the
   grid methods get), point weight ``point_weight`` (screening), stage ``reconstruct_poisson``;
3. density trimming as users apply it (PoissonRecon's SurfaceTrimmer): the filter's per-vertex scalar
   is the sampling density in octree-depth units (about ``depth - 0.5`` on a uniformly sampled
   surface); vertices more than ``trim_depth`` below ``depth`` are removed with their faces: the
   low-density membrane Poisson spans over holes and open boundaries (what it removes from a
   sphere and a hemisphere: docs/PERFORMANCE.md, section 7). 0 keeps the
   untrimmed surface.

Poisson's output is a closed (indicator-function) surface: open boundaries and non-manifold
branchings of the input do not survive it, except where trimming cuts the membrane.
"""

from __future__ import annotations

import numpy as np

from foundation.timing import stage
from methods.base import Extraction, PointCloudMethod, register_method
from methods.extractors.mesh_ops import keep_vertices
from methods.extractors.meshlab import current_mesh, oriented_point_set, poisson_depth
from foundation.params import Param


@register_method(order=110, color="#8c564b")
class PoissonMethod(PointCloudMethod):
    name = "poisson"
    description = "screened Poisson reconstruction (pymeshlab) with PCA normals and density trimming"
    extractor = "screened Poisson"
    uses_sensors = True
    parameters = {
        "depth": Param(0, "octree depth (0: round(log2 grid))", ge=0),
        "point_weight": Param(4.0, "screening weight of the points (pymeshlab's default)", ge=0),
        "normal_k": Param(10, "neighbours of the PCA normal estimate", ge=3),
        "trim_depth": Param(2.0, "vertices whose density is more than this below the depth are removed (0: none)",
                            ge=0),
    }

    def reconstruct(self, points: np.ndarray, N: int, device=None, seed: int = 0,
                    sensors: np.ndarray | None = None) -> Extraction:
        ms = oriented_point_set(points, self.params["normal_k"], sensors)
        depth = self.params["depth"] or poisson_depth(N)
        with stage("poisson"):
            ms.generate_surface_reconstruction_screened_poisson(depth=depth, pointweight=self.params["point_weight"],
                                                                 preclean=True, threads=1)
        V, F, mesh = current_mesh(ms)
        density = np.asarray(mesh.vertex_scalar_array(), dtype=np.float64)
        trim = self.params["trim_depth"]
        V, F, removed = trim_by_density(V, F, density, depth - trim if trim > 0 else -np.inf)
        return Extraction(V, F, info={"poisson_depth": depth, "trimmed_vertices": removed})


def trim_by_density(vertices: np.ndarray, faces: np.ndarray, density: np.ndarray, threshold: float):
    """Remove the vertices whose density lies below ``threshold``, with every face using one;
    returns (vertices, faces reindexed, vertices removed)."""
    return keep_vertices(vertices, faces, density >= threshold)


