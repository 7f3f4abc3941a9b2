"""``pointclouds``: a folder of point-cloud files, each with its GT mesh beside it or alone (the
reconstruct task's inputs given as files instead of sampled from a mesh).

Files: ``<name>.xyz`` (text, one point per line, the first 3 columns; more columns such as normals are
ignored, as the methods get no normals), ``<name>.npy`` ((P, >= 3) float array), ``<name>.ply``
(vertices only: a PLY with faces is a mesh, not a cloud) or ``<name>.npz`` (array ``points``).
A scan carries the position of the sensor that saw each point: vertex properties ``sx sy sz`` of a
PLY, or the array ``sensor_position`` (or ``sensors``), (P, 3), of an NPZ, in the cloud's own frame
(:func:`write_point_cloud` writes both; methods that use sensors get them, the others ignore them). The GT is the mesh file
``<name>.gt.<ext>`` (any mesh extension of :data:`datasets.io.MESH_EXTENSIONS`) in the same folder.
With a GT the canonical frame is the GT's and the cloud moves with the same
transform; the reconstruction is scored against it. A cloud without a GT (a scan) is a shape with
no faces (:attr:`datasets.io.Shape.has_gt` False, kind :data:`datasets.io.NO_GT`) in the canonical
frame of its own points: every method reconstructs it, the mesh and its validity counts are
recorded, and no metric is computed (the tables list it apart). Bad clouds (unreadable, empty, non-
finite, fewer than :data:`MIN_POINTS` points) raise a one-line :class:`datasets.io.MeshError`.
"""

from __future__ import annotations

import io
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from foundation.errors import one_line
from datasets.formats import decode_text, ply_bytes
from datasets.io import (
    MESH_EXTENSIONS,
    NO_GT,
    MeshError,
    Shape,
    canonical_transform,
    classify_topology,
    load_shape,
    quiet_trimesh,
)
from datasets.registry import Dataset, DatasetError, existing_dir, register_dataset

#: Extensions of point-cloud files.
CLOUD_EXTENSIONS = (".xyz", ".npy", ".ply", ".npz")
#: The names of the sensor positions in an NPZ cloud (the first is written) and of their PLY properties.
NPZ_SENSOR_KEYS = ("sensor_position", "sensors")
PLY_SENSOR_PROPERTIES = ("sx", "sy", "sz")
#: Fewest points of a usable cloud (the reconstruct task's --pc-points minimum).
MIN_POINTS = 100
GT_SUFFIX = ".gt"


def read_point_cloud(path: str | Path) -> np.ndarray:
    """(P, 3) float64 points of a cloud file (:func:`read_scan` without its sensors)."""
    return read_scan(path)[0]


