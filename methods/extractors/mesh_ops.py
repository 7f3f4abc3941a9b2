"""Mesh operations shared by the extractors: arrays in, arrays out."""

from __future__ import annotations

import numpy as np


def keep_vertices(vertices: np.ndarray, faces: np.ndarray, keep: np.ndarray):
    """The mesh of the vertices where ``keep`` (n,) holds and the faces using only those; returns
    (vertices, faces reindexed, vertices removed). Vertices and faces keep their order."""
    index = np.cumsum(keep) - 1
    faces = faces[keep[faces].all(axis=1)]
    return vertices[keep], index[faces], int((~keep).sum())


def drop_unreferenced_vertices(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh without the vertices no face uses: (vertices, faces reindexed), both in their order."""
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.reshape(-1)] = True
    vertices, faces, _ = keep_vertices(vertices, faces, used)
    return vertices, faces
