"""The ``rooms`` dataset: Synthetic-Rooms-style scenes generated from a seed.

After ConvONet's Synthetic Rooms (Peng et al., ECCV 2020, ``scripts/dataset_synthetic_room``): a
floor, up to four walls and 4-8 objects standing on the floor without overlapping footprints; the
GT of a room is all of them concatenated as one triangle soup (components touch: kind
'nonmanifold'), moved to the canonical frame. Our objects are CAD parts of the built-in generator
(or the meshes of a folder, option ``objects_dir``), not ShapeNet furniture. The steps, one function
each (room units throughout, z up):

1. :func:`floor_and_walls`: the floor box ``[0, sx] x [0, sy] x [-FLOOR_THICKNESS, 0]``, one side
   1 and the other U[0.3, 1] (which axis is the long one: a fair coin); each of the four walls
   (``x0``, ``x1``, ``y0``, ``y1``: on the floor edge x = 0, x = sx, y = 0, y = sy) present with
   probability 0.5, height U[0.2, 0.4] drawn per wall, thickness ``WALL_THICKNESS``; a wall stands
   on the floor top (z in [0, h]) inside the floor outline along its edge (``y0``/``y1`` span the
   whole x side, ``x0``/``x1`` the y side between them, so walls never overlap).
2. :func:`draw_objects`: the number of objects U{4..8}; per object the index of its source mesh
   (uniform), its size group (uniform among :data:`SIZE_GROUPS`) and its max extent U[group].
3. :func:`object_in_local_frame`: the object's mesh scaled so the largest side of its own
   axis-aligned bounding box is the max extent, its xy bounding-box centre at the origin and its
   lowest vertex at z = 0 exactly; :func:`footprint`: the 2D convex hull of its xy projection.
4. :func:`place_objects`: rejection sampling, objects in draw order: per object ``MAX_TRIES`` tries,
   each a yaw U[0, 2 pi) and a position uniform among those that keep the yawed hull inside the
   floor less a ``WALL_THICKNESS`` margin (whether or not the walls are there); the first try whose
   hull is at least ``MIN_GAP`` from every hull placed before (separating-axis test on the exact
   convex hulls) is kept. An object with no such try is dropped and recorded.
5. :func:`build_room` (room units, with the room's record) and :func:`room_shape` (the canonical
   :class:`~datasets.io.Shape`, via :func:`datasets.io.normalize_shape`).

Randomness: the layout (steps 1, 2 and 4) is drawn from ``numpy.random.default_rng([seed, index])``
in that order, with a fixed number of draws per step (all four walls' presence and heights, all
``MAX_TRIES`` tries of an object even when the first one fits), so room ``index`` does not depend on
``count`` and the same (seed, index) gives bit-identical arrays. A built-in object in slot ``j`` of
room ``index`` is :func:`datasets.builtin.build_part` of its template with dimensions from
``default_rng([seed, index, OBJECT_STREAM + j])`` (OBJECT_STREAM = 100; the built-in test shapes
and the learned methods' training parts use streams 0-2), moved to its canonical frame and refined
like a built-in part (:func:`datasets.builtin.canonical_part` with ``REFINE_LENGTH``), so it is never
one of those shapes' parts.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from datasets.abc import scan_meshes
from datasets.builtin import REFINE_LENGTH, TEMPLATE_NAMES, build_part, canonical_part, manifold_arrays
from datasets.io import MESH_EXTENSIONS, Shape, load_shape, normalize_shape
from datasets.registry import Dataset, DatasetError, DatasetNotFoundError, as_int, existing_dir, register_dataset

#: Floor: one side this long (room units), the other U[MIN_FLOOR_SIDE, FLOOR_SIDE].
FLOOR_SIDE, MIN_FLOOR_SIDE = 1.0, 0.3
#: Floor thickness: the floor spans z in [-FLOOR_THICKNESS, 0]; objects and walls stand on z = 0.
FLOOR_THICKNESS = 0.01
#: Wall thickness, and the margin every object footprint keeps from the floor's edges.
WALL_THICKNESS = 0.01
#: Each wall is present with this probability; its height is U[WALL_HEIGHT].
WALL_PROBABILITY, WALL_HEIGHT = 0.5, (0.2, 0.4)
#: Walls in draw order: on the floor edge x = 0, x = sx, y = 0, y = sy.
WALL_NAMES = ("x0", "x1", "y0", "y1")
#: Objects drawn per room: U{MIN_OBJECTS, ..., MAX_OBJECTS}.
MIN_OBJECTS, MAX_OBJECTS = 4, 8
#: Size groups, picked uniformly: the max extent (largest side of the object's own bounding box,
#: room units) is uniform in the group's interval.
SIZE_GROUPS = ((0.10, 0.25), (0.15, 0.35), (0.25, 0.45))
#: Tries per object in the rejection sampling of its (yaw, position); then it is dropped.
MAX_TRIES = 200
#: Smallest distance between two objects' footprints (room units).
MIN_GAP = 0.001
#: Slot j of a room draws its built-in part from default_rng([seed, index, OBJECT_STREAM + j]).
OBJECT_STREAM = 100
DEFAULT_COUNT = 10

Mesh = tuple[np.ndarray, np.ndarray]


# -- meshes ---------------------------------------------------------------------------------------


def box_mesh(lo: Sequence[float], hi: Sequence[float]) -> Mesh:
    """The axis-aligned box [lo, hi]: 8 vertices (n, 3) float64 and 12 outward-facing triangles."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    corner = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=bool)
    vertices = np.where(corner, hi, lo)
    faces = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6],  # z = lo, z = hi
                      [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7],  # y = lo, y = hi
                      [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]],  # x = lo, x = hi
                     dtype=np.int64)
    return vertices, faces


