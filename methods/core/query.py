"""Evaluating a fitted network on the grid of :mod:`foundation.grid`: dense, sparse, with input gradients.

Everything is chunked (``chunk`` rows per forward pass: small chunks are faster on the CPU, see
docs/PERFORMANCE.md, section 6) and returns numpy float32 arrays.

Sparse coarse-to-fine strategy (the same for every method)
----------------------------------------------------------
1. Coarse grid: the fine grid indices ``0, S, 2S, ...`` plus ``N - 1`` along each axis
   (:func:`coarse_indices`, stride ``S``, default 4). Consecutive coarse indices bound *blocks* of up
   to ``S^3`` fine cells.
2. Evaluate the network on the coarse grid (points), or on the coarse edges (segments between
   consecutive coarse points, for segment fields).
3. Mark blocks near the surface with a method-supplied criterion: for point fields
   ``near(corners)`` gets the values at the 8 corners of every block, ``(nb, nb, nb, 8, C)``, and
   returns ``(nb, nb, nb)`` bool (e.g. SDF: a sign change or ``min |f| < margin``); for segment
   fields ``near(values)`` gets the values of the coarse edges ``(K, C)`` and returns ``(K,)`` bool
   (SALS: ``o_hat > o_low``); a block is marked when one of its 12 edges is.
4. Dilate the marked blocks by ``dilate`` blocks (26-neighbourhood, default 1).
5. Evaluate the fine grid points (or fine edges with both endpoints) in marked blocks.

Edges (coarse and fine) go through :func:`evaluate_point_pairs`: a grid point is an endpoint of up
to 6 edges, and the segment networks of :mod:`methods.core.network` are split after their first layer
into one term per endpoint, so each point is encoded once and an edge costs the rest of the network
(most of an edge's cost is the head's Softplus, which both ways pay; docs/PERFORMANCE.md, section 6).

Fill values where nothing is evaluated ("far"): point fields get the *trilinear upsampling of the
coarse values* (so a far point keeps the side of the level set its block's corners have: an SDF
stays signed, an occupancy stays inside/outside, a UDF stays >= the margin); segment fields get
``edge_fill`` (default 0 = "no hit", s = 0). The returned ``evaluated`` mask says which entries are
network values.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch
from scipy.ndimage import binary_dilation

from foundation.grid import LOWER, edge_index_to_ijk_axis, edges_in_points, num_edges, point_inputs, spacing
from methods.core.device import flush_denormals, get_device, synchronize
from methods.core.network import endpoint_split, value_and_input_gradients

#: Rows per forward pass (small chunks are faster than large ones on the CPU: see the module docstring).
DEFAULT_CHUNK = 32768
#: Rows per forward + backward pass for input gradients.
GRAD_CHUNK = 16_384
#: Coarse stride S of the sparse strategy.
DEFAULT_STRIDE = 4
#: Grid edges per pass of :func:`evaluate_grid_edges` (their endpoints' first-layer terms are held
#: at once: ~1/3 as many points, 2 x width floats each).
SPLIT_EDGES = 1 << 18


# ---------------------------------------------------------------------------------------------
# plain evaluation
# ---------------------------------------------------------------------------------------------
def _model_device(model, device):
    if device is not None:
        return get_device(device)
    try:
        return next(model.parameters()).device
    except StopIteration:
        return get_device()


def evaluate(model, inputs: np.ndarray, device=None, chunk: int = DEFAULT_CHUNK) -> np.ndarray:
    """Network outputs for ``inputs`` (P, in_dim), in chunks, no autograd: (P, out_dim) float32."""
    device = _model_device(model, device)
    inputs = np.ascontiguousarray(inputs, dtype=np.float32)
    outs = []
    with torch.inference_mode(), flush_denormals():
        for i in range(0, len(inputs), chunk):
            x = torch.from_numpy(inputs[i:i + chunk]).to(device)
            outs.append(model(x).float().cpu().numpy())
    if not outs:
        out_dim = model.config["out_dim"] if hasattr(model, "config") else 1
        return np.zeros((0, out_dim), dtype=np.float32)
    return np.concatenate(outs, axis=0)


def evaluate_with_input_grad(model, inputs: np.ndarray, output_index: int = 0, device=None,
                             chunk: int = GRAD_CHUNK) -> tuple[np.ndarray, np.ndarray]:
    """Outputs (P, out_dim) and the gradient of output ``output_index`` w.r.t. the inputs (P, in_dim),
    float32, in chunks, no graph kept (:func:`evaluate_with_input_grads` of the one output)."""
    outs, grads = evaluate_with_input_grads(model, inputs, (output_index,), device, chunk)
    return outs, grads[:, 0]


def evaluate_with_input_grads(model, inputs: np.ndarray, output_indices, device=None,
                              chunk: int = GRAD_CHUNK) -> tuple[np.ndarray, np.ndarray]:
    """Outputs (P, out_dim) and the gradients of outputs ``output_indices`` (M of them) w.r.t. the
    inputs (P, M, in_dim), float32, in chunks, no graph kept, one network evaluation per chunk
    (:func:`methods.core.network.value_and_input_gradients`)."""
    device = _model_device(model, device)
    inputs = np.ascontiguousarray(inputs, dtype=np.float32)
    outs, grads = [], []
    with torch.enable_grad(), flush_denormals():
        for i in range(0, len(inputs), chunk):
            x = torch.from_numpy(inputs[i:i + chunk]).to(device)
            y, g = value_and_input_gradients(model, x, output_indices, create_graph=False)
            outs.append(y.detach().float().cpu().numpy())
            grads.append(torch.stack(g, dim=1).float().cpu().numpy())
    if not outs:
        out_dim = model.config["out_dim"] if hasattr(model, "config") else 1
        return (np.zeros((0, out_dim), np.float32),
                np.zeros((0, len(output_indices), inputs.shape[1]), np.float32))
    return np.concatenate(outs), np.concatenate(grads)


def evaluate_point_pairs(model, points: np.ndarray, iu: np.ndarray, iv: np.ndarray, device=None,
                         chunk: int = DEFAULT_CHUNK) -> np.ndarray:
    """A segment network on the segments ``(points[iu], points[iv])``: (K, out_dim) float32, the
    values of ``evaluate(model, [points[iu], points[iv]])`` up to float rounding.

    For the networks :func:`methods.core.network.endpoint_split` cuts (both backbones' segment
    networks) each point is encoded once (the feature grid and the first layer, split into one term
    per endpoint) and each segment adds its endpoints' terms and runs the rest of the network; any
    other model is evaluated on the ``[u, v]`` rows.
    """
    points = np.ascontiguousarray(points, dtype=np.float32)
    split = endpoint_split(model)
    if split is None or not len(iu):
        return evaluate(model, np.concatenate([points[iu], points[iv]], axis=1), device, chunk)
    device = _model_device(model, device)
    outs = []
    with torch.inference_mode(), flush_denormals():
        P = torch.from_numpy(points).to(device)
        terms = [split.terms(P[i:i + chunk]) for i in range(0, len(P), chunk)]
        A = torch.cat([a for a, _ in terms])
        B = torch.cat([b for _, b in terms])
        iu = torch.from_numpy(np.asarray(iu, dtype=np.int64)).to(device)
        iv = torch.from_numpy(np.asarray(iv, dtype=np.int64)).to(device)
        for i in range(0, len(iu), chunk):
            y = split.tail(A.index_select(0, iu[i:i + chunk]) + B.index_select(0, iv[i:i + chunk]))
            outs.append(y.float().cpu().numpy())
    return np.concatenate(outs)


def evaluate_grid_edges(model, N: int, edge_ids: np.ndarray, device=None, chunk: int = DEFAULT_CHUNK,
                        edges_per_pass: int = SPLIT_EDGES) -> np.ndarray:
    """A segment network on grid edges (flat ids): (K, out_dim) float32, the values of
    ``evaluate(model, edge_inputs(N, edge_ids))`` up to float rounding.

    A grid point is an endpoint of up to 6 edges; :func:`evaluate_point_pairs` encodes it once per
    pass (for the grid backbone at N = 128 an edge then costs about what a point query costs).
    Passes take ``edges_per_pass`` edges in the order of their lower endpoint, so each pass holds a
    slab of points (2 x width floats each; a slab's boundary layer is encoded again by the next).
    """
    ids = np.asarray(edge_ids, dtype=np.int64)
    ijk, axis = edge_index_to_ijk_axis(N, ids)
    lower = (ijk[:, 0] * N + ijk[:, 1]) * N + ijk[:, 2]  # flat point ids, 'ij' order
    upper = lower + np.array([N * N, N, 1], dtype=np.int64)[axis]
    order = np.argsort(lower, kind="stable")  # the flat edge order is 3 runs sorted by lower point
    parts = []
    for start in range(0, len(ids), edges_per_pass):
        sel = order[start:start + edges_per_pass]
        lo, hi = lower[sel], upper[sel]
        first = lo.min()
        used = np.zeros(hi.max() - first + 1, dtype=bool)
        used[lo - first] = True
        used[hi - first] = True
        row = np.cumsum(used) - 1  # point id - first -> row in this pass's points
        points = np.stack(np.unravel_index(np.flatnonzero(used) + first, (N, N, N)), axis=1)
        parts.append(evaluate_point_pairs(model, point_inputs(N, points), row[lo - first], row[hi - first],
                                          device, chunk))
    if not parts:
        return evaluate(model, np.zeros((0, 6), np.float32), device, chunk)
    out = np.empty((len(ids), parts[0].shape[1]), dtype=np.float32)
    out[order] = np.concatenate(parts)
    return out


def dense_grid_points(model, N: int, device=None, chunk: int = DEFAULT_CHUNK) -> np.ndarray:
    """The network on all N^3 grid points: (N, N, N, out_dim) float32 ('ij' order)."""
    c = (LOWER + np.arange(N) * spacing(N)).astype(np.float32)
    outs = []
    step = max(1, chunk // (N * N))
    for i0 in range(0, N, step):  # slabs of x indices: no (N^3, 3) array at once
        P = np.stack(np.meshgrid(c[i0:i0 + step], c, c, indexing="ij"), axis=-1).reshape(-1, 3)
        outs.append(evaluate(model, P, device, chunk))
    return np.concatenate(outs).reshape(N, N, N, -1)


def dense_grid_edges(model, N: int, device=None, chunk: int = DEFAULT_CHUNK) -> np.ndarray:
    """The network on all 3 (N - 1) N^2 grid edges, flat edge order: (E, out_dim) float32."""
    E = num_edges(N)
    big = 1 << 20  # endpoints generated in blocks of edges
    outs = [evaluate_grid_edges(model, N, np.arange(i, min(i + big, E)), device, chunk) for i in range(0, E, big)]
    return np.concatenate(outs)


# ---------------------------------------------------------------------------------------------
# sparse coarse-to-fine
# ---------------------------------------------------------------------------------------------
@dataclass
class SparseInfo:
    """What a sparse query evaluated: counts, fractions of the dense work, seconds per stage."""

    stride: int
    coarse_evaluations: int
    fine_evaluations: int
    dense_evaluations: int
    marked_blocks: int
    total_blocks: int
    timings: dict = field(default_factory=dict)

    @property
    def fraction(self) -> float:
        """(coarse + fine evaluations) / dense evaluations."""
        return (self.coarse_evaluations + self.fine_evaluations) / max(self.dense_evaluations, 1)


def coarse_indices(N: int, stride: int = DEFAULT_STRIDE) -> np.ndarray:
    """Fine indices of the coarse grid along one axis: 0, S, 2S, ... and N - 1 (sorted, unique)."""
    if stride < 1:
        raise ValueError(f"coarse stride must be >= 1, got {stride}")
    return np.unique(np.r_[np.arange(0, N, stride), N - 1]).astype(np.int64)


def _membership(N: int, cidx: np.ndarray) -> np.ndarray:
    """(N, nb) float32: 1 where fine index i lies in the closed range of block b [cidx[b], cidx[b+1]]."""
    i = np.arange(N)[:, None]
    return ((i >= cidx[None, :-1]) & (i <= cidx[None, 1:])).astype(np.float32)


def _interpolation(N: int, cidx: np.ndarray) -> np.ndarray:
    """(N, nc) linear interpolation weights from the coarse indices to every fine index."""
    i = np.arange(N)
    b = np.clip(np.searchsorted(cidx, i, side="right") - 1, 0, len(cidx) - 2)
    t = (i - cidx[b]) / (cidx[b + 1] - cidx[b])
    W = np.zeros((N, len(cidx)))
    W[i, b] = 1.0 - t
    W[i, b + 1] = t
    return W


def blocks_to_points(N: int, cidx: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """(N, N, N) bool: fine grid points lying in (the closed box of) at least one marked block."""
    A = _membership(N, cidx)
    return np.einsum("ia,jb,kc,abc->ijk", A, A, A, blocks.astype(np.float32), optimize=True) > 0.5


def upsample_trilinear(N: int, cidx: np.ndarray, coarse: np.ndarray) -> np.ndarray:
    """Trilinear interpolation of coarse values (nc, nc, nc, C) to the fine grid (N, N, N, C) float32."""
    W = _interpolation(N, cidx)
    return np.einsum("ia,jb,kc,abcd->ijkd", W, W, W, coarse.astype(np.float64), optimize=True).astype(np.float32)


def _dilate(blocks: np.ndarray, dilate: int) -> np.ndarray:
    if dilate <= 0 or not blocks.any():
        return blocks
    return binary_dilation(blocks, structure=np.ones((3, 3, 3), dtype=bool), iterations=int(dilate))


def block_corners(coarse: np.ndarray) -> np.ndarray:
    """Values at the 8 corners of every block: (nc, nc, nc, C) -> (nb, nb, nb, 8, C)."""
    nb = coarse.shape[0] - 1
    return np.stack([coarse[dx:dx + nb, dy:dy + nb, dz:dz + nb]
                     for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)], axis=3)


def sparse_grid_points(model, N: int, near: Callable[[np.ndarray], np.ndarray], device=None,
                       stride: int = DEFAULT_STRIDE, dilate: int = 1, chunk: int = DEFAULT_CHUNK):
    """The network on the N^3 grid points by the sparse strategy (module docstring).

    Returns ``(values (N, N, N, C) float32, evaluated (N, N, N) bool, SparseInfo)``; unevaluated
    points hold the trilinear upsampling of the coarse values.
    """
    device = _model_device(model, device)
    t0 = time.perf_counter()
    cidx = coarse_indices(N, stride)
    nc = len(cidx)
    cg = np.stack(np.meshgrid(cidx, cidx, cidx, indexing="ij"), axis=-1).reshape(-1, 3)
    coarse = evaluate(model, point_inputs(N, cg), device, chunk).reshape(nc, nc, nc, -1)
    t1 = time.perf_counter()
    marked = np.asarray(near(block_corners(coarse)), dtype=bool)
    blocks = _dilate(marked, dilate)
    mask = blocks_to_points(N, cidx, blocks)
    values = upsample_trilinear(N, cidx, coarse)
    t2 = time.perf_counter()
    ijk = np.argwhere(mask)
    if len(ijk):
        values[mask] = evaluate(model, point_inputs(N, ijk), device, chunk)
    synchronize(device)
    t3 = time.perf_counter()
    info = SparseInfo(stride, nc ** 3, len(ijk), N ** 3, int(blocks.sum()), int(blocks.size),
                      {"coarse_s": t1 - t0, "mark_s": t2 - t1, "fine_s": t3 - t2})
    return values, mask, info


def _coarse_edges(nc: int):
    """Per axis: the coarse edges as (lower, upper) flat ids of the coarse grid's nc^3 points ('ij'
    order) and the shape of that axis' edge array (nc - 1 along the axis, nc elsewhere)."""
    out = []
    for a in range(3):
        shape = [nc, nc, nc]
        shape[a] = nc - 1
        lower = np.ravel_multi_index(np.indices(shape).reshape(3, -1), (nc, nc, nc))
        out.append((lower, lower + (nc * nc, nc, 1)[a], tuple(shape)))
    return out


