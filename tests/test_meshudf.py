"""MeshUDF-style extraction on analytic UDFs with analytic gradients: sphere, open square sheet, cube."""

import numpy as np
import pytest

from foundation.grid import grid_points, spacing
from foundation.timing import StageTimer, stage
from methods.extractors.meshudf import CUBE_EDGES, mc_case_table, meshudf_marching_cubes

N = 40
H = spacing(N)
P = grid_points(N)


def sphere_udf(r=0.6):
    rad = np.linalg.norm(P, axis=-1)
    return np.abs(rad - r), np.sign(rad - r)[..., None] * P / rad[..., None]


def sheet_distance(q, b=0.5321, z0=0.0123):
    """Distance to the square [-b, b]^2 x {z0} and its gradient."""
    dxy = np.maximum(np.abs(q[..., :2]) - b, 0.0)
    dz = q[..., 2] - z0
    d = np.sqrt((dxy**2).sum(-1) + dz**2)
    g = np.concatenate([np.sign(q[..., :2]) * dxy, dz[..., None]], axis=-1) / np.maximum(d, 1e-300)[..., None]
    return d, g


def cube_distance(q, a=0.4567):
    """Distance to the surface of the cube [-a, a]^3 and its gradient (pointing away from the surface)."""
    aq = np.abs(q)
    out = np.maximum(aq - a, 0.0)
    d_out = np.linalg.norm(out, axis=-1)
    inside = (aq <= a).all(-1)
    nearest_face = np.argmax(aq, axis=-1)
    g_in = -np.sign(q) * np.eye(3)[nearest_face]
    g_out = np.sign(q) * out / np.maximum(d_out, 1e-300)[..., None]
    return np.where(inside, (a - aq).min(-1), d_out), np.where(inside[..., None], g_in, g_out)


def meshudf(*args, **options):
    """(vertices, faces) of :func:`meshudf_marching_cubes`."""
    mesh = meshudf_marching_cubes(*args, **options)
    return mesh.vertices, mesh.faces


def area(v, f):
    return float(np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum() / 2)


def edge_use_counts(f):
    e = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0, return_counts=True)[1]


def test_case_table_basics():
    table, counts = mc_case_table()
    assert counts[0] == 0 and counts[255] == 0
    # corner 0 alone: one triangle over the 3 edges at corner 0 (ids 0, 4, 8)
    assert counts[1] == 1 and set(table[1, 0]) == {0, 4, 8}
    # corners 0 and 1 (the x-edge 0 between them): a quad over edges 4, 5, 8, 9
    assert counts[3] == 2 and set(table[3, :2].ravel()) == {4, 5, 8, 9}
    # every edge used by a case joins a negative and a positive corner
    for case in (1, 3, 7, 15, 90, 165):
        used = table[case, : counts[case]].ravel()
        neg = (case >> CUBE_EDGES[used]) & 1
        assert (neg[:, 0] != neg[:, 1]).all()


def test_sphere_closed_near_radius():
    r = 0.6
    d, g = sphere_udf(r)
    with StageTimer().active() as timer, stage("extract"):
        mesh = meshudf_marching_cubes(d, g)
    v, f = mesh.vertices, mesh.faces
    assert set(timer.seconds) == {"extract_s", "extract_candidates_s", "extract_pseudo_signs_s",
                                  "extract_triangulation_s", "extract_filter_s"}
    assert v.dtype == np.float64 and f.dtype == np.int64 and mesh.info == {}
    radial = np.abs(np.linalg.norm(v, axis=1) - r)
    assert radial.max() < H / 4
    assert radial.mean() < H / 50  # Chamfer-like mean distance to the sphere
    assert edge_use_counts(f).min() == 2 and edge_use_counts(f).max() == 2  # closed, manifold
    assert area(v, f) == pytest.approx(4 * np.pi * r**2, rel=0.02)


def test_udf_callback_is_used_for_the_face_filter():
    r = 0.6
    d, g = sphere_udf(r)
    seen = {}

    def exact(q):
        seen["shape"] = q.shape
        return np.abs(np.linalg.norm(q, axis=1) - r)

    v1, f1 = meshudf(d, g, udf_at=exact)
    v2, f2 = meshudf(d, g)
    assert seen["shape"][1] == 3 and len(f1) == len(f2)
    # a callback that says "far" everywhere removes every face
    v3, f3 = meshudf(d, g, udf_at=lambda q: np.ones(len(q)))
    assert len(f3) == 0 and len(v3) == 0


def test_open_square_sheet_is_single_and_open():
    b, z0 = 0.5321, 0.0123
    d, g = sheet_distance(P, b, z0)
    v, f = meshudf(d, g)
    counts = edge_use_counts(f)
    assert (counts == 1).sum() > 0 and counts.max() == 2  # open, manifold
    assert np.abs(v[:, 2] - z0).max() < H / 4  # one layer on the plane
    assert np.abs(v[:, :2]).max() <= b + H
    assert area(v, f) == pytest.approx((2 * b) ** 2, rel=0.10)  # not doubled, not eaten


def test_cube_keeps_its_area():
    a = 0.4567
    d, g = cube_distance(P, a)
    v, f = meshudf(d, g)
    assert area(v, f) == pytest.approx(6 * (2 * a) ** 2, rel=0.05)
    assert (edge_use_counts(f) == 1).sum() == 0  # closed
    assert np.abs(cube_distance(v, a)[0]).max() < H / 6
    # the simple anchor rule cuts holes along the sharp edges
    v2, f2 = meshudf(d, g, sign_rule="anchor")
    assert (edge_use_counts(f2) == 1).sum() > 0
    assert area(v2, f2) < area(v, f)


def test_far_field_gives_empty_mesh_and_bad_inputs_raise():
    d = np.ones((8, 8, 8))
    v, f = meshudf(d, np.zeros((8, 8, 8, 3)))
    assert v.shape == (0, 3) and f.shape == (0, 3)
    d[0, 0, 0] = np.nan  # NaN = unknown = far
    assert len(meshudf(d, np.zeros((8, 8, 8, 3)))[1]) == 0
    with pytest.raises(ValueError, match="grad"):
        meshudf_marching_cubes(np.ones((8, 8, 8)), np.zeros((8, 8, 8)))
    with pytest.raises(ValueError, match="udf"):
        meshudf_marching_cubes(np.ones((8, 8, 7)), np.zeros((8, 8, 7, 3)))
    with pytest.raises(ValueError, match="sign_rule"):
        meshudf_marching_cubes(np.ones((8, 8, 8)), np.zeros((8, 8, 8, 3)), sign_rule="majority")
