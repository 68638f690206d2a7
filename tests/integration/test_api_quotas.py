"""Tenant quotas through the shared `nbake serve` (`served`): set and shown with `nbake tokens quota`; a
submission over the queued quota is a 429 problem+json with Retry-After (RESOURCE_EXHAUSTED over gRPC)
naming the quota, its limit and the tenant's use; identical work is answered with its job even at the
limit; a priority over the tenant's ceiling is a 422 naming the field; the scheduler starts none of a
tenant's jobs while it is at its running quota, and starts them once the quota is raised."""

from __future__ import annotations

import json
import time

import grpc
import httpx
import pytest
from neuralbake.v1 import jobs_pb2, jobs_pb2_grpc

from tests.integration import test_grpc_server as grpc_server
from tests.integration.test_api_server import TOKENS
from tests.integration.test_grpc_server import TINY, Served, config, details, rpc_error
from tests.integration.test_tenancy import create_token, nbake

served = grpc_server.served  # fixture

TENANT = "quota-acme"  # of this module only: the server is shared
ADMIN = {"Authorization": f"Bearer {TOKENS['admin']}"}
RENDER = {"kind": "render", "scene": "cornell_box", "preset": "quick", "config": TINY}


@pytest.fixture(autouse=True)
def _default_quotas(served):
    """Each test starts from the tenant's default quotas."""
    with httpx.Client(base_url=served.url, headers=ADMIN, timeout=60) as http:
        http.put(f"/v1/tenants/{TENANT}/quotas", json={}).raise_for_status()


def quota(served: Served, *options: str) -> dict:
    code, out, err = nbake(served, "tokens", "quota", TENANT, *options)
    assert code == 0, err + out
    shown = json.loads(out)
    assert shown["event"] == "quotas" and shown["tenant"] == TENANT
    return shown


def wait_for(http: httpx.Client, job_id: str, states: set[str], timeout: float = 240) -> dict:
    deadline = time.monotonic() + timeout
    while (job := http.get(f"/v1/jobs/{job_id}").json())["state"] not in states:
        assert time.monotonic() < deadline, job
        time.sleep(0.3)
    return job


def test_nbake_tokens_quota_sets_and_shows_a_tenants_quotas(served):
    defaults = quota(served)["defaults"]
    shown = quota(
        served, "--max-running", "2", "--max-queued", "20", "--max-compute", "4h", "--max-priority", "7"
    )
    assert shown["own"] == {"max_running": 2, "max_queued": 20, "max_compute_s": 14400.0, "max_priority": 7}
    assert shown["limits"] == shown["own"] and shown["updated_at"]
    assert shown["use"] == {"running": 0, "queued": 0, "compute_s": 0.0}
    kept = quota(served, "--max-compute", "default")  # the others stay
    assert kept["own"] == shown["own"] | {"max_compute_s": None}
    assert kept["limits"]["max_compute_s"] == defaults["max_compute_s"]
    code, out, err = nbake(served, "tokens", "quota", TENANT, "--max-queued", "-3")
    assert code == 2 and "--max-queued" in err + out
    submitter = create_token(served, TENANT, "submit")
    code, out, err = nbake(served, "tokens", "quota", TENANT, token=submitter)
    assert code != 0 and "403" in err + out  # an admin's


def test_the_queued_quota_priority_ceiling_and_running_quota_hold_a_tenant(served):
    token = create_token(served, TENANT, "submit")
    headers = {"Authorization": f"Bearer {token}"}
    quota(served, "--max-running", "0", "--max-queued", "1", "--max-priority", "5")
    with httpx.Client(base_url=served.url, headers=headers, timeout=60) as http:
        first = http.post("/v1/jobs", json=RENDER)
        assert first.status_code == 201 and first.json()["state"] == "QUEUED", first.text
        job_id = first.json()["id"]

        refused = http.post("/v1/jobs", json=RENDER | {"seed": 1})
        assert refused.status_code == 429, refused.text
        assert refused.headers["content-type"] == "application/problem+json"
        assert int(refused.headers["Retry-After"]) >= 1
        problem = refused.json()
        assert (problem["quota"], problem["limit"], problem["current"]) == ("max_queued", 1, 1)
        assert "field" not in problem and TENANT in problem["detail"] and "max_queued" in problem["detail"]

        again = http.post("/v1/jobs", json=RENDER)  # identical work: its job, not counted against the quota
        assert again.status_code == 200 and again.json()["id"] == job_id

        high = http.post("/v1/jobs", json=RENDER | {"seed": 2, "priority": 6})
        assert high.status_code == 422 and high.json()["field"] == "priority", high.text
        assert "ceiling of 5" in high.json()["detail"] and high.json()["limit"] == 5

        with grpc.insecure_channel(served.grpc_target) as channel:
            request = jobs_pb2.SubmitJobRequest(
                kind="render", scene_ref="cornell_box", preset="quick", config=config(TINY), seed=1
            )
            stub = jobs_pb2_grpc.JobServiceStub(channel)
            error = rpc_error(stub.SubmitJob, request, metadata=(("authorization", f"Bearer {token}"),))
        assert error.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
        found = details(error)
        assert {k: found.get(k) for k in ("quota", "limit", "current")} == {
            "quota": "max_queued",
            "limit": "1",
            "current": "1",
        }

        # another tenant's job, submitted later, runs while this tenant's waits at its running quota of 0
        with httpx.Client(base_url=served.url, headers=ADMIN, timeout=60) as admin:
            other = admin.post("/v1/jobs", json=RENDER | {"force": True}).json()
            assert wait_for(admin, other["id"], {"SUCCEEDED", "FAILED"})["state"] == "SUCCEEDED"
        assert http.get(f"/v1/jobs/{job_id}").json()["state"] == "QUEUED"
        assert quota(served)["use"]["queued"] == 1

        quota(served, "--max-running", "1")
        assert wait_for(http, job_id, {"SUCCEEDED", "FAILED", "CANCELLED"})["state"] == "SUCCEEDED"
        assert quota(served)["use"] == {"running": 0, "queued": 0, "compute_s": 0.0}
