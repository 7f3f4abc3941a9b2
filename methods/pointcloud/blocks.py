"""Block-wise reconstruction of a large cloud: one global grid, blocks that own disjoint parts of it.

A scene is reconstructed on one global grid of ``N`` points per axis over the canonical cube
(:mod:`foundation.grid`; a scene larger than an object gets a larger ``N`` at the same spacing
relative to its point density, :func:`density_scale`). The grid's points are partitioned into
blocks of ``block`` points per axis: block ``b`` owns the points ``lo <= ijk < hi`` (per axis), the
grid edges that start at them and the cells whose lowest corner they are, so every point, edge and
cell belongs to exactly one block. A block sees only the input points within ``halo`` (canonical
units) of the box of what it owns (:func:`crop`).

Two ways to run a method by blocks, by what the method's output is made of:

* **Edges** (:func:`block_edges`, methods with ``edge_field``: ``sals-knn``): a block queries the
  band edges it owns (:func:`band_edges_in_block`: the edges whose midpoint lies within
  ``band h`` of an input point, the test of :func:`methods.pointcloud.neighbourhoods.band_edges`)
  with their K nearest input points, and returns the intersected ones with their ``s`` and
  normals. The driver concatenates every block's edges in edge order and runs E-DC once
  (:func:`merge_edges`): the mesh is a function of the edges alone, so no seam needs stitching. The
  crop holds every input point the block's edges depend on when the halo is at least the band
  radius and every queried midpoint's K-th neighbour is nearer than the crop's boundary; a block
  checks the second condition (:func:`halo_is_enough`) and reports the radius it needs
  (:class:`HaloTooSmall`), and :func:`reconstruct_by_edges` crops again with that radius. Under
  both conditions a block computes, for each of its edges, the very inputs the whole-grid
  reconstruction computes, so the block-wise mesh equals the whole one cell for cell (up to the
  float rounding of the network's batches of other sizes).
* **Windows** (:func:`reconstruct_by_windows`, any point-cloud method): the window of ``window``
  points per axis centred on a block (:func:`window_of`: ``(window - block) // 2`` points on its
  lower side) is mapped onto the canonical cube by the translation and scale that put its points on
  the method's own ``window`` grid (:func:`window_frame`; on a scene grid chosen by
  :func:`density_scale`, a learned method sees the density and the grid spacing it was trained at,
  POCO's rule for large inputs). The method reconstructs the window's crop of the cloud as if it were a shape;
  each block keeps the triangles whose centroid lies in its owned box, moved back to the scene's
  frame. The blocks' surfaces meet at the owned boxes' faces without stitching: where two windows
  disagree there the seam shows gaps or overlaps the size of that disagreement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np
from pykdtree.kdtree import KDTree

from foundation.grid import LOWER, edge_inputs, ijk_axis_to_edge_index, spacing
from methods.base import Extraction
from methods.extractors.edc import edge_dual_contouring
from methods.pointcloud.errors import TooFewPointsError
from methods.pointcloud.neighbourhoods import dilate_by_ball, nearest_distance

__all__ = ["Block", "blocks", "occupied_blocks", "owned_box", "crop", "band_edges_in_block", "halo_is_enough", "HaloTooSmall",
           "BlockEdges", "block_edges", "merge_edges", "reconstruct_by_edges", "window_frame", "clip_to_box",
           "window_of", "window_piece", "merge_pieces", "reconstruct_by_windows", "density_scale",
           "mean_neighbour_distance"]


@dataclass(frozen=True)
class Block:
    """The grid points ``lo <= ijk < hi`` (per axis) of a grid of ``N`` points per axis, with the
    edges starting at them and the cells whose lowest corner they are."""

    N: int
    lo: tuple[int, int, int]
    hi: tuple[int, int, int]

    @property
    def name(self) -> str:
        return "b" + "-".join(str(v) for v in self.lo)


def blocks(N: int, block: int) -> list[Block]:
    """The blocks of ``block`` points per axis (the last one per axis shorter) that partition the
    points of the N grid, in x-major order."""
    if block < 1:
        raise ValueError(f"a block must own at least one grid point per axis, got {block}")
    starts = range(0, N, block)
    return [Block(N, (i, j, k), (min(i + block, N), min(j + block, N), min(k + block, N)))
            for i in starts for j in starts for k in starts]


def owned_box(block: Block) -> tuple[np.ndarray, np.ndarray]:
    """Canonical box ``[lo h, hi h]`` (plus LOWER) of what the block owns: its points, its edges
    (an edge from point hi - 1 reaches hi) and its cells; at the grid's upper face, the cube's."""
    h = spacing(block.N)
    lo = LOWER + np.asarray(block.lo, dtype=np.float64) * h
    hi = LOWER + np.minimum(np.asarray(block.hi, dtype=np.float64), block.N - 1) * h
    return lo, hi


def crop(points: np.ndarray, box: tuple[np.ndarray, np.ndarray], halo: float) -> np.ndarray:
    """Indices (ascending) of the points inside ``box`` grown by ``halo`` on every side."""
    lo, hi = box
    inside = np.all((points >= lo - halo) & (points <= hi + halo), axis=1)
    return np.flatnonzero(inside)


def band_edges_in_block(cloud: np.ndarray, block: Block, radius: float) -> np.ndarray:
    """Flat ids (ascending) of the N grid's edges owned by ``block`` whose midpoint lies within
    ``radius`` of ``cloud``: the same test as :func:`methods.pointcloud.neighbourhoods.band_edges`
    (voxels of the cloud dilated by ``ceil(radius / h) + 2`` steps, then the exact distance), on
    the block's window of points only, so memory follows the block, not the grid. Exact when
    ``cloud`` holds every point within ``radius`` of the block's owned box."""
    N, h = block.N, spacing(block.N)
    lo = np.asarray(block.lo)
    hi = np.minimum(np.asarray(block.hi) + 1, N)  # edges of the last owned points end one further
    shape = tuple(hi - lo)
    steps = int(np.ceil((radius + h) / h)) + 1
    ijk = np.rint((np.asarray(cloud) - LOWER) / h).astype(np.int64) - lo
    near = np.all((ijk >= -steps) & (ijk < np.asarray(shape) + steps), axis=1)
    padded = np.zeros(tuple(s + 2 * steps for s in shape), dtype=bool)
    padded[tuple((ijk[near] + steps).T)] = True
    mask = dilate_by_ball(padded, steps)[tuple(slice(steps, steps + s) for s in shape)]
    owned = tuple(int(v) for v in np.asarray(block.hi) - lo)
    start = mask[:owned[0], :owned[1], :owned[2]]
    ids = []
    for axis in range(3):
        n = min(owned[axis], shape[axis] - 1)  # the grid's last points start no edge along it
        end = np.zeros(owned, dtype=bool)
        src = [slice(0, o) for o in owned]
        src[axis] = slice(1, n + 1)
        dst = [slice(None)] * 3
        dst[axis] = slice(0, n)
        end[tuple(dst)] = mask[tuple(src)]
        ids.append(ijk_axis_to_edge_index(N, np.argwhere(start & end) + lo, axis))
    ids = np.sort(np.concatenate(ids))
    mid = edge_inputs(N, ids).reshape(-1, 2, 3).mean(axis=1)
    return ids[nearest_distance(cloud, mid) <= radius]


