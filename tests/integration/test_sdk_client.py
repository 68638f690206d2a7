"""The neuralbake-client SDK against a real `nbake serve`, over REST and over gRPC: the same calls, the
same models, the same exceptions. Uploads, submit/wait/events, cancel, errors carrying the problem,
resumable checksummed downloads, retries, the async client, and the models against the OpenAPI schemas.
"""

from __future__ import annotations

import asyncio
import hashlib
import socket
from pathlib import Path

import httpx
import pytest
import yaml
from neuralbake_client import (
    AsyncClient,
    Client,
    Conflict,
    ConnectionFailed,
    InvalidRequest,
    JobState,
    NotFound,
    PermissionDenied,
    Retry,
    Unauthenticated,
)
from neuralbake_client import models as sdk_models

from tests.integration import test_grpc_server as grpc_server
from tests.integration.test_api_server import TOKENS
from tests.integration.test_grpc_server import LONG, TINY
from workers.scene.generators.builtin import get_builtin

served = grpc_server.served  # fixture


@pytest.fixture(params=["rest", "grpc"])
def client(request, served):
    url = served.url if request.param == "rest" else served.grpc_url
    with Client(url, TOKENS["admin"]) as sdk:
        yield sdk


@pytest.fixture(scope="module")
def finished(served):
    """One succeeded tiny render (shared by the download tests)."""
    with Client(served.url, TOKENS["admin"]) as sdk:
        return sdk.wait(sdk.submit("render", "cornell_box", preset="quick", config=TINY))


def scene_folder(root: Path) -> Path:
    folder = root / "box"
    (folder / "notes").mkdir(parents=True)
    spec = get_builtin("cornell_box").model_dump(mode="json", exclude_none=True)
    (folder / "scene.yaml").write_text(yaml.safe_dump(spec))
    (folder / "notes" / "README.txt").write_text("packed with the scene, ignored by the renderer\n")
    return folder


def test_upload_a_folder_submit_it_and_wait_with_progress(client, tmp_path):
    folder = scene_folder(tmp_path)
    asset = client.upload(folder)
    assert asset.scene_file == "scene.yaml" and {f.name for f in asset.files} >= {"scene.yaml"}
    assert client.get_asset(asset.asset_id).files == asset.files
    job = client.submit("render", folder, preset="quick", config=TINY, seed=3, force=True)
    assert job.scene["asset_id"] == asset.asset_id and job.config["spp"] == 4 and job.seed == 3
    seen = []
    done = client.wait(job, on_progress=seen.append)
    assert done.state == JobState.SUCCEEDED and done.artifact_id
    assert seen and seen[-1].step == seen[-1].total == 4 and seen[-1].samples_per_s > 0
    events = list(client.events(job))
    assert [e.seq for e in events] == list(range(1, len(events) + 1)) and events[-1].final
    assert [e.seq for e in client.events(job, after=2)] == [e.seq for e in events[2:]]
    assert any(j.id == job.id for j in client.jobs(JobState.SUCCEEDED, "render", page_size=2))


def test_cancel_a_running_job(client):
    job = client.submit("render", "cornell_box", preset="quick", config=LONG, force=True)
    for event in client.events(job):
        if event.progress is not None:
            break
    assert client.cancel(job).cancel_requested
    assert client.wait(job).state == JobState.CANCELLED
    with pytest.raises(Conflict) as caught:
        client.cancel(job)
    assert "already CANCELLED" in caught.value.detail and caught.value.status == 409


def test_errors_carry_the_servers_problem(client, served):
    with pytest.raises(InvalidRequest) as caught:
        client.submit("render", "cornell_box", config={"spp": 0})
    assert caught.value.field == "config.spp" and caught.value.status == 422
    with pytest.raises(InvalidRequest) as caught:
        client.submit("nope", "cornell_box")
    assert caught.value.field == "kind" and "render" in caught.value.detail
    with pytest.raises(NotFound):
        client.get("job-missing")
    with Client(client.url, "wrong") as stranger, pytest.raises(Unauthenticated):
        stranger.list()
    with Client(client.url, TOKENS["read"]) as reader, pytest.raises(PermissionDenied) as denied:
        reader.submit("render", "cornell_box")
    assert "submit" in denied.value.detail


