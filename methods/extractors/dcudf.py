"""DCUDF (Hou et al., SIGGRAPH Asia 2023): the zero level set of an unsigned distance field from its
double cover.

The level set ``{d = r}`` of a UDF ``d`` at a small ``r`` is a closed surface that wraps the surface
``{d = 0}`` on both sides (its *double cover*). Steps, with the constants of the authors'
``dcudf/mesh_extraction.py`` and ``dcudf/mesh_cut.py``:

1. **Double cover** (:func:`double_cover`): marching cubes of the grid UDF at level ``r``. The grid
   is padded with layers of the field on every side first, so that the cover is whole where the
   surface lies within ``r`` of the grid's faces (the authors' grid spans the shape's box plus a
   margin larger than ``r``).
2. **Optimisation** (:func:`optimise_vertices`): the vertices move toward ``d = 0``. Loss per
   iteration: mean d at the vertices + mean d at the face centroids; for the first ``normal_step``
   iterations (inclusive) + ``laplacian_weight`` x mean over the vertices of ``a_v |L x_v|^2`` (``L``
   the uniform Laplacian, ``a_v = max_u s_u / s_v``, ``s_v`` the square root of the area of the
   faces around v); after them + 0.5 x mean over the faces of ``|(c - c_0) x n_0|`` (the centroid's
   move off the line along the face normal frozen at iteration ``normal_step``). VectorAdam
   (:class:`VectorAdam`: Adam whose second moment is the squared norm of each vertex's gradient)
   with the authors' schedule (:func:`learning_rate`).
3. **Min-cut** (:func:`mesh_cut`): drop the face-connected components of fewer faces than a fifth of
   the vertices; pick a random seed face, grow a region of ``F / region_rate`` faces around it, take
   the nearest face outside it (by centroid) as the sink and grow its region likewise; cut the
   face-adjacency graph between the two regions with weights ``exp(200 (max angle - dihedral)) + 1``
   (so the cut runs along the folds of the cover); retry with another seed when the two parts differ
   by more than 15 % (after 6 failures with regions 1.5 x smaller, 21 times at most); give the
   larger part the faces around its non-manifold vertices until it has none; keep the part with
   more vertices.

Units: the canonical frame (the shape's largest side 1.99, the grid cube [-1, 1]^3 with N points per
axis, spacing h = 2 / (N - 1)). The authors state their constants in a frame where the shape's
largest side is 1 (their ``evaluate.py``); :data:`FRAME_SCALE` converts them: lengths (r, the
learning rate, which is a vertex's step length) are multiplied by it, the Laplacian weight (it
weighs squared lengths against lengths) is divided by it. Their r is 0.005 at 256^3 and their
README scales it with the resolution (``256 / res x 0.005``) and the Laplacian weight with it
(500 at 64^3, 2000 at 256^3): :func:`authors_r`, :func:`authors_laplacian_weight`. With fewer
iterations than their 400, the end of the Laplacian stage, the warm-up and the learning-rate drop
come in proportion and the learning rate grows by 400 / iterations (:func:`authors_lr`).

Max-flow: scipy's ``maximum_flow`` takes int32 capacities, while the authors' weights span up to
e^628. :func:`integer_capacities` rescales them exactly where it matters: every cut costs at least
the bottleneck weight (the least weight at which the edges up to it separate the two regions), a
known cut costs U; capacities are scaled so that U is 2^30 and rounded (each at least 1), and
weights above U, which no minimum cut contains, are capped just above it. The cut found is a
minimum cut of the float weights up to one unit (U / 2^30) per cut edge.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import torch
import trimesh
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, maximum_flow
from scipy.spatial import cKDTree

from foundation.grid import LOWER, spacing
from foundation.timing import stage
from methods.core.schedules import warmup_then_cosine
from methods.base import Extraction
from methods.core.device import get_device
from methods.extractors.marching_cubes import marching_cubes_grid
from methods.extractors.mesh_ops import drop_unreferenced_vertices

#: Largest side of the shape in the canonical frame over the authors' (1).
FRAME_SCALE = 1.99
#: The authors' r at their resolution, and that resolution (their frame).
AUTHORS_R, AUTHORS_RESOLUTION = 0.005, 256
#: The authors' Laplacian weight at their resolution (their frame).
AUTHORS_LAPLACIAN_WEIGHT = 2000.0
#: The authors' learning rate (their frame), iterations, end of the Laplacian stage, warm-up length
#: and the iteration from which the learning rate is divided by 10.
AUTHORS_LR, AUTHORS_ITERATIONS, AUTHORS_NORMAL_STEP, AUTHORS_WARM_UP, AUTHORS_LR_DROP = 5e-4, 400, 300, 25, 200
#: Weight of the normal-constraint term.
NORMAL_WEIGHT = 0.5
#: VectorAdam's betas and epsilon (the authors').
BETAS, EPS = (0.9, 0.999), 1e-8
#: Dihedral-angle exponent of the cut weights, seed/sink region size (F / region_rate), the largest
#: imbalance of an accepted cut, the sink candidates per seed (nearest face centroids).
ANGLE_EXPONENT, REGION_RATE, MAX_IMBALANCE, SINK_CANDIDATES = 200.0, 20.0, 0.15, 50
#: Failed seeds before the regions shrink, how often they may shrink, region shrink factor.
FAILURES_PER_SIZE, SIZE_CHANGES, REGION_SHRINK = 5, 20, 1.5
#: Seeds tried at most (also counting seeds whose region cannot grow to its size).
MAX_SEEDS = 400
#: A known cut's cost in capacity units; capacity of the terminal links (int32 max).
CUT_UNITS, TERMINAL_CAPACITY = 2 ** 30, 2 ** 31 - 1
#: Rounds of the non-manifold repair at most.
REPAIR_ROUNDS = 100

UDFAndGrad = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


# ---------------------------------------------------------------------------------------------
# the authors' settings in the canonical frame
# ---------------------------------------------------------------------------------------------
def authors_r(N: int) -> float:
    """The authors' r at N points per axis (``256 / N x 0.005`` in their frame), canonical units."""
    return AUTHORS_R * AUTHORS_RESOLUTION / N * FRAME_SCALE


