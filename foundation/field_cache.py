"""Disk cache of the exact grid fields, keyed by (mesh hash, N, kind).

A :class:`FieldCache` serves the four oracle grid fields of an :class:`foundation.fields.ExactFields`
(each costly to compute at N = 128) from one folder. The caller chooses the folder: the run layer
passes ``foundation.storage.cache_root(...) / "fields"`` (the one cache-root rule), ``None`` turns
caching off.

Entries
-------
One file per (mesh, N, kind, band): ``<cache_key(...)>.npz`` in the cache folder. The file is a
checksummed entry of :mod:`foundation.storage` (written atomically by ``write_checked``) whose
payload is an ``np.savez_compressed`` archive; grid edges are stored sparse (hit edges only).
A file whose checksum fails -- damaged bytes, a truncated write, a file written without a checksum --
or whose payload is not the expected archive is counted in ``stats.rejected``, recomputed and
overwritten: a damaged entry is never used.
"""

from __future__ import annotations

import io
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from foundation.fields import FIELDS_VERSION, ExactFields, default_band
from foundation.grid import EdgeField, num_edges
from foundation.registry import Registry
from foundation.storage import CacheStats, CorruptEntry, mesh_hash, read_entry, write_checked

__all__ = ["FieldCache", "cache_key", "CACHE_KINDS"]


def cache_key(mesh_hash: str, N: int, kind: str, band: float | None = None) -> str:
    """File stem of a cached field: mesh hash, N, kind, band (distance kinds) and FIELDS_VERSION.

    ``band`` (canonical units) defaults to :func:`foundation.fields.default_band` (N); it is part of
    the key of the distance kinds 'sdf' and 'udf_grad' only.
    """
    parts = [mesh_hash, f"N{N}", kind]
    if kind in ("sdf", "udf_grad"):
        parts.append(f"band{(default_band(N) if band is None else float(band)):.6g}")
    parts.append(FIELDS_VERSION)
    return "_".join(parts)


@dataclass(frozen=True)
class _Kind:
    """How one kind of grid field is computed, stored and read back."""

    compute: Callable[[ExactFields, int, float | None], dict[str, np.ndarray]]  # arrays to store
    load: Callable[[int, Mapping[str, np.ndarray]], object]  # stored arrays -> the returned value


def _grid(N: int, array: np.ndarray, dtype=None) -> np.ndarray:
    array = np.asarray(array, dtype=dtype)
    if array.shape[:3] != (N, N, N):
        raise ValueError(f"stored grid has shape {array.shape}, expected ({N}, {N}, {N}, ...)")
    return array


def _compute_edges(fields: ExactFields, N: int, band) -> dict[str, np.ndarray]:
    ef = fields.grid_edges(N)
    ids = np.flatnonzero(ef.hit)  # stored sparse: hit edges only (s and normal are 0 elsewhere)
    return {"ids": ids, "s": ef.s[ids], "normal": ef.normal[ids]}


def _load_edges(N: int, z: Mapping[str, np.ndarray]) -> EdgeField:
    E = num_edges(N)
    ids = np.asarray(z["ids"], dtype=np.int64)
    hit = np.zeros(E, dtype=bool)
    s = np.zeros(E, dtype=np.float32)
    normal = np.zeros((E, 3), dtype=np.float32)
    hit[ids] = True
    s[ids] = z["s"]
    normal[ids] = z["normal"]
    return EdgeField(N=N, hit=hit, s=s, normal=normal)


def _compute_udf_grad(fields: ExactFields, N: int, band) -> dict[str, np.ndarray]:
    d, g = fields.grid_udf_with_grad(N, band)
    return {"udf": d, "grad": g}


#: The cached kinds: 'occupancy' -> (N, N, N) bool; 'sdf' -> (N, N, N) float32 (narrow band);
#: 'udf_grad' -> (udf (N, N, N), grad (N, N, N, 3)) float32 (narrow band); 'edges' -> EdgeField.
_KINDS: Registry[_Kind] = Registry("cached field kind")
_KINDS.register("occupancy", _Kind(lambda f, N, band: {"occupancy": f.grid_occupancy(N)},
                                   lambda N, z: _grid(N, z["occupancy"], bool)))
_KINDS.register("sdf", _Kind(lambda f, N, band: {"sdf": f.grid_scalar(N, "sdf", band)},
                             lambda N, z: _grid(N, z["sdf"])))
_KINDS.register("udf_grad", _Kind(_compute_udf_grad, lambda N, z: (_grid(N, z["udf"]), _grid(N, z["grad"]))))
_KINDS.register("edges", _Kind(_compute_edges, _load_edges))

#: Names of the cached kinds, in the order above.
CACHE_KINDS = tuple(_KINDS.names())


class FieldCache:
    """Exact grid fields, read from a folder of checksummed entries or computed and stored there.

    Parameters
    ----------
    directory : folder of the entries (created on the first write), or None: caching off (every
        :meth:`get` computes and nothing is written anywhere).
    stats : where hits (``'fields'``) and rejected corrupt entries are counted; default: a new
        :class:`foundation.storage.CacheStats`, available as ``self.stats``.
    """

    def __init__(self, directory: str | os.PathLike | None, stats: CacheStats | None = None):
        self.directory = None if directory is None else Path(directory)
        self.stats = CacheStats() if stats is None else stats

    def path(self, fields: ExactFields, N: int, kind: str, band: float | None = None) -> Path | None:
        """The entry file of a field (it may not exist yet); None when caching is off."""
        _KINDS.get(kind)
        if self.directory is None:
            return None
        return self.directory / (cache_key(mesh_hash(fields.vertices, fields.faces), N, kind, band) + ".npz")

    def get(self, fields: ExactFields, N: int, kind: str, band: float | None = None):
        """One exact grid field of ``fields`` at resolution N (see :data:`CACHE_KINDS` for the types).

        ``band``: narrow-band half width of the distance kinds (canonical units, default
        :func:`foundation.fields.default_band` (N)). A readable entry is returned (and counted as a
        hit); a missing one is computed and stored; a corrupt one is counted in ``stats.rejected``,
        recomputed and overwritten. Computed and cached values are identical arrays.
        """
        spec = _KINDS.get(kind)
        path = self.path(fields, N, kind, band)
        value = read_entry(path, self.stats, "fields", lambda payload: _read_payload(spec, N, payload, path))
        if value is not None:
            return value
        arrays = spec.compute(fields, N, band)
        if path is not None:
            buffer = io.BytesIO()
            np.savez_compressed(buffer, **arrays)
            write_checked(path, buffer.getvalue())
        return spec.load(N, arrays)


def _read_payload(spec: _Kind, N: int, payload: bytes, path: Path):
    """The value stored in a checksum-verified payload; CorruptEntry when it is not the expected archive."""
    try:
        with np.load(io.BytesIO(payload), allow_pickle=False) as z:
            return spec.load(N, z)
    except (OSError, KeyError, IndexError, ValueError, zipfile.BadZipFile) as exc:
        raise CorruptEntry(f"{path}: not a grid field archive of this kind ({exc})") from None
