"""Files on disk: the cache root, atomic writes and checksummed cache entries (one owner each).

* :func:`cache_root` -- where every cache lives: an explicit directory, else ``$SALSBENCH_CACHE``,
  else ``~/.cache/salsbench``. Kinds of entries go in sub-folders (``fields/``, ``weights/``,
  ``meshes/``), always below this root.
* :func:`atomic_write` -- write bytes to a temporary file in the same folder, then ``os.replace``:
  a reader sees the old file or the new one, never half of one (a killed writer leaves no entry).
* :func:`write_checked` / :func:`read_checked` -- a cache entry is ``MAGIC + sha256(payload) +
  payload``. Reading checks the digest: a flipped byte, a truncated file or a file that is not an
  entry raises :class:`CorruptEntry`, so the caller recomputes (and counts it) instead of using
  damaged weights, meshes or fields.
* :func:`read_entry` -- an entry read, checked and decoded, or refused and counted
  (:class:`CacheStats`); :func:`entry_lock` -- the lock one entry's writer holds while others wait.
* :func:`mesh_hash` -- the content hash of a mesh's arrays, which keys exact-field caches and the
  seeds of a shape's jobs (never its name or position).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import tempfile
from pathlib import Path
from typing import Callable, Iterator, TypeVar

import numpy as np

#: First bytes of a checksummed cache entry (format version 1).
MAGIC = b"SALSBENCH-ENTRY-1\n"
_DIGEST = 32

T = TypeVar("T")


class CorruptEntry(ValueError):
    """A cache entry whose bytes do not match its checksum (or that is not an entry at all)."""


def mesh_hash(vertices: np.ndarray, faces: np.ndarray) -> str:
    """SHA-256 (16 hex) of the vertices as float64 and the faces as int64, C order."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return h.hexdigest()[:16]


def cache_root(explicit: str | os.PathLike | None = None) -> Path:
    """The cache root: ``explicit``, else ``$SALSBENCH_CACHE``, else ``~/.cache/salsbench``."""
    if explicit:
        return Path(explicit).expanduser()
    env = os.environ.get("SALSBENCH_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "salsbench"


@contextlib.contextmanager
def exclusive_lock(path: str | os.PathLike) -> Iterator[None]:
    """Hold an exclusive flock on ``path`` (created with its folders): works across processes and is
    released when the holder dies. For cache entries that one job computes and others wait for."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def atomic_write(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder + ``os.replace``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def write_checked(path: str | os.PathLike, payload: bytes) -> Path:
    """Write a checksummed cache entry atomically: ``MAGIC + sha256(payload) + payload``."""
    return atomic_write(path, MAGIC + hashlib.sha256(payload).digest() + payload)


def read_checked(path: str | os.PathLike) -> bytes | None:
    """The payload of a checksummed entry; None when the file does not exist.

    Raises :class:`CorruptEntry` (one line naming the file) when the digest does not match.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return None
    head = len(MAGIC) + _DIGEST
    if len(data) < head or not data.startswith(MAGIC):
        raise CorruptEntry(f"{path}: not a salsbench cache entry (no header)")
    payload = data[head:]
    if hashlib.sha256(payload).digest() != data[len(MAGIC):head]:
        raise CorruptEntry(f"{path}: checksum mismatch (the file was damaged after it was written)")
    return payload


class CacheStats:
    """What the caches did for one job: kinds served from cache, and corrupt entries recomputed.

    ``hits``: cache kinds read successfully ('fields', 'weights', 'mesh'), in order of use.
    ``rejected``: one line per entry whose checksum failed (it was recomputed and overwritten).
    """

    def __init__(self) -> None:
        self.hits: list[str] = []
        self.rejected: list[str] = []

    def hit(self, kind: str) -> None:
        if kind not in self.hits:
            self.hits.append(kind)

    def reject(self, error: Exception) -> None:
        self.rejected.append(str(error))


def read_entry(path: str | os.PathLike | None, stats: CacheStats, kind: str, decode: Callable[[bytes], T],
               refused: tuple[type[Exception], ...] = ()) -> T | None:
    """The value of the checksummed entry at ``path`` (``decode`` of its payload), counted in
    ``stats`` as a hit of ``kind``; None when there is no entry (or ``path`` is None: the cache is
    off). An entry whose checksum fails, or that ``decode`` refuses (:class:`CorruptEntry` or one of
    ``refused``), is None too and counted in ``stats.rejected`` with one line naming the file: the
    caller computes the value again and overwrites the entry, never uses it."""
    if path is None:
        return None
    try:
        payload = read_checked(path)
        if payload is None:
            return None
        value = decode(payload)
    except CorruptEntry as exc:
        stats.reject(exc)
        return None
    except refused as exc:
        stats.reject(f"{path}: {exc}")
        return None
    stats.hit(kind)
    return value


def entry_lock(cache_root: str | os.PathLike, name: str):
    """The exclusive lock (:func:`exclusive_lock`) of the cache entry ``name`` under ``cache_root``
    (``locks/<name>.lock``): the job that computes the entry holds it, the others wait, then read it."""
    return exclusive_lock(Path(cache_root) / "locks" / f"{name}.lock")
