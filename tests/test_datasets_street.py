"""datasets/street.py: street scenes scanned by a rotating multi-beam LiDAR (and scanner.cast_rays)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from foundation.scanner import cast_rays
from datasets import DatasetError, DatasetNotFoundError, available_datasets, get_dataset
from datasets.street import (
    CAR_GAP,
    CAR_HEIGHT,
    CAR_KERB_GAP,
    CAR_LENGTH,
    CAR_WIDTH,
    DEPTH,
    FRONTAGE,
    GT_EDGE,
    HEIGHT,
    KERB_HEIGHT,
    MIN_FRONTAGE,
    POLE_HEIGHT,
    POLE_RADIUS,
    ROAD_HALF_WIDTH,
    SETBACK,
    SIDEWALK_WIDTH,
    STEP_RECESS,
    Lidar,
    box_grid,
    build_street,
    concatenate,
    cylinder_grid,
    draw_layout,
    gable_grid,
    grid_quad,
    lidar_scan,
    visible_faces,
)

SMALL = Lidar(beams=16, azimuths=360)


@pytest.fixture(scope="module")
def street():
    """A 20 m street (seed 0, index 0) scanned by a coarse 16-beam sensor, in metres."""
    return build_street(0, 0, 20.0, SMALL)


def component(scene, prefix):
    """Face rows of the components whose name starts with ``prefix``."""
    ranges = [c["faces"] for c in scene.record["components"] if c["name"].startswith(prefix)]
    return np.concatenate([np.arange(a, b) for a, b in ranges])


def triangle_areas(vertices, faces):
    tri = vertices[faces]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def segment_hits_box(start, ends, lo, hi):
    """(n,) bool: the segments start -> ends[i] meet the closed box [lo, hi] (slab test, no ray caster)."""
    d = ends - start
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - start) / d, (hi - start) / d
    near = np.where(d == 0, np.where((start >= lo) & (start <= hi), -np.inf, np.inf), np.minimum(t0, t1))
    far = np.where(d == 0, np.where((start >= lo) & (start <= hi), np.inf, -np.inf), np.maximum(t0, t1))
    enter, leave = np.max(np.maximum(near, 0.0), axis=1), np.min(np.minimum(far, 1.0), axis=1)
    return enter <= leave


# -- scanner.cast_rays ----------------------------------------------------------------------------


def test_cast_rays_hits_a_box_where_geometry_says():
    vertices, faces = box_grid((0, 0, 0), (1, 1, 1), 0.5)
    origins = np.array([[-2.0, 0.3, 0.6], [-2.0, 0.3, 0.6], [0.4, 0.6, 3.0], [-2.0, 5.0, 0.5]])
    directions = np.array([[4.0, 0.0, 0.0], [1.0, 0.0, 1.0], [0.0, 0.0, -0.1], [1.0, 0.0, 0.0]])  # any length
    scan = cast_rays(vertices, faces, origins, directions)
    assert scan.sensor_ids.tolist() == [0, 2]  # ray 1 passes over the box, ray 3 beside it
    assert np.allclose(scan.points, [[0.0, 0.3, 0.6], [0.4, 0.6, 1.0]], atol=1e-12, rtol=0)
    assert np.array_equal(scan.sensors, origins[[0, 2]]) and np.allclose(scan.ray_cosines, 1.0)
    assert np.allclose(vertices[faces[scan.face_ids]][:, :, 0][0], 0.0)  # the x = 0 face
    origin, direction = [[-0.5, 0.4, 1.008]], [[1.0, 0.0, -0.01]]  # meets the top at x = 0.3, 89.4 deg
    grazing = cast_rays(vertices, faces, origin, direction, grazing_dropout_deg=85.0)
    kept = cast_rays(vertices, faces, origin, direction, grazing_dropout_deg=None)
    assert len(grazing) == 0 and len(kept) == 1
    assert np.allclose(kept.points, [[0.3, 0.4, 1.0]], atol=1e-12, rtol=0)


# -- the visibility rule on a hand-built street ---------------------------------------------------


def test_visibility_on_a_two_box_street():
    """Sensor at (0, 0, 1.8); box A [5, 7] x [-1, 1] x [0, 2.5] in front of box B [10, 12] x [-1, 1] x
    [0, 2]: B lies wholly in A's shadow, A shows only its -x face, the ground its unshadowed part."""
    edge = 0.25
    box_a, box_b = ((5.0, -1.0, 0.0), (7.0, 1.0, 2.5)), ((10.0, -1.0, 0.0), (12.0, 1.0, 2.0))
    ground = grid_quad((-10.0, -10.0, 0.0), (40.0, 0.0, 0.0), (0.0, 20.0, 0.0), edge)
    vertices, faces = concatenate([ground, box_grid(*box_a, edge), box_grid(*box_b, edge)])
    n_ground, n_box = len(ground[1]), (len(faces) - len(ground[1])) // 2
    a_rows, b_rows = np.arange(n_ground, n_ground + n_box), np.arange(n_ground + n_box, len(faces))
    pose = np.array([[0.0, 0.0, 1.8]])
    lidar = Lidar(beams=32, azimuths=720)
    scan, _ = lidar_scan(vertices, faces, pose, lidar, np.random.default_rng(0))
    visible = visible_faces(vertices, faces, pose, lidar, scan.face_ids)
    # the far box: no point, no GT face
    assert not np.isin(scan.face_ids, b_rows).any() and not visible[b_rows].any()
    # the near box: points only on its -x face, and that whole face (2 x 2.5 m, inside the FOV) is GT
    on_a = np.isin(scan.face_ids, a_rows)
    assert on_a.sum() > 100 and np.all(np.abs(scan.points[on_a, 0] - 5.0) < 1e-9)
    front = a_rows[np.all(vertices[faces[a_rows]][:, :, 0] == 5.0, axis=1)]
    assert np.array_equal(np.flatnonzero(visible[a_rows]) + n_ground, front)
    assert triangle_areas(vertices, faces[front]).sum() == pytest.approx(5.0, abs=1e-9)
    # the ground: a cell is GT when hit, or when its centroid is out of both boxes' shadow and within
    # the vertical field of view (range < 80 m and incidence < 88 deg hold for the whole quad)
    centroid = vertices[faces[:n_ground]].mean(axis=1)
    sight = centroid - pose[0]
    elevation = np.degrees(np.arcsin(sight[:, 2] / np.linalg.norm(sight, axis=1)))
    in_fov = (elevation >= -30.67) & (elevation <= 10.67)
    pad = np.array([1e-6, 1e-6, 1e-6])
    hidden_wide = segment_hits_box(pose[0], centroid, np.subtract(box_a[0], pad), np.add(box_a[1], pad)) | \
        segment_hits_box(pose[0], centroid, np.subtract(box_b[0], pad), np.add(box_b[1], pad))
    hidden_tight = segment_hits_box(pose[0], centroid, np.add(box_a[0], pad), np.subtract(box_a[1], pad)) | \
        segment_hits_box(pose[0], centroid, np.add(box_b[0], pad), np.subtract(box_b[1], pad))
    sure = hidden_wide == hidden_tight  # lines of sight farther than 1e-6 from every box edge
    assert sure.mean() > 0.99
    hit = np.zeros(n_ground, dtype=bool)
    hit[scan.face_ids[scan.face_ids < n_ground]] = True
    expected = hit | (in_fov & ~hidden_wide)
    assert np.array_equal(visible[:n_ground][sure], expected[sure])
    assert (~in_fov & ~hit).sum() > 100 and (in_fov & hidden_wide).sum() > 100  # both rules at work


