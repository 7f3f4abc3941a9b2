"""Named, graded corruptions of an input point cloud: the project's one owner of the corruption ladder.

Seventeen names (:data:`CORRUPTIONS`, in this order):

* ``uniform`` -- area-uniform samples of the mesh (:func:`foundation.surface.sample_surface`), as the
  point-cloud task has always drawn them (the same points for the same generator);
* ``scan`` -- a clean virtual range scan (:func:`foundation.scanner.scan_cloud`; setup in
  ``LEVELS["scan"]``: 10 sensors on a Fibonacci sphere about the origin at 3.0 canonical units,
  grazing hits beyond 85 deg dropped);
* ``<kind>-<level>``, kind in ``noise, outliers, missing, density, misalign`` and level in 1, 2, 3:
  the clean scan, then that corruption, with the exact parameters of :data:`LEVELS`.

Sizes in :data:`LEVELS` are fractions of the largest side of the mesh's bounding box (times 1.99 for
canonical units: the canonical frame of :mod:`datasets.io` has largest side 1.99). Anchors:

* noise -- SCUTSurface (Huang et al., "Surface Reconstruction from Point Clouds: A Survey and a
  Benchmark", TPAMI 2024) noise levels 0.001 / 0.003 / 0.006, applied as Gaussian range noise along
  each point's line of sight. dsr-benchmark (Sulzer et al., "A Survey and Benchmark of Automatic
  Surface Reconstruction from Point Clouds") uses 0.005, between our levels 2 and 3.
* outliers -- 1% / 5% / 10% of the cloud replaced by points uniform in the bounding box enlarged
  by 0.25% of its side each way (in the canonical frame: [-1, 1]^3 to 2.5e-5, the grid cube);
  dsr-benchmark's "outliers 0.1" is our level 3. The total stays ``n``.
* missing -- SCUTSurface's missing data by dropped viewpoints: of the 10 sensors, the 2 / 4 / 6 whose
  directions are nearest a seeded random direction are dropped, so whole sides go unobserved; the
  remaining sensors are scanned to ``n`` points.
* density -- non-uniform density by per-region thinning: a keep probability falling linearly along
  a seeded random direction from 1 (the mesh's lowest extent along it) to 0.5 / 0.2 / 0.05 (its
  highest), then refilled to ``n`` from a larger scan (see :func:`input_cloud`).
* misalign -- per-sensor rigid registration error, SCUTSurface's 0.005-0.02 shift and 0.5-2 deg
  rotation: each sensor's points are rotated about a random axis through the origin by
  0.5 / 1 / 2 deg and shifted by 0.005 / 0.01 / 0.02 in a random direction.

Monotone in level by construction: the random draws of a kind do not depend on the level (the same
scan, the same standard normal draws, the same outlier rows and positions, the same side, the same
thinning draws, the same axes and directions), and the level only scales them. So for one
generator state, level 3's outliers are a superset of level 2's, its dropped sensors a superset, its
kept set under thinning a subset, and its noise and misalignment the same draws scaled up.

Everything is a deterministic function of the generator's state: the same seed gives the same cloud
bit for bit. The sensors are about the origin: the mesh should be in the canonical frame (bounding
box centred at the origin).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from foundation.scanner import Scan, scan_cloud, sphere_sensors
from foundation.seeding import job_streams
from foundation.surface import sample_surface

__all__ = ["Corruption", "CORRUPTIONS", "KINDS", "LEVELS", "Cloud", "parse_corruption", "input_cloud",
           "UniformSampling", "ScanSetup", "NoiseLevel", "OutlierLevel", "MissingLevel", "DensityLevel",
           "MisalignLevel"]

#: The graded kinds, each with levels 1, 2, 3.
KINDS = ("noise", "outliers", "missing", "density", "misalign")
_LEVELS = (1, 2, 3)
#: Every corruption name, in the fixed order of the tables.
CORRUPTIONS: tuple[str, ...] = ("uniform", "scan") + tuple(f"{k}-{lv}" for k in KINDS for lv in _LEVELS)


# ------------------------------------------------------------------------------------- the levels
@dataclass(frozen=True)
class UniformSampling:
    """``uniform``: :func:`foundation.surface.sample_surface` (no parameters)."""


@dataclass(frozen=True)
class ScanSetup:
    """The virtual scanner every scan-based corruption starts from.

    sensors: number of sensors (Fibonacci sphere, :func:`foundation.scanner.sphere_sensors`);
    distance: their distance from the origin, as a fraction of the largest side (3.0 / 1.99: 3.0
    canonical units); grazing_dropout_deg: hits beyond this angle to the normal are dropped.
    """

    sensors: int
    distance: float
    grazing_dropout_deg: float


@dataclass(frozen=True)
class NoiseLevel:
    """sigma: standard deviation of the Gaussian range noise (fraction of the largest side)."""

    sigma: float


@dataclass(frozen=True)
class OutlierLevel:
    """fraction: share of the cloud's points replaced by outliers, uniform in the bounding box
    enlarged by ``margin`` (fraction of the largest side) on every side."""

    fraction: float
    margin: float


@dataclass(frozen=True)
class MissingLevel:
    """dropped: number of sensors dropped (those whose directions are nearest the seeded side)."""

    dropped: int


@dataclass(frozen=True)
class DensityLevel:
    """min_keep: keep probability at the thinned end (1 at the other, linear in between);
    oversample: the scan thinned has ``ceil(oversample * n)`` points (the same for every level)."""

    min_keep: float
    oversample: float


@dataclass(frozen=True)
class MisalignLevel:
    """translation: per-sensor shift (fraction of the largest side); rotation_deg: per-sensor rotation
    angle about a random axis through the origin (degrees)."""

    translation: float
    rotation_deg: float


_MARGIN = 0.0025     # outlier box: +-0.25% of the side, i.e. [-1, 1]^3 to 2.5e-5 in the canonical frame
_OVERSAMPLE = 2.5    # density: a scan of 2.5 n thinned at mean keep >= ~0.525 leaves >= ~1.3 n

#: The exact parameters of every corruption (sizes: fractions of the bounding box's largest side).
LEVELS: dict[str, object] = {
    "uniform": UniformSampling(),
    "scan": ScanSetup(sensors=10, distance=3.0 / 1.99, grazing_dropout_deg=85.0),
    # SCUTSurface noise levels; dsr-benchmark's 0.005 lies between levels 2 and 3
    "noise-1": NoiseLevel(sigma=0.001),
    "noise-2": NoiseLevel(sigma=0.003),
    "noise-3": NoiseLevel(sigma=0.006),
    # 1% / 5% / 10% of the points (dsr-benchmark "outliers 0.1" = level 3)
    "outliers-1": OutlierLevel(fraction=0.01, margin=_MARGIN),
    "outliers-2": OutlierLevel(fraction=0.05, margin=_MARGIN),
    "outliers-3": OutlierLevel(fraction=0.10, margin=_MARGIN),
    # SCUTSurface missing data by dropped viewpoints: 2 / 4 / 6 of the 10 sensors
    "missing-1": MissingLevel(dropped=2),
    "missing-2": MissingLevel(dropped=4),
    "missing-3": MissingLevel(dropped=6),
    # per-region thinning down to 0.5 / 0.2 / 0.05
    "density-1": DensityLevel(min_keep=0.5, oversample=_OVERSAMPLE),
    "density-2": DensityLevel(min_keep=0.2, oversample=_OVERSAMPLE),
    "density-3": DensityLevel(min_keep=0.05, oversample=_OVERSAMPLE),
    # SCUTSurface misalignment: 0.005-0.02 shift, 0.5-2 deg rotation
    "misalign-1": MisalignLevel(translation=0.005, rotation_deg=0.5),
    "misalign-2": MisalignLevel(translation=0.01, rotation_deg=1.0),
    "misalign-3": MisalignLevel(translation=0.02, rotation_deg=2.0),
}


# ------------------------------------------------------------------------------------- the names
@dataclass(frozen=True)
class Corruption:
    """One rung of the ladder: ``kind`` (``uniform``, ``scan`` or one of :data:`KINDS`) and ``level``
    (0 for ``uniform`` and ``scan``, else 1, 2 or 3). ``str()`` gives the canonical name."""

    kind: str
    level: int = 0

    def __post_init__(self):
        ok = (self.kind in ("uniform", "scan") and self.level == 0) or (self.kind in KINDS and self.level in _LEVELS)
        if not ok or isinstance(self.level, bool) or not isinstance(self.level, int):
            raise ValueError(f"no corruption kind={self.kind!r} level={self.level!r}; {_known()}")

    @property
    def name(self) -> str:
        return self.kind if self.kind in ("uniform", "scan") else f"{self.kind}-{self.level}"

    def __str__(self) -> str:
        return self.name

    @property
    def parameters(self):
        """This rung's record in :data:`LEVELS`."""
        return LEVELS[self.name]


