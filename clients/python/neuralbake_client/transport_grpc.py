"""The gRPC transport: the generated `neuralbake.v1` stubs, token metadata, rich error statuses turned
into the same exceptions the REST transport raises, and messages turned into the same models.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, BinaryIO

import grpc
from google.protobuf import json_format, struct_pb2
from google.rpc import error_details_pb2
from grpc_status import rpc_status
from neuralbake.v1 import (
    artifacts_pb2,
    artifacts_pb2_grpc,
    assets_pb2,
    assets_pb2_grpc,
    jobs_pb2,
    jobs_pb2_grpc,
)

from neuralbake_client.errors import ConnectionFailed, NeuralbakeError, api_error
from neuralbake_client.models import Asset, Job, JobEvent, JobList, JobState, Manifest

CHUNK_BYTES = 1 << 20  # upload chunk; the server accepts messages up to 4 MiB
STATE_PREFIX = "JOB_STATE_"
HTTP_STATUS = {
    grpc.StatusCode.INVALID_ARGUMENT: 422,
    grpc.StatusCode.UNAUTHENTICATED: 401,
    grpc.StatusCode.PERMISSION_DENIED: 403,
    grpc.StatusCode.NOT_FOUND: 404,
    grpc.StatusCode.FAILED_PRECONDITION: 409,
    grpc.StatusCode.RESOURCE_EXHAUSTED: 413,
    grpc.StatusCode.UNAVAILABLE: 503,
    grpc.StatusCode.DEADLINE_EXCEEDED: 504,
}


class DeadlineExceeded(NeuralbakeError):
    """A gRPC call ran past its deadline (`timeout`)."""


def call_error(error: grpc.RpcError) -> NeuralbakeError:
    """The exception for a failed call: the server's problem from the status details when it sent one."""
    code = error.code()
    if code == grpc.StatusCode.DEADLINE_EXCEEDED:
        return DeadlineExceeded(error.details() or "deadline exceeded")
    status = rpc_status.from_call(error)
    metadata: dict[str, str] = {}
    detail = error.details() or code.name
    for packed in status.details if status is not None else ():
        info, bad = error_details_pb2.ErrorInfo(), error_details_pb2.BadRequest()
        if packed.Unpack(info):
            metadata = dict(info.metadata)
        elif packed.Unpack(bad) and bad.field_violations:
            detail = bad.field_violations[0].description
    if code == grpc.StatusCode.UNAVAILABLE and not metadata:
        return ConnectionFailed(detail)
    http_status = int(metadata.get("status", HTTP_STATUS.get(code, 500)))
    title = metadata.get("title", code.name.replace("_", " ").capitalize())
    extra = {"retry_after": metadata["retry_after"]} if "retry_after" in metadata else {}
    return api_error(http_status, title, detail, metadata.get("field"), grpc_code=code.name, **extra)


def submit_request(body: dict[str, Any]) -> jobs_pb2.SubmitJobRequest:
    """The SubmitJobRequest of a `POST /v1/jobs` body."""
    scene = body["scene"]
    return jobs_pb2.SubmitJobRequest(
        kind=body["kind"],
        config=struct(body.get("config") or {}),
        force=body.get("force", False),
        **({"scene_spec": struct(scene)} if isinstance(scene, dict) else {"scene_ref": scene}),
        **{k: body[k] for k in ("preset", "seed", "priority") if body.get(k) is not None},
    )


def submitted_job(response: jobs_pb2.SubmitJobResponse) -> Job:
    job = job_model(response.job)
    job._reused = not response.created
    return job


