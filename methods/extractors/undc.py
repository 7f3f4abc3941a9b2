"""UNDC: Neural Dual Contouring for unsigned distance input (Chen et al., SIGGRAPH 2022).

Unsigned NDC predicts, from the UDF on a grid, which grid edges cross the surface (no signs exist)
and where each cell's dual vertex lies; dual contouring joins the 4 cells around every crossing edge
by a quad. Two networks of NDC's ``CNN_3d_rec7`` layout (:class:`UNDCNetwork`) read the same input:

* the *bool* network: 3 logits per grid point p, the grid edges from p along +x, +y, +z cross the
  surface when ``sigmoid > 0.5``;
* the *float* network: 3 values per cell c (the cell of lower corner c), its vertex inside the cell
  in cell units, clipped to [0, 1].

Input (:func:`network_input`): the UDF on the N^3 grid points in voxel units (``|udf| / h``), padded
by :data:`RECEPTIVE_PADDING` points on each side with :data:`PADDING_VALUE` and clipped to
[-2, 2] (so [0, 2]), as NDC's data loader does for UDF input. Output position p reads the input
points p .. p + 6 per axis (three unpadded 3x3x3 convolutions).

This module holds the network, the ground truth of a shape on a grid (:func:`ground_truth`, the
labels of NDC's ``get_gt_LOD.py`` for UNDC from our exact grid-line intersections), the dual
contouring of edge flags and cell vertices (:func:`dual_contour_edges`, NDC's
``dual_contouring_undc_test`` vectorised), the sparse inference of both networks
(:func:`undc_predict`, in voxel and grid index units), the extractor on a grid UDF in canonical
units (:func:`unsigned_neural_dual_contouring`) and the weights file (:func:`save_weights`, :func:`load_weights`). The
training recipe is :mod:`methods.training.undc`, the registered method ``udf-ndc``
:mod:`methods.fields.udf_ndc`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from foundation.fields import default_band
from foundation.grid import index_to_world, spacing
from foundation.raster import grid_line_hits
from foundation.timing import stage
from methods.base import Extraction
from methods.core.weights import WeightsError, read_weights_file, write_weights_file  # noqa: F401 (WeightsError: what load_weights raises)
from methods.extractors.rec7 import DEFAULT_CHANNELS, RECEPTIVE_PADDING, Rec7Network, sparse_forward

#: Input clip, voxel units (NDC's data loader clips to [-2, 2]; the UDF is >= 0).
INPUT_CLIP = 2.0
#: Value of the padding before the clip (NDC pads with +10 where the corner point's value is > 0).
PADDING_VALUE = 10.0
#: An edge crosses the surface when the bool network's sigmoid exceeds this.
FLAG_THRESHOLD = 0.5
#: The bool loss (and here the inference) covers the edges whose both end points have UDF below
#: this many voxels: no other edge can cross the surface (an edge is one voxel long).
EDGE_MASK_VOXELS = 1.0
#: Eigenvalues of a cell's normal matrix below this hold no constraint (null space of the QEF).
EIGEN_FLOOR = 1e-9
#: NDC's QEF regularisation: the initial weight, its integer steps' upper end, the bisection steps.
REG_START = 1e-6
REG_MAX = 1000.0
REG_BISECTIONS = 10
#: Regularisation weights tried per block of the vectorised integer search.
_REG_BLOCK = 50

#: Environment variable naming the weights file of ``udf-ndc``.
WEIGHTS_ENV = "SALSBENCH_UNDC_WEIGHTS"
#: The weights file without the variable: trained by ``python -m methods.training.undc --budget cpu``.
DEFAULT_WEIGHTS = Path(__file__).resolve().parents[1] / "weights" / "undc_cpu.pt"


# --------------------------------------------------------------------------------------------------
# The network
# --------------------------------------------------------------------------------------------------

#: UNDC's two networks are NDC's ``CNN_3d_rec7`` with one input channel (the UDF) and 3 outputs:
#: logits of the 3 edge flags (bool network; NDC applies the sigmoid inside the network) or vertex
#: positions in cell units (float network; clipped to [0, 1] at inference only).
UNDCNetwork = Rec7Network


def network_input(udf_voxels: np.ndarray) -> np.ndarray:
    """The networks' input grid from a UDF in voxel units, (D, H, W): ``|udf|`` padded by
    :data:`RECEPTIVE_PADDING` with :data:`PADDING_VALUE` and clipped to [-2, 2]; (D + 6, H + 6, W + 6)
    float32."""
    udf = np.abs(np.asarray(udf_voxels, dtype=np.float32))
    padded = np.pad(udf, RECEPTIVE_PADDING, mode="constant", constant_values=PADDING_VALUE)
    return np.clip(padded, -INPUT_CLIP, INPUT_CLIP)


# --------------------------------------------------------------------------------------------------
# Edges and cells of the grid
# --------------------------------------------------------------------------------------------------

def edge_mask(udf_voxels: np.ndarray, limit: float = EDGE_MASK_VOXELS) -> np.ndarray:
    """(N, N, N, 3) bool: the edge from point p along axis a has both end points with UDF < ``limit``
    voxels (NDC's bool-loss mask for UDF input); False for the edges that would leave the grid."""
    near = np.abs(np.asarray(udf_voxels)) < limit
    mask = np.zeros(near.shape + (3,), dtype=bool)
    mask[:-1, :, :, 0] = near[:-1] & near[1:]
    mask[:, :-1, :, 1] = near[:, :-1] & near[:, 1:]
    mask[:, :, :-1, 2] = near[:, :, :-1] & near[:, :, 1:]
    return mask


#: Per axis: the two triangles of the quad over the 4 cells around an edge from point p, as cell
#: offsets from p, in NDC's ``dual_contouring_undc_test`` order.
_QUAD_TRIANGLES = {
    0: np.array([[[0, -1, -1], [0, 0, -1], [0, 0, 0]], [[0, -1, -1], [0, 0, 0], [0, -1, 0]]]),
    1: np.array([[[-1, 0, -1], [0, 0, 0], [0, 0, -1]], [[-1, 0, -1], [-1, 0, 0], [0, 0, 0]]]),
    2: np.array([[[-1, -1, 0], [0, 0, 0], [-1, 0, 0]], [[-1, -1, 0], [0, -1, 0], [0, 0, 0]]]),
}


def _quad_edges(edge_flags: np.ndarray, axis: int) -> np.ndarray:
    """Start points (E, 3) of the flagged edges along ``axis`` whose 4 cells all exist, C order."""
    n = edge_flags.shape[:3]
    lo = [1, 1, 1]
    hi = [s - 1 for s in n]
    lo[axis] = 0
    block = edge_flags[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2], axis]
    return np.argwhere(block) + np.array(lo)


