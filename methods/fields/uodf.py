"""``uodf``: unsigned orthogonal distance fields (Lu et al., CVPR 2024) fitted as its authors fit them,
one distance network and one mask network per axis, + their point extraction and screened Poisson.

Field: at a point x, for each axis a, the distance f_a(x) along the line x + t e_a to the nearest
surface point on it, either way (``ExactFields.orthogonal_distances``), and the mask m_a: whether
that line hits the surface at all.

Networks: one :class:`methods.core.network.StackedNetworks` of six independent members, outputs
(f_x, f_y, f_z, m_x, m_y, m_z). Member a < 3 is axis a's distance network, the budget's backbone
with one output on x; member 3 + a is axis a's mask network, the budget's backbone with at most
:data:`MASK_DEPTH` linear layers (the authors' mask network has 3) and one output, a logit, on x with
its coordinate a set to 0: a function of the line only. Every member has the budget's size; they
train together in one optimizer on the sum of their losses, which (disjoint parameters, AdamW per
parameter) is six separate fits with the same steps and batches.

Targets: per axis, the exact distance d_a where the a-line hits (:data:`NO_HIT` elsewhere, read by
no loss) and the flag hit_a. Loss: per axis, the authors' three terms over the samples whose
a-line hits (their distance networks never see a line that misses), with their weights relative to
the L1 (3e3 : 5e1 : 1e3)::

    mean_hit |f_a - d_a|
    + 50/3000   * mean_hit | |df_a/dx_a| - 1 |                 (axis eikonal)
    + 1000/3000 * mean_hit | f_a(x + s_a |f_a| e_a) |           (the predicted hit is on the surface)

with s_a = +1 where df_a/dx_a < 0 (the surface lies towards +e_a), else -1 (not differentiated),
plus the mask's binary cross-entropy of sigmoid(m_a) against hit_a over every sample; summed over
the axes.

Extraction (:func:`surface_points_along`, :func:`remove_outliers`, :func:`poisson_mesh`), per axis a
along every grid line the mask keeps (m_a >= 0): each grid point predicts the hit c + s_a f_a e_a;
a run of consecutive points with s_a = +1 followed by a point with s_a = -1 and f_a <= 1 (a
crossing) gives the mean of the run's predicted hits if the run has >= 2 points; symmetrically the
run of s_a = -1 after the crossing. Per crossing the second estimate is dropped when within
``dedupe`` h of the first. The three axes' points are then filtered (a point is an outlier when its
nearest point of the other two axes is farther than 1.5 h *and* its second-nearest point of its own
axis farther than 2 h), given PCA normals (10 neighbours), meshed by screened Poisson (depth
round(log2 N); full depth 5, 8 iterations, point weight 4, 1.5 samples per node, scale 1.1) and
trimmed: vertices farther than ``trim`` h (0.945 h, the authors' limit at their 257^3 grid) from the
nearest point are removed with their faces.
Oracle: the exact distances and sides on the grid (``ExactFields.grid_orthogonal_distances``; side
0 on the lines that miss: the exact mask).
Neural: the sparse query of :mod:`methods.core.query` (criterion: some corner has an axis the mask
keeps with |f_a| below sqrt(3) times the block's half diagonal), then s_a = -sign(df_a/dx_a) by
autograd at the evaluated points (:func:`fitted_sides`); points the query skips and lines the mask
drops get side 0, which ends every run.
"""

from __future__ import annotations

import numpy as np
import torch

from foundation.grid import axis_coords, point_inputs, spacing
from foundation.params import Param
from foundation.timing import stage
from methods.core import query
from methods.base import Extraction, FieldMethod, register_method
from methods.core.network import value_and_input_gradients
from methods.extractors.mesh_ops import keep_vertices
from methods.extractors.meshlab import poisson_depth

#: The distance a target or the exact grid field holds where the axis line hits nothing (the cube's
#: side: no hit inside it is farther). No loss reads it and no side goes with it.
NO_HIT = 2.0
#: Weights of the eikonal and hit-point terms relative to the L1 (the authors' 5e1 / 3e3, 1e3 / 3e3).
EIKONAL_WEIGHT = 50.0 / 3000.0
HIT_WEIGHT = 1000.0 / 3000.0
#: Linear layers of a mask network at most (the authors': PE -> 256 -> 256 -> 1).
MASK_DEPTH = 3
#: A crossing gives a point only where the distance after it is at most this (canonical units).
MAX_CROSSING_DISTANCE = 1.0
#: Runs shorter than this give no point (the authors' ``postprocessingThreshold`` 1: length > 1).
MIN_RUN = 2
#: Trimming distance in units of h: the authors' squared limit 2 / res * 0.007 at their grid res = 257
#: (h = 2 / 256), sqrt(0.014 / 257) / (2 / 256) = 0.945.
TRIM_FACTOR = float(np.sqrt(0.014 / 257) * 128)