def _known() -> str:
    return "known corruptions: " + ", ".join(CORRUPTIONS)


def parse_corruption(text: str | Corruption) -> Corruption:
    """The :class:`Corruption` of a canonical name (``"scan"``, ``"noise-2"``, ...).

    Raises ``ValueError`` with one line naming every valid name for anything else.
    """
    if isinstance(text, Corruption):
        return text
    if not isinstance(text, str) or text not in CORRUPTIONS:
        raise ValueError(f"unknown corruption {text!r}; {_known()}")
    if text in ("uniform", "scan"):
        return Corruption(text)
    kind, level = text.rsplit("-", 1)
    return Corruption(kind, int(level))


# ------------------------------------------------------------------------------------- the clouds
@dataclass(frozen=True, eq=False)
class Cloud:
    """An input point cloud and what is known of how it was made.

    Attributes
    ----------
    points : (P, 3) float64
        The cloud, in the mesh's frame and unit.
    sensors : (P, 3) float64 or None
        Position of the sensor that saw each point (None for ``uniform``). An outlier keeps the
        sensor of the point it replaced; a misaligned point keeps its sensor's true position.
    sensor_ids : (P,) int64 or None
        Row of that sensor in ``sensor_layout``.
    outlier_mask : (P,) bool
        True for the points that are outliers (only ``outliers-*`` has any).
    corruption : str
        The canonical name of the corruption.
    sensor_layout : (S, 3) float64 or None
        Every sensor of the scan setup, dropped ones included (None for ``uniform``).
    dropped_sensors : (k,) int64
        Rows of ``sensor_layout`` that were dropped (``missing-*``; else empty).
    direction : (3,) float64 or None
        The seeded unit direction of ``missing-*`` (the unobserved side) and ``density-*`` (the
        thinned end); None otherwise.
    """

    points: np.ndarray
    sensors: np.ndarray | None
    sensor_ids: np.ndarray | None
    outlier_mask: np.ndarray
    corruption: str
    sensor_layout: np.ndarray | None = None
    dropped_sensors: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    direction: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)


