"""datasets/builtin.py: the generated CAD-like shapes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from datasets import DatasetError, get_dataset
from datasets.builtin import (
    TEMPLATE_NAMES,
    build_shape,
    builtin_names,
    generate_shape,
    largest_planar_region,
    remove_faces,
)


def edge_face_counts(faces: np.ndarray) -> np.ndarray:
    """How many faces use each undirected edge."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(edges, axis=0, return_counts=True)[1]


def in_canonical_frame(shape) -> bool:
    v = shape.vertices
    return np.abs(v).max() <= 0.995 + 1e-9 and abs(np.ptp(v, axis=0).max() - 1.99) < 1e-12


@pytest.fixture(scope="module")
def closed_shapes():
    """Every template once, closed (shape i uses template i)."""
    return [generate_shape(i, "closed", seed=0) for i in range(len(TEMPLATE_NAMES))]


def test_default_dataset_is_two_closed_one_open_one_nonmanifold():
    ds = get_dataset()
    assert ds.name == "builtin" and len(ds) == 4
    assert ds.names() == [
        "builtin_000_bracket",
        "builtin_001_flange",
        "builtin_002_housing_open",
        "builtin_003_slotted_block+pipe_tee_nonmanifold",
    ]
    kinds = [shape.kind for shape in ds]
    assert kinds == ["closed", "closed", "open", "nonmanifold"]
    assert ds.describe()["options"] == {"count": 4, "seed": 0, "variants": ["closed", "open", "nonmanifold"]}


def test_same_seed_same_arrays_and_count_does_not_change_a_shape():
    first = [s.content_hash for s in get_dataset("builtin", count=2, seed=7)]
    again = [s.content_hash for s in get_dataset("builtin", count=3, seed=7)]
    assert first == again[:2]
    other = get_dataset("builtin", count=1, seed=8).load("builtin_000_bracket")
    assert other.content_hash != first[0]
    assert build_shape(0, "closed", 7).content_hash == build_shape(0, "closed", 7).content_hash == first[0]


def test_each_load_is_its_own_copy_of_the_shape_built_once():
    a = generate_shape(3, "nonmanifold", seed=0)
    a.vertices[:] = 0.0
    a.meta["template"] = "edited"
    b = generate_shape(3, "nonmanifold", seed=0)
    assert b.content_hash == build_shape(3, "nonmanifold", 0).content_hash and b.meta["template"] == "slotted_block"
    assert b.vertices is not a.vertices


def test_closed_templates_are_watertight_cad_like_parts(closed_shapes):
    assert len({s.name for s in closed_shapes}) == len(TEMPLATE_NAMES) >= 8
    for shape in closed_shapes:
        assert shape.faces.shape[1] == 3 and shape.kind == "closed"
        assert 1000 <= len(shape.faces) <= 20000, (shape.name, len(shape.faces))
        assert in_canonical_frame(shape), shape.name
        mesh = shape.to_trimesh()  # manifold3d output is indexed: watertight as generated
        assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0, shape.name
        assert np.all(edge_face_counts(shape.faces) == 2)
        assert len(mesh.split(only_watertight=False)) == 1, shape.name
        merged = shape.to_trimesh()
        merged.merge_vertices()
        assert merged.is_watertight
        # sharp CAD edges: some dihedral angles above 30 degrees, and flat faces (angle 0)
        angles = np.degrees(mesh.face_adjacency_angles)
        assert (angles > 30).sum() >= 50, shape.name
        assert (angles < 1e-6).mean() > 0.5, shape.name


def test_open_variant_has_boundary_where_a_plane_was_removed():
    closed = generate_shape(2, "closed", seed=0)
    opened = generate_shape(2, "open", seed=0)
    assert opened.name == "builtin_002_housing_open" and opened.kind == "open"
    uses = edge_face_counts(opened.faces)
    assert (uses == 1).sum() > 0 and uses.max() == 2
    assert len(closed.faces) - len(opened.faces) == opened.meta["removed_faces"] > 0
    assert in_canonical_frame(opened)


def test_largest_planar_region_hand_worked():
    box = trimesh.creation.box(extents=(4, 2, 1))  # the two 4x2 faces are the largest planes
    drop = largest_planar_region(box.vertices, box.faces)
    assert drop.sum() == 2
    normals = box.face_normals[drop]
    assert np.allclose(np.abs(normals[:, 2]), 1) and np.allclose(normals[0], normals[1])
    vertices, faces = remove_faces(box.vertices, box.faces, drop)
    assert len(faces) == 10 and len(vertices) == 8 and (edge_face_counts(faces) == 1).sum() == 4


def test_nonmanifold_variant_is_two_intersecting_parts():
    shape = generate_shape(3, "nonmanifold", seed=0)
    assert shape.kind == "nonmanifold" and shape.name == "builtin_003_slotted_block+pipe_tee_nonmanifold"
    n_a, n_b = shape.meta["part_faces"]
    assert len(shape.faces) == n_a + n_b
    assert in_canonical_frame(shape)
    part_a = trimesh.Trimesh(shape.vertices, shape.faces[:n_a], process=False)
    part_b = trimesh.Trimesh(shape.vertices, shape.faces[n_a:], process=False)
    part_a.remove_unreferenced_vertices()
    part_b.remove_unreferenced_vertices()
    assert part_a.is_watertight and part_b.is_watertight
    assert not set(np.unique(shape.faces[:n_a])) & set(np.unique(shape.faces[n_a:]))  # a soup: nothing shared
    # B's (connected) surface has vertices inside and outside the closed part A, so it crosses A's surface
    inside = part_a.contains(part_b.vertices)
    assert 0.05 < inside.mean() < 0.95
    assert len(part_b.split(only_watertight=False)) == 1


def test_options():
    ds = get_dataset("builtin", count="5", variants="closed")
    assert [s for s in ds.names()] == [f"builtin_{i:03d}_{t}" for i, t in enumerate(TEMPLATE_NAMES[:5])]
    ds = get_dataset("builtin", count=3, variants=["open", "nonmanifold"])
    assert [kind for _, _, kind in builtin_names(3, ("open", "nonmanifold"))] == ["open", "nonmanifold", "open"]
    assert ds.names()[1] == "builtin_001_flange+housing_nonmanifold"
    for bad in ({"count": 0}, {"count": "many"}, {"variants": "broken"}, {"seed": -1}):
        with pytest.raises(DatasetError):
            get_dataset("builtin", **bad)
    with pytest.raises(DatasetError, match="no shape 'builtin_009_gear'"):
        get_dataset("builtin").load("builtin_009_gear")
