"""The job API's gRPC services and the scope each of their methods needs; the health and reflection
services are open."""

from __future__ import annotations

from neuralbake.v1 import artifacts_pb2, assets_pb2, jobs_pb2

SERVICE_NAMES = tuple(
    service.full_name
    for module in (jobs_pb2, assets_pb2, artifacts_pb2)
    for service in module.DESCRIPTOR.services_by_name.values()
)
SUBMIT_METHODS = frozenset(
    {
        "/neuralbake.v1.JobService/SubmitJob",
        "/neuralbake.v1.JobService/SubmitJobs",
        "/neuralbake.v1.JobService/CancelJob",
        "/neuralbake.v1.AssetService/UploadAsset",
    }
)


def needed_scope(method: str) -> str | None:
    """The scope a full method name needs; None for the open (health, reflection) services."""
    service = method.strip("/").split("/", 1)[0]
    if service not in SERVICE_NAMES:
        return None
    return "submit" if method in SUBMIT_METHODS else "read"
