"""Marching cubes on a grid field, for the signed representations (`sdf`, `bof`).

The field is sampled on the grid of :mod:`foundation.grid` (``(N, N, N)``, ``'ij'`` indexing, point
``[i, j, k]`` at ``(-1 + i h, -1 + j h, -1 + k h)``). The mesh comes from scikit-image's
``marching_cubes`` (Lewiner tables) and is mapped to the canonical frame [-1, 1]^3 with
:func:`foundation.grid.index_to_world`.

Orientation: faces are returned OUTWARD, i.e. the right-hand normal ``(b - a) x (c - a)`` of a face
``(a, b, c)`` points away from the inside region, so a closed surface has positive signed volume.

* ``inside='low'`` (SDF, level 0): inside is ``value < level``. scikit-image's default
  ``gradient_direction='descent'`` already gives outward faces here.
* ``inside='high'`` (occupancy probability, level 0.5): inside is ``value > level``; scikit-image
  gives inward faces, so the winding is flipped.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from skimage.measure import marching_cubes as _skimage_marching_cubes

from foundation.grid import index_to_world
from methods.base import Extraction

__all__ = ["marching_cubes_grid", "skimage_marching_cubes", "empty_mesh", "far_occupancy"]


def empty_mesh() -> tuple[np.ndarray, np.ndarray]:
    """A mesh with no vertices and no faces: ((0, 3) float64, (0, 3) int64)."""
    return np.zeros((0, 3), dtype=np.float64), np.zeros((0, 3), dtype=np.int64)


#: scikit-image's message when a volume has no triangle at the level: the one "no surface" case.
NO_SURFACE = "No surface found"


def skimage_marching_cubes(volume: np.ndarray, **options):
    """scikit-image's ``marching_cubes(volume, **options)``, or None when it finds no triangle at
    the level (its "No surface found"); every other error propagates, so a bug never reads as an
    empty mesh."""
    try:
        return _skimage_marching_cubes(volume, **options)
    except RuntimeError as exc:
        if NO_SURFACE not in str(exc):
            raise
        return None


def marching_cubes_grid(volume: np.ndarray, level: float = 0.0, inside: str = "low") -> Extraction:
    """Extract the ``level`` isosurface of a grid field, faces oriented outward.

    Parameters
    ----------
    volume : (N, N, N) array (float or bool) of field values on the grid of :mod:`foundation.grid`.
        A boolean mask is read as 0/1 (use ``level=0.5, inside='high'`` for "True = inside").
        NaN values are rejected with a ``ValueError``.
    level : iso value (0 for an SDF, 0.5 for an occupancy probability).
    inside : ``'low'`` if the inside region is ``value < level`` (SDF), ``'high'`` if it is
        ``value > level`` (occupancy).

    Returns
    -------
    :class:`methods.base.Extraction`: vertices (n, 3) float64 in the canonical frame, faces (m, 3)
    int64 oriented so normals point away from the inside. A volume that never crosses ``level``
    (all values on one side, or constant) gives an empty mesh (0 vertices, 0 faces) instead of an
    exception.
    """
    if inside not in ("low", "high"):
        raise ValueError(f"inside must be 'low' or 'high', got {inside!r}")
    volume = np.asarray(volume)
    if volume.ndim != 3 or len(set(volume.shape)) != 1 or volume.shape[0] < 2:
        raise ValueError(f"volume must have shape (N, N, N) with N >= 2, got {volume.shape}")
    if volume.dtype == bool:
        volume = volume.astype(np.float32)
    elif not np.issubdtype(volume.dtype, np.floating):
        volume = volume.astype(np.float64)
    if np.isnan(volume).any():
        raise ValueError(f"volume has {int(np.isnan(volume).sum())} NaN values; fill them before marching cubes")
    level = float(level)
    vmin, vmax = float(volume.min()), float(volume.max())
    if not (vmin <= level <= vmax) or vmin == vmax:
        return Extraction(*empty_mesh())
    found = skimage_marching_cubes(volume, level=level)
    if found is None:  # e.g. a level equal to the minimum or maximum that produces no triangle
        return Extraction(*empty_mesh())
    verts, faces, _, _ = found
    verts = index_to_world(verts, volume.shape[0])
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    if inside == "high":
        faces = faces[:, ::-1].copy()
    return Extraction(verts, faces)


def far_occupancy(known: np.ndarray) -> np.ndarray:
    """(N, N, N) float32 occupancy of the grid points outside ``known`` (bool): 0 for the connected
    regions of ~known that touch the border of the grid, 1 for the enclosed ones; 0 where known."""
    labels, _ = ndimage.label(~known)
    border = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(),
                                       labels[:, :, [0, -1]].ravel()]))
    enclosed = ~np.isin(labels, border) & ~known
    return enclosed.astype(np.float32)