def authors_laplacian_weight(N: int) -> float:
    """The authors' Laplacian weight at N points per axis (2000 at 256^3, 500 at 64^3: linear in N),
    converted to the canonical frame."""
    return AUTHORS_LAPLACIAN_WEIGHT * N / AUTHORS_RESOLUTION / FRAME_SCALE


def authors_lr(iterations: int = AUTHORS_ITERATIONS) -> float:
    """The authors' learning rate (a vertex's step length), canonical units, times
    ``400 / iterations``: fewer iterations take longer steps, so the sum of the steps' lengths over
    the schedule (about 157 learning rates, 0.16 canonical units) is the authors'."""
    return AUTHORS_LR * FRAME_SCALE * AUTHORS_ITERATIONS / iterations


def default_normal_step(iterations: int) -> int:
    """The end of the Laplacian stage: the authors' 300 of 400 iterations, in proportion."""
    return int(round(iterations * AUTHORS_NORMAL_STEP / AUTHORS_ITERATIONS))


def learning_rate(it: int, iterations: int, lr: float) -> float:
    """The authors' schedule at iteration ``it`` of ``iterations``: a linear warm-up over the first
    25/400 of them (0 at the first), then a cosine from ``lr`` to 0, divided by 10 from iteration
    200/400 on (the three lengths in proportion to ``iterations``)."""
    factor = warmup_then_cosine(it, iterations, max(1, int(round(iterations * AUTHORS_WARM_UP / AUTHORS_ITERATIONS))))
    if it >= iterations * AUTHORS_LR_DROP / AUTHORS_ITERATIONS:
        factor *= 0.1
    return lr * factor


# ---------------------------------------------------------------------------------------------
# 1. the double cover
# ---------------------------------------------------------------------------------------------
def padded_udf_grid(udf_grid: np.ndarray, udf_at: Callable[[np.ndarray], np.ndarray], pad: int) -> np.ndarray:
    """The (N, N, N) grid UDF with ``pad`` more layers of points (spacing h) on every side, (N + 2 pad)^3;
    the new points' values from ``udf_at`` (points (P, 3) -> (P,))."""
    N = udf_grid.shape[0]
    M = N + 2 * pad
    out = np.full((M, M, M), np.nan, dtype=np.float32)
    out[pad:pad + N, pad:pad + N, pad:pad + N] = udf_grid
    if pad == 0:
        return out
    ijk = np.argwhere(np.isnan(out))
    points = LOWER + (ijk - pad) * spacing(N)
    out[tuple(ijk.T)] = np.asarray(udf_at(points), dtype=np.float32)
    return out


