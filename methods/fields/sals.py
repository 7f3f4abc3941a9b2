"""``sals``: neural line segment field (SALS) + E-DC.

Network (u, v) (6) -> two logits; o_hat = sigmoid(out_0) (the segment hits the surface), s_hat =
sigmoid(out_1) (hit point s u + (1 - s) v). Targets: ``ExactFields.segments(u, v)`` on the shared
samples' segments: o (0/1) and s. Loss::

    10 * mean_{o = 1} |s_hat - s|  +  BCE(o_hat, o)

(BCE computed from the logit, ``binary_cross_entropy_with_logits``: the same value, stable).
Extraction: E-DC (:func:`methods.extractors.edc.edge_dual_contouring`) on the edges with o_hat >
``o_threshold``: 0.5, the decision point of the BCE-trained o (the paper evaluates at 0.1,
``PAPER_O_THRESHOLD``, a trade of false hits for recall that suits its GPU-budget network; at the
``cpu`` budget o is blurrier and 0.1 keeps edges next to the surface: spurious faces and false sharp
edges; docs/PROTOCOL.md, "The o threshold").
Face rule ``faces``: ``fan4`` (the paper's, default), ``quad2`` or ``fan4-adaptive`` (the fan except
where its edge point is off the plane of the 4 cell vertices, as on walls thinner than a cell, where
the fans fold into false sharp edges: 2 triangles there; see ``edge_dual_contouring`` and
docs/PROTOCOL.md, "E-DC face rules").
Normals (``normals=True``): the gradient of s_hat w.r.t. the endpoint nearer the hit (d s/d u if
s_hat > 0.5, else d s/d v), normalised (sigmoid is monotonic, so the gradient of the s logit has the
same direction), by autograd in chunks, only for intersected edges.
Oracle: the exact segment field of every grid edge (``foundation.fields``, disk-cached) and the hit
triangle's normal.
Neural: sparse query of :mod:`methods.core.query` on the edges: coarse edges (length S h) with
o_hat > ``o_low`` (0.02) mark the blocks they touch; far edges are "no hit"; each grid point is
encoded once for all the edges it ends (:func:`methods.core.query.evaluate_grid_edges`).
Training segments (``edge_segments``, default 0 = the paper's): a fraction of the shared segments
(u, v) may be replaced by grid-edge-like ones (u, u + L e), e a random signed axis, L
``edge_length``: the queries E-DC makes are axis-aligned edges of length h, which the paper's
isotropic segments cover only in part. A deviation from the paper, off by default.
"""

from __future__ import annotations

import hashlib

import numpy as np
from scipy.special import expit

from foundation.grid import edge_inputs, spacing
from foundation.params import Param
from foundation.timing import stage
from methods.core import query
from methods.base import Extraction, FieldMethod, median_angle_deg, register_method
from methods.core.segment_field import nearer_endpoint_normals, segment_loss, segment_targets
from methods.extractors.edc import PAPER_HIT_THRESHOLD, edge_dual_contouring

#: The paper's hit threshold of o_hat.
PAPER_O_THRESHOLD = PAPER_HIT_THRESHOLD
#: The default hit threshold: o_hat's own decision point (BCE).
DEFAULT_O_THRESHOLD = 0.5
#: Default length of the optional grid-edge-like training segments: a 128^3 grid edge, 2 / 127.
EDGE_LENGTH = 2.0 / 127.0


def _logit(p: float) -> float:
    return float(np.log(p / (1.0 - p)))


