"""``pointclouds``: a folder of point-cloud files, each with its GT mesh beside it or alone (the
reconstruct task's inputs given as files instead of sampled from a mesh).

Files: ``<name>.xyz`` (text, one point per line, the first 3 columns; more columns such as normals are
ignored, as the methods get no normals), ``<name>.npy`` ((P, >= 3) float array) or ``<name>.ply``
(vertices only: a PLY with faces is a mesh, not a cloud). The GT is the mesh file
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
CLOUD_EXTENSIONS = (".xyz", ".npy", ".ply")
#: Fewest points of a usable cloud (the reconstruct task's --pc-points minimum).
MIN_POINTS = 100
GT_SUFFIX = ".gt"


def read_point_cloud(path: str | Path) -> np.ndarray:
    """(P, 3) float64 points of a .xyz/.npy/.ply cloud file; MeshError (one line) when unusable.

    A ``.xyz`` is decoded like the text mesh formats (UTF-8, else Latin-1; binary data refused), a
    ``.npy`` header is checked before its array is read (numbers only, and as many bytes as its shape
    needs, so a header claiming 10^12 points allocates nothing), a ``.ply`` as a mesh's
    (:func:`datasets.formats.ply_bytes`)."""
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            data = _read_npy(path)
        elif suffix == ".xyz":
            text = decode_text(path.read_bytes(), "XYZ")
            with warnings.catch_warnings():  # an empty file: numpy warns, we say it in one line below
                warnings.simplefilter("ignore")
                data = np.loadtxt(io.StringIO(text, newline=None), dtype=np.float64, ndmin=2, comments="#")
        elif suffix == ".ply":
            import trimesh

            with quiet_trimesh():
                loaded = trimesh.load(io.BytesIO(ply_bytes(path.read_bytes())), file_type="ply", process=False)
            if len(getattr(loaded, "faces", [])):
                raise MeshError("a mesh with faces, not a point cloud")
            data = np.asarray(loaded.vertices)
        else:
            raise MeshError(f"not a point-cloud file ({' '.join(CLOUD_EXTENSIONS)})")
    except MeshError as exc:
        raise MeshError(f"{path}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 -- any parser failure is one line naming the file
        raise MeshError(f"{path}: cannot read the point cloud ({type(exc).__name__}: "
                        f"{str(exc).strip().splitlines()[0] if str(exc).strip() else 'unreadable'})") from None
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


def _read_npy(path: Path) -> np.ndarray:
    """The array of a .npy file whose header declares integers or floats and no more bytes than the
    file holds (MeshError otherwise), read without pickles."""
    from numpy.lib import format as npy

    with open(path, "rb") as f:
        version = npy.read_magic(f)
        if version not in ((1, 0), (2, 0)):  # 3.0: a header with UTF-8 field names, a structured array
            raise MeshError(f".npy format version {version[0]}.{version[1]} (structured fields); a (P, 3) array "
                            f"of numbers is needed")
        read_header = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
        shape, _, dtype = read_header(f)
        available = path.stat().st_size - f.tell()
    if dtype.hasobject or dtype.kind not in "iuf":
        raise MeshError(f"holds values of type {dtype}, not coordinates (a .npy of integers or floats is needed)")
    needed = math.prod(shape) * dtype.itemsize
    if needed > available:
        raise MeshError(f"its header declares an array of shape {shape} ({needed:,} bytes) but the file holds "
                        f"{available:,} bytes of data (truncated?)")
    return np.load(path, allow_pickle=False)


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
        if gt is None:
            raw = read_point_cloud(cloud)
            try:
                transform = canonical_transform(raw)
            except MeshError as exc:  # all points at one place, or a box beyond float64
                raise MeshError(f"{cloud}: {exc}") from None
            return Shape(name, np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), transform, str(cloud), NO_GT,
                         {}, transform.apply(raw))
        mesh = load_shape(gt, name=name, kind="closed")
        points = mesh.transform.apply(read_point_cloud(cloud))
        return Shape(name, mesh.vertices, mesh.faces, mesh.transform, str(cloud), classify_topology(mesh.faces),
                     {"gt": str(gt)}, points)

    def stored_files(self, name: str) -> tuple[tuple[Path, str], ...]:
        if name not in self._paths:
            raise self._unknown_shape(name)
        gt = gt_path(self._paths[name])
        return ((self._paths[name], "cloud"),) + (((gt, "mesh"),) if gt is not None else ())

    def options(self) -> dict[str, Any]:
        return {"data_dir": str(self.data_dir)}