def double_cover(udf_grid: np.ndarray, r: float, udf_at: Callable[[np.ndarray], np.ndarray] | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes of the grid UDF (N, N, N) at level ``r`` (canonical units): (V (n, 3) float64,
    canonical frame; F (m, 3) int64). With ``udf_at`` the grid is padded first by ``ceil(r / h) + 1``
    layers of that field, so the cover closes beyond [-1, 1]^3 where the surface comes within r of it."""
    N = udf_grid.shape[0]
    h = spacing(N)
    pad = int(math.ceil(r / h)) + 1 if udf_at is not None else 0
    grid = padded_udf_grid(udf_grid, udf_at, pad) if pad else np.asarray(udf_grid, dtype=np.float32)
    cover = marching_cubes_grid(grid, level=r)
    M = grid.shape[0]
    index = (cover.vertices - LOWER) / spacing(M)  # marching_cubes_grid maps an M-point grid onto [-1, 1]
    return LOWER + (index - pad) * h, cover.faces


# ---------------------------------------------------------------------------------------------
# 2. the vertex optimisation
# ---------------------------------------------------------------------------------------------
class _FieldUDF(torch.autograd.Function):
    """d(x) from a numpy field, differentiable through the field's gradient."""

    @staticmethod
    def forward(ctx, points, udf_and_grad):
        d, grad = udf_and_grad(points.detach().cpu().numpy().astype(np.float64))
        ctx.save_for_backward(torch.as_tensor(np.asarray(grad), dtype=points.dtype, device=points.device))
        return torch.as_tensor(np.asarray(d), dtype=points.dtype, device=points.device)

    @staticmethod
    def backward(ctx, grad_out):
        (grad,) = ctx.saved_tensors
        return grad_out[:, None] * grad, None


def field_udf(udf_and_grad: UDFAndGrad) -> Callable[[torch.Tensor], torch.Tensor]:
    """A torch-differentiable UDF from a numpy one: ``udf_and_grad(points (P, 3)) -> (d (P,), its
    gradient (P, 3))`` (for the exact UDF the unit vector ``(x - c) / |x - c|``, for a network its
    autograd gradient)."""
    return lambda points: _FieldUDF.apply(points, udf_and_grad)


class VectorAdam:
    """Adam on per-vertex vectors (Ling et al. 2022): the second moment is the running mean of each
    row's squared gradient norm, so a vertex's step keeps its gradient's direction."""

    def __init__(self, x: torch.Tensor, betas: tuple[float, float] = BETAS, eps: float = EPS):
        self.x, self.betas, self.eps = x, betas, eps
        self.m1 = torch.zeros_like(x)
        self.m2 = torch.zeros_like(x[:, :1])
        self.steps = 0

    @torch.no_grad()
    def step(self, lr: float) -> None:
        b1, b2 = self.betas
        grad = self.x.grad
        self.steps += 1
        self.m1.mul_(b1).add_(grad, alpha=1 - b1)
        self.m2.mul_(b2).add_((grad * grad).sum(dim=1, keepdim=True), alpha=1 - b2)
        m1 = self.m1 / (1 - b1 ** self.steps)
        m2 = self.m2 / (1 - b2 ** self.steps)
        self.x.sub_(lr * m1 / (self.eps + m2.sqrt()))


def uniform_laplacian(F: np.ndarray, n: int, device) -> torch.Tensor:
    """The sparse (n, n) matrix averaging each vertex's neighbours (along the mesh edges of ``F``)."""
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    rows = np.concatenate([edges[:, 0], edges[:, 1]])
    cols = np.concatenate([edges[:, 1], edges[:, 0]])
    degree = np.bincount(rows, minlength=n).astype(np.float64)
    values = 1.0 / degree[rows]
    index = torch.as_tensor(np.stack([rows, cols]), dtype=torch.int64)
    matrix = torch.sparse_coo_tensor(index, torch.as_tensor(values, dtype=torch.float32), (n, n), check_invariants=False)
    return matrix.coalesce().to(device)


def _face_areas(x: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """(m,) areas of the faces."""
    a, b, c = x[faces[:, 0]], x[faces[:, 1]], x[faces[:, 2]]
    return 0.5 * torch.linalg.cross(b - a, c - a).norm(dim=1)


def _face_normals(x: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """(m, 3) unit face normals, 0 for faces of no area."""
    a, b, c = x[faces[:, 0]], x[faces[:, 1]], x[faces[:, 2]]
    n = torch.linalg.cross(b - a, c - a)
    length = n.norm(dim=1, keepdim=True)
    return torch.where(length > 0, n / length.clamp(min=1e-30), torch.zeros_like(n))


def laplacian_loss(x: torch.Tensor, faces: torch.Tensor, laplacian: torch.Tensor) -> torch.Tensor:
    """Mean over the vertices of ``a_v |L x_v - x_v|^2``, ``a_v = max s / s_v`` with ``s_v`` the square
    root of the area around v (not differentiated; areas below 1e-15 count as 1e-15)."""
    with torch.no_grad():
        area = _face_areas(x, faces).clamp(min=1e-15)
        around = torch.zeros(len(x), dtype=x.dtype, device=x.device).index_add_(0, faces.reshape(-1), area.repeat_interleave(3))
        s = around.sqrt()
        weight = s.max() / s
    lap = torch.sparse.mm(laplacian, x) - x
    return (weight * (lap * lap).sum(dim=1)).mean()


def optimise_vertices(V: np.ndarray, F: np.ndarray, udf: Callable[[torch.Tensor], torch.Tensor],
                      iterations: int = AUTHORS_ITERATIONS, normal_step: int | None = None,
                      laplacian_weight: float = AUTHORS_LAPLACIAN_WEIGHT / FRAME_SCALE,
                      lr: float | None = None, device=None) -> np.ndarray:
    """Move the vertices of the double cover (V (n, 3), F (m, 3)) toward d = 0 (module docstring,
    step 2). ``udf``: torch-differentiable, points (P, 3) -> d (P,) (:func:`field_udf` wraps a numpy
    field). ``normal_step`` defaults to 3/4 of ``iterations`` (the authors' 300 of 400), ``lr`` to
    :func:`authors_lr` (iterations). Runs on ``device`` (:func:`methods.core.device.get_device`). Returns V (n, 3) float64."""
    device = get_device(device)
    normal_step = default_normal_step(iterations) if normal_step is None else int(normal_step)
    lr = authors_lr(iterations) if lr is None else float(lr)
    x = torch.tensor(np.asarray(V, dtype=np.float32), device=device, requires_grad=True)
    faces = torch.as_tensor(np.asarray(F, dtype=np.int64), device=device)
    laplacian = uniform_laplacian(np.asarray(F), len(V), device)
    optimizer = VectorAdam(x)
    normals = start = None
    for it in range(iterations):
        if it == normal_step:
            with torch.no_grad():
                normals, start = _face_normals(x, faces), x[faces].mean(dim=1)
        x.grad = None
        centroids = x[faces].mean(dim=1)
        d = udf(torch.cat([x, centroids]))
        loss = d[:len(x)].mean() + d[len(x):].mean()
        if it <= normal_step:
            loss = loss + laplacian_weight * laplacian_loss(x, faces, laplacian)
        else:
            loss = loss + NORMAL_WEIGHT * torch.linalg.cross(centroids - start, normals).norm(dim=1).mean()
        loss.backward()
        optimizer.step(learning_rate(it, iterations, lr))
    return x.detach().cpu().numpy().astype(np.float64)


# ---------------------------------------------------------------------------------------------
# 3. the min-cut
# ---------------------------------------------------------------------------------------------
def _graph(pairs: np.ndarray, n: int, values: np.ndarray | None = None) -> csr_matrix:
    """Symmetric (n, n) sparse graph of the node ``pairs`` (k, 2), with ``values`` (k,) (default 1)."""
    values = np.ones(len(pairs)) if values is None else values
    rows = np.concatenate([pairs[:, 0], pairs[:, 1]])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0]])
    return coo_matrix((np.concatenate([values, values]), (rows, cols)), shape=(n, n)).tocsr()


