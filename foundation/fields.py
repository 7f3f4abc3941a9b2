"""Exact fields of a triangle mesh in the canonical frame.

Everything here is ground truth: training targets for the point and segment fields, and the
*oracle* fields the extractors read on the grid. Inputs are numpy arrays in the canonical frame
([-1, 1]^3): vertices float64 (n, 3), faces int64 (m, 3). Meshes may be soups, open or
non-manifold; nothing assumes watertightness.

Definitions (p a point, M the mesh)
-----------------------------------
* winding number w(p): generalised winding number, sum over triangles of the signed solid angle /
  (4 pi). Integer off the surface of a closed surface (+1 inside an outward-oriented one), continuous
  and fractional for open meshes. Evaluated exactly, by libigl's hierarchical ``winding_number`` or
  by crossing counts (below); never by the fast-winding-number approximation (not exact; its
  error on ABC meshes: docs/PERFORMANCE.md, section 5).
* occupancy: inside iff |w| > 0.5.
* UDF d(p) = min_{x in M} |p - x| (libigl AABB ``squared_distance``); gradient (p - c) / |p - c| with
  c the closest point (zero where d = 0).
* SDF = d * sign(0.5 - |w|): negative inside. On open meshes the |w| = 0.5 level set spans holes
  ("membranes"): expected behaviour of signed fields, not patched.
* segment field of (u, v): first hit of the ray u + t (v - u), 0 <= t <= 1 (so tau = t in units of
  |v - u|); o = hit, s = 1 - tau (hit point s u + (1 - s) v), normal = unit normal of the hit
  triangle (sign irrelevant). Zero-length segments miss.
* orthogonal distances (UODF) of p: for each axis a, the distance along the line p + t e_a to the
  nearest surface point on it in either direction, min(t+, t-) (t+ the first hit of the ray
  towards +e_a, t- towards -e_a), +inf where the line hits nothing; and the side of that hit (+1
  towards +e_a, -1 towards -e_a, ties -1, 0 for no hit).

Grid conventions (foundation.grid)
--------------------------------
* Grid edges (:meth:`ExactFields.grid_edges`): no ray per edge. For every axis the 3 N^2 grid lines
  are intersected with all triangles at once by rasterising each triangle's projection onto the
  plane across the axis (:func:`foundation.raster.grid_line_hits`: exact float64 2D edge functions,
  a vectorised segment-triangle test). Convention: triangles are *closed* (a line through a triangle's edge or
  vertex hits it); a line parallel to a triangle's plane (zero projected area) never hits it, so a
  line lying inside a face only hits the faces it crosses. A hit exactly at a grid point (within
  1e-9 h) belongs to both edges sharing that point (tau = 1 on the lower edge, tau = 0 on the upper).
  Per edge the hit with the smallest tau is kept; ties (hits within 1e-9 in tau, e.g. the two
  triangles of a shared mesh edge) go to the smallest face index. Duplicates therefore never matter.
* Grid orthogonal distances (:meth:`ExactFields.grid_orthogonal_distances`): the grid points lie on
  the grid lines, so the hits along axis a are those of :func:`foundation.raster.grid_line_hits`
  (rule 'closed'), exact in float64; a hit within 1e-10 of a grid point may count as the other side.
* Grid occupancy / SDF sign: for a *closed chain* (every undirected edge, after welding exactly equal
  positions, is used equally often in both directions: closed meshes and soups of closed meshes,
  even self-intersecting) w is an integer and is counted exactly along the x grid lines: w(p) = sum
  over crossings at x < p_x of -sign(n_x) (n the face normal). Crossings use a watertight tie rule
  (symbolic perturbation of the line by (0, +eps, +eps^2) in (y, z)), so a line through a mesh edge
  or vertex is counted once. For other meshes the boundary is closed by a cone C from one apex over
  the boundary edges; then w_M = w_(M+C) - w_C, the first counted along lines, the second evaluated
  exactly with libigl on the small cone mesh. Grid points exactly on the surface get one side by the
  tie rule (their SDF is 0 anyway).
* Narrow band: grid distances are exact (libigl) where d < band and *clamped* to ``band`` elsewhere
  (the true distance there is >= band): udf = band, sdf = +-band, gradient = 0. Default band
  max(0.1, 2h): 0.1 is the SDF/UDF loss clamp and MeshUDF reads gradients only where
  d < 2h. Signs are exact everywhere (they do not use the band).
"""

