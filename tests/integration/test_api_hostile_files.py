"""Scene files that once made the server answer 500 (issue 50): glTF indices that point nowhere, a
matrix of the wrong size, a negative or oversized accessor count, a data URI that is not base64, a zip
entry flagged UTF-8 whose name is not, a USD mesh without faces. Each is a 422 (or 400) naming the field
or the file, through a real server."""

from __future__ import annotations

import io
import json
import struct
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from pxr import UsdGeom, Vt

from tests.integration import test_api_server as api
from tests.integration.test_api_server import problem_of
from tests.support import usd_files
from tests.support.gltf_files import GltfBuilder, quad

server, client = api.server, api.client  # fixtures


@pytest.fixture(scope="module")
def database():
    """Input handling does not depend on the database: SQLite only."""
    return api.DatabaseChoice("sqlite", None)


def gltf_upload(tmp_path: Path, change: Callable[[dict], None]) -> list[tuple[str, bytes]]:
    """A valid quad scene (mesh, material, camera, point light) as `scene.gltf` and `scene.bin`, its JSON
    changed by `change`."""
    builder = GltfBuilder()
    builder.node(mesh=quad(builder, material=builder.material(name="grey")))
    builder.node(camera=builder.camera(0.8), translation=[0.0, 0.0, 3.0])
    builder.light(type="point", intensity=5.0)
    builder.node(extensions={"KHR_lights_punctual": {"light": 0}}, translation=[0.0, 0.0, 2.0])
    builder.save(tmp_path / "scene.gltf")
    document = json.loads((tmp_path / "scene.gltf").read_text())
    change(document)
    binary = (tmp_path / "scene.bin").read_bytes()
    return [("scene.gltf", json.dumps(document).encode()), ("scene.bin", binary)]


def upload(client, files: list[tuple[str, bytes]]):
    return client.post("/v1/assets", files=[("files", (name, data)) for name, data in files])


def test_the_unchanged_gltf_scene_is_accepted(client, tmp_path):
    response = upload(client, gltf_upload(tmp_path, lambda document: None))
    assert response.status_code == 201, response.text


@pytest.mark.parametrize(
    ("change", "field", "detail_part"),
    [
        pytest.param(lambda d: d.update(scene=5), "scene", "scene 5 does not exist", id="scene"),
        pytest.param(
            lambda d: d["nodes"][0].update(mesh=9), "nodes[0].mesh", "mesh 9 does not exist", id="node-mesh"
        ),
        pytest.param(
            lambda d: d["nodes"][1].update(camera=9),
            "nodes[1].camera",
            "camera 9 does not exist",
            id="node-camera",
        ),
        pytest.param(
            lambda d: d["meshes"][0]["primitives"][0].update(material=9),
            "meshes[0].primitives[0].material",
            "material 9 does not exist",
            id="primitive-material",
        ),
        pytest.param(
            lambda d: d["bufferViews"][0].update(buffer=9),
            "bufferViews[0].buffer",
            "buffer 9 does not exist",
            id="bufferview-buffer",
        ),
        pytest.param(
            lambda d: d["nodes"][2]["extensions"]["KHR_lights_punctual"].update(light=9),
            "nodes[2].extensions.KHR_lights_punctual.light",
            "light 9 does not exist",
            id="light",
        ),
        pytest.param(
            lambda d: d["nodes"][0].update(children=[99]),
            "nodes[0].children",
            "node 99 does not exist",
            id="node-child",
        ),
        pytest.param(
            lambda d: d["nodes"][0].update(matrix=[1, 2, 3]), "nodes[0].matrix", "16 numbers", id="matrix"
        ),
        pytest.param(
            lambda d: d["accessors"][0].update(count=-5), "accessors[0]", "count -5", id="negative-count"
        ),
        pytest.param(
            lambda d: d["buffers"][0].update(uri="data:application/octet-stream;base64,!!!not-base64"),
            "buffers[0].uri",
            "not valid base64",
            id="data-uri",
        ),
    ],
)
def test_a_gltf_reference_that_points_nowhere_is_422_naming_it(client, tmp_path, change, field, detail_part):
    body = problem_of(upload(client, gltf_upload(tmp_path, change)), 422)
    assert field in body["field"] and detail_part in body["detail"], body


def test_an_accessor_count_beyond_the_file_bytes_is_refused_before_it_is_allocated(client):
    """400 bytes of JSON asking for 20 M zeroed VEC3 floats (240 MB): refused from the count alone."""
    document = {
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [{"componentType": 5126, "count": 20_000_000, "type": "VEC3"}],
    }
    body = problem_of(upload(client, [("scene.gltf", json.dumps(document).encode())]), 422)
    assert "accessors[0]" in body["field"]
    assert "asks for 240000000 bytes, more than the file's 0" in body["detail"]


def zip_with_a_false_utf8_name() -> bytes:
    """A zip whose member `m\\xff.obj` is flagged as a UTF-8 name (general purpose bit 11)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("mX.obj", b"v 0 0 0\n")
    data = bytearray(buffer.getvalue().replace(b"mX.obj", b"m\xff.obj"))
    for signature, flags_at in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):  # local and central headers
        at = data.find(signature) + flags_at
        struct.pack_into("<H", data, at, struct.unpack_from("<H", data, at)[0] | 0x800)
    return bytes(data)


def test_a_zip_entry_flagged_utf8_with_another_name_is_400_naming_it(client):
    body = problem_of(upload(client, [("scene.zip", zip_with_a_false_utf8_name())]), 400)
    assert body["field"] == "m\\udcff.obj" and "not valid UTF-8" in body["detail"]


def test_a_usd_mesh_without_faces_is_422_naming_it(client, tmp_path):
    stage = usd_files.new_stage(tmp_path / "scene.usda")
    empty = UsdGeom.Mesh.Define(stage, "/World/empty")
    empty.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.zeros((3, 3), np.float32)))
    stage.GetRootLayer().Save()
    body = problem_of(upload(client, [("scene.usda", (tmp_path / "scene.usda").read_bytes())]), 422)
    assert "/World/empty" in body["field"] and "no faces" in body["detail"]