# -- the scan --------------------------------------------------------------------------------------


def test_clean_points_lie_on_the_face_they_hit(street):
    scan = street.scan
    tri = street.vertices[street.faces[scan.face_ids]]
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    normal = np.cross(e1, e2)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    assert np.abs(np.einsum("ij,ij->i", scan.points - a, normal)).max() < 1e-9  # metres
    q = scan.points - a
    gram = np.stack([np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e1, e2), np.einsum("ij,ij->i", e2, e2)])
    rhs = np.stack([np.einsum("ij,ij->i", q, e1), np.einsum("ij,ij->i", q, e2)])
    den = gram[0] * gram[2] - gram[1] ** 2
    beta, gamma = (gram[2] * rhs[0] - gram[1] * rhs[1]) / den, (gram[0] * rhs[1] - gram[1] * rhs[0]) / den
    assert min(beta.min(), gamma.min(), (1 - beta - gamma).min()) > -1e-9
    assert street.visible[scan.face_ids].all()  # every point lies on the GT


def test_range_noise_is_along_the_beam_with_the_stated_sigma(street):
    scan, lidar = street.scan, SMALL
    beam = np.tile(lidar.directions(), (len(street.poses), 1))[scan.sensor_ids]
    pose = scan.sensor_ids // (lidar.beams * lidar.azimuths)
    assert np.array_equal(scan.sensors, street.poses[pose])
    moved = street.points - scan.points
    along = np.einsum("ij,ij->i", moved, beam)
    assert np.abs(moved - along[:, None] * beam).max() < 1e-12
    assert len(along) > 5000 and lidar.range_sigma == 0.02
    assert abs(along.mean()) < 4 * 0.02 / np.sqrt(len(along))
    assert np.std(along) == pytest.approx(0.02, rel=0.05)


