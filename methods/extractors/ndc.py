"""Neural Dual Contouring (Chen et al., SIGGRAPH 2022) for SDF input, with NDC's published network.

NDC places one vertex in every grid cell whose corners do not all have the same sign and connects
them by dual contouring; a 3D CNN predicts each vertex's position inside its cell from the SDF
around it. For SDF input the intersection flags are not predicted: they are the signs of the SDF
(inside = ``sdf < 0``). :func:`neural_dual_contouring` is the extractor (SDF grid in canonical
units to mesh); it runs the two steps:

* :func:`ndc_vertex_offsets`: NDC's CNN ``CNN_3d_rec7_resnet`` (three unpadded 3x3x3 convolutions,
  eight residual blocks of 1x1x1 convolutions, leaky ReLU 0.01) evaluated *sparsely*: only at the
  cells that get a vertex and at the cells their receptive field (7^3 grid points) needs. A dense
  ``conv3d`` over the whole grid gives the same values and spends most of its work on empty space.
  It runs block by block (:func:`position_blocks`: :data:`BLOCK` cells per axis, each block with
  the grid points its receptive field reads), so its memory follows one block's surface, not the
  grid's N^3 or its whole surface: what lets a 512^3 grid fit.
* :func:`dual_contour_signs`: NDC's dual contouring of a sign grid with per-cell vertex offsets,
  vectorised (NDC's ``dual_contouring_ndc_test``): the same vertices in the same order and the same
  triangles, which point outward.

Input as NDC feeds its network: the SDF on the grid points in voxel units (one cell edge = 1),
padded by 3 points on each side with +-10 (the sign of the grid's corner point [0, 0, 0]) and
clipped to [-2, 2]. Output offsets are clipped to [0, 1] (cell units).

The network runs in float64 and its outputs are rounded to float32 (:func:`inference_state`): a
float32 matrix product sums in an order that depends on the CPU's kernels and the thread count,
and its rounding differences reach the offsets; float64's are far below a float32 step, so every
CPU gives the same offsets, bit for bit (docs/TESTING.md, "What reproduces").

The weights are data: ``network_float.pth`` of NDC's repository (MIT), found at
``$SALSBENCH_NDC_WEIGHTS`` or :data:`DEFAULT_WEIGHTS`, and checked against their published SHA-256
before use.
"""

from __future__ import annotations

import hashlib
import io
import itertools
import os
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from foundation.grid import index_to_world, spacing
from foundation.timing import stage
from methods.base import Extraction
from methods.core.weights import WeightsError

#: Environment variable naming the weights file.
WEIGHTS_ENV = "SALSBENCH_NDC_WEIGHTS"
#: Where the weights are found without the variable: ``shared/data/weights/ndc/`` in the directory
#: that holds the checkout.
DEFAULT_WEIGHTS = Path(__file__).resolve().parents[3] / "shared" / "data" / "weights" / "ndc" / "network_float.pth"
#: SHA-256 of NDC's published SDF-input network (github.com/czq142857/NDC, ``network_float.pth``).
WEIGHTS_SHA256 = "935d1bb16fb7c2bbbb68e2c3f521001aae1cbeff4cf0fc01984f414cfe4a247e"
#: The ABC object ids (inclusive) NDC's published networks were trained on (its training split:
#: ABC objects 00000002-00007903).
TRAINING_ABC_IDS = ((2, 7903),)

#: Grid points of padding each side: the receptive field of the three unpadded 3x3x3 convolutions.
RECEPTIVE_PADDING = 3
#: Input clip, voxel units.
INPUT_CLIP = 2.0
#: Value of the padding before the clip (its sign is the corner point's).
PADDING_VALUE = 10.0
LEAKY_SLOPE = 0.01
#: The residual blocks after the last 3x3x3 convolution (res_1 follows conv_0, res_2 conv_1).
_TAIL_RESIDUALS = tuple(f"res_{i}" for i in range(3, 9))
#: The 27 offsets of a 3x3x3 kernel in the C order of its weight's (kd, kh, kw) axes.
KERNEL_OFFSETS = np.array(list(itertools.product(range(3), repeat=3)), dtype=np.int64)
#: Rows gathered per matrix product of a sparse 3x3x3 convolution (bounds the (rows, 27 x 64) buffer).
_CHUNK = 16384
#: Output positions per axis of a block of the sparse networks (:func:`position_blocks`).
BLOCK = 64


def weights_path() -> Path:
    """The weights file: ``$SALSBENCH_NDC_WEIGHTS`` when set, else :data:`DEFAULT_WEIGHTS`."""
    return Path(os.environ.get(WEIGHTS_ENV) or DEFAULT_WEIGHTS)