def sparse_grid_edges(model, N: int, near: Callable[[np.ndarray], np.ndarray], device=None,
                      stride: int = DEFAULT_STRIDE, dilate: int = 1, chunk: int = DEFAULT_CHUNK,
                      edge_fill: float | np.ndarray = 0.0):
    """A segment network on the 3 (N - 1) N^2 grid edges by the sparse strategy (module docstring).

    Returns ``(values (E, C) float32 in flat edge order, evaluated (E,) bool, SparseInfo)``;
    unevaluated edges hold ``edge_fill`` (raw network-output units; broadcast over C).
    """
    device = _model_device(model, device)
    t0 = time.perf_counter()
    cidx = coarse_indices(N, stride)
    nc = len(cidx)
    nb = nc - 1
    blocks = np.zeros((nb, nb, nb), dtype=bool)
    edges = _coarse_edges(nc)
    cg = np.stack(np.meshgrid(cidx, cidx, cidx, indexing="ij"), axis=-1).reshape(-1, 3)
    coarse = evaluate_point_pairs(model, point_inputs(N, cg), np.concatenate([lo for lo, _, _ in edges]),
                                  np.concatenate([hi for _, hi, _ in edges]), device, chunk)
    starts = np.cumsum([0] + [len(lo) for lo, _, _ in edges])
    for a, (_, _, shape) in enumerate(edges):
        hit = np.asarray(near(coarse[starts[a]:starts[a + 1]]), dtype=bool).reshape(shape)
        others = [b for b in range(3) if b != a]
        for o1 in (slice(0, nb), slice(1, nb + 1)):  # an edge at coarse index p touches blocks p-1, p
            for o2 in (slice(0, nb), slice(1, nb + 1)):
                sl = [slice(None)] * 3
                sl[others[0]], sl[others[1]] = o1, o2
                blocks |= hit[tuple(sl)]
    t1 = time.perf_counter()
    blocks = _dilate(blocks, dilate)
    mask = edges_in_points(N, blocks_to_points(N, cidx, blocks))
    ids = np.flatnonzero(mask)
    t2 = time.perf_counter()
    fine = evaluate_grid_edges(model, N, ids, device, chunk) if len(ids) else None
    C = fine.shape[1] if fine is not None else (model.config["out_dim"] if hasattr(model, "config") else 1)
    values = np.empty((num_edges(N), C), dtype=np.float32)
    values[:] = edge_fill
    if fine is not None:
        values[ids] = fine
    synchronize(device)
    t3 = time.perf_counter()
    info = SparseInfo(stride, len(coarse), len(ids), num_edges(N), int(blocks.sum()), int(blocks.size),
                      {"coarse_s": t1 - t0, "mark_s": t2 - t1, "fine_s": t3 - t2})
    return values, mask, info