# -- step 1: floor and walls ----------------------------------------------------------------------


@dataclass(frozen=True)
class Shell:
    """Floor and walls of a room (room units). ``floor_size`` = (sx, sy); per wall of
    :data:`WALL_NAMES`: present or not, and its height (drawn even for an absent wall)."""

    floor_size: tuple[float, float]
    walls_present: tuple[bool, bool, bool, bool]
    wall_heights: tuple[float, float, float, float]

    def record(self) -> dict[str, Any]:
        return {"floor_size": list(self.floor_size), "floor_z": [-FLOOR_THICKNESS, 0.0],
                "walls": [{"side": n, "present": p, "height": h, "thickness": WALL_THICKNESS}
                          for n, p, h in zip(WALL_NAMES, self.walls_present, self.wall_heights)]}


def draw_shell(rng: np.random.Generator) -> Shell:
    """Draw floor size and walls (5 + 4 + 4 draws, always): the long axis (a fair coin), the short
    side U[0.3, 1], each wall's presence (probability 0.5) and height U[0.2, 0.4]."""
    long_axis = int(rng.integers(2))
    short = float(rng.uniform(MIN_FLOOR_SIDE, FLOOR_SIDE))
    size = (FLOOR_SIDE, short) if long_axis == 0 else (short, FLOOR_SIDE)
    present = rng.random(len(WALL_NAMES)) < WALL_PROBABILITY
    heights = rng.uniform(*WALL_HEIGHT, size=len(WALL_NAMES))
    return Shell(size, tuple(bool(p) for p in present), tuple(float(h) for h in heights))


