"""``occ-knn``: a K-NN local network to the occupancy logit (the POCO / ConvONet family, implemented
here with the shared encoder, not those papers' code) + marching cubes.

A point x and its K nearest input points go through :class:`methods.pointcloud.knn.network.PointKNNNetwork`
to an occupancy logit, trained once across shapes on the exact occupancy (winding number > 1/2,
``ExactFields.occupancy``) of the shared samples' points, BCE loss. Inference: the grid points
within ``band`` h of an input point get the network's probability; every other grid point is
outside if its connected far region touches the border of the grid, inside otherwise (a flood
fill, scipy.ndimage.label); marching cubes at 0.5 (scikit-image). Like every occupancy method it
closes open surfaces and cannot keep a non-manifold branching.

The shared encoder is purely local, and occupancy is not a local quantity: the K neighbours of
x + d n and of x - d n beside a flat patch with normal n are mirror images, so the network cannot
tell the inside from the outside there (only curvature hints at it): its training BCE stays
above 0 and the band keeps sheets of p ~ 0.5 (the numbers at the ``cpu`` budget: docs/PROTOCOL.md,
"Point-cloud reconstruction"; docs/PERFORMANCE.md, section 10). POCO and
ConvONet get the sign from a large receptive field; here the encoder is the shared one so that the
comparison isolates the representation, and this is the price.
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit
import torch.nn.functional as F

from foundation.grid import spacing
from foundation.timing import stage
from methods.base import Extraction, register_method
from methods.pointcloud.knn.method import KNNTrainedMethod
from methods.pointcloud.knn.query import evaluate_knn, knn_k
from methods.pointcloud.neighbourhoods import band_points
from methods.extractors.marching_cubes import far_occupancy, marching_cubes_grid
from foundation.params import Param
from foundation.grid import point_inputs


@register_method(order=120, color="#17becf",
                 note="occ-knn is SALS's K-NN encoder with an occupancy output, a controlled ablation of the "
                      "representation (the published POCO is the row poco).")
class OccKNNMethod(KNNTrainedMethod):
    name = "occ-knn"
    description = "K-NN local network to occupancy (POCO/ConvONet family) + marching cubes"
    network_kind = "point"
    output_dim = 1
    extractor = "marching cubes"
    parameters = {
        "band": Param(4.0, "grid points within this many h of an input point are queried", gt=0),
    }

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        return {"occupancy": np.asarray(fields.occupancy(samples.points), dtype=np.float32)}

    def loss(self, prediction, targets):
        return F.binary_cross_entropy_with_logits(prediction[:, 0], targets["occupancy"])

    def reconstruct(self, points, N, device=None, seed=0, model=None) -> Extraction:
        model, device = self.network_on_device(model, device)
        with stage("band"):
            ijk = band_points(points, N, self.params["band"] * spacing(N))
        with stage("field"):
            out, _ = evaluate_knn(model, point_inputs(N, ijk), points, knn_k(model), device)
            known = np.zeros((N, N, N), dtype=bool)
            known[tuple(ijk.T)] = True
            volume = far_occupancy(known)
            volume[tuple(ijk.T)] = expit(out[:, 0])
        mesh = marching_cubes_grid(volume, 0.5, inside="high")
        return Extraction(mesh.vertices, mesh.faces, info={"queried_points": int(len(ijk))})