# ---------------------------------------------------------------------------------------------
# ready-made criteria
# ---------------------------------------------------------------------------------------------
def near_level(level: float, margin: float) -> Callable[[np.ndarray], np.ndarray]:
    """Block criterion for a scalar field (channel 0): the corners straddle ``level`` or one corner is
    within ``margin`` of it."""

    def near(corners: np.ndarray) -> np.ndarray:
        c = corners[..., 0] - level
        return ((c.min(axis=-1) <= 0) & (c.max(axis=-1) >= 0)) | (np.abs(c).min(axis=-1) < margin)

    return near


def near_below(margin: float) -> Callable[[np.ndarray], np.ndarray]:
    """Block criterion for an unsigned field (channel 0): some corner value is below ``margin``."""

    def near(corners: np.ndarray) -> np.ndarray:
        return corners[..., 0].min(axis=-1) < margin

    return near


def block_half_diagonal(N: int, stride: int = DEFAULT_STRIDE) -> float:
    """sqrt(3) S h / 2: a surface point inside a block is this close to one of its corners."""
    return 0.5 * np.sqrt(3.0) * stride * spacing(N)


def network_udf(model, device=None):
    """The fitted UDF as a function of points (P, 3) -> max(f, 0) (P,)."""
    def udf_at(points):
        return np.maximum(evaluate(model, np.asarray(points, dtype=np.float32), device)[:, 0], 0.0)

    return udf_at


def network_udf_and_gradient(model, points: np.ndarray, device=None) -> tuple[np.ndarray, np.ndarray]:
    """max(f, 0) (P,) and the unit input gradient of f (P, 3; 0 where it vanishes) at ``points``."""
    out, g = evaluate_with_input_grad(model, np.asarray(points, dtype=np.float32), 0, device)
    norm = np.linalg.norm(g, axis=1, keepdims=True)
    return np.maximum(out[:, 0], 0.0), np.divide(g, norm, out=np.zeros_like(g), where=norm > 0)