# ------------------------------------------------------------------------------------------------
# the networks' field
# ------------------------------------------------------------------------------------------------
def stack_config(member: dict) -> dict:
    """``make_network`` arguments of the six networks from one backbone's (``budget.network_config()``):
    three distance networks on x, then three mask networks (at most :data:`MASK_DEPTH` layers), the
    mask of axis a on x with column a zeroed; one output each."""
    distance = {**member, "out_dim": 1}
    mask = {**distance, "depth": min(int(member.get("depth", MASK_DEPTH)), MASK_DEPTH)}
    return {"backbone": "stack", "members": [distance] * 3 + [mask] * 3, "zeroed": [[], [], [], [0], [1], [2]]}


def side_from_derivative(derivative):
    """+1 where the field decreases along the axis (surface towards +e_a), else -1 (the authors' rule)."""
    if isinstance(derivative, torch.Tensor):
        return torch.where(derivative < 0, 1.0, -1.0).to(derivative.dtype)
    return np.where(derivative < 0, 1, -1).astype(np.int8)


def axis_terms(model, x: torch.Tensor, axis: int, create_graph: bool = True):
    """Axis ``axis``'s distance network at x (B, 3): (f (B,), df/dx_axis (B,), f at the predicted hit
    x + s |f| e_axis (B,)), s from :func:`side_from_derivative` of the detached derivative."""
    net = model.nets[axis]
    f, (grad,) = value_and_input_gradients(net, x, (0,), create_graph)
    f, derivative = f[:, 0], grad[:, axis]
    step = side_from_derivative(derivative.detach()) * f.abs()
    hit = x + step[:, None] * torch.eye(3, dtype=x.dtype, device=x.device)[axis]
    return f, derivative, net(hit)[:, 0]


def fitted_sides(model, points: np.ndarray, device=None, mask_logits: np.ndarray | None = None) -> np.ndarray:
    """The fitted sides (P, 3) int8 at ``points`` (P, 3): s_a from the sign of df_a/dx_a, 0 where the
    mask network drops the a-line (``mask_logits`` (P, 3), the stack's outputs 3..5, evaluated if
    not given)."""
    points = np.ascontiguousarray(points, dtype=np.float32)
    if mask_logits is None:
        mask_logits = query.evaluate(model, points, device)[:, 3:]
    side = np.zeros((len(points), 3), dtype=np.int8)
    for a in range(3):
        _, grads = query.evaluate_with_input_grads(model.nets[a], points, (0,), device)
        side[:, a] = np.where(mask_logits[:, a] >= 0, side_from_derivative(grads[:, 0, a]), 0)
    return side


def side_agreement(model, fields, N: int, band: float = 2.0, device=None) -> float:
    """The share of near-surface (grid point, axis) pairs whose fitted side (:func:`fitted_sides`, the
    mask included) is the exact one (``fields.grid_orthogonal_distances``): the points of the N^3 grid
    within ``band`` h of the surface (exact unsigned distance), each with every axis whose line
    through it hits the surface."""
    h = spacing(N)
    distance, side = fields.grid_orthogonal_distances(N)
    hit = np.isfinite(distance)
    # the unsigned distance is at most every axis distance: only these points can lie within the band
    ijk = np.argwhere(np.where(hit, distance, np.inf).min(axis=-1) < band * h)
    points = point_inputs(N, ijk)
    near = fields.udf(points) < band * h
    ijk, points = ijk[near], points[near]
    pairs = hit[tuple(ijk.T)]
    fitted = fitted_sides(model, points, device)
    return float((fitted == side[tuple(ijk.T)])[pairs].mean())


def near_surface(margin: float):
    """Sparse-query block criterion on the stack's outputs: some corner has an axis a whose mask
    keeps the line (m_a >= 0) and |f_a| below ``margin``."""

    def near(corners: np.ndarray) -> np.ndarray:
        close = (np.abs(corners[..., :3]) < margin) & (corners[..., 3:] >= 0)
        return close.any(axis=(-2, -1))

    return near


# ------------------------------------------------------------------------------------------------
# extraction
# ------------------------------------------------------------------------------------------------
def _lines_along(array: np.ndarray, axis: int) -> np.ndarray:
    """A grid array (N, N, N) as (N^2, N): grid lines along ``axis`` (other axes in order) by points."""
    N = array.shape[0]
    return np.moveaxis(array, axis, 2).reshape(N * N, N)


