"""Every bad request to the jobs and artifacts API is a 4xx problem+json that names what is wrong;
none is a 500, and none changes stored data."""

from __future__ import annotations

import pytest

from tests.integration import test_api_server as api
from tests.integration.test_api_server import QUICK_RENDER, problem_of, submit

database, server, client = api.incidental_database, api.server, api.client  # fixtures
UNKNOWN_DIGEST = "sha256:" + "0" * 64


@pytest.mark.parametrize(
    ("change", "field", "detail_part"),
    [
        pytest.param({"kind": "nerf"}, "kind", "known kinds:", id="unknown-kind"),
        pytest.param(
            {"preset": "huge"}, "preset", "known presets: quick, default, paper", id="unknown-preset"
        ),
        pytest.param(
            {"config": {"spp": 0}}, "config.spp", "greater than or equal to 1", id="config-out-of-range"
        ),
        pytest.param({"config": {"sppp": 4}}, "config.sppp", "Extra inputs", id="config-unknown-field"),
        pytest.param({"config": {"spp": "many"}}, "config.spp", "integer", id="config-wrong-type"),
        pytest.param({"scene": UNKNOWN_DIGEST}, "scene", "no asset", id="unknown-asset"),
        pytest.param({"scene": "cornell_boxx"}, "scene", "built-in scene", id="unknown-builtin"),
        pytest.param(
            {"scene": {"materials": {}, "objects": []}}, "scene.objects", "at least 1", id="invalid-inline"
        ),
        pytest.param(
            {
                "scene": {
                    "materials": {"m": {"type": "diffuse"}},
                    "objects": [{"name": "o", "shape": {"type": "mesh", "path": "a.obj"}, "material": "m"}],
                }
            },
            "scene.objects[0].shape.path",
            "upload it as an asset",
            id="inline-names-a-file",
        ),
        pytest.param({"seed": -1}, "seed", "greater than or equal to 0", id="negative-seed"),
        pytest.param({"priority": "high"}, "priority", "integer", id="priority-not-int"),
        pytest.param({"colour": "red"}, "colour", "Extra inputs", id="unknown-body-field"),
        pytest.param({"kind": None}, "kind", "string", id="kind-null"),
    ],
)
def test_invalid_job_requests_are_422_naming_the_field(client, change, field, detail_part):
    body = problem_of(client.post("/v1/jobs", json={**QUICK_RENDER, **change}), 422)
    assert body["field"] == field
    assert detail_part in body["detail"]


def test_missing_required_fields_are_422(client):
    assert problem_of(client.post("/v1/jobs", json={"scene": "cornell_box"}), 422)["field"] == "kind"
    assert problem_of(client.post("/v1/jobs", json={"kind": "render"}), 422)["field"] == "scene"
    assert problem_of(client.post("/v1/jobs", json=[QUICK_RENDER]), 422)


@pytest.mark.parametrize("text", ['{"kind": "render",', "{'kind': 'render'}", "\x00\xff", ""])
def test_malformed_json_is_400(client, text):
    response = client.post("/v1/jobs", content=text, headers={"Content-Type": "application/json"})
    assert response.status_code in (400, 422)
    assert response.headers["content-type"] == "application/problem+json"
    if text.startswith("{"):
        assert "not valid JSON" in problem_of(response, 400)["detail"]


def test_oversized_bodies_are_413(client):
    huge = {**QUICK_RENDER, "config": {"note": "x" * (2 << 20)}}
    assert "exceeds" in problem_of(client.post("/v1/jobs", json=huge), 413)["detail"]

    def chunks():  # no Content-Length: the limit holds while the body streams in
        for _ in range(40):
            yield b" " * (64 << 10)

    streamed = client.post("/v1/jobs", content=chunks(), headers={"Content-Type": "application/json"})
    problem_of(streamed, 413)


@pytest.mark.parametrize(
    ("params", "field"),
    [
        ({"state": "DONE"}, "state"),
        ({"limit": 0}, "limit"),
        ({"limit": 1000}, "limit"),
        ({"cursor": "!!!"}, "cursor"),
    ],
)
def test_bad_list_parameters_are_422(client, params, field):
    assert field in problem_of(client.get("/v1/jobs", params=params), 422)["field"]


def test_bad_idempotency_key_and_event_ids_are_4xx(client):
    long_key = {"Idempotency-Key": "k" * 300}
    assert (
        problem_of(client.post("/v1/jobs", json=QUICK_RENDER, headers=long_key), 422)["field"]
        == "idempotency-key"
    )
    job = submit(client, **{**QUICK_RENDER, "config": {"spp": 1}}, force=True)
    bad = client.get(f"/v1/jobs/{job['id']}/events", headers={"Last-Event-ID": "yesterday"})
    assert problem_of(bad, 422)["field"] == "last-event-id"


@pytest.mark.parametrize(
    "path",
    [
        f"/v1/artifacts/{UNKNOWN_DIGEST}",
        "/v1/artifacts/not-a-digest",
        f"/v1/artifacts/{UNKNOWN_DIGEST}/files/image.exr",
        "/v1/nothing-here",
    ],
)
def test_unknown_artifacts_and_routes_are_404(client, path):
    problem_of(client.get(path), 404)


def test_unknown_file_in_an_artifact_is_404_listing_the_files(client):
    job = submit(client, **{**QUICK_RENDER, "config": {"spp": 1}}, force=True)
    job = api.wait_for(client, job["id"], {"SUCCEEDED"})
    body = problem_of(client.get(f"/v1/artifacts/{job['artifact_id']}/files/nope.exr"), 404)
    assert "image.exr" in body["detail"]


def test_wrong_method_is_405(client):
    problem_of(client.delete("/v1/jobs"), 405)


def test_bad_input_changes_nothing(client):
    before = client.get("/v1/jobs", params={"limit": 200}).json()
    for change in ({"kind": "nerf"}, {"config": {"spp": 0}}, {"scene": UNKNOWN_DIGEST}):
        client.post("/v1/jobs", json={**QUICK_RENDER, **change})
    after = client.get("/v1/jobs", params={"limit": 200}).json()
    assert [j["id"] for j in after["items"]] == [j["id"] for j in before["items"]]
