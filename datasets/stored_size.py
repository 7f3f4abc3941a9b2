"""How many faces or points a file stores, known before the file is read.

A job checks its shape's files against the run's size limits (``--max-faces``, ``--max-points``)
with :func:`stored_count` first, so a file over a limit is refused without allocating its arrays:

* PLY: the ``element face`` / ``element vertex`` counts of its header;
* OFF: the counts line of its header;
* binary STL: the triangle count of its 84-byte header;
* NPY, NPZ (its ``points`` array): the first dimension of the array shape in its header;
* OBJ, ASCII STL, XYZ: lines counted in a stream of 16 MiB chunks (memory bounded by the chunk,
  time linear in the file): OBJ lines that start with ``f`` (faces) or ``v`` (points), ASCII STL
  ``vertex`` keywords / 3, XYZ lines (comments included: an upper bound);
* glTF/GLB: not known before reading (None); the count after reading is checked instead.

A polygon counts once here (the loader fan-triangulates it into more triangles; the job checks the
triangle count again after loading). A header that cannot be parsed gives None: the loader then
says what is wrong with the file.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

__all__ = ["stored_count", "CHUNK_BYTES"]

#: Bytes read at a time when a text file's lines are counted.
CHUNK_BYTES = 1 << 24
#: Most bytes of a PLY or OFF header read to find its counts.
HEADER_BYTES = 1 << 16


def stored_count(path: str | os.PathLike, what: str) -> int | None:
    """The number of faces (``what='faces'``) or points (``what='points'``: vertices of a mesh file,
    points of a cloud file) that ``path`` stores, from its header or a bounded-memory line count;
    None when the format does not say before it is read, or the header is unreadable."""
    if what not in ("faces", "points"):
        raise ValueError(f"what must be 'faces' or 'points', got {what!r}")
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".ply":
            return _ply_count(path, "face" if what == "faces" else "vertex")
        if suffix == ".off":
            return _off_count(path, what)
        if suffix == ".stl":
            return _stl_count(path) if what == "faces" else None
        if suffix == ".npy":
            return _npy_count(path) if what == "points" else None
        if suffix == ".npz":
            return _npz_count(path) if what == "points" else None
        if suffix == ".obj":
            return count_line_starts(path, (b"f ", b"f\t") if what == "faces" else (b"v ", b"v\t"))
        if suffix == ".xyz":
            return count_line_starts(path, (b"",)) if what == "points" else None
    except (OSError, ValueError):
        return None
    return None


def count_line_starts(path: Path, prefixes: tuple[bytes, ...]) -> int:
    """Lines of ``path`` that start with one of ``prefixes`` (``(b"",)``: every line, a last one
    without its newline included), read in chunks of :data:`CHUNK_BYTES`."""
    if prefixes == (b"",):
        return _count_lines(path)
    return count_occurrences(path, tuple(b"\n" + p for p in prefixes), start=b"\n")


def count_occurrences(path: Path, patterns: tuple[bytes, ...], start: bytes = b"") -> int:
    """Occurrences of ``patterns`` (all of one length) in ``start`` + the bytes of ``path``, read in
    chunks of :data:`CHUNK_BYTES` (a match across two chunks is counted once)."""
    if len({len(p) for p in patterns}) != 1:
        raise ValueError("patterns must have one length")
    carry = len(patterns[0]) - 1  # a tail this short holds no whole match: nothing is counted twice
    total, tail = 0, start
    with open(path, "rb") as f:
        while chunk := f.read(CHUNK_BYTES):
            data = tail + chunk
            total += sum(data.count(p) for p in patterns)
            tail = data[len(data) - carry:]
    return total


def _count_lines(path: Path) -> int:
    total, last = 0, b"\n"
    with open(path, "rb") as f:
        while chunk := f.read(CHUNK_BYTES):
            total += chunk.count(b"\n")
            last = chunk[-1:]
    return total + (last != b"\n")


def _header(path: Path) -> bytes:
    with open(path, "rb") as f:
        return f.read(HEADER_BYTES)


def _ply_count(path: Path, element: str) -> int | None:
    head = _header(path)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return None
    found = re.search(rb"^\s*element\s+" + element.encode() + rb"\s+(\d+)\s*$", head[:end], re.MULTILINE)
    return int(found.group(1)) if found else 0


def _off_count(path: Path, what: str) -> int | None:
    lines = (line.split(b"#")[0].split() for line in _header(path).splitlines())
    tokens = [t for line in lines for t in line][:4]
    if not tokens or not tokens[0].endswith(b"OFF"):
        return None
    counts = tokens[1:]
    if len(counts) < 2 or not all(t.isdigit() for t in counts[:2]):
        return None
    return int(counts[1] if what == "faces" else counts[0])


def _stl_count(path: Path) -> int | None:
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(84)
    if len(head) == 84:
        declared = int.from_bytes(head[80:84], "little")
        if size == 84 + 50 * declared:
            return declared
    return count_occurrences(path, (b"vertex",)) // 3


def _npy_count(path: Path) -> int | None:
    with open(path, "rb") as f:
        return _npy_rows(f)


def _npz_count(path: Path) -> int | None:
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive, archive.open("points.npy") as f:
            return _npy_rows(f)
    except (zipfile.BadZipFile, KeyError):
        return None


def _npy_rows(f) -> int:
    """The first dimension of the array whose .npy header ``f`` is at (1 for a scalar)."""
    from numpy.lib import format as npy

    version = npy.read_magic(f)
    read_header = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
    shape, _, _ = read_header(f)
    return int(shape[0]) if shape else 1
