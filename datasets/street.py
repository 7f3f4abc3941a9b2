"""The ``street`` dataset: street scenes scanned by a simulated rotating multi-beam LiDAR.

A street generated from a seed and what a car-mounted LiDAR driving along it sees. Metres, z up, the
street along +x from x = 0 to ``length``; one function per step:

1. :func:`draw_layout`: a road ``|y| <= 3.5`` with a sidewalk (0.15 m high, 2.5 m wide) on each
   side; beyond each a row of buildings with gaps (a box, a "stepped" pair of boxes whose second
   part is recessed and of another height, or a box with a gable roof prism); poles on the
   sidewalks; car-sized objects parked along both road edges. Each row is laid out along x, one
   item after the other with a gap, so nothing overlaps by construction (intervals: the constants).
2. :func:`street_mesh`: ground strips (open quads, normal +z: the road, and beyond the sidewalks out
   to ``|y| = 28``), closed sidewalk, building, roof and pole solids (outward normals) and the cars
   (built-in CAD parts or ``objects_dir`` meshes, scaled to the drawn car box). Planar faces are
   grids of cells at most ``edge`` x ``edge`` (two triangles each); gable ends and cars are
   subdivided until no edge is longer than ``edge`` (:data:`GT_EDGE` = 0.25 m).
3. :func:`lidar_scan`: the :class:`Lidar` (after the Velodyne HDL-32E) makes one revolution at
   each pose of :meth:`Lidar.poses`, its rays cast by :func:`foundation.scanner.cast_rays`; returns
   beyond the maximum range or more grazing than the dropout angle are lost; Gaussian range noise
   moves each point along its beam.
4. :func:`visible_faces`, the GT: the faces of the scene mesh the sensor could see. A face is
   visible when a ray of the scan hit it, or when its centroid ``c`` is seen from some pose ``s``:
   the first hit of the ray from ``s`` towards ``c`` (:func:`~foundation.scanner.cast_rays`, grazing
   hits dropped as in the scan) is on that face, ``|c - s|`` is at most the maximum range and the
   elevation of ``c - s`` lies within the beams' (lowest to highest beam).
5. :func:`build_street` (all in metres) and :func:`street_shape`: the visible faces as a canonical
   :class:`~datasets.io.Shape` (:func:`datasets.io.normalize_shape`; ``Shape.transform`` maps metres
   to canonical units), the noisy scan as ``points``, its sensor positions as ``sensors``, and
   ``meta['metres_per_unit']`` (1 / the transform's scale) to read canonical lengths in metres.

Randomness: the layout of street ``index`` is drawn from ``numpy.random.default_rng([seed, index])``
(buildings of side +y, then -y, poles, cars), the range noise from ``default_rng([seed, index,
NOISE_STREAM])``, the built-in part of car slot ``j`` from ``default_rng([seed, index, OBJECT_STREAM
+ j])`` (built-in shapes use streams 0-2, rooms 100-107). The same (seed, index, options) gives
bit-identical arrays; street ``index`` does not depend on ``count``.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from foundation.scanner import Scan, cast_rays
from datasets.builtin import TEMPLATE_NAMES, build_part, manifold_arrays
from datasets.io import Shape, classify_topology, normalize_shape
from datasets.registry import Dataset, as_int, register_dataset
from datasets.rooms import MeshFiles, objects_folder

#: Road half width (two 3.5 m lanes), sidewalk width and kerb height (m).
ROAD_HALF_WIDTH, SIDEWALK_WIDTH, KERB_HEIGHT = 3.5, 2.5, 0.15
#: The ground strips reach |y| = GROUND_HALF_WIDTH (past the deepest building).
GROUND_HALF_WIDTH = 28.0
#: Buildings, per side, along x: a gap, then a frontage, repeated; intervals of uniform draws (m).
BUILDING_GAP, FRONTAGE, MIN_FRONTAGE = (1.5, 6.0), (8.0, 20.0), 4.0
SETBACK, DEPTH, HEIGHT = (0.0, 3.0), (8.0, 14.0), (4.0, 16.0)
BUILDING_KINDS = ("box", "stepped", "gable")
#: Stepped building: split point (fraction of the frontage) and recess of the second part (m).
STEP_SPLIT, STEP_RECESS = (0.3, 0.7), (1.0, 3.0)
#: Gable roof: ridge height above the eaves (m); the ridge runs along x.
ROOF_RISE = (1.5, 4.0)
#: Poles: on the sidewalk, POLE_OFFSET from the kerb line; spacing, radius and height (m).
POLE_OFFSET, POLE_SPACING, POLE_RADIUS, POLE_HEIGHT, POLE_SEGMENTS = 0.6, (8.0, 15.0), (0.10, 0.15), (4.0, 8.0), 16
#: Cars: parked with their side CAR_KERB_GAP from the kerb; box length, width, height, gap (m).
CAR_KERB_GAP, CAR_LENGTH, CAR_WIDTH, CAR_HEIGHT, CAR_GAP = 0.3, (3.8, 4.8), (1.6, 1.9), (1.3, 1.7), (1.0, 8.0)
#: Longest cell side / edge of the scene mesh (m): the resolution of the visibility rule.
GT_EDGE = 0.25
#: Random streams (module docstring).
NOISE_STREAM, OBJECT_STREAM = 200, 300
DEFAULT_COUNT, DEFAULT_LENGTH, MIN_LENGTH = 3, 50, 10

Mesh = tuple[np.ndarray, np.ndarray]


# -- meshes ---------------------------------------------------------------------------------------


def grid_quad(origin, u, v, edge: float) -> Mesh:
    """The parallelogram ``origin + a u + b v``, (a, b) in [0, 1]^2, as ceil(|u| / edge) x
    ceil(|v| / edge) cells of two triangles, normal along ``u x v``."""
    origin, u, v = (np.asarray(x, dtype=np.float64) for x in (origin, u, v))
    nu, nv = (max(1, math.ceil(np.linalg.norm(w) / edge - 1e-9)) for w in (u, v))
    a, b = np.linspace(0.0, 1.0, nu + 1), np.linspace(0.0, 1.0, nv + 1)
    vertices = (origin + a[:, None, None] * u + b[None, :, None] * v).reshape(-1, 3)
    i, j = (x.ravel() for x in np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij"))
    v00 = i * (nv + 1) + j
    v10, v01 = v00 + nv + 1, v00 + 1
    faces = np.concatenate([np.stack([v00, v10, v10 + 1], 1), np.stack([v00, v10 + 1, v01], 1)])
    return vertices, faces


def concatenate(meshes: list[Mesh]) -> Mesh:
    """One mesh of several (vertex sets kept apart, nothing merged)."""
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes[:-1]])
    return np.vstack([v for v, _ in meshes]), np.vstack([f + o for (_, f), o in zip(meshes, offsets)])


def subdivided(vertices: np.ndarray, faces: np.ndarray, edge: float) -> Mesh:
    """trimesh's ``subdivide_to_size``: every edge longer than ``edge`` bisected (shared midpoints,
    the surface unchanged) until none is."""
    vertices, faces = trimesh.remesh.subdivide_to_size(vertices, faces, max_edge=float(edge), max_iter=40)
    return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)


def box_grid(lo, hi, edge: float) -> Mesh:
    """The closed box [lo, hi] (six :func:`grid_quad` faces, outward normals)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    dx, dy, dz = (x1 - x0, 0, 0), (0, y1 - y0, 0), (0, 0, z1 - z0)
    return concatenate([grid_quad((x0, y0, z0), dy, dx, edge), grid_quad((x0, y0, z1), dx, dy, edge),
                        grid_quad((x0, y0, z0), dx, dz, edge), grid_quad((x0, y1, z0), dz, dx, edge),
                        grid_quad((x0, y0, z0), dz, dy, edge), grid_quad((x1, y0, z0), dy, dz, edge)])


