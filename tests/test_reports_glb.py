"""The viewer's GLB files (reports/glb.py): a glTF 2.0 container whose Draco buffers decode back to
the mesh and the points given, within the quantisation step, with their colours."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from reports.glb import QUANTIZATION_BITS, draco_glb, read_glb


def _decoded(gltf: dict, body: bytes, node: int):
    """(DracoPy's decoding of the node's buffer view, the primitive) of a GLB's node."""
    import DracoPy

    primitive = gltf["meshes"][gltf["nodes"][node]["mesh"]]["primitives"][0]
    view = gltf["bufferViews"][primitive["extensions"]["KHR_draco_mesh_compression"]["bufferView"]]
    return DracoPy.decode(body[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]), primitive


def test_a_mesh_and_its_points_come_back_within_the_quantisation_step_with_their_colours():
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5)).subdivide()
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    colors = np.linspace(0, 1, 3 * len(V)).reshape(-1, 3)
    points = np.random.default_rng(0).uniform(-1, 1, (50, 3))
    point_colors = np.tile([0.0, 0.5, 1.0], (50, 1))
    data = draco_glb((V, F, colors), (points, point_colors))
    gltf, body = read_glb(data)
    assert data[:4] == b"glTF" and gltf["asset"]["version"] == "2.0"
    assert [n["name"] for n in gltf["nodes"]] == ["surface", "edges"]
    assert gltf["extensionsRequired"] == ["KHR_draco_mesh_compression"]

    mesh, primitive = _decoded(gltf, body, 0)
    assert primitive["mode"] == 4 and len(mesh.faces) == len(F)
    step = 2.0 / 2 ** QUANTIZATION_BITS  # the box's longest side over the quantisation grid
    # every decoded corner is an input vertex moved by at most one quantisation step, colour kept
    decoded_corners = mesh.points[mesh.faces].reshape(-1, 3)
    nearest = np.argmin(np.linalg.norm(decoded_corners[:, None] - V[None], axis=2), axis=1)
    assert np.abs(decoded_corners - V[nearest]).max() <= step
    assert np.array_equal(mesh.colors[mesh.faces].reshape(-1, 3), np.rint(colors[nearest] * 255))
    assert gltf["accessors"][primitive["attributes"]["POSITION"]]["count"] == len(mesh.points)
    assert gltf["accessors"][primitive["attributes"]["COLOR_0"]]["normalized"] is True

    cloud, primitive = _decoded(gltf, body, 1)
    assert primitive["mode"] == 0 and "indices" not in primitive and len(cloud.points) == 50
    assert np.all(cloud.colors == [0, 128, 255])
    # the Draco attribute ids the GLB names are those of the decoded attributes of each type
    ids = {a["attribute_type"]: a["unique_id"] for a in cloud.attributes}
    assert primitive["extensions"]["KHR_draco_mesh_compression"]["attributes"] == {"POSITION": ids[0], "COLOR_0": ids[2]}


def test_an_uncoloured_mesh_and_empty_parts():
    V, F = np.eye(3), np.array([[0, 1, 2]])
    gltf, _ = read_glb(draco_glb((V, F, None), (np.zeros((0, 3)), np.zeros((0, 3)))))
    assert [n["name"] for n in gltf["nodes"]] == ["surface"]
    assert set(gltf["meshes"][0]["primitives"][0]["attributes"]) == {"POSITION"}
    assert read_glb(draco_glb())[0]["nodes"] == []
    with pytest.raises(ValueError, match="not a GLB"):
        read_glb(b"glTF" + bytes(8))
