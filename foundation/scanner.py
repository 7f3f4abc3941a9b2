"""A virtual range scanner: point clouds as a set of range sensors would see a triangle mesh.

The project's one owner of "a scan of a mesh". Four functions, arrays in and arrays out:

* :func:`sphere_sensors` -- sensor positions on a sphere about the origin (Fibonacci layout);
* :func:`range_scan` -- the first hits of a regular angular grid of rays from each sensor;
* :func:`scan_cloud` -- a scan of (about) ``n`` points: enough rays, then a uniform subsample;
* :func:`cast_rays` -- the first hits of rays the caller lays out (origins and directions).

Frame and units: the mesh's own (the canonical frame of :mod:`datasets.io` in the benchmark: the
bounding box centred at the origin, largest side 1.99). Every sensor of :func:`range_scan` looks at
the origin.

Ray grid of one sensor ``s`` at distance ``d = |s|`` (:func:`range_scan`): the sensor frame is
``f = -s / d`` (forward, towards the origin), ``u = unit(f x h)`` (right) and ``w = u x f`` (up), with
the helper ``h = e_z``, or ``e_x`` when ``|f_z| >= 0.9``. The mesh lies inside the sphere of radius
``r = max |vertex|`` about the origin (the vertices of the faces), which the sensor sees under the
half-angle ``alpha = asin(r / d)``. With ``k = ceil(sqrt(rays_per_sensor))``, the ``k^2`` rays have
azimuth ``a_i`` and elevation ``e_j`` on the cell-centred grid
``-alpha + (i + 1/2) 2 alpha / k``, ``i = 0 .. k-1`` (the same for ``e_j``), and direction
``cos(e) cos(a) f + cos(e) sin(a) u + sin(e) w`` (a unit vector; angle ``theta`` to ``f`` with
``cos(theta) = cos(e) cos(a)``, so ``|a|, |e| <= theta`` and the grid covers the whole cone of the
bounding sphere). Rays are ordered ``i`` major (``(i, j) -> i k + j``), sensors in their given order.

Intersection: embree (``embreex``, float32) finds the first triangle each ray hits; the point is then
recomputed in float64 as the exact intersection of the float64 ray with that triangle's plane,
``p = s + t d``, ``t = ((a - s) . n) / (d . n)``. Where float32 traversal assigned a hit just outside
its triangle (a ray within ~1e-7 of an edge), the barycentric coordinates of ``p`` are clipped to
the triangle and renormalised, which moves ``p`` by at most that ~1e-7 and puts it on the
triangle. Every clean point thus lies on the surface to float64 rounding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Scan", "sphere_sensors", "range_scan", "scan_cloud", "cast_rays", "DEFAULT_GRAZING_DROPOUT_DEG",
           "DEFAULT_SENSORS", "DEFAULT_DISTANCE"]

#: Hits whose ray makes more than this angle (degrees) with the face normal are dropped by default.
#: A real range sensor loses its return at grazing incidence (the returned power falls like
#: cos(angle) on a Lambertian surface while the footprint stretches like 1 / cos(angle)), and its
#: range error grows like 1 / cos(angle). 85 deg (|cos| < 0.087) removes only the most grazing hits:
#: a stand-in for that loss, not a calibrated sensor model. It also keeps the float64 recomputation
#: well conditioned (the plane intersection's error grows like 1 / |cos|).
DEFAULT_GRAZING_DROPOUT_DEG = 85.0
#: :func:`scan_cloud`'s default sensors: this many on a sphere of radius :data:`DEFAULT_DISTANCE`.
DEFAULT_SENSORS = 10
#: Canonical units: 3.0 is ~1.5 times the canonical box's largest side (1.99) from its centre.
DEFAULT_DISTANCE = 3.0

#: Rays per sensor of :func:`scan_cloud`'s first (pilot) cast.
_PILOT_RAYS = 32 * 32
#: Factor on the rays a hit-fraction estimate asks for, so one more cast usually suffices.
_RAY_MARGIN = 1.1
#: Rays :func:`cast_rays` hands embree at once (bounds the float64 arrays of one batch).
_CAST_CHUNK = 2 ** 20


@dataclass(frozen=True, eq=False)
class Scan:
    """The hits of a scan, one row per point (all arrays have ``P`` rows).

    Attributes
    ----------
    points : (P, 3) float64
        Hit points (with range noise when the scan has any), in the mesh's frame and unit.
    sensors : (P, 3) float64
        Position of the sensor whose ray gave each point.
    sensor_ids : (P,) int64
        Row of that sensor in the ``sensors`` array passed to the scan.
    face_ids : (P,) int64
        The triangle each ray hit.
    ray_cosines : (P,) float64
        ``|cos|`` of the angle between the ray and the hit face's normal (1: head-on, 0: grazing).
    """

    points: np.ndarray
    sensors: np.ndarray
    sensor_ids: np.ndarray
    face_ids: np.ndarray
    ray_cosines: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, rows: np.ndarray) -> "Scan":
        """The scan restricted to ``rows`` (indices or a boolean mask), in that order."""
        return Scan(self.points[rows], self.sensors[rows], self.sensor_ids[rows], self.face_ids[rows],
                    self.ray_cosines[rows])


def sphere_sensors(count: int, distance: float) -> np.ndarray:
    """``count`` sensor positions spread evenly on a sphere about the origin (Fibonacci sphere).

    Sensor ``i`` has height ``z_i = 1 - 2 (i + 1/2) / count`` and longitude ``i * pi (3 - sqrt 5)``
    (the golden angle) on the unit sphere, scaled by ``distance``. Deterministic (no randomness).

    Parameters
    ----------
    count : int
        Number of sensors (>= 1).
    distance : float
        Radius of the sphere (> 0), in the mesh's unit (canonical units in the benchmark).

    Returns
    -------
    (count, 3) float64 ndarray
        Sensor positions, each at ``distance`` from the origin.
    """
    count = int(count)
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    if not (math.isfinite(distance) and distance > 0):
        raise ValueError(f"distance must be finite and > 0, got {distance}")
    i = np.arange(count, dtype=np.float64)
    z = 1.0 - 2.0 * (i + 0.5) / count
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = i * (math.pi * (3.0 - math.sqrt(5.0)))
    return distance * np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


# ---------------------------------------------------------------------------------------- internals
def _mesh_arrays(vertices, faces) -> tuple[np.ndarray, np.ndarray, float]:
    """(vertices (V, 3) float64, faces (F, 3) int64, bounding radius about the origin)."""
    V = np.ascontiguousarray(vertices, dtype=np.float64)
    F = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"vertices must have shape (V, 3), got {V.shape}")
    if len(F) == 0:
        raise ValueError("the mesh has no faces to scan")
    used = V[np.unique(F)]
    if not np.all(np.isfinite(used)):
        raise ValueError("the mesh has non-finite vertices")
    radius = float(np.sqrt(np.max(np.einsum("ij,ij->i", used, used))))
    if not radius > 0:
        raise ValueError("the mesh has no extent (all its vertices at the origin)")
    return V, F, radius


def _embree_scene(V: np.ndarray, F: np.ndarray):
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene=scene, vertices=V.astype(np.float32), indices=F.astype(np.int32))
    return scene


def _as_sensors(sensors) -> np.ndarray:
    S = np.ascontiguousarray(sensors, dtype=np.float64)
    if S.ndim != 2 or S.shape[1] != 3 or len(S) == 0:
        raise ValueError(f"sensors must have shape (S, 3) with S >= 1, got {S.shape}")
    if not np.all(np.isfinite(S)):
        raise ValueError("sensor positions must be finite")
    return S


def _ray_directions(sensor: np.ndarray, radius: float, k: int) -> np.ndarray:
    """The (k^2, 3) float64 unit directions of one sensor's grid (module docstring)."""
    d = float(np.linalg.norm(sensor))
    if not d > radius:
        raise ValueError(f"sensor {sensor.tolist()} lies inside the mesh's bounding sphere (radius "
                         f"{radius:.6g} about the origin): a sensor must be farther than that")
    f = -sensor / d
    helper = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(f, helper)
    u /= np.linalg.norm(u)
    w = np.cross(u, f)
    alpha = math.asin(radius / d)
    angles = -alpha + (np.arange(k, dtype=np.float64) + 0.5) * (2.0 * alpha / k)
    az, el = np.meshgrid(angles, angles, indexing="ij")
    az, el = az.reshape(-1, 1), el.reshape(-1, 1)
    return np.cos(el) * np.cos(az) * f + np.cos(el) * np.sin(az) * u + np.sin(el) * w


