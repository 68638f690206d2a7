"""Tenants through the real servers: the shared `nbake serve` (`served`) and an `nbake serve-inference` on
its data dir. Tokens are made with `nbake tokens` (admin); a token of tenant B asking for tenant A's job,
event stream, artifact or asset gets 404 (NOT_FOUND) over REST, SSE, gRPC and the inference service, as if
it did not exist; identical work is one job per tenant; an admin token sees every tenant; a revoked token
gets 401 at its next request."""

from __future__ import annotations

import hashlib
import json
import sqlite3
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass

import grpc
import httpx
import pytest
from neuralbake.v1 import (
    artifacts_pb2,
    artifacts_pb2_grpc,
    inference_pb2,
    inference_pb2_grpc,
    jobs_pb2,
    jobs_pb2_grpc,
)
from neuralbake_client.cli.main import app
from typer.testing import CliRunner

from tests.integration import test_grpc_server as grpc_server
from tests.integration.test_api_assets import CUBE_OBJ, scene_yaml
from tests.integration.test_api_server import NBAKE, TOKENS
from tests.integration.test_grpc_server import TINY, Served
from tests.integration.test_sdk_inference import wait_ready
from tests.support.ports import free_port

served = grpc_server.served  # fixture

RENDER = {"kind": "render", "scene": "cornell_box", "preset": "quick", "config": TINY}
FILES = [("scene.yaml", scene_yaml()), ("meshes/cube.obj", CUBE_OBJ)]


def nbake(server: Served, *args: str, token: str = TOKENS["admin"]) -> tuple[int, str, str]:
    """`nbake ARGS --url ... --token ... --json` run in this process against the server."""
    done = CliRunner().invoke(app, [*args, "--url", server.url, "--token", token, "--json"])
    return done.exit_code, done.stdout, done.stderr


def create_token(server: Served, tenant: str, scope: str) -> str:
    code, out, err = nbake(server, "tokens", "create", "--tenant", tenant, "--scope", scope, "--name", "test")
    assert code == 0, err
    created = json.loads(out)
    assert created["tenant"] == tenant and created["scope"] == scope and created["source"] == "created"
    return created["token"]


@dataclass
class Tenants:
    served: Served
    tokens: dict[str, str]  # "a-read", "a-submit", "b-read", "b-submit"
    job: dict  # tenant A's succeeded tiny render
    asset: str  # uploaded by tenant A

    def http(self, who: str) -> httpx.Client:
        token = TOKENS["admin"] if who == "admin" else self.tokens[who]
        return httpx.Client(
            base_url=self.served.url, headers={"Authorization": f"Bearer {token}"}, timeout=60
        )

    def metadata(self, who: str) -> tuple:
        return (("authorization", f"Bearer {self.tokens[who]}"),)


@pytest.fixture(scope="module")
def tenants(served) -> Iterator[Tenants]:
    tokens = {
        f"{t}-{s}": create_token(served, name, s)
        for t, name in (("a", "acme"), ("b", "bolt"))
        for s in ("read", "submit")
    }
    with httpx.Client(base_url=served.url, timeout=60) as http:
        a_submit = {"Authorization": f"Bearer {tokens['a-submit']}"}
        job = http.post("/v1/jobs", json=RENDER, headers=a_submit).json()
        asset = http.post("/v1/assets", files=[("files", f) for f in FILES], headers=a_submit).json()
        deadline = time.monotonic() + 240
        while job["state"] not in ("SUCCEEDED", "FAILED", "CANCELLED"):
            assert time.monotonic() < deadline, job
            time.sleep(0.3)
            job = http.get(f"/v1/jobs/{job['id']}", headers=a_submit).json()
    assert job["state"] == "SUCCEEDED", job
    yield Tenants(served, tokens, job, asset["asset_id"])


