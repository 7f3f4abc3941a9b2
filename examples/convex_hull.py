"""An example plugin: a point-cloud method defined outside the package, run as a row of the tables.

    .venv/bin/python run_benchmark.py --task reconstruct --plugin examples/convex_hull.py --methods convex-hull poisson

``convex-hull`` reconstructs the convex hull of the input points (scipy's Qhull): exact for convex
parts, and an upper bound on the error of every method that can represent a concavity. A plugin is
a Python file (or an installed module, or a package's ``salsbench.plugins`` entry point) that
subclasses :class:`methods.base.Method` (here :class:`methods.base.PointCloudMethod`) and registers
it; its code enters the cache keys like a built-in method's.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull

from foundation.params import Param
from methods.base import Extraction, PointCloudMethod, register_method


@register_method(order=900, color="#7f7f7f")
class ConvexHullMethod(PointCloudMethod):
    name = "convex-hull"
    description = "convex hull of the input points (scipy Qhull): an example plugin"
    extractor = "convex hull"
    parameters = {"joggle": Param(False, "joggle the input (Qhull option QJ) so every facet is a triangle")}

    def reconstruct(self, points: np.ndarray, N: int, device=None, seed: int = 0) -> Extraction:
        points = self.checked_points(points)
        hull = ConvexHull(points, qhull_options="QJ" if self.params["joggle"] else None)
        used, faces = np.unique(hull.simplices, return_inverse=True)
        faces = faces.reshape(-1, 3)
        outward = np.einsum("ij,ij->i", np.cross(points[hull.simplices[:, 1]] - points[hull.simplices[:, 0]],
                                                  points[hull.simplices[:, 2]] - points[hull.simplices[:, 0]]),
                            hull.equations[:, :3]) > 0
        faces[~outward] = faces[~outward][:, ::-1]  # Qhull's vertex order is arbitrary; its normals point out
        return Extraction(points[used], faces, info={"hull_vertices": int(len(used))})
