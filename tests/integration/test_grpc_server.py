"""The gRPC API of a real `nbake serve` (subprocess, free ports, temporary data dir, its own Ray):
health and reflection, auth, error statuses with details, deadlines, and streams that stop when their
caller goes away. This module also holds the `served` fixture the SDK and CLI tests share.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import grpc
import httpx
import pytest
from google.protobuf import struct_pb2
from google.rpc import error_details_pb2
from grpc_health.v1 import health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection_pb2, reflection_pb2_grpc
from grpc_status import rpc_status
from neuralbake.v1 import artifacts_pb2, artifacts_pb2_grpc, jobs_pb2, jobs_pb2_grpc

from tests.integration.test_api_server import NBAKE, TOKENS, TOKENS_ENV
from tests.support.ports import free_port

TINY = {"width": 32, "height": 32, "spp": 4}  # a render job of a few seconds
LONG = {"width": 32, "height": 32, "spp": 1 << 16, "tile_size": 32}  # runs for minutes unless cancelled
START_TIMEOUT_S = 180


@dataclass
class Served:
    """A running `nbake serve`: its REST URL, gRPC URL/target and data dir."""

    process: subprocess.Popen
    url: str
    grpc_target: str
    data_dir: Path

    @property
    def grpc_url(self) -> str:
        return f"grpc://{self.grpc_target}"

    def metric(self, name: str) -> float:
        """Sum of a Prometheus metric's samples from /metrics."""
        text = httpx.get(f"{self.url}/metrics", timeout=30).text
        return sum(float(line.rsplit(" ", 1)[1]) for line in text.splitlines() if line.startswith(name))

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(60)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)  # the group this test started, nothing else
                self.process.wait(30)


def start_serve(data_dir: Path) -> Served:
    http_port, grpc_port = free_port(), free_port()
    env = os.environ | {"NBAKE_TOKENS": TOKENS_ENV, "NBAKE_MAX_RUNNING": "2"}
    env.pop("RAY_ADDRESS", None)
    log = (data_dir / "serve.log").open("wb")
    command = [NBAKE, "serve", "--port", str(http_port), "--grpc-port", str(grpc_port)]
    process = subprocess.Popen(
        [*command, "--data-dir", str(data_dir), "--log-level", "warning"],
        stdout=log,
        stderr=subprocess.STDOUT,
        env=env,
        start_new_session=True,
    )
    served = Served(process, f"http://127.0.0.1:{http_port}", f"127.0.0.1:{grpc_port}", data_dir)
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        if process.poll() is not None:
            raise RuntimeError(f"nbake serve exited: {(data_dir / 'serve.log').read_text()[-3000:]}")
        try:
            if httpx.get(f"{served.url}/readyz", timeout=5).status_code == 200:
                with grpc.insecure_channel(served.grpc_target) as channel:
                    check = health_pb2_grpc.HealthStub(channel).Check(
                        health_pb2.HealthCheckRequest(), timeout=5
                    )
                if check.status == health_pb2.HealthCheckResponse.SERVING:
                    return served
        except (httpx.TransportError, grpc.RpcError):
            pass
        if time.monotonic() > deadline:
            served.stop()
            raise RuntimeError("nbake serve did not become ready")
        time.sleep(0.5)


_shared: dict = {"served": None, "users": 0}


@pytest.fixture(scope="session")
def served(tmp_path_factory) -> Iterator[Served]:
    """One `nbake serve` for every module that imports this fixture (it stops with the last of them)."""
    if _shared["served"] is None:
        _shared["served"] = start_serve(tmp_path_factory.mktemp("served"))
    _shared["users"] += 1
    try:
        yield _shared["served"]
    finally:
        _shared["users"] -= 1
        if _shared["users"] == 0:
            _shared["served"].stop()
            _shared["served"] = None


def bearer(scope: str | None = "admin") -> tuple:
    return (("authorization", f"Bearer {TOKENS[scope]}"),) if scope else ()


@pytest.fixture
def channel(served) -> Iterator[grpc.Channel]:
    with grpc.insecure_channel(served.grpc_target) as open_channel:
        yield open_channel


@pytest.fixture
def jobs(channel) -> jobs_pb2_grpc.JobServiceStub:
    return jobs_pb2_grpc.JobServiceStub(channel)


