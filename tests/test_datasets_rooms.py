"""datasets/rooms.py: Synthetic-Rooms-style scenes (floor, walls, objects on the floor)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.spatial import ConvexHull

from datasets import DatasetError, DatasetNotFoundError, available_datasets, get_dataset
from datasets.rooms import (
    FLOOR_THICKNESS,
    MIN_GAP,
    SIZE_GROUPS,
    WALL_NAMES,
    WALL_THICKNESS,
    box_mesh,
    build_room,
    place_objects,
    room_shape,
)


class ToyParts:
    """A cheap object source for checking many layouts: boxes of several aspects and a tetrahedron
    (any frame: the room scales and moves them)."""

    names = ("cube", "slab", "pole", "tetra")

    def mesh(self, choice, seed, index, slot):
        if choice == 3:
            vertices = np.array([[0, 0, 0], [3, 0, 0], [0, 2, 0], [0, 0, 1.0]])
            return vertices, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
        return box_mesh((5, 5, 5), [(6, 6, 6), (9, 7, 5.5), (5.2, 5.3, 7)][choice])

    def describe(self, choice, seed, index, slot):
        return f"toy:{self.names[choice]}"


def component(vertices, record, name):
    (start, stop), = [c["vertices"] for c in record["components"] if c["name"] == name]
    return vertices[start:stop]


def overlap_depth(a_xy, b_xy) -> float:
    """Largest t such that some point is at depth >= t inside both convex hulls (an LP on the hulls'
    half-planes, independent of the placement code): < 0 exactly when the hulls are disjoint."""
    rows = np.vstack([ConvexHull(a_xy).equations, ConvexHull(b_xy).equations])  # n.p + off <= 0 inside, |n| = 1
    a_ub = np.column_stack([rows[:, :2], np.ones(len(rows))])
    res = linprog([0, 0, -1], A_ub=a_ub, b_ub=-rows[:, 2], bounds=[(None, None), (None, None), (-1, 1)])
    assert res.status == 0
    return float(res.x[2])


def hull_distance(a_xy, b_xy) -> float:
    """Distance between two disjoint convex hulls: the least distance from a vertex of one to an edge
    of the other."""
    def vertex_to_edges(points, polygon):
        start = polygon
        edge = np.roll(polygon, -1, axis=0) - start
        t = np.einsum("pek,ek->pe", points[:, None] - start, edge) / np.einsum("ek,ek->e", edge, edge)
        nearest = start + np.clip(t, 0, 1)[..., None] * edge
        return np.linalg.norm(points[:, None] - nearest, axis=-1).min()

    a, b = a_xy[ConvexHull(a_xy).vertices], b_xy[ConvexHull(b_xy).vertices]
    return min(vertex_to_edges(a, b), vertex_to_edges(b, a))


def assert_disjoint(a_xy, b_xy):
    assert overlap_depth(a_xy, b_xy) < 0 and hull_distance(a_xy, b_xy) >= MIN_GAP - 1e-12


def check_room(vertices, faces, record):
    """Every constraint of the room contract, in room units, from the arrays and the record."""
    sx, sy = record["floor_size"]
    assert sorted([sx, sy])[1] == 1.0 and 0.3 <= min(sx, sy) <= 1.0
    floor = component(vertices, record, "floor")
    assert np.array_equal(floor.min(0), [0, 0, -FLOOR_THICKNESS]) and np.array_equal(floor.max(0), [sx, sy, 0])
    # walls: each recorded present or absent; a present one stands on the floor top along its edge
    assert [w["side"] for w in record["walls"]] == list(WALL_NAMES)
    names = [c["name"] for c in record["components"]]
    for wall in record["walls"]:
        assert 0.2 <= wall["height"] <= 0.4
        assert (f"wall_{wall['side']}" in names) == wall["present"]
        if wall["present"]:
            box = component(vertices, record, f"wall_{wall['side']}")
            assert box.min(0)[2] == 0.0 and box.max(0)[2] == wall["height"]
            axis, at = "xy".index(wall["side"][0]), int(wall["side"][1]) * (sx, sy)["xy".index(wall["side"][0])]
            assert np.isclose(np.ptp(box[:, axis]), WALL_THICKNESS) and at in (box[:, axis].min(), box[:, axis].max())
    # objects: 4-8 drawn, each placed or recorded as dropped
    placed, dropped = record["objects"], record["dropped"]
    assert 4 <= record["drawn"] <= 8 and len(placed) + len(dropped) == record["drawn"]
    assert sorted(o["slot"] for o in placed + dropped) == list(range(record["drawn"]))
    hulls = []
    for obj in placed:
        lo, hi = obj["group_interval"]
        assert tuple(obj["group_interval"]) == SIZE_GROUPS[obj["group"]] and lo <= obj["max_extent"] <= hi
        points = component(vertices, record, f"object_{obj['slot']}_{obj['name']}")
        assert points[:, 2].min() == 0.0  # exactly on the floor top
        xy = points[:, :2]
        assert np.all(xy >= WALL_THICKNESS - 1e-12) and np.all(xy <= np.array([sx, sy]) - WALL_THICKNESS + 1e-12)
        c, s = np.cos(-obj["yaw"]), np.sin(-obj["yaw"])  # undo the yaw: the object's own box
        own = (xy - obj["position"][:2]) @ np.array([[c, s], [-s, c]])
        extent = max(np.ptp(own, axis=0).max(), np.ptp(points[:, 2]))
        assert extent == pytest.approx(obj["max_extent"], rel=1e-9)
        hulls.append(xy)
    for i in range(len(hulls)):
        for j in range(i):
            assert_disjoint(hulls[i], hulls[j])
    last = record["components"][-1]
    assert len(faces) == last["faces"][1] and len(vertices) == last["vertices"][1]


@pytest.fixture(scope="module")
def rooms():
    """Rooms 0-4 of seed 0 with built-in CAD parts, in room units."""
    return [build_room(i, 0) for i in range(5)]


def test_registered_with_defaults():
    ds = get_dataset("rooms")
    assert "rooms" in available_datasets()
    assert ds.names() == [f"room_{i:03d}" for i in range(10)]
    assert ds.options() == {"count": 10, "seed": 0, "objects_dir": None}
    assert ds.stored_files("room_000") == ()


def test_same_seed_same_arrays_count_does_not_change_a_room_other_seed_differs():
    a = get_dataset("rooms", count=4, seed=0).load("room_003")
    b = get_dataset("rooms", count=10, seed=0).load("room_003")
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    assert a.content_hash == b.content_hash and a.meta == b.meta
    again, _, record = build_room(3, 0)
    assert np.array_equal(again, build_room(3, 0)[0]) and record == a.meta["room"]
    other = get_dataset("rooms", count=4, seed=1).load("room_003")
    assert other.content_hash != a.content_hash and other.meta["room"]["floor_size"] != record["floor_size"]


def test_rooms_of_builtin_parts_meet_the_contract(rooms):
    for vertices, faces, record in rooms:
        check_room(vertices, faces, record)
        assert all(o["source"].startswith("builtin:") for o in record["objects"])
    placed = sum(len(r["objects"]) for _, _, r in rooms)
    assert placed >= 0.7 * sum(r["drawn"] for _, _, r in rooms)  # drops are the exception


def test_many_layouts_meet_the_contract():
    records = []
    for index in range(40):
        vertices, faces, record = build_room(index, 5, ToyParts())
        check_room(vertices, faces, record)
        records.append(record)
    walls = np.array([[w["present"] for w in r["walls"]] for r in records])
    assert 0.3 < walls.mean() < 0.7  # each wall present with probability 0.5
    assert {r["drawn"] for r in records} == {4, 5, 6, 7, 8}
    assert {o["group"] for r in records for o in r["objects"]} == {0, 1, 2}


def test_place_objects_drops_what_cannot_fit_and_draws_a_fixed_amount():
    square = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    small = place_objects([0.05 * square, 0.05 * square], (1.0, 0.3), rng_a)
    huge = place_objects([0.05 * square, 0.2 * square], (1.0, 0.3), rng_b)  # 0.4 wide: no yaw fits in 0.28
    assert all(p is not None for p in small) and huge[0] is not None and huge[1] is None
    assert rng_a.random() == rng_b.random()  # the same number of draws whatever happened
    assert_disjoint(small[0].footprint, small[1].footprint)


def test_shape_is_canonical_nonmanifold_with_a_json_record(rooms):
    shape = room_shape(0, 0)
    vertices, faces, record = rooms[0]
    lo, hi = shape.vertices.min(0), shape.vertices.max(0)
    assert np.abs(lo + hi).max() < 1e-12 and np.ptp(shape.vertices, axis=0).max() == pytest.approx(1.99, abs=1e-12)
    assert shape.kind == "nonmanifold" and shape.name == "room_000"
    assert np.array_equal(shape.faces, faces) and np.array_equal(shape.vertices, shape.transform.apply(vertices))
    assert json.loads(json.dumps(shape.meta)) == shape.meta and shape.meta["room"] == record


def test_objects_dir_uses_those_meshes(tmp_path):
    (tmp_path / "tetra.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    box_v, box_f = box_mesh((0, 0, 0), (2, 1, 1))
    (tmp_path / "box.obj").write_text("".join(f"v {x} {y} {z}\n" for x, y, z in box_v)
                                      + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in box_f))
    ds = get_dataset("rooms", count=3, seed=2, objects_dir=tmp_path)
    sizes = {"tetra.obj": (4, 4), "box.obj": (8, 12)}
    used = set()
    for name in ds.names():
        shape = ds.load(name)
        record = shape.meta["room"]
        walls = sum(w["present"] for w in record["walls"])
        objects = [sizes[o["name"]] for o in record["objects"]]
        assert len(shape.vertices) == 8 + 8 * walls + sum(v for v, _ in objects)
        assert len(shape.faces) == 12 + 12 * walls + sum(f for _, f in objects)
        check_room(*build_room(int(name[5:]), 2, ds.source))  # the same room in room units
        drawn = {o["name"] for o in record["objects"] + record["dropped"]}
        files = ds.stored_files(name)
        assert {p.name for p, _ in files} == drawn and all(kind == "mesh" for _, kind in files)
        used |= drawn
    assert used == set(sizes)
    assert ds.options()["objects_dir"] == str(tmp_path)


def test_bad_options_are_one_line_errors(tmp_path):
    cases = [({"count": -1}, "option 'count' must be >= 1, got -1"),
             ({"count": "ten"}, "option 'count' needs an integer"),
             ({"seed": -2}, "option 'seed' must be >= 0"), ({"objects_dir": tmp_path / "absent"}, "objects_dir"),
             ({"objects_dir": tmp_path}, "no mesh files"), ({"data_dir": tmp_path}, "no mesh files"),
             ({"list_file": tmp_path}, "has no option 'list_file'")]
    for options, expected in cases:
        with pytest.raises(DatasetError) as info:
            get_dataset("rooms", **options)
        assert expected in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(DatasetNotFoundError, match="absent"):
        get_dataset("rooms", objects_dir=tmp_path / "absent")
    with pytest.raises(DatasetError, match="has no shape 'room_010'"):
        get_dataset("rooms").load("room_010")


def test_tiles_put_rooms_side_by_side():
    """tiles=2: rooms 4i .. 4i+3 moved to the unit squares of a 2 x 2 grid; one tile is room i."""
    from datasets.rooms import tiled_room

    V, F, record = tiled_room(1, 0, ToyParts(), tiles=2)
    rooms = [build_room(4 + t, 0, ToyParts()) for t in range(4)]
    assert len(F) == sum(len(f) for _, f, _ in rooms) and record["tiles"] == 2
    start = 0
    for t, (v, _, _) in enumerate(rooms):
        np.testing.assert_array_equal(V[start:start + len(v)], v + [t // 2, t % 2, 0])
        start += len(v)
    assert V[:, :2].min() >= 0 and V[:, :2].max() <= 2
    one = tiled_room(3, 0, ToyParts(), tiles=1)
    np.testing.assert_array_equal(one[0], build_room(3, 0, ToyParts())[0])
    ds = get_dataset("rooms", count=2, tiles=2)
    assert ds.options()["tiles"] == 2 and ds.load("room_000").meta["room"]["tiles"] == 2
