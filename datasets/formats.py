"""Mesh file formats: the OBJ and OFF parsers, and the checks that name what is wrong with an STL
or PLY file before trimesh parses it (:mod:`datasets.io` reads files through these).

Everything here works on the bytes or text of one file and raises :class:`MeshError` with one line
saying what is wrong (the caller adds the file name); nothing here warns.
"""

from __future__ import annotations

import re

import numpy as np

__all__ = ["MeshError", "decode_text", "stl_bytes", "ascii_stl_vertex_count", "check_ply_header", "ply_bytes",
           "parse_obj", "parse_off"]


class MeshError(ValueError):
    """A mesh that cannot be used; the message is one line naming the file and the problem."""


def _is_binary(data: bytes) -> bool:
    """Control bytes other than whitespace in the first 64 KiB: not a text file."""
    head = np.frombuffer(data[:65536], dtype=np.uint8)
    return bool(np.any((head < 32) & ~np.isin(head, (9, 10, 11, 12, 13))))


def decode_text(data: bytes, kind: str) -> str:
    """A text mesh file as str (UTF-8, else Latin-1); binary data gives a one-line MeshError."""
    if _is_binary(data):
        raise MeshError(f"holds binary data, not a text {kind} file")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")  # comments/names in a legacy encoding; numbers are ASCII


def binary_stl(data: bytes) -> bool:
    """True when ``data`` is a binary STL: its size is 84 + 50 x the triangle count of its header."""
    return len(data) >= 84 and len(data) == 84 + 50 * int.from_bytes(data[80:84], "little")


def stl_bytes(data: bytes) -> bytes:
    """What trimesh gets of an STL file: a binary STL as is (:func:`binary_stl`), an ASCII STL
    decoded here and re-encoded as UTF-8; else MeshError."""
    if binary_stl(data):
        return data
    count = int.from_bytes(data[80:84], "little") if len(data) >= 84 else None
    if count is None:
        as_binary = f"{len(data)} bytes, shorter than a binary STL header (84 bytes)"
    else:
        as_binary = f"binary header claims {count:,} triangles ({84 + 50 * count:,} bytes) but the file holds {len(data):,} bytes"
    if data.lstrip()[:5].lower() != b"solid":
        raise MeshError(f"not an STL file: {as_binary}, and it does not start with 'solid' (ASCII STL)")
    if _is_binary(data):
        raise MeshError(f"not an STL file: starts with 'solid' but holds binary data, and its {as_binary}")
    text = decode_text(data, "ASCII STL")
    last = text.rstrip().rsplit("\n", 1)[-1].strip()
    if not last.lower().startswith("endsolid"):
        raise MeshError(f"ASCII STL does not end with an 'endsolid' line (truncated?); its last line is {last[:40]!r}")
    return text.encode("utf-8")


def ascii_stl_vertex_count(text: bytes) -> int:
    """How many ``vertex`` keywords an ASCII STL text holds: three per triangle that a reader must
    return (trimesh's reader silently skips a facet whose numbers it cannot read)."""
    return len(re.findall(rb"vertex", text.lower()))


_PLY_FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
#: Bytes of each PLY scalar type in a binary file.
_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}
_PLY_TYPES = set(_PLY_SIZES)


