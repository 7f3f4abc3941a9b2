"""foundation.scanner, the virtual range scanner, on meshes whose visible parts are known by hand."""

import math

import igl
import numpy as np
import pytest
import trimesh

from foundation.scanner import DEFAULT_GRAZING_DROPOUT_DEG, range_scan, scan_cloud, sphere_sensors

R = 0.8  # sphere radius


@pytest.fixture(scope="module")
def sphere():
    s = trimesh.creation.icosphere(subdivisions=5, radius=R)
    return np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces, dtype=np.int64)


@pytest.fixture(scope="module")
def cube():  # the unit cube [-0.5, 0.5]^3, 12 triangles
    b = trimesh.creation.box()
    return np.asarray(b.vertices, dtype=np.float64), np.asarray(b.faces, dtype=np.int64)


def distance_to_mesh(points, mesh):
    d2, _, _ = igl.point_mesh_squared_distance(points, mesh[0], mesh[1])
    return np.sqrt(d2)


def test_sphere_sensors_are_a_deterministic_fibonacci_layout():
    s = sphere_sensors(10, 3.0)
    assert s.shape == (10, 3) and s.dtype == np.float64
    assert np.allclose(np.linalg.norm(s, axis=1), 3.0, rtol=0, atol=1e-14)
    assert np.array_equal(s, sphere_sensors(10, 3.0))
    # heights 1 - 2 (i + 1/2) / 10, longitudes i * golden angle
    assert np.allclose(s[:, 2] / 3.0, 1 - 2 * (np.arange(10) + 0.5) / 10)
    golden = math.pi * (3 - math.sqrt(5))
    assert math.isclose(math.atan2(s[1, 1], s[1, 0]), golden)
    assert np.allclose(s.mean(axis=0), 0, atol=0.35)  # spread round the sphere
    gaps = np.linalg.norm(s[:, None] - s[None], axis=2) + np.eye(10) * 9
    assert gaps.min() > 1.5  # ~ sqrt(4 pi / 10) * 3 * 0.8: no two sensors bunched
    assert np.allclose(sphere_sensors(1, 2.0), [[2.0, 0, 0]])
    with pytest.raises(ValueError):
        sphere_sensors(0, 1.0)


def test_sphere_points_lie_on_the_mesh_and_only_on_the_visible_cap(sphere):
    s = np.array([0.6, -1.2, 2.2])
    d = np.linalg.norm(s)
    scan = range_scan(*sphere, s[None], 150 * 150, np.random.default_rng(0), grazing_dropout_deg=None)
    assert len(scan) > 8000
    assert distance_to_mesh(scan.points, sphere).max() < 1e-12  # float64 plane intersection
    assert np.array_equal(scan.sensors, np.broadcast_to(s, scan.points.shape)) and np.all(scan.sensor_ids == 0)
    # visible from s: the cap dot(p, s) >= R^2 (the horizon circle seen from s), up to the chords
    # of the triangulation (sagitta ~ R (1 - cos(edge / 2)) < 1e-4)
    assert np.all(scan.points @ s >= R**2 * (1 - 1e-3))
    # every hit face faces the sensor (outward normals of a convex mesh: exactly the visible ones)
    tri = sphere[0][sphere[1][scan.face_ids]]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(np.einsum("ij,ij->i", normal, s - scan.points) > 0)
    # ... and the cap is covered up to near its horizon (angle acos(R / d) from the sensor axis)
    angle = np.arccos(np.clip(scan.points @ s / (np.linalg.norm(scan.points, axis=1) * d), -1, 1))
    assert angle.max() > 0.97 * math.acos(R / d)
    # the default dropout removes the grazing hits, and only them
    dropped = range_scan(*sphere, s[None], 150 * 150, np.random.default_rng(0))
    cut = math.cos(math.radians(DEFAULT_GRAZING_DROPOUT_DEG))
    assert np.all(dropped.ray_cosines >= cut) and len(dropped) == np.sum(scan.ray_cosines >= cut) < len(scan)


def test_cube_occluded_faces_get_no_points(cube):
    rng = np.random.default_rng(0)
    head_on = range_scan(*cube, np.array([[3.0, 0, 0]]), 60 * 60, rng)
    assert len(head_on) > 500
    assert np.abs(head_on.points[:, 0] - 0.5).max() <= 1e-15  # the +x face, only
    assert np.abs(head_on.points[:, 1:]).max() <= 0.5
    oblique = range_scan(*cube, np.array([[2.0, 1.5, 1.0]]), 60 * 60, rng)
    on = np.isclose(np.abs(oblique.points), 0.5, rtol=0, atol=1e-15) & (oblique.points > 0)
    assert np.all(on.any(axis=1))  # every point on +x, +y or +z
    assert np.all(on.sum(axis=0) > 100)  # and all three seen
    assert distance_to_mesh(oblique.points, cube).max() < 1e-15