def shell_meshes(shell: Shell) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, vertices, faces) of the floor ('floor') and of each present wall ('wall_x0', ...)."""
    sx, sy = shell.floor_size
    t = WALL_THICKNESS
    boxes = {"x0": ((0.0, t, 0.0), (t, sy - t)), "x1": ((sx - t, t, 0.0), (sx, sy - t)),
             "y0": ((0.0, 0.0, 0.0), (sx, t)), "y1": ((0.0, sy - t, 0.0), (sx, sy))}
    meshes = [("floor", *box_mesh((0.0, 0.0, -FLOOR_THICKNESS), (sx, sy, 0.0)))]
    for wall, present, height in zip(WALL_NAMES, shell.walls_present, shell.wall_heights):
        if present:
            lo, (hx, hy) = boxes[wall]
            meshes.append((f"wall_{wall}", *box_mesh(lo, (hx, hy, height))))
    return meshes


def floor_and_walls(rng: np.random.Generator) -> tuple[Shell, list[tuple[str, np.ndarray, np.ndarray]]]:
    """Step 1: :func:`draw_shell` and its meshes (:func:`shell_meshes`)."""
    shell = draw_shell(rng)
    return shell, shell_meshes(shell)


# -- step 2: which objects ------------------------------------------------------------------------


@dataclass(frozen=True)
class ObjectDraw:
    """One object slot of a room: its source mesh (index into the source's names), size group and
    max extent (room units)."""

    slot: int
    choice: int
    group: int
    max_extent: float


def draw_objects(rng: np.random.Generator, n_choices: int) -> list[ObjectDraw]:
    """Step 2 (1 + 3 x count draws): the count U{4..8}, then per slot the source mesh
    U{0..n_choices-1}, the size group U{0..2} and the max extent U[group interval]."""
    count = int(rng.integers(MIN_OBJECTS, MAX_OBJECTS + 1))
    choices = rng.integers(n_choices, size=count)
    groups = rng.integers(len(SIZE_GROUPS), size=count)
    lo, hi = np.asarray(SIZE_GROUPS)[groups].T
    extents = lo + (hi - lo) * rng.random(count)
    return [ObjectDraw(j, int(c), int(g), float(e)) for j, (c, g, e) in enumerate(zip(choices, groups, extents))]


# -- where objects come from ----------------------------------------------------------------------


class ObjectSource(Protocol):
    """What a room's objects are drawn from: ``names`` (one per mesh the rng can pick),
    ``mesh(choice, seed, index, slot) -> (vertices, faces)`` in any frame (z up; the room scales and
    moves it) and ``describe(...)``, the object's source as one line for the room's record."""

    names: tuple[str, ...]

    def mesh(self, choice: int, seed: int, index: int, slot: int) -> Mesh: ...

    def describe(self, choice: int, seed: int, index: int, slot: int) -> str: ...


class BuiltinParts:
    """The built-in CAD templates (:data:`datasets.builtin.TEMPLATE_NAMES`). Slot ``slot`` of room
    ``index`` at ``seed``: ``build_part(template, seed, index, OBJECT_STREAM + slot)`` in its
    canonical frame, refined to ``REFINE_LENGTH`` like a built-in part."""

    names = TEMPLATE_NAMES

    def mesh(self, choice: int, seed: int, index: int, slot: int) -> Mesh:
        part = build_part(self.names[choice], seed, index, OBJECT_STREAM + slot)
        return manifold_arrays(canonical_part(part, REFINE_LENGTH))

    def describe(self, choice: int, seed: int, index: int, slot: int) -> str:
        return f"builtin:{self.names[choice]} rng=[{seed}, {index}, {OBJECT_STREAM + slot}]"


def objects_folder(objects_dir, dataset: str) -> Path | None:
    """The folder a scene dataset draws its objects from (None: the built-in parts); a missing
    folder or one without mesh files is a one-line error naming the option ``objects_dir``."""
    if objects_dir is None or str(objects_dir) == "":
        return None
    try:
        folder = existing_dir(objects_dir, dataset)
    except DatasetNotFoundError as exc:
        raise DatasetNotFoundError(str(exc).replace("data_dir", "objects_dir", 1)) from None
    if not scan_meshes(folder):
        raise DatasetError(f"dataset '{dataset}': no mesh files ({' '.join(MESH_EXTENSIONS)}) in objects_dir {folder}")
    return folder


class MeshFiles:
    """The mesh files of a folder (:func:`datasets.abc.scan_meshes`: recursive, sorted by relative
    path), read with :func:`datasets.io.load_shape` (a bad file: MeshError naming it), unused
    vertices dropped; each file is read once per instance. Names: relative paths."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.files = tuple(scan_meshes(self.folder))
        self.names = tuple(p.relative_to(self.folder).as_posix() for p in self.files)
        self._read: dict[int, Mesh] = {}

    def mesh(self, choice: int, seed: int, index: int, slot: int) -> Mesh:
        if choice not in self._read:
            shape = load_shape(self.files[choice], kind="closed")
            used = np.unique(shape.faces)
            remap = np.zeros(len(shape.vertices), dtype=np.int64)
            remap[used] = np.arange(len(used))
            self._read[choice] = (shape.vertices[used], remap[shape.faces])
        return self._read[choice]

    def describe(self, choice: int, seed: int, index: int, slot: int) -> str:
        return str(self.files[choice])


# -- step 3: an object in its local frame ---------------------------------------------------------


def object_in_local_frame(vertices: np.ndarray, max_extent: float) -> tuple[np.ndarray, float]:
    """The object scaled by s = max_extent / (largest side of its bounding box), its xy
    bounding-box centre moved to the origin and its lowest vertex to z = 0 (exactly: the shift is
    applied before the scale). Returns (vertices (n, 3), s)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    scale = float(max_extent / np.max(hi - lo))
    origin = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    return (vertices - origin) * scale, scale


def footprint(vertices: np.ndarray) -> np.ndarray:
    """The 2D convex hull (h, 2) of the xy projection, counter-clockwise. A projection without area
    (all xy on a line) falls back to its bounding rectangle widened to 1e-6 of its size."""
    xy = np.asarray(vertices, dtype=np.float64)[:, :2]
    try:
        return xy[ConvexHull(xy).vertices]
    except (QhullError, ValueError):
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        pad = 0.5e-6 * max(float(np.max(hi - lo)), 1e-12)
        lo, hi = lo - pad, hi + pad
        return np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])


# -- step 4: placement ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Placement:
    """Where an object stands: yaw (radians, counter-clockwise about +z), position (x, y) of its
    local origin on the floor, and its footprint hull in the room frame (h, 2)."""

    yaw: float
    position: tuple[float, float]
    footprint: np.ndarray = field(repr=False)


def rotate_xy(points: np.ndarray, yaw: np.ndarray | float) -> np.ndarray:
    """Points (..., n, 2) rotated counter-clockwise by ``yaw`` (scalar, or (...) one per set)."""
    c, s = np.cos(yaw), np.sin(yaw)
    c, s = np.asarray(c)[..., None], np.asarray(s)[..., None]
    x, y = points[..., 0], points[..., 1]
    return np.stack([c * x - s * y, s * x + c * y], axis=-1)


def _unit_normals(polygons: np.ndarray) -> np.ndarray:
    """Unit normals (..., h, 2) of the edges of polygons (..., h, 2)."""
    edges = np.roll(polygons, -1, axis=-2) - polygons
    normals = np.stack([edges[..., 1], -edges[..., 0]], axis=-1)
    return normals / np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-300)


def separated(candidates: np.ndarray, polygon: np.ndarray, gap: float) -> np.ndarray:
    """Separating-axis test: for each convex candidate (t, h, 2), whether some edge normal of it
    or of the convex ``polygon`` (p, 2) separates the two by more than ``gap``. Returns (t,) bool."""
    def apart(a_lo, a_hi, b_lo, b_hi):
        return np.any((a_hi + gap < b_lo) | (b_hi + gap < a_lo), axis=-1)

    axes = _unit_normals(candidates)                                      # (t, h, 2)
    own = np.einsum("tpk,tak->tap", candidates, axes)                     # (t, h axes, h points)
    other = np.einsum("pk,tak->tap", polygon, axes)
    by_candidate = apart(own.min(-1), own.max(-1), other.min(-1), other.max(-1))
    axes = _unit_normals(polygon)                                         # (a, 2)
    own = np.einsum("tpk,ak->tap", candidates, axes)
    other = polygon @ axes.T                                              # (p, a)
    by_polygon = apart(own.min(-1), own.max(-1), other.min(0), other.max(0))
    return by_candidate | by_polygon


def place_objects(footprints: Sequence[np.ndarray], floor_size: tuple[float, float], rng: np.random.Generator,
                  tries: int = MAX_TRIES, margin: float = WALL_THICKNESS, gap: float = MIN_GAP,
                  chunk: int = 25) -> list[Placement | None]:
    """Step 4: place objects, in order, by rejection sampling; None for an object that is dropped.

    ``footprints``: each object's hull (h, 2) in its local frame (:func:`footprint`). Per object
    3 x ``tries`` draws, always: ``tries`` yaws U[0, 2 pi) and ``tries`` pairs u in [0, 1)^2. Try k
    rotates the hull by its yaw and puts it at x = lo + u (hi - lo) (likewise y), where [lo, hi] are
    the positions keeping the rotated hull inside [margin, side - margin] (a try with lo > hi is
    invalid). The first try (in order; tested ``chunk`` at a time) whose hull is more than ``gap``
    from the hulls placed so far is kept.
    """
    size = np.asarray(floor_size, dtype=np.float64)
    placed: list[np.ndarray] = []
    result: list[Placement | None] = []
    for hull in footprints:
        yaws = rng.uniform(0.0, 2 * np.pi, size=tries)
        u = rng.random((tries, 2))
        turned = rotate_xy(np.asarray(hull, dtype=np.float64)[None], yaws)      # (tries, h, 2)
        lo = margin - turned.min(axis=1)
        hi = size - margin - turned.max(axis=1)
        fits = np.all(hi >= lo, axis=1)
        offset = lo + u * (hi - lo)
        chosen = None
        for start in range(0, tries, chunk):
            stop = min(start + chunk, tries)
            ok = fits[start:stop].copy()
            moved = turned[start:stop] + offset[start:stop, None, :]
            for other in placed:
                if not ok.any():
                    break
                ok &= separated(moved, other, gap)
            if ok.any():
                chosen = start + int(np.argmax(ok))
                break
        if chosen is None:
            result.append(None)
            continue
        room_hull = turned[chosen] + offset[chosen]
        placed.append(room_hull)
        result.append(Placement(float(yaws[chosen]), (float(offset[chosen, 0]), float(offset[chosen, 1])), room_hull))
    return result


# -- step 5: the room -----------------------------------------------------------------------------


def room_rng(index: int, seed: int) -> np.random.Generator:
    """The generator of room ``index``'s layout: ``default_rng([seed, index])``."""
    return np.random.default_rng([int(seed), int(index)])


def room_layout(index: int, seed: int, n_choices: int) -> tuple[np.random.Generator, Shell, list[ObjectDraw]]:
    """Steps 1-2 without building any object (cheap): the room's generator (positioned for step 4),
    its shell and its object draws."""
    rng = room_rng(index, seed)
    shell = draw_shell(rng)
    return rng, shell, draw_objects(rng, n_choices)


def build_room(index: int, seed: int = 0,
               object_source: ObjectSource | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """Room ``index`` at ``seed`` in room units: (vertices (n, 3) float64, faces (m, 3) int64, record).

    The arrays are floor, present walls (order of :data:`WALL_NAMES`) and placed objects (slot
    order) concatenated, nothing merged. The record (plain JSON data) holds ``seed``, ``index``, the
    shell (``floor_size``, ``floor_z``, ``walls``: side, present, height, thickness), ``objects``
    (placed: slot, name, source, group, group_interval, max_extent, scale, yaw in radians,
    position [x, y, 0] of the local origin), ``dropped`` (the same without yaw/position), ``drawn``
    (the number of slots) and ``components`` (name with vertex and face ranges [start, stop) in the
    arrays).
    """
    source = BuiltinParts() if object_source is None else object_source
    rng, shell, draws = room_layout(index, seed, len(source.names))
    parts = shell_meshes(shell)
    local = []
    for draw in draws:
        vertices, faces = source.mesh(draw.choice, seed, index, draw.slot)
        moved, scale = object_in_local_frame(vertices, draw.max_extent)
        local.append((moved, np.asarray(faces, dtype=np.int64), scale))
    placements = place_objects([footprint(v) for v, _, _ in local], shell.floor_size, rng)
    objects, dropped = [], []
    for draw, (vertices, faces, scale), where in zip(draws, local, placements):
        entry = {"slot": draw.slot, "name": source.names[draw.choice],
                 "source": source.describe(draw.choice, seed, index, draw.slot), "group": draw.group,
                 "group_interval": list(SIZE_GROUPS[draw.group]), "max_extent": draw.max_extent, "scale": scale}
        if where is None:
            dropped.append({**entry, "reason": f"no footprint position free in {MAX_TRIES} tries"})
            continue
        moved = vertices.copy()
        moved[:, :2] = rotate_xy(vertices[:, :2], where.yaw) + np.asarray(where.position)
        objects.append({**entry, "yaw": where.yaw, "position": [*where.position, 0.0]})
        parts.append((f"object_{draw.slot}_{source.names[draw.choice]}", moved, faces))
    components, v_at, f_at = [], 0, 0
    for name, vertices, faces in parts:
        components.append({"name": name, "vertices": [v_at, v_at + len(vertices)], "faces": [f_at, f_at + len(faces)]})
        v_at, f_at = v_at + len(vertices), f_at + len(faces)
    offsets = np.cumsum([0] + [len(v) for _, v, _ in parts[:-1]])
    vertices = np.vstack([v for _, v, _ in parts])
    faces = np.vstack([f + o for (_, _, f), o in zip(parts, offsets)])
    record = {"seed": int(seed), "index": int(index), "units": "room", **shell.record(), "drawn": len(draws),
              "objects": objects, "dropped": dropped, "components": components}
    return vertices, faces, record


def room_name(index: int) -> str:
    return f"room_{index:03d}"


def tiled_room(index: int, seed: int = 0, object_source: ObjectSource | None = None,
               tiles: int = 1) -> tuple[np.ndarray, np.ndarray, dict]:
    """A scene of ``tiles`` x ``tiles`` rooms side by side (room units): rooms ``index tiles^2 + t``
    (:func:`build_room`), room t's floor origin at ``(t // tiles, t % tiles)`` (each floor fits in
    the unit square, so floors touch at most). One tile: room ``index`` itself."""
    if tiles == 1:
        return build_room(index, seed, object_source)
    parts, records = [], []
    for t in range(tiles * tiles):
        vertices, faces, record = build_room(index * tiles * tiles + t, seed, object_source)
        origin = np.array([t // tiles, t % tiles, 0.0]) * FLOOR_SIDE
        parts.append((vertices + origin, faces))
        records.append({**record, "origin": origin.tolist()})
    offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
    vertices = np.vstack([v for v, _ in parts])
    faces = np.vstack([f + o for (_, f), o in zip(parts, offsets)])
    return vertices, faces, {"seed": int(seed), "index": int(index), "units": "room", "tiles": int(tiles),
                             "rooms": records}


def room_shape(index: int, seed: int = 0, object_source: ObjectSource | None = None, source: str = "",
               tiles: int = 1) -> Shape:
    """Room ``index`` (``tiles`` x ``tiles`` rooms: :func:`tiled_room`) as a canonical :class:`Shape`
    (kind 'nonmanifold'); ``meta['room']`` is the record of :func:`build_room` (room units;
    ``Shape.transform`` maps room units to canonical)."""
    vertices, faces, record = tiled_room(index, seed, object_source, tiles)
    name = room_name(index)
    shape = normalize_shape(name, vertices, faces, source=source or f"rooms:{name} seed={seed}", kind="nonmanifold")
    shape.meta.update(seed=int(seed), index=int(index), room=record)
    return shape


_ROOM_NAME = re.compile(r"^room_(\d{3,})$")


@register_dataset("rooms")
class RoomsDataset(Dataset):
    """Synthetic-Rooms-style scenes (module docstring). Options: ``count`` (default 10), ``seed``
    (default 0), ``tiles`` (default 1: a scene is ``tiles`` x ``tiles`` rooms side by side,
    :func:`tiled_room`), ``objects_dir`` (default None: built-in CAD parts; else a folder whose mesh files
    the objects are drawn from; ``data_dir``, the run's ``--data-dir``, is the same option). Shapes ``room_000``, ``room_001``, ...; room i does not depend on
    ``count``."""

    name = "rooms"
    up_axis = "z"

    def __init__(self, count: int = DEFAULT_COUNT, seed: int = 0, objects_dir=None, data_dir=None, tiles: int = 1):
        if objects_dir is None or str(objects_dir) == "":
            objects_dir = data_dir  # the run's --data-dir names the object folder
        self.count = as_int(count, "count", minimum=1)
        self.tiles = as_int(tiles, "tiles", minimum=1)
        self.seed = as_int(seed, "seed", minimum=0)
        self.objects_dir = objects_folder(objects_dir, self.name)
        self.source: ObjectSource = BuiltinParts() if self.objects_dir is None else MeshFiles(self.objects_dir)

    def names(self) -> list[str]:
        return [room_name(i) for i in range(self.count)]

    def _index(self, name: str) -> int:
        match = _ROOM_NAME.match(name)
        if match is None or int(match.group(1)) >= self.count or room_name(int(match.group(1))) != name:
            raise self._unknown_shape(name)
        return int(match.group(1))

    def load(self, name: str) -> Shape:
        index = self._index(name)
        where = f" objects_dir={self.objects_dir}" if self.objects_dir is not None else ""
        tiles = f" tiles={self.tiles}" if self.tiles > 1 else ""
        return room_shape(index, self.seed, self.source, source=f"rooms:{name} seed={self.seed}{tiles}{where}",
                          tiles=self.tiles)

    def stored_files(self, name: str) -> tuple[tuple[Path, str], ...]:
        index = self._index(name)
        if self.objects_dir is None:
            return ()
        n = self.tiles * self.tiles
        chosen = sorted({d.choice for t in range(n)
                         for d in room_layout(index * n + t, self.seed, len(self.source.names))[2]})
        return tuple((self.source.files[c], "mesh") for c in chosen)

    def options(self) -> dict[str, Any]:
        return {"count": self.count, "seed": self.seed, **({"tiles": self.tiles} if self.tiles > 1 else {}),
                "objects_dir": None if self.objects_dir is None else str(self.objects_dir)}