@pytest.fixture(scope="module")
def inference(served, tenants) -> Iterator[tuple[str, str]]:
    """`nbake serve-inference` over the served data dir (its store, its job database): (REST URL, gRPC)."""
    http_port, grpc_port = free_port(), free_port()
    command = [NBAKE, "serve-inference", "--port", str(http_port), "--grpc-port", str(grpc_port)]
    command += ["--data-dir", str(served.data_dir), "--device", "cpu", "--log-level", "warning"]
    log = served.data_dir / "tenancy-inference.log"
    with log.open("wb") as sink:
        process = subprocess.Popen(command, stdout=sink, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        url = f"http://127.0.0.1:{http_port}"
        wait_ready(process, log, url)
        yield url, f"127.0.0.1:{grpc_port}"
    finally:
        process.terminate()
        process.wait(30)


# ---------------------------------------------------------------------------------------------- REST, SSE


def test_another_tenants_job_events_and_artifact_are_not_found_over_rest(tenants):
    job, artifact = tenants.job, tenants.job["artifact_id"]
    paths = [
        f"/v1/jobs/{job['id']}",
        f"/v1/jobs/{job['id']}/events",
        f"/v1/artifacts/{artifact}",
        f"/v1/artifacts/{artifact}/files/image.exr",
        f"/v1/assets/{tenants.asset}",
    ]
    with tenants.http("b-read") as b, tenants.http("a-read") as a, tenants.http("admin") as admin:
        for path in paths:
            assert b.get(path).status_code == 404, path
            assert a.get(path).status_code == 200, path
            assert admin.get(path).status_code == 200, path
        unknown = b.get(f"/v1/jobs/job-{'0' * 32}").json()
        assert b.get(f"/v1/jobs/{job['id']}").json()["title"] == unknown["title"]  # no difference to probe
        assert job["id"] not in {j["id"] for j in b.get("/v1/jobs", params={"limit": 200}).json()["items"]}
        assert job["id"] in {j["id"] for j in a.get("/v1/jobs", params={"limit": 200}).json()["items"]}
        listed = admin.get("/v1/jobs", params={"limit": 200}).json()["items"]
        everyone = {j["id"]: j["tenant"] for j in listed}
        assert job["tenant"] == "acme" and everyone[job["id"]] == "acme"  # an admin sees whose a job is
    with tenants.http("b-submit") as b:
        assert b.post(f"/v1/jobs/{job['id']}:cancel").status_code == 404
        named = b.post("/v1/jobs", json=RENDER | {"scene": tenants.asset})
        assert named.status_code == 422 and named.json()["field"] == "scene"


def test_identical_work_is_one_job_per_tenant(tenants):
    with tenants.http("a-submit") as a, tenants.http("b-submit") as b:
        again = a.post("/v1/jobs", json=RENDER)
        assert again.status_code == 200 and again.json()["id"] == tenants.job["id"]
        theirs = b.post("/v1/jobs", json=RENDER)
        assert theirs.status_code == 201 and theirs.json()["id"] != tenants.job["id"]
        assert b.post("/v1/jobs", json=RENDER).json()["id"] == theirs.json()["id"]
        assert b.post(f"/v1/jobs/{theirs.json()['id']}:cancel").status_code in (200, 202, 409)


def test_the_same_upload_is_one_asset_seen_by_each_uploader_only(tenants):
    with tenants.http("b-submit") as b, tenants.http("a-read") as a:
        assert b.get(f"/v1/assets/{tenants.asset}").status_code == 404
        uploaded = b.post("/v1/assets", files=[("files", f) for f in FILES])
        assert uploaded.status_code == 201 and uploaded.json()["asset_id"] == tenants.asset  # shared blobs
        assert b.get(f"/v1/assets/{tenants.asset}").status_code == 200
        assert a.get(f"/v1/assets/{tenants.asset}").status_code == 200


# ---------------------------------------------------------------------------------------------- gRPC


def test_another_tenants_job_stream_and_artifact_are_not_found_over_grpc(tenants):
    job_id, artifact = tenants.job["id"], tenants.job["artifact_id"]
    with grpc.insecure_channel(tenants.served.grpc_target) as channel:
        jobs = jobs_pb2_grpc.JobServiceStub(channel)
        artifacts = artifacts_pb2_grpc.ArtifactServiceStub(channel)
        calls = [
            lambda m: jobs.GetJob(jobs_pb2.GetJobRequest(job_id=job_id), metadata=m, timeout=30),
            lambda m: list(jobs.WatchJob(jobs_pb2.WatchJobRequest(job_id=job_id), metadata=m, timeout=30)),
            lambda m: artifacts.GetManifest(
                artifacts_pb2.GetManifestRequest(artifact_id=artifact), metadata=m, timeout=30
            ),
            lambda m: list(
                artifacts.DownloadFile(
                    artifacts_pb2.DownloadFileRequest(artifact_id=artifact, name="image.exr"),
                    metadata=m,
                    timeout=30,
                )
            ),
        ]
        for call in calls:
            with pytest.raises(grpc.RpcError) as refused:
                call(tenants.metadata("b-read"))
            assert refused.value.code() == grpc.StatusCode.NOT_FOUND
            assert call(tenants.metadata("a-read"))
        with pytest.raises(grpc.RpcError) as refused:
            jobs.CancelJob(jobs_pb2.CancelJobRequest(job_id=job_id), metadata=tenants.metadata("b-submit"))
        assert refused.value.code() == grpc.StatusCode.NOT_FOUND
        listed = jobs.ListJobs(jobs_pb2.ListJobsRequest(page_size=200), metadata=tenants.metadata("b-read"))
        assert job_id not in {j.id for j in listed.jobs}
        mine = jobs.GetJob(jobs_pb2.GetJobRequest(job_id=job_id), metadata=tenants.metadata("a-read"))
        assert mine.job.tenant == "acme"


# ---------------------------------------------------------------------------------------------- inference


def test_another_tenants_artifact_is_not_found_by_the_inference_service(tenants, inference):
    url, target = inference
    artifact = tenants.job["artifact_id"]
    headers = {"Accept": "image/x-exr"}
    with httpx.Client(base_url=url, timeout=120) as http:
        for who, status in (("b-read", 404), ("a-read", 200)):
            auth = {"Authorization": f"Bearer {tenants.tokens[who]}"}
            assert http.post(
                f"/v1/artifacts/{artifact}:render", json={}, headers=auth | headers
            ).status_code == (status), who
            assert http.post(f"/v1/models/{artifact}:load", headers=auth).status_code == status, who
        b_models = http.get("/v1/models", headers={"Authorization": f"Bearer {tenants.tokens['b-read']}"})
        assert artifact not in {m["artifact_id"] for m in b_models.json()}  # loaded, but not theirs
        a_models = http.get("/v1/models", headers={"Authorization": f"Bearer {tenants.tokens['a-read']}"})
        assert artifact in {m["artifact_id"] for m in a_models.json()}
    with grpc.insecure_channel(target) as channel:
        stub = inference_pb2_grpc.InferenceServiceStub(channel)
        request = inference_pb2.RenderRequest(artifact_id=artifact)
        with pytest.raises(grpc.RpcError) as refused:
            stub.Render(request, metadata=tenants.metadata("b-read"), timeout=60)
        assert refused.value.code() == grpc.StatusCode.NOT_FOUND
        assert stub.Render(request, metadata=tenants.metadata("a-read"), timeout=60).data
        listed = stub.ListModels(inference_pb2.ListModelsRequest(), metadata=tenants.metadata("b-read"))
        assert artifact not in {m.artifact_id for m in listed.models}


# ---------------------------------------------------------------------------------------------- tokens


def test_nbake_tokens_create_list_revoke_round_trip(served):
    secret = create_token(served, "carol", "read")
    assert secret.startswith("nbk_")
    headers = {"Authorization": f"Bearer {secret}"}
    assert httpx.get(f"{served.url}/v1/jobs", headers=headers, timeout=30).status_code == 200

    code, out, err = nbake(served, "tokens", "list")
    assert code == 0, err
    listed = [json.loads(line) for line in out.splitlines()]
    assert secret not in out and all("token" not in t for t in listed)
    (mine,) = [t for t in listed if t["tenant"] == "carol"]
    assert mine["scope"] == "read" and mine["source"] == "created" and mine["name"] == "test"
    assert {"default"} <= {t["tenant"] for t in listed if t["source"] == "configured"}
    with sqlite3.connect(served.data_dir / "jobs.db") as database:  # stored hashed, never in clear
        rows = database.execute("SELECT * FROM api_tokens").fetchall()
    assert hashlib.sha256(secret.encode()).hexdigest() in {row[0] for row in rows}
    assert not any(secret in str(value) for row in rows for value in row)

    assert nbake(served, "tokens", "list", token=secret)[0] == 4  # not an admin: 403
    code, _, err = nbake(served, "tokens", "revoke", mine["id"])
    assert code == 0, err
    revoked = httpx.get(f"{served.url}/v1/jobs", headers=headers, timeout=30)
    assert revoked.status_code == 401 and revoked.json()["detail"] == "unknown token"
    configured = next(t for t in listed if t["source"] == "configured")
    code, _, err = nbake(served, "tokens", "revoke", configured["id"])
    assert code == 2 and "NBAKE_TOKENS" in err  # 409: configured tokens are revoked in the configuration
    assert nbake(served, "tokens", "revoke", "tok-nope")[0] == 2  # 404