def vertex_cells(edge_flags: np.ndarray) -> np.ndarray:
    """The cells (C, 3) int64, C order, that get a vertex: those around a flagged edge with all 4
    of its cells inside the grid (the vertices the quads use).

    ``edge_flags`` (N, N, N, 3) bool: the edge from point p along axis a crosses the surface."""
    edge_flags = np.asarray(edge_flags, dtype=bool)
    used = np.zeros(tuple(s - 1 for s in edge_flags.shape[:3]), dtype=bool)
    for axis in range(3):
        starts = _quad_edges(edge_flags, axis)
        cells = (starts[:, None, None, :] + _QUAD_TRIANGLES[axis][None]).reshape(-1, 3)
        used[cells[:, 0], cells[:, 1], cells[:, 2]] = True
    return np.argwhere(used)


def dual_contour_edges(edge_flags: np.ndarray, cells: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """UNDC's dual contouring of edge flags and cell vertices.

    Parameters
    ----------
    edge_flags : (N, N, N, 3) bool, the edge from point p along axis a crosses the surface.
    cells : (C, 3) the cells with a vertex, :func:`vertex_cells` (edge_flags), in that order.
    offsets : (C, 3) each cell's vertex inside it, cell units (clipped to [0, 1] by the caller).

    Returns
    -------
    vertices : (C, 3) float64 in grid index units, ``cells + offsets``.
    faces : (F, 3) int64, unoriented: two triangles per flagged edge whose 4 cells exist (edges on
        the grid's boundary faces get none), in NDC's order (axis, then edge in C order, the two
        triangles of ``dual_contouring_undc_test``). Unlike NDC, cells touched only by boundary
        edges get no vertex (NDC keeps them unreferenced).
    """
    edge_flags = np.asarray(edge_flags, dtype=bool)
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    vertex_of = np.full(tuple(s - 1 for s in edge_flags.shape[:3]), -1, dtype=np.int64)
    vertex_of[cells[:, 0], cells[:, 1], cells[:, 2]] = np.arange(len(cells))
    faces = []
    for axis in range(3):
        starts = _quad_edges(edge_flags, axis)
        corner_cells = starts[:, None, None, :] + _QUAD_TRIANGLES[axis][None]  # (E, 2, 3, 3)
        faces.append(vertex_of[corner_cells[..., 0], corner_cells[..., 1], corner_cells[..., 2]].reshape(-1, 3))
    faces = np.concatenate(faces)
    if len(faces) and faces.min() < 0:
        raise ValueError("a quad uses a cell that has no vertex: pass cells = vertex_cells(edge_flags)")
    vertices = cells.astype(np.float64) + np.asarray(offsets, dtype=np.float64).reshape(-1, 3)
    return vertices, np.ascontiguousarray(faces, dtype=np.int64)


# --------------------------------------------------------------------------------------------------
# Ground truth
# --------------------------------------------------------------------------------------------------

@dataclass
class EdgeHits:
    """Intersections of the grid edges with a mesh (every one, not only the first per edge).

    start : (H, 3) int64 grid index of the edge's lower end point; axis : (H,) int64 its axis;
    t : (H,) float64 position along the edge from ``start``, edge units in [0, 1];
    normal : (H, 3) float64 unit normal of the hit triangle (sign irrelevant).
    A hit at a grid point (within 1e-9 edge) belongs to both edges that meet there."""

    start: np.ndarray
    axis: np.ndarray
    t: np.ndarray
    normal: np.ndarray


def edge_hits(fields, N: int) -> EdgeHits:
    """Every intersection of the N^3 grid's edges with the mesh of ``fields``
    (:class:`foundation.fields.ExactFields`), from the exact grid-line intersections of
    :func:`foundation.raster.grid_line_hits` (rule 'closed', as :meth:`ExactFields.grid_edges`).
    Repeats (the same point and normal from two triangles sharing an edge) are dropped."""
    h = spacing(N)
    starts, axes, ts, normals = [], [], [], []
    for axis in range(3):
        j, k, x, face, _ = grid_line_hits(fields.vertices, fields.faces, N, axis, rule="closed")
        if len(x) == 0:
            continue
        r = (x + 1.0) / h
        base = np.floor(r).astype(np.int64)
        edge = np.concatenate([base - 1, base, base + 1])
        t = np.concatenate([r - base + 1, r - base, r - base - 1])
        row = np.tile(np.arange(len(x)), 3)
        ok = (edge >= 0) & (edge <= N - 2) & (t >= -1e-9) & (t <= 1 + 1e-9)
        edge, t, row = edge[ok], np.clip(t[ok], 0.0, 1.0), row[ok]
        start = np.empty((len(row), 3), dtype=np.int64)
        others = [a for a in range(3) if a != axis]
        start[:, axis], start[:, others[0]], start[:, others[1]] = edge, j[row], k[row]
        starts.append(start)
        axes.append(np.full(len(row), axis, dtype=np.int64))
        ts.append(t)
        normals.append(fields.face_normals[face[row]])
    if not starts:
        return EdgeHits(np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)))
    start, axis, t, normal = (np.concatenate(a) for a in (starts, axes, ts, normals))
    key = np.column_stack([start, axis, np.round(t * 1e9), np.round(normal * 1e9)])
    _, keep = np.unique(key, axis=0, return_index=True)
    keep = np.sort(keep)
    return EdgeHits(start[keep], axis[keep], t[keep], normal[keep])