def check_ply_header(data: bytes) -> None:
    """Raise a :class:`MeshError` naming what is wrong with the header of PLY file bytes: not a PLY
    file, no ``end_header``, a bad ``format``/``element``/``property`` line, no ``element vertex``,
    or a vertex element without ``x``, ``y`` or ``z``; or with the size of its data: an ASCII body
    whose line count is not the header's element count, a binary body shorter than its elements
    need (checked before any array is allocated, so a header claiming billions of elements costs
    nothing)."""
    end = data.find(b"end_header")
    lines = data[: end if end >= 0 else 65536].decode("latin-1").splitlines()
    if not lines or lines[0].strip() != "ply":
        raise MeshError("not a PLY file (its first line is not 'ply')")
    if end < 0:
        raise MeshError("PLY header has no 'end_header' line")
    properties: dict[str, list[str]] = {}
    counts: dict[str, int] = {}
    min_bytes: dict[str, int] = {}  # per element: its scalars and list lengths (the lists may be empty)
    lists: dict[str, list[bool]] = {}  # per element: which of its properties are lists
    formats = []
    for number, line in enumerate(lines[1:], start=2):
        words = line.split()
        keyword = words[0] if words else ""
        if keyword == "format":
            formats.append(words[1] if len(words) == 3 else "")
        elif keyword == "element":
            if len(words) != 3 or not (words[2].isascii() and words[2].isdigit()):
                raise MeshError(f"PLY header line {number} is not 'element <name> <count>': {line.strip()!r}")
            element = properties.setdefault(words[1], [])
            counts[words[1]] = counts.get(words[1], 0) + int(words[2])
            min_bytes.setdefault(words[1], 0)
            lists.setdefault(words[1], [])
            name = words[1]
        elif keyword == "property":
            types = words[2:4] if words[1:2] == ["list"] and len(words) == 5 else words[1:2] if len(words) == 3 else []
            if not properties or not types or not set(types) <= _PLY_TYPES:
                raise MeshError(f"PLY header line {number} is not a property of a declared element: {line.strip()!r}")
            element.append(words[-1])
            min_bytes[name] += _PLY_SIZES[types[0]]
            lists[name].append(len(types) == 2)
    if not formats:
        raise MeshError("PLY header has no 'format' line")
    if formats[0] not in _PLY_FORMATS:
        raise MeshError(f"PLY format {formats[0]!r} is not one of {', '.join(_PLY_FORMATS)} (with a version)")
    if "vertex" not in properties:
        raise MeshError("PLY header has no 'element vertex' line")
    for axis in ("x", "y", "z"):
        if axis not in properties["vertex"]:
            raise MeshError(f"PLY vertex element lacks property '{axis}'")
    newline = data.find(b"\n", end)
    body = data[newline + 1:] if newline >= 0 else b""
    declared = ", ".join(f"{count:,} {name}" for name, count in counts.items())
    if formats[0] == "ascii":  # one element per line
        body = body.rstrip()
        rows = 0 if not body else body.count(b"\n") + 1 if b"\n" in body else body.count(b"\r") + 1
        if rows != sum(counts.values()):
            raise MeshError(f"PLY data does not match its header (it declares {declared}: "
                            f"{sum(counts.values()):,} lines of ASCII data; the file holds {rows:,})")
        last = [name for name in counts if counts[name]][-1:]
        line = body[max(body.rfind(b"\n"), body.rfind(b"\r")) + 1:]
        if last and not _ply_line_fits(line.split(), lists[last[0]]):
            raise MeshError(f"PLY data does not match its header (its last line does not hold one "
                            f"'{last[0]}': {line[:40].decode('latin-1')!r}; truncated?)")
    else:
        need = sum(counts[name] * min_bytes[name] for name in counts)
        if len(body) < need:
            raise MeshError(f"PLY data does not match its header (it declares {declared}: at least {need:,} bytes "
                            f"of binary data; the file holds {len(body):,})")


def ply_bytes(data: bytes) -> bytes:
    """What trimesh gets of a PLY file: the bytes checked by :func:`check_ply_header`, with a header
    that is not UTF-8 (a comment in a legacy encoding) decoded as Latin-1 and re-encoded as UTF-8,
    as the text mesh formats are read (trimesh would refuse it)."""
    check_ply_header(data)
    end = data.find(b"\n", data.find(b"end_header"))
    header = data[: end + 1] if end >= 0 else data
    try:
        header.decode("utf-8")
    except UnicodeDecodeError:
        return header.decode("latin-1").encode("utf-8") + data[len(header):]
    return data


def _ply_line_fits(tokens: list[bytes], lists: list[bool]) -> bool:
    """Whether one line of an ASCII PLY holds exactly the properties of its element: one number per
    scalar, a length then that many numbers per list."""
    at = 0
    for is_list in lists:
        if is_list:
            try:
                length = float(tokens[at])
            except (IndexError, ValueError):
                return False
            if not (length >= 0 and length.is_integer()):  # NaN and inf are not integers
                return False
            at += int(length)
        at += 1
    return at == len(tokens)