def gable_grid(lo, hi, rise: float, edge: float) -> Mesh:
    """The closed roof prism on the box top [lo, hi] x {z = hi_z}: ridge along x at the middle of
    the y side, ``rise`` above the base; outward normals."""
    (x0, y0, _), (x1, y1, z) = lo, hi
    half, dx = (y1 - y0) / 2, (x1 - x0, 0, 0)
    ridge = (y0 + half, z + rise)
    return concatenate([grid_quad((x0, y0, z), (0, y1 - y0, 0), dx, edge),
                        grid_quad((x0, y0, z), dx, (0, half, rise), edge),
                        grid_quad((x0, y1, z), (0, -half, rise), dx, edge),
                        subdivided(np.array([(x0, y0, z), (x0, *ridge), (x0, y1, z)]), np.array([[0, 1, 2]]), edge),
                        subdivided(np.array([(x1, y0, z), (x1, y1, z), (x1, *ridge)]), np.array([[0, 1, 2]]), edge)])


def cylinder_grid(x: float, y: float, z0: float, radius: float, height: float, edge: float,
                  segments: int = POLE_SEGMENTS) -> Mesh:
    """The closed cylinder (axis +z, base centre (x, y, z0)): a side of ``segments`` x
    ceil(height / edge) cells and two fans; outward normals."""
    rows = max(1, math.ceil(height / edge - 1e-9))
    angle = 2 * np.pi * np.arange(segments) / segments
    ring = np.column_stack([x + radius * np.cos(angle), y + radius * np.sin(angle)])
    z = np.linspace(z0, z0 + height, rows + 1)
    n, k, s = segments * (rows + 1), np.arange(segments * rows), np.arange(segments)
    vertices = np.vstack([np.column_stack([np.tile(ring, (rows + 1, 1)), np.repeat(z, segments)]),
                          [[x, y, z0], [x, y, z0 + height]]])
    a, b, top = k, k - k % segments + (k + 1) % segments, n - segments + s
    faces = np.concatenate([np.stack([a, b, b + segments], 1), np.stack([a, b + segments, a + segments], 1),
                            np.stack([np.full(segments, n), (s + 1) % segments, s], 1),
                            np.stack([np.full(segments, n + 1), top, top - s + (s + 1) % segments], 1)])
    return vertices, faces


