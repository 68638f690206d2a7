"""Uploading scenes through the API: a scene with a mesh file becomes an asset that a job renders; every
unusable upload (too large, too many files, unsafe archives, an invalid scene) is a clear 4xx."""

from __future__ import annotations

import io
import tarfile
import zipfile

import pytest
import yaml

from services.artifacts.staging import UploadLimits
from tests.integration import test_api_server as api
from tests.integration.test_api_server import ServerThread, events, problem_of, settings_for, submit
from workers.scene.generators.builtin import get_builtin

database = api.incidental_database  # fixture: the uploads' files, not the database, are tested
LIMITS = UploadLimits(
    max_total_bytes=64 << 10, max_files=4, max_file_bytes=48 << 10, max_compression_ratio=20
)
CUBE_OBJ = b"""v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1
f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 4 8 7\nf 4 7 3\nf 1 5 8\nf 1 8 4\nf 2 3 7\nf 2 7 6
"""


def scene_yaml(mesh_path: str = "meshes/cube.obj") -> bytes:
    """The Cornell box with its tall block replaced by a mesh file."""
    scene = get_builtin("cornell_box").model_dump(mode="json", exclude_none=True)
    block = next(o for o in scene["objects"] if o["shape"]["type"] == "box")
    block["shape"] = {"type": "mesh", "path": mesh_path}
    return yaml.safe_dump(scene).encode()


@pytest.fixture(scope="module")
def server(ray_cluster, database, tmp_path_factory):
    data_dir = tmp_path_factory.mktemp(f"assets-{database.name}")
    with ServerThread(settings_for(data_dir, database, upload_limits=LIMITS)) as running:
        yield running


@pytest.fixture
def client(server):
    with server.client("submit") as http:
        yield http


def upload(client, files: list[tuple[str, bytes]]):
    return client.post("/v1/assets", files=[("files", (name, data)) for name, data in files])


def test_uploaded_scene_with_a_mesh_renders_as_a_job(client):
    response = upload(client, [("scene.yaml", scene_yaml()), ("meshes/cube.obj", CUBE_OBJ)])
    assert response.status_code == 201, response.text
    asset = response.json()
    assert asset["asset_id"].startswith("sha256:") and asset["scene_file"] == "scene.yaml"
    assert {f["name"] for f in asset["files"]} == {"scene.yaml", "meshes/cube.obj"}
    assert client.get(f"/v1/assets/{asset['asset_id']}").json() == asset
    again = upload(client, [("scene.yaml", scene_yaml()), ("meshes/cube.obj", CUBE_OBJ)]).json()
    assert again["asset_id"] == asset["asset_id"]  # content-addressed: the same files are the same asset

    job = submit(
        client, kind="render", scene=asset["asset_id"], preset="quick", config={"spp": 2}, force=True
    )
    assert job["scene"] == {"source": "asset", "name": "cornell_box", "asset_id": asset["asset_id"]}
    assert events(client, job["id"])[-1]["data"]["state"] == "SUCCEEDED"

    # The scene hash covers the files: the same scene text with another mesh is other work.
    other = upload(
        client, [("scene.yaml", scene_yaml()), ("meshes/cube.obj", CUBE_OBJ.replace(b"v 1 1 1", b"v 1 2 1"))]
    )
    job2 = submit(client, kind="render", scene=other.json()["asset_id"], preset="quick", config={"spp": 2})
    assert job2["scene_hash"] != job["scene_hash"]
    client.post(f"/v1/jobs/{job2['id']}:cancel")


def test_an_archive_upload_is_one_asset(client):
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("scene.yaml", scene_yaml())
        archive.writestr("meshes/cube.obj", CUBE_OBJ)
    response = upload(client, [("scene.zip", buffer.getvalue())])
    assert response.status_code == 201, response.text
    assert {f["name"] for f in response.json()["files"]} == {"scene.yaml", "meshes/cube.obj"}


def zip_of(entries: dict[str, bytes]) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in entries.items():
            archive.writestr(name, data)
    return buffer.getvalue()


def tar_with_symlink() -> bytes:
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as archive:
        data = scene_yaml()
        info = tarfile.TarInfo("scene.yaml")
        info.size = len(data)
        archive.addfile(info, io.BytesIO(data))
        link = tarfile.TarInfo("meshes/cube.obj")
        link.type, link.linkname = tarfile.SYMTYPE, "/etc/passwd"
        archive.addfile(link)
    return buffer.getvalue()


@pytest.mark.parametrize(
    ("files", "status", "field_part"),
    [
        pytest.param(
            [("scene.yaml", scene_yaml()), ("big.obj", b"#" * (60 << 10))],
            413,
            "big.obj",
            id="file-too-large",
        ),
        pytest.param(
            [("scene.yaml", scene_yaml())] + [(f"m{i}.obj", CUBE_OBJ) for i in range(5)],
            413,
            "",
            id="too-many-files",
        ),
        pytest.param(
            [("scene.zip", zip_of({"../escape.yaml": scene_yaml()}))], 400, "", id="zip-path-traversal"
        ),
        pytest.param([("scene.tar", tar_with_symlink())], 400, "", id="tar-symlink"),
        pytest.param(
            [("scene.zip", zip_of({"scene.yaml": scene_yaml(), "meshes/cube.obj": b"\n" * (2 << 20)}))],
            413,
            "",
            id="decompression-bomb",
        ),
        pytest.param(
            [("scene.yaml", scene_yaml("meshes/missing.obj"))], 422, "objects", id="scene-names-missing-file"
        ),
        pytest.param([("scene.yaml", b"materials: {}\nobjects: []\n")], 422, "objects", id="invalid-scene"),
        pytest.param([("notes.txt", b"hello")], 400, "files", id="no-scene-file"),
    ],
)
def test_unusable_uploads_are_4xx_naming_the_problem(client, files, status, field_part):
    body = problem_of(upload(client, files), status)
    assert field_part in (body.get("field") or "")


def test_an_upload_body_over_the_limit_is_413_before_it_is_read(client):
    body = problem_of(upload(client, [("scene.yaml", b"#" * (2 << 20))]), 413)
    assert "exceeds" in body["detail"]


def test_an_upload_without_files_is_4xx(client):
    response = client.post("/v1/assets", data={"note": "no files"})
    assert 400 <= response.status_code < 500
    assert response.headers["content-type"] == "application/problem+json"


@pytest.mark.parametrize("asset_id", ["sha256:" + "0" * 64, "not-a-digest"])
def test_unknown_asset_is_404(client, asset_id):
    problem_of(client.get(f"/v1/assets/{asset_id}"), 404)
