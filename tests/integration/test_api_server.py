"""The job server as users reach it: a real uvicorn server on a free loopback port, real Ray, real SQLite
and (when NBAKE_TEST_POSTGRES_URL is set) real PostgreSQL. This module holds the fixtures the other
`test_api_*` / `test_jobs_*` modules import, and tests the open endpoints, auth and `nbake serve` itself.
"""

from __future__ import annotations

import json
import os
import socket
import stat
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest
import ray
import uvicorn
from sqlalchemy import create_engine, text

from services.api.app import create_app
from services.api.settings import ServiceSettings
from services.jobs.db import normalize_url

POSTGRES_ENV = "NBAKE_TEST_POSTGRES_URL"
TOKENS = {"admin": "test-admin-token", "submit": "test-submit-token", "read": "test-read-token"}
TOKENS_ENV = ",".join(f"{token}:{scope}" for scope, token in TOKENS.items())
FINAL = {"SUCCEEDED", "FAILED", "CANCELLED"}
NBAKE = str(Path(sys.executable).with_name("nbake"))
QUICK_RENDER = {"kind": "render", "scene": "cornell_box", "preset": "quick"}


# ---------------------------------------------------------------------------------------------- databases


@dataclass
class DatabaseChoice:
    name: str
    url: str | None  # None: the server's default SQLite file in its data dir
    schema: str | None = None


def postgres_url() -> str:
    url = os.environ.get(POSTGRES_ENV)
    if not url:
        reason = f"{POSTGRES_ENV} is not set, so the PostgreSQL variant cannot run (.ci/run sets it)"
        print(f"SKIP: {reason}", file=sys.stderr)
        pytest.skip(reason)
    return url


@pytest.fixture(scope="module", params=["sqlite", "postgresql"])
def database(request) -> Iterator[DatabaseChoice]:
    """Each variant of the suite: SQLite, or a private schema on the test PostgreSQL, dropped after. For
    modules that test what the database does: job states, queries, events, recovery."""
    yield from choose_database(request.param)


@pytest.fixture(scope="module", params=["sqlite", pytest.param("postgresql", marks=pytest.mark.slow)])
def incidental_database(request) -> Iterator[DatabaseChoice]:
    """`database` for modules that test something else through the server (rendering, validation, files):
    their PostgreSQL variant repeats the same jobs for no new coverage, so it runs with `make test-all`."""
    yield from choose_database(request.param)


def choose_database(name: str) -> Iterator[DatabaseChoice]:
    if name == "sqlite":
        yield DatabaseChoice("sqlite", None)
        return
    url = postgres_url()
    schema = f"nbt_{uuid.uuid4().hex[:12]}"
    yield DatabaseChoice("postgresql", url, schema)
    drop_schema(url, schema)


def drop_schema(url: str, schema: str) -> None:
    engine = create_engine(normalize_url(url))
    with engine.begin() as connection:
        connection.execute(text(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE'))
    engine.dispose()


# ---------------------------------------------------------------------------------------------- servers


class ServerThread:
    """uvicorn serving `create_app(settings)` on a thread, on a socket bound before it starts."""

    def __init__(self, settings: ServiceSettings):
        self.settings = settings
        self.socket = socket.socket()
        self.socket.bind(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.socket.getsockname()[1]}"
        config = uvicorn.Config(create_app(settings), log_level="warning", lifespan="on")
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.socket]}, daemon=True)

    def __enter__(self) -> ServerThread:
        self.thread.start()
        deadline = time.monotonic() + 60
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("the test server did not start")
            time.sleep(0.05)
        return self

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=60)
        self.socket.close()

    def client(self, scope: str | None = "admin") -> httpx.Client:
        headers = {"Authorization": f"Bearer {TOKENS[scope]}"} if scope else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=60)


def settings_for(data_dir: Path, database: DatabaseChoice, **overrides) -> ServiceSettings:
    return ServiceSettings(
        data_dir=data_dir,
        database_url=database.url,
        database_schema=database.schema,
        tokens=TOKENS_ENV,
        **overrides,
    )


@pytest.fixture(scope="module")
def server(ray_cluster, database, tmp_path_factory) -> Iterator[ServerThread]:
    """One server per module and database variant (jobs are independent: each test submits its own)."""
    data_dir = tmp_path_factory.mktemp(f"server-{database.name}")
    with ServerThread(settings_for(data_dir, database, max_running=2)) as running:
        yield running


@pytest.fixture
def client(server) -> Iterator[httpx.Client]:
    with server.client("admin") as http:
        yield http


# ---------------------------------------------------------------------------------------------- helpers


def submit(client: httpx.Client, expect: int = 201, headers: dict | None = None, **body) -> dict:
    response = client.post("/v1/jobs", json=body, headers=headers)
    assert response.status_code == expect, response.text
    return response.json()