# -- step 1: layout -------------------------------------------------------------------------------


def _uniform(u: float, interval: tuple[float, float]) -> float:
    return float(interval[0] + u * (interval[1] - interval[0]))


def draw_buildings(rng: np.random.Generator, length: float, side: int) -> list[dict]:
    """The buildings of one side (+1: y > 0), along x: gap U[BUILDING_GAP], frontage U[FRONTAGE]
    (cut at the street's end; below MIN_FRONTAGE the row ends), then the next. 8 draws each: kind,
    frontage, setback, depth, height, split, recess, second height or roof rise. Records in
    metres: ``boxes`` [lo, hi] (the side -1 ones mirrored in y), ``roof_rise`` (gable) or None."""
    buildings, x = [], _uniform(rng.random(), BUILDING_GAP)
    front = ROAD_HALF_WIDTH + SIDEWALK_WIDTH
    while True:
        u = rng.random(8)
        width = min(_uniform(u[1], FRONTAGE), length - x)
        if width < MIN_FRONTAGE:
            return buildings
        kind = BUILDING_KINDS[min(int(u[0] * len(BUILDING_KINDS)), len(BUILDING_KINDS) - 1)]
        y0 = front + _uniform(u[2], SETBACK)
        y1, height = y0 + _uniform(u[3], DEPTH), _uniform(u[4], HEIGHT)
        boxes, roof = [[[x, y0, 0.0], [x + width, y1, height]]], None
        if kind == "stepped":
            split = x + _uniform(u[5], STEP_SPLIT) * width
            boxes = [[[x, y0, 0.0], [split, y1, height]],
                     [[split, y0 + _uniform(u[6], STEP_RECESS), 0.0], [x + width, y1, _uniform(u[7], HEIGHT)]]]
        elif kind == "gable":
            roof = _uniform(u[7], ROOF_RISE)
        if side < 0:
            boxes = [[[lo[0], -hi[1], lo[2]], [hi[0], -lo[1], hi[2]]] for lo, hi in boxes]
        buildings.append({"side": side, "kind": kind, "x": [x, x + width], "boxes": boxes, "roof_rise": roof})
        x += width + _uniform(rng.random(), BUILDING_GAP)