def _qef_solution(eigvals, eigvecs, vtb, anchor, reg):
    """The regularised least-squares point ``argmin |A x - b|^2 + reg^2 |x - anchor|^2`` per cell.

    eigvals (C, 3), eigvecs (C, 3, 3) of M = A^T A; vtb (C, 3) = V^T A^T b; anchor (C, 3);
    reg (C,) or (C, K). Returns (C, 3) or (C, K, 3): ``anchor + V diag(1 / (l + reg^2)) V^T (A^T b -
    M anchor)``, the components along eigenvalues below :data:`EIGEN_FLOOR` set to 0 (there the
    right-hand side vanishes and only rounding would be amplified)."""
    va = np.einsum("cij,ci->cj", eigvecs, anchor)
    rhs = np.where(eigvals > EIGEN_FLOOR, vtb - eigvals * va, 0.0)  # (C, 3)
    reg2 = np.asarray(reg, dtype=np.float64) ** 2
    if reg2.ndim == 1:
        return anchor + np.einsum("cij,cj->ci", eigvecs, rhs / (eigvals + reg2[:, None]))
    coef = rhs[:, None, :] / (eigvals[:, None, :] + reg2[..., None])  # (C, K, 3)
    return anchor[:, None, :] + np.einsum("cij,ckj->cki", eigvecs, coef)