def crossing_estimates(distance: np.ndarray, side: np.ndarray, coords: np.ndarray):
    """Hit estimates along lines (L, N): the authors' run averages at each crossing.

    ``distance``, ``side`` (L, N) along each line, ``coords`` (N,) the points' coordinates. A
    crossing is a point pair (i - 1, i) with side +1 then -1. Returns, per crossing, (line id, i,
    the first estimate, whether it counts, the second estimate, whether it counts): the first is the
    mean predicted hit of the +1 run ending at i - 1, counted if the run has >= MIN_RUN points and
    distance[i] <= MAX_CROSSING_DISTANCE; the second that of the -1 run starting at i, under the
    mirrored conditions.
    """
    L, N = side.shape
    predicted = coords[None, :] + side * distance  # the hit each point predicts
    starts = np.ones((L, N), dtype=bool)
    starts[:, 1:] = side[:, 1:] != side[:, :-1]
    run = np.cumsum(starts.reshape(-1)) - 1  # run id of every point, runs never span two lines
    length = np.bincount(run)
    mean = np.bincount(run, weights=predicted.reshape(-1)) / length
    line, i = np.nonzero((side[:, :-1] == 1) & (side[:, 1:] == -1))
    i = i + 1
    before, after = run[line * N + i - 1], run[line * N + i]
    ok_before = (length[before] >= MIN_RUN) & (distance[line, i] <= MAX_CROSSING_DISTANCE)
    ok_after = (length[after] >= MIN_RUN) & (distance[line, i - 1] <= MAX_CROSSING_DISTANCE)
    return line, i, mean[before], ok_before, mean[after], ok_after


