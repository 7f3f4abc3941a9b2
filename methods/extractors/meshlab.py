"""pymeshlab steps shared by the classic point-cloud baselines (``poisson``, ``ball-pivoting``)."""

from __future__ import annotations

import numpy as np

from foundation.timing import stage


def oriented_point_set(points: np.ndarray, k: int, sensors: np.ndarray | None = None):
    """A pymeshlab MeshSet holding ``points`` with PCA normals over their ``k`` nearest neighbours
    (``compute_normal_for_point_clouds``), oriented by MeshLab's propagation, or, given ``sensors``
    ((P, 3): the position of the sensor that saw each point), each flipped to face its sensor
    (``dot(n, sensor - p) >= 0``: a scanned point is seen from outside). Timed as the ``normals``
    sub-stage."""
    import pymeshlab

    points = np.asarray(points, dtype=np.float64)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points))
    with stage("normals"):
        ms.compute_normal_for_point_clouds(k=k, smoothiter=0)
        if sensors is not None:
            normals = np.asarray(ms.current_mesh().vertex_normal_matrix(), dtype=np.float64)
            away = np.einsum("ij,ij->i", normals, np.asarray(sensors, dtype=np.float64) - points) < 0
            normals[away] *= -1
            ms = pymeshlab.MeshSet()
            ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points, v_normals_matrix=normals))
    return ms


def current_mesh(ms) -> tuple[np.ndarray, np.ndarray, object]:
    """(vertices float64, faces int64, the pymeshlab mesh) of the MeshSet's current mesh."""
    mesh = ms.current_mesh()
    return np.asarray(mesh.vertex_matrix(), dtype=np.float64), np.asarray(mesh.face_matrix(), dtype=np.int64), mesh


def poisson_depth(N: int) -> int:
    """The octree depth whose finest level matches an N-point grid: round(log2 N), at least 1."""
    return max(1, int(round(np.log2(max(2, int(N))))))
