"""The defects found by probing a running server as an attacker would, each a regression test: every one
is a 4xx naming the field, answered without building the geometry in the server's process, and the
connection stays usable after it (and after a 500)."""

from __future__ import annotations

import io
import tarfile

import httpx
import pytest

from services.artifacts import validation
from tests.integration import test_api_server as api
from tests.integration.test_api_server import QUICK_RENDER, problem_of
from tests.support.hostile_inputs import YAML_ALIAS_BOMB

server, client = api.server, api.client  # fixtures


@pytest.fixture(scope="module")
def database():
    """Input handling does not depend on the database: SQLite only (the bad-input suite runs both)."""
    return api.DatabaseChoice("sqlite", None)


LIGHT = "lights: [{type: point, position: [0, 5, 0], intensity: [1, 1, 1]}]\n"


def procedural_yaml(generator: str, params: str, extra: str = "") -> str:
    return (
        "materials: {grey: {type: diffuse}}\n"
        f"objects:\n  - {{name: thing, material: grey, shape: {{type: procedural, generator: {generator}, "
        f"params: {params}}}{extra}}}\n" + LIGHT
    )


def upload(client: httpx.Client, name: str, data: bytes) -> httpx.Response:
    return client.post("/v1/assets", files=[("files", (name, data))])


def test_alias_bomb_upload_is_422_naming_the_file(client):
    body = problem_of(upload(client, "scene.yaml", YAML_ALIAS_BOMB.encode()), 422)
    assert body["field"] == "scene.yaml" and "200000 values" in body["detail"]


@pytest.mark.parametrize("suffix", ["yaml", "json"])
def test_deeply_nested_scene_files_are_422(client, suffix):
    deep = "[" * 100_000 + "]" * 100_000
    text = f"materials: {deep}\n" if suffix == "yaml" else f'{{"materials": {deep}}}'
    body = problem_of(upload(client, f"scene.{suffix}", text.encode()), 422)
    assert "levels deep" in body["detail"]


def test_a_deeply_nested_inline_scene_is_4xx(client):
    deep = "[" * 100_000 + "]" * 100_000
    body = '{"kind": "render", "preset": "quick", "scene": {"materials": ' + deep + "}}"
    response = client.post("/v1/jobs", content=body, headers={"content-type": "application/json"})
    assert 400 <= response.status_code < 500, response.text


@pytest.mark.parametrize(
    ("generator", "params"),
    [
        ("fractal_tree", "{depth: 10, branching: 6, leaves_per_tip: 200}"),
        ("displaced_sphere", "{resolution: 2000}"),
        ("fur", "{strands: 200000, segments: 16, sides: 8}"),
        ("menger_sponge", "{level: 5}"),
    ],
)
def test_validator_maxima_of_generators_are_refused_naming_the_params(client, generator, params):
    body = problem_of(upload(client, "scene.yaml", procedural_yaml(generator, params).encode()), 422)
    assert body["field"] == "objects[0].shape.params" and "over the limit" in body["detail"]


def test_an_upload_builds_its_geometry_outside_the_server_process(client, monkeypatch):
    def built_here(*_):
        raise AssertionError("the server process built the scene")

    monkeypatch.setattr(validation, "compile_scene", built_here)  # the child processes are not patched
    response = upload(client, "scene.yaml", procedural_yaml("menger_sponge", "{level: 3}").encode())
    assert response.status_code == 201, response.text


def test_twenty_thousand_instances_are_refused_naming_them(client):
    tree = {"type": "procedural", "generator": "fractal_tree", "params": {"depth": 5}}
    instances = [{"translate": [i, 0, 0]} for i in range(20_000)]
    scene = {
        "materials": {"m": {"type": "diffuse"}},
        "objects": [{"name": "forest", "shape": tree, "material": "m", "instances": instances}],
        "lights": [{"type": "point", "position": [0, 5, 0], "intensity": [1, 1, 1]}],
    }
    body = problem_of(client.post("/v1/jobs", json={**QUICK_RENDER, "scene": scene}), 422)
    assert body["field"] == "scene.objects[0].instances" and "over the limit" in body["detail"]


def test_a_tar_member_with_a_non_utf8_name_is_400_naming_it(client):
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.GNU_FORMAT, errors="surrogateescape") as tar:
        member = tarfile.TarInfo("m\udcff.obj")
        member.size = 4
        tar.addfile(member, io.BytesIO(b"v 0\n"))
    body = problem_of(upload(client, "scene.tar", buffer.getvalue()), 400)
    assert body["field"] == "m\\udcff.obj" and "UTF-8" in body["detail"]


@pytest.mark.parametrize(
    ("config", "field", "detail_part"),
    [
        ('{"width": 16384, "height": 16384, "spp": 1048576}', "config", "over the limit of 67,108,864"),
        ('{"width": 4096, "height": 4096, "spp": 65536}', "config", "samples, over the limit"),
        ('{"checkpoint_interval_s": 1e309}', "config.checkpoint_interval_s", "finite"),
        ('{"num_gpus": 1e309}', "config.num_gpus", "finite"),
        ('{"spp": "256"}', "config.spp", "integer"),
        ('{"spp": true}', "config.spp", "integer"),
    ],
)
def test_costly_non_finite_and_loosely_typed_configs_are_422(client, config, field, detail_part):
    text = '{"kind": "render", "scene": "cornell_box", "preset": "quick", "config": ' + config + "}"
    response = client.post("/v1/jobs", content=text, headers={"content-type": "application/json"})
    body = problem_of(response, 422)
    assert body["field"] == field and detail_part in body["detail"]


def test_a_plan_over_the_cost_ceiling_is_422_naming_it(client):
    sphere = {"type": "procedural", "generator": "displaced_sphere", "params": {"resolution": 40}}
    scene = {
        "materials": {"m": {"type": "diffuse"}},
        "objects": [{"name": "ball", "shape": sphere, "material": "m"}],
        "lights": [{"type": "point", "position": [0, 5, 0], "intensity": [1, 1, 1]}],
    }
    config = {"batch_size": 1 << 22, "train": {"steps": 10_000_000}}
    request = {"kind": "lsnif", "scene": scene, "preset": "quick", "config": config}
    body = problem_of(client.post("/v1/jobs", json=request), 422)
    assert body["field"] == "config" and "max_job_seconds" in body["detail"]


@pytest.mark.parametrize(
    ("kind", "config", "field"),
    [
        ("lsnif", {"batch_size": 10**9}, "config.batch_size"),
        ("lsnif", {"train": {"steps": 10**12}}, "config.train.steps"),
        ("lsnif", {"grid": {"base_resolution": 10**9}}, "config.grid.base_resolution"),
    ],
)
def test_every_count_has_an_upper_bound(client, kind, config, field):
    request = {"kind": kind, "scene": "cornell_box", "preset": "quick", "config": config}
    assert problem_of(client.post("/v1/jobs", json=request), 422)["field"] == field


def test_a_500_keeps_the_connection_usable(server, client, monkeypatch):
    services = server.thread and client  # the app runs in this process: break one route for one request
    app_services = server.server.config.app.state.services
    monkeypatch.setattr(app_services.jobs, "list", lambda *a, **k: 1 / 0)
    body = problem_of(services.get("/v1/jobs"), 500)
    assert "ZeroDivisionError" in body["detail"]
    monkeypatch.undo()
    for _ in range(3):  # the same keep-alive connection (an httpx.Client reuses it)
        assert client.get("/v1/jobs").status_code == 200


def test_405_lists_every_allowed_method(client):
    response = client.put("/v1/jobs")
    problem_of(response, 405)
    assert response.headers["allow"] == "GET, POST"