def _inside(x: np.ndarray) -> np.ndarray:
    return (x >= 0.0).all(axis=-1) & (x <= 1.0).all(axis=-1)


def _regularised_search(eigvals, eigvecs, vtb, anchor):
    """NDC's search for a vertex inside the cell, vectorised over cells: the solution at weight
    :data:`REG_START`; where it leaves the cell, the first weight ``REG_START + k`` (k = 1, 2, ...)
    that brings it inside, then :data:`REG_BISECTIONS` halvings of the step back down, keeping the
    inside ones. Returns (x (C, 3), found (C,) bool: inside at some weight <= REG_MAX + 1)."""
    C = len(anchor)
    reg = np.full(C, REG_START)
    x = _qef_solution(eigvals, eigvecs, vtb, anchor, reg)
    found = _inside(x)
    todo = np.flatnonzero(~found)
    step = 0
    while len(todo) and step < REG_MAX:
        ks = REG_START + step + np.arange(1, _REG_BLOCK + 1, dtype=np.float64)
        xs = _qef_solution(eigvals[todo], eigvecs[todo], vtb[todo], anchor[todo], np.broadcast_to(ks, (len(todo), len(ks))))
        ok = _inside(xs)
        hit = ok.any(axis=1)
        first = ok.argmax(axis=1)
        rows = todo[hit]
        reg[rows] = ks[first[hit]]
        found[rows] = True
        todo = todo[~hit]
        step += _REG_BLOCK
    searched = found & (reg > REG_START)
    rows = np.flatnonzero(searched)
    if len(rows):
        r, size = reg[rows], 1.0
        for _ in range(REG_BISECTIONS):
            size /= 2.0
            trial = r - size
            ok = _inside(_qef_solution(eigvals[rows], eigvecs[rows], vtb[rows], anchor[rows], trial))
            r = np.where(ok, trial, r)
        reg[rows] = r
        x[rows] = _qef_solution(eigvals[rows], eigvecs[rows], vtb[rows], anchor[rows], r)
    return x, found


def qef_cell_vertices(N: int, hits: EdgeHits) -> tuple[np.ndarray, np.ndarray]:
    """UNDC's target vertex of every cell with a hit on one of its 12 edges.

    The least-squares point of the planes ``n_i . (x - p_i) = 0`` of the cell's hits p_i (cell units,
    from the cell's lower corner) with normals n_i, regularised towards the mass point m of the
    p_i as NDC's ``get_gt_LOD.py`` does (``lstsq`` of the rows n_i and 3 rows ``reg I`` with right-hand
    side ``reg m``): weight 1e-6 (the minimiser nearest m), raised in steps of 1 and refined by
    bisection until the point lies in the cell; where even weight 1000 does not bring it inside, the
    same search towards the cell's centre. Solved in closed form from the eigen-decomposition of
    ``sum n_i n_i^T`` per cell, all cells at once.

    Returns (cells (C, 3) int64 in C order, offsets (C, 3) float32 in [0, 1])."""
    M = N - 1
    flat, local, normal = [], [], []
    for db in (0, 1):
        for dc in (0, 1):
            b = (hits.axis + 1) % 3
            c = (hits.axis + 2) % 3
            rows = np.arange(len(hits.t))
            cell = hits.start.copy()
            cell[rows, b] -= db
            cell[rows, c] -= dc
            ok = ((cell >= 0) & (cell <= M - 1)).all(axis=1)
            point = hits.start[ok] - cell[ok] + 0.0
            point[np.arange(int(ok.sum())), hits.axis[ok]] += hits.t[ok]
            flat.append((cell[ok, 0] * M + cell[ok, 1]) * M + cell[ok, 2])
            local.append(point)
            normal.append(hits.normal[ok])
    flat, local, normal = np.concatenate(flat), np.concatenate(local), np.concatenate(normal)
    ids, row = np.unique(flat, return_inverse=True)
    C = len(ids)
    if C == 0:
        return np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3), dtype=np.float32)

    def per_cell(values):  # (P, ...) -> (C, ...) sums
        columns = values.reshape(len(values), -1)
        sums = [np.bincount(row, weights=columns[:, i], minlength=C) for i in range(columns.shape[1])]
        return np.stack(sums, axis=1).reshape((C,) + values.shape[1:])

    count = np.bincount(row, minlength=C).astype(np.float64)
    mass = per_cell(local) / count[:, None]
    normal_matrix = per_cell(normal[:, :, None] * normal[:, None, :])  # (C, 3, 3)
    atb = per_cell(normal * np.einsum("pi,pi->p", normal, local)[:, None])
    eigvals, eigvecs = np.linalg.eigh(normal_matrix)
    vtb = np.einsum("cij,ci->cj", eigvecs, atb)
    x, found = _regularised_search(eigvals, eigvecs, vtb, mass)
    lost = np.flatnonzero(~found)
    if len(lost):
        centre = np.full((len(lost), 3), 0.5)
        x[lost], _ = _regularised_search(eigvals[lost], eigvecs[lost], vtb[lost], centre)
    cells = np.stack(np.unravel_index(ids, (M, M, M)), axis=1).astype(np.int64)
    return cells, np.clip(x, 0.0, 1.0).astype(np.float32)


