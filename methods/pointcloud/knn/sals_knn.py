"""``sals-knn``: the SALS K-NN network of point-cloud reconstruction + E-DC.

A segment (u, v) and the K nearest input points of its midpoint go through
:class:`methods.pointcloud.knn.network.SegmentKNNNetwork` to two logits (o, s), trained once across many shapes
(:mod:`methods.pointcloud.knn.training`) with SALS's labels and loss (``methods.core.segment_field.segment_targets`` /
``segment_loss``: 10 L1(s | o = 1) + BCE(o)). Inference on a cloud: only the grid edges whose
midpoint lies within ``band`` h of an input point are queried (the paper: 4 h; the others are "no
hit"); an edge is intersected when o_hat > ``o_threshold`` (the paper's evaluation value 0.3);
normals by autograd of s w.r.t. the endpoint nearer the hit; E-DC (``methods.extractors.edc``) as in the
encoding task. The points are never subsampled.
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit

from foundation.grid import edge_inputs, spacing
from foundation.params import Param
from foundation.timing import stage
from methods.base import Extraction, register_method
from methods.core.segment_field import nearer_endpoint_normals, segment_loss, segment_targets
from methods.extractors.edc import edge_dual_contouring
from methods.pointcloud.knn.query import evaluate_knn, knn_k
from methods.pointcloud.knn.method import KNNTrainedMethod
from methods.pointcloud.neighbourhoods import band_edges


@register_method(order=140, color="#b8321a")
class SALSKNNMethod(KNNTrainedMethod):
    name = "sals-knn"
    description = "SALS K-NN local network (trained across shapes) + E-DC, from a raw point cloud"
    network_kind = "segment"
    input_kind = "segments"
    output_dim = 2
    extractor = "E-DC"
    parameters = {
        "o_threshold": Param(0.3, "an edge is intersected when o_hat > this (the paper's evaluation value)",
                             gt=0, lt=1),
        "band": Param(4.0, "edges whose midpoint is within this many h of an input point are queried", gt=0),
        "normals": Param(True, "E-DC vertices from the QEF with autograd normals (else mass points)"),
        "qef_cutoff": Param(0.1, "eigenvalues of A^T A below this are dropped in the QEF", ge=0),
        "faces": Param("fan4", "E-DC face rule (see methods.fields.sals)", choices=("fan4", "quad2", "fan4-adaptive")),
    }

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        return segment_targets(fields, samples.segments)

    def loss(self, prediction, targets):
        return segment_loss(prediction, targets)

    def reconstruct(self, points, N, device=None, seed=0, model=None) -> Extraction:
        model, device = self.network_on_device(model, device)
        with stage("band"):
            ids = band_edges(points, N, self.params["band"] * spacing(N))
        queried = len(ids)
        ids, s, normals = self.edge_field(points, N, ids, model, device)
        mesh = edge_dual_contouring(N, ids, s, normals, qef_cutoff=self.params["qef_cutoff"], faces=self.params["faces"])
        return Extraction(mesh.vertices, mesh.faces, info={"queried_edges": int(queried), "intersected_edges": int(len(ids))})

    def neighbour_count(self, model) -> int:
        """The K input points each edge query reads (the network's training K)."""
        return knn_k(model)

    def edge_field(self, points, N, ids, model, device, input_scale: float = 1.0):
        """The network on the grid edges ``ids`` (flat ids of the N grid) with their K nearest of
        ``points``: (the intersected ids, their s (float32), their unit normals or None).

        ``input_scale`` multiplies every coordinate the network sees (segments and points alike;
        the K nearest are the same): a grid finer than the training grid by that factor, in a
        frame where the cloud has the training density (:mod:`methods.pointcloud.blocks`)."""
        model, device = self.network_on_device(model, device)
        k = knn_k(model)
        segments = edge_inputs(N, ids).reshape(-1, 2, 3)
        cloud = np.asarray(points)
        if input_scale != 1.0:
            segments = segments * np.float32(input_scale)
            cloud = cloud * input_scale
        with stage("field"):
            out, _ = evaluate_knn(model, segments, cloud, k, device)
            hit = expit(out[:, 0].astype(np.float64)) > self.params["o_threshold"]
            ids, segments = ids[hit], segments[hit]
            s = expit(out[hit, 1].astype(np.float64)).astype(np.float32)
        normals = None
        if self.params["normals"] and len(ids):
            with stage("normals"):
                _, grad = evaluate_knn(model, segments, cloud, k, device, grad_output=1)
                normals = nearer_endpoint_normals(s, grad.reshape(-1, 6))
        return ids, s, normals
