"""Untrusted files are parsed outside the API process (issue 50): each hostile upload of the issue's table
is a 4xx naming the file and the limit, the server's peak RSS barely moves while it is refused, health
checks answer while one is parsed, and a job naming an uploaded asset reads it in a child process too."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.integration.test_api_server import (
    QUICK_RENDER,
    DatabaseChoice,
    ServerThread,
    problem_of,
    settings_for,
)
from tests.support import hostile_inputs as hostile
from workers.scene.geometry.budget import MAX_SCENE_INSTANCES
from workers.scene.portability import io
from workers.scene.portability.io import MAX_SCENE_VALUES

PEAK_GROWTH_BYTES = 256 << 20  # the 5.7 MiB list took +1 GB in the API process, the glTF bomb +1.9 GB


@pytest.fixture(scope="module")
def server(tmp_path_factory) -> Iterator[ServerThread]:
    """An API-only server (no scheduler, no Ray): uploads and submissions only."""
    data_dir = tmp_path_factory.mktemp("untrusted")
    with ServerThread(settings_for(data_dir, DatabaseChoice("sqlite", None), scheduling=False)) as running:
        yield running


@pytest.fixture
def client(server) -> Iterator[httpx.Client]:
    with server.client("admin") as http:
        yield http


def upload(client: httpx.Client, files: hostile.Files) -> httpx.Response:
    return client.post("/v1/assets", files=[("files", file) for file in files])


def peak_rss_growth(action) -> tuple[int, object]:
    """(growth of this process's peak RSS while `action()` runs, its result): the server runs here."""
    Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM to the current RSS
    before = _status_bytes("VmHWM")
    result = action()
    return _status_bytes("VmHWM") - before, result


def _status_bytes(field: str) -> int:
    line = next(x for x in Path("/proc/self/status").read_text().splitlines() if x.startswith(f"{field}:"))
    return int(line.split()[1]) << 10


@pytest.mark.parametrize(
    ("files", "detail_part"),
    [
        (hostile.yaml_list(), "over the limit of 4,194,304 bytes"),  # 5.7 MiB: refused by its size
        (hostile.yaml_list(700_000), f"more than {MAX_SCENE_VALUES} values, over the limit"),  # 2.7 MiB
        (hostile.gltf_accessor_bomb(), ""),
    ],
    ids=["yaml-5.7MiB-list", "yaml-700k-values", "gltf-accessor-bomb"],
)
def test_a_hostile_scene_file_is_refused_without_the_server_growing(client, files, detail_part):
    growth, response = peak_rss_growth(lambda: upload(client, files))
    assert growth < PEAK_GROWTH_BYTES, f"the server's peak RSS grew by {growth >> 20} MiB"
    body = problem_of(response, 422)
    assert files[0][0] in body["field"] + body["detail"] and detail_part in body["detail"]
    assert "alias" not in body["detail"]


def test_a_texture_declaring_ten_billion_pixels_is_refused_at_upload(client):
    body = problem_of(upload(client, hostile.png_bomb_texture()), 422)
    assert body["field"] == "materials.m.reflectance.path"
    assert "big.png" in body["detail"] and "over the limit of 67,108,864 pixels" in body["detail"]


def test_a_point_instancer_over_the_limit_is_refused_naming_it(client):
    body = problem_of(upload(client, hostile.usd_point_instancer(2 * MAX_SCENE_INSTANCES)), 422)
    assert body["field"] == "scene.usda" and "/World/Scatter" in body["detail"]
    assert f"over the limit of {MAX_SCENE_INSTANCES:,}" in body["detail"]


def test_health_answers_while_a_hostile_upload_is_parsed(server, client):
    uploads = Path(server.settings.data_dir)
    done = threading.Event()
    responses = []

    def hostile_upload():
        with server.client("admin") as other:
            responses.append(upload(other, hostile.yaml_list(700_000)))
        done.set()

    thread = threading.Thread(target=hostile_upload)
    thread.start()
    try:
        while not any(uploads.glob("nbake-upload-*/files/scene.yaml")) and not done.is_set():
            time.sleep(0.01)  # staged: the server is parsing it now
        health = client.get("/healthz")
        answered_first = not done.is_set()
    finally:
        thread.join(timeout=120)
    assert health.status_code == 200 and answered_first, "/healthz waited for the upload's parsing"
    problem_of(responses[0], 422)


def test_a_job_reads_its_uploaded_scene_in_a_child_process(client, monkeypatch):
    response = upload(client, hostile.usd_point_instancer(3))
    assert response.status_code == 201, response.text

    def read_here(*_):
        raise AssertionError("the server process parsed the uploaded scene")

    monkeypatch.setattr(io, "import_scene_file", read_here)  # the child processes are not patched
    job = client.post("/v1/jobs", json={**QUICK_RENDER, "scene": response.json()["asset_id"]})
    assert job.status_code == 201, job.text