@dataclass
class UNDCLabels:
    """UNDC's training data of one shape on the N^3 grid.

    udf_voxels : (N, N, N) float32, the exact UDF in voxel units (narrow band: >= 2 voxels are 2+).
    edge_flags : (N, N, N, 3) bool, the edge from point p along axis a intersects the mesh.
    edge_mask : (N, N, N, 3) bool, the bool loss's mask (:func:`edge_mask`).
    cell_offsets : (N, N, N, 3) float32, the target vertex of cell p in cell units (zeros where
        ``cell_mask`` is False; the layer p = N - 1 holds no cell).
    cell_mask : (N, N, N) bool, the cell has a target (a hit on one of its 12 edges).
    """

    udf_voxels: np.ndarray
    edge_flags: np.ndarray
    edge_mask: np.ndarray
    cell_offsets: np.ndarray
    cell_mask: np.ndarray


def ground_truth(fields, N: int) -> UNDCLabels:
    """The UNDC labels (:class:`UNDCLabels`) of the mesh of ``fields`` on the N^3 grid: the exact UDF
    (band ``max(default_band(N), 2.5 h)``, beyond which the input is clipped anyway), the flags of
    the edges with a hit (:func:`edge_hits`) and the QEF vertex of every cell with a hit
    (:func:`qef_cell_vertices`)."""
    h = spacing(N)
    udf = fields.grid_scalar(N, "udf", band=max(default_band(N), (INPUT_CLIP + 0.5) * h)) / np.float32(h)
    hits = edge_hits(fields, N)
    flags = np.zeros((N, N, N, 3), dtype=bool)
    flags[hits.start[:, 0], hits.start[:, 1], hits.start[:, 2], hits.axis] = True
    cells, offsets = qef_cell_vertices(N, hits)
    cell_offsets = np.zeros((N, N, N, 3), dtype=np.float32)
    cell_mask = np.zeros((N, N, N), dtype=bool)
    cell_offsets[cells[:, 0], cells[:, 1], cells[:, 2]] = offsets
    cell_mask[cells[:, 0], cells[:, 1], cells[:, 2]] = True
    return UNDCLabels(udf.astype(np.float32), flags, edge_mask(udf), cell_offsets, cell_mask)


# --------------------------------------------------------------------------------------------------
# Inference
# --------------------------------------------------------------------------------------------------

def predict_edge_flags(bool_network: UNDCNetwork, udf_voxels: np.ndarray, grid: np.ndarray | None = None) -> np.ndarray:
    """(N, N, N, 3) bool edge flags: ``sigmoid(bool network) > 0.5`` on the edges of
    :func:`edge_mask` (``udf_voxels``), False elsewhere; the network runs only at the start points of
    those edges (:func:`sparse_forward`)."""
    grid = network_input(udf_voxels) if grid is None else grid
    mask = edge_mask(udf_voxels)
    points = np.argwhere(mask.any(axis=-1))
    flags = np.zeros(mask.shape, dtype=bool)
    if len(points):
        logits = torch.from_numpy(sparse_forward(bool_network, grid, points))
        crossing = (torch.sigmoid(logits) > FLAG_THRESHOLD).numpy()
        flags[points[:, 0], points[:, 1], points[:, 2]] = crossing & mask[points[:, 0], points[:, 1], points[:, 2]]
    return flags