def plain(value: Any) -> Any:
    """JSON from a Struct: numbers come back as floats, so whole ones are made ints again."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [plain(v) for v in value]
    return value


def as_dict(message) -> dict[str, Any]:
    data = json_format.MessageToDict(
        message, preserving_proto_field_name=True, always_print_fields_with_no_presence=True
    )
    return plain(data)


def job_model(message: jobs_pb2.Job) -> Job:
    data = as_dict(message)
    data["state"] = data["state"].removeprefix(STATE_PREFIX)
    return Job.model_validate(data)


def struct(data: dict[str, Any]) -> struct_pb2.Struct:
    message = struct_pb2.Struct()
    message.update(data)
    return message


def open_channel(target: str, secure: bool, options: list[tuple[str, Any]] | None = None) -> grpc.Channel:
    if secure:
        return grpc.secure_channel(target, grpc.ssl_channel_credentials(), options)
    return grpc.insecure_channel(target, options)


class GrpcTransport:
    def __init__(self, target: str, token: str | None, timeout: float, secure: bool):
        self.channel = open_channel(target, secure)
        self.metadata = (("authorization", f"Bearer {token}"),) if token else ()
        self.timeout = timeout
        self.jobs = jobs_pb2_grpc.JobServiceStub(self.channel)
        self.assets = assets_pb2_grpc.AssetServiceStub(self.channel)
        self.artifacts = artifacts_pb2_grpc.ArtifactServiceStub(self.channel)

    def close(self) -> None:
        self.channel.close()

    def _unary(self, method, request, extra: tuple = ()):
        try:
            return method(request, metadata=self.metadata + extra, timeout=self.timeout)
        except grpc.RpcError as error:
            raise call_error(error) from None

    def _stream(self, method, request, timeout: float | None = None) -> Iterator:
        try:
            yield from method(request, metadata=self.metadata, timeout=timeout)
        except grpc.RpcError as error:
            raise call_error(error) from None

    # ------------------------------------------------------------------ assets

    def upload(self, parts: list[tuple[str, BinaryIO]]) -> Asset:
        def chunks() -> Iterator[assets_pb2.UploadAssetRequest]:
            for name, stream in parts:
                stream.seek(0)
                while data := stream.read(CHUNK_BYTES):
                    yield assets_pb2.UploadAssetRequest(path=name, data=data)

        response = self._unary(self.assets.UploadAsset, chunks())
        return Asset.model_validate(as_dict(response.asset))

    def get_asset(self, asset_id: str) -> Asset:
        response = self._unary(self.assets.GetAsset, assets_pb2.GetAssetRequest(asset_id=asset_id))
        return Asset.model_validate(as_dict(response.asset))

    # ------------------------------------------------------------------ jobs

    def submit(self, body: dict[str, Any], idempotency_key: str) -> Job:
        response = self._unary(
            self.jobs.SubmitJob, submit_request(body), (("idempotency-key", idempotency_key),)
        )
        return submitted_job(response)

    def submit_many(self, bodies: list[dict[str, Any]], idempotency_key: str) -> list[Job]:
        request = jobs_pb2.SubmitJobsRequest(jobs=[submit_request(body) for body in bodies])
        response = self._unary(self.jobs.SubmitJobs, request, (("idempotency-key", idempotency_key),))
        return [submitted_job(item) for item in response.items]

    def get_job(self, job_id: str) -> Job:
        return job_model(self._unary(self.jobs.GetJob, jobs_pb2.GetJobRequest(job_id=job_id)).job)

    def list_jobs(self, states: list[str], kind: str | None, cursor: str | None, limit: int) -> JobList:
        request = jobs_pb2.ListJobsRequest(
            states=[jobs_pb2.JobState.Value(STATE_PREFIX + JobState(s).value) for s in states],
            kind=kind or "",
            page_token=cursor or "",
            page_size=limit,
        )
        response = self._unary(self.jobs.ListJobs, request)
        return JobList(
            items=[job_model(j) for j in response.jobs], next_cursor=response.next_page_token or None
        )

    def cancel(self, job_id: str) -> Job:
        return job_model(self._unary(self.jobs.CancelJob, jobs_pb2.CancelJobRequest(job_id=job_id)).job)

    def events(self, job_id: str, after: int) -> Iterator[JobEvent]:
        request = jobs_pb2.WatchJobRequest(job_id=job_id, after_seq=after)
        for response in self._stream(self.jobs.WatchJob, request):
            yield JobEvent.model_validate(as_dict(response.event))

    # ------------------------------------------------------------------ artifacts

    def manifest(self, artifact_id: str) -> Manifest:
        request = artifacts_pb2.GetManifestRequest(artifact_id=artifact_id)
        return Manifest.model_validate(as_dict(self._unary(self.artifacts.GetManifest, request).manifest))

    def read_file(self, artifact_id: str, name: str, digest: str, offset: int) -> Iterator[bytes]:
        request = artifacts_pb2.DownloadFileRequest(artifact_id=artifact_id, name=name, offset=offset)
        for response in self._stream(self.artifacts.DownloadFile, request):
            if response.digest != digest or response.offset != offset:
                raise NeuralbakeError(f"{name}: the server sent bytes from {response.offset}, not {offset}")
            offset += len(response.data)
            yield response.data
