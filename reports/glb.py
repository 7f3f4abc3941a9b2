"""Binary glTF (GLB) of a display mesh, Draco-compressed: what report.html's 3D viewer embeds.

One file holds up to two primitives, each a node of the scene: ``surface`` (triangles) and
``edges`` (points), each with optional per-vertex RGB colours (``COLOR_0``, 8 bits). Both are
compressed with Google's Draco (glTF extension ``KHR_draco_mesh_compression``, encoded by DracoPy)
and positions quantised to :data:`QUANTIZATION_BITS` bits over each primitive's bounding box.
trimesh writes GLB too, but not Draco, which makes the viewer's meshes about ten times smaller.
"""

from __future__ import annotations

import json
import struct

import numpy as np

#: Bits per position coordinate: a grid of 2^14 steps over the box (1.2e-4 of a canonical 2-unit side).
QUANTIZATION_BITS = 14
_FLOAT, _UINT8, _UINT32 = 5126, 5121, 5125
_POINTS, _TRIANGLES = 0, 4
_DRACO_POSITION, _DRACO_COLOR = 0, 2  # draco::GeometryAttribute::Type


def draco_glb(surface: tuple | None = None, edges: tuple | None = None, compression_level: int = 7) -> bytes:
    """GLB bytes of a triangle mesh and/or a point set.

    Parameters
    ----------
    surface : (vertices (n,3) float, faces (m,3) int, colors (n,3) in [0, 1] or None), or None
    edges : (points (k,3) float, colors (k,3) in [0, 1] or None), or None
    compression_level : Draco's speed/size trade-off, 0 (fastest) to 10 (smallest).

    Returns
    -------
    bytes : a GLB file (glTF 2.0) whose nodes are named 'surface' and 'edges' (those given, in
    that order); an empty primitive is left out.
    """
    primitives = []
    if surface is not None and len(surface[1]):
        primitives.append(("surface", _TRIANGLES, *surface))
    if edges is not None and len(edges[0]):
        primitives.append(("edges", _POINTS, edges[0], None, edges[1]))
    gltf = {"asset": {"version": "2.0", "generator": "salsbench reports.glb"}, "scene": 0,
            "scenes": [{"nodes": list(range(len(primitives)))}], "nodes": [], "meshes": [], "accessors": [],
            "bufferViews": [], "buffers": [],
            "extensionsUsed": ["KHR_draco_mesh_compression"], "extensionsRequired": ["KHR_draco_mesh_compression"]}
    body = bytearray()
    for name, mode, points, faces, colors in primitives:
        _add_primitive(gltf, body, name, mode, points, faces, colors, compression_level)
    gltf["buffers"] = [{"byteLength": len(body)}] if body else []
    if not primitives:
        del gltf["extensionsUsed"], gltf["extensionsRequired"]
    return _pack(gltf, bytes(body))


def _add_primitive(gltf: dict, body: bytearray, name: str, mode: int, points, faces, colors, level: int) -> None:
    """Append one Draco-compressed primitive (its accessors, buffer view, mesh and node) to ``gltf``,
    its bytes to ``body`` (4-byte aligned)."""
    import DracoPy

    points = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 3)
    rgb = None if colors is None else np.rint(np.clip(np.asarray(colors, float).reshape(-1, 3), 0, 1) * 255).astype(np.uint8)
    encoded = DracoPy.encode(points, None if faces is None else np.asarray(faces, dtype=np.uint32).reshape(-1, 3),
                             quantization_bits=QUANTIZATION_BITS, compression_level=level, colors=rgb)
    decoded = DracoPy.decode(encoded)  # counts after Draco's own vertex handling, as the accessors must state
    ids = {a["attribute_type"]: a["unique_id"] for a in decoded.attributes}  # Draco numbers them its own way
    accessors = gltf["accessors"]
    attributes = {"POSITION": len(accessors)}
    accessors.append({"componentType": _FLOAT, "count": len(decoded.points), "type": "VEC3",
                      "min": points.min(0).tolist(), "max": points.max(0).tolist()})
    draco_ids = {"POSITION": ids[_DRACO_POSITION]}
    if rgb is not None:
        attributes["COLOR_0"] = len(accessors)
        accessors.append({"componentType": _UINT8, "normalized": True, "count": len(decoded.points), "type": "VEC3"})
        draco_ids["COLOR_0"] = ids[_DRACO_COLOR]
    primitive = {"attributes": attributes, "mode": mode,
                 "extensions": {"KHR_draco_mesh_compression": {"bufferView": len(gltf["bufferViews"]),
                                                               "attributes": draco_ids}}}
    if faces is not None:
        primitive["indices"] = len(accessors)
        accessors.append({"componentType": _UINT32, "count": 3 * len(decoded.faces), "type": "SCALAR"})
    gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(body), "byteLength": len(encoded)})
    body += encoded + b"\0" * (-len(encoded) % 4)
    gltf["nodes"].append({"mesh": len(gltf["meshes"]), "name": name})
    gltf["meshes"].append({"name": name, "primitives": [primitive]})


def _pack(gltf: dict, body: bytes) -> bytes:
    """The GLB container: 12-byte header, JSON chunk (space-padded), BIN chunk (when not empty)."""
    text = json.dumps(gltf, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text
    if body:
        chunks += struct.pack("<I4s", len(body), b"BIN\0") + body
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def read_glb(data: bytes) -> tuple[dict, bytes]:
    """(glTF JSON, BIN chunk) of GLB bytes; ValueError when ``data`` is not a GLB file."""
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF" or version != 2 or length != len(data):
        raise ValueError("not a GLB 2.0 file of this length")
    size, kind = struct.unpack_from("<I4s", data, 12)
    gltf = json.loads(data[20:20 + size])
    body = b""
    if 20 + size < len(data):
        body_size, _ = struct.unpack_from("<I4s", data, 20 + size)
        body = data[28 + size:28 + size + body_size]
    return gltf, body