def _numbers_per_line(lines: list[str] | tuple[str, ...], dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """Parse whitespace-separated numbers of many lines at once.

    Returns ``(values, counts)``: all numbers flat in reading order and how many each line holds
    (vectorised: the separators are counted in one byte array, no loop over lines).
    """
    if len(lines) == 0:
        return np.zeros(0, dtype), np.zeros(0, np.int64)
    joined = "\n".join(" ".join(line.split()) for line in lines)
    buffer = np.frombuffer(joined.encode("utf-8", errors="replace"), dtype=np.uint8)
    line_of_byte = np.concatenate([[0], np.cumsum(buffer == 10)[:-1]])
    is_token_start = (buffer > 32) & np.concatenate([[True], buffer[:-1] <= 32])
    counts = np.bincount(line_of_byte[is_token_start], minlength=len(lines)).astype(np.int64)
    values = np.array(joined.split(), dtype=np.float64)
    return (values if dtype is np.float64 else _as_indices(values)), counts


def _as_indices(values: np.ndarray) -> np.ndarray:
    """Parsed face numbers as int64 vertex indices; MeshError for non-integers and for numbers no
    index can be (beyond 2^53, where float64 stops counting in ones)."""
    if not np.all(np.isfinite(values)) or np.any(values != np.round(values)):
        raise MeshError("face line holds a non-integer vertex index")
    if np.any(np.abs(values) > 2**53):
        raise MeshError(f"face index {values[np.argmax(np.abs(values))]:.6g} is out of range (no mesh has that many vertices)")
    return values.astype(np.int64)


def _fan_triangles(indices: np.ndarray, starts: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons stored flat: polygon p is ``indices[starts[p] : starts[p] + sizes[p]]``
    and becomes triangles (v0, v_j, v_j+1), j = 1 .. size - 2 (the order trimesh and most tools use)."""
    if np.any(sizes < 3):
        bad = int(np.flatnonzero(sizes < 3)[0])
        raise MeshError(f"face {bad + 1} has {int(sizes[bad])} vertices (need at least 3)")
    per_polygon = sizes - 2
    polygon = np.repeat(np.arange(len(sizes)), per_polygon)
    j = np.arange(len(polygon)) - np.repeat(np.cumsum(per_polygon) - per_polygon, per_polygon) + 1
    first = starts[polygon]
    return np.stack([indices[first], indices[first + j], indices[first + j + 1]], axis=1)


_OBJ_LINE = re.compile(r"^[ \t]*(v|f)[ \t]+([^\r\n#]*)", re.M)


def parse_obj(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (first three numbers of each ``v`` line, in file order) and fan-triangulated ``f``
    polygons of an OBJ text. Texture/normal indices (``v/vt/vn``) are ignored; negative indices
    count back from the last vertex defined before the face (OBJ rule). Other statements (``vt``,
    ``vn``, ``o``, ``g``, ``usemtl``, lines, points) are ignored; groups share one vertex list."""
    matches = _OBJ_LINE.findall(text)
    if not matches:
        raise MeshError("no vertices found (not an OBJ mesh?)")
    tags, rests = zip(*matches)
    is_vertex = np.array(tags) == "v"
    vertex_lines = [r for r, v in zip(rests, is_vertex) if v]
    face_lines = [r for r, v in zip(rests, is_vertex) if not v]
    if not vertex_lines:
        raise MeshError("no vertices found (not an OBJ mesh?)")
    values, counts = _numbers_per_line(vertex_lines)
    if np.any(counts < 3):
        bad = int(np.flatnonzero(counts < 3)[0])
        raise MeshError(f"vertex {bad + 1} has {int(counts[bad])} coordinates (need 3)")
    starts = np.cumsum(counts) - counts
    vertices = values[starts[:, None] + np.arange(3)]
    if not face_lines:
        return vertices, np.zeros((0, 3), dtype=np.int64)
    face_text = re.sub(r"/[^\s]*", "", "\n".join(face_lines)).split("\n")
    indices, sizes = _numbers_per_line(face_text, dtype=np.int64)
    if np.any(indices == 0):
        raise MeshError("face index 0 (OBJ indices start at 1)")
    # vertices defined before each face line, for negative (relative) indices
    defined_before = np.cumsum(is_vertex)[~is_vertex]
    per_index = np.repeat(defined_before, sizes)
    indices = np.where(indices < 0, per_index + indices, indices - 1)
    faces = _fan_triangles(indices, np.cumsum(sizes) - sizes, sizes)
    return vertices, faces


_OFF_HEADER = re.compile(r"^(ST)?(C)?(N)?(4)?(n)?OFF(.*)$", re.I)


def parse_off(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and fan-triangulated faces of an OFF text.

    Accepts the common variants and quirks: ``OFF``/``COFF``/``NOFF``/``STOFF`` headers in any
    case, counts on the header line (``OFF 8 6 0``) or glued to it (ModelNet's ``OFF490 518 0``) or
    spread over lines, ``#`` comments anywhere, blank lines, CRLF, tabs, extra per-vertex columns
    (normals, colours, texture coordinates) and per-face colours after the indices."""
    lines = [line for line in (raw.split("#", 1)[0].strip() for raw in text.splitlines()) if line]
    if not lines:
        raise MeshError("no OFF header")
    header = _OFF_HEADER.match(lines[0])
    if header is None:
        raise MeshError(f"no OFF header (first line starts with {lines[0][:20]!r})")
    if header.group(4) or header.group(5):
        raise MeshError("4D / n-dimensional OFF is not supported")
    count_tokens = header.group(6).split()
    row = 1
    if not count_tokens and row < len(lines):  # counts on their own line (the usual layout)
        count_tokens, row = lines[row].split(), row + 1
    if len(count_tokens) == 1:  # counts spread over several lines: read all three
        while len(count_tokens) < 3 and row < len(lines):
            count_tokens, row = count_tokens + lines[row].split(), row + 1
    try:
        n_vertices, n_faces = int(count_tokens[0]), int(count_tokens[1])
    except (IndexError, ValueError):
        raise MeshError("malformed vertex/face count line") from None
    if n_vertices < 0 or n_faces < 0:
        raise MeshError(f"negative vertex or face count ({n_vertices}, {n_faces})")
    if len(lines) < row + n_vertices + n_faces:
        raise MeshError(
            f"file ends early: header promises {n_vertices} vertices and {n_faces} faces, "
            f"found {len(lines) - row} data lines"
        )
    values, counts = _numbers_per_line(lines[row : row + n_vertices])
    if np.any(counts < 3):
        bad = int(np.flatnonzero(counts < 3)[0])
        raise MeshError(f"vertex {bad + 1} has {int(counts[bad])} coordinates (need 3)")
    vertices = values[(np.cumsum(counts) - counts)[:, None] + np.arange(3)].reshape(-1, 3)
    if n_faces == 0:
        return vertices, np.zeros((0, 3), dtype=np.int64)
    values, counts = _numbers_per_line(lines[row + n_vertices : row + n_vertices + n_faces])
    line_starts = np.cumsum(counts) - counts
    sizes = values[line_starts]
    if np.any(sizes != np.round(sizes)) or np.any(counts < sizes + 1):
        bad = int(np.flatnonzero((sizes != np.round(sizes)) | (counts < sizes + 1))[0])
        raise MeshError(f"face {bad + 1} is malformed (its vertex count does not match its indices)")
    sizes = sizes.astype(np.int64)
    indices = _as_indices(values[np.repeat(line_starts + 1, sizes) + _ranks(sizes)])
    faces = _fan_triangles(indices, np.cumsum(sizes) - sizes, sizes)
    return vertices, faces


def _ranks(sizes: np.ndarray) -> np.ndarray:
    """0, 1, .., sizes[0]-1, 0, 1, .., sizes[1]-1, ... (positions within consecutive runs)."""
    return np.arange(int(sizes.sum())) - np.repeat(np.cumsum(sizes) - sizes, sizes)
