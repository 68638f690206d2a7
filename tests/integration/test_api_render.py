"""A `render` job through the whole service: HTTP submission, SSE to completion, the EXR downloaded and
compared with a direct render of the same scene, config and seed; idempotent resubmission."""

from __future__ import annotations

import hashlib

import numpy as np

from tests.integration import test_api_server as api
from tests.integration.test_api_server import QUICK_RENDER, events, submit, wait_for
from workers.models.render.config import RenderConfig
from workers.render.render import render
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene
from workers.scene.importers.image_io import read_exr

SEED = 7
database, server, client = api.incidental_database, api.server, api.client  # fixtures


def test_render_job_over_http_equals_a_direct_render(client, tmp_path):
    job = submit(client, **QUICK_RENDER, seed=SEED, config={"spp": 8}, force=True)
    assert job["state"] == "QUEUED" and job["config"]["spp"] == 8 and job["seed"] == SEED
    assert client.get(f"/v1/jobs/{job['id']}").json()["id"] == job["id"]

    stream = events(client, job["id"])
    assert [e["seq"] for e in stream] == list(range(1, len(stream) + 1))
    states = [e["data"]["state"] for e in stream if e["type"] == "state"]
    assert states == ["QUEUED", "RUNNING", "SUCCEEDED"]
    progress = [e["data"] for e in stream if e["type"] == "progress"]
    assert progress and progress[-1]["step"] == progress[-1]["total"] == 8
    assert {"samples_per_s", "eta_s"} <= set(progress[-1])

    done = client.get(f"/v1/jobs/{job['id']}").json()
    assert done["state"] == "SUCCEEDED" and done["progress"]["step"] == 8
    manifest = client.get(done["links"]["artifact"]).json()
    assert manifest["artifact_id"] == done["artifact_id"] and manifest["job_id"] == job["id"]
    assert manifest["config"] == done["config"] and manifest["scene_hash"] == done["scene_hash"]
    files = {f["name"]: f for f in manifest["files"]}
    assert {"image.exr", "preview.png"} <= set(files)
    assert (
        files["image.exr"]["media_type"] == "image/x-exr"
        and files["preview.png"]["media_type"] == "image/png"
    )

    download = client.get(f"/v1/artifacts/{done['artifact_id']}/files/image.exr")
    assert download.status_code == 200
    assert int(download.headers["content-length"]) == files["image.exr"]["size"] == len(download.content)
    assert "sha256:" + hashlib.sha256(download.content).hexdigest() == files["image.exr"]["digest"]
    (tmp_path / "service.exr").write_bytes(download.content)

    config = RenderConfig.model_validate(done["config"])
    direct = render(compile_scene(get_builtin("cornell_box")), config.settings(SEED))
    np.testing.assert_array_equal(read_exr(tmp_path / "service.exr"), direct.image)


def test_artifact_files_support_etag_and_ranges(client):
    job = wait_for(client, submit(client, **QUICK_RENDER, seed=SEED, config={"spp": 8})["id"], {"SUCCEEDED"})
    url = f"/v1/artifacts/{job['artifact_id']}/files/preview.png"
    whole = client.get(url)
    etag = whole.headers["etag"]
    assert whole.headers["accept-ranges"] == "bytes"
    assert client.get(url, headers={"If-None-Match": etag}).status_code == 304

    part = client.get(url, headers={"Range": "bytes=10-19"})
    assert part.status_code == 206 and part.content == whole.content[10:20]
    assert part.headers["content-range"] == f"bytes 10-19/{len(whole.content)}"
    assert part.headers["content-length"] == "10"
    tail = client.get(url, headers={"Range": "bytes=-5"})
    assert tail.status_code == 206 and tail.content == whole.content[-5:]
    stale = client.get(url, headers={"Range": "bytes=0-3", "If-Range": '"sha256:other"'})
    assert stale.status_code == 200 and stale.content == whole.content
    beyond = client.get(url, headers={"Range": f"bytes={len(whole.content)}-"})
    assert beyond.status_code == 416 and beyond.headers["content-range"] == f"bytes */{len(whole.content)}"


def test_identical_submission_returns_the_existing_job_unless_forced(client):
    body = {**QUICK_RENDER, "seed": 11, "config": {"spp": 4}}
    first = submit(client, **body)
    again = submit(client, expect=200, **body)
    assert again["id"] == first["id"]
    assert client.post("/v1/jobs", json=body).headers["location"] == f"/v1/jobs/{first['id']}"
    # The same work named differently (the built-in inline, a preset value spelled out) is the same job.
    inline = {
        **body,
        "scene": get_builtin("cornell_box").model_dump(mode="json"),
        "config": {"spp": 4, "width": 64},
    }
    assert submit(client, expect=200, **inline)["id"] == first["id"]

    forced = submit(client, **body, force=True)
    assert forced["id"] != first["id"] and forced["idempotency_key"] == first["idempotency_key"]
    other_seed = submit(client, **{**body, "seed": 12})
    assert other_seed["idempotency_key"] != first["idempotency_key"]
    wait_for(client, first["id"], {"SUCCEEDED"})
    assert (
        submit(client, expect=200, **body)["artifact_id"]
        == client.get(f"/v1/jobs/{first['id']}").json()["artifact_id"]
    )


def test_idempotency_key_header_is_honoured(client):
    body = {**QUICK_RENDER, "seed": 21, "config": {"spp": 4}, "force": True}
    first = submit(client, headers={"Idempotency-Key": "ci-build-1234"}, **body)
    again = submit(client, expect=200, headers={"Idempotency-Key": "ci-build-1234"}, **body)
    assert again["id"] == first["id"]  # even with force: the header names one submission
    changed = client.post("/v1/jobs", json={**body, "seed": 22}, headers={"Idempotency-Key": "ci-build-1234"})
    assert changed.status_code == 409
    assert changed.json()["field"] == "Idempotency-Key"