def test_head_on_face_gets_exactly_the_grid_rays_that_hit_it(cube):
    # By hand: the cube's bounding sphere about the origin has radius sqrt(3) / 2, seen from the
    # sensor (3, 0, 0) under alpha = asin(r / 3). The sensor frame: forward -x, right
    # (-x) x z = +y, up y x (-x) = +z. A ray of azimuth a and elevation e has direction
    # (-cos e cos a, cos e sin a, sin e) and meets the plane x = 0.5 at distance 2.5 / (cos e cos a),
    # i.e. at y = 2.5 tan a, z = 2.5 tan e / cos a.
    k = 24
    alpha = math.asin(math.sqrt(3) / 2 / 3)
    angles = -alpha + (np.arange(k) + 0.5) * 2 * alpha / k
    a, e = np.meshgrid(angles, angles, indexing="ij")
    y, z = 2.5 * np.tan(a), 2.5 * np.tan(e) / np.cos(a)
    inside = (np.abs(y) < 0.5) & (np.abs(z) < 0.5)
    assert np.min(np.abs(np.abs(np.r_[y.ravel(), z.ravel()]) - 0.5)) > 1e-3  # no ray near an edge
    scan = range_scan(*cube, np.array([[3.0, 0, 0]]), k * k, np.random.default_rng(0))
    assert len(scan) == inside.sum() == 16 * 16
    # the same points, in grid order (azimuth major)
    expected = np.stack([np.full(inside.sum(), 0.5), y[inside], z[inside]], axis=1)
    assert np.allclose(scan.points, expected, rtol=0, atol=1e-14)
    # rays_per_sensor is rounded up to a square grid: 24^2 - 5 rays still make the 24 x 24 grid
    assert np.array_equal(range_scan(*cube, np.array([[3.0, 0, 0]]), k * k - 5, np.random.default_rng(0)).points,
                          scan.points)


def test_range_noise_lies_along_the_ray_with_the_requested_sigma(sphere):
    sensors = sphere_sensors(4, 2.5)
    sigma = 0.01
    clean = range_scan(*sphere, sensors, 80 * 80, np.random.default_rng(7))
    noisy = range_scan(*sphere, sensors, 80 * 80, np.random.default_rng(7), noise=sigma)
    assert len(noisy) == len(clean) > 15000
    assert np.array_equal(noisy.face_ids, clean.face_ids)  # same rays, same hits
    ray = clean.points - clean.sensors
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    residual = noisy.points - clean.points
    along = np.einsum("ij,ij->i", residual, ray)
    assert np.abs(residual - along[:, None] * ray).max() < 1e-14  # parallel to the ray
    # the draws are the generator's first len(clean) standard normals, scaled by sigma
    z = np.random.default_rng(7).standard_normal(len(clean))
    assert np.allclose(along, sigma * z, rtol=0, atol=1e-13)
    se = sigma / math.sqrt(2 * len(along))  # standard error of a sample std
    assert abs(along.std() - sigma) < 4 * se and abs(along.mean()) < 4 * sigma / math.sqrt(len(along))


def test_scan_cloud_gives_exactly_n_points_on_the_surface_seeded(sphere):
    n = 5000
    a = scan_cloud(*sphere, n, np.random.default_rng(3))
    b = scan_cloud(*sphere, n, np.random.default_rng(3))
    assert len(a) == n and len(np.unique(a.points, axis=0)) == n  # a subsample without replacement
    for field in ("points", "sensors", "sensor_ids", "face_ids", "ray_cosines"):
        assert np.array_equal(getattr(a, field), getattr(b, field))
    assert distance_to_mesh(a.points, sphere).max() < 1e-12
    layout = sphere_sensors(10, 3.0)  # the default sensors
    assert np.array_equal(a.sensors, layout[a.sensor_ids]) and set(a.sensor_ids.tolist()) == set(range(10))
    # each point is visible from its own sensor
    assert np.all(np.einsum("ij,ij->i", a.points, a.sensors) >= R**2 * (1 - 1e-3))
    assert not np.array_equal(scan_cloud(*sphere, n, np.random.default_rng(4)).points, a.points)


def test_scan_cloud_returns_all_hits_when_the_surface_cannot_give_n():
    # a square in the plane z = 0 seen edge-on by a sensor in that plane: every hit is grazing
    v = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], dtype=float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    empty = scan_cloud(v, f, 100, np.random.default_rng(0), sensors=np.array([[3.0, 0, 0]]))
    assert empty.points.shape == (0, 3) and empty.sensor_ids.shape == (0,)
    # seen from above, a few rounds of casting give the n points
    top = scan_cloud(v, f, 20_000, np.random.default_rng(0), sensors=np.array([[0, 0, 3.0]]))
    assert len(top) == 20_000 and np.all(top.points[:, 2] == 0)


def test_refusals(sphere):
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="bounding sphere"):
        range_scan(*sphere, np.array([[0.5, 0, 0]]), 100, rng)
    with pytest.raises(TypeError):
        range_scan(*sphere, np.array([[3.0, 0, 0]]), 100, 0)
    with pytest.raises(ValueError):
        range_scan(*sphere, np.array([[3.0, 0, 0]]), 100, rng, grazing_dropout_deg=95)
