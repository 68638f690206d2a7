"""Batch submission (`POST /v1/jobs:batch`, gRPC `SubmitJobs`, `Client.submit_many`) through the shared
`nbake serve`: jobs come back in order, identical work reused; one bad job refuses the whole batch with
its field named under `jobs[i]` and nothing stored; the tenant's queued quota counts the batch's own jobs;
the same Idempotency-Key gives the same jobs. The tenant's running quota is 0, so nothing trains."""

from __future__ import annotations

from collections.abc import Iterator

import grpc
import httpx
import pytest
from neuralbake.v1 import jobs_pb2, jobs_pb2_grpc
from neuralbake_client import Client, InvalidRequest

from tests.integration import test_grpc_server as grpc_server
from tests.integration.test_api_server import TOKENS
from tests.integration.test_grpc_server import TINY, config, details, rpc_error
from tests.integration.test_tenancy import create_token

served = grpc_server.served  # fixture
TENANT = "batch-acme"  # of this module only: the server is shared
ADMIN = {"Authorization": f"Bearer {TOKENS['admin']}"}
RENDER = {"kind": "render", "scene": "cornell_box", "preset": "quick", "config": TINY}


@pytest.fixture(scope="module")
def token(served) -> Iterator[str]:
    """A submit token of a tenant whose jobs never start (running quota 0); its jobs are cancelled after."""
    with httpx.Client(base_url=served.url, headers=ADMIN, timeout=60) as admin:
        admin.put(f"/v1/tenants/{TENANT}/quotas", json={"max_running": 0}).raise_for_status()
        yield create_token(served, TENANT, "submit")
        for job in admin.get("/v1/jobs", params={"state": "QUEUED", "limit": 200}).json()["items"]:
            if job["tenant"] == TENANT:
                admin.post(f"/v1/jobs/{job['id']}:cancel")
        admin.put(f"/v1/tenants/{TENANT}/quotas", json={}).raise_for_status()


@pytest.fixture
def http(served, token) -> Iterator[httpx.Client]:
    with httpx.Client(
        base_url=served.url, headers={"Authorization": f"Bearer {token}"}, timeout=120
    ) as client:
        yield client


def queued(http: httpx.Client) -> int:
    with httpx.Client(base_url=http.base_url, headers=ADMIN, timeout=60) as admin:
        return admin.get(f"/v1/tenants/{TENANT}/quotas").json()["use"]["queued"]


def test_a_batch_queues_its_jobs_in_order_and_reuses_identical_work(http):
    first = http.post("/v1/jobs", json=RENDER | {"seed": 10}).json()
    jobs = [RENDER | {"seed": 11}, RENDER | {"seed": 10}, RENDER | {"seed": 12}, RENDER | {"seed": 11}]
    answer = http.post("/v1/jobs:batch", json={"jobs": jobs}, headers={"Idempotency-Key": "build-1"})
    assert answer.status_code == 200, answer.text
    items = answer.json()["items"]
    assert [item["job"]["seed"] for item in items] == [11, 10, 12, 11]
    assert [item["created"] for item in items] == [True, False, True, False]
    assert items[1]["job"]["id"] == first["id"] and items[3]["job"]["id"] == items[0]["job"]["id"]
    assert all(item["job"]["tenant"] == TENANT and item["job"]["state"] == "QUEUED" for item in items)
    again = http.post("/v1/jobs:batch", json={"jobs": jobs}, headers={"Idempotency-Key": "build-1"})
    assert [i["job"]["id"] for i in again.json()["items"]] == [i["job"]["id"] for i in items]
    assert not any(i["created"] for i in again.json()["items"])


def test_one_bad_job_refuses_the_whole_batch_naming_it(http):
    before = queued(http)
    jobs = [RENDER | {"seed": 20}, RENDER | {"seed": 21, "config": TINY | {"spp": 0}}, RENDER | {"seed": 22}]
    refused = http.post("/v1/jobs:batch", json={"jobs": jobs})
    assert refused.status_code == 422, refused.text
    assert refused.headers["content-type"] == "application/problem+json"
    assert refused.json()["field"] == "jobs[1].config.spp"
    unknown = http.post("/v1/jobs:batch", json={"jobs": [RENDER, RENDER | {"scene": "no_such_scene"}]})
    assert unknown.status_code == 422 and unknown.json()["field"] == "jobs[1].scene", unknown.text
    assert queued(http) == before
    assert http.post("/v1/jobs:batch", json={"jobs": []}).status_code == 422


def test_the_queued_quota_counts_the_batchs_own_jobs(http, served):
    before = queued(http)
    with httpx.Client(base_url=served.url, headers=ADMIN, timeout=60) as admin:
        admin.put(f"/v1/tenants/{TENANT}/quotas", json={"max_running": 0, "max_queued": before + 2})
        try:
            jobs = [RENDER | {"seed": seed} for seed in (30, 31, 32)]
            refused = http.post("/v1/jobs:batch", json={"jobs": jobs})
            assert refused.status_code == 429 and refused.json()["field"] == "jobs[2]", refused.text
            assert int(refused.headers["Retry-After"]) >= 1
            assert queued(http) == before  # all or nothing: the first two were not kept
        finally:
            admin.put(f"/v1/tenants/{TENANT}/quotas", json={"max_running": 0})


def test_submit_jobs_over_grpc(served, token):
    metadata = (("authorization", f"Bearer {token}"),)
    request = jobs_pb2.SubmitJobsRequest(
        jobs=[
            jobs_pb2.SubmitJobRequest(kind="render", scene_ref="cornell_box", config=config(TINY), seed=seed)
            for seed in (40, 41)
        ]
    )
    with grpc.insecure_channel(served.grpc_target) as channel:
        stub = jobs_pb2_grpc.JobServiceStub(channel)
        answer = stub.SubmitJobs(request, metadata=metadata)
        assert [item.job.seed for item in answer.items] == [40, 41] and all(i.created for i in answer.items)
        request.jobs[1].config.update({"spp": 0})
        error = rpc_error(stub.SubmitJobs, request, metadata=metadata)
    assert error.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert details(error)["field"] == "jobs[1].config.spp"


@pytest.mark.parametrize("transport", ["rest", "grpc"])
def test_the_sdk_submits_many_and_says_which_were_reused(served, token, transport):
    url = served.url if transport == "rest" else served.grpc_url
    with Client(url, token) as client:
        jobs = [{"kind": "render", "scene": "cornell_box", "config": TINY, "seed": 50 + i} for i in range(3)]
        made = client.submit_many(jobs)
        assert [job.seed for job in made] == [50, 51, 52]
        assert [job.reused for job in made] == [transport == "grpc"] * 3  # the REST run made them first
        with pytest.raises(InvalidRequest) as refused:
            client.submit_many([*jobs, {"kind": "rendr", "scene": "cornell_box"}])
        assert refused.value.field == "jobs[3].kind"
