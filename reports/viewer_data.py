"""The geometry report.html's 3D viewer shows, arrays in and out: the mesh drawn (usable faces,
decimated for display only), the sharp-edge overlay, the first camera and the size budget.

Sharp edges are the metrics' own edge points (:func:`foundation.metrics.edges.sharp_edge_points`, NDC's
test) on the metrics' own area-uniform samples (:func:`foundation.surface.sample_surface`), with the
run's preset's radius and EF1 threshold in the canonical frame (:func:`edge_lengths`). The overlay
is drawn from the scored meshes, never from a decimated one.
"""

from __future__ import annotations

import numpy as np

from foundation.metrics.edges import EdgeSearchTooDense, sharp_edge_points
from foundation.metrics.presets import DEFAULT, get_preset
from foundation.surface import sample_surface
from methods.extractors.mesh_ops import drop_unreferenced_vertices

#: Surface samples per prediction for the overlay's edge points (the metrics draw more; the edge
#: test's radius is the same, so the overlay shows the same band, sparser).
EDGE_SAMPLES = 100_000
#: Surface samples of the GT for the edge points a prediction's are matched against: dense enough
#: that their spacing, about sqrt(area / n), stays well below the EF1 threshold (0.005 D) on CAD
#: parts, so that a prediction's edge point on a GT edge is never called unmatched for want of samples.
GT_EDGE_SAMPLES = 400_000
#: At most this many edge points per mesh are drawn (a seeded subset).
MAX_EDGE_POINTS = 20_000
#: Overlay colours: the GT's edge points, the prediction's within the EF1 threshold of one of them
#: (EF1's match) and the prediction's others.
GT_EDGE_COLOR = (0.08, 0.08, 0.08)
MATCHED_EDGE_COLOR = (0.10, 0.60, 0.31)
UNMATCHED_EDGE_COLOR = (0.82, 0.11, 0.55)
#: Vertical field of view of the viewer's perspective cameras, degrees.
FOV_DEG = 30.0
#: World axis vectors by the dataset's up axis ('' : y).
UP_VECTORS = {"": (0.0, 1.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0), "x": (1.0, 0.0, 0.0)}


def usable_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The faces whose indices are in range and whose corners are finite, with the vertices they use
    (a prediction file may hold NaN or stray indices; the scores skip such faces too)."""
    V = np.asarray(vertices, dtype=float).reshape(-1, 3)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    F = F[((F >= 0) & (F < len(V))).all(1)]
    F = F[np.isfinite(V[F]).all(axis=(1, 2))] if len(F) else F
    return drop_unreferenced_vertices(V, F) if len(F) else (np.zeros((0, 3)), np.zeros((0, 3), np.int64))


def display_mesh(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """The mesh itself when it has at most ``max_faces`` faces, else a copy decimated to about that
    many by quadric edge collapse (pymeshlab, topology not forced); only for display."""
    if len(faces) <= max_faces:
        return vertices, faces
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.ascontiguousarray(vertices, dtype=np.float64),
                               np.ascontiguousarray(faces, dtype=np.int32)))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(max(max_faces, 4)), preservenormal=True,
                                                autoclean=True)
    mesh = ms.current_mesh()
    return np.asarray(mesh.vertex_matrix(), dtype=float), np.asarray(mesh.face_matrix(), dtype=np.int64)


def edge_lengths(preset_name: str, gt_diagonal: float) -> tuple[float, float, str]:
    """(edge radius, EF1 threshold, note) of the preset ``preset_name`` in the GT's canonical frame,
    ``gt_diagonal`` its bounding-box diagonal there. A preset in metres (scenes) cannot be converted
    without the scene's scale, which the report does not have: the default preset's rule is used
    and the note says so (else the note is '')."""
    preset = get_preset(preset_name)
    if preset.frame == "metres":
        return (DEFAULT.edge_radius * gt_diagonal, DEFAULT.ef1_threshold * gt_diagonal,
                f"the '{preset.name}' preset measures edges in metres, which the report cannot convert: "
                f"edges drawn with the default preset's radius {DEFAULT.edge_radius:g} D and threshold "
                f"{DEFAULT.ef1_threshold:g} D")
    # diag1 divides lengths by D, so its lengths are D-multiples; canonical takes 'frame' lengths as they are
    scale = gt_diagonal if (preset.edge_units == "gt_diagonal" or preset.frame == "diag1") else 1.0
    return preset.edge_radius * scale, preset.ef1_threshold * scale, ""


def sharp_edge_samples(vertices: np.ndarray, faces: np.ndarray, radius: float, dot_threshold: float,
                       n: int = EDGE_SAMPLES, seed: int = 0) -> np.ndarray:
    """(k,3) sharp-edge points of the mesh: of ``n`` seeded area-uniform samples, those NDC's test
    flags (radius ``radius``, ``|n.n| < dot_threshold``). Empty when the mesh has no area or the
    search would be too dense."""
    try:
        points, normals = sample_surface(vertices, faces, n, np.random.default_rng(seed))
        return points[sharp_edge_points(points, normals, radius, dot_threshold)]
    except (ValueError, EdgeSearchTooDense):  # no face of positive area; a degenerate, too dense input
        return np.zeros((0, 3))


def point_subset(points: np.ndarray, max_points: int = MAX_EDGE_POINTS, seed: int = 0) -> np.ndarray:
    """The points themselves when there are at most ``max_points``, else a seeded subset of that
    many, in their order."""
    if len(points) <= max_points:
        return points
    return points[np.sort(np.random.default_rng(seed).choice(len(points), max_points, replace=False))]


def edge_colors(points: np.ndarray, gt_edges: np.ndarray | None, tau: float) -> np.ndarray:
    """(k,3) overlay colours of edge points: the GT's own (``gt_edges`` None) in GT_EDGE_COLOR; a
    prediction's in MATCHED_EDGE_COLOR within ``tau`` of a GT edge point, else UNMATCHED_EDGE_COLOR."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if gt_edges is None:
        return np.tile(GT_EDGE_COLOR, (len(points), 1))
    matched = np.zeros(len(points), dtype=bool)
    if len(gt_edges) and len(points):
        from scipy.spatial import cKDTree

        distance = cKDTree(gt_edges).query(points, distance_upper_bound=tau)[0]
        matched = distance < tau
    return np.where(matched[:, None], MATCHED_EDGE_COLOR, UNMATCHED_EDGE_COLOR)