def surface_points_along(distance: np.ndarray, side: np.ndarray, axis: int, dedupe: float) -> np.ndarray:
    """Surface points (K, 3) read off one axis' field on the grid ((N, N, N) each): the crossing
    estimates of every grid line along ``axis``, the second of a crossing dropped when within
    ``dedupe`` of the first."""
    N = distance.shape[0]
    coords = axis_coords(N)
    line, _, first, ok_first, second, ok_second = crossing_estimates(
        _lines_along(distance, axis), _lines_along(side, axis), coords)
    ok_second &= ~(ok_first & (np.abs(second - first) < dedupe))
    line = np.concatenate([line[ok_first], line[ok_second]])
    along = np.concatenate([first[ok_first], second[ok_second]])
    others = [b for b in range(3) if b != axis]
    points = np.empty((len(line), 3))
    points[:, axis] = along
    points[:, others[0]], points[:, others[1]] = coords[line // N], coords[line % N]
    return points


def remove_outliers(per_axis: list[np.ndarray], h: float) -> tuple[np.ndarray, int]:
    """The authors' filter of the three axes' points: a point is removed when its nearest point of
    the other two axes is farther than 1.5 h and its second-nearest other point of its own axis
    farther than 2 h. Returns (kept points (K, 3), points removed)."""
    from scipy.spatial import cKDTree

    kept = []
    for a, points in enumerate(per_axis):
        if len(points) == 0:
            continue
        others = np.concatenate([per_axis[b] for b in range(3) if b != a])
        far_other = cKDTree(others).query(points)[0] > 1.5 * h if len(others) else np.ones(len(points), bool)
        if len(points) >= 3:
            far_own = cKDTree(points).query(points, k=3)[0][:, 2] > 2.0 * h
        else:
            far_own = np.ones(len(points), bool)
        kept.append(points[~(far_other & far_own)])
    total = sum(len(p) for p in per_axis)
    out = np.concatenate(kept) if kept else np.zeros((0, 3))
    return out, total - len(out)


def poisson_mesh(points: np.ndarray, depth: int, normal_k: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Screened Poisson (pymeshlab) of ``points`` with PCA normals, the authors' MeshLab settings."""
    from methods.extractors.meshlab import current_mesh, oriented_point_set

    ms = oriented_point_set(points, normal_k)
    with stage("poisson"):
        ms.generate_surface_reconstruction_screened_poisson(depth=depth, fulldepth=5, iters=8, pointweight=4.0,
                                                             samplespernode=1.5, scale=1.1, preclean=False,
                                                             threads=1)
    V, F, _ = current_mesh(ms)
    return V, F


def trim_far_vertices(V: np.ndarray, F: np.ndarray, points: np.ndarray, limit: float):
    """Remove the vertices farther than ``limit`` from the nearest of ``points``, with every face
    using one; returns (vertices, faces reindexed, vertices removed)."""
    from scipy.spatial import cKDTree

    return keep_vertices(V, F, cKDTree(points).query(V)[0] <= limit)


# ------------------------------------------------------------------------------------------------
# the method
# ------------------------------------------------------------------------------------------------
@register_method(order=45, color="#e377c2",
                 note="uodf fits a distance and a mask network per axis, as its authors do, each on the run's "
                      "backbone (theirs: an MLP with a positional encoding of the line).")
class UODFMethod(FieldMethod):
    name = "uodf"
    description = ("unsigned orthogonal distance fields, the authors' fit (a distance and a mask network per axis) "
                   "+ UODF point extraction and screened Poisson")
    input_kind = "points"
    output_dim = 6
    extractor = "UODF points + Poisson"
    parameters = {
        "dedupe": Param(1.0, "a crossing's second estimate is dropped within this x h of the first", ge=0),
        "normal_k": Param(10, "neighbours of the PCA normals before Poisson", ge=3),
        "trim": Param(TRIM_FACTOR, "Poisson vertices farther than this x h from every point are removed", gt=0),
        "stride": Param(query.DEFAULT_STRIDE, "coarse stride of the sparse query", ge=1, neural_only=True),
    }

    def network_config(self, budget) -> dict:
        return stack_config(budget.network_config())

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        d, _ = fields.orthogonal_distances(samples.points)
        hit = np.isfinite(d)
        return {"distance": np.where(hit, d, NO_HIT).astype(np.float32), "hit": hit.astype(np.float32)}

    def predict(self, model, inputs):
        """(f (B, 3), df_a/dx_a (B, 3), f_a at the predicted hit along a (B, 3), mask logits (B, 3))."""
        terms = [axis_terms(model, inputs, a) for a in range(3)]
        f, derivative, at_hits = (torch.stack(t, dim=1) for t in zip(*terms))
        masks = torch.cat([model.member(3 + a, inputs) for a in range(3)], dim=1)
        return f, derivative, at_hits, masks

    def loss(self, prediction, targets):
        f, derivative, at_hits, masks = prediction
        d, hit = targets["distance"], targets["hit"]
        count = hit.sum(dim=0).clamp(min=1.0)  # per axis

        def mean_hit(values):
            return ((values * hit).sum(dim=0) / count).sum()

        l1 = mean_hit((f - d).abs())
        eikonal = mean_hit((derivative.abs() - 1.0).abs())
        on_surface = mean_hit(at_hits.abs())
        mask = torch.nn.functional.binary_cross_entropy_with_logits(masks, hit, reduction="none").mean(dim=0).sum()
        return l1 + EIKONAL_WEIGHT * eikonal + HIT_WEIGHT * on_surface + mask

    def oracle_grid(self, fields, N, cache):
        d, side = fields.grid_orthogonal_distances(N)
        return {"distance": np.minimum(d, NO_HIT).astype(np.float32), "side": side}, {}

    def neural_grid(self, model, N, device=None):
        stride = self.params["stride"]
        margin = np.sqrt(3.0) * query.block_half_diagonal(N, stride)
        with stage("values"):
            values, evaluated, info = query.sparse_grid_points(model, N, near_surface(margin), device, stride=stride)
        with stage("sides"):
            side = np.zeros(values.shape[:3] + (3,), dtype=np.int8)
            ijk = np.argwhere(evaluated)
            side[tuple(ijk.T)] = fitted_sides(model, point_inputs(N, ijk), device, values[evaluated][:, 3:])
        return {"distance": np.abs(values[..., :3]), "side": side}, {"query_fraction": info.fraction}

    def extract(self, grid_field, N) -> Extraction:
        h = spacing(N)
        distance, side = grid_field["distance"], grid_field["side"]
        with stage("points"):
            per_axis = [surface_points_along(distance[..., a], side[..., a], a, self.params["dedupe"] * h)
                        for a in range(3)]
        with stage("filter"):
            points, removed = remove_outliers(per_axis, h)
        info = {"surface_points": int(sum(len(p) for p in per_axis)), "outlier_points": removed}
        if len(points) < 4 * self.params["normal_k"]:
            return Extraction(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), info)
        depth = poisson_depth(N)
        V, F = poisson_mesh(points, depth, self.params["normal_k"])
        with stage("trim"):
            V, F, trimmed = trim_far_vertices(V, F, points, self.params["trim"] * h)
        return Extraction(V, F, {**info, "poisson_depth": depth, "trimmed_vertices": trimmed})