def draw_poles(rng: np.random.Generator, length: float, side: int) -> list[dict]:
    """Poles of one side: at x = U[1, 8], then every U[POLE_SPACING] while x <= length - 1; each
    radius U[POLE_RADIUS], height U[POLE_HEIGHT], on the sidewalk top POLE_OFFSET from the kerb."""
    poles, x = [], _uniform(rng.random(), (1.0, POLE_SPACING[0]))
    while x <= length - 1.0:
        u = rng.random(3)
        poles.append({"side": side, "x": x, "y": side * (ROAD_HALF_WIDTH + POLE_OFFSET), "z0": KERB_HEIGHT,
                      "radius": _uniform(u[0], POLE_RADIUS), "height": _uniform(u[1], POLE_HEIGHT)})
        x += _uniform(u[2], POLE_SPACING)
    return poles


def draw_cars(rng: np.random.Generator, length: float, side: int, n_choices: int, first_slot: int) -> list[dict]:
    """Cars of one side: the first starts at x = U[0, 8], then each box [x, x + l] x (width w,
    CAR_KERB_GAP from the kerb) x [0, h] followed by a gap U[CAR_GAP], while the box ends by the
    street's end. Per car: its mesh (uniform among ``n_choices``) and 4 uniforms (l, w, h, gap)."""
    cars, x = [], _uniform(rng.random(), (0.0, 8.0))
    while True:
        choice, u = int(rng.integers(n_choices)), rng.random(4)
        size = [_uniform(u[0], CAR_LENGTH), _uniform(u[1], CAR_WIDTH), _uniform(u[2], CAR_HEIGHT)]
        if x + size[0] > length:
            return cars
        y = side * (ROAD_HALF_WIDTH - CAR_KERB_GAP - size[1] / 2)
        cars.append({"slot": first_slot + len(cars), "side": side, "choice": choice, "size": size,
                     "centre": [x + size[0] / 2, y, 0.0]})
        x += size[0] + _uniform(u[3], CAR_GAP)


def draw_layout(index: int, seed: int, length: float, n_choices: int) -> dict:
    """Step 1: buildings (+y side, then -y), poles, cars from ``default_rng([seed, index])``."""
    rng = np.random.default_rng([int(seed), int(index)])
    buildings = draw_buildings(rng, length, 1) + draw_buildings(rng, length, -1)
    poles = draw_poles(rng, length, 1) + draw_poles(rng, length, -1)
    cars = draw_cars(rng, length, 1, n_choices, 0)
    return {"buildings": buildings, "poles": poles, "cars": cars + draw_cars(rng, length, -1, n_choices, len(cars))}


# -- where cars come from -------------------------------------------------------------------------


