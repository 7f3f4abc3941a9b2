"""Surface metrics between a ground-truth and a predicted triangle mesh (SPEC section 7).

Protocol (preset ``default``, all lengths in the canonical frame of the GT, SPEC section 1):

* Sample ``n`` points area-uniformly on each mesh (:func:`sample_surface`), each with the unit
  normal of the face it came from. GT and prediction use two independent streams spawned from one
  seed, so every prediction of a shape is scored against the same GT samples.
* Nearest neighbours by KD-tree in both directions (pykdtree, exact): ``d(g -> P)`` for every GT
  sample ``g`` and ``d(p -> G)`` for every predicted sample ``p``.
* **CD** (Chamfer-L1) ``= 1/2 (mean_g d(g -> P) + mean_p d(p -> G))``, unsquared; tables x 1e3.
* **NC** ``= 1/2 (mean_g |n_g . n_nn(g)| + mean_p |n_p . n_nn(p)|)`` (orientation-agnostic).
* **F1@tau**: precision ``P = #{p : d(p -> G) < tau} / n_pred``, recall
  ``R = #{g : d(g -> P) < tau} / n_gt``, ``F1 = 2PR / (P + R)`` (0 when both are 0); tau = 0.005, 0.01.
* **Sharp-edge points** (Neural Dual Contouring's test): a sample ``p`` is an edge point when a sample
  ``q`` of the same mesh lies within ``r`` of it (``|p - q| <= r``) with ``|n_p . n_q| < 0.2``;
  ``r = 0.004 D`` with ``D`` the GT bounding-box diagonal (:func:`sharp_edge_points`).
* **ECD** = the CD formula between the two edge-point sets (tables x 1e2); **EF1** = F1 at
  ``tau_e = 0.005 D``. GT without edge points: ECD = 0, EF1 = 1. Prediction without edge points
  (GT has some): ECD = NaN with ``ecd_flag`` set, EF1 = 0.

Preset ``ndc`` reproduces NDC's evaluation script (Chen et al. 2022, ``eval_cd_nc_f1_ecd_ef1.py``):
both meshes mapped to the frame where the GT bounding box is centred with diagonal 1, n = 100,000,
CD = ``mean_g d^2 + mean_p d^2`` (squared, summed, tables x 1e5), F1@0.003, edge radius 0.004,
ECD squared and summed (tables x 100), EF1@0.005, and 486 points at the origin standing in for the
prediction's edge points when it has none. Presets are data (:class:`MetricPreset`), not code paths.

The raw values are returned (never scaled); :attr:`MetricPreset.report_scale` / :data:`REPORT_SCALE`
give the table multipliers. Predictions that are empty or degenerate never raise: their distance
metrics are NaN, F1/EF1 are 0 and ``empty_prediction`` is set. Mesh validity (vertex/face counts,
boundary and non-manifold edges, components, watertightness) is counted on the prediction's faces
*as given*, vertices not merged (:func:`mesh_validity`).

Command line: ``python -m benchmark.metrics GT PRED [--points N] [--preset default|ndc] [--seed S]
[--json] [--no-normalize]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict, dataclass

import numpy as np
from pykdtree.kdtree import KDTree
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = [
    "MetricPreset",
    "HeadlineMetric",
    "f1_column",
    "PRESETS",
    "REPORT_SCALE",
    "sample_surface",
    "spatial_order",
    "nearest_distances",
    "sharp_edge_points",
    "EdgeSearchTooDense",
    "MAX_EDGE_PAIRS",
    "surface_metrics",
    "edge_metrics",
    "mesh_validity",
    "evaluate",
    "floor",
    "main",
]


# --------------------------------------------------------------------------------------------
# Presets
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HeadlineMetric:
    """A reported metric: result column, display name, table multiplier, better direction."""

    column: str
    name: str
    scale: float
    lower_is_better: bool


def f1_column(tau: float) -> str:
    """Result column of the F1 score at threshold ``tau``: 0.005 -> 'f1_005', 0.01 -> 'f1_01'
    (the digits after '0.'; other values: '.' -> '_'). The one naming rule of F1 columns."""
    text = f"{tau:.10f}".rstrip("0").rstrip(".")
    return "f1_" + (text[2:] if text.startswith("0.") else text.replace(".", "_"))


@dataclass(frozen=True)
class MetricPreset:
    """One evaluation protocol, as data. Every length is in the preset's ``frame``.

    Attributes
    ----------
    name : preset name ('default', 'ndc').
    n_points : surface samples per mesh.
    frame : 'canonical' (inputs are used as given: the GT's canonical frame, SPEC section 1) or
        'diag1' (both meshes mapped by ``x -> (x - c) / D``, c and D the GT bounding-box centre and
        diagonal: NDC's frame).
    chamfer : 'l1_half_mean' -> ``1/2 (mean d(g->P) + mean d(p->G))``; 'squared_sum' ->
        ``mean d(g->P)^2 + mean d(p->G)^2``.
    cd_scale : multiplier for tables (the returned value is raw).
    f1_thresholds : F1 thresholds tau (absolute, in the frame); F1 counts ``d < tau``.
    edge_units : 'gt_diagonal' (edge radius and EF1 threshold are multiples of the GT
        bounding-box diagonal D in the frame) or 'frame' (absolute lengths in the frame).
    edge_radius : edge-point radius r (in ``edge_units``); neighbours count when ``|p - q| <= r``.
    edge_dot_threshold : q makes p an edge point when ``|n_p . n_q| < edge_dot_threshold``.
    ef1_threshold : EF1 threshold tau_e (in ``edge_units``).
    ecd : chamfer form of ECD ('l1_half_mean' or 'squared_sum').
    ecd_scale : multiplier for tables.
    empty_edge_fallback : 0 -> a prediction without edge points gets ECD = NaN (flagged), EF1 = 0;
        k > 0 -> it is given k edge points at the frame origin and scored (NDC uses 486).
    """

    name: str
    n_points: int
    frame: str
    chamfer: str
    cd_scale: float
    f1_thresholds: tuple[float, ...]
    edge_units: str
    edge_radius: float
    edge_dot_threshold: float
    ef1_threshold: float
    ecd: str
    ecd_scale: float
    empty_edge_fallback: int

    def __post_init__(self):
        if self.frame not in ("canonical", "diag1"):
            raise ValueError(f"preset {self.name}: frame must be 'canonical' or 'diag1', got {self.frame!r}")
        for what in (self.chamfer, self.ecd):
            if what not in ("l1_half_mean", "squared_sum"):
                raise ValueError(f"preset {self.name}: chamfer form must be 'l1_half_mean' or 'squared_sum', got {what!r}")
        if self.edge_units not in ("gt_diagonal", "frame"):
            raise ValueError(f"preset {self.name}: edge_units must be 'gt_diagonal' or 'frame', got {self.edge_units!r}")

    @property
    def f1_keys(self) -> tuple[str, ...]:
        """Result keys of the F1 scores: 'f1_005' for tau = 0.005, 'f1_01' for 0.01, ..."""
        return tuple(f1_column(t) for t in self.f1_thresholds)

    @property
    def report_scale(self) -> dict[str, float]:
        """Table multipliers per result key (keys not listed are reported as is)."""
        return {
            "cd": self.cd_scale,
            "cd_gt_to_pred": self.cd_scale,
            "cd_pred_to_gt": self.cd_scale,
            "ecd": self.ecd_scale,
        }

    def headline_metrics(self) -> list["HeadlineMetric"]:
        """The reported metrics in paper order (CD, NC, F1@tau..., ECD, EF1) with their table
        multipliers and better directions: what every table and plot shows."""
        out = [HeadlineMetric("cd", "CD", self.cd_scale, True), HeadlineMetric("nc", "NC", 1.0, False)]
        out += [HeadlineMetric(k, f"F1@{t:g}", 1.0, False) for t, k in zip(self.f1_thresholds, self.f1_keys)]
        out += [HeadlineMetric("ecd", "ECD", self.ecd_scale, True), HeadlineMetric("ef1", "EF1", 1.0, False)]
        return out

    def describe_items(self, n_points: int | None = None) -> list[tuple[str, str]]:
        """(label, value) pairs stating the protocol, for table captions and the HTML report.
        ``n_points`` overrides the preset's sample count (a run's ``--eval-points``)."""
        unit = " D" if self.edge_units == "gt_diagonal" else ""
        frame = {"canonical": "GT canonical frame (bbox centred, largest side 1.99)",
                 "diag1": "GT bbox centred, diagonal 1 (NDC)"}[self.frame]
        chamfer = {"l1_half_mean": "½(mean d(g→P) + mean d(p→G)), unsquared",
                   "squared_sum": "mean d(g→P)² + mean d(p→G)²"}
        items = [
            ("metric preset", self.name),
            ("frame", frame),
            ("points per mesh", f"{int(self.n_points if n_points is None else n_points):,}"),
            ("CD form", f"{chamfer[self.chamfer]} ×{self.cd_scale:g}"),
            ("NC", "|n·n| (orientation-agnostic)"),
            ("F1 thresholds", ", ".join(f"{t:g}" for t in self.f1_thresholds)),
            ("sharp-edge points", f"|p−q| ≤ {self.edge_radius:g}{unit}, |n·n| < {self.edge_dot_threshold:g}"),
            ("ECD form", f"{chamfer[self.ecd]} ×{self.ecd_scale:g}"),
            ("EF1 threshold", f"{self.ef1_threshold:g}{unit}"),
            ("no predicted edge points", "ECD NaN (counted), EF1 = 0" if not self.empty_edge_fallback
             else f"{self.empty_edge_fallback} origin points scored"),
        ]
        if unit:
            items.append(("D", "GT bounding-box diagonal"))
        return items

    def describe(self, n_points: int | None = None) -> str:
        """One line stating the protocol (the items of :meth:`describe_items`)."""
        return "; ".join(f"{k}: {v}" for k, v in self.describe_items(n_points))

    def to_dict(self) -> dict:
        return asdict(self)


PRESETS: dict[str, MetricPreset] = {
    "default": MetricPreset(
        name="default",
        n_points=1_000_000,
        frame="canonical",
        chamfer="l1_half_mean",
        cd_scale=1e3,
        f1_thresholds=(0.005, 0.01),
        edge_units="gt_diagonal",
        edge_radius=0.004,
        edge_dot_threshold=0.2,
        ef1_threshold=0.005,
        ecd="l1_half_mean",
        ecd_scale=1e2,
        empty_edge_fallback=0,
    ),
    "ndc": MetricPreset(
        name="ndc",
        n_points=100_000,
        frame="diag1",
        chamfer="squared_sum",
        cd_scale=1e5,
        f1_thresholds=(0.003,),
        edge_units="frame",
        edge_radius=0.004,
        edge_dot_threshold=0.2,
        ef1_threshold=0.005,
        ecd="squared_sum",
        ecd_scale=1e2,
        empty_edge_fallback=486,
    ),
}

#: Table multipliers per preset and result key (raw values are multiplied by these in tables).
REPORT_SCALE: dict[str, dict[str, float]] = {name: p.report_scale for name, p in PRESETS.items()}


def _get_preset(preset: str | MetricPreset) -> MetricPreset:
    if isinstance(preset, MetricPreset):
        return preset
    if preset not in PRESETS:
        raise ValueError(f"unknown metric preset {preset!r} (choose from {', '.join(PRESETS)})")
    return PRESETS[preset]


# --------------------------------------------------------------------------------------------
# Sampling and nearest neighbours
# --------------------------------------------------------------------------------------------


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform random points on a triangle mesh, with the unit normal of their face.

    Face ``f`` is drawn with probability ``area_f / sum(area)`` (zero-area faces never), then a
    uniform point ``a + u (b - a) + v (c - a)`` with ``(u, v)`` uniform on the unit triangle
    (``u, v ~ U[0, 1)``, reflected to ``(1 - u, 1 - v)`` when ``u + v > 1``). Normal:
    ``(b - a) x (c - a) / |...|``. ``rng`` is a numpy Generator (or a seed for one); the result is a
    deterministic function of it. Returns ``points (n, 3)`` and ``normals (n, 3)``, float64.
    Raises ValueError when the mesh has no face of positive finite area.
    """
    rng = np.random.default_rng(rng)
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    a = vertices[faces[:, 0]]
    e1 = vertices[faces[:, 1]] - a
    e2 = vertices[faces[:, 2]] - a
    cross = np.cross(e1, e2)
    double_area = np.linalg.norm(cross, axis=1)
    double_area = np.where(np.isfinite(double_area), double_area, 0.0)
    cumulative = np.cumsum(double_area)
    total = cumulative[-1] if len(cumulative) else 0.0
    if not total > 0:
        raise ValueError("mesh has no face with positive area to sample")
    # face f is chosen when cumulative[f-1] <= x < cumulative[f]: a zero-area face never is
    face = np.searchsorted(cumulative, rng.random(n) * total, side="right")
    face = np.minimum(face, np.flatnonzero(double_area > 0)[-1])
    uv = rng.random((n, 2))
    flip = uv.sum(axis=1) > 1.0
    uv[flip] = 1.0 - uv[flip]
    points = a[face] + uv[:, :1] * e1[face] + uv[:, 1:] * e2[face]
    normals = cross[face] / double_area[face, None]
    return points, normals


def spatial_order(points: np.ndarray, cells_per_axis: int = 256) -> np.ndarray:
    """A permutation listing the points cell by cell (x-major cells of a 256^3 grid on their bbox).

    KD-tree queries on spatially sorted points are ~5x faster (cache locality) than on the random
    order that sampling produces; metrics are order-independent, so :func:`evaluate` sorts.
    """
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    lo = points.min(axis=0)
    size = float(np.max(points.max(axis=0) - lo))
    scale = cells_per_axis / size if size > 0 else 0.0
    ijk = np.minimum(((points - lo) * scale).astype(np.int64), cells_per_axis - 1)
    keys = (ijk[:, 0] * cells_per_axis + ijk[:, 1]) * cells_per_axis + ijk[:, 2]
    return np.argsort(keys, kind="stable")


def nearest_distances(query: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Euclidean distance from every query point to its nearest reference point, and its index.

    Exact k = 1 search with pykdtree (multi-threaded, deterministic). Returns ``(d (m,), idx (m,))``.
    """
    reference = np.ascontiguousarray(reference, dtype=np.float64)
    query = np.ascontiguousarray(query, dtype=np.float64)
    dist, idx = KDTree(reference).query(query, k=1)
    return np.asarray(dist, dtype=np.float64), np.asarray(idx, dtype=np.int64)


# --------------------------------------------------------------------------------------------
# Sharp-edge points
# --------------------------------------------------------------------------------------------

_MAX_CELLS_PER_AXIS = 1 << 20
_PAIR_BLOCK = 100_000
_DOT_CHUNK = 4_000_000

#: Default work limit of :func:`sharp_edge_points`: an upper bound on the ordered candidate pairs
#: (cell counts times 27-neighbourhood counts, ~3x the true count). A 1M-sample CAD mesh: 1e7-1e8.
MAX_EDGE_PAIRS = 1_000_000_000


class EdgeSearchTooDense(ValueError):
    """The exact edge-point search would enumerate more pairs than allowed (a degenerate input,
    e.g. a prediction far smaller than the GT so that all its samples lie within a few radii)."""


def sharp_edge_points(
    points: np.ndarray, normals: np.ndarray, radius: float, dot_threshold: float = 0.2, max_pairs: float = MAX_EDGE_PAIRS
) -> np.ndarray:
    """Boolean mask of the samples that are sharp-edge points (NDC's test).

    ``p`` is an edge point when some sample ``q`` of the same set has ``|p - q| <= radius`` and
    ``|n_p . n_q| < dot_threshold`` (``q = p`` never qualifies for unit normals). Exact: every pair
    within ``radius`` that could qualify is tested; no k-NN truncation.

    Method (chosen for speed at n = 1M: a full radius search finds ~20-40 neighbours per point,
    i.e. 10-20M pairs and 4-6 s per mesh, of which only the few near edges matter):

    1. *Conservative cell filter.* Hash the points into cubic cells of side ``s >= radius``; any
       neighbour of ``p`` lies in the 27 cells around p's cell. Per cell c take a representative
       normal ``m_c`` (its first point's) and ``dev_c = max_{p in c} angle(n_p, m_c)``, angles between
       *lines* (``arccos |dot|``, a metric on directions). For two cells c0, c1 of a 27-block every
       pair of their points has ``angle <= dev_c0 + angle(m_c0, m_c1) + dev_c1``; if that bound is below
       ``arccos(dot_threshold)`` (minus 1e-6 rad for rounding) for all 27 neighbours of c0, no pair
       touching c0 can qualify: c0 is *safe*. A qualifying pair therefore joins two points of unsafe
       cells, and the search is restricted to them (typically 5-40% of the samples).
    2. *Exact search* on the remaining candidates: scipy ``cKDTree.query_pairs(radius)`` (inclusive
       ``<=``, like sklearn's ``query_radius`` that NDC uses), in slabs of cell layers along the
       longest axis (each slab plus one layer of halo), so memory stays bounded.

    Raises :class:`EdgeSearchTooDense` (one line) when the cell counts bound the candidate pairs
    above ``max_pairs`` (samples far denser than the radius: minutes of work and tens of GB).
    The filter assumes unit (or zero) normals; with other normals it is skipped (plain exact search).
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    n = len(points)
    flags = np.zeros(n, dtype=bool)
    if n < 2 or not dot_threshold > 0 or not radius >= 0:
        return flags
    lengths = np.linalg.norm(normals, axis=1)
    unit = bool(np.all((np.abs(lengths - 1.0) < 1e-6) | (lengths == 0)))

    lo = points.min(axis=0)
    extent = float(np.max(points.max(axis=0) - lo))
    cell = max(float(radius), extent / _MAX_CELLS_PER_AXIS)
    if not cell > 0:
        cell = 1.0
    ijk = np.floor((points - lo) / cell).astype(np.int64) + 1  # +1: neighbour keys never wrap
    dims = ijk.max(axis=0) + 2
    keys = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]

    max_angle = np.arccos(dot_threshold) - 1e-6 if unit and dot_threshold <= 1.0 else -1.0
    candidate, pair_bound = _unsafe_points(keys, normals, dims, max_angle)
    if pair_bound > max_pairs:
        raise EdgeSearchTooDense(
            f"edge-point search too dense: up to {pair_bound:.3g} sample pairs within r = {radius:.4g} "
            f"(limit {max_pairs:.3g}); the samples span only {extent:.4g}"
        )
    cand = np.flatnonzero(candidate)
    if len(cand) < 2:
        return flags

    # slabs of cell layers along the axis with the most layers
    axis = int(np.argmax(np.ptp(ijk[cand], axis=0)))
    layer = ijk[cand, axis]
    order = np.lexsort((keys[cand], layer))  # by layer, then cell: spatially coherent trees
    cand, layer = cand[order], layer[order]
    block_first_layer = np.unique(np.concatenate([layer[:1], layer[_PAIR_BLOCK::_PAIR_BLOCK]]))
    block_last_layer = np.concatenate([block_first_layer[1:], [layer[-1] + 1]])  # inclusive halo layer
    starts = np.searchsorted(layer, block_first_layer, side="left")
    stops = np.searchsorted(layer, block_last_layer, side="right")
    for start, stop in zip(starts, stops):  # a loop over chunks (a thread pool gave no speed-up: GIL)
        members = cand[start:stop]
        pairs = cKDTree(points[members]).query_pairs(float(radius), output_type="ndarray")
        for chunk in range(0, len(pairs), _DOT_CHUNK):
            i, j = members[pairs[chunk : chunk + _DOT_CHUNK]].T
            hit = np.abs(np.einsum("ij,ij->i", normals[i], normals[j])) < dot_threshold
            flags[i[hit]] = True
            flags[j[hit]] = True
    return flags


def _unsafe_points(keys: np.ndarray, normals: np.ndarray, dims: np.ndarray, max_angle: float) -> tuple[np.ndarray, float]:
    """Step 1 of :func:`sharp_edge_points`: the points whose cell is not provably edge-free, and an
    upper bound on the ordered pairs among them within the radius (sum over unsafe cells c of
    ``count(c) * count(unsafe cells among the 27 around c)``). ``max_angle < 0``: no cell is safe."""
    cell_keys, first, inverse, counts = np.unique(keys, return_index=True, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    offsets = [(dx * dims[1] + dy) * dims[2] + dz for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)]

    def neighbours(offset):
        other = cell_keys + offset
        pos = np.minimum(np.searchsorted(cell_keys, other), len(cell_keys) - 1)
        hit = np.flatnonzero(cell_keys[pos] == other)
        return hit, pos[hit]

    if max_angle < 0:
        unsafe = np.ones(len(cell_keys), dtype=bool)
    else:
        rep = normals[first]
        cos_to_rep = np.abs(np.einsum("ij,ij->i", normals, rep[inverse]))
        min_cos = np.ones(len(cell_keys))
        np.minimum.at(min_cos, inverse, cos_to_rep)
        dev = np.arccos(np.clip(min_cos, 0.0, 1.0))
        bound = 2.0 * dev  # a cell with itself: dev + 0 + dev
        for offset in offsets:
            if offset == 0:
                continue
            c0, c1 = neighbours(offset)
            cos = np.abs(np.einsum("ij,ij->i", rep[c0], rep[c1]))
            bound[c0] = np.maximum(bound[c0], dev[c0] + np.arccos(np.clip(cos, 0.0, 1.0)) + dev[c1])
        unsafe = ~(bound < max_angle)
    unsafe_counts = np.where(unsafe, counts, 0).astype(np.float64)
    around = np.zeros(len(cell_keys))
    for offset in offsets:
        c0, c1 = neighbours(offset)
        around[c0] += unsafe_counts[c1]
    return unsafe[inverse], float(np.dot(unsafe_counts, around))


# --------------------------------------------------------------------------------------------
# Metric formulas on point sets
# --------------------------------------------------------------------------------------------


def _chamfer(d_gt_to_pred: np.ndarray, d_pred_to_gt: np.ndarray, form: str) -> tuple[float, float, float]:
    """(total, gt->pred term, pred->gt term) for the chamfer ``form``."""
    if form == "l1_half_mean":
        a, b = float(np.mean(d_gt_to_pred)), float(np.mean(d_pred_to_gt))
        return 0.5 * (a + b), a, b
    a, b = float(np.mean(np.square(d_gt_to_pred))), float(np.mean(np.square(d_pred_to_gt)))
    return a + b, a, b


def _f1(d_gt_to_pred: np.ndarray, d_pred_to_gt: np.ndarray, tau: float) -> tuple[float, float, float]:
    """(F1, precision, recall) at threshold tau, strict ``d < tau``."""
    recall = float(np.mean(d_gt_to_pred < tau))
    precision = float(np.mean(d_pred_to_gt < tau))
    f1 = 2.0 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return f1, precision, recall


def surface_metrics(gt_points, gt_normals, pred_points, pred_normals, preset: str | MetricPreset = "default") -> dict:
    """CD, NC and F1 between two oriented point sets (already in the preset's frame).

    Returns ``cd`` (preset's chamfer form), ``cd_gt_to_pred`` and ``cd_pred_to_gt`` (its two terms:
    means of d or d^2), ``nc``, and per threshold ``f1_*``, ``precision_*``, ``recall_*``.
    """
    preset = _get_preset(preset)
    d_gp, i_gp = nearest_distances(gt_points, pred_points)
    d_pg, i_pg = nearest_distances(pred_points, gt_points)
    out = {}
    out["cd"], out["cd_gt_to_pred"], out["cd_pred_to_gt"] = _chamfer(d_gp, d_pg, preset.chamfer)
    nc_gp = np.mean(np.abs(np.einsum("ij,ij->i", gt_normals, pred_normals[i_gp])))
    nc_pg = np.mean(np.abs(np.einsum("ij,ij->i", pred_normals, gt_normals[i_pg])))
    out["nc"] = float(0.5 * (nc_gp + nc_pg))
    for tau, key in zip(preset.f1_thresholds, preset.f1_keys):
        suffix = key[3:]
        out[key], out[f"precision_{suffix}"], out[f"recall_{suffix}"] = _f1(d_gp, d_pg, tau)
    return out


def edge_metrics(gt_edge_points, pred_edge_points, preset: str | MetricPreset = "default", gt_diagonal: float = 1.0) -> dict:
    """ECD and EF1 between two edge-point sets (in the preset's frame).

    ``gt_diagonal`` is D, the GT bounding-box diagonal, used when ``preset.edge_units`` is
    'gt_diagonal' (tau_e = ef1_threshold * D). Rules: GT without edge points -> ECD 0, EF1 1;
    prediction without edge points -> ``empty_edge_fallback`` origin points if the preset has one,
    else ECD NaN and EF1 0. ``ecd_flag`` is True when the prediction has no edge points but the GT
    has some. Returns ``ecd, ef1, eprecision, erecall, ecd_flag``.
    """
    preset = _get_preset(preset)
    gt_edge_points = np.asarray(gt_edge_points, dtype=np.float64).reshape(-1, 3)
    pred_edge_points = np.asarray(pred_edge_points, dtype=np.float64).reshape(-1, 3)
    unit = gt_diagonal if preset.edge_units == "gt_diagonal" else 1.0
    if len(gt_edge_points) == 0:
        return {"ecd": 0.0, "ef1": 1.0, "eprecision": 1.0, "erecall": 1.0, "ecd_flag": False}
    flag = len(pred_edge_points) == 0
    if flag:
        if preset.empty_edge_fallback <= 0:
            return {"ecd": float("nan"), "ef1": 0.0, "eprecision": 0.0, "erecall": 0.0, "ecd_flag": True}
        pred_edge_points = np.zeros((preset.empty_edge_fallback, 3))
    d_gp, _ = nearest_distances(gt_edge_points, pred_edge_points)
    d_pg, _ = nearest_distances(pred_edge_points, gt_edge_points)
    ecd, _, _ = _chamfer(d_gp, d_pg, preset.ecd)
    ef1, eprecision, erecall = _f1(d_gp, d_pg, preset.ef1_threshold * unit)
    return {"ecd": ecd, "ef1": ef1, "eprecision": eprecision, "erecall": erecall, "ecd_flag": flag}


# --------------------------------------------------------------------------------------------
# Mesh validity
# --------------------------------------------------------------------------------------------


def mesh_validity(vertices: np.ndarray, faces: np.ndarray) -> dict:
    """Topology counts of a triangle mesh, on its faces *as given* (no vertex merging).

    An undirected edge is a pair of vertex indices used by a face side (duplicated vertex positions
    with different indices are different vertices, so a triangle soup has only boundary edges).
    ``boundary_edges``: edges used by exactly one face side; ``nonmanifold_edges``: used by more
    than two; ``components``: connected components of faces, two faces being connected when they
    share an edge (sharing only a vertex does not connect); ``watertight``: at least one face and
    every edge used by exactly two face sides.
    """
    vertices = np.asarray(vertices).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    m = len(faces)
    out = {"n_vertices": int(len(vertices)), "n_faces": int(m)}
    if m == 0:
        out.update(boundary_edges=0, nonmanifold_edges=0, components=0, watertight=False)
        return out
    sides = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)  # face f owns rows 3f..3f+2
    sides = sides - min(int(sides.min()), 0)  # out-of-range indices are counted as given
    side_keys = sides[:, 0] * (int(sides.max()) + 1) + sides[:, 1]
    edge_keys, edge_of_side, uses = np.unique(side_keys, return_inverse=True, return_counts=True)
    edge_of_side = edge_of_side.reshape(-1)
    boundary = int(np.sum(uses == 1))
    nonmanifold = int(np.sum(uses > 2))
    # bipartite face-edge graph: its components are the edge-connected face components
    face_of_side = np.repeat(np.arange(m), 3)
    graph = coo_matrix(
        (np.ones(3 * m, dtype=np.int8), (face_of_side, m + edge_of_side)), shape=(m + len(edge_keys),) * 2
    )
    components, _ = connected_components(graph, directed=False)
    out.update(
        boundary_edges=boundary,
        nonmanifold_edges=nonmanifold,
        components=int(components),
        watertight=bool(boundary == 0 and nonmanifold == 0),
    )
    return out


# --------------------------------------------------------------------------------------------
# evaluate / floor
# --------------------------------------------------------------------------------------------


def _bbox(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    used = vertices[np.unique(faces)]
    return used.min(axis=0), used.max(axis=0)


def _usable_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces with in-range indices and finite vertex coordinates (the rest are dropped)."""
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0 or vertices.ndim != 2 or len(vertices) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    ok = np.all((faces >= 0) & (faces < len(vertices)), axis=1)
    finite = np.all(np.isfinite(vertices), axis=1)
    ok[ok] = np.all(finite[faces[ok]], axis=1)
    return faces[ok]


def evaluate(
    gt_vertices,
    gt_faces,
    pred_vertices,
    pred_faces,
    preset: str | MetricPreset = "default",
    seed: int = 0,
    n_points: int | None = None,
) -> dict:
    """All SPEC section 7 metrics of a prediction against a GT mesh. Never raises on the prediction.

    Inputs are vertex (n, 3) and face (m, 3) arrays in one frame: the GT's canonical frame for the
    ``default`` preset (they are used as given); for ``ndc`` both are first mapped by
    ``x -> (x - c) / D`` (c, D = GT bounding-box centre and diagonal). ``n_points`` overrides the
    preset's sample count. GT samples come from stream 0 and prediction samples from stream 1 of
    ``SeedSequence(seed)``.

    Returns a flat dict of raw (unscaled) values: ``cd, cd_gt_to_pred, cd_pred_to_gt, nc``,
    ``f1_*/precision_*/recall_*`` per threshold, ``ecd, ef1, eprecision, erecall, ecd_flag``,
    ``gt_edge_points, pred_edge_points`` (counts; -1 = not computed), ``edge_search_skipped`` ('' or
    why the exact edge search was refused, :class:`EdgeSearchTooDense`: ECD/EF1 are then NaN; happens
    for samples far denser than r, e.g. a prediction 100x smaller than the GT), ``empty_prediction``, ``dropped_faces`` (faces with
    out-of-range indices or non-finite vertices, excluded from sampling), the validity columns of
    the prediction as given (:func:`mesh_validity`), and the protocol: ``preset, n_points, seed,
    gt_diagonal, edge_radius, ef1_threshold`` (absolute, in the frame) and ``seconds`` (per stage).
    Raises ValueError only for an unusable GT (no faces of positive area, NaN vertices).
    """
    t_start = time.perf_counter()
    preset = _get_preset(preset)
    n = int(preset.n_points if n_points is None else n_points)
    if n < 1:
        raise ValueError(f"n_points must be >= 1, got {n}")
    gt_vertices = np.asarray(gt_vertices, dtype=np.float64)
    gt_faces = np.asarray(gt_faces, dtype=np.int64)
    pred_vertices = np.asarray(pred_vertices, dtype=np.float64)
    pred_faces = np.asarray(pred_faces)
    pred_faces = pred_faces.astype(np.int64) if pred_faces.size else np.zeros((0, 3), dtype=np.int64)
    if pred_vertices.size == 0:
        pred_vertices = np.zeros((0, 3))

    if gt_faces.ndim != 2 or gt_faces.shape[1] != 3 or len(gt_faces) == 0:
        raise ValueError("GT mesh has no triangles")
    if len(_usable_faces(gt_vertices, gt_faces)) != len(gt_faces):
        raise ValueError("GT mesh has out-of-range face indices or non-finite vertices")
    lo, hi = _bbox(gt_vertices, gt_faces)
    if preset.frame == "diag1":
        centre, diag = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
        if not diag > 0:
            raise ValueError("GT bounding box has zero size")
        gt_vertices = (gt_vertices - centre) / diag
        pred_vertices = (pred_vertices - centre) / diag
        lo, hi = (lo - centre) / diag, (hi - centre) / diag
    gt_diagonal = float(np.linalg.norm(hi - lo))
    unit = gt_diagonal if preset.edge_units == "gt_diagonal" else 1.0
    radius, tau_e = preset.edge_radius * unit, preset.ef1_threshold * unit

    seconds = {}
    t = time.perf_counter()
    validity = mesh_validity(pred_vertices, pred_faces)
    usable = _usable_faces(pred_vertices, pred_faces)
    seconds["validity"] = time.perf_counter() - t

    gt_stream, pred_stream = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    t = time.perf_counter()
    gt_points, gt_normals = sample_surface(gt_vertices, gt_faces, n, gt_stream)
    try:
        pred_points, pred_normals = sample_surface(pred_vertices, usable, n, pred_stream)
        empty = False
    except ValueError:  # no faces, or zero total area
        pred_points = pred_normals = np.zeros((0, 3))
        empty = True
    # spatial order: same point sets, much faster KD-tree queries
    order = spatial_order(gt_points)
    gt_points, gt_normals = gt_points[order], gt_normals[order]
    order = spatial_order(pred_points)
    pred_points, pred_normals = pred_points[order], pred_normals[order]
    seconds["sample"] = time.perf_counter() - t

    result = {"preset": preset.name, "n_points": n, "seed": int(seed)}
    t = time.perf_counter()
    if empty:
        result.update(cd=float("nan"), cd_gt_to_pred=float("nan"), cd_pred_to_gt=float("nan"), nc=float("nan"))
        for key in preset.f1_keys:
            result.update({key: 0.0, f"precision_{key[3:]}": 0.0, f"recall_{key[3:]}": 0.0})
    else:
        result.update(surface_metrics(gt_points, gt_normals, pred_points, pred_normals, preset))
    seconds["distances"] = time.perf_counter() - t

    t = time.perf_counter()
    skipped = ""
    try:
        gt_edge = sharp_edge_points(gt_points, gt_normals, radius, preset.edge_dot_threshold)
    except EdgeSearchTooDense as exc:
        gt_edge, skipped = None, f"GT {exc}"
    try:
        pred_edge = sharp_edge_points(pred_points, pred_normals, radius, preset.edge_dot_threshold)
    except EdgeSearchTooDense as exc:
        pred_edge, skipped = None, skipped or f"prediction {exc}"
    seconds["edge_points"] = time.perf_counter() - t
    t = time.perf_counter()
    nan = float("nan")
    if empty:
        has_gt_edges = gt_edge is None or bool(gt_edge.any())
        edges = {"ecd": nan, "ef1": 0.0, "eprecision": 0.0, "erecall": 0.0, "ecd_flag": has_gt_edges}
    elif skipped:
        edges = {"ecd": nan, "ef1": nan, "eprecision": nan, "erecall": nan, "ecd_flag": False}
    else:
        edges = edge_metrics(gt_points[gt_edge], pred_points[pred_edge], preset, gt_diagonal)
    seconds["edge_metrics"] = time.perf_counter() - t
    result.update(edges)
    result.update(
        gt_edge_points=-1 if gt_edge is None else int(gt_edge.sum()),
        pred_edge_points=-1 if pred_edge is None else int(pred_edge.sum()),
        edge_search_skipped=skipped,
        empty_prediction=empty,
        dropped_faces=int(len(pred_faces) - len(usable)),
    )
    result.update(validity)
    result.update(gt_diagonal=gt_diagonal, edge_radius=radius, ef1_threshold=tau_e)
    seconds["total"] = time.perf_counter() - t_start
    result["seconds"] = seconds
    return result


def floor(gt_vertices, gt_faces, preset: str | MetricPreset = "default", seed: int = 0, n_points: int | None = None) -> dict:
    """The protocol's noise floor: the GT scored against an independent resample of itself.

    Identical to ``evaluate(gt, gt, preset, seed)``: the prediction's samples come from a
    different stream of the seed than the GT's, so the two point sets are independent draws.
    """
    return evaluate(gt_vertices, gt_faces, gt_vertices, gt_faces, preset=preset, seed=seed, n_points=n_points)


# --------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------


def _format_table(result: dict, preset: MetricPreset, frame_note: str) -> str:
    scale = preset.report_scale
    rows = [("CD", "cd"), ("CD gt->pred", "cd_gt_to_pred"), ("CD pred->gt", "cd_pred_to_gt"), ("NC", "nc")]
    rows += [(f"F1@{t:g}", k) for t, k in zip(preset.f1_thresholds, preset.f1_keys)]
    rows += [("ECD", "ecd"), ("EF1", "ef1")]
    lines = [preset.describe(), f"seed {result['seed']}, n = {result['n_points']:,} points per mesh; {frame_note}", ""]
    for label, key in rows:
        s = scale.get(key, 1.0)
        name = f"{label} (x{s:g})" if s != 1.0 else label
        lines.append(f"  {name:<22} {result[key] * s:.6g}")
    flag = "  (prediction has no edge points" + (": ECD NaN)" if preset.empty_edge_fallback == 0 else f": {preset.empty_edge_fallback} origin points used)")
    lines.append(f"  {'edge points gt/pred':<22} {result['gt_edge_points']:,} / {result['pred_edge_points']:,}" + (flag if result["ecd_flag"] else ""))
    lines.append("")
    lines.append(
        f"  prediction: {result['n_vertices']:,} vertices, {result['n_faces']:,} faces, {result['boundary_edges']:,} boundary edges, "
        f"{result['nonmanifold_edges']:,} non-manifold edges, {result['components']:,} components, "
        f"watertight {'yes' if result['watertight'] else 'no'}"
    )
    if result["edge_search_skipped"]:
        lines.append(f"  ECD/EF1 not computed: {result['edge_search_skipped']}")
    if result["empty_prediction"]:
        lines.append("  prediction is EMPTY or degenerate (no area to sample): distance metrics NaN, F1 = 0")
    if result["dropped_faces"]:
        lines.append(f"  {result['dropped_faces']:,} prediction faces dropped (out-of-range indices or non-finite vertices)")
    lines.append(f"  time {result['seconds']['total']:.2f} s")
    return "\n".join(lines)


def _json_safe(value):
    """NaN/inf -> None (JSON null), numpy scalars -> Python, recursively."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    return value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m benchmark.metrics", description="Score a predicted mesh against a GT mesh (SPEC section 7)."
    )
    parser.add_argument("gt", help="ground-truth mesh file")
    parser.add_argument("pred", help="predicted mesh file")
    parser.add_argument("--points", type=int, default=None, help="samples per mesh (default: the preset's)")
    parser.add_argument("--preset", choices=sorted(PRESETS), default="default")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument(
        "--no-normalize", action="store_true", help="use both meshes as stored (default: map both by the GT's canonical transform)"
    )
    args = parser.parse_args(argv)

    from datasets.io import MeshError, canonical_transform, read_mesh_arrays

    try:
        if args.points is not None and args.points < 1:
            raise MeshError(f"--points must be >= 1, got {args.points}")
        gt_v, gt_f = read_mesh_arrays(args.gt)
        pred_v, pred_f = read_mesh_arrays(args.pred)
        if args.no_normalize:
            frame_note = "meshes used as stored (--no-normalize)"
        else:
            try:
                transform = canonical_transform(gt_v[np.unique(gt_f)])
            except MeshError as exc:
                raise MeshError(f"{args.gt}: {exc}") from None
            gt_v, pred_v = transform.apply(gt_v), transform.apply(pred_v)
            frame_note = "both meshes mapped by the GT's canonical transform"
        result = evaluate(gt_v, gt_f, pred_v, pred_f, preset=args.preset, seed=args.seed, n_points=args.points)
    except (MeshError, ValueError, MemoryError) as exc:
        print(f"error: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}", file=sys.stderr)
        return 2
    result["gt"], result["pred"] = str(args.gt), str(args.pred)
    result["normalized"] = not args.no_normalize
    if args.json:
        print(json.dumps(_json_safe(result), indent=2))
    else:
        print(_format_table(result, PRESETS[args.preset], frame_note))
    return 0


if __name__ == "__main__":
    sys.exit(main())