def _min_cosine(grazing_dropout_deg) -> float:
    """The least ``|cos|`` of a kept hit for a grazing dropout angle in degrees (None: 0, keep all)."""
    if grazing_dropout_deg is None:
        return 0.0
    if not 0.0 < grazing_dropout_deg <= 90.0:
        raise ValueError(f"grazing_dropout_deg must lie in (0, 90] or be None, got {grazing_dropout_deg}")
    return math.cos(math.radians(grazing_dropout_deg))


def _first_hits(scene, V, F, origins, dirs, min_cos) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The first hit of each ray ``origins[i] + t dirs[i]`` (unit ``dirs``; module docstring):
    (ray rows (h,), points (h, 3), face ids (h,), |cos| (h,)) of the kept hits, in ray order."""
    res = scene.run(np.ascontiguousarray(origins, dtype=np.float32), np.ascontiguousarray(dirs, dtype=np.float32),
                    output=1)
    hit = np.flatnonzero(res["primID"] >= 0)
    face = res["primID"][hit].astype(np.int64)
    s, d = origins[hit], dirs[hit]
    tri = V[F[face]]
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    normal = np.cross(e1, e2)
    nlen = np.linalg.norm(normal, axis=1)
    denom = np.einsum("ij,ij->i", d, normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        cosine = np.abs(denom) / nlen
        t = np.einsum("ij,ij->i", a - s, normal) / denom
    ok = (nlen > 0) & (denom != 0) & np.isfinite(t) & (cosine >= min_cos)
    hit, face, s, d, a, e1, e2, t, cosine = hit[ok], face[ok], s[ok], d[ok], a[ok], e1[ok], e2[ok], t[ok], cosine[ok]
    p = s + t[:, None] * d
    # barycentric coordinates of p; clip into the triangle where float32 traversal was off
    q = p - a
    d00 = np.einsum("ij,ij->i", e1, e1)
    d01 = np.einsum("ij,ij->i", e1, e2)
    d11 = np.einsum("ij,ij->i", e2, e2)
    d20 = np.einsum("ij,ij->i", q, e1)
    d21 = np.einsum("ij,ij->i", q, e2)
    den = d00 * d11 - d01 * d01
    beta = (d11 * d20 - d01 * d21) / den
    gamma = (d00 * d21 - d01 * d20) / den
    bary = np.stack([1.0 - beta - gamma, beta, gamma], axis=1)
    out = np.any(bary < 0.0, axis=1)
    if np.any(out):
        b = np.maximum(bary[out], 0.0)
        b /= b.sum(axis=1, keepdims=True)
        p[out] = a[out] + b[:, 1:2] * e1[out] + b[:, 2:3] * e2[out]
    return hit, p, face, cosine


def _cast(scene, V, F, radius, sensors, rays_per_sensor, grazing_dropout_deg) -> Scan:
    """The clean hits of every sensor's grid (module docstring), grazing hits dropped."""
    rays_per_sensor = int(rays_per_sensor)
    if rays_per_sensor < 1:
        raise ValueError(f"rays_per_sensor must be >= 1, got {rays_per_sensor}")
    k = math.isqrt(rays_per_sensor - 1) + 1  # ceil(sqrt(rays_per_sensor))
    min_cos = _min_cosine(grazing_dropout_deg)
    parts = []
    for sid, s in enumerate(sensors):  # one sensor at a time: arrays of k^2 rays
        dirs = _ray_directions(s, radius, k)
        _, p, face, cosine = _first_hits(scene, V, F, np.broadcast_to(s, dirs.shape), dirs, min_cos)
        parts.append((p, np.full(len(p), sid, dtype=np.int64), face, cosine))
    points = np.concatenate([x[0] for x in parts])
    sensor_ids = np.concatenate([x[1] for x in parts])
    return Scan(points=points, sensors=sensors[sensor_ids], sensor_ids=sensor_ids,
                face_ids=np.concatenate([x[2] for x in parts]), ray_cosines=np.concatenate([x[3] for x in parts]))