def _box_map(vertices: np.ndarray, size) -> tuple[list[float], list[float]]:
    """(shift, scale) taking the bounding box of ``vertices`` to [-l/2, l/2] x [-w/2, w/2] x [0, h]
    as (v + shift) * scale (its lowest vertex exactly to z = 0)."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    shift = [-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]]
    return shift, [float(s) for s in np.asarray(size, dtype=np.float64) / (hi - lo)]


class BuiltinCars:
    """Car meshes from the built-in CAD parts. A car source has ``names`` (one per mesh a draw can
    pick), ``mesh(choice, seed, index, slot, size, edge)`` (the mesh scaled per axis to the box
    [-l/2, l/2] x [-w/2, w/2] x [0, h], ``size`` = (l, w, h) m, no edge longer than ``edge``) and
    ``describe(...)`` (its source, one line). Here slot ``slot`` is ``build_part(template, seed,
    index, OBJECT_STREAM + slot)``, scaled, manifold3d's ``refine_to_length(edge)`` (edges split
    evenly: few faces), then :func:`subdivided` (the bound on every edge)."""

    names = TEMPLATE_NAMES

    def mesh(self, choice: int, seed: int, index: int, slot: int, size, edge: float) -> Mesh:
        part = build_part(self.names[choice], seed, index, OBJECT_STREAM + slot)
        shift, scale = _box_map(manifold_arrays(part)[0], size)
        return subdivided(*manifold_arrays(part.translate(shift).scale(scale).refine_to_length(float(edge))), edge)

    def describe(self, choice: int, seed: int, index: int, slot: int) -> str:
        return f"builtin:{self.names[choice]} rng=[{seed}, {index}, {OBJECT_STREAM + slot}]"


class CarFiles:
    """Car meshes (:class:`BuiltinCars`) from the mesh files of a folder
    (:class:`datasets.rooms.MeshFiles`), z up as stored, scaled to the car box, then :func:`subdivided`."""

    def __init__(self, folder: Path):
        self.files_source = MeshFiles(folder)
        self.files, self.names = self.files_source.files, self.files_source.names

    def mesh(self, choice: int, seed: int, index: int, slot: int, size, edge: float) -> Mesh:
        vertices, faces = self.files_source.mesh(choice, seed, index, slot)
        shift, scale = _box_map(vertices, size)
        return subdivided((vertices + shift) * np.asarray(scale), faces, edge)

    def describe(self, choice: int, seed: int, index: int, slot: int) -> str:
        return str(self.files[choice])


# -- step 2: the scene mesh -----------------------------------------------------------------------


def street_mesh(layout: dict, length: float, source: BuiltinCars | CarFiles, seed: int, index: int,
                edge: float = GT_EDGE) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """Step 2: the scene in metres: (vertices, faces, components: name and face range [start, stop)).
    Order: ground strips (road, +y, -y), sidewalks (+y, -y), buildings, poles, cars."""
    inner, outer, dx = ROAD_HALF_WIDTH, ROAD_HALF_WIDTH + SIDEWALK_WIDTH, (length, 0.0, 0.0)
    parts = [("ground_road", grid_quad((0.0, -inner, 0.0), dx, (0.0, 2 * inner, 0.0), edge)),
             ("ground_+y", grid_quad((0.0, outer, 0.0), dx, (0.0, GROUND_HALF_WIDTH - outer, 0.0), edge)),
             ("ground_-y", grid_quad((0.0, -GROUND_HALF_WIDTH, 0.0), dx, (0.0, GROUND_HALF_WIDTH - outer, 0.0), edge)),
             ("sidewalk_+y", box_grid((0.0, inner, 0.0), (length, outer, KERB_HEIGHT), edge)),
             ("sidewalk_-y", box_grid((0.0, -outer, 0.0), (length, -inner, KERB_HEIGHT), edge))]
    for k, b in enumerate(layout["buildings"]):
        solids = [box_grid(lo, hi, edge) for lo, hi in b["boxes"]]
        if b["roof_rise"] is not None:
            solids.append(gable_grid(*b["boxes"][0], b["roof_rise"], edge))
        parts.append((f"building_{k}_{b['kind']}", concatenate(solids)))
    parts += [(f"pole_{k}", cylinder_grid(p["x"], p["y"], p["z0"], p["radius"], p["height"], edge))
              for k, p in enumerate(layout["poles"])]
    for car in layout["cars"]:
        vertices, faces = source.mesh(car["choice"], seed, index, car["slot"], car["size"], edge)
        parts.append((f"car_{car['slot']}_{source.names[car['choice']]}", (vertices + car["centre"], faces)))
    stops = np.cumsum([len(f) for _, (_, f) in parts])
    components = [{"name": name, "faces": [int(stop - len(f)), int(stop)]}
                  for (name, (_, f)), stop in zip(parts, stops)]
    vertices, faces = concatenate([mesh for _, mesh in parts])
    return vertices, faces, components


# -- step 3: the sensor ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Lidar:
    """A rotating multi-beam LiDAR after the Velodyne HDL-32E: ``beams`` lasers at elevations evenly
    spread over ``fov_deg`` (HDL-32E: 32 over +10.67 .. -30.67 deg, 1.33 deg apart), ``azimuths``
    firings per revolution (1080: 1/3 deg, as the HDL-32E at 20 Hz), returns up to ``max_range`` m,
    range noise N(0, ``range_sigma``) m along the beam, mounted ``mount_height`` m above the road on
    the centreline, one static revolution every ``pose_spacing`` m (no motion during a revolution);
    returns whose beam makes more than ``grazing_dropout_deg`` with the face normal are lost."""

    beams: int = 32
    azimuths: int = 1080
    fov_deg: tuple[float, float] = (-30.67, 10.67)
    max_range: float = 80.0
    range_sigma: float = 0.02
    mount_height: float = 1.8
    pose_spacing: float = 5.0
    grazing_dropout_deg: float = 88.0

    def elevations(self) -> np.ndarray:
        """(beams,) beam elevations (radians, lowest first)."""
        return np.radians(np.linspace(self.fov_deg[0], self.fov_deg[1], self.beams))

    def directions(self) -> np.ndarray:
        """(azimuths * beams, 3) unit beam directions of one revolution, azimuth ``2 pi k / azimuths``
        (from +x, counter-clockwise) major: row ``k * beams + b``."""
        azimuth = (2 * np.pi * np.arange(self.azimuths) / self.azimuths)[:, None]
        elevation = self.elevations()[None, :]
        xyz = np.broadcast_arrays(np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                                  np.sin(elevation))
        return np.stack(xyz, axis=-1).reshape(-1, 3)

    def poses(self, length: float) -> np.ndarray:
        """(n, 3) sensor positions: n = max(1, floor(length / pose_spacing)) at x = (k + 1/2) length / n,
        y = 0, z = mount_height."""
        n = max(1, math.floor(length / self.pose_spacing + 1e-9))
        x = (np.arange(n) + 0.5) * (length / n)
        return np.column_stack([x, np.zeros(n), np.full(n, self.mount_height)])


def lidar_scan(vertices: np.ndarray, faces: np.ndarray, poses: np.ndarray, lidar: Lidar,
               rng: np.random.Generator) -> tuple[Scan, np.ndarray]:
    """Step 3: (clean scan, noisy points (P, 3)), rows alike. One revolution per pose, cast with
    :func:`~foundation.scanner.cast_rays` (``sensor_ids``: the ray's row, pose ``row // (azimuths x
    beams)``); hits farther than ``max_range`` dropped; then P standard normals ``z`` from ``rng`` and
    the point moved ``range_sigma z`` along its beam; a point whose noisy range exceeds ``max_range``
    is dropped (with its clean row)."""
    beams = lidar.directions()
    origins = np.repeat(np.asarray(poses, dtype=np.float64), len(beams), axis=0)
    directions = np.tile(beams, (len(poses), 1))
    scan = cast_rays(vertices, faces, origins, directions, lidar.grazing_dropout_deg)
    scan = scan.subset(np.linalg.norm(scan.points - scan.sensors, axis=1) <= lidar.max_range)
    shift = lidar.range_sigma * rng.standard_normal(len(scan))
    noisy = scan.points + shift[:, None] * directions[scan.sensor_ids]
    keep = np.linalg.norm(noisy - scan.sensors, axis=1) <= lidar.max_range
    return scan.subset(keep), noisy[keep]


# -- step 4: what the sensor could see ------------------------------------------------------------


def visible_faces(vertices: np.ndarray, faces: np.ndarray, poses: np.ndarray, lidar: Lidar,
                  hit_faces: np.ndarray | None = None, batch: int = 2 ** 21) -> np.ndarray:
    """Step 4: (F,) bool, the faces of the visibility rule (module docstring): ``hit_faces`` (the
    scan's face ids), or centroid seen from a pose within range and the vertical field of view.
    Poses are taken in order, their lines of sight cast about ``batch`` at a time; a face already
    found visible is not cast again (which changes the cost, not the result)."""
    vertices, faces = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    centroid = vertices[faces].mean(axis=1)
    low, high = np.sin(lidar.elevations()[[0, -1]])
    visible = np.zeros(len(faces), dtype=bool)
    if hit_faces is not None:
        visible[np.asarray(hit_faces, dtype=np.int64)] = True
    poses = np.asarray(poses, dtype=np.float64)
    rows, origins = [], []
    for k, pose in enumerate(poses):
        sight = centroid - pose
        distance = np.linalg.norm(sight, axis=1)
        sine = sight[:, 2] / np.maximum(distance, 1e-300)
        rows.append(np.flatnonzero(~visible & (distance > 0) & (distance <= lidar.max_range)
                                   & (sine >= low) & (sine <= high)))
        origins.append(np.broadcast_to(pose, (len(rows[-1]), 3)))
        if sum(len(r) for r in rows) >= batch or k == len(poses) - 1:
            target, origin = np.concatenate(rows), np.concatenate(origins)
            rows, origins = [], []
            if len(target):
                scan = cast_rays(vertices, faces, origin, centroid[target] - origin, lidar.grazing_dropout_deg)
                visible[scan.face_ids[scan.face_ids == target[scan.sensor_ids]]] = True
    return visible


# -- step 5: the street ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class StreetScene:
    """A street in metres: the scene mesh (``vertices``, ``faces``), the GT mask ``visible`` (F,),
    the clean ``scan`` and the ``points`` (noisy, rows of ``scan``), the sensor ``poses`` and the
    JSON record."""

    vertices: np.ndarray
    faces: np.ndarray
    visible: np.ndarray
    scan: Scan
    points: np.ndarray
    poses: np.ndarray
    record: dict

    def gt_mesh(self) -> Mesh:
        """The visible faces with only the vertices they use (metres; face order kept)."""
        kept = self.faces[self.visible]
        used, inverse = np.unique(kept, return_inverse=True)
        return self.vertices[used], inverse.reshape(kept.shape)


def build_street(index: int, seed: int = 0, length: float = DEFAULT_LENGTH, lidar: Lidar | None = None,
                 source: BuiltinCars | CarFiles | None = None, edge: float = GT_EDGE) -> StreetScene:
    """Street ``index`` at ``seed`` in metres (steps 1-4). The record (plain JSON) holds the layout
    (buildings, poles, cars: slot, side, source, box size, centre), the sensor model, the poses,
    the components (name, face range, visible faces) and counts (rays, points, faces, GT area)."""
    lidar, source = lidar or Lidar(), source or BuiltinCars()
    layout = draw_layout(index, seed, length, len(source.names))
    vertices, faces, components = street_mesh(layout, length, source, seed, index, edge)
    poses = lidar.poses(length)
    noise = np.random.default_rng([int(seed), int(index), NOISE_STREAM])
    scan, points = lidar_scan(vertices, faces, poses, lidar, noise)
    visible = visible_faces(vertices, faces, poses, lidar, scan.face_ids)
    for c in components:
        c["visible_faces"] = int(visible[c["faces"][0]:c["faces"][1]].sum())
    for car in layout["cars"]:
        car["source"] = source.describe(car["choice"], seed, index, car["slot"])
    tri = vertices[faces[visible]]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    record = {"seed": int(seed), "index": int(index), "units": "metres", "length": float(length),
              "edge": float(edge), "road_half_width": ROAD_HALF_WIDTH, "sidewalk_width": SIDEWALK_WIDTH,
              "kerb_height": KERB_HEIGHT, "ground_half_width": GROUND_HALF_WIDTH, **layout,
              "lidar": {**asdict(lidar), "fov_deg": list(lidar.fov_deg)}, "poses": poses.tolist(),
              "components": components, "rays": len(poses) * lidar.beams * lidar.azimuths, "points": len(points),
              "scene_faces": len(faces), "gt_faces": int(visible.sum()), "gt_area_m2": float(area)}
    return StreetScene(vertices, faces, visible, scan, points, poses, record)


def street_name(index: int) -> str:
    return f"street_{index:03d}"


def street_shape(scene: StreetScene, name: str, source: str = "") -> Shape:
    """The street as a canonical :class:`Shape`: the visible faces (kind by
    :func:`datasets.io.classify_topology`), ``points``/``sensors`` the noisy scan and its sensor
    positions moved with the same transform (``Shape.transform`` maps metres to canonical units);
    ``meta['metres_per_unit']`` = 1 / transform scale, ``meta['street']`` the record."""
    vertices, faces = scene.gt_mesh()
    shape = normalize_shape(name, vertices, faces, source=source or name, kind=classify_topology(faces))
    shape.points = shape.transform.apply(scene.points)
    shape.sensors = shape.transform.apply(scene.scan.sensors)
    shape.meta.update(seed=scene.record["seed"], index=scene.record["index"],
                      metres_per_unit=1.0 / shape.transform.scale, street=scene.record)
    return shape


_STREET_NAME = re.compile(r"^street_(\d{3,})$")


@register_dataset("street")
class StreetDataset(Dataset):
    """Street scenes scanned by a LiDAR (module docstring), for ``--task reconstruct``. Options:
    ``count`` (3), ``seed`` (0), ``length`` (m, 50), ``beams`` (32), ``azimuths`` (firings per
    revolution, 1080: 1/3 deg), ``objects_dir`` (None: built-in CAD parts as cars; else a folder of
    mesh files; ``data_dir``, the run's ``--data-dir``, is the same option). Shapes ``street_000``, ..."""

    name = "street"
    point_clouds = True
    up_axis = "z"

    def __init__(self, count: int = DEFAULT_COUNT, seed: int = 0, length: int = DEFAULT_LENGTH, beams: int = 32,
                 azimuths: int = 1080, objects_dir=None, data_dir=None):
        if objects_dir is None or str(objects_dir) == "":
            objects_dir = data_dir
        self.count = as_int(count, "count", minimum=1)
        self.seed = as_int(seed, "seed", minimum=0)
        self.length = as_int(length, "length", minimum=MIN_LENGTH)
        self.lidar = Lidar(beams=as_int(beams, "beams", minimum=2), azimuths=as_int(azimuths, "azimuths", minimum=4))
        self.objects_dir = objects_folder(objects_dir, self.name)
        self.source: BuiltinCars | CarFiles = BuiltinCars() if self.objects_dir is None else CarFiles(self.objects_dir)

    def names(self) -> list[str]:
        return [street_name(i) for i in range(self.count)]

    def _index(self, name: str) -> int:
        match = _STREET_NAME.match(name)
        if match is None or int(match.group(1)) >= self.count or street_name(int(match.group(1))) != name:
            raise self._unknown_shape(name)
        return int(match.group(1))

    def scene(self, name: str) -> StreetScene:
        """The street in metres: the whole scene mesh, the GT mask, the clean and noisy scan."""
        return build_street(self._index(name), self.seed, self.length, self.lidar, self.source)

    def load(self, name: str) -> Shape:
        where = f" objects_dir={self.objects_dir}" if self.objects_dir is not None else ""
        return street_shape(self.scene(name), name, f"street:{name} seed={self.seed} length={self.length} "
                                                    f"beams={self.lidar.beams} azimuths={self.lidar.azimuths}{where}")

    def stored_files(self, name: str) -> tuple[tuple[Path, str], ...]:
        index = self._index(name)
        if self.objects_dir is None:
            return ()
        cars = draw_layout(index, self.seed, self.length, len(self.source.names))["cars"]
        chosen = sorted({car["choice"] for car in cars})
        return tuple((self.source.files[c], "mesh") for c in chosen)

    def options(self) -> dict[str, Any]:
        return {"count": self.count, "seed": self.seed, "length": self.length, "beams": self.lidar.beams,
                "azimuths": self.lidar.azimuths,
                "objects_dir": None if self.objects_dir is None else str(self.objects_dir)}
