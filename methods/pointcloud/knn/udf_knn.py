"""``udf-knn``: a K-NN local network regressing the unsigned distance (the GeoUDF / CAP-UDF family,
implemented here with the shared encoder, not those papers' code) + MeshUDF-style extraction.

A point x and its K nearest input points go through :class:`methods.pointcloud.knn.network.PointKNNNetwork`
to the UDF d(x), trained once across shapes on the exact UDF of the shared samples' points, loss
L1 on d clamped at :data:`DISTANCE_CLAMP` (far values carry no surface information). Inference: the grid
points within ``band`` h of an input point get the network's d and, where d < 2 h, its autograd
gradient (the neighbours held fixed); every other grid point is far (d = :data:`FAR`); then
MeshUDF-style extraction (``methods.extractors.meshudf``) with the network as the face filter's UDF.
"""

from __future__ import annotations

import numpy as np

from foundation.grid import point_inputs, spacing
from foundation.params import Param
from foundation.timing import stage
from methods.base import Extraction, register_method
from methods.extractors.meshudf import meshudf_marching_cubes
from methods.pointcloud.knn.query import evaluate_knn, knn_k
from methods.pointcloud.knn.method import KNNTrainedMethod
from methods.pointcloud.neighbourhoods import band_points

#: Training targets and predictions are compared clamped at this distance (canonical units).
DISTANCE_CLAMP = 0.1
#: UDF of grid points outside the band.
FAR = 1.0


@register_method(order=130, color="#9467bd",
                 note="udf-knn is SALS's K-NN encoder with an unsigned-distance output, a controlled ablation of the "
                      "representation (the published GeoUDF and CAP-UDF are the rows geoudf and cap-udf).")
class UDFKNNMethod(KNNTrainedMethod):
    name = "udf-knn"
    description = "K-NN local network to the unsigned distance (GeoUDF/CAP-UDF family) + MeshUDF-style extraction"
    network_kind = "point"
    output_dim = 1
    extractor = "MeshUDF-style"
    parameters = {
        "band": Param(4.0, "grid points within this many h of an input point are queried", gt=0),
        "face_filter": Param(1.0 / 6.0, "faces whose largest vertex UDF is >= this x h are removed", gt=0),
        "sign_rule": Param("hybrid", "pseudo-sign rule of a cube's corners", choices=("hybrid", "anchor")),
    }

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        return {"udf": np.asarray(fields.udf(samples.points), dtype=np.float32)}

    def loss(self, prediction, targets):
        return (prediction[:, 0].clamp(max=DISTANCE_CLAMP) - targets["udf"].clamp(max=DISTANCE_CLAMP)).abs().mean()

    def reconstruct(self, points, N, device=None, seed=0, model=None) -> Extraction:
        model, device = self.network_on_device(model, device)
        k, h = knn_k(model), spacing(N)
        with stage("band"):
            ijk = band_points(points, N, self.params["band"] * h)
        with stage("field"):
            out, _ = evaluate_knn(model, point_inputs(N, ijk), points, k, device)
            d = np.maximum(out[:, 0], 0.0)
            udf = np.full((N, N, N), FAR, dtype=np.float32)
            udf[tuple(ijk.T)] = d
        with stage("grad"):
            near = ijk[d < 2.0 * h]
            grad = np.zeros((N, N, N, 3), dtype=np.float32)
            if len(near):
                _, g = evaluate_knn(model, point_inputs(N, near), points, k, device, grad_output=0)
                norm = np.linalg.norm(g, axis=1, keepdims=True)
                grad[tuple(near.T)] = np.divide(g, norm, out=np.zeros_like(g), where=norm > 0)

        def udf_at(x):
            return np.maximum(evaluate_knn(model, np.asarray(x, dtype=np.float32), points, k, device)[0][:, 0], 0.0)

        mesh = meshudf_marching_cubes(udf, grad, udf_at=udf_at, face_factor=self.params["face_filter"],
                                      sign_rule=self.params["sign_rule"])
        return Extraction(mesh.vertices, mesh.faces, info={"queried_points": int(len(ijk))})