def edge_draws(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per sample a signed axis ``d`` in 0..5 (``(-1)^(d // 3) e_(d % 3)``) and a uniform draw in [0, 1),
    from a generator seeded by the SHA-256 of the shared points: a function of the shared samples
    (same shape and seed, same draws), drawn without touching the sampler's stream, so every other
    sample and every later draw of the run stay what they are without the option."""
    digest = hashlib.sha256(np.ascontiguousarray(points, dtype=np.float32).tobytes()).digest()
    rng = np.random.default_rng(np.frombuffer(digest, dtype=np.uint32))
    return rng.integers(0, 6, len(points)).astype(np.int8), rng.random(len(points), dtype=np.float32)


#: Grid edges labelled per calibration, and how far (in grid spacings h, per axis) their lower
#: endpoints lie from the surface points that seed them.
CALIBRATION_EDGES = 200_000
CALIBRATION_BAND = 2.0


def calibrated_o_threshold(model, fields, N: int, rng: np.random.Generator, device=None,
                           n: int = CALIBRATION_EDGES) -> tuple[float, dict]:
    """The o threshold that maximises the F1 of the network's hit flags on grid edges near the surface.

    ``n`` area-uniform surface points of the exact fields' mesh, each moved by a uniform offset in
    ``[-CALIBRATION_BAND h, CALIBRATION_BAND h]^3``, pick the grid edge along a random axis that starts
    at the grid point below them (duplicates dropped); the exact segment field labels each edge (hit
    or not) and the network gives its o logit. F1 = 2 TP / (2 TP + FP + FN) counts no true negatives,
    so the far edges of the band do not move it. Returns the probability halfway (in logits) between
    the last edge kept and the next, and facts: the threshold, the F1 there and at the paper's 0.1,
    the labelled edges and their hits. With no hit among them the default threshold stays.
    """
    from foundation.grid import LOWER, edge_endpoints, ijk_axis_to_edge_index
    from foundation.surface import sample_surface

    h = spacing(N)
    points, _ = sample_surface(fields.vertices, fields.faces, n, rng)
    near = points + rng.uniform(-CALIBRATION_BAND * h, CALIBRATION_BAND * h, size=points.shape)
    axis = rng.integers(0, 3, n)
    ijk = np.floor((near - LOWER) / h).astype(np.int64).clip(0, N - 1)
    ijk[np.arange(n), axis] = ijk[np.arange(n), axis].clip(max=N - 2)
    ids = np.unique(ijk_axis_to_edge_index(N, ijk, axis))
    u, v = edge_endpoints(N, ids)
    hit, _, _ = fields.segments(u, v)
    logits = query.evaluate(model, edge_inputs(N, ids), device)[:, 0].astype(np.float64)
    positives = int(hit.sum())
    facts = {"o_calibration_edges": int(len(ids)), "o_calibration_hits": positives}
    if positives == 0:
        return DEFAULT_O_THRESHOLD, {**facts, "o_threshold_calibrated": DEFAULT_O_THRESHOLD}
    order = np.argsort(-logits, kind="stable")
    tp = np.cumsum(hit[order])
    kept = np.arange(1, len(order) + 1)
    f1 = 2 * tp / (kept + positives)  # 2 TP / (2 TP + FP + FN), FP + TP = kept, FN = positives - TP
    best = int(np.argmax(f1))
    cut = logits[order[best]] if best + 1 == len(order) else 0.5 * (logits[order[best]] + logits[order[best + 1]])
    threshold = float(expit(cut))
    paper = logits > _logit(PAPER_O_THRESHOLD)
    paper_tp = int((paper & hit).sum())
    return threshold, {**facts, "o_threshold_calibrated": threshold, "o_calibration_f1": float(f1[best]),
                       "o_calibration_f1_paper": 2 * paper_tp / (int(paper.sum()) + positives)}


def _positions(ids: np.ndarray, table: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For sorted unique ``table``: which of ``ids`` it holds (bool mask) and where (indices into
    ``table`` of the held ones)."""
    at = np.searchsorted(table, ids).clip(max=max(len(table) - 1, 0))
    held = (at < len(table)) & (table[at] == ids) if len(table) else np.zeros(len(ids), dtype=bool)
    return held, at[held]


@register_method(order=40, color="#e4572e")
class SALSMethod(FieldMethod):
    name = "sals"
    description = "neural line segment field (SALS) + edge-based dual contouring (E-DC)"
    input_kind = "segments"
    output_dim = 2
    extractor = "E-DC"
    components = ("flags", "s", "normals")
    parameters = {
        "o_threshold": Param(DEFAULT_O_THRESHOLD, "an edge is intersected when o_hat > this (the paper: 0.1)", gt=0,
                             lt=1, neural_only=True),
        "normals": Param(True, "E-DC vertices from the QEF with autograd normals (else mass points)"),
        "qef_cutoff": Param(0.1, "eigenvalues of A^T A below this are dropped in the QEF", ge=0),
        "clamp_to_cell": Param(False, "clip each QEF vertex to its cell (off in the paper)"),
        "faces": Param("fan4", "face rule: the paper's 4-triangle fan, 2 triangles per quad, or the fan only "
                       "where its edge point lies on the plane of the 4 cell vertices, else 2 triangles "
                       "(fan4-adaptive: no thin-wall folds, see methods.extractors.edc.edge_dual_contouring)",
                       choices=("fan4", "quad2", "fan4-adaptive")),
        "o_calibration": Param(False, "after the fit, set o_threshold per shape to the value that maximises the F1 "
                               "of the network's hit flags on grid edges near the surface, labelled by the exact "
                               "field as the training segments are: a deviation from the paper (off)",
                               neural_only=True),
        "o_low": Param(0.02, "coarse edges with o_hat > this mark blocks for the sparse query", gt=0, lt=1, neural_only=True),
        "stride": Param(query.DEFAULT_STRIDE, "coarse stride of the sparse query", ge=1, neural_only=True),
        "edge_segments": Param(0.0, "fraction of the training segments replaced by grid-edge-like ones "
                               "(u, u + edge_length e), e a random signed axis: a deviation from the paper (0)",
                               ge=0, le=1, neural_only=True, fit=True),
        "edge_length": Param(EDGE_LENGTH, "length of the grid-edge-like training segments, canonical units "
                             "(default: a 128^3 grid edge)", gt=0, neural_only=True, fit=True),
    }

    def training_segments(self, samples) -> np.ndarray:
        """The (M, 2, 3) segments the network trains on: the shared samples' segments, with the
        fraction ``edge_segments`` of them replaced by ``(u, u + edge_length e)``, ``e`` a random signed
        axis; ``u`` stays the shared point. Which samples and which axes: :func:`edge_draws`."""
        segments = samples.segments
        if self.params["edge_segments"] == 0:
            return segments
        direction, draw = edge_draws(samples.points)
        swap = np.flatnonzero(draw < self.params["edge_segments"])
        d = direction[swap].astype(np.int64)
        step = np.zeros((len(swap), 3), dtype=np.float32)
        step[np.arange(len(swap)), d % 3] = np.where(d < 3, 1.0, -1.0) * self.params["edge_length"]
        segments = segments.copy()
        segments[swap, 1] = segments[swap, 0] + step
        return segments

    def network_inputs(self, samples) -> np.ndarray:
        return np.ascontiguousarray(self.training_segments(samples).reshape(len(samples), 6), dtype=np.float32)

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        return segment_targets(fields, self.training_segments(samples))

    def loss(self, prediction, targets):
        return segment_loss(prediction, targets)

    def oracle_grid(self, fields, N, cache):
        ef = cache.get(fields, N, "edges")
        ids = np.flatnonzero(ef.hit)
        return {"edge_ids": ids, "s": ef.s[ids], "normals": ef.normal[ids]}, {}

    def __init__(self, **params):
        super().__init__(**params)
        self.calibrated_threshold: float | None = None

    def calibrate(self, model, fields, N, rng, device=None):
        self.calibrated_threshold = None
        if not self.params["o_calibration"]:
            return {}
        with stage("calibrate"):
            threshold, facts = calibrated_o_threshold(model, fields, N, rng, device)
        self.calibrated_threshold = threshold
        return facts

    def o_threshold(self) -> float:
        """The hit threshold of the neural query: the calibrated one after :meth:`calibrate`, else ``o_threshold``."""
        return self.params["o_threshold"] if self.calibrated_threshold is None else self.calibrated_threshold

    def neural_grid(self, model, N, device=None):
        threshold = self.o_threshold()
        low = _logit(min(self.params["o_low"], threshold))

        def near(values):
            return values[:, 0] > low

        with stage("edges"):
            out, _, info = query.sparse_grid_edges(model, N, near, device, stride=self.params["stride"],
                                                   edge_fill=np.array([-30.0, 0.0], dtype=np.float32))
            ids = np.flatnonzero(out[:, 0] > _logit(threshold))
            s = expit(out[ids, 1].astype(np.float64)).astype(np.float32)
        normals = None
        if self.params["normals"] and len(ids):
            with stage("normals"):
                _, g = query.evaluate_with_input_grad(model, edge_inputs(N, ids), 1, device)
                normals = nearer_endpoint_normals(s, g)
        return {"edge_ids": ids, "s": s, "normals": normals}, {"query_fraction": info.fraction}

    def fitted_edges(self, model, N: int, ids: np.ndarray, device=None) -> tuple[np.ndarray, np.ndarray | None]:
        """The network's s (E,) and, with ``normals``, its unit normals (E, 3) on the grid edges ``ids``."""
        inputs = edge_inputs(N, ids)
        if not self.params["normals"]:
            return expit(query.evaluate(model, inputs, device)[:, 1].astype(np.float64)).astype(np.float32), None
        out, g = query.evaluate_with_input_grad(model, inputs, 1, device)
        s = expit(out[:, 1].astype(np.float64)).astype(np.float32)
        return s, nearer_endpoint_normals(s, g)

    def hybrid_grid(self, fitted, exact, exact_parts, model, N, device=None):
        ids = exact["edge_ids"] if "flags" in exact_parts else fitted["edge_ids"]
        in_fitted, at_fitted = _positions(ids, fitted["edge_ids"])
        s = np.empty(len(ids), dtype=np.float32)
        normals = np.empty((len(ids), 3), dtype=np.float32) if self.params["normals"] else None
        s[in_fitted] = fitted["s"][at_fitted]
        if normals is not None:
            normals[in_fitted] = fitted["normals"][at_fitted]
        if not in_fitted.all():  # edges the network's own flags left out: its values there
            s[~in_fitted], missing_normals = self.fitted_edges(model, N, ids[~in_fitted], device)
            if normals is not None:
                normals[~in_fitted] = missing_normals
        in_exact, at_exact = _positions(ids, exact["edge_ids"])  # false hits have no exact value: theirs stay
        if "s" in exact_parts:
            s[in_exact] = exact["s"][at_exact]
        if "normals" in exact_parts and normals is not None:
            normals[in_exact] = exact["normals"][at_exact]
        return {"edge_ids": ids, "s": s, "normals": normals}

    def component_errors(self, fitted, exact, N):
        both, at_fitted, at_exact = np.intersect1d(fitted["edge_ids"], exact["edge_ids"], assume_unique=True,
                                                   return_indices=True)
        errors = {"hit_edges": len(both), "false_hit_edges": len(fitted["edge_ids"]) - len(both),
                  "missed_edges": len(exact["edge_ids"]) - len(both),
                  "s_error_h": float(np.abs(fitted["s"][at_fitted] - exact["s"][at_exact]).mean()) if len(both) else np.nan}
        if fitted.get("normals") is not None:
            errors["normal_error_deg"] = median_angle_deg(fitted["normals"][at_fitted], exact["normals"][at_exact])
        return errors

    def extract(self, grid_field, N) -> Extraction:
        normals = grid_field.get("normals") if self.params["normals"] else None
        return edge_dual_contouring(N, grid_field["edge_ids"], grid_field["s"], normals,
                                    qef_cutoff=self.params["qef_cutoff"], clamp_to_cell=self.params["clamp_to_cell"],
                                    faces=self.params["faces"])