from __future__ import annotations

import igl
import numpy as np

from foundation.grid import EdgeField, axis_coords, ijk_axis_to_edge_index, num_edges, spacing
from foundation.raster import closed_chain_winding_number, grid_line_hits

#: Version of the field definitions; part of every cache key of :mod:`foundation.field_cache`
#: (bump when a convention changes).
FIELDS_VERSION = "fields-v1"

#: Points per libigl call (bounds libigl's peak memory).
CHUNK = 1 << 20

#: Tolerance, in units of h, for a hit to count as lying at a grid point / edge end.
TAU_TOL = 1e-9

GRID_KINDS = ("occupancy", "sdf", "udf")


def default_band(N: int) -> float:
    """Narrow-band half width for grid distances: max(0.1, 2h) in canonical units."""
    return max(0.1, 2.0 * spacing(N))


def _as_points(points, what="points") -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{what} must have shape (P, 3), got {p.shape}")
    return np.ascontiguousarray(p)


def _unit(vectors: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return np.divide(vectors, n, out=np.zeros_like(vectors), where=n > 0)


class ExactFields:
    """Exact fields of one triangle mesh; acceleration structures are built once, on first use.

    Parameters
    ----------
    vertices : (n, 3) float64, canonical frame.
    faces : (m, 3) int64.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        V = np.asarray(vertices, dtype=np.float64)
        F = np.asarray(faces)
        if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
            raise ValueError(f"vertices must have shape (n, 3) with n > 0, got {V.shape}")
        if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
            raise ValueError(f"faces must have shape (m, 3) with m > 0, got {F.shape}")
        if F.min() < 0 or F.max() >= len(V):
            raise ValueError(f"face indices out of range [0, {len(V)})")
        if not np.all(np.isfinite(V)):
            raise ValueError("vertices contain NaN or infinite coordinates")
        self.vertices = np.ascontiguousarray(V)
        self.faces = np.ascontiguousarray(F, dtype=np.int64)
        self._aabb = None
        self._embree = None
        self._normals = None
        self._weld = None
        self._closure = None
        self._band_cache: dict = {}
        self._occ_cache: dict = {}

    # ------------------------------------------------------------------ lazy structures
    @property
    def face_normals(self) -> np.ndarray:
        """(m, 3) float64 unit face normals (b - a) x (c - a) / |...|; 0 for degenerate faces."""
        if self._normals is None:
            t = self.vertices[self.faces]
            self._normals = _unit(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]))
        return self._normals

    def _aabb_tree(self):
        if self._aabb is None:
            self._aabb = igl.AABB()
            self._aabb.init(self.vertices, self.faces)
        return self._aabb

    def _embree_scene(self):
        if self._embree is None:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh

            scene = rtcore_scene.EmbreeScene()
            TriangleMesh(scene=scene, vertices=self.vertices.astype(np.float32),
                         indices=self.faces.astype(np.int32))
            self._embree = scene
        return self._embree

    def _welded(self):
        """(welded vertices (k, 3), faces in welded ids (m, 3)): exact-position weld, no tolerance."""
        if self._weld is None:
            Vw, inv = np.unique(self.vertices, axis=0, return_inverse=True)
            self._weld = (Vw, inv.reshape(-1)[self.faces])
        return self._weld

    def boundary_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Net boundary of the mesh as a 2-chain, after the exact weld.

        Returns (edges (b, 2) welded vertex ids lo < hi, net (b,) int): the number of times lo->hi
        is used minus hi->lo, only where non-zero. Empty for a closed chain.
        """
        _, Fw = self._welded()
        a = Fw.reshape(-1)
        b = np.roll(Fw, -1, axis=1).reshape(-1)
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        sign = np.where(a < b, 1, -1)
        keep = lo != hi
        key = lo[keep] * np.int64(len(self._weld[0])) + hi[keep]
        uniq, inv = np.unique(key, return_inverse=True)
        net = np.bincount(inv, weights=sign[keep], minlength=len(uniq)).astype(np.int64)
        nz = net != 0
        k = len(self._weld[0])
        return np.stack([uniq[nz] // k, uniq[nz] % k], axis=1), net[nz]

    @property
    def is_closed_chain(self) -> bool:
        """True when the winding number is integer off the surface (no net boundary edge)."""
        return len(self.boundary_edges()[0]) == 0

    def _cone_closure(self):
        """(cone vertices, cone faces, all vertices, all faces) with M + C a closed chain."""
        if self._closure is None:
            Vw, Fw = self._welded()
            edges, net = self.boundary_edges()
            if len(edges) == 0:
                self._closure = (None, None, Vw, Fw)
            else:
                used = np.unique(edges)
                # apex: centroid of the boundary, nudged off grid planes by an irrational offset
                apex = Vw[used].mean(axis=0) + 1e-3 * np.array([np.pi / 7, np.e / 11, np.sqrt(2) / 5])
                rep = np.repeat(np.arange(len(edges)), np.abs(net))
                lo, hi = edges[rep, 0], edges[rep, 1]
                pos = net[rep] > 0
                # lo->hi used net n > 0 times: add (apex, hi, lo), whose boundary holds hi->lo
                second = np.where(pos, hi, lo)
                third = np.where(pos, lo, hi)
                apex_id = len(Vw)
                Fc = np.stack([np.full(len(rep), apex_id), second, third], axis=1)
                Vall = np.vstack([Vw, apex[None]])
                cone_used, cone_inv = np.unique(Fc, return_inverse=True)
                self._closure = (Vall[cone_used], cone_inv.reshape(-1, 3).astype(np.int64),
                                 Vall, np.vstack([Fw, Fc]))
        return self._closure

    # ------------------------------------------------------------------ point fields
    def winding_number(self, points: np.ndarray, method: str = "auto") -> np.ndarray:
        """Generalised winding number w(p), (P,) float64, exact.

        method 'auto' (default): 'crossings' for >= 100,000 points, else 'libigl' (both exact; the
            crossing count has a fixed set-up cost and its cost grows with how many triangles overlap
            in the x projection, so it pays off for many points only).
        method 'crossings': integer signed crossing count along -x rays of the mesh closed
            by its boundary cone, minus the cone's own winding number (libigl, only for open meshes):
            w_M = w_(M+C) - w_C (module docstring). Exact off the surface; a point exactly on the
            surface gets one side (libigl would give the average). Much faster than 'libigl' on CAD
            meshes for many points (docs/PERFORMANCE.md, section 5).
        method 'libigl': libigl's exact hierarchical ``winding_number`` (not the fast-winding-number
            approximation, which is not exact), in chunks of ``CHUNK``.
        """
        P = _as_points(points)
        if method == "auto":
            method = "crossings" if len(P) >= 100_000 else "libigl"
        if method == "libigl":
            out = np.empty(len(P))
            for i in range(0, len(P), CHUNK):
                out[i:i + CHUNK] = igl.winding_number(self.vertices, self.faces, P[i:i + CHUNK])
            return out
        if method != "crossings":
            raise ValueError(f"unknown winding number method '{method}' (use 'crossings' or 'libigl')")
        cone_V, cone_F, Vall, Fall = self._cone_closure()
        out = np.empty(len(P))
        for i in range(0, len(P), CHUNK):
            out[i:i + CHUNK] = closed_chain_winding_number(Vall, Fall, P[i:i + CHUNK])
            if cone_F is not None:
                out[i:i + CHUNK] -= igl.winding_number(cone_V, cone_F, P[i:i + CHUNK])
        return out

    def occupancy(self, points: np.ndarray) -> np.ndarray:
        """Inside iff |w(p)| > 0.5, (P,) bool."""
        return np.abs(self.winding_number(points)) > 0.5

    def udf(self, points: np.ndarray, return_grad: bool = False):
        """Unsigned distance d(p) (P,) float64 via libigl AABB squared distance.

        With ``return_grad`` also the exact unit gradient (p - c) / |p - c| (P, 3) float64, c the
        closest surface point; zero where d = 0.
        """
        P = _as_points(points)
        tree = self._aabb_tree()
        d = np.empty(len(P))
        grad = np.zeros((len(P), 3)) if return_grad else None
        for i in range(0, len(P), CHUNK):
            sq, _, C = tree.squared_distance(self.vertices, self.faces, P[i:i + CHUNK])
            d[i:i + CHUNK] = np.sqrt(np.maximum(sq, 0.0))
            if return_grad:
                grad[i:i + CHUNK] = _unit(P[i:i + CHUNK] - C)
        return (d, grad) if return_grad else d

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """Signed distance d(p) * sign(0.5 - |w(p)|), (P,) float64: negative inside."""
        P = _as_points(points)
        d = self.udf(P)
        return np.where(self.occupancy(P), -d, d)

    def segments(self, u: np.ndarray, v: np.ndarray):
        """Line segment field of segments (u, v), each (S, 3) (embree, float32).

        The ray u + t (v - u) is cast with 0 <= t <= 1 (embree tfar = 1, so t is tau directly).
        Returns (hit (S,) bool, s (S,) float32 = 1 - tau, normal (S, 3) float32 unit face normal);
        s and normal are 0 on misses. Zero-length segments miss.
        """
        u = _as_points(u, "u")
        v = _as_points(v, "v")
        if u.shape != v.shape:
            raise ValueError(f"u and v must have the same shape, got {u.shape} and {v.shape}")
        S = len(u)
        hit = np.zeros(S, dtype=bool)
        s = np.zeros(S, dtype=np.float32)
        normal = np.zeros((S, 3), dtype=np.float32)
        d = (v - u).astype(np.float32)
        live = np.flatnonzero(np.any(d != 0, axis=1))
        if len(live) == 0:
            return hit, s, normal
        scene = self._embree_scene()
        step = 4 * CHUNK
        for i in range(0, len(live), step):
            ids = live[i:i + step]
            res = scene.run(np.ascontiguousarray(u[ids], dtype=np.float32), np.ascontiguousarray(d[ids]),
                            dists=np.ones(len(ids), dtype=np.float32), output=1)
            prim = res["primID"]
            ok = prim >= 0
            sel = ids[ok]
            hit[sel] = True
            s[sel] = 1.0 - np.clip(res["tfar"][ok], 0.0, 1.0)
            normal[sel] = self.face_normals[prim[ok]].astype(np.float32)
        return hit, s, normal

    def orthogonal_distances(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Orthogonal distances (UODF, module docstring) at arbitrary points (embree, float32 rays).

        Six ray casts per point (+-e_x, +-e_y, +-e_z, from the point, unbounded). Returns (distance
        (P, 3) float64, +inf where the axis line hits nothing; side (P, 3) int8: +1 if the nearest
        hit lies towards +e_a, -1 towards -e_a (also on ties), 0 for no hit).
        """
        P = _as_points(points)
        forward = np.full((len(P), 3), np.inf)
        backward = np.full((len(P), 3), np.inf)
        scene = self._embree_scene()
        origins = P.astype(np.float32)
        step = 4 * CHUNK
        for axis in range(3):
            for sign, out in ((1.0, forward), (-1.0, backward)):
                direction = np.zeros((len(P), 3), dtype=np.float32)
                direction[:, axis] = sign
                for i in range(0, len(P), step):
                    res = scene.run(np.ascontiguousarray(origins[i:i + step]),
                                    np.ascontiguousarray(direction[i:i + step]), output=1)
                    hit = res["primID"] >= 0
                    out[i:i + step, axis] = np.where(hit, res["tfar"], np.inf)
        return _nearest_side(forward, backward)

    # ------------------------------------------------------------------ grid fields
    def grid_edges(self, N: int) -> EdgeField:
        """Segment field of all 3 (N - 1) N^2 grid edges (flat edge order of foundation.grid).

        Per edge: the hit nearest the lower endpoint u (first hit from u towards v), s = 1 - tau and
        that triangle's unit normal. Computed from all line/triangle intersections of the 3 N^2 grid
        lines (see the module docstring for the conventions at edges, vertices and grid points).
        """
        h = spacing(N)
        E = num_edges(N)
        hit = np.zeros(E, dtype=bool)
        s = np.zeros(E, dtype=np.float32)
        normal = np.zeros((E, 3), dtype=np.float32)
        Vw, Fw = self._welded()
        for axis in range(3):
            j, k, x, face, _ = grid_line_hits(Vw, Fw, N, axis, rule="closed")
            if len(x) == 0:
                continue
            r = (x + 1.0) / h  # position along the line in index units
            base = np.floor(r).astype(np.int64)
            cand_e = np.concatenate([base - 1, base, base + 1])
            cand_tau = np.concatenate([r - base + 1, r - base, r - base - 1])
            cand_i = np.tile(np.arange(len(x)), 3)
            ok = (cand_e >= 0) & (cand_e <= N - 2) & (cand_tau >= -TAU_TOL) & (cand_tau <= 1 + TAU_TOL)
            e_line, tau, i = cand_e[ok], np.clip(cand_tau[ok], 0.0, 1.0), cand_i[ok]
            ijk = np.empty((len(i), 3), dtype=np.int64)  # lower endpoint of each candidate edge
            others = [a for a in range(3) if a != axis]
            ijk[:, axis], ijk[:, others[0]], ijk[:, others[1]] = e_line, j[i], k[i]
            eid = ijk_axis_to_edge_index(N, ijk, axis)
            f = face[i]
            # smallest tau per edge; ties within TAU_TOL go to the smallest face index
            order = np.lexsort((tau, eid))
            eid, tau, f = eid[order], tau[order], f[order]
            first = np.r_[True, eid[1:] != eid[:-1]]
            group = np.cumsum(first) - 1
            tau_min = tau[first][group]
            near = tau <= tau_min + TAU_TOL
            eid, tau, f = eid[near], tau[near], f[near]
            order = np.lexsort((f, eid))
            eid, tau, f = eid[order], tau[order], f[order]
            first = np.r_[True, eid[1:] != eid[:-1]]
            eid, tau, f = eid[first], tau[first], f[first]
            hit[eid] = True
            s[eid] = (1.0 - tau).astype(np.float32)
            normal[eid] = self.face_normals[f].astype(np.float32)
        return EdgeField(N=N, hit=hit, s=s, normal=normal)

    def grid_orthogonal_distances(self, N: int) -> tuple[np.ndarray, np.ndarray]:
        """Orthogonal distances (UODF) on the grid points, exact (module docstring).

        Returns (distance (N, N, N, 3) float64, +inf where the grid line hits nothing; side
        (N, N, N, 3) int8 as in :meth:`orthogonal_distances`), 'ij' order, last axis the axis a.
        """
        forward = np.full((N, N, N, 3), np.inf)
        backward = np.full((N, N, N, 3), np.inf)
        Vw, Fw = self._welded()
        for axis in range(3):
            j, k, x, _, _ = grid_line_hits(Vw, Fw, N, axis, rule="closed")
            fwd, bwd = _nearest_hits_on_lines(j * N + k, x, N)  # (N^2 lines (j, k), N points along axis)
            forward[..., axis] = np.moveaxis(fwd.reshape(N, N, N), 2, axis)
            backward[..., axis] = np.moveaxis(bwd.reshape(N, N, N), 2, axis)
        return _nearest_side(forward, backward)

    def grid_winding_number(self, N: int) -> np.ndarray:
        """Winding number on the grid points, (N, N, N) float64 ('ij' order).

        Closed chains: exact integer counts along x grid lines. Otherwise: integer counts of the
        mesh closed by a boundary cone C, minus w_C evaluated by libigl (see module docstring).
        """
        cone_V, cone_F, Vall, Fall = self._cone_closure()
        j, k, x, face, sign = grid_line_hits(Vall, Fall, N, 0, rule="watertight")
        coords = axis_coords(N)
        # a crossing at x contributes -sign(n_x) to every grid point with coordinate > x
        start = np.searchsorted(coords, x, side="right")
        delta = np.zeros((N, N, N + 1), dtype=np.int64)  # [j, k, i]
        np.add.at(delta, (j, k, start), -sign)
        w = np.cumsum(delta[:, :, :N], axis=2).transpose(2, 0, 1).astype(np.float64)  # -> [i, j, k]
        if cone_F is not None:
            for i0, i1, P in _grid_slabs(N):
                w[i0:i1] -= igl.winding_number(cone_V, cone_F, P).reshape(i1 - i0, N, N)
        return w

    def grid_occupancy(self, N: int) -> np.ndarray:
        """|w| > 0.5 on the grid, (N, N, N) bool."""
        if N not in self._occ_cache:
            self._occ_cache = {N: np.abs(self.grid_winding_number(N)) > 0.5}
        return self._occ_cache[N]

    def _grid_band(self, N: int, band: float):
        """(d (N, N, N) float64, NaN where d >= band; grad (N, N, N, 3) float32, 0 there) via libigl.

        libigl's signed_distance with an upper bound returns NaN beyond it cheaply (narrow band).
        Memoised for the last (N, band) so sdf and udf_grad share one pass.
        """
        key = (N, float(band))
        if key not in self._band_cache:
            d = np.empty((N, N, N))
            grad = np.zeros((N, N, N, 3), dtype=np.float32)
            unsigned = igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_UNSIGNED
            for i0, i1, P in _grid_slabs(N):
                S, _, C, _ = igl.signed_distance(P, self.vertices, self.faces, unsigned, -float(band), float(band))
                S = np.abs(S)
                near = S < band  # False for NaN
                g = np.zeros_like(P)
                g[near] = _unit(P[near] - C[near])
                d[i0:i1] = np.where(near, S, np.nan).reshape(i1 - i0, N, N)
                grad[i0:i1] = g.reshape(i1 - i0, N, N, 3)
            self._band_cache = {key: (d, grad)}
        return self._band_cache[key]

    def grid_udf_with_grad(self, N: int, band: float | None = None):
        """Grid UDF and its exact unit gradient in a narrow band.

        Returns (d (N, N, N) float32, grad (N, N, N, 3) float32). d is exact where d < band and
        clamped to ``band`` elsewhere (true distance >= band); grad = (p - c)/|p - c| where
        0 < d < band, 0 elsewhere. ``band`` defaults to :func:`default_band` (N).
        """
        band = default_band(N) if band is None else float(band)
        d, grad = self._grid_band(N, band)
        return np.where(np.isfinite(d), d, band).astype(np.float32), grad.copy()

    def grid_scalar(self, N: int, kind: str, band: float | None = None) -> np.ndarray:
        """A scalar field on the grid points, (N, N, N) float32, 'ij' order (foundation.grid).

        kind 'occupancy' (1 inside, 0 outside; exact everywhere), 'udf' (exact where d < band,
        else band) or 'sdf' (same magnitude, negative inside; sign exact everywhere).
        """
        if kind not in GRID_KINDS:
            raise ValueError(f"unknown grid field kind '{kind}' (use one of {', '.join(GRID_KINDS)})")
        if kind == "occupancy":
            return self.grid_occupancy(N).astype(np.float32)
        band = default_band(N) if band is None else float(band)
        d, _ = self._grid_band(N, band)
        d = np.where(np.isfinite(d), d, band).astype(np.float32)
        if kind == "udf":
            return d
        return np.where(self.grid_occupancy(N), -d, d).astype(np.float32)


def _grid_slabs(N: int):
    """Yield (i0, i1, points (k, 3) float64) for slabs of x indices holding <= ~CHUNK grid points."""
    c = axis_coords(N)
    step = max(1, CHUNK // (N * N))
    for i0 in range(0, N, step):
        i1 = min(N, i0 + step)
        yield i0, i1, np.stack(np.meshgrid(c[i0:i1], c, c, indexing="ij"), axis=-1).reshape(-1, 3)


def _nearest_side(forward: np.ndarray, backward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min(forward, backward), side: +1 where forward < backward, -1 where backward <= forward and
    finite, 0 where both are +inf), from the distances to the first hit each way along each axis."""
    side = np.where(forward < backward, 1, np.where(np.isfinite(backward), -1, 0)).astype(np.int8)
    return np.minimum(forward, backward), side


def _nearest_hits_on_lines(line: np.ndarray, x: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Distances from the N grid points of each of N^2 lines to the nearest hit on it each way.

    ``line`` (H,) line ids, ``x`` (H,) hit coordinates along the lines. Returns (forward, backward),
    each (N^2, N) float64: x_hit - c for the first hit with x_hit >= c, c - x_hit for the last
    with x_hit <= c (c the point's coordinate, :func:`foundation.grid.axis_coords`), +inf if none.
    Points and hits are ordered together by the key line * span + x (span > the range of x).
    """
    coords = axis_coords(N)
    forward = np.full((N * N, N), np.inf)
    backward = np.full((N * N, N), np.inf)
    if len(x) == 0:
        return forward, backward
    span = 2.0 * (max(np.abs(x).max(), 1.0) + 1.0)
    order = np.lexsort((x, line))
    line, x = line[order], x[order]
    hit_key = line * span + x
    point_line = np.repeat(np.arange(N * N), N)
    point_c = np.tile(coords, N * N)
    point_key = point_line * span + point_c
    after = np.searchsorted(hit_key, point_key, side="left")
    before = np.searchsorted(hit_key, point_key, side="right") - 1
    ok_after = (after < len(x)) & (line[np.minimum(after, len(x) - 1)] == point_line)
    ok_before = (before >= 0) & (line[np.maximum(before, 0)] == point_line)
    forward.reshape(-1)[ok_after] = np.maximum(x[after[ok_after]] - point_c[ok_after], 0.0)
    backward.reshape(-1)[ok_before] = np.maximum(point_c[ok_before] - x[before[ok_before]], 0.0)
    return forward, backward