def undc_predict(bool_network: UNDCNetwork, float_network: UNDCNetwork, udf_voxels: np.ndarray) -> dict:
    """UNDC on a UDF grid in voxel units (N, N, N): the mesh in grid index units and its parts.

    Returns ``{'vertices': (C, 3) float64 index units, 'faces': (F, 3) int64 unoriented,
    'edge_flags': (N, N, N, 3) bool, 'cells': (C, 3), 'offsets': (C, 3) float32 in [0, 1]}``; the
    float network runs only at the cells that get a vertex."""
    grid = network_input(udf_voxels)
    flags = predict_edge_flags(bool_network, udf_voxels, grid)
    cells = vertex_cells(flags)
    offsets = np.clip(sparse_forward(float_network, grid, cells), 0.0, 1.0)
    vertices, faces = dual_contour_edges(flags, cells, offsets)
    return {"vertices": vertices, "faces": faces, "edge_flags": flags, "cells": cells, "offsets": offsets}


def unsigned_neural_dual_contouring(udf: np.ndarray, bool_network: UNDCNetwork,
                                    float_network: UNDCNetwork) -> Extraction:
    """UNDC on a UDF sampled on the grid of :mod:`foundation.grid`: :func:`undc_predict` on ``udf / h``.

    Parameters
    ----------
    udf : (N, N, N) unsigned distance on the grid points, canonical units.
    bool_network, float_network : the two networks (:func:`load_weights`).

    Returns
    -------
    :class:`methods.base.Extraction`: vertices (C, 3) float64, canonical frame; faces (F, 3) int64,
    unoriented; info ``undc_edges`` (flagged edges) and ``undc_cells`` (C). Timed as the stage
    ``undc_networks`` (:mod:`foundation.timing`).
    """
    udf = np.asarray(udf, dtype=np.float32)
    N = udf.shape[0]
    with stage("undc_networks"):
        out = undc_predict(bool_network, float_network, udf / np.float32(spacing(N)))
    return Extraction(index_to_world(out["vertices"], N), out["faces"],
                      {"undc_edges": int(out["edge_flags"].sum()), "undc_cells": int(len(out["cells"]))})


# --------------------------------------------------------------------------------------------------
# Weights
# --------------------------------------------------------------------------------------------------

def weights_path() -> Path:
    """The weights file: ``$SALSBENCH_UNDC_WEIGHTS`` when set, else :data:`DEFAULT_WEIGHTS`."""
    return Path(os.environ.get(WEIGHTS_ENV) or DEFAULT_WEIGHTS)


def save_weights(path: str | Path, bool_network: UNDCNetwork, float_network: UNDCNetwork, info: dict) -> str:
    """Write both networks and ``info`` (budget, training-set digest, losses...) to ``path``, atomically
    and checksummed (:func:`foundation.storage.write_checked`). Returns the SHA-256 of the payload."""
    return write_weights_file(path, {"bool": bool_network.state_dict(), "float": float_network.state_dict(),
                                     "config": dict(bool_network.config), "info": dict(info)})


def _training_command(path: Path) -> str:
    return f"python -m methods.training.undc --budget cpu --out {path}"


def load_weights(path: str | Path | None = None) -> tuple[UNDCNetwork, UNDCNetwork, dict]:
    """(bool network, float network, info (with ``sha256``, the payload's digest)) from ``path`` (default
    :func:`weights_path`), in eval mode
    on the CPU, after checking the file's checksum (:func:`foundation.storage.read_checked`).

    Raises :class:`WeightsError` with one line naming the file (and, when it is absent, the command
    that trains it)."""
    path = Path(path) if path is not None else weights_path()
    blob, sha256 = read_weights_file(path, "UNDC weights", _training_command(path), WEIGHTS_ENV)
    info = {**blob["info"], "sha256": sha256}
    networks = []
    for kind in ("bool", "float"):
        network = UNDCNetwork(**blob["config"])
        network.load_state_dict(blob[kind])
        networks.append(network.eval())
    return networks[0], networks[1], info
