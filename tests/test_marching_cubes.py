"""Marching cubes on grid fields: frame mapping, outward orientation for SDF and occupancy, edge cases."""

import numpy as np
import pytest

from foundation.grid import grid_points, spacing
from methods.extractors.marching_cubes import far_occupancy, marching_cubes_grid

N = 40
R = 0.6
CENTRE = np.array([0.1, -0.05, 0.02])


def _mesh(extraction):
    """(vertices, faces) of an Extraction, after checking its array types."""
    assert extraction.vertices.dtype == np.float64 and extraction.faces.dtype == np.int64
    return extraction.vertices, extraction.faces


def sphere_sdf(N=N, r=R, centre=CENTRE):
    return np.linalg.norm(grid_points(N) - centre, axis=-1) - r


def signed_volume(v, f):
    """Sum over faces of a . (b x c) / 6: positive for a closed mesh with outward faces."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)


def face_normals_dot_radial(v, f, centre=CENTRE):
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    n = np.cross(b - a, c - a)
    return np.einsum("ij,ij->i", n, (a + b + c) / 3.0 - centre)


def test_sdf_sphere_is_in_frame_and_outward():
    v, f = _mesh(marching_cubes_grid(sphere_sdf(), level=0.0, inside="low"))
    assert v.dtype == np.float64 and f.dtype == np.int64
    h = spacing(N)
    radius = np.linalg.norm(v - CENTRE, axis=1)
    # exact SDF, linear interpolation along edges: error O(h^2 / r), well under h / 10
    assert np.abs(radius - R).max() < h / 10
    assert signed_volume(v, f) > 0
    assert np.isclose(signed_volume(v, f), 4 / 3 * np.pi * R**3, rtol=0.02)
    assert (face_normals_dot_radial(v, f) > 0).all()


def test_occupancy_sphere_is_outward():
    sdf = sphere_sdf()
    prob = 1.0 / (1.0 + np.exp(sdf / 0.02))  # high inside, 0.5 on the sphere
    v, f = _mesh(marching_cubes_grid(prob, level=0.5, inside="high"))
    assert signed_volume(v, f) > 0
    assert np.isclose(signed_volume(v, f), 4 / 3 * np.pi * R**3, rtol=0.02)
    assert (face_normals_dot_radial(v, f) > 0).all()


def test_bool_mask_high_inside_is_outward():
    mask = sphere_sdf() < 0
    v, f = _mesh(marching_cubes_grid(mask, level=0.5, inside="high"))
    assert len(f) > 0 and signed_volume(v, f) > 0
    assert (face_normals_dot_radial(v, f) > 0).all()
    # a 0/1 mask puts every vertex at an edge midpoint: within h/2 + h^2 of the sphere
    assert np.abs(np.linalg.norm(v - CENTRE, axis=1) - R).max() < spacing(N) * 0.75


def test_low_and_high_give_opposite_windings_of_the_same_surface():
    sdf = sphere_sdf()
    v1, f1 = _mesh(marching_cubes_grid(sdf, 0.0, "low"))
    v2, f2 = _mesh(marching_cubes_grid(-sdf, 0.0, "high"))
    assert len(v1) == len(v2) and len(f1) == len(f2)
    assert np.allclose(np.sort(v1, axis=0), np.sort(v2, axis=0))
    assert np.isclose(signed_volume(v1, f1), signed_volume(v2, f2))


@pytest.mark.parametrize("volume", [np.ones((8, 8, 8)), np.full((8, 8, 8), 0.5), np.zeros((8, 8, 8), bool)])
def test_no_crossing_gives_empty_mesh(volume):
    v, f = _mesh(marching_cubes_grid(volume, level=0.5, inside="high"))
    assert v.shape == (0, 3) and f.shape == (0, 3)


def test_bad_inputs_raise_one_line_errors():
    vol = sphere_sdf(N=8)
    vol[1, 2, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        marching_cubes_grid(vol)
    with pytest.raises(ValueError, match="shape"):
        marching_cubes_grid(np.zeros((4, 4, 5)))
    with pytest.raises(ValueError, match="inside"):
        marching_cubes_grid(sphere_sdf(N=8), inside="outside")


def test_far_region_enclosed_by_the_band_is_inside():
    known = np.zeros((N, N, N), bool)
    known[4:20, 4:20, 4:20] = True
    known[6:18, 6:18, 6:18] = False  # a hollow box: the band of a closed surface
    occ = far_occupancy(known)
    assert occ[12, 12, 12] == 1 and occ[0, 0, 0] == 0 and occ[5, 5, 5] == 0  # inside, outside, band
    assert occ[6:18, 6:18, 6:18].all() and occ.sum() == 12 ** 3


def test_only_scikit_images_no_surface_reads_as_an_empty_mesh(monkeypatch):
    import methods.extractors.marching_cubes as mc

    def no_surface(volume, **options):
        raise RuntimeError("No surface found at the given iso value.")

    monkeypatch.setattr(mc, "_skimage_marching_cubes", no_surface)
    assert len(marching_cubes_grid(sphere_sdf(), 0.0).faces) == 0

    def bug(volume, **options):
        raise ValueError("a bug in the extraction")

    monkeypatch.setattr(mc, "_skimage_marching_cubes", bug)
    with pytest.raises(ValueError, match="a bug in the extraction"):  # fails the job with its message
        marching_cubes_grid(sphere_sdf(), 0.0)