def read_scan(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(points (P, 3) float64, sensors (P, 3) float64 or None) of a .xyz/.npy/.ply/.npz cloud file;
    MeshError (one line) when unusable.

    A ``.xyz`` is decoded like the text mesh formats (UTF-8, else Latin-1; binary data refused), a
    ``.npy`` header is checked before its array is read (numbers only, and as many bytes as its shape
    needs, so a header claiming 10^12 points allocates nothing), a ``.ply`` as a mesh's
    (:func:`datasets.formats.ply_bytes`), a ``.npz`` without pickles. Sensors: a PLY's ``sx sy sz``
    vertex properties, an NPZ's ``sensor_position`` (or ``sensors``) array."""
    path = Path(path)
    suffix = path.suffix.lower()
    sensors = None
    try:
        if suffix == ".npy":
            data = _read_npy(path)
        elif suffix == ".npz":
            data, sensors = _read_npz(path)
        elif suffix == ".xyz":
            text = decode_text(path.read_bytes(), "XYZ")
            with warnings.catch_warnings():  # an empty file: numpy warns, we say it in one line below
                warnings.simplefilter("ignore")
                data = np.loadtxt(io.StringIO(text, newline=None), dtype=np.float64, ndmin=2, comments="#")
        elif suffix == ".ply":
            data, sensors = _read_ply(path)
        else:
            raise MeshError(f"not a point-cloud file ({' '.join(CLOUD_EXTENSIONS)})")
    except MeshError as exc:
        raise MeshError(f"{path}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 -- any parser failure is one line naming the file
        raise MeshError(f"{path}: cannot read the point cloud ({one_line(exc)})") from None
    points = _checked_points(path, data)
    if sensors is not None:
        with np.errstate(over="ignore"):
            sensors = np.asarray(sensors, dtype=np.float64)
        if sensors.shape != points.shape:
            raise MeshError(f"{path}: {sensors.shape} sensor positions for {len(points)} points; one (x, y, z) "
                            f"per point is needed")
        if not np.isfinite(sensors).all():
            raise MeshError(f"{path}: sensor positions with NaN/inf coordinates")
    return points, sensors


def _checked_points(path: Path, data) -> np.ndarray:
    with np.errstate(over="ignore"):  # a float128 beyond float64 becomes inf, refused below in one line
        data = np.asarray(data, dtype=np.float64)
    if data.size == 0:
        raise MeshError(f"{path}: 0 points; a cloud needs at least {MIN_POINTS}")
    if data.ndim != 2 or data.shape[1] < 3:
        raise MeshError(f"{path}: expected (P, 3) points, got an array of shape {data.shape}")
    points = data[:, :3]
    if len(points) < MIN_POINTS:
        raise MeshError(f"{path}: {len(points)} points; a cloud needs at least {MIN_POINTS}")
    if not np.isfinite(points).all():
        raise MeshError(f"{path}: {int((~np.isfinite(points).all(axis=1)).sum())} points with NaN/inf coordinates")
    return points


def _read_ply(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    import trimesh

    with quiet_trimesh():
        loaded = trimesh.load(io.BytesIO(ply_bytes(path.read_bytes())), file_type="ply", process=False)
    if len(getattr(loaded, "faces", [])):
        raise MeshError("a mesh with faces, not a point cloud")
    raw = loaded.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    names = getattr(getattr(raw, "dtype", None), "names", None) or ()
    sensors = None
    if all(p in names for p in PLY_SENSOR_PROPERTIES):
        sensors = np.stack([np.asarray(raw[p], dtype=np.float64).reshape(-1) for p in PLY_SENSOR_PROPERTIES], axis=1)
    return np.asarray(loaded.vertices), sensors


def _read_npz(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """The ``points`` and sensor arrays of an NPZ archive, each member's header checked as a .npy's
    (:func:`_read_npy_member`), read without pickles."""
    import zipfile

    if not zipfile.is_zipfile(path):
        raise MeshError("not an NPZ archive (a zip of .npy arrays)")
    with zipfile.ZipFile(path) as archive:
        members = {name[:-4]: name for name in archive.namelist() if name.endswith(".npy")}
        if "points" not in members:
            raise MeshError(f"has no array 'points' (arrays: {', '.join(members) or 'none'})")
        arrays = {}
        for key in ("points", *NPZ_SENSOR_KEYS):
            if key in members:
                info = archive.getinfo(members[key])
                with archive.open(info) as member:
                    arrays[key] = _read_npy_member(member, info.file_size, key)
    sensors = next((arrays[k] for k in NPZ_SENSOR_KEYS if k in arrays), None)
    return arrays["points"], sensors


def write_point_cloud(path: str | Path, points: np.ndarray, sensors: np.ndarray | None = None) -> None:
    """Write a cloud file that :func:`read_scan` reads back bit for bit: ``.ply`` (binary, float64
    ``x y z`` and, with sensors, ``sx sy sz``), ``.npz`` (``points`` and ``sensor_position``),
    ``.npy`` or ``.xyz`` (points only: ValueError with sensors). Written atomically."""
    from foundation.storage import atomic_write

    path = Path(path)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if sensors is not None:
        sensors = np.ascontiguousarray(sensors, dtype=np.float64).reshape(-1, 3)
        if len(sensors) != len(points):
            raise ValueError(f"{len(sensors)} sensor positions for {len(points)} points")
    suffix = path.suffix.lower()
    if suffix in (".npy", ".xyz") and sensors is not None:
        raise ValueError(f"{path}: a {suffix} file holds no sensor positions; write .ply or .npz")
    buffer = io.BytesIO()
    if suffix == ".ply":
        names = ("x", "y", "z") + (PLY_SENSOR_PROPERTIES if sensors is not None else ())
        header = "".join(["ply\nformat binary_little_endian 1.0\n", f"element vertex {len(points)}\n",
                          *(f"property double {n}\n" for n in names), "end_header\n"])
        body = points if sensors is None else np.hstack([points, sensors])
        buffer.write(header.encode("ascii") + body.astype("<f8").tobytes())
    elif suffix == ".npz":
        np.savez(buffer, points=points, **({NPZ_SENSOR_KEYS[0]: sensors} if sensors is not None else {}))
    elif suffix == ".npy":
        np.save(buffer, points)
    elif suffix == ".xyz":
        np.savetxt(buffer, points, fmt="%.17g")
    else:
        raise ValueError(f"{path}: not a point-cloud extension ({' '.join(CLOUD_EXTENSIONS)})")
    atomic_write(path, buffer.getvalue())


def _read_npy(path: Path) -> np.ndarray:
    """The array of a .npy file (:func:`_read_npy_member`)."""
    with open(path, "rb") as f:
        return _read_npy_member(f, path.stat().st_size, "")


def _read_npy_member(f, size: int, name: str) -> np.ndarray:
    """The array of the .npy data ``f`` (``size`` bytes in all) whose header declares integers or
    floats and no more bytes than there are (MeshError otherwise), read without pickles."""
    from numpy.lib import format as npy

    what = f"array '{name}' " if name else ""
    version = npy.read_magic(f)
    if version not in ((1, 0), (2, 0)):  # 3.0: a header with UTF-8 field names, a structured array
        raise MeshError(f"{what}.npy format version {version[0]}.{version[1]} (structured fields); a (P, 3) array "
                        f"of numbers is needed")
    read_header = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
    shape, fortran, dtype = read_header(f)
    available = size - f.tell()
    if dtype.hasobject or dtype.kind not in "iuf":
        raise MeshError(f"{what}holds values of type {dtype}, not coordinates (a .npy of integers or floats is needed)")
    needed = math.prod(shape) * dtype.itemsize
    if needed > available:
        raise MeshError(f"{what}its header declares an array of shape {shape} ({needed:,} bytes) but the file holds "
                        f"{available:,} bytes of data (truncated?)")
    data = np.frombuffer(f.read(needed), dtype=dtype)
    if len(data) * dtype.itemsize != needed:
        raise MeshError(f"{what}holds fewer bytes than its header declares (truncated?)")
    return data.reshape(shape, order="F" if fortran else "C")


def _cloud_files(folder: Path) -> dict[str, Path]:
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in CLOUD_EXTENSIONS and p.is_file()
                   and not p.stem.endswith(GT_SUFFIX))
    return {p.stem: p for p in files}


def gt_path(cloud: Path) -> Path | None:
    """The GT mesh beside a cloud file (``<name>.gt.<mesh ext>``), or None."""
    for ext in MESH_EXTENSIONS:
        candidate = cloud.with_name(cloud.stem + GT_SUFFIX + ext)
        if candidate.is_file():
            return candidate
    return None


def _moved(transform, sensors: np.ndarray | None) -> np.ndarray | None:
    return None if sensors is None else transform.apply(sensors)


@register_dataset("pointclouds")
class PointCloudDataset(Dataset):
    """Point-cloud files, with or without GT meshes (module docstring); shapes named by file stem,
    sorted. Only for ``--task reconstruct``."""

    name = "pointclouds"
    point_clouds = True

    def __init__(self, data_dir=None):
        self.data_dir = existing_dir(data_dir, self.name)
        self._paths = _cloud_files(self.data_dir)
        if not self._paths:
            raise DatasetError(f"dataset 'pointclouds': no point-cloud files ({' '.join(CLOUD_EXTENSIONS)}) in "
                               f"{self.data_dir}")

    def names(self) -> list[str]:
        return list(self._paths)

    def load(self, name: str) -> Shape:
        if name not in self._paths:
            raise self._unknown_shape(name)
        cloud = self._paths[name]
        gt = gt_path(cloud)
        raw, sensors = read_scan(cloud)
        if gt is None:
            try:
                transform = canonical_transform(raw)
            except MeshError as exc:  # all points at one place, or a box beyond float64
                raise MeshError(f"{cloud}: {exc}") from None
            return Shape(name, np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), transform, str(cloud), NO_GT,
                         {}, transform.apply(raw), _moved(transform, sensors))
        mesh = load_shape(gt, name=name, kind="closed")
        return Shape(name, mesh.vertices, mesh.faces, mesh.transform, str(cloud), classify_topology(mesh.faces),
                     {"gt": str(gt)}, mesh.transform.apply(raw), _moved(mesh.transform, sensors))

    def stored_files(self, name: str) -> tuple[tuple[Path, str], ...]:
        if name not in self._paths:
            raise self._unknown_shape(name)
        gt = gt_path(self._paths[name])
        return ((self._paths[name], "cloud"),) + (((gt, "mesh"),) if gt is not None else ())

    def options(self) -> dict[str, Any]:
        return {"data_dir": str(self.data_dir)}