def large_components(F: np.ndarray, min_faces: int) -> np.ndarray:
    """(m,) bool: the faces in edge-connected components of at least ``min_faces`` faces."""
    pairs = trimesh.graph.face_adjacency(faces=F)
    _, labels = connected_components(_graph(pairs, len(F)), directed=False)
    size = np.bincount(labels)
    return size[labels] >= min_faces


def grow_region(adjacency: csr_matrix, seed: int, size: int) -> np.ndarray | None:
    """The ``size`` faces nearest ``seed`` in breadth-first order over ``adjacency`` (seed included),
    or None when its component has fewer."""
    order = breadth_first_order(adjacency, seed, directed=False, return_predecessors=False)
    return order[:size] if len(order) >= size else None


def bottleneck(pairs: np.ndarray, log_weights: np.ndarray, n: int, source: np.ndarray, sink: np.ndarray) -> float:
    """The least level L such that the edges of log weight <= L separate the ``source`` nodes from the
    ``sink`` nodes (-inf when they are apart already): every cut between them has an edge of log weight
    >= L."""
    levels = np.unique(log_weights)

    def apart(level: float) -> bool:
        keep = log_weights > level
        _, labels = connected_components(_graph(pairs[keep], n), directed=False)
        return not np.intersect1d(labels[source], labels[sink]).size

    if apart(-np.inf):
        return -np.inf
    lo, hi = 0, len(levels) - 1  # apart(levels[-1]) holds: no edge is left
    while lo < hi:
        mid = (lo + hi) // 2
        if apart(levels[mid]):
            hi = mid
        else:
            lo = mid + 1
    return float(levels[lo])