def load_weights(path: str | Path | None = None) -> dict[str, torch.Tensor]:
    """NDC's state dict (float32 CPU tensors) from ``path`` (default :func:`weights_path`), after
    checking the file's SHA-256.

    Raises :class:`WeightsError` with one line naming the file when it is absent or differs."""
    return _load_checked(str(Path(path) if path is not None else weights_path()))


@lru_cache(maxsize=2)
def _load_checked(path: str) -> dict[str, torch.Tensor]:
    if not Path(path).is_file():
        raise WeightsError(f"NDC weights not found at {path} (set {WEIGHTS_ENV} to network_float.pth "
                           "of github.com/czq142857/NDC)")
    data = Path(path).read_bytes()
    digest = hashlib.sha256(data).hexdigest()
    if digest != WEIGHTS_SHA256:
        raise WeightsError(f"{path} is not NDC's published SDF network (sha256 {digest[:12]}..., "
                           f"expected {WEIGHTS_SHA256[:12]}...)")
    state = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    return {k: v.float() for k, v in state.items()}


#: The dtype the networks of NDC and UNDC are evaluated in (their outputs are then rounded to float32).
INFERENCE_DTYPE = torch.float64


def inference_state(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """A state dict's tensors on the CPU in :data:`INFERENCE_DTYPE`."""
    return {k: v.detach().to("cpu", INFERENCE_DTYPE) for k, v in state.items()}


def network_input(sdf_voxels: np.ndarray) -> np.ndarray:
    """NDC's input grid from an SDF in voxel units, shape (N, N, N): padded by
    :data:`RECEPTIVE_PADDING` with +-:data:`PADDING_VALUE` (the sign of point [0, 0, 0]) and clipped
    to [-2, 2]; shape (N + 6,)^3, float32."""
    sdf_voxels = np.asarray(sdf_voxels, dtype=np.float32)
    fill = PADDING_VALUE if sdf_voxels[0, 0, 0] > 0 else -PADDING_VALUE
    padded = np.pad(sdf_voxels, RECEPTIVE_PADDING, mode="constant", constant_values=fill)
    return np.clip(padded, -INPUT_CLIP, INPUT_CLIP)


def leaky(x: torch.Tensor) -> torch.Tensor:
    return F.leaky_relu(x, LEAKY_SLOPE)


def pointwise_conv(state: dict, name: str, x: torch.Tensor) -> torch.Tensor:
    """A 1x1x1 convolution on rows of features (M, C_in) -> (M, C_out)."""
    w = state[f"{name}.weight"]
    return torch.addmm(state[f"{name}.bias"], x, w.reshape(w.shape[0], -1).t())


def _residual(state: dict, name: str, x: torch.Tensor) -> torch.Tensor:
    y = leaky(pointwise_conv(state, f"{name}.conv_1", x))
    return leaky(pointwise_conv(state, f"{name}.conv_2", y) + x)


def sparse_conv3(state: dict, name: str, features: torch.Tensor, index: np.ndarray, coords: np.ndarray) -> torch.Tensor:
    """An unpadded 3x3x3 convolution evaluated at output positions ``coords`` (M, 3): output (p)
    reads the input at p + (a, b, c), a, b, c in {0, 1, 2}; ``index`` maps an input position to its
    row of ``features`` (-1: not computed, which the caller's dilation rules out)."""
    w = state[f"{name}.weight"]  # (out, in, 3, 3, 3)
    matrix = w.permute(2, 3, 4, 1, 0).reshape(27 * w.shape[1], w.shape[0])
    out = torch.empty((len(coords), w.shape[0]), dtype=features.dtype)
    for start in range(0, len(coords), _CHUNK):
        block = coords[start:start + _CHUNK, None, :] + KERNEL_OFFSETS[None]
        rows = torch.from_numpy(index[block[..., 0], block[..., 1], block[..., 2]].reshape(-1))
        gathered = features.index_select(0, rows).reshape(len(block), -1)
        out[start:start + _CHUNK] = torch.addmm(state[f"{name}.bias"], gathered, matrix)
    return leaky(out)


def receptive_positions(coords: np.ndarray, shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The positions an unpadded 3x3x3 convolution at ``coords`` reads, sorted (C order), and a
    volume of ``shape`` mapping each to its row (-1 elsewhere)."""
    mask = np.zeros(shape, dtype=bool)
    reads = coords[:, None, :] + KERNEL_OFFSETS[None]
    mask[reads[..., 0].ravel(), reads[..., 1].ravel(), reads[..., 2].ravel()] = True
    needed = np.argwhere(mask)
    index = np.full(shape, -1, dtype=np.int64)
    index[needed[:, 0], needed[:, 1], needed[:, 2]] = np.arange(len(needed))
    return needed, index


def position_blocks(positions: np.ndarray, block: int = BLOCK):
    """Output ``positions`` (M, 3) of a sparse network grouped by block of ``block`` positions per
    axis: yields ``(rows, origin)``, the rows of ``positions`` in one block (in their order) and the
    block's lowest position. A network whose outputs at p read its input at p .. p + 6 gives each
    block's outputs from the input ``[origin, origin + block + 6)`` alone, the same values as on the
    whole grid."""
    if len(positions) == 0:
        return
    key = positions // block
    order = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))
    ordered = key[order]
    starts = np.flatnonzero(np.r_[True, np.any(ordered[1:] != ordered[:-1], axis=1)])
    for lo, hi in zip(starts, np.r_[starts[1:], len(order)]):
        yield order[lo:hi], ordered[lo] * block


def block_input(grid: np.ndarray, origin: np.ndarray, block: int = BLOCK) -> np.ndarray:
    """The input a block of outputs at ``origin`` reads (:func:`position_blocks`): the last three
    axes of ``grid`` cut to ``[origin, origin + block + 2 * RECEPTIVE_PADDING)``."""
    cut = tuple(slice(int(o), int(o) + block + 2 * RECEPTIVE_PADDING) for o in origin)
    return grid[(Ellipsis, *cut)]


def ndc_vertex_offsets(sdf_voxels: np.ndarray, cells: np.ndarray, state: dict | None = None,
                       block: int = BLOCK) -> np.ndarray:
    """NDC's predicted vertex position inside each of ``cells``, in cell units.

    Parameters
    ----------
    sdf_voxels : (N, N, N) signed distance on the grid points in voxel units (negative inside).
    cells : (M, 3) int cell indices (i, j, k), each in [0, N - 1).
    state : NDC's state dict (default: :func:`load_weights`).
    block : cells per axis evaluated at once (:func:`position_blocks`; the values do not depend on it).

    Returns
    -------
    (M, 3) float32 offsets in [0, 1]^3 from the cell's lower corner, clipped as NDC does; evaluated
    in :data:`INFERENCE_DTYPE` and rounded to float32, so the same bits on every CPU.
    """
    state = inference_state(load_weights() if state is None else state)
    grid = network_input(sdf_voxels)
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    offsets = np.zeros((len(cells), 3), dtype=np.float32)
    for rows, origin in position_blocks(cells, block):
        offsets[rows] = _block_offsets(state, block_input(grid, origin, block), cells[rows] - origin)
    return offsets


def _block_offsets(state: dict, grid: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """:func:`ndc_vertex_offsets` of ``cells`` on the network input ``grid`` that holds their
    receptive fields (cells at p read grid points p .. p + 6)."""
    shape = np.array(grid.shape) - 2 * RECEPTIVE_PADDING
    # positions per layer output: conv_2 -> the cells, conv_1 -> (shape + 2), conv_0 -> (shape + 4)
    at_conv1, index_conv1 = receptive_positions(cells, tuple(int(s) for s in shape + 2))
    at_conv0, index_conv0 = receptive_positions(at_conv1, tuple(int(s) for s in shape + 4))
    with torch.no_grad():
        patches = at_conv0[:, None, :] + KERNEL_OFFSETS[None]
        x = torch.from_numpy(grid[patches[..., 0], patches[..., 1], patches[..., 2]]).to(INFERENCE_DTYPE)  # (M0, 27)
        w0 = state["conv_0.weight"]
        x = leaky(torch.addmm(state["conv_0.bias"], x, w0.permute(2, 3, 4, 1, 0).reshape(27, -1)))
        x = _residual(state, "res_1", x)
        x = sparse_conv3(state, "conv_1", x, index_conv0, at_conv1)
        x = _residual(state, "res_2", x)
        x = sparse_conv3(state, "conv_2", x, index_conv1, cells)
        for name in _TAIL_RESIDUALS:
            x = _residual(state, name, x)
        x = leaky(pointwise_conv(state, "conv_3", x))
        x = leaky(pointwise_conv(state, "conv_4", x))
        offsets = pointwise_conv(state, "conv_out_float", x).to(torch.float32)
    return np.clip(offsets.numpy(), 0.0, 1.0)


def active_cells(inside: np.ndarray) -> np.ndarray:
    """Cells (i, j, k) of an (N, N, N) boolean grid whose 8 corners are not all equal, (M, 3) int64
    in C order (NDC's vertex order)."""
    inside = np.asarray(inside, dtype=bool)
    corners = [inside[a:inside.shape[0] - 1 + a, b:inside.shape[1] - 1 + b, c:inside.shape[2] - 1 + c]
               for a, b, c in itertools.product((0, 1), repeat=3)]
    anyone, everyone = np.logical_or.reduce(corners), np.logical_and.reduce(corners)
    return np.argwhere(anyone & ~everyone)


#: Per axis: the four cells around an edge (offsets from the edge's start point, in NDC's corner
#: names c00 = (-1, -1), c10, c11, c01 over the two other axes) and the two triangles of its quad
#: when the edge's start point is outside, as NDC writes them (indices into those four cells).
_QUAD_CELLS = {
    0: np.array([[0, -1, -1], [0, 0, -1], [0, 0, 0], [0, -1, 0]]),
    1: np.array([[-1, 0, -1], [0, 0, -1], [0, 0, 0], [-1, 0, 0]]),
    2: np.array([[-1, -1, 0], [-1, 0, 0], [0, 0, 0], [0, -1, 0]]),
}
_OUTSIDE_FIRST = {0: np.array([[0, 2, 1], [0, 3, 2]]), 1: np.array([[0, 1, 2], [0, 2, 3]]),
                  2: np.array([[0, 1, 2], [0, 2, 3]])}


def dual_contour_signs(inside: np.ndarray, offsets: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """NDC's dual contouring of a sign grid.

    Parameters
    ----------
    inside : (N, N, N) bool, True inside.
    offsets : (M, 3) vertex positions inside ``cells`` in cell units.
    cells : (M, 3) the active cells (:func:`active_cells`), in that order.

    Returns
    -------
    vertices : (M, 3) float64 in grid index units (vertex m at ``cells[m] + offsets[m]``).
    faces : (F, 3) int64, two triangles per grid edge whose end points differ (edges on the grid's
        boundary faces have no quad), oriented outward (right-hand normal away from the inside):
        the triangles of NDC's code in its order (axis, then edge in C order).
    """
    inside = np.asarray(inside, dtype=bool)
    n = inside.shape
    vertex_of = np.full(tuple(s - 1 for s in n), -1, dtype=np.int64)
    vertex_of[cells[:, 0], cells[:, 1], cells[:, 2]] = np.arange(len(cells))
    faces = []
    for axis in range(3):
        lo = [1, 1, 1]
        lo[axis] = 0
        hi = [s - 1 for s in n]
        start = inside[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
        step = np.zeros(3, dtype=np.int64)
        step[axis] = 1
        end = inside[lo[0] + step[0]:hi[0] + step[0], lo[1] + step[1]:hi[1] + step[1], lo[2] + step[2]:hi[2] + step[2]]
        crossing = np.argwhere(start != end) + np.array(lo)
        quad = vertex_of[tuple(np.moveaxis(crossing[:, None, :] + _QUAD_CELLS[axis][None], -1, 0))]  # (E, 4)
        tris = quad[:, _OUTSIDE_FIRST[axis]]  # (E, 2, 3)
        flip = inside[crossing[:, 0], crossing[:, 1], crossing[:, 2]]
        tris[flip] = tris[flip][:, :, [0, 2, 1]]
        faces.append(tris.reshape(-1, 3))
    faces = np.concatenate(faces)
    vertices = cells.astype(np.float64) + np.asarray(offsets, dtype=np.float64)
    return vertices, np.ascontiguousarray(faces, dtype=np.int64)


def neural_dual_contouring(sdf: np.ndarray, state: dict | None = None) -> Extraction:
    """NDC on an SDF sampled on the grid of :mod:`foundation.grid`.

    Parameters
    ----------
    sdf : (N, N, N) signed distance on the grid points, canonical units (negative inside).
    state : NDC's state dict (default: :func:`load_weights`).

    Returns
    -------
    :class:`methods.base.Extraction`: vertices (M, 3) float64, canonical frame, one per active
    cell (:func:`active_cells`); faces (F, 3) int64, oriented outward (:func:`dual_contour_signs`);
    info ``ndc_cells`` (M). The network and the dual contouring are timed as the stages
    ``ndc_network`` and ``dual_contouring`` (:mod:`foundation.timing`).
    """
    sdf = np.asarray(sdf, dtype=np.float32)
    N = sdf.shape[0]
    sdf_voxels = sdf / np.float32(spacing(N))
    inside = sdf_voxels < 0
    cells = active_cells(inside)
    with stage("ndc_network"):
        offsets = ndc_vertex_offsets(sdf_voxels, cells, state)
    with stage("dual_contouring"):
        vertices, faces = dual_contour_signs(inside, offsets, cells)
    return Extraction(index_to_world(vertices, N), faces, {"ndc_cells": int(len(cells))})
