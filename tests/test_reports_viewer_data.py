"""The viewer's geometry (reports/viewer_data.py): what is drawn, the sharp-edge overlay, the first
camera and the faces each mesh keeps within a byte budget, each checked by hand."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import reports.viewer_data as vd
from reports.render import distances_to_mesh


def _arrays(mesh):
    return np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)


def test_usable_mesh_drops_faces_with_stray_indices_or_non_finite_corners_and_their_lone_vertices():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [np.nan, 0, 0], [5, 5, 5]], float)
    F = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 9], [-1, 0, 1]])
    V2, F2 = vd.usable_mesh(V, F)
    assert np.array_equal(F2, [[0, 1, 2]]) and np.array_equal(V2, V[:3])
    assert vd.usable_mesh(V, F[1:])[1].shape == (0, 3)


def test_display_mesh_keeps_a_small_mesh_and_decimates_a_large_one_close_to_the_surface():
    V, F = _arrays(trimesh.creation.icosphere(subdivisions=5))  # 20,480 faces on the unit sphere
    assert vd.display_mesh(V, F, len(F)) == (V, F)
    V2, F2 = vd.display_mesh(V, F, 2_000)
    assert 1_500 <= len(F2) <= 2_000
    assert np.abs(np.linalg.norm(V2, axis=1) - 1).max() < 0.01  # still on the sphere
    assert distances_to_mesh(V, V2, F2).max() < 0.02  # and still covering it


def test_edge_lengths_are_the_presets_in_the_canonical_frame():
    D = 3.0
    assert vd.edge_lengths("default", D) == (pytest.approx(0.004 * D), pytest.approx(0.005 * D), "")
    assert vd.edge_lengths("ndc", D) == (pytest.approx(0.004 * D), pytest.approx(0.005 * D), "")  # its frame: D = 1
    radius, tau, note = vd.edge_lengths("scene", D)  # metres: the report cannot convert them
    assert (radius, tau) == (pytest.approx(0.004 * D), pytest.approx(0.005 * D)) and "metres" in note


def test_sharp_edge_samples_of_a_box_lie_along_its_edges_and_a_sphere_has_none():
    V, F = _arrays(trimesh.creation.box(extents=(2.0, 1.5, 1.0)))
    radius = 0.01
    edges = vd.sharp_edge_samples(V, F, radius, 0.2, n=50_000)
    assert len(edges) > 100
    # within the radius of an edge: at least two coordinates within the radius of the box's faces
    near_face = np.abs(np.abs(edges) - [1.0, 0.75, 0.5]) <= radius
    assert (near_face.sum(1) >= 2).all()
    assert len(vd.sharp_edge_samples(*_arrays(trimesh.creation.icosphere(4)), radius, 0.2, n=50_000)) == 0
    assert len(vd.sharp_edge_samples(np.zeros((3, 3)), np.array([[0, 1, 2]]), radius, 0.2)) == 0  # no area
    assert len(vd.point_subset(edges, 10)) == 10 and vd.point_subset(edges, 10 ** 6) is edges


def test_edge_colours_say_which_prediction_points_are_within_the_threshold_of_a_gt_edge_point():
    gt = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    pred = np.array([[0.0, 0, 0.04], [1.0, 0.06, 0], [0.5, 0, 0]])
    colours = vd.edge_colors(pred, gt, tau=0.05)
    assert colours.tolist() == [list(vd.MATCHED_EDGE_COLOR), list(vd.UNMATCHED_EDGE_COLOR),
                                list(vd.UNMATCHED_EDGE_COLOR)]
    assert vd.edge_colors(gt, None, 0.05).tolist() == [list(vd.GT_EDGE_COLOR)] * 2
    assert vd.edge_colors(pred, np.zeros((0, 3)), 0.05).tolist() == [list(vd.UNMATCHED_EDGE_COLOR)] * 3


def test_the_first_camera_looks_at_the_box_from_the_thumbnails_view_about_the_up_axis():
    lo, hi = np.array([-1.0, -0.5, 0.0]), np.array([1.0, 0.5, 2.0])
    camera = vd.initial_camera(lo, hi, "z", (-35.0, 25.0))
    direction = np.subtract(camera["position"], camera["target"])
    distance = np.linalg.norm(direction)
    assert camera["target"] == [0.0, 0.0, 1.0] and camera["up"] == [0.0, 0.0, 1.0]
    assert direction[2] / distance == pytest.approx(np.sin(np.radians(25.0)))  # 25 degrees above, z up
    radius = np.linalg.norm(hi - lo) / 2
    assert radius / distance < np.sin(np.radians(camera["fov"]) / 2)  # the bounding sphere fits the view
    assert vd.initial_camera(lo, hi, "", (-35.0, 25.0))["up"] == [0.0, 1.0, 0.0]


def test_face_caps_fill_the_budget_with_one_cap_for_the_largest_meshes():
    counts = np.array([5000, 100, 1000])
    # 3,100 faces allowed: 100 and 1,000 fit whole, the 5,000-face mesh gets what is left
    assert vd.face_caps(counts, 3100.0, 1.0, 10).tolist() == [2000, 100, 1000]
    assert vd.face_caps(counts, 9000.0, 1.0, 10).tolist() == [5000, 100, 1000]  # all fit
    assert vd.face_caps(counts, 300.0, 1.0, 10).tolist() == [100, 100, 100]  # one cap for all
    assert vd.face_caps(counts, 30.0, 1.0, 50).tolist() == [50, 50, 50]  # never below the floor