def integer_capacities(pairs: np.ndarray, log_weights: np.ndarray, n: int, source: np.ndarray,
                       sink: np.ndarray) -> np.ndarray:
    """int32 capacities (k,) for edges of weight ``exp(log_weights)`` whose minimum cut between the
    ``source`` and ``sink`` nodes is a minimum cut of the float weights up to one unit per cut edge
    (module docstring): a known cut of cost U (the edges of log weight <= the bottleneck leaving the
    source's side) is scaled to 2^30 units, heavier edges capped at 2^30 + 1, each edge >= 1."""
    level = bottleneck(pairs, log_weights, n, source, sink)
    if level == -np.inf:
        return np.ones(len(pairs), dtype=np.int32)
    keep = log_weights > level
    _, labels = connected_components(_graph(pairs[keep], n), directed=False)
    source_side = np.isin(labels, labels[source])
    crossing = source_side[pairs[:, 0]] != source_side[pairs[:, 1]]
    known_cut = np.exp(log_weights[crossing] - level).sum()
    relative = np.exp(np.minimum(log_weights - level, math.log(2.0 * known_cut)))
    units = np.rint(relative * (CUT_UNITS / known_cut))
    return np.clip(units, 1, CUT_UNITS + 1).astype(np.int32)


def _min_cut_sink_side(pairs: np.ndarray, capacities: np.ndarray, n: int, source: np.ndarray,
                       sink: np.ndarray) -> np.ndarray:
    """(n,) bool: the nodes that still reach the sink nodes after a maximum flow between the two sets
    (the others, nodes apart from both included, form the source's side, as in Boykov-Kolmogorov)."""
    s, t = n, n + 1
    terminal = np.concatenate([np.stack([np.full(len(source), s), source], 1), np.stack([sink, np.full(len(sink), t)], 1)])
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], terminal[:, 0]])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], terminal[:, 1]])
    caps = np.concatenate([capacities, capacities, np.full(len(terminal), TERMINAL_CAPACITY)]).astype(np.int32)
    graph = csr_matrix((caps, (rows, cols)), shape=(n + 2, n + 2))
    graph.sum_duplicates()
    flow = maximum_flow(graph, s, t).flow
    residual = (graph - flow).tocsr()
    residual.data = (residual.data > 0).astype(np.int8)
    residual.eliminate_zeros()
    reaches = breadth_first_order(residual.T.tocsr(), t, directed=True, return_predecessors=False)
    side = np.zeros(n + 2, dtype=bool)
    side[reaches] = True
    return side[:n]


