"""``ball-pivoting``: the ball-pivoting algorithm (Bernardini et al. 1999) by pymeshlab on the raw
points, with PCA normals (oriented toward each point's sensor when the input carries them;
``reconstruct`` task). A ball of radius ``radius`` (0: MeshLab's
automatic choice from the points' spacing) pivots around edges, adding a triangle wherever it
touches three points without containing another; it interpolates the points, keeps open
boundaries, and leaves holes where the sampling is sparser than the ball.
"""

from __future__ import annotations

import numpy as np

from foundation.timing import stage
from methods.base import Extraction, PointCloudMethod, register_method
from methods.extractors.meshlab import current_mesh, oriented_point_set
from foundation.params import Param


@register_method(order=120, color="#bcbd22")
class BallPivotingMethod(PointCloudMethod):
    name = "ball-pivoting"
    description = "ball-pivoting surface reconstruction (pymeshlab) with PCA normals"
    extractor = "ball pivoting"
    uses_sensors = True
    parameters = {
        "radius": Param(0.0, "ball radius, canonical units (0: MeshLab's automatic radius)", ge=0),
        "normal_k": Param(10, "neighbours of the PCA normal estimate", ge=3),
    }

    def reconstruct(self, points: np.ndarray, N: int, device=None, seed: int = 0,
                    sensors: np.ndarray | None = None) -> Extraction:
        import pymeshlab

        ms = oriented_point_set(points, self.params["normal_k"], sensors)
        with stage("pivoting"):
            if self.params["radius"] > 0:
                ms.generate_surface_reconstruction_ball_pivoting(
                    ballradius=pymeshlab.PureValue(self.params["radius"]))
            else:
                ms.generate_surface_reconstruction_ball_pivoting()
        V, F, _ = current_mesh(ms)
        return Extraction(V, F)
