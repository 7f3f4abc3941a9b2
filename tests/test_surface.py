"""foundation.surface.sample_surface, the one area-uniform surface sampler, on hand-checked meshes."""

import numpy as np
import pytest
import trimesh

from foundation.surface import MIN_RELATIVE_AREA, binary_exponent, relative_area, sample_surface


def test_sample_surface_is_area_uniform_seeded_and_on_the_surface():
    # two triangles of areas 1/2 and 3/2 (a 1x1 and a 1x3 right triangle, both in z = 0)
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 0, 0], [6, 0, 0], [5, 3, 0]], dtype=float)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    p, nrm = sample_surface(v, f, 40_000, np.random.default_rng(3))
    assert p.shape == nrm.shape == (40_000, 3)
    assert np.allclose(p[:, 2], 0) and np.allclose(nrm, [0, 0, 1])
    on_big = p[:, 0] >= 5
    assert abs(on_big.mean() - 0.75) < 0.01  # area fraction 1.5 / 2
    small = p[~on_big]
    assert np.all(small[:, 0] + small[:, 1] <= 1 + 1e-12) and np.all(small >= -1e-12)
    assert abs(small[:, 0].mean() - 1 / 3) < 0.01  # centroid of the triangle
    again, _ = sample_surface(v, f, 40_000, np.random.default_rng(3))
    assert np.array_equal(p, again)


def test_sample_surface_never_picks_zero_area_faces():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 2, 2]], dtype=float)
    f = np.array([[0, 1, 1], [0, 1, 2], [3, 3, 3]])  # faces 0 and 2 degenerate
    p, _ = sample_surface(v, f, 5000, np.random.default_rng(0))
    assert np.allclose(p[:, 2], 0)
    with pytest.raises(ValueError, match="no face with positive area"):
        sample_surface(v, f[[0, 2]], 10, np.random.default_rng(0))


def test_points_lie_on_a_sphere():
    s = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    p, _ = sample_surface(s.vertices, s.faces, 20000, np.random.default_rng(0))
    r = np.linalg.norm(p, axis=1)
    # icosphere(4) chords sit at most ~0.5 * (1 - cos(edge/2)) below the sphere
    assert r.max() <= 0.5 + 1e-9 and r.min() > 0.497


def test_two_squares_of_different_size_share_points_by_area():
    # square A (area 1) and square B (area 4): B must get ~80% of the points
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [5, 0, 0], [7, 0, 0], [7, 2, 0], [5, 2, 0]], float)
    F = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    p, _ = sample_surface(V, F, 100000, np.random.default_rng(1))
    assert abs(np.mean(p[:, 0] >= 5) - 0.8) < 0.01
    assert np.all((p[:, 0] >= 0) & (p[:, 0] <= 7) & (p[:, 1] >= 0) & (p[:, 1] <= 2))


def test_a_seed_is_not_a_generator():
    v, f = np.eye(3), np.array([[0, 1, 2]])
    with pytest.raises(TypeError, match="^rng must be a numpy.random.Generator, got int$"):
        sample_surface(v, f, 10, 0)


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("exponent", [-1000, 1000])
def test_a_mesh_at_2_to_the_1000_or_its_inverse_samples_exactly_like_at_1(exponent):
    """Scaling by a power of two is exact, so the samples of the scaled mesh are the scaled samples,
    bit for bit. Without the internal rescale the cross products of a 2^-1000 mesh underflow to 0
    and those of a 2^1000 mesh overflow to inf: "no face with positive area"."""
    s = trimesh.creation.icosphere(subdivisions=2)
    points, normals = sample_surface(s.vertices, s.faces, 5000, np.random.default_rng(4))
    scale = 2.0**exponent
    scaled_points, scaled_normals = sample_surface(s.vertices * scale, s.faces, 5000, np.random.default_rng(4))
    assert np.array_equal(scaled_points, points * scale) and np.array_equal(scaled_normals, normals)


@pytest.mark.filterwarnings("error")
def test_relative_area_of_hand_worked_meshes_at_any_scale():
    """Area over the largest bounding-box side squared: unit square 1, a 2 x 1 rectangle 2 / 4,
    the surface of a cube 6, collinear triangles 0, a 1e-14-high sliver 0.5e-14 / 1 (below
    MIN_RELATIVE_AREA = 1e-12: degenerate); the same at 1e-300 and 1e300 (no under- or overflow)."""
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]])
    rectangle = square[0] * [2, 1, 0], square[1]
    cube = trimesh.creation.box()
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float), np.array([[0, 1, 2]])
    sliver = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1e-14, 0]]), np.array([[0, 1, 2]])
    for scale in (1.0, 1e-300, 1e300):
        assert relative_area(square[0] * scale, square[1]) == pytest.approx(1.0, rel=1e-12)
        assert relative_area(rectangle[0] * scale, rectangle[1]) == pytest.approx(0.5, rel=1e-12)
        assert relative_area(cube.vertices * scale, cube.faces) == pytest.approx(6.0, rel=1e-12)
        assert relative_area(line[0] * scale, line[1]) == 0.0
        assert relative_area(sliver[0] * scale, sliver[1]) == pytest.approx(0.5e-14, rel=1e-6)
    assert relative_area(*sliver) < MIN_RELATIVE_AREA
    assert relative_area(square[0], np.zeros((0, 3), dtype=np.int64)) == 0.0
    assert binary_exponent(np.array([0.75, -3.0, np.nan])) == 2 and binary_exponent(np.zeros(0)) == 0