def _unit_direction(rng: np.random.Generator) -> np.ndarray:
    """A direction uniform on the unit sphere (3 standard normal draws)."""
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def _count(fraction: float, total: int) -> int:
    """round(fraction * total), halves up."""
    return int(math.floor(fraction * total + 0.5))


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: the rotation by ``angle`` (radians) about the unit ``axis``."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def input_cloud(vertices: np.ndarray, faces: np.ndarray, n: int, corruption: str | Corruption,
                rng: np.random.Generator) -> Cloud:
    """The input cloud of ``n`` points of a mesh under a named corruption (module docstring).

    * ``uniform``: ``sample_surface(vertices, faces, n, rng)[0]``, the very same points.
    * ``scan``: ``scan_cloud`` of ``n`` points with the ``LEVELS["scan"]`` setup (sensors at
      ``distance * side`` from the origin, ``side`` the largest side of the bounding box of the
      faces' vertices).
    * ``noise-L``: the scan, then ``P`` standard normal draws ``z``; each point moves by
      ``sigma_L * side * z`` along its line of sight ``unit(point - sensor)``.
    * ``outliers-L``: the scan, then a permutation of its ``P`` rows and ``round(0.10 P)`` uniform
      positions in the enlarged box (drawn for the top level whatever the level); the first
      ``round(fraction_L * P)`` rows of the permutation take the first as many positions.
    * ``missing-L``: a random direction first (3 normal draws), the ``dropped_L`` sensors with the
      largest ``unit(sensor) . direction`` dropped, then ``scan_cloud`` of ``n`` from the others.
    * ``density-L``: a random direction ``v`` first, then a scan of ``ceil(oversample * n)`` points,
      one uniform draw ``u`` and one priority draw per point; with ``t`` the position along ``v``
      scaled to [0, 1] over the mesh's extent, a point is kept when
      ``u < 1 - (1 - min_keep_L) t``, and of the kept points the ``n`` of lowest priority stay (a
      uniform subset: the refill to ``n``). When fewer than ``n`` survive, all are returned.
    * ``misalign-L``: the scan, then per sensor of the layout a random axis and a random shift
      direction (unit vectors from normal draws); the points of sensor ``s`` become
      ``R_s p + translation_L * side * b_s``, ``R_s`` the rotation by ``rotation_deg_L`` about
      axis ``a_s`` (through the origin).

    Parameters
    ----------
    vertices : (V, 3) array_like
        Vertex positions, canonical frame (bounding box centred at the origin).
    faces : (F, 3) array_like of int
        Triangles.
    n : int
        Number of points.
    corruption : str or Corruption
        A name of :data:`CORRUPTIONS` (``ValueError`` otherwise).
    rng : numpy.random.Generator
        The only source of randomness: the same state gives the same cloud, bit for bit.

    Returns
    -------
    Cloud
        ``n`` points (fewer only when the surface cannot give ``n`` hits, or under strong thinning).
    """
    c = parse_corruption(corruption)
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    n = int(n)
    if c.kind == "uniform":
        points, _ = sample_surface(vertices, faces, n, rng)
        return Cloud(points, None, None, np.zeros(len(points), dtype=bool), c.name)

    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    used = V[np.unique(F)]
    lo, hi = used.min(axis=0), used.max(axis=0)
    side = float(np.max(hi - lo))
    setup: ScanSetup = LEVELS["scan"]
    layout = sphere_sensors(setup.sensors, setup.distance * side)
    params = c.parameters
    direction = None
    dropped = np.zeros(0, dtype=np.int64)

    def scan(count: int, sensor_rows: np.ndarray) -> tuple[Scan, np.ndarray]:
        s = scan_cloud(V, F, count, rng, sensors=layout[sensor_rows], grazing_dropout_deg=setup.grazing_dropout_deg)
        return s, sensor_rows[s.sensor_ids]

    all_rows = np.arange(len(layout), dtype=np.int64)
    if c.kind == "missing":
        direction = _unit_direction(rng)
        nearness = (layout / np.linalg.norm(layout, axis=1, keepdims=True)) @ direction
        order = np.argsort(-nearness, kind="stable")
        dropped = np.sort(order[:params.dropped])
        base, ids = scan(n, np.setdiff1d(all_rows, dropped))
    elif c.kind == "density":
        direction = _unit_direction(rng)
        base, ids = scan(math.ceil(params.oversample * n), all_rows)
        u = rng.random(len(base))
        priority = rng.random(len(base))
        along = used @ direction
        a_lo, a_hi = float(along.min()), float(along.max())
        t = np.clip((base.points @ direction - a_lo) / (a_hi - a_lo), 0.0, 1.0)
        kept = np.flatnonzero(u < 1.0 - (1.0 - params.min_keep) * t)
        if len(kept) > n:
            kept = np.sort(kept[np.argsort(priority[kept], kind="stable")[:n]])
        base, ids = base.subset(kept), ids[kept]
    else:
        base, ids = scan(n, all_rows)

    points = base.points.copy()
    sensors = layout[ids]
    outliers = np.zeros(len(points), dtype=bool)
    P = len(points)
    if c.kind == "noise":
        z = rng.standard_normal(P)
        sight = points - sensors
        sight /= np.linalg.norm(sight, axis=1, keepdims=True)
        points += (params.sigma * side * z)[:, None] * sight
    elif c.kind == "outliers":
        top = LEVELS["outliers-3"]
        order = rng.permutation(P)
        m_top = _count(top.fraction, P)
        box = rng.random((m_top, 3))
        m = _count(params.fraction, P)
        pad = params.margin * side
        rows = order[:m]
        points[rows] = (lo - pad) + box[:m] * ((hi + pad) - (lo - pad))
        outliers[rows] = True
    elif c.kind == "misalign":
        axes = rng.standard_normal((len(layout), 3))
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        shifts = rng.standard_normal((len(layout), 3))
        shifts /= np.linalg.norm(shifts, axis=1, keepdims=True)
        angle = math.radians(params.rotation_deg)
        for s in range(len(layout)):  # a loop over sensors
            rows = ids == s
            R = _rotation(axes[s], angle)
            points[rows] = points[rows] @ R.T + params.translation * side * shifts[s]
    return Cloud(points, sensors, ids, outliers, c.name, sensor_layout=layout, dropped_sensors=dropped,
                 direction=direction)


def input_point_cloud(shape, n: int, noise: float, seed: int,
                      corruption: str | Corruption = "uniform") -> tuple[np.ndarray, np.ndarray | None]:
    """(points (P, 3), sensors (P, 3) or None): the reconstruct task's input cloud of a job. The
    shape's own cloud and sensors (a dataset of point-cloud files), else ``n`` points of the GT
    surface made as ``corruption`` names (:func:`input_cloud`), on the job's sampler stream
    (:func:`foundation.seeding.job_streams` of the shape's content hash and ``seed``: the same cloud
    for every method of a (shape, seed, corruption)); plus Gaussian noise of sigma ``noise``
    (canonical units) from the same stream; no normals."""
    rng = job_streams(shape.content_hash, seed).sampler_rng()
    if shape.points is not None:
        points, sensors = np.asarray(shape.points, dtype=np.float64), shape.sensors
    else:
        cloud = input_cloud(shape.vertices, shape.faces, n, corruption, rng)
        points, sensors = cloud.points, cloud.sensors
    if noise > 0:
        points = points + rng.normal(scale=noise, size=points.shape)
    return np.asarray(points, dtype=np.float64), sensors
