"""The built-in CAD-like shapes: the default dataset, generated on the fly.

Each part is a boolean combination of boxes, cylinders, cones, wedges (extruded polygons), chamfers
(45-degree diamond prisms subtracted along an edge), holes, slots and thin walls, built with
manifold3d. Like ABC models they have flat faces, sharp edges and thin parts. Each part is moved
to the canonical frame and refined by manifold's ``refine_to_length(REFINE_LENGTH)`` (edges at most
0.2 long, so 2.5k-16k faces a part, flat faces stay exactly flat). Everything is deterministic: the
dimensions of shape ``i`` are drawn from ``numpy.random.default_rng([seed, i, part])``, so the same
seed gives bit-identical arrays (see :func:`foundation.storage.mesh_hash`) and shape ``i`` does not depend
on ``count``.

Variants (``Shape.kind``):

* ``closed``: the part itself, a watertight, consistently oriented triangle mesh (manifold3d
  output is indexed; nothing is merged afterwards).
* ``open``: the part with its largest planar region removed (all coplanar faces of the plane of
  largest area), so it has a boundary.
* ``nonmanifold``: two parts as one triangle soup: part B is scaled, rotated and shifted until it
  pierces part A (checked with booleans: A and B each have >= 5% of their volume inside and outside the other),
  and the two triangle sets are concatenated without a boolean union, so the surfaces intersect.

Shape ``i`` uses template ``TEMPLATE_NAMES[i % 10]`` (a non-manifold shape adds the next template as
part B) and its kind comes from cycling ``closed, closed, open, nonmanifold`` restricted to the
requested variants. The default dataset is 4 shapes: 2 closed, 1 open, 1 non-manifold.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable
from typing import Any

import numpy as np
from manifold3d import CrossSection, Manifold

from datasets.io import MeshError, Shape, canonical_transform, normalize_shape
from datasets.registry import Dataset, DatasetError, as_int, register_dataset

#: Variants in the order of the default cycle (2 closed : 1 open : 1 non-manifold).
VARIANT_CYCLE = ("closed", "closed", "open", "nonmanifold")
VARIANTS = ("closed", "open", "nonmanifold")
DEFAULT_COUNT = 4

#: Segments of a full circle for large / small round features.
SEGMENTS, SMALL_SEGMENTS = 96, 48
#: Longest edge after refinement, canonical units (about 10% of the largest side): 2.5k-15k faces.
REFINE_LENGTH = 0.2


# -- primitives (units: millimetre-like, parts are ~40-120 across before normalisation) ---------


def box(size, at=(0.0, 0.0, 0.0)) -> Manifold:
    """Axis-aligned box with lower corner ``at`` and side lengths ``size``."""
    return Manifold.cube([float(s) for s in size]).translate([float(a) for a in at])


def cylinder(radius, height, at=(0.0, 0.0, 0.0), axis: str = "z", radius_top=None, segments: int = SEGMENTS) -> Manifold:
    """Cylinder (or cone when ``radius_top`` differs) with base centre ``at``, extending ``height``
    along +axis."""
    top = radius if radius_top is None else radius_top
    part = Manifold.cylinder(float(height), float(radius), float(top), int(segments))
    return part.transform(_axis_frame(axis, at))


def prism(polygon, length, axis: str = "z", at=(0.0, 0.0, 0.0)) -> Manifold:
    """A polygon extruded ``length`` along +axis: ``polygon`` is in the plane of the two other
    axes in cyclic order ((x, y) for axis z, (y, z) for x, (z, x) for y), offset by ``at``."""
    polygon = np.asarray(polygon, dtype=np.float64)
    x, y = polygon[:, 0], polygon[:, 1]
    if np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0:  # manifold fills counter-clockwise loops
        polygon = polygon[::-1]
    section = CrossSection([polygon.tolist()])
    return Manifold.extrude(section, float(length)).transform(_axis_frame(axis, at))


def chamfer_cut(start, end, size: float) -> Manifold:
    """The solid to subtract to chamfer the axis-aligned edge ``start``-``end`` by ``size`` (a
    diamond prism |du| + |dv| <= size around the edge, so each face loses a strip of width size)."""
    start, end = np.asarray(start, dtype=np.float64), np.asarray(end, dtype=np.float64)
    axis = int(np.flatnonzero(np.abs(end - start) > 0)[0])
    length = float(abs(end[axis] - start[axis])) + 2.0 * size
    diamond = [(-size, 0.0), (0.0, -size), (size, 0.0), (0.0, size)]
    at = start.copy()
    at[axis] = min(start[axis], end[axis]) - size
    return prism(diamond, length, "xyz"[axis], at)


def _axis_frame(axis: str, at) -> list[list[float]]:
    """3x4 affine map taking local (u, v, w) to the frame where w runs along ``axis`` (a cyclic
    permutation of the coordinates, so orientation is kept) and translating by ``at``."""
    rows = {"z": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "x": [[0, 0, 1], [1, 0, 0], [0, 1, 0]],
            "y": [[0, 1, 0], [0, 0, 1], [1, 0, 0]]}[axis]
    return [[float(r[0]), float(r[1]), float(r[2]), float(a)] for r, a in zip(rows, at)]


def union(*parts: Manifold) -> Manifold:
    return Manifold.batch_boolean(list(parts), _op("Add"))


def subtract(base: Manifold, *cuts: Manifold) -> Manifold:
    return base - Manifold.batch_boolean(list(cuts), _op("Add")) if cuts else base


def _op(name: str):
    from manifold3d import OpType

    return getattr(OpType, name)


# -- the templates --------------------------------------------------------------------------------


def bracket(rng: np.random.Generator) -> Manifold:
    """L-shaped angle bracket: base and upright plates, a wedge gusset, countersunk holes in the
    base, two holes through the upright, chamfered edges."""
    W, D, H, T = rng.uniform(60, 90), rng.uniform(40, 60), rng.uniform(40, 70), rng.uniform(6, 10)
    g = rng.uniform(0.4, 0.6) * min(D, H)
    r = rng.uniform(3, 4.5)
    solid = union(
        box((W, D, T)),
        box((W, T, H)),
        prism([(T - 0.5, T - 0.5), (T + g, T - 0.5), (T - 0.5, T + g)], 0.8 * T, "x", (W / 2 - 0.4 * T, 0, 0)),
    )
    cuts = []
    for x in (0.2 * W, 0.8 * W):
        cuts.append(cylinder(r, T + 2, (x, 0.65 * D, -1), segments=SMALL_SEGMENTS))
        cuts.append(cylinder(r, 1.6 * r, (x, 0.65 * D, T - 0.6 * r), radius_top=2.2 * r, segments=SMALL_SEGMENTS))
        cuts.append(cylinder(r, T + 2, (x, -1, 0.65 * H), axis="y", segments=SMALL_SEGMENTS))
    cuts.append(chamfer_cut((0, D, T), (W, D, T), 0.4 * T))
    cuts.append(chamfer_cut((0, 0, H), (W, 0, H), 0.4 * T))
    cuts.append(chamfer_cut((0, T, H), (W, T, H), 0.3 * T))
    return subtract(solid, *cuts)


def flange(rng: np.random.Generator) -> Manifold:
    """Round flange: disc with a bolt circle, a hub with a chamfered top, a bore with a keyway and
    two flats milled on the disc rim."""
    R, t = rng.uniform(40, 50), rng.uniform(6, 10)
    r_hub, h_hub = R * rng.uniform(0.45, 0.55), rng.uniform(15, 25)
    r_bore, n_bolts, r_bolt = r_hub * rng.uniform(0.5, 0.65), int(rng.integers(4, 9)), rng.uniform(2.5, 4)
    c = 0.15 * r_hub
    solid = union(
        cylinder(R, t, (0, 0, 0)),
        cylinder(r_hub, t + h_hub - c, (0, 0, 0)),
        cylinder(r_hub, c, (0, 0, t + h_hub - c), radius_top=r_hub - c),
    )
    angles = 2 * np.pi * np.arange(n_bolts) / n_bolts + np.pi / n_bolts
    ring = 0.5 * (R + r_hub)
    cuts = [cylinder(r_bolt, t + 2, (ring * np.cos(a), ring * np.sin(a), -1), segments=SMALL_SEGMENTS) for a in angles]
    cuts.append(cylinder(r_bore, t + h_hub + 2, (0, 0, -1)))
    cuts.append(box((0.5 * r_bore, 2 * r_bore * 0.35, t + h_hub + 2), (r_bore * 0.8, -0.35 * r_bore, -1)))
    flat = R * rng.uniform(0.85, 0.92)
    cuts.append(box((R, 2 * R + 2, t + 2), (flat, -R - 1, -1)))
    cuts.append(box((R, 2 * R + 2, t + 2), (-flat - R, -R - 1, -1)))
    return subtract(solid, *cuts)


def housing(rng: np.random.Generator) -> Manifold:
    """Open-top box with thin walls, chamfered vertical corners, mounting lugs with holes and a round
    window in one wall."""
    L, W, H, tw = rng.uniform(70, 100), rng.uniform(45, 65), rng.uniform(30, 45), rng.uniform(2.0, 3.5)
    lug, r = rng.uniform(10, 14), rng.uniform(2.5, 3.5)
    solid = union(box((L, W, H)), box((lug + 1, W * 0.4, 0.25 * H), (-lug, 0.3 * W, 0)),
                  box((lug + 1, W * 0.4, 0.25 * H), (L - 1, 0.3 * W, 0)))
    cuts = [box((L - 2 * tw, W - 2 * tw, H), (tw, tw, tw))]
    for x, y in ((0, 0), (L, 0), (0, W), (L, W)):
        cuts.append(chamfer_cut((x, y, -1), (x, y, H + 1), 0.5 * tw + 1.0))
    cuts.append(cylinder(r, 0.25 * H + 2, (-lug / 2, W / 2, -1), segments=SMALL_SEGMENTS))
    cuts.append(cylinder(r, 0.25 * H + 2, (L + lug / 2, W / 2, -1), segments=SMALL_SEGMENTS))
    cuts.append(cylinder(0.25 * H, tw + 2, (L * rng.uniform(0.3, 0.7), -1, 0.55 * H), axis="y"))
    return subtract(solid, *cuts)


def slotted_block(rng: np.random.Generator) -> Manifold:
    """Block with a rounded through slot, a rectangular pocket, a milled step and chamfered top edges."""
    L, W, H = rng.uniform(70, 100), rng.uniform(35, 50), rng.uniform(25, 40)
    rs = rng.uniform(0.12, 0.18) * W
    slot = Manifold.batch_hull([cylinder(rs, H + 2, (0.25 * L, W / 2, -1)), cylinder(rs, H + 2, (0.5 * L, W / 2, -1))])
    pocket = box((0.2 * L, 0.6 * W, 0.5 * H), (0.68 * L, 0.2 * W, 0.5 * H + 0.01 * H))
    step = box((0.3 * L, W + 2, 0.35 * H), (-1, -1, 0.65 * H + 0.01 * H))
    c = 0.12 * H
    edges = [chamfer_cut((0.3 * L, 0, H), (L, 0, H), c), chamfer_cut((0.3 * L, W, H), (L, W, H), c),
             chamfer_cut((L, 0, 0), (L, 0, H), c), chamfer_cut((L, W, 0), (L, W, H), c)]
    return subtract(box((L, W, H)), slot, pocket, step, *edges)


def pipe_tee(rng: np.random.Generator) -> Manifold:
    """Thin-walled pipe tee with flanges on its three ends."""
    R, L = rng.uniform(12, 16), rng.uniform(80, 110)
    Rb, Hb = R * rng.uniform(0.7, 0.9), rng.uniform(35, 50)
    t = R * rng.uniform(0.15, 0.22)
    fl, ft = 1.35, rng.uniform(3, 5)
    solid = union(
        cylinder(R, L, (0, 0, 0), axis="x"),
        cylinder(Rb, Hb, (L / 2, 0, 0)),
        cylinder(R * fl, ft, (0, 0, 0), axis="x"),
        cylinder(R * fl, ft, (L - ft, 0, 0), axis="x"),
        cylinder(Rb * fl, ft, (L / 2, 0, Hb - ft)),
    )
    return subtract(solid, cylinder(R - t, L + 2, (-1, 0, 0), axis="x"), cylinder(Rb - t, Hb + 1, (L / 2, 0, 0)))


def stepped_shaft(rng: np.random.Generator) -> Manifold:
    """Turned shaft: three diameters, chamfered ends (cones), a keyway, a cross hole and a centre hole."""
    r1, r2, r3 = rng.uniform(14, 18), rng.uniform(10, 12), rng.uniform(6, 8)
    l1, l2, l3 = rng.uniform(15, 25), rng.uniform(30, 45), rng.uniform(20, 30)
    c = 1.5
    solid = union(
        cylinder(r1 - c, c, (0, 0, 0), radius_top=r1),
        cylinder(r1, l1 - c, (0, 0, c)),
        cylinder(r2, l2, (0, 0, l1)),
        cylinder(r3, l3 - c, (0, 0, l1 + l2)),
        cylinder(r3, c, (0, 0, l1 + l2 + l3 - c), radius_top=r3 - c),
    )
    key = box((0.5 * r2, 0.5 * r2, 0.6 * l2), (r2 - 0.3 * r2, -0.25 * r2, l1 + 0.2 * l2))
    cross = cylinder(0.35 * r3, 2 * r3 + 2, (-r3 - 1, 0, l1 + l2 + 0.5 * l3), axis="x", segments=SMALL_SEGMENTS)
    centre = cylinder(0.3 * r1, 0.6 * l1, (0, 0, -1), segments=SMALL_SEGMENTS)
    return subtract(solid, key, cross, centre)


def wedge_block(rng: np.random.Generator) -> Manifold:
    """Wedge (sloped-top extrusion) with a V-groove underneath, a notch and a vertical hole."""
    L, W = rng.uniform(70, 100), rng.uniform(35, 50)
    h_low, h_high = rng.uniform(10, 16), rng.uniform(30, 45)
    profile = [(0, 0), (L, 0), (L, h_low), (0, h_high)]  # in (z, x) plane: (z, x) pairs below
    wedge = prism([(z, x) for x, z in profile], W, "y")
    v = 0.25 * h_low
    groove = chamfer_cut((0.55 * L, -1, 0), (0.55 * L, W + 1, 0), 2 * v)
    notch = box((0.15 * L, 0.4 * W, h_high), (L - 0.15 * L + 0.01, 0.3 * W, -1))
    hole = cylinder(rng.uniform(4, 6), h_high + 2, (0.25 * L, W / 2, -1))
    return subtract(wedge, groove, notch, hole)


def heat_sink(rng: np.random.Generator) -> Manifold:
    """Base plate with thin parallel fins (thin parts) and two mounting holes."""
    L, W, tb = rng.uniform(70, 90), rng.uniform(40, 55), rng.uniform(4, 6)
    n, tf, hf = int(rng.integers(6, 10)), rng.uniform(1.0, 1.8), rng.uniform(20, 30)
    margin = 0.15 * L
    xs = margin + (L - 2 * margin - tf) * np.arange(n) / (n - 1)
    fins = [box((tf, W, hf), (x, 0, tb - 0.01)) for x in xs]
    solid = union(box((L, W, tb)), *fins)
    holes = [cylinder(2.5, tb + 2, (margin / 2, W / 2, -1), segments=SMALL_SEGMENTS),
             cylinder(2.5, tb + 2, (L - margin / 2, W / 2, -1), segments=SMALL_SEGMENTS)]
    return subtract(solid, *holes, chamfer_cut((0, 0, tb), (L, 0, tb), 1.0), chamfer_cut((0, W, tb), (L, W, tb), 1.0))


def gear(rng: np.random.Generator) -> Manifold:
    """Spur-gear-like extrusion: trapezoidal teeth, a hub, a bore with a keyway."""
    n, R, depth, t = int(rng.integers(14, 22)), rng.uniform(35, 45), rng.uniform(4, 6), rng.uniform(8, 12)
    r_root = R - depth
    k = np.arange(n)[:, None]
    # per tooth: root, flank up, flank down, root (fractions of the tooth pitch)
    frac = np.array([0.0, 0.3, 0.5, 0.8])
    radius = np.array([r_root, R, R, r_root])
    angle = 2 * np.pi * (k + frac[None, :]) / n
    outline = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=-1).reshape(-1, 2)
    body = prism(outline, t)
    hub = cylinder(0.35 * R, 0.6 * t, (0, 0, t - 0.01))
    bore = cylinder(0.2 * R, 3 * t, (0, 0, -1))
    key = box((0.08 * R, 0.1 * R, 3 * t), (0.17 * R, -0.05 * R, -1))
    lightening = [cylinder(0.12 * R, t + 2, (0.62 * R * np.cos(a), 0.62 * R * np.sin(a), -1), segments=SMALL_SEGMENTS)
                  for a in 2 * np.pi * np.arange(4) / 4 + np.pi / 4]
    return subtract(union(body, hub), bore, key, *lightening)


def u_channel(rng: np.random.Generator) -> Manifold:
    """U-profile extrusion (thin flanges) with holes in the web and the flanges and an end notch."""
    L, W, H, t = rng.uniform(80, 110), rng.uniform(30, 40), rng.uniform(20, 30), rng.uniform(2.5, 4)
    profile = [(0, 0), (W, 0), (W, H), (W - t, H), (W - t, t), (t, t), (t, H), (0, H)]
    channel = prism(profile, L, "x")
    cuts = [cylinder(rng.uniform(3, 4), t + 2, (x, W / 2, -1), segments=SMALL_SEGMENTS) for x in (0.2 * L, 0.5 * L, 0.8 * L)]
    cuts += [cylinder(2.5, W + 2, (x, -1, 0.6 * H), axis="y", segments=SMALL_SEGMENTS) for x in (0.35 * L, 0.65 * L)]
    cuts.append(box((0.1 * L, W + 2, 0.5 * H), (L - 0.1 * L + 0.01, -1, 0.5 * H + 0.01)))
    return subtract(channel, *cuts)


#: Template name -> function(rng) -> Manifold, in the order shapes cycle through them.
TEMPLATES: dict[str, Callable[[np.random.Generator], Manifold]] = {
    "bracket": bracket,
    "flange": flange,
    "housing": housing,
    "slotted_block": slotted_block,
    "pipe_tee": pipe_tee,
    "stepped_shaft": stepped_shaft,
    "wedge_block": wedge_block,
    "heat_sink": heat_sink,
    "gear": gear,
    "u_channel": u_channel,
}
TEMPLATE_NAMES = tuple(TEMPLATES)


# -- arrays and variants -------------------------------------------------------------------------


def manifold_arrays(part: Manifold) -> tuple[np.ndarray, np.ndarray]:
    """Indexed float64 vertices (n, 3) and int64 faces (m, 3) of a manifold (no merging needed)."""
    mesh = part.to_mesh64()
    return np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3].copy(), np.asarray(mesh.tri_verts, dtype=np.int64)


def build_part(template: str, seed: int, index: int, stream: int = 0) -> Manifold:
    """The solid of ``template`` with dimensions drawn from ``default_rng([seed, index, stream])``."""
    if template not in TEMPLATES:
        raise DatasetError(f"unknown builtin template '{template}'; known: {', '.join(TEMPLATE_NAMES)}")
    part = TEMPLATES[template](np.random.default_rng([seed, index, stream]))
    if part.is_empty() or part.num_tri() == 0:
        raise MeshError(f"builtin {template} (seed {seed}, index {index}): boolean result is empty")
    return part


def largest_planar_region(vertices: np.ndarray, faces: np.ndarray, decimals: int = 6) -> np.ndarray:
    """Boolean mask of the faces lying in the plane of largest total area.

    Planes are keyed by the unit normal n and offset d = n . centroid, rounded to ``decimals``
    (coordinates in the canonical frame); ties go to the first key in lexicographic order."""
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    normal = cross / np.maximum(double_area, 1e-300)[:, None]
    offset = np.einsum("ij,ij->i", normal, tri.mean(axis=1))
    key = np.round(np.column_stack([normal, offset]), decimals) + 0.0  # +0.0 folds -0.0 into 0.0
    _, plane = np.unique(key, axis=0, return_inverse=True)
    plane = plane.reshape(-1)
    area = np.bincount(plane, weights=double_area)
    return plane == int(np.argmax(area))


def remove_faces(vertices: np.ndarray, faces: np.ndarray, drop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Delete the faces marked in ``drop`` and the vertices no face uses any more (order kept)."""
    kept = faces[~drop]
    used = np.unique(kept)
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[kept]


