"""Mesh validity columns: vertex and face counts, boundary and non-manifold
edges, edge-connected components, watertightness, Euler characteristic and genus, counted on the
faces as given."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

__all__ = ["mesh_validity"]


def mesh_validity(vertices: np.ndarray, faces: np.ndarray) -> dict:
    """Topology counts of a triangle mesh, on its faces *as given* (no vertex merging).

    An undirected edge is a pair of vertex indices used by a face side (duplicated vertex positions
    with different indices are different vertices, so a triangle soup has only boundary edges).
    ``boundary_edges``: edges used by exactly one face side; ``nonmanifold_edges``: used by more
    than two; ``components``: connected components of faces, two faces being connected when they
    share an edge (sharing only a vertex does not connect); ``watertight``: at least one face and
    every edge used by exactly two face sides.

    ``euler_characteristic`` ``= V_used - E + F``: vertices referenced by a face, undirected edges
    (as above), faces; NaN without faces. ``genus`` ``= (2 * components - euler_characteristic) / 2``
    for a watertight mesh (closed and edge-manifold: then each component is a closed surface), NaN
    otherwise. A cube: 8 - 18 + 12 = 2, genus 0; a torus: 0, genus 1; two disjoint spheres: 4,
    genus 0 (the genera summed over the components). Where closed sheets share only a vertex (a
    non-manifold vertex, counted once in V_used) the genus comes out 1/2 higher per extra sheet
    through that vertex: e.g. two cubes sharing a corner, 2 components, 15 - 36 + 24 = 3, genus 1/2.
    """
    vertices = np.asarray(vertices).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    m = len(faces)
    out = {"n_vertices": int(len(vertices)), "n_faces": int(m)}
    if m == 0:
        out.update(boundary_edges=0, nonmanifold_edges=0, components=0, watertight=False,
                   euler_characteristic=float("nan"), genus=float("nan"))
        return out
    sides = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)  # face f owns rows 3f..3f+2
    sides = sides - int(sides.min())  # out-of-range indices are counted as given
    if int(sides.max()) >= 2**31:  # keys below would overflow int64: renumber the used ids densely
        sides = np.unique(sides, return_inverse=True)[1].reshape(sides.shape)
    side_keys = sides[:, 0] * (int(sides.max()) + 1) + sides[:, 1]
    edge_keys, edge_of_side, uses = np.unique(side_keys, return_inverse=True, return_counts=True)
    edge_of_side = edge_of_side.reshape(-1)
    boundary = int(np.sum(uses == 1))
    nonmanifold = int(np.sum(uses > 2))
    # bipartite face-edge graph: its components are the edge-connected face components
    face_of_side = np.repeat(np.arange(m), 3)
    graph = coo_matrix(
        (np.ones(3 * m, dtype=np.int8), (face_of_side, m + edge_of_side)), shape=(m + len(edge_keys),) * 2
    )
    components, _ = connected_components(graph, directed=False)
    watertight = bool(boundary == 0 and nonmanifold == 0)
    euler = int(len(np.unique(faces))) - int(len(edge_keys)) + m  # faces as given: out-of-range ids count too
    out.update(
        boundary_edges=boundary,
        nonmanifold_edges=nonmanifold,
        components=int(components),
        watertight=watertight,
        euler_characteristic=euler,
        genus=(2 * int(components) - euler) / 2 if watertight else float("nan"),
    )
    return out