def config(values: dict) -> struct_pb2.Struct:
    message = struct_pb2.Struct()
    message.update(values)
    return message


def submit(jobs, values: dict = TINY, **fields) -> jobs_pb2.Job:
    request = jobs_pb2.SubmitJobRequest(
        kind="render", scene_ref="cornell_box", preset="quick", config=config(values)
    )
    request.MergeFrom(jobs_pb2.SubmitJobRequest(**fields))
    return jobs.SubmitJob(request, metadata=bearer(), timeout=60).job


def rpc_error(call, *args, **kwargs) -> grpc.RpcError:
    with pytest.raises(grpc.RpcError) as caught:
        call(*args, **kwargs)
    return caught.value


def details(error: grpc.RpcError) -> dict[str, object]:
    """The ErrorInfo metadata and the BadRequest field of an error's rich status."""
    found: dict[str, object] = {}
    for packed in rpc_status.from_call(error).details:
        info, bad = error_details_pb2.ErrorInfo(), error_details_pb2.BadRequest()
        if packed.Unpack(info):
            found |= dict(info.metadata)
        elif packed.Unpack(bad):
            found["violation"] = bad.field_violations[0].field
    return found


def wait_until(predicate, timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.2)


# ---------------------------------------------------------------------------------------------- tests


def test_health_and_reflection_are_open(channel):
    health = health_pb2_grpc.HealthStub(channel)
    for service in ("", "neuralbake.v1.JobService", "neuralbake.v1.ArtifactService"):
        check = health.Check(health_pb2.HealthCheckRequest(service=service), timeout=10)
        assert check.status == health_pb2.HealthCheckResponse.SERVING
    reflect = reflection_pb2_grpc.ServerReflectionStub(channel)
    (answer,) = reflect.ServerReflectionInfo(iter([reflection_pb2.ServerReflectionRequest(list_services="")]))
    names = {s.name for s in answer.list_services_response.service}
    assert {
        "neuralbake.v1.JobService",
        "neuralbake.v1.AssetService",
        "neuralbake.v1.ArtifactService",
    } <= names
    assert "grpc.health.v1.Health" in names


