"""Self-intersections of a triangle mesh: the pairs of its faces that meet other than at a vertex or
an edge they share, found by libigl's exact search (``igl.predicates.find_self_intersections``).

Chosen over pymeshlab's ``compute_selection_by_self_intersections_per_face`` (measured on the
first 270k faces of an E-DC prediction of ABC 00000009, 2 busy cores: libigl 0.56 s, pymeshlab
0.37 s) because pymeshlab ignores every pair of faces with a common vertex, so it misses fold-overs
(two faces on one edge, coplanar and overlapping: 1,291 of that mesh's 1,317 pairs) and reports 16
faces where libigl reports 2,618.

Cost of :func:`self_intersections` (search, vertex merging and probe; medians of 3, 2 busy cores):
0.64 s for that 270k-face mesh (1,317 pairs), 1.17 s for a 270k-face neural E-DC prediction with
71,663 pairs, 0.95 s at 360k faces, 2.6 s at 1M (an icosphere).
"""

from __future__ import annotations

import igl.predicates
import numpy as np

from foundation.surface import binary_exponent

__all__ = ["self_intersections", "MAX_SELF_INTERSECTION_FACES", "PROBE_FACES", "MAX_SELF_INTERSECTION_PAIRS"]

#: Faces beyond which the search is not run (the counts are NaN, with the reason): its time grows
#: with the faces (module docstring: 0.6-1.2 s at 270k, 2.6 s at 1M).
MAX_SELF_INTERSECTION_FACES = 1_000_000
#: Faces of the mesh (every k-th) whose contacts with all faces are found before the search.
PROBE_FACES = 32
#: The search is not run when the probed faces predict more pairs than this (their contacts with
#: faces that share no vertex with them, times faces / probes / 2): its time and memory grow with
#: the pairs it reports, ~0.6 us and ~24 bytes each, so a mesh of long spikes through each other
#: would take minutes and GBs. A sound mesh predicts 0; the E-DC predictions measured, < 0.5 F.
MAX_SELF_INTERSECTION_PAIRS = 5_000_000


def self_intersections(vertices: np.ndarray, faces: np.ndarray) -> dict:
    """The self-intersecting face pairs of a triangle mesh and the faces they involve.

    Two faces intersect when they share a point other than a vertex or an edge they both have:
    crossing, touching (exact predicates count a contact at one point), or overlapping when
    coplanar (a fold-over across a shared edge counts). The geometry decides, not the indexing:
    vertices at bit-identical positions are taken as one before the search (so a triangle soup's
    neighbours, which meet only along their common edges, do not count), and faces that then have
    a repeated vertex (no area) are left out, as are faces with out-of-range indices or
    non-finite vertices. Any scale: the positions are rescaled by one power of two (exact) first.

    Parameters
    ----------
    vertices : (V, 3) array_like
    faces : (F, 3) array_like of int
        Any mesh; never raises on its content.

    Returns
    -------
    dict
        ``self_intersecting_pairs`` (int: unordered pairs of faces), ``self_intersecting_faces``
        (int: faces in at least one pair; indices as given), ``self_intersections_skipped`` ('' or
        why the search was not run: more than :data:`MAX_SELF_INTERSECTION_FACES` faces, or more
        than :data:`MAX_SELF_INTERSECTION_PAIRS` pairs predicted from :data:`PROBE_FACES` probed
        faces; both counts are then NaN). No usable face: both counts NaN, reason ''.
    """
    nan = float("nan")
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(faces).reshape(-1, 3).astype(np.int64) if np.size(faces) else np.zeros((0, 3), dtype=np.int64)
    out = {"self_intersecting_pairs": nan, "self_intersecting_faces": nan, "self_intersections_skipped": ""}
    ok = np.all((faces >= 0) & (faces < len(vertices)), axis=1)
    finite = np.all(np.isfinite(vertices), axis=1)
    ok[ok] = np.all(finite[faces[ok]], axis=1)
    face_ids = np.flatnonzero(ok)
    if len(face_ids) == 0:
        return out
    if len(face_ids) > MAX_SELF_INTERSECTION_FACES:
        out["self_intersections_skipped"] = (f"{len(face_ids):,} faces, over the limit of "
                                             f"{MAX_SELF_INTERSECTION_FACES:,} of the self-intersection search")
        return out
    # one vertex per position (bytewise, after + 0.0 makes -0.0 and 0.0 one), then faces of 3 distinct vertices
    used = np.unique(faces[face_ids])
    keys = np.ascontiguousarray(vertices[used] + 0.0).view(np.dtype((np.void, 24))).ravel()
    first, position_of_used = np.unique(keys, return_index=True, return_inverse=True)[1:]
    position_of = np.zeros(len(vertices), dtype=np.int64)
    position_of[used] = position_of_used.ravel()
    positions = vertices[used[first]]
    positions = np.ascontiguousarray(np.ldexp(positions, -binary_exponent(positions)))  # exact: no overflow at 1e300
    merged = position_of[faces[face_ids]]
    distinct = (merged[:, 0] != merged[:, 1]) & (merged[:, 1] != merged[:, 2]) & (merged[:, 0] != merged[:, 2])
    face_ids, merged = face_ids[distinct], np.ascontiguousarray(merged[distinct])
    if len(face_ids) == 0:
        return {**out, "self_intersecting_pairs": 0, "self_intersecting_faces": 0}
    probe = np.ascontiguousarray(merged[:: max(1, len(merged) // PROBE_FACES)][:PROBE_FACES])
    contacts = igl.predicates.find_intersections(positions, probe, positions, merged, False)[1].reshape(-1, 2)
    apart = ~np.any(probe[contacts[:, 0], :, None] == merged[contacts[:, 1], None, :], axis=(1, 2))
    predicted = np.count_nonzero(apart) / len(probe) * len(merged) / 2
    if predicted > MAX_SELF_INTERSECTION_PAIRS:
        out["self_intersections_skipped"] = (f"~{predicted:.3g} face pairs predicted from {len(probe)} probed faces, "
                                             f"over the limit of {MAX_SELF_INTERSECTION_PAIRS:,} of the search")
        return out
    pairs = igl.predicates.find_self_intersections(positions, merged, False)[1].reshape(-1, 2)
    out.update(self_intersecting_pairs=int(len(pairs)), self_intersecting_faces=int(len(np.unique(face_ids[pairs]))))
    return out