def test_no_point_beyond_max_range_and_the_gt_respects_it(street):
    for points in (street.points, street.scan.points):
        assert np.linalg.norm(points - street.scan.sensors, axis=1).max() <= SMALL.max_range
    near = Lidar(beams=16, azimuths=360, max_range=12.0)
    scan, points = lidar_scan(street.vertices, street.faces, street.poses, near, np.random.default_rng(1))
    ranges = np.linalg.norm(points - scan.sensors, axis=1)
    assert ranges.max() <= 12.0 and np.linalg.norm(street.scan.points - street.scan.sensors, axis=1).max() > 15.0
    visible = visible_faces(street.vertices, street.faces, street.poses, near, scan.face_ids)
    centroid = street.vertices[street.faces[visible]].mean(axis=1)
    nearest = np.linalg.norm(centroid[:, None] - street.poses[None], axis=2).min(axis=1)
    hit = np.isin(np.flatnonzero(visible), scan.face_ids)
    assert np.all(hit | (nearest <= 12.0)) and nearest.max() <= 12.0 + GT_EDGE


# -- the generator ---------------------------------------------------------------------------------


def check_layout(layout, length):
    """The generator's constraints, from the record alone (metres)."""
    kerb, outer = ROAD_HALF_WIDTH, ROAD_HALF_WIDTH + SIDEWALK_WIDTH
    for side in (1, -1):
        rows = [b for b in layout["buildings"] if b["side"] == side]
        for b in rows:
            x0, x1 = b["x"]
            assert 0 <= x0 and x1 <= length and MIN_FRONTAGE <= x1 - x0 <= FRONTAGE[1]
            for lo, hi in b["boxes"]:
                assert x0 <= lo[0] < hi[0] <= x1 and lo[2] == 0 and HEIGHT[0] <= hi[2] <= HEIGHT[1]
                near_y = lo[1] if side > 0 else -hi[1]
                assert side * lo[1] > 0 and side * hi[1] > 0 and near_y >= outer + SETBACK[0] - 1e-12
                assert DEPTH[0] - STEP_RECESS[1] <= hi[1] - lo[1] <= DEPTH[1]
        for b, c in zip(rows, rows[1:]):
            assert c["x"][0] - b["x"][1] >= 1.5  # the gap between neighbours
        cars = [c for c in layout["cars"] if c["side"] == side]
        for c in cars:
            (long, w, h), (x, y, z) = c["size"], c["centre"]
            assert CAR_LENGTH[0] <= long <= CAR_LENGTH[1] and CAR_WIDTH[0] <= w <= CAR_WIDTH[1]
            assert CAR_HEIGHT[0] <= h <= CAR_HEIGHT[1] and z == 0.0 and 0 <= x - long / 2 and x + long / 2 <= length
            assert abs(y) + w / 2 == pytest.approx(kerb - CAR_KERB_GAP) and abs(y) - w / 2 > 0.5  # on the road
        for c, d in zip(cars, cars[1:]):
            assert d["centre"][0] - d["size"][0] / 2 - (c["centre"][0] + c["size"][0] / 2) >= CAR_GAP[0] - 1e-12
    for p in layout["poles"]:
        assert kerb < abs(p["y"]) - p["radius"] and abs(p["y"]) + p["radius"] < outer and p["z0"] == KERB_HEIGHT
        assert POLE_RADIUS[0] <= p["radius"] <= POLE_RADIUS[1] and POLE_HEIGHT[0] <= p["height"] <= POLE_HEIGHT[1]