def initial_camera(lo: np.ndarray, hi: np.ndarray, up: str, view: tuple[float, float]) -> dict:
    """The viewer's first camera: looking at the box ``lo``-``hi`` from ``view`` = (azimuth,
    elevation) degrees about the world axis ``up``, as the thumbnails do
    (:func:`reports.render.camera_rotation`), far enough for the box's bounding sphere to fill the
    perspective view. Returns {'position', 'target', 'up', 'near', 'far', 'fov'} (lists, floats)."""
    from reports.render import camera_rotation

    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    centre = (lo + hi) / 2.0
    radius = max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-6)
    distance = 1.1 * radius / np.sin(np.radians(FOV_DEG) / 2.0)
    back = camera_rotation(*view, up=up or "y")[2]  # the camera's back axis, in world coordinates
    return {"position": (centre + distance * back).tolist(), "target": centre.tolist(),
            "up": list(UP_VECTORS[up]), "near": distance / 100.0, "far": distance * 10.0, "fov": FOV_DEG}


def face_caps(face_counts: np.ndarray, budget_bytes: float, bytes_per_face: float, min_faces: int) -> np.ndarray:
    """Faces to draw per mesh so that their estimated bytes (``bytes_per_face`` each) fit
    ``budget_bytes``: every mesh in full when they fit, else one cap for all (water filling: the
    meshes below the cap keep all their faces, the others get the cap), never below ``min_faces``."""
    counts = np.asarray(face_counts, dtype=np.int64)
    allowed = budget_bytes / max(bytes_per_face, 1e-9)
    if counts.sum() <= allowed or not len(counts):
        return counts.copy()
    ordered = np.sort(counts)
    below = np.concatenate([[0], np.cumsum(ordered)])[:-1]  # faces of the meshes smaller than each
    left = len(ordered) - np.arange(len(ordered))  # meshes at or above each
    caps = (allowed - below) / left  # the cap if the meshes from this one up share what is left
    fits = np.flatnonzero(caps <= ordered)
    cap = caps[fits[0]] if len(fits) else ordered[-1]
    return np.maximum(np.minimum(counts, int(cap)), np.minimum(counts, min_faces))
