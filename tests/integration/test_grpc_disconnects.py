"""gRPC clients that vanish mid-stream leak no server work: a client process killed (SIGKILL, so its
connection drops without a cancel, as a crashed client or a cut network gives) while it follows a job's
events, uploads an asset or downloads an artifact file; each stream is counted in
`nbake_grpc_active_streams{method}` while it runs and the count returns to zero. Through the shared real
`nbake serve` of test_grpc_server."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest
from neuralbake.v1 import artifacts_pb2, artifacts_pb2_grpc, jobs_pb2

from tests.integration import test_grpc_server as grpc_server
from tests.integration.test_grpc_server import LONG, bearer, submit, wait_until

served = grpc_server.served  # fixture
channel, jobs = grpc_server.channel, grpc_server.jobs  # fixtures

DOWNLOAD = {"width": 1024, "height": 1024, "spp": 1}  # an image of several 1 MiB chunks, in seconds

CLIENT = """
import sys, time, grpc
from neuralbake.v1 import artifacts_pb2, artifacts_pb2_grpc, assets_pb2, assets_pb2_grpc
from neuralbake.v1 import jobs_pb2, jobs_pb2_grpc
method, target, token, *args = sys.argv[1:]
metadata = (("authorization", f"Bearer {token}"),)
# No BDP probing: the receive window stays at HTTP/2's 64 KiB, so the server cannot push the whole file into
# the client's buffers and finish its stream before it is counted.
channel = grpc.insecure_channel(target, options=[("grpc.http2.bdp_probe", 0)])
if method == "WatchJob":
    request = jobs_pb2.WatchJobRequest(job_id=args[0])
    stream = jobs_pb2_grpc.JobServiceStub(channel).WatchJob(request, metadata=metadata)
    next(stream)
elif method == "DownloadFile":
    request = artifacts_pb2.DownloadFileRequest(artifact_id=args[0], name=args[1])
    stream = artifacts_pb2_grpc.ArtifactServiceStub(channel).DownloadFile(request, metadata=metadata)
    next(stream)  # one chunk read; the rest wait in flow control
elif method == "UploadAsset":
    def chunks():
        yield assets_pb2.UploadAssetRequest(path="scene.yaml", data=b"objects: []\\n")
        time.sleep(600)  # the upload never finishes
    future = assets_pb2_grpc.AssetServiceStub(channel).UploadAsset.future(chunks(), metadata=metadata)
print("streaming", flush=True)
time.sleep(600)
"""


def active(served, method: str) -> float:
    return served.metric(f'nbake_grpc_active_streams{{method="{method}"}}')


def kill_client_mid_stream(served, method: str, *args: str) -> None:
    """Start a client of `method`, SIGKILL it once its stream is counted, and wait for the count to drop."""
    client = subprocess.Popen(
        [sys.executable, "-c", CLIENT, method, served.grpc_target, grpc_server.TOKENS["admin"], *args],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert client.stdout.readline() == "streaming\n"
        wait_until(lambda: active(served, method) >= 1)
    finally:
        os.kill(client.pid, signal.SIGKILL)
        client.wait()
    wait_until(lambda: active(served, method) == 0)


def test_a_killed_follower_leaves_no_watch_running(served, jobs):
    job = submit(jobs, LONG, force=True)
    try:
        kill_client_mid_stream(served, "WatchJob", job.id)
    finally:
        jobs.CancelJob(jobs_pb2.CancelJobRequest(job_id=job.id), metadata=bearer())


def test_a_killed_uploader_leaves_no_upload_running(served):
    kill_client_mid_stream(served, "UploadAsset")


def test_a_killed_downloader_leaves_no_download_running(served, jobs, channel):
    job = submit(jobs, DOWNLOAD)
    list(jobs.WatchJob(jobs_pb2.WatchJobRequest(job_id=job.id), metadata=bearer(), timeout=300))
    done = jobs.GetJob(jobs_pb2.GetJobRequest(job_id=job.id), metadata=bearer()).job
    assert done.state == jobs_pb2.JOB_STATE_SUCCEEDED, done.error
    artifact_id = done.artifact_id
    request = artifacts_pb2.GetManifestRequest(artifact_id=artifact_id)
    manifest = (
        artifacts_pb2_grpc.ArtifactServiceStub(channel).GetManifest(request, metadata=bearer()).manifest
    )
    largest = max(manifest.files, key=lambda entry: entry.size)
    if largest.size <= 4 << 20:
        pytest.fail(f"{largest.name} has {largest.size} bytes: too few to still be streaming when killed")
    kill_client_mid_stream(served, "DownloadFile", artifact_id, largest.name)