def test_submit_watch_and_download_over_grpc(jobs, channel):
    job = submit(jobs, force=True)
    assert job.state == jobs_pb2.JOB_STATE_QUEUED and job.config["spp"] == 4
    stream = list(
        jobs.WatchJob(jobs_pb2.WatchJobRequest(job_id=job.id), metadata=bearer("read"), timeout=120)
    )
    events = [r.event for r in stream]
    assert [e.seq for e in events] == list(range(1, len(events) + 1))
    assert events[-1].type == "state" and events[-1].data["state"] == "SUCCEEDED"
    assert any(e.type == "progress" and e.data["step"] == 4 for e in events)
    resumed = list(jobs.WatchJob(jobs_pb2.WatchJobRequest(job_id=job.id, after_seq=2), metadata=bearer()))
    assert [r.event.seq for r in resumed] == [e.seq for e in events[2:]]

    done = jobs.GetJob(jobs_pb2.GetJobRequest(job_id=job.id), metadata=bearer()).job
    artifacts = artifacts_pb2_grpc.ArtifactServiceStub(channel)
    manifest = artifacts.GetManifest(
        artifacts_pb2.GetManifestRequest(artifact_id=done.artifact_id), metadata=bearer()
    ).manifest
    entry = next(f for f in manifest.files if f.name == "image.exr")
    request = artifacts_pb2.DownloadFileRequest(artifact_id=done.artifact_id, name="image.exr")
    whole = b"".join(r.data for r in artifacts.DownloadFile(request, metadata=bearer()))
    assert len(whole) == entry.size
    request.offset = entry.size // 2
    tail = list(artifacts.DownloadFile(request, metadata=bearer()))
    assert tail[0].offset == entry.size // 2 and tail[0].digest == entry.digest
    assert b"".join(r.data for r in tail) == whole[entry.size // 2 :]


def test_auth_errors_map_to_unauthenticated_and_permission_denied(jobs):
    missing = rpc_error(jobs.ListJobs, jobs_pb2.ListJobsRequest())
    assert missing.code() == grpc.StatusCode.UNAUTHENTICATED
    unknown = rpc_error(
        jobs.ListJobs, jobs_pb2.ListJobsRequest(), metadata=(("authorization", "Bearer nope"),)
    )
    assert unknown.code() == grpc.StatusCode.UNAUTHENTICATED and unknown.details() == "unknown token"
    request = jobs_pb2.SubmitJobRequest(kind="render", scene_ref="cornell_box")
    denied = rpc_error(jobs.SubmitJob, request, metadata=bearer("read"))
    assert denied.code() == grpc.StatusCode.PERMISSION_DENIED and "submit" in denied.details()
    assert details(denied)["status"] == "403"


@pytest.mark.parametrize(
    ("fields", "values", "field"),
    [
        ({"kind": "nope"}, TINY, "kind"),
        ({"preset": "huge"}, TINY, "preset"),
        ({}, {"spp": -1}, "config.spp"),
        ({}, {"colour": 1}, "config.colour"),
        ({"scene_ref": "no_such_scene"}, TINY, "scene"),
        ({}, {"spp": float("nan")}, "config.spp"),  # a Struct holds NaN and Infinity, JSON cannot
        (
            {"scene_spec": config({"objects": [{"scale": [1, float("inf")]}]})},
            TINY,
            "scene.objects[0].scale[1]",
        ),
    ],
)
def test_invalid_input_is_invalid_argument_naming_the_field(jobs, fields, values, field):
    error = rpc_error(submit, jobs, values, **fields)
    assert error.code() == grpc.StatusCode.INVALID_ARGUMENT
    found = details(error)
    assert found["field"] == found["violation"] == field and found["status"] == "422"
    assert error.details().startswith(f"{field}: ")


def test_not_found_and_failed_precondition(jobs, channel):
    missing = rpc_error(jobs.GetJob, jobs_pb2.GetJobRequest(job_id="job-nope"), metadata=bearer())
    assert missing.code() == grpc.StatusCode.NOT_FOUND and details(missing)["status"] == "404"
    artifacts = artifacts_pb2_grpc.ArtifactServiceStub(channel)
    request = artifacts_pb2.GetManifestRequest(artifact_id="sha256:" + "0" * 64)
    assert rpc_error(artifacts.GetManifest, request, metadata=bearer()).code() == grpc.StatusCode.NOT_FOUND

    job = submit(jobs)  # an identical tiny job: finished already, or soon
    list(jobs.WatchJob(jobs_pb2.WatchJobRequest(job_id=job.id), metadata=bearer(), timeout=120))
    again = rpc_error(jobs.CancelJob, jobs_pb2.CancelJobRequest(job_id=job.id), metadata=bearer())
    assert again.code() == grpc.StatusCode.FAILED_PRECONDITION and "already" in again.details()
    assert rpc_error(jobs.ListJobs, jobs_pb2.ListJobsRequest(page_size=500), metadata=bearer()).code() == (
        grpc.StatusCode.INVALID_ARGUMENT
    )


def test_deadline_ends_a_watch_and_its_server_work(served, jobs):
    job = submit(jobs, LONG, force=True)
    try:
        stream = jobs.WatchJob(jobs_pb2.WatchJobRequest(job_id=job.id), metadata=bearer(), timeout=3)
        error = rpc_error(list, stream)
        assert error.code() == grpc.StatusCode.DEADLINE_EXCEEDED
        wait_until(lambda: served.metric('nbake_grpc_active_streams{method="WatchJob"}') == 0)
    finally:
        jobs.CancelJob(jobs_pb2.CancelJobRequest(job_id=job.id), metadata=bearer())


def test_a_client_that_disconnects_mid_stream_leaves_no_work_running(served, jobs):
    job = submit(jobs, LONG, force=True)
    try:
        stream = jobs.WatchJob(jobs_pb2.WatchJobRequest(job_id=job.id), metadata=bearer())
        next(stream)
        assert served.metric('nbake_grpc_active_streams{method="WatchJob"}') >= 1
        stream.cancel()
        wait_until(lambda: served.metric('nbake_grpc_active_streams{method="WatchJob"}') == 0)
    finally:
        jobs.CancelJob(jobs_pb2.CancelJobRequest(job_id=job.id), metadata=bearer())