def test_layouts_meet_the_generator_constraints():
    kinds = set()
    for length in (25.0, 50.0, 100.0):
        for index in range(12):
            layout = draw_layout(index, 7, length, 10)
            check_layout(layout, length)
            kinds |= {b["kind"] for b in layout["buildings"]}
            assert layout["cars"] and layout["poles"] and layout["buildings"]
    assert kinds == {"box", "stepped", "gable"}


def test_scene_mesh_matches_its_layout(street):
    record, vertices, faces = street.record, street.vertices, street.faces
    check_layout(record, 20.0)
    for car in record["cars"]:
        points = vertices[np.unique(faces[component(street, f"car_{car['slot']}_")])]
        (long, w, h), centre = car["size"], np.array(car["centre"])
        lo, hi = centre - [long / 2, w / 2, 0.0], centre + [long / 2, w / 2, h]
        assert np.allclose(points.min(axis=0), lo, atol=1e-9) and np.allclose(points.max(axis=0), hi, atol=1e-9)
        assert abs(points[:, 2].min()) < 1e-9  # standing on the road
    for k, pole in enumerate(record["poles"]):
        points = vertices[np.unique(faces[component(street, f"pole_{k}")])]
        assert points[:, 2].min() == KERB_HEIGHT and points[:, 2].max() == pytest.approx(KERB_HEIGHT + pole["height"])
    building = vertices[np.unique(faces[component(street, "building_")])]
    assert np.abs(building[:, 1]).min() >= ROAD_HALF_WIDTH + SIDEWALK_WIDTH - 1e-12
    tri = vertices[faces]
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    assert longest.max() <= np.sqrt(2) * GT_EDGE + 1e-9  # grid cells at most edge x edge
    assert longest[component(street, "car_")].max() <= GT_EDGE + 1e-9
    assert np.all(street.poses[:, 1] == 0) and np.all(street.poses[:, 2] == 1.8)


def signed_volume(vertices, faces):
    tri = vertices[faces]
    return np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6


def test_solids_are_closed_with_outward_normals_and_fine_cells():
    """Divergence theorem: the signed volume of a closed, outward surface is the solid's volume."""
    box = box_grid((1.0, -2.0, 0.5), (3.3, -1.1, 4.0), 0.25)
    roof = gable_grid((0.0, 0.0, 0.0), (7.0, 5.0, 3.0), 2.0, 0.25)
    pole = cylinder_grid(2.0, 3.0, 0.15, 0.12, 5.0, 0.25, segments=16)
    polygon = 0.5 * 16 * 0.12 ** 2 * np.sin(2 * np.pi / 16)
    for (vertices, faces), volume in ((box, 2.3 * 0.9 * 3.5), (roof, 0.5 * 5 * 2 * 7), (pole, polygon * 5.0)):
        assert signed_volume(vertices, faces) == pytest.approx(volume, rel=1e-12)
        tri = vertices[faces]
        assert np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max() <= np.sqrt(2) * 0.25 + 1e-12
    assert len(box[1]) == 2 * 2 * (10 * 4 + 10 * 14 + 4 * 14)  # 2 faces of 10 x 4 cells (2.3 x 0.9 m), ...


# -- the dataset ----------------------------------------------------------------------------------


def test_registered_with_defaults():
    ds = get_dataset("street")
    assert "street" in available_datasets() and ds.point_clouds
    assert ds.names() == ["street_000", "street_001", "street_002"]
    assert ds.options() == {"count": 3, "seed": 0, "length": 50, "beams": 32, "azimuths": 1080, "objects_dir": None}
    assert ds.stored_files("street_000") == ()