def _random_rotation(rng: np.random.Generator, min_deg: float, max_deg: float) -> np.ndarray:
    """Rotation by an angle in [min_deg, max_deg] about a random unit axis (Rodrigues)."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = np.radians(rng.uniform(min_deg, max_deg))
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def canonical_part(part: Manifold, refine_length: float | None = None) -> Manifold:
    """The part moved to the canonical frame and, when ``refine_length`` is given,
    refined so that no edge is longer than it (flat faces stay flat: new vertices lie on the
    original triangles)."""
    vertices, _ = manifold_arrays(part)
    transform = canonical_transform(vertices)
    moved = part.translate([-c for c in transform.centre]).scale([transform.scale] * 3)
    return moved.refine_to_length(float(refine_length)) if refine_length else moved


def piercing_transform(part_a: Manifold, part_b: Manifold, rng: np.random.Generator, attempts: int = 32) -> list[list[float]]:
    """3x4 affine map for part B (both parts in the canonical frame): scale 0.55-0.85, rotation by
    20-70 degrees about a random axis, shift up to 0.25 per axis, re-drawn until each solid has at
    least 5% of its volume inside and 5% outside the other (so the two surfaces cross)."""
    vol_a = part_a.volume()
    for _ in range(attempts):
        matrix = rng.uniform(0.55, 0.85) * _random_rotation(rng, 20, 70)
        affine = np.column_stack([matrix, rng.uniform(-0.25, 0.25, size=3)]).tolist()
        moved = part_b.transform(affine)
        common, vol_b = (part_a ^ moved).volume(), moved.volume()
        if min(common, vol_a - common) > 0.05 * vol_a and min(common, vol_b - common) > 0.05 * vol_b:
            return affine
    raise MeshError("builtin non-manifold variant: no piercing placement found")  # pragma: no cover


def generate_shape(index: int, kind: str = "closed", seed: int = 0) -> Shape:
    """Built-in shape number ``index`` of the given variant, in the canonical frame.

    A shape is a function of its arguments (:func:`build_shape`): each is built once per process
    (the last :data:`GENERATED_KEPT` kept) and every call returns its own copy."""
    return copy.deepcopy(_kept_shape(int(index), kind, int(seed)))


#: Built-in shapes a process keeps after building them (:func:`generate_shape`).
GENERATED_KEPT = 64


@functools.lru_cache(maxsize=GENERATED_KEPT)
def _kept_shape(index: int, kind: str, seed: int) -> Shape:
    return build_shape(index, kind, seed)


def build_shape(index: int, kind: str = "closed", seed: int = 0) -> Shape:
    """:func:`generate_shape` without the per-process copy: builds the shape each call."""
    if kind not in VARIANTS:
        raise DatasetError(f"unknown builtin variant '{kind}'; known: {', '.join(VARIANTS)}")
    template = TEMPLATE_NAMES[index % len(TEMPLATE_NAMES)]
    meta: dict[str, Any] = {"template": template, "seed": seed, "index": index}
    if kind == "nonmanifold":
        other = TEMPLATE_NAMES[(index + 1) % len(TEMPLATE_NAMES)]
        part_a = canonical_part(build_part(template, seed, index, 0))
        part_b = canonical_part(build_part(other, seed, index, 1))
        affine = piercing_transform(part_a, part_b, np.random.default_rng([seed, index, 2]))
        part_a = part_a.refine_to_length(REFINE_LENGTH)
        part_b = part_b.refine_to_length(REFINE_LENGTH).transform(affine)
        va, fa = manifold_arrays(part_a)
        vb, fb = manifold_arrays(part_b)
        vertices, faces = np.vstack([va, vb]), np.vstack([fa, fb + len(va)])
        meta.update(parts=[template, other], part_faces=[len(fa), len(fb)])
        name = f"builtin_{index:03d}_{template}+{other}_nonmanifold"
    else:
        vertices, faces = manifold_arrays(canonical_part(build_part(template, seed, index, 0), REFINE_LENGTH))
        name = f"builtin_{index:03d}_{template}"
        if kind == "open":
            drop = largest_planar_region(vertices, faces)
            vertices, faces = remove_faces(vertices, faces, drop)
            meta["removed_faces"] = int(drop.sum())
            name += "_open"
    shape = normalize_shape(name, vertices, faces, source=f"builtin:{name} seed={seed}", kind=kind)
    shape.meta.update(meta)
    return shape


def builtin_names(count: int = DEFAULT_COUNT, variants=VARIANTS) -> list[tuple[str, int, str]]:
    """(name, index, kind) of the first ``count`` shapes for the given variants (no generation)."""
    cycle = [v for v in VARIANT_CYCLE if v in variants]
    rows = []
    for index in range(count):
        kind = cycle[index % len(cycle)]
        a = TEMPLATE_NAMES[index % len(TEMPLATE_NAMES)]
        if kind == "nonmanifold":
            b = TEMPLATE_NAMES[(index + 1) % len(TEMPLATE_NAMES)]
            name = f"builtin_{index:03d}_{a}+{b}_nonmanifold"
        else:
            name = f"builtin_{index:03d}_{a}" + ("_open" if kind == "open" else "")
        rows.append((name, index, kind))
    return rows


def parse_variants(variants) -> tuple[str, ...]:
    """'all' / 'closed' / 'closed,open' / a list -> a tuple of variant names (one-line error else)."""
    if variants is None or variants == "all":
        return VARIANTS
    if isinstance(variants, str):
        variants = [v.strip() for v in variants.split(",") if v.strip()]
    chosen = tuple(v for v in VARIANTS if v in set(variants))
    unknown = sorted(set(variants) - set(VARIANTS) - {"all"})
    if unknown or not chosen:
        raise DatasetError(f"builtin variants must be 'all' or among {', '.join(VARIANTS)}; got {variants!r}")
    return VARIANTS if "all" in variants else chosen


@register_dataset("builtin")
class BuiltinDataset(Dataset):
    """Generated CAD-like shapes (no download). Options: ``count`` (default 4), ``seed`` (default 0),
    ``variants`` ('all' (default), 'closed', 'open', 'nonmanifold', or a comma list / list).
    With all variants the kinds cycle closed, closed, open, nonmanifold."""

    name = "builtin"

    def __init__(self, count: int = DEFAULT_COUNT, seed: int = 0, variants="all"):
        self.count = as_int(count, "count", minimum=1)
        self.seed = as_int(seed, "seed", minimum=0)
        self.variants = parse_variants(variants)
        self._rows = {name: (index, kind) for name, index, kind in builtin_names(self.count, self.variants)}

    def names(self) -> list[str]:
        return list(self._rows)

    def load(self, name: str) -> Shape:
        if name not in self._rows:
            raise self._unknown_shape(name)
        index, kind = self._rows[name]
        return generate_shape(index, kind, self.seed)

    def options(self) -> dict[str, Any]:
        return {"count": self.count, "seed": self.seed, "variants": list(self.variants)}
