"""Job lifecycles through the server: cancellation, a failing job's error, a retried infrastructure
failure, pagination and filters, and resuming an event stream with Last-Event-ID."""

from __future__ import annotations

import json
import time

import pytest
import ray

from tests.integration import test_api_server as api
from tests.integration.test_api_server import (
    FINAL,
    QUICK_RENDER,
    events,
    problem_of,
    ray_state,
    submit,
    wait_for,
)
from workers.driver.jobs import NAMESPACE, actor_name
from workers.scene.generators.builtin import get_builtin

database, server, client = api.database, api.server, api.client  # fixtures
LONG_RENDER = {**QUICK_RENDER, "config": {"spp": 1 << 16}, "force": True}  # many passes: runs for minutes


def first_event(client, job_id: str, kind: str, timeout: float = 240) -> dict:
    """Read the job's stream until its first event of `kind` (then drop the connection)."""
    deadline = time.monotonic() + timeout
    with client.stream("GET", f"/v1/jobs/{job_id}/events", timeout=120) as response:
        for line in response.iter_lines():  # a keep-alive comment arrives at least every 15 s
            assert time.monotonic() < deadline, f"no {kind} event within {timeout} s; {ray_state()}"
            if line.startswith("data:"):
                event = json.loads(line.removeprefix("data:"))
                assert event["type"] == kind or event["data"].get("state") not in FINAL, event
                if event["type"] == kind:
                    return event
    raise AssertionError(f"no {kind} event")


def driver_alive(job_id: str) -> bool:
    try:
        ray.get_actor(actor_name(job_id), namespace=NAMESPACE)
    except ValueError:
        return False
    return True


@pytest.mark.database_incidental
def test_cancelling_a_running_job_stops_it(client):
    job = submit(client, **LONG_RENDER)
    first_event(client, job["id"], "progress")
    response = client.post(f"/v1/jobs/{job['id']}:cancel")
    assert response.status_code == 202 and response.json()["cancel_requested"] is True
    stream = events(client, job["id"])
    assert stream[-1]["data"]["state"] == "CANCELLED"
    assert any(e["type"] == "log" and e["data"]["message"] == "cancellation requested" for e in stream)
    done = client.get(f"/v1/jobs/{job['id']}").json()
    assert done["state"] == "CANCELLED" and done["artifact_id"] is None
    assert done["progress"]["step"] < done["progress"]["total"]
    assert not driver_alive(job["id"])
    again = client.post(f"/v1/jobs/{job['id']}:cancel")
    assert "already CANCELLED" in problem_of(again, 409)["detail"]


def test_a_failing_job_reports_a_useful_error(client):
    dark = get_builtin("cornell_box").model_dump(mode="json")
    dark["objects"] = [o for o in dark["objects"] if not o.get("emission")]
    job = submit(client, kind="render", scene=dark, preset="quick", force=True)
    stream = events(client, job["id"])
    final = stream[-1]["data"]
    assert final["state"] == "FAILED"
    assert "no light" in final["error"] and "lights" in final["error"]
    failed = client.get(f"/v1/jobs/{job['id']}").json()
    assert failed["error"] == final["error"] and failed["attempts"] == 1  # the job's fault: not retried


@pytest.mark.database_incidental
def test_an_infrastructure_failure_is_retried_from_the_checkpoint(client):
    job = submit(
        client, **{**QUICK_RENDER, "config": {"spp": 512, "checkpoint_interval_s": 0}, "force": True}
    )
    first_event(client, job["id"], "progress")
    ray.kill(ray.get_actor(actor_name(job["id"]), namespace=NAMESPACE), no_restart=True)
    stream = events(client, job["id"])
    states = [e["data"]["state"] for e in stream if e["type"] == "state"]
    assert states == ["QUEUED", "RUNNING", "QUEUED", "RUNNING", "SUCCEEDED"]
    retry = next(e["data"] for e in stream if e["type"] == "state" and e["data"].get("previous") == "RUNNING")
    assert "retrying (attempt 2 of 3)" in retry["message"] and "died" in retry["message"]
    assert any("resuming from the checkpoint" in (e["data"].get("message") or "") for e in stream)
    assert client.get(f"/v1/jobs/{job['id']}").json()["attempts"] == 2


def test_pagination_and_filters(client):
    mine = [
        submit(client, **{**QUICK_RENDER, "config": {"spp": 1}, "seed": 1000 + i})["id"] for i in range(5)
    ]
    for job_id in mine:
        client.post(f"/v1/jobs/{job_id}:cancel")
    for job_id in mine:
        wait_for(client, job_id, FINAL)
    everything = client.get("/v1/jobs", params={"limit": 200}).json()
    assert everything["next_cursor"] is None

    pages, cursor = [], None
    while True:
        page = client.get("/v1/jobs", params={"limit": 2, **({"cursor": cursor} if cursor else {})}).json()
        assert len(page["items"]) <= 2
        pages.append([job["id"] for job in page["items"]])
        cursor = page["next_cursor"]
        if cursor is None:
            break
    paged = [job_id for page in pages for job_id in page]
    assert paged == [job["id"] for job in everything["items"]]  # newest first, nothing twice, nothing lost
    assert [job_id for job_id in paged if job_id in mine] == mine[::-1]

    by_state = client.get("/v1/jobs", params=[("state", "CANCELLED"), ("state", "SUCCEEDED"), ("limit", 200)])
    assert {job["state"] for job in by_state.json()["items"]} <= {"CANCELLED", "SUCCEEDED"}
    assert set(mine) <= {job["id"] for job in by_state.json()["items"]}
    assert (
        client.get("/v1/jobs", params={"kind": "render", "limit": 200}).json()["items"] == everything["items"]
    )
    assert client.get("/v1/jobs", params={"kind": "lod"}).json() == {"items": [], "next_cursor": None}


def test_event_stream_resumes_after_last_event_id(client):
    job = submit(client, **{**QUICK_RENDER, "config": {"spp": 2}, "force": True})
    whole = events(client, job["id"])
    assert events(client, job["id"], last_event_id=2) == whole[2:]
    assert events(client, job["id"], last_event_id=whole[-1]["seq"]) == []  # nothing after the final event
    resumed = client.get(f"/v1/jobs/{job['id']}/events", params={"after": len(whole) - 1})
    assert resumed.text.count("\nevent: ") == 1 and "SUCCEEDED" in resumed.text


@pytest.mark.parametrize("path", ["/v1/jobs/job-missing", "/v1/jobs/job-missing/events"])
def test_unknown_job_is_404(client, path):
    assert problem_of(client.get(path), 404)["detail"] == "no job 'job-missing'"