def non_manifold_vertices(F: np.ndarray, n: int) -> np.ndarray:
    """Indices of the vertices (of n) whose faces in ``F`` do not form one fan: more than one group of
    corners joined across the mesh edges shared by exactly two faces."""
    if len(F) == 0:
        return np.zeros(0, dtype=np.int64)
    pairs, edges = trimesh.graph.face_adjacency(faces=F, return_edges=True)
    corner_of = lambda f, v: 3 * f + np.argmax(F[f] == v[:, None], axis=1)
    links = np.concatenate([np.stack([corner_of(pairs[:, 0], edges[:, k]), corner_of(pairs[:, 1], edges[:, k])], 1)
                            for k in range(2)])
    _, labels = connected_components(_graph(links, 3 * len(F)), directed=False)
    fans = np.unique(np.stack([F.reshape(-1), labels], 1), axis=0)
    return np.flatnonzero(np.bincount(fans[:, 0], minlength=n) > 1)


def repair_non_manifold(F: np.ndarray, kept: np.ndarray, n: int) -> np.ndarray:
    """Give the kept part (``kept`` (m,) bool over F) every face around its non-manifold vertices until
    it has none (at most :data:`REPAIR_ROUNDS` rounds); the new mask."""
    kept = kept.copy()
    for _ in range(REPAIR_ROUNDS):
        bad = non_manifold_vertices(F[kept], n)
        if not len(bad):
            break
        around = np.isin(F, bad).any(axis=1)
        if not (around & ~kept).any():
            break
        kept |= around
    return kept


def _cut_once(F, pairs, log_weights, adjacency, tree, centroids, seed, size):
    """One seed's try: (faces on the seed's side (m,) bool, 'ok') or (None, why) with why one of
    'no region' (the seed's component is too small), 'no sink' (no candidate outside the region),
    'no sink region', 'overlap' (the sink's region meets the seed's), 'unbalanced'."""
    region = grow_region(adjacency, seed, size)
    if region is None:
        return None, "no region"
    in_region = np.zeros(len(F), dtype=bool)
    in_region[region] = True
    _, near = tree.query(centroids[seed], min(SINK_CANDIDATES, len(F)))
    why = "no sink"
    for candidate in np.atleast_1d(near):
        if in_region[candidate]:
            continue
        sink = grow_region(adjacency, candidate, size)
        if sink is None:
            why = "no sink region"
            continue
        if in_region[sink].any():
            return None, "overlap"
        capacities = integer_capacities(pairs, log_weights, len(F), region, sink)
        sink_side = _min_cut_sink_side(pairs, capacities, len(F), region, sink)
        sink_side[region], sink_side[sink] = False, True
        free = np.ones(len(F), dtype=bool)
        free[region] = free[sink] = False
        p0, p1 = int((free & ~sink_side).sum()), int((free & sink_side).sum())
        if p0 + p1 == 0 or abs(p0 - p1) / (p0 + p1) > MAX_IMBALANCE:
            return None, "unbalanced"
        return ~sink_side, "ok"
    return None, why


