"""DualMesh-UDF (methods.extractors.dualmesh): the QEF's corner / edge / plane cases by hand, the leaves of a
plane, and the whole extraction against the authors' own code on a turned box."""

from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from foundation.grid import grid_points, spacing
from methods.extractors import dualmesh
from tests.data.make_dualmesh_reference import MAX_DEPTH, box_udf_grad

REFERENCE = Path(__file__).parent / "data" / "dualmesh_reference_box.npz"


def test_truncated_solve_finds_a_corner_an_edge_and_a_plane():
    # rows: unit normals n, right-hand sides n . c with c = (0.1, -0.2, 0.3); unused rows masked out
    c = np.array([0.1, -0.2, 0.3])
    normals = np.zeros((3, 4, 3))
    normals[0, :3] = np.eye(3)  # three planes: the corner c
    normals[1, :2] = np.eye(3)[:2]  # two planes: the line through c along z
    normals[1, 2] = np.eye(3)[0]
    normals[2, :3] = np.eye(3)[2]  # one plane z = 0.3, three times
    mask = np.array([[1, 1, 1, 0], [1, 1, 1, 0], [1, 1, 1, 0]], dtype=bool)
    b = normals @ c
    x, rank, direction = dualmesh._truncated_solve(normals, b, mask)
    np.testing.assert_array_equal(rank, [3, 2, 1])
    np.testing.assert_allclose(x[0], c, atol=1e-12)
    np.testing.assert_allclose(x[1], [0.1, -0.2, 0.0], atol=1e-12)  # least norm: z = 0 on the line
    np.testing.assert_allclose(np.abs(direction[1]), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(x[2], [0, 0, 0.3], atol=1e-12)
    np.testing.assert_allclose(np.abs(direction[2]), [0, 0, 1], atol=1e-12)


def test_leaves_of_a_plane_are_the_cells_whose_centre_is_near_it():
    N = 17
    h = spacing(N)
    z0 = 0.3 * h  # inside the cell layer k = 8 (z in [0, h])

    def udf(p):
        return np.abs(np.asarray(p)[:, 2] - z0)

    grid = udf(grid_points(N).reshape(-1, 3)).reshape(N, N, N)
    cells = dualmesh.leaf_cells(grid, udf)
    centre_z = -1 + (cells[:, 2] + 0.5) * h
    assert np.all(np.abs(centre_z - z0) < 0.5 * np.sqrt(3) * h + dualmesh.RELIABLE_UDF)
    # the layers at 0.2 h and 0.8 h from the plane; the next (1.2 h) is too far
    assert sorted(set(cells[:, 2])) == [7, 8] and len(cells) == 2 * 16 * 16


def test_a_plane_gives_a_flat_mesh_on_the_plane():
    N = 17
    h = spacing(N)
    normal = np.array([0.2, 0.3, 1.0]) / np.linalg.norm([0.2, 0.3, 1.0])
    offset = 0.37 * h

    def udf_grad(p):
        s = np.asarray(p) @ normal - offset
        return np.abs(s), np.sign(s)[:, None] * normal

    grid = udf_grad(grid_points(N).reshape(-1, 3))[0].reshape(N, N, N)
    mesh = dualmesh.dualmesh_udf(grid, udf_grad, lambda p: udf_grad(p)[0])
    V, F, facts = mesh.vertices, mesh.faces, mesh.info
    assert len(F) > 0 and facts["corner_vertices"] == 0 and facts["edge_vertices"] == 0
    np.testing.assert_allclose(V @ normal, offset, atol=1e-9)  # every vertex on the plane
    mesh = trimesh.Trimesh(V, F, process=False)
    cos = np.abs(mesh.face_normals @ normal)
    assert np.all(cos[mesh.area_faces > 1e-12] > 0.999)


def test_same_surface_as_the_authors_code_on_a_turned_box():
    """The authors' extract_mesh (tests/data/make_dualmesh_reference.py) and this module on the same
    analytic UDF (float32, as the authors' wrapper gives it) at 32^3 leaves: the same vertices (but
    those only triangles of no area use), as many distinct triangles with an area up to the choice of
    diagonal, and the same area. Planar quads (4 coplanar vertices) may be split along the other
    diagonal: the authors' edge recursion starts some quads at another corner."""
    reference = np.load(REFERENCE)
    N = 2 ** MAX_DEPTH + 1

    def udf_grad(p):
        d, g = box_udf_grad(p)
        return d.astype(np.float32).astype(np.float64), g.astype(np.float32).astype(np.float64)

    grid = udf_grad(grid_points(N).reshape(-1, 3))[0].reshape(N, N, N)
    mesh = dualmesh.dualmesh_udf(grid, udf_grad, lambda p: udf_grad(p)[0])
    V, F, facts = mesh.vertices, mesh.faces, mesh.info
    RV, RF = reference["vertices"], reference["faces"]
    RF = RF[(RF[:, 0] != RF[:, 1]) & (RF[:, 1] != RF[:, 2]) & (RF[:, 2] != RF[:, 0])]
    distinct = np.unique(np.sort(RF, axis=1), axis=0)
    area = trimesh.Trimesh(RV, distinct, process=False).area_faces
    distinct = distinct[area > dualmesh.ZERO_AREA * spacing(N) ** 2]  # collinear corners: no area
    used = RV[np.unique(distinct)]
    assert cKDTree(RV).query(V)[0].max() < 1e-6 and cKDTree(V).query(used)[0].max() < 1e-6
    # a quad with 3 collinear corners gives one triangle of no area along one diagonal and none along
    # the other: the counts may differ by those
    assert abs(len(F) - len(distinct)) <= 0.005 * len(distinct)
    assert trimesh.Trimesh(V, F, process=False).area == pytest.approx(
        trimesh.Trimesh(RV, distinct, process=False).area, rel=1e-8)
    assert facts["corner_vertices"] > 0 and facts["edge_vertices"] > 0  # the box's corners and edges


def test_no_leaf_no_mesh():
    N = 9
    far = np.full((N, N, N), 1.0)
    mesh = dualmesh.dualmesh_udf(far, lambda p: (np.ones(len(p)), np.zeros((len(p), 3))), lambda p: np.ones(len(p)))
    assert mesh.vertices.shape == (0, 3) and mesh.faces.shape == (0, 3) and mesh.info["leaves"] == 0
