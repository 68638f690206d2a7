"""PostgreSQL restarted under a running job, on a private instance (`pg_ctl` on a free port, so the
machine's server is untouched): while it is down the API answers 503 with Retry-After and changes
nothing; when it is back, the job finishes, its events are all there in order, and no job is lost."""

from __future__ import annotations

import time

import pytest
from sqlalchemy import text

import services.jobs.db as db_module
from services.jobs.db import Database
from tests.integration.test_api_server import (
    FINAL,
    QUICK_RENDER,
    DatabaseChoice,
    ServerThread,
    events,
    problem_of,
    settings_for,
    submit,
    wait_for,
)
from tests.support.postgres import PrivatePostgres


@pytest.fixture
def postgres():
    with PrivatePostgres() as running:
        yield running


def test_a_pooled_connection_idle_across_a_restart_is_pinged_and_replaced(postgres, monkeypatch):
    """Pooled connections are pinged only after `PING_IDLE_S` idle (not at every checkout, a round trip per
    read): one left over from before a restart is found dead by its ping and replaced, and the read works."""
    db = Database(postgres.url)
    try:
        db.ping()  # leaves one connection in the pool
        postgres.stop("fast")
        postgres.start()
        monkeypatch.setattr(db_module, "PING_IDLE_S", 0.0)  # it has been idle long enough
        with db.reading() as session:
            assert session.execute(text("SELECT 1")).scalar_one() == 1
    finally:
        db.dispose()


@pytest.mark.slow  # a private PostgreSQL, a server and a render job: about two minutes on the shared machine
def test_a_database_restart_mid_job_is_503_then_nothing_is_lost(ray_cluster, postgres, tmp_path):
    settings = settings_for(tmp_path / "data", DatabaseChoice("postgresql", postgres.url), max_running=1)
    with ServerThread(settings) as server, server.client("admin") as client:
        config = {"spp": 64, "width": 64, "height": 64, "checkpoint_interval_s": 0}
        job = submit(client, **{**QUICK_RENDER, "config": config})
        wait_for(client, job["id"], {"RUNNING", *FINAL})
        postgres.stop("fast")
        try:
            down = client.get(f"/v1/jobs/{job['id']}")
            assert problem_of(down, 503)["title"] == "Database unavailable"
            assert int(down.headers["retry-after"]) > 0
            refused = client.post("/v1/jobs", json={**QUICK_RENDER, "seed": 99})
            problem_of(refused, 503)
            assert client.get("/readyz").status_code == 503
            time.sleep(2)  # the job's driver goes on; its events wait for the database
        finally:
            postgres.start()
        done = wait_for(client, job["id"], FINAL, timeout=300)
        assert done["state"] == "SUCCEEDED", done["error"]
        listed = client.get("/v1/jobs").json()["items"]
        assert [j["id"] for j in listed] == [job["id"]]  # the refused submission made nothing
        stored = events(client, job["id"])  # every stored event, through the SSE stream
        assert [e["seq"] for e in stored] == list(range(1, len(stored) + 1))
        states = [e["data"]["state"] for e in stored if e["type"] == "state"]
        assert states[0] == "QUEUED" and states[-1] == "SUCCEEDED"
