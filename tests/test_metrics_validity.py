"""Mesh validity columns (foundation.metrics.validity), counted by hand on small meshes."""

from __future__ import annotations

import numpy as np

from foundation import metrics as M
from tests.test_metrics import box, square


def test_validity_of_cube_square_and_nonmanifold_fan():
    v, f = box(2.0)
    assert M.mesh_validity(v, f) == {
        "n_vertices": 8, "n_faces": 12, "boundary_edges": 0, "nonmanifold_edges": 0, "components": 1, "watertight": True,
        "euler_characteristic": 2, "genus": 0.0}  # 8 - 18 + 12; (2 * 1 - 2) / 2 (tests/test_metrics_topology.py)
    sv, sf = square()
    got = M.mesh_validity(sv, sf)
    assert (got["boundary_edges"], got["nonmanifold_edges"], got["components"], got["watertight"]) == (4, 0, 1, False)
    # three triangles on the edge (0, 1): one non-manifold edge, 6 boundary edges, one component
    fv = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1]], dtype=float)
    ff = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    got = M.mesh_validity(fv, ff)
    assert (got["boundary_edges"], got["nonmanifold_edges"], got["components"], got["watertight"]) == (6, 1, 1, False)
    # as given, no merging: a soup of the square (duplicated corner vertices) is 2 components
    soup_v = sv[sf.ravel()]
    got = M.mesh_validity(soup_v, np.arange(6).reshape(2, 3))
    assert (got["n_vertices"], got["boundary_edges"], got["components"]) == (6, 6, 2)
    # indices as a broken file may hold (2^31 + 1 and 2^33 - 1): two triangles sharing the edge
    # (B, C) only, so 4 boundary edges. Keys a * 2^33 + b would wrap around 2^64 and pair the
    # edges (1, B) ~ (A, B) and (1, C) ~ (A, C): "watertight"
    a, b, c = 2**31 + 1, 2**33 - 1, 2**33 - 2
    got = M.mesh_validity(fv, np.array([[1, b, c], [a, b, c]]))
    assert (got["boundary_edges"], got["nonmanifold_edges"], got["components"], got["watertight"]) == (4, 0, 1, False)
    # two triangles sharing only a vertex: 2 components
    got = M.mesh_validity(fv, np.array([[0, 1, 2], [0, 3, 4]]))
    assert got["components"] == 2
    assert M.evaluate(v, f, v, f, n_points=2000)["watertight"] is True
