"""A scene that passes the upload's checks but cannot be used when the job runs (a texture whose header is
fine and whose pixels cannot be decoded) is the user's error: the job fails at once naming the file, and
is not retried as a cluster failure would be."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from tests.integration import test_api_server as api
from tests.integration.test_api_server import events, submit
from tests.support.gltf_files import GltfBuilder, quad

server, client = api.server, api.client  # fixtures


@pytest.fixture(scope="module")
def database():
    """Failure classing does not depend on the database: SQLite only."""
    return api.DatabaseChoice("sqlite", None)


def png_with_a_corrupt_idat() -> bytes:
    """A 16 x 16 PNG whose header reads but whose compressed pixels are garbage (with a valid CRC)."""
    encoded = io.BytesIO()
    Image.fromarray(np.full((16, 16, 3), 200, np.uint8)).save(encoded, format="PNG")
    data = encoded.getvalue()
    at = data.find(b"IDAT")
    (length,) = struct.unpack(">I", data[at - 4 : at])
    garbage = bytes(byte ^ 0x5A for byte in data[at + 4 : at + 4 + length])
    crc = struct.pack(">I", zlib.crc32(b"IDAT" + garbage))
    return data[: at + 4] + garbage + crc + data[at + 8 + length :]


def textured_quad(tmp_path) -> list[tuple[str, bytes]]:
    builder = GltfBuilder()
    texture = builder.texture(builder.image(np.full((16, 16, 3), 200), uri="wood.png"))
    material = builder.material(name="wood", pbrMetallicRoughness={"baseColorTexture": {"index": texture}})
    builder.node(mesh=quad(builder, material=material))
    builder.save(tmp_path / "scene.gltf")
    files = [(name, (tmp_path / name).read_bytes()) for name in ("scene.gltf", "scene.bin")]
    return [*files, ("wood.png", png_with_a_corrupt_idat())]


def test_a_texture_that_cannot_be_decoded_fails_the_job_once_naming_it(client, tmp_path):
    upload = client.post("/v1/assets", files=[("files", file) for file in textured_quad(tmp_path)])
    assert upload.status_code == 201, upload.text  # the header is fine: the upload cannot tell
    config = {"samplers": 1, "min_triangles": 1, "train": {"steps": 5}}
    job = submit(
        client, kind="lod", scene=upload.json()["asset_id"], preset="quick", config=config, force=True
    )
    final = events(client, job["id"])[-1]["data"]
    job = client.get(f"/v1/jobs/{job['id']}").json()
    assert job["state"] == "FAILED" and final["state"] == "FAILED", job
    assert job["attempts"] == 1, job
    assert "wood.png" in job["error"] and "cannot read texture" in job["error"], job["error"]
    assert "InfrastructureFailure" not in job["error"]
