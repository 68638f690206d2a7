"""A misspelt key deep in a job's config, over REST, gRPC and the CLI: refused with the key's full path,
never answered with the earlier job that the submission equals once the key is dropped.

The server is an API-only replica (no scheduler): the stored job stays queued, which the reuse lookup
treats as it treats a succeeded one, and nothing trains.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass

import grpc
import pytest
from neuralbake.v1.jobs_pb2_grpc import JobServiceStub

from services.api.grpc.server import grpc_serving
from tests.integration import test_grpc_server as over_grpc
from tests.integration.test_api_server import (
    TOKENS,
    DatabaseChoice,
    ServerThread,
    problem_of,
    settings_for,
    submit,
)
from tests.integration.test_cli_jobs import nbake
from workers.models.registry import get_kind

KIND = "lsnif"  # a kind that trains, so its config has `train`; planning its example takes milliseconds
MISSPELT = [
    ({"train": {"stpes": 10}}, "config.train.stpes"),
    ({"train": {"schedule": {"lrr": 0.1}}}, "config.train.schedule.lrr"),
]


@dataclass
class Stored:
    server: ServerThread
    grpc_target: str
    job_id: str
    body: dict  # the stored job's submission


@pytest.fixture(scope="module")
def stored(ray_cluster, tmp_path_factory) -> Iterator[Stored]:
    """REST and gRPC on one API-only server, holding one job of the kind's example; resubmitting that job
    unchanged is answered with it (200), so a submission equal to it once a key is dropped would be too."""
    data_dir = tmp_path_factory.mktemp("strict-configs")
    with ServerThread(settings_for(data_dir, DatabaseChoice("sqlite", None), scheduling=False)) as server:
        services = server.server.config.app.state.services
        with grpc_serving(services, "127.0.0.1", 0) as grpc_server, server.client() as client:
            example = get_kind(KIND).example
            body = {"kind": KIND, "scene": example.scene, "preset": "quick", "config": example.overrides}
            job = submit(client, **body)
            assert submit(client, expect=200, **body)["id"] == job["id"]
            yield Stored(server, f"127.0.0.1:{grpc_server.port}", job["id"], body)


def with_overrides(body: dict, overrides: dict) -> dict:
    return body | {"config": body["config"] | overrides}


@pytest.mark.parametrize(("overrides", "field"), MISSPELT)
def test_rest_refuses_a_misspelt_key_naming_its_path(stored, overrides, field):
    with stored.server.client() as client:
        response = client.post("/v1/jobs", json=with_overrides(stored.body, overrides))
    assert problem_of(response, 422)["field"] == field


@pytest.mark.parametrize(("overrides", "field"), MISSPELT)
def test_grpc_refuses_a_misspelt_key_naming_its_path(stored, overrides, field):
    with grpc.insecure_channel(stored.grpc_target) as channel:
        jobs = JobServiceStub(channel)
        config = with_overrides(stored.body, overrides)["config"]
        error = over_grpc.rpc_error(over_grpc.submit, jobs, config, kind=KIND, scene_ref=stored.body["scene"])
    assert error.code() == grpc.StatusCode.INVALID_ARGUMENT
    found = over_grpc.details(error)
    assert found["field"] == found["violation"] == field


@pytest.mark.parametrize("protocol", ["rest", "grpc"])
def test_the_cli_exits_2_naming_the_misspelt_key(stored, protocol, tmp_path):
    url = stored.server.url if protocol == "rest" else f"grpc://{stored.grpc_target}"
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NBAKE_")}
    env = clean | {
        "NBAKE_URL": url,
        "NBAKE_TOKEN": TOKENS["admin"],
        "NBAKE_CONFIG": str(tmp_path / "none.toml"),
    }
    done = nbake(
        "submit",
        stored.body["scene"],
        "--kind",
        KIND,
        "--preset",
        "quick",
        "--set",
        "train.stpes=10",
        env=env,
    )
    assert done.returncode == 2, done.stdout
    assert "config.train.stpes" in done.stderr and stored.job_id not in done.stdout + done.stderr