def test_same_seed_bit_identical_count_does_not_change_a_street_other_seed_differs():
    options = {"length": 20, "beams": 16, "azimuths": 360}
    a = get_dataset("street", count=2, seed=0, **options).load("street_001")
    b = get_dataset("street", count=5, seed=0, **options).load("street_001")
    for x, y in ((a.vertices, b.vertices), (a.faces, b.faces), (a.points, b.points), (a.sensors, b.sensors)):
        assert np.array_equal(x, y)
    assert a.content_hash == b.content_hash and a.meta == b.meta
    other = get_dataset("street", count=2, seed=1, **options).load("street_001")
    assert other.content_hash != a.content_hash


def test_shape_is_canonical_with_metres_per_unit(street):
    ds = get_dataset("street", count=1, length=20, beams=16, azimuths=360)
    shape = ds.load("street_000")
    vertices, faces = street.gt_mesh()
    assert np.array_equal(shape.faces, faces) and np.array_equal(shape.vertices, shape.transform.apply(vertices))
    lo, hi = shape.vertices.min(0), shape.vertices.max(0)
    assert np.abs(lo + hi).max() < 1e-12 and np.ptp(shape.vertices, axis=0).max() == pytest.approx(1.99, abs=1e-12)
    scale = shape.meta["metres_per_unit"]
    assert np.ptp(vertices, axis=0).max() == pytest.approx(1.99 * scale, rel=1e-12)
    back = shape.points * scale + np.asarray(shape.transform.centre)  # canonical -> metres
    assert np.allclose(back, street.points, atol=1e-9) and np.allclose(shape.transform.invert(shape.sensors),
                                                                       street.scan.sensors, atol=1e-9)
    assert shape.name == "street_000" and shape.kind == "open" and len(shape.points) == len(shape.sensors)
    assert json.loads(json.dumps(shape.meta)) == shape.meta and shape.meta["street"]["gt_faces"] == len(faces)
    record = shape.meta["street"]
    assert record["gt_area_m2"] == pytest.approx(triangle_areas(vertices, faces).sum())
    assert sum(c["visible_faces"] for c in record["components"]) == len(faces)


def test_objects_dir_uses_those_meshes(tmp_path):
    vertices, faces = box_grid((0, 0, 0), (2, 1, 1), 5.0)
    (tmp_path / "block.obj").write_text("".join(f"v {x} {y} {z}\n" for x, y, z in vertices)
                                        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces))
    ds = get_dataset("street", count=1, length=20, beams=16, azimuths=360, objects_dir=tmp_path)
    scene = ds.scene("street_000")
    cars = scene.record["cars"]
    assert cars and all(c["source"] == str(tmp_path / "block.obj") for c in cars)
    rows = component(scene, "car_")
    tri = scene.vertices[scene.faces[rows]]
    assert np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max() <= GT_EDGE + 1e-9
    check_layout(scene.record, 20.0)
    assert ds.stored_files("street_000") == ((tmp_path / "block.obj", "mesh"),)
    assert ds.options()["objects_dir"] == str(tmp_path)


def test_bad_options_are_one_line_errors(tmp_path):
    cases = [({"count": 0}, "option 'count' must be >= 1"), ({"length": 5}, "option 'length' must be >= 10"),
             ({"beams": 1}, "option 'beams' must be >= 2"),
             ({"azimuths": "many"}, "option 'azimuths' needs an integer"),
             ({"objects_dir": tmp_path / "absent"}, "objects_dir"), ({"objects_dir": tmp_path}, "no mesh files"),
             ({"list_file": tmp_path}, "has no option 'list_file'")]
    for options, expected in cases:
        with pytest.raises(DatasetError) as info:
            get_dataset("street", **options)
        assert expected in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(DatasetNotFoundError, match="absent"):
        get_dataset("street", objects_dir=tmp_path / "absent")
    with pytest.raises(DatasetError, match="has no shape 'street_003'"):
        get_dataset("street").load("street_003")