def events(
    client: httpx.Client, job_id: str, last_event_id: int | None = None, timeout: float = 240
) -> list[dict]:
    """Follow a job's SSE stream until the server ends it (after the final state); the parsed events."""
    headers = {"Last-Event-ID": str(last_event_id)} if last_event_id is not None else {}
    parsed, fields, deadline = [], {}, time.monotonic() + timeout
    with client.stream("GET", f"/v1/jobs/{job_id}/events", headers=headers, timeout=60) as response:
        assert response.status_code == 200, response.read()
        assert response.headers["content-type"].startswith("text/event-stream")
        for line in response.iter_lines():  # a keep-alive comment arrives at least every 15 s
            assert time.monotonic() < deadline, (
                f"no final state within {timeout} s; events so far: {parsed}; {ray_state()}"
            )
            if line == "":
                if "data" in fields:
                    event = json.loads(fields["data"])
                    assert int(fields["id"]) == event["seq"] and fields["event"] == event["type"]
                    parsed.append(event)
                fields = {}
            elif not line.startswith(":"):
                name, _, value = line.partition(":")
                fields[name] = value.removeprefix(" ")
    return parsed


def ray_state() -> str:
    """What this process's Ray cluster holds, for the message of a test whose job made no progress (one
    CI run beside a benchmark had three jobs in a row wait 240-600 s without a progress event; a job
    waiting for sampler CPUs shows here what holds them)."""
    if not ray.is_initialized():
        return "Ray is not initialised in this process"
    reservations = {k: (v["state"], v["bundles"]) for k, v in ray.util.placement_group_table().items()}
    return (
        f"Ray resources {ray.cluster_resources()}, available {ray.available_resources()}, "
        f"placement groups {reservations}"
    )


def wait_for(client: httpx.Client, job_id: str, states: set[str], timeout: float = 180) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["state"] in states:
            return job
        assert time.monotonic() < deadline, f"job stayed {job['state']}: {job}"
        time.sleep(0.1)


def problem_of(response: httpx.Response, status: int) -> dict:
    """The problem+json body of an error response, checked for the shape every error has."""
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/problem+json"
    body = response.json()
    assert body["status"] == status and body["title"] and body["detail"]
    return body


# ---------------------------------------------------------------------------------------------- tests


def test_health_readiness_and_metrics_are_open(server):
    with server.client(None) as anonymous:
        assert anonymous.get("/healthz").json() == {"status": "ok"}
        ready = anonymous.get("/readyz")
        assert ready.status_code == 200
        assert ready.json()["checks"] == {"database": "ok", "store": "ok", "ray": "ok"}
        metrics = anonymous.get("/metrics")
        assert metrics.status_code == 200
        assert 'nbake_jobs{state="QUEUED"}' in metrics.text
        for name in (
            "nbake_job_queue_wait_seconds",
            "nbake_job_duration_seconds",
            "nbake_job_samples_per_second",
        ):
            assert f"# TYPE {name}" in metrics.text


def test_openapi_documents_every_route(server):
    with server.client(None) as anonymous:
        spec = anonymous.get("/openapi.json").json()
        assert anonymous.get("/docs").status_code == 200
    assert {
        "/v1/jobs",
        "/v1/jobs/{job_id}",
        "/v1/jobs/{job_id}:cancel",
        "/v1/jobs/{job_id}/events",
        "/v1/assets",
        "/v1/assets/{asset_id}",
        "/v1/artifacts/{artifact_id}",
        "/v1/artifacts/{artifact_id}/files/{name}",
        "/healthz",
        "/readyz",
        "/metrics",
    } <= set(spec["paths"])
    submit_op = spec["paths"]["/v1/jobs"]["post"]
    assert {"201", "200", "401", "403", "422"} <= set(submit_op["responses"])
    assert "HTTPBearer" in spec["components"]["securitySchemes"]


def test_missing_or_unknown_token_is_401(server):
    with server.client(None) as anonymous:
        body = problem_of(anonymous.get("/v1/jobs"), 401)
        assert "Bearer" in body["detail"]
        assert anonymous.get("/v1/jobs").headers["www-authenticate"] == "Bearer"
        wrong = anonymous.get("/v1/jobs", headers={"Authorization": "Bearer not-a-token"})
        assert problem_of(wrong, 401)["detail"] == "unknown token"


def test_token_lacking_the_scope_is_403(server):
    with server.client("read") as reader:
        assert reader.get("/v1/jobs").status_code == 200
        body = problem_of(reader.post("/v1/jobs", json=QUICK_RENDER), 403)
        assert "submit" in body["detail"]
        problem_of(reader.post("/v1/jobs/job-x:cancel"), 403)


def test_without_configured_tokens_an_admin_token_file_is_generated(ray_cluster, tmp_path):
    settings = ServiceSettings(data_dir=tmp_path)
    with ServerThread(settings) as running:
        path = tmp_path / "admin-token"
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
        token = path.read_text().strip()
        with httpx.Client(base_url=running.url, headers={"Authorization": f"Bearer {token}"}) as http:
            assert http.get("/v1/jobs").status_code == 200
    with ServerThread(settings):
        assert path.read_text().strip() == token  # reused, not replaced, on the next start


def test_serve_refuses_a_non_loopback_host_without_tokens(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("NBAKE_TOKENS", "NBAKE_TOKENS_FILE")}
    done = subprocess.run(
        [
            NBAKE,
            "serve",
            "--host",
            "0.0.0.0",
            "--data-dir",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )
    assert done.returncode == 2
    assert "--host" in done.stderr and "NBAKE_TOKENS" in done.stderr