def mesh_cut(V: np.ndarray, F: np.ndarray, rng: np.random.Generator, region_rate: float = REGION_RATE,
             angle_exponent: float = ANGLE_EXPONENT) -> tuple[np.ndarray, np.ndarray, dict]:
    """Cut the optimised double cover (V (n, 3), F (m, 3)) into its two sheets and keep one (module
    docstring, step 3). Seeds come from ``rng``. Returns (V, F) without unreferenced vertices and
    facts: ``small_faces_removed``, ``cut`` (1 when a cut was accepted, else the mesh without its small
    components is returned), ``cut_seeds`` (seeds tried)."""
    V, F = np.asarray(V), np.asarray(F, dtype=np.int64)
    n_vertices = len(np.unique(F)) if len(F) else 0
    large = large_components(F, n_vertices // 5) if len(F) else np.zeros(0, dtype=bool)
    facts = {"small_faces_removed": int((~large).sum()), "cut": 0, "cut_seeds": 0}
    F = F[large]
    if len(F) < 2:
        return (*drop_unreferenced_vertices(V, F), facts)
    mesh = trimesh.Trimesh(V, F, process=False)
    pairs, angles = mesh.face_adjacency, mesh.face_adjacency_angles
    log_weights = np.logaddexp(angle_exponent * (angles.max() - angles), 0.0)  # log(exp(.) + 1)
    adjacency = _graph(pairs, len(F))
    centroids = mesh.triangles_center
    tree = cKDTree(centroids)
    failures = size_changes = 0
    for tries in range(1, MAX_SEEDS + 1):
        if failures > FAILURES_PER_SIZE:
            if size_changes >= SIZE_CHANGES:
                break
            failures, size_changes = 0, size_changes + 1
            region_rate *= REGION_SHRINK
        seed = int(rng.integers(len(F)))
        seed_side, why = _cut_once(F, pairs, log_weights, adjacency, tree, centroids, seed, int(len(F) / region_rate))
        facts["cut_seeds"] = tries
        if why == "ok":
            facts["cut"] = 1
            return (*drop_unreferenced_vertices(V, _keep_one_sheet(F, seed_side, len(V))), facts)
        failures += why in ("unbalanced", "no sink")
    return (*drop_unreferenced_vertices(V, F), facts)


def _keep_one_sheet(F: np.ndarray, seed_side: np.ndarray, n: int) -> np.ndarray:
    """The authors' choice after a cut: the larger side (the sink's on a tie) takes the faces around
    its non-manifold vertices, then the side with more vertices is kept."""
    larger = seed_side if seed_side.sum() > (~seed_side).sum() else ~seed_side
    larger = repair_non_manifold(F, larger, n)
    other = ~larger
    count = lambda mask: len(np.unique(F[mask]))
    return F[larger] if count(larger) >= count(other) else F[other]


# ---------------------------------------------------------------------------------------------
# all steps
# ---------------------------------------------------------------------------------------------
def dcudf(udf_grid: np.ndarray, udf_and_grad: UDFAndGrad, udf_at: Callable[[np.ndarray], np.ndarray],
          r: float, iterations: int = AUTHORS_ITERATIONS, normal_step: int | None = None,
          laplacian_weight: float | None = None, cut: bool = True, region_rate: float = REGION_RATE,
          seed: int = 0, device=None) -> Extraction:
    """DCUDF on the grid UDF (N, N, N), canonical units: the double cover at ``r`` (canonical units),
    ``iterations`` of the vertex optimisation on ``udf_and_grad`` (numpy: points -> (d, gradient)),
    then, with ``cut``, the min-cut (seeds from ``numpy.random.default_rng(seed)``).
    ``laplacian_weight`` defaults to :func:`authors_laplacian_weight` (N); ``udf_at`` pads the grid
    (:func:`double_cover`). The sub-steps are timed as the stages ``double_cover``, ``optimise`` and
    ``cut`` (:mod:`foundation.timing`).

    Returns :class:`methods.base.Extraction`: vertices (n, 3) float64, canonical frame; faces (m, 3)
    int64, unoriented; info ``r``, ``iterations``, ``cover_faces`` (faces of the double cover),
    ``cut`` and, when the cut ran, the facts of :func:`mesh_cut`, then ``faces``."""
    N = udf_grid.shape[0]
    laplacian_weight = authors_laplacian_weight(N) if laplacian_weight is None else laplacian_weight
    with stage("double_cover"):
        V, F = double_cover(udf_grid, r, udf_at)
    facts = {"r": float(r), "iterations": int(iterations), "cover_faces": int(len(F))}
    if len(F) == 0:
        return Extraction(V, F, {**facts, "faces": 0, "cut": 0})
    with stage("optimise"):
        V = optimise_vertices(V, F, field_udf(udf_and_grad), iterations, normal_step, laplacian_weight, device=device)
    if cut:
        with stage("cut"):
            V, F, cut_facts = mesh_cut(V, F, np.random.default_rng(seed), region_rate)
        facts.update(cut_facts)
    else:
        facts["cut"] = 0
    return Extraction(V, F, {**facts, "faces": int(len(F))})