def occupied_blocks(points: np.ndarray, N: int, block: int, reach: float) -> list[Block]:
    """The blocks of :func:`blocks` (N grid, ``block`` points per axis) whose owned box grown by
    ``reach`` holds at least one of ``points``, in the order of :func:`blocks`. The others see no
    input point, and a local method gives them nothing."""
    size = block * spacing(N)
    count = -(-N // block)
    x = (np.asarray(points, dtype=np.float64) - LOWER) / size
    first = np.clip(np.ceil(x - reach / size - 1), 0, count - 1).astype(np.int64)
    last = np.clip(np.floor(x + reach / size), 0, count - 1).astype(np.int64)
    keys = set()
    span = int((last - first).max(initial=0)) + 1
    for offset in np.ndindex(span, span, span):
        k = first + np.asarray(offset)
        keep = np.all(k <= last, axis=1)
        keys.update(map(tuple, np.unique(k[keep], axis=0).tolist()))
    return [b for b in blocks(N, block) if tuple(v // block for v in b.lo) in keys]


class HaloTooSmall(Exception):
    """A block's crop misses input points its edges depend on; ``radius`` is the halo it needs."""

    def __init__(self, block: Block, radius: float):
        super().__init__(f"block {block.name}: the halo must be at least {radius:.6g} canonical units")
        self.block, self.radius = block, radius


def halo_is_enough(cloud: np.ndarray, queries: np.ndarray, k: int, box: tuple[np.ndarray, np.ndarray],
                   halo: float) -> float | None:
    """None when every query's ``k`` nearest points of ``cloud`` (a crop of a larger cloud to
    ``box`` grown by ``halo``) are its k nearest in the larger cloud too; else the halo that
    would make it so for these queries.

    A query at distance ``b`` from the crop's boundary has its k nearest of the larger cloud in the
    crop when its k-th nearest in the crop is nearer than ``b`` (any point outside is farther)."""
    if len(queries) == 0:
        return None
    if len(cloud) < k:
        return 2.0 * halo + 1e-9
    dist, _ = KDTree(np.ascontiguousarray(cloud, dtype=np.float64)).query(
        np.ascontiguousarray(queries, dtype=np.float64), k=k)
    kth = np.asarray(dist, dtype=np.float64).reshape(len(queries), k)[:, -1]
    lo, hi = box
    to_boundary = np.minimum(queries - (lo - halo), (hi + halo) - queries).min(axis=1)
    short = kth >= to_boundary
    if not short.any():
        return None
    # a query's distance to the owned box's boundary plus the new halo must exceed its k-th distance
    inner = to_boundary - halo
    return float(np.max(kth[short] - inner[short])) * 1.05 + 1e-9


@dataclass(frozen=True)
class BlockEdges:
    """What a block gives the merge: its intersected edges (flat ids of the N grid, ascending),
    their s and unit normals (None without normals), and what it queried."""

    block: Block
    ids: np.ndarray
    s: np.ndarray
    normals: np.ndarray | None
    queried: int
    points: int


def block_edges(method, cloud: np.ndarray, block: Block, halo: float, model, device=None,
                input_scale: float = 1.0) -> BlockEdges:
    """The intersected edges ``block`` owns, from ``cloud`` (the crop of the scene's cloud to the
    block's owned box grown by ``halo``). ``method`` has ``edge_field``, ``neighbour_count`` and the parameters ``band``
    (in grid steps), ``qef_cutoff`` and ``faces``. Raises :class:`HaloTooSmall` when the crop
    misses points the block's edges depend on."""
    radius = method.params["band"] * spacing(block.N)
    box = owned_box(block)
    if halo < radius:
        raise HaloTooSmall(block, radius)
    ids = band_edges_in_block(cloud, block, radius)
    if len(ids):
        mid = edge_inputs(block.N, ids).reshape(-1, 2, 3).mean(axis=1)
        needed = halo_is_enough(cloud, mid, method.neighbour_count(model), box, halo)
        if needed is not None:
            raise HaloTooSmall(block, needed)
    hit, s, normals = method.edge_field(cloud, block.N, ids, model, device, input_scale=input_scale)
    return BlockEdges(block, hit, s, normals, int(len(ids)), int(len(cloud)))


def merge_edges(parts: Iterable[BlockEdges], N: int, **edc) -> Extraction:
    """E-DC over the union of the blocks' edges (in edge order, as one whole-grid query gives
    them): the block-wise mesh."""
    parts = list(parts)
    ids = np.concatenate([p.ids for p in parts]) if parts else np.zeros(0, np.int64)
    order = np.argsort(ids, kind="stable")
    s = np.concatenate([p.s for p in parts])[order] if parts else np.zeros(0, np.float32)
    with_normals = parts and all(p.normals is not None or len(p.ids) == 0 for p in parts)
    normals = (np.concatenate([p.normals if p.normals is not None else np.zeros((0, 3)) for p in parts])[order]
               if with_normals and len(ids) else None)
    mesh = edge_dual_contouring(N, ids[order], s, normals, **edc)
    return Extraction(mesh.vertices, mesh.faces, info={
        "blocks": len(parts), "queried_edges": int(sum(p.queried for p in parts)),
        "intersected_edges": int(len(ids)), "block_points_max": int(max((p.points for p in parts), default=0))})


def reconstruct_by_edges(method, points: np.ndarray, N: int, block: int, model, device=None,
                         input_scale: float = 1.0, halo: float | None = None,
                         run: Callable[[Callable, list], list] | None = None) -> Extraction:
    """``method`` (with ``edge_field``) on the N grid, block by block (module docstring).

    ``halo`` (canonical units) starts at the band radius plus one grid step (default) and grows for
    a block that reports :class:`HaloTooSmall`. ``run(fn, tasks)`` maps ``fn`` over the tasks
    (default: in this process, in order); a task is ``(block, cloud crop, halo)``."""
    points = np.asarray(points, dtype=np.float64)
    start = method.params["band"] * spacing(N) + spacing(N) if halo is None else float(halo)
    run = run or (lambda fn, tasks: [fn(*t) for t in tasks])

    def one(b: Block, cloud: np.ndarray, h: float):
        try:
            return block_edges(method, cloud, b, h, model, device, input_scale)
        except HaloTooSmall as exc:
            return exc

    todo = {b: start for b in blocks(N, block)}
    done: list[BlockEdges] = []
    retries = 0
    while todo:
        tasks = [(b, points[crop(points, owned_box(b), h)], h) for b, h in todo.items()]
        results = run(one, tasks)
        todo = {}
        for (b, _, h), r in zip(tasks, results):
            if isinstance(r, HaloTooSmall):
                todo[b] = max(r.radius, 2.0 * h)
                retries += 1
            else:
                done.append(r)
    out = merge_edges(done, N, qef_cutoff=method.params["qef_cutoff"], faces=method.params["faces"])
    out.info["halo_retries"] = retries
    return out


def window_frame(block: Block, halo_points: int, window: int) -> tuple[np.ndarray, float]:
    """(origin, scale) of the window around ``block``: the window's grid point 0 is the N grid's
    point ``lo - halo_points``, at canonical ``origin``; ``x_window = LOWER + (x - origin) scale``
    puts the window's ``window`` points per axis on the canonical ``window`` grid."""
    h = spacing(block.N)
    origin = LOWER + (np.asarray(block.lo, dtype=np.float64) - halo_points) * h
    return origin, (block.N - 1) / (window - 1)


def clip_to_box(vertices: np.ndarray, faces: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The faces whose centroid lies in the half-open box ``lo <= c < hi``."""
    if len(faces) == 0:
        return faces
    c = vertices[faces].mean(axis=1)
    return faces[np.all((c >= lo) & (c < hi), axis=1)]


def _owned_half_open(block: Block) -> tuple[np.ndarray, np.ndarray]:
    """The block's owned box as a half-open one, open to infinity at the grid's faces, so the
    blocks' boxes tile space and every centroid falls in exactly one."""
    h = spacing(block.N)
    lo = np.where(np.asarray(block.lo) > 0, LOWER + np.asarray(block.lo) * h, -np.inf)
    hi = np.where(np.asarray(block.hi) < block.N, LOWER + np.asarray(block.hi) * h, np.inf)
    return lo, hi


def window_of(block: Block, window: int) -> tuple[int, tuple[np.ndarray, np.ndarray]]:
    """(halo points, canonical box) of the window of ``window`` grid points per axis centred on
    ``block``: ``(window - block size) // 2`` points on its lower side."""
    size = max(b - a for a, b in zip(block.lo, block.hi))
    halo_points = (window - size) // 2
    if halo_points < 1:
        raise ValueError(f"a window of {window} points leaves no halo around a block of {size} points")
    origin, _ = window_frame(block, halo_points, window)
    return halo_points, (origin, origin + (window - 1) * spacing(block.N))


def window_piece(method, cloud: np.ndarray, block: Block, window: int, device=None, seed: int = 0,
                 sensors: np.ndarray | None = None, min_points: int = 16, **network) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) that ``block`` owns of ``method.reconstruct`` on its window (the points of
    ``cloud`` inside the window's box, with their ``sensors`` for a method that uses them, moved to
    the window's frame), in the frame of ``cloud``. Nothing below ``min_points`` input points, nor
    where the window holds fewer points than the method's neighbourhoods (:class:`TooFewPointsError`)."""
    halo_points, box = window_of(block, window)
    rows = crop(cloud, box, 0.0)
    if len(rows) < min_points:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    origin, scale = window_frame(block, halo_points, window)
    if sensors is not None:
        network = {**network, "sensors": LOWER + (np.asarray(sensors)[rows] - origin) * scale}
    try:
        out = method.reconstruct(LOWER + (np.asarray(cloud)[rows] - origin) * scale, window, device, seed=seed,
                                 **network)
    except TooFewPointsError:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    V = (np.asarray(out.vertices, dtype=np.float64) - LOWER) / scale + origin
    F = clip_to_box(V, np.asarray(out.faces, dtype=np.int64), *_owned_half_open(block))
    used, F = np.unique(F, return_inverse=True)
    return V[used], F.reshape(-1, 3)


def merge_pieces(pieces: Iterable[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """One mesh of the blocks' pieces (vertices concatenated, faces re-indexed; nothing welded)."""
    pieces = list(pieces)
    offsets = np.cumsum([0] + [len(V) for V, _ in pieces])
    V = np.concatenate([V for V, _ in pieces]) if pieces else np.zeros((0, 3))
    F = np.concatenate([F + o for (_, F), o in zip(pieces, offsets)]) if pieces else np.zeros((0, 3), np.int64)
    return V, F.reshape(-1, 3).astype(np.int64)


def reconstruct_by_windows(method, points: np.ndarray, N: int, block: int, window: int, device=None, seed: int = 0,
                           sensors: np.ndarray | None = None,
                           run: Callable[[Callable, list], list] | None = None, **network) -> Extraction:
    """``method.reconstruct`` window by window on the N grid (module docstring): blocks of
    ``block`` points per axis, each reconstructed from the points of the window of ``window``
    points centred on it, on the method's ``window`` grid, keeping the triangles whose centroid it
    owns. ``network``: passed to ``method.reconstruct`` (a learned method's model)."""
    points = np.asarray(points, dtype=np.float64)
    run = run or (lambda fn, tasks: [fn(*t) for t in tasks])
    parts = blocks(N, block)
    pieces = run(lambda b: window_piece(method, points, b, window, device, seed, sensors, **network),
                 [(b,) for b in parts])
    V, F = merge_pieces(pieces)
    return Extraction(V, F, info={"blocks": len(parts)})


def mean_neighbour_distance(points: np.ndarray) -> float:
    """Mean distance of each point to its nearest other point (the density measure of POCO's rule)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    dist, _ = KDTree(points).query(points, k=2)
    return float(np.mean(np.asarray(dist).reshape(len(points), 2)[:, 1]))


def density_scale(points: np.ndarray, reference_distance: float, N: int) -> tuple[int, float]:
    """POCO's rule for large inputs: the grid on which ``points`` have the density of training.

    A method trained on clouds whose mean neighbour distance is ``reference_distance`` at grid
    ``N`` sees ``points`` at that density once they are scaled by ``f = reference_distance /
    mean_neighbour_distance(points)``; at the training grid's spacing the scaled cube needs
    ``N' = round(f (N - 1)) + 1`` points per axis. Returns ``(N', (N' - 1) / (N - 1))``: the grid
    and the scale ``f`` rounded to it (the ``input_scale`` of :func:`reconstruct_by_edges`)."""
    f = reference_distance / mean_neighbour_distance(points)
    if not math.isfinite(f) or f <= 0:
        raise ValueError(f"no density scale for a cloud of mean neighbour distance {reference_distance / f}")
    n = max(2, int(round(f * (N - 1))) + 1)
    return n, (n - 1) / (N - 1)