def test_download_verifies_resumes_and_skips(client, finished, tmp_path):
    files = {f.entry.name: f for f in client.download(finished, tmp_path)}
    manifest = client.manifest(finished)
    assert set(files) == set(manifest.names())
    image = files["image.exr"].path
    data = image.read_bytes()
    assert "sha256:" + hashlib.sha256(data).hexdigest() == manifest.file("image.exr").digest

    # an interrupted download: half the bytes in the .part file, none in place
    image.unlink()
    part = image.with_name("image.exr.part")
    part.write_bytes(data[: len(data) // 2])
    (again,) = client.download(finished, tmp_path, ["image.exr"])
    assert again.resumed_from == len(data) // 2 and image.read_bytes() == data and not part.exists()

    # a corrupt partial file is thrown away and fetched again from the start
    image.unlink()
    part.write_bytes(b"x" * 100)
    (fixed,) = client.download(finished, tmp_path, ["image.exr"])
    assert image.read_bytes() == data and fixed.resumed_from == 100

    (kept,) = client.download(finished, tmp_path, ["image.exr"])
    assert kept.skipped


def test_a_job_and_its_artifact_are_named_alike_by_every_call(client, finished, tmp_path):
    """A job (id or `Job`) and its artifact (id, bare digest or `Manifest`) name each other everywhere."""
    manifest = client.manifest(finished)
    digest = manifest.artifact_id.removeprefix("sha256:")
    for ref in (finished, finished.id, manifest.artifact_id, digest, manifest):
        assert client.manifest(ref) == manifest
        assert client.get(ref).id == finished.id
        assert list(client.events(ref))[-1].state == JobState.SUCCEEDED
    (file,) = client.download(finished.id, tmp_path, ["preview.png"])
    assert file.entry == manifest.file("preview.png")


def test_rest_and_grpc_show_a_job_the_same_way(served, finished):
    with Client(served.url, TOKENS["read"]) as rest, Client(served.grpc_url, TOKENS["read"]) as rpc:
        over_rest, over_grpc = rest.get(finished.id), rpc.get(finished.id)
        assert over_rest.model_dump(exclude={"links"}) == over_grpc.model_dump(exclude={"links"})
        assert rest.manifest(finished) == rpc.manifest(finished)


def test_an_unreachable_server_raises_connection_failed_after_retries():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]  # nothing listens here once the socket closes
    for url in (f"http://127.0.0.1:{port}", f"grpc://127.0.0.1:{port}"):
        retry = Retry(attempts=2, backoff_s=0.05)
        with Client(url, "t", timeout=5, retry=retry) as sdk, pytest.raises(ConnectionFailed):
            sdk.list()


def test_async_client(served):
    async def run():
        async with AsyncClient(served.grpc_url, TOKENS["admin"]) as sdk:
            job = await sdk.submit("render", "cornell_box", preset="quick", config=TINY)
            steps = []
            done = await sdk.wait(job, on_progress=lambda p: steps.append(p.step))
            types = [event.type async for event in sdk.events(job)]
            return done, steps, types

    done, steps, types = asyncio.run(run())
    assert done.state == JobState.SUCCEEDED and steps and types[-1] == "state"


@pytest.mark.parametrize(
    ("model", "schema"),
    [
        (sdk_models.Job, "JobView"),
        (sdk_models.JobList, "JobList"),
        (sdk_models.JobEvent, "EventView"),
        (sdk_models.Asset, "Asset"),
        (sdk_models.Manifest, "Manifest"),
        (sdk_models.FileEntry, "FileEntry"),
        (sdk_models.Token, "TokenView"),
        (sdk_models.CreatedToken, "CreatedToken"),
        (sdk_models.TenantQuotas, "TenantQuotas"),
        (sdk_models.QuotaLimits, "QuotaLimits"),
        (sdk_models.QuotaUse, "QuotaUse"),
    ],
)
def test_sdk_models_match_the_servers_schemas(served, model, schema):
    spec = httpx.get(f"{served.url}/openapi.json", timeout=30).json()
    events = spec["paths"]["/v1/jobs/{job_id}/events"]["get"]["responses"]["200"]["content"]
    schemas = spec["components"]["schemas"] | {"EventView": events["text/event-stream"]["schema"]}
    properties = (schemas.get(schema) or schemas[f"{schema}-Output"])["properties"]
    assert set(model.model_fields) == set(properties)