def _add_range_noise(scan: Scan, noise: float, rng: np.random.Generator) -> Scan:
    """``len(scan)`` standard normal draws ``z`` (always drawn); points move by ``noise z`` along
    their line of sight ``unit(point - sensor)``."""
    if not (math.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise must be finite and >= 0, got {noise}")
    z = rng.standard_normal(len(scan))
    if noise == 0:
        return scan
    sight = scan.points - scan.sensors
    sight /= np.linalg.norm(sight, axis=1, keepdims=True)
    return Scan(scan.points + (noise * z)[:, None] * sight, scan.sensors, scan.sensor_ids, scan.face_ids,
                scan.ray_cosines)


def _check_rng(rng) -> None:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")


# ---------------------------------------------------------------------------------------- public
def range_scan(vertices: np.ndarray, faces: np.ndarray, sensors: np.ndarray, rays_per_sensor: int,
               rng: np.random.Generator, noise: float = 0.0,
               grazing_dropout_deg: float | None = DEFAULT_GRAZING_DROPOUT_DEG) -> Scan:
    """The first hits of each sensor's regular angular ray grid (module docstring), with range noise.

    Parameters
    ----------
    vertices : (V, 3) array_like
        Vertex positions (any unit; the canonical frame in the benchmark). The mesh is scanned as a
        two-sided surface: face orientation plays no part.
    faces : (F, 3) array_like of int
        Triangles.
    sensors : (S, 3) array_like
        Sensor positions, each farther from the origin than every vertex (else ``ValueError``).
        Every sensor looks at the origin.
    rays_per_sensor : int
        Rays cast per sensor: a grid of ``k x k`` with ``k = ceil(sqrt(rays_per_sensor))`` over the
        bounding sphere's cone (so ``k^2 >= rays_per_sensor`` rays).
    rng : numpy.random.Generator
        Source of the ``P`` standard normal draws of the range noise, drawn even when ``noise`` is 0
        (the grid itself is deterministic): scans at different noise levels from the same generator
        state have the same rays and draws, the noisy points being the clean ones moved by
        ``noise * z`` along their ray.
    noise : float
        Standard deviation of the Gaussian range noise, in the mesh's unit, applied along the line of
        sight (``unit(clean point - sensor)``, the ray direction to ~1e-7).
    grazing_dropout_deg : float or None
        Hits whose ray makes an angle above this (degrees, in (0, 90]) with the face normal are
        dropped; None keeps them all. Default :data:`DEFAULT_GRAZING_DROPOUT_DEG` (85).

    Returns
    -------
    Scan
        One row per kept hit, ordered by sensor, then by ray (``i`` major).
    """
    _check_rng(rng)
    V, F, radius = _mesh_arrays(vertices, faces)
    S = _as_sensors(sensors)
    scene = _embree_scene(V, F)
    return _add_range_noise(_cast(scene, V, F, radius, S, rays_per_sensor, grazing_dropout_deg), noise, rng)


def cast_rays(vertices: np.ndarray, faces: np.ndarray, origins: np.ndarray, directions: np.ndarray,
              grazing_dropout_deg: float | None = DEFAULT_GRAZING_DROPOUT_DEG) -> Scan:
    """The first hit of each of the rays ``origins[i] + t directions[i]``, ``t >= 0`` (arbitrary rays).

    The same intersection as :func:`range_scan` (module docstring: embree's first triangle, the
    point recomputed in float64 on it), for rays the caller lays out (a rotating LiDAR's beams, a
    line of sight to a point). Rays are cast ``2**20`` at a time.

    Parameters
    ----------
    vertices, faces : array_like
        The mesh (as in :func:`range_scan`; any frame and unit, scanned two-sided).
    origins : (R, 3) array_like
        Ray origins, in the mesh's frame.
    directions : (R, 3) array_like
        Ray directions, any non-zero length: each is divided by its norm first.
    grazing_dropout_deg : float or None
        Hits whose ray makes an angle above this (degrees, in (0, 90]) with the face normal are
        dropped; None keeps them all. Default :data:`DEFAULT_GRAZING_DROPOUT_DEG` (85).

    Returns
    -------
    Scan
        One row per kept hit, in ray order: ``sensor_ids`` is the ray's row in ``origins`` (so
        ``sensors = origins[sensor_ids]``), ``points`` the hit (no noise: add it along
        ``directions[sensor_ids]``), its distance from the origin the hit's range.
    """
    V, F, _ = _mesh_arrays(vertices, faces)
    S = np.ascontiguousarray(origins, dtype=np.float64)
    D = np.ascontiguousarray(directions, dtype=np.float64)
    if S.ndim != 2 or S.shape[1] != 3 or D.shape != S.shape:
        raise ValueError(f"origins and directions must both have shape (R, 3), got {S.shape} and {D.shape}")
    if not (np.all(np.isfinite(S)) and np.all(np.isfinite(D))):
        raise ValueError("ray origins and directions must be finite")
    length = np.linalg.norm(D, axis=1)
    if np.any(length == 0):
        raise ValueError("a ray direction is zero")
    D = D / length[:, None]
    min_cos = _min_cosine(grazing_dropout_deg)
    scene = _embree_scene(V, F)
    parts = []
    for start in range(0, len(S), _CAST_CHUNK):
        rows, p, face, cosine = _first_hits(scene, V, F, S[start:start + _CAST_CHUNK], D[start:start + _CAST_CHUNK],
                                            min_cos)
        parts.append((rows + start, p, face, cosine))
    rows = np.concatenate([x[0] for x in parts]) if parts else np.zeros(0, dtype=np.int64)
    points = np.concatenate([x[1] for x in parts]) if parts else np.zeros((0, 3))
    face_ids = np.concatenate([x[2] for x in parts]) if parts else np.zeros(0, dtype=np.int64)
    cosines = np.concatenate([x[3] for x in parts]) if parts else np.zeros(0)
    return Scan(points=points, sensors=S[rows], sensor_ids=rows.astype(np.int64), face_ids=face_ids,
                ray_cosines=cosines)


def scan_cloud(vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator,
               sensors: np.ndarray | None = None, noise: float = 0.0,
               grazing_dropout_deg: float | None = DEFAULT_GRAZING_DROPOUT_DEG, max_rounds: int = 4) -> Scan:
    """A scan of ``n`` points (fewer only when the surface cannot give ``n`` hits).

    Casts the grids of :func:`range_scan` with a growing number of rays: first a pilot of
    ``32 x 32`` rays per sensor; while it has fewer than ``n`` hits, the next cast asks for
    ``1.1 n / (S * hit fraction)`` rays per sensor, the hit fraction measured on the cast before
    (16 times more rays when that cast hit nothing), at most ``max_rounds`` casts in all and
    ``max(1024, 50 n / S)`` rays per sensor. The hits of the last cast are then subsampled
    uniformly at random WITHOUT replacement to ``n`` (kept in scan order), which keeps the
    range- and angle-dependent density of the angular grid. If the last cast still has fewer than
    ``n`` hits, all are returned.

    Parameters
    ----------
    vertices, faces : array_like
        The mesh (as in :func:`range_scan`).
    n : int
        Number of points wanted (>= 0).
    rng : numpy.random.Generator
        Source of the subsample (one ``Generator.choice`` when there are more than ``n`` hits), then
        of the ``len(result)`` standard normal draws of the range noise (drawn even when ``noise``
        is 0). The result is a deterministic function of its state.
    sensors : (S, 3) array_like, optional
        Sensor positions; default ``sphere_sensors(10, 3.0)`` (canonical units).
    noise : float
        Range noise sigma along the line of sight, added after the subsample (:func:`range_scan`).
    grazing_dropout_deg : float or None
        As in :func:`range_scan` (default 85 deg).
    max_rounds : int
        Most casts (pilot included).

    Returns
    -------
    Scan
        ``min(n, hits)`` rows, ordered by sensor, then by ray.
    """
    _check_rng(rng)
    n = int(n)
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    V, F, radius = _mesh_arrays(vertices, faces)
    S = _as_sensors(sphere_sensors(DEFAULT_SENSORS, DEFAULT_DISTANCE) if sensors is None else sensors)
    scene = _embree_scene(V, F)
    max_rays = max(_PILOT_RAYS, math.ceil(50 * n / len(S)))
    rays = _PILOT_RAYS
    for _ in range(max(1, int(max_rounds))):
        scan = _cast(scene, V, F, radius, S, rays, grazing_dropout_deg)
        if len(scan) >= n or rays >= max_rays:
            break
        cast = len(S) * (math.isqrt(rays - 1) + 1) ** 2
        wanted = 16 * rays if len(scan) == 0 else math.ceil(_RAY_MARGIN * n * cast / (len(S) * len(scan)))
        rays = min(max_rays, max(wanted, rays + 1))
    if len(scan) > n:
        scan = scan.subset(np.sort(rng.choice(len(scan), size=n, replace=False)))
    return _add_range_noise(scan, noise, rng)
