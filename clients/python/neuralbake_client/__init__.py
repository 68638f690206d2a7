"""neuralbake-client: the Python SDK of the neuralbake job service (REST or gRPC).

from neuralbake_client import Client

with Client("http://127.0.0.1:8080", token) as client:
    job = client.submit("render", Path("scenes/chair"), preset="quick")
    job = client.wait(job, on_progress=lambda p: print(p.step, p.total))
    client.download(job, "out/chair")
"""

from neuralbake_client.aio import AsyncClient
from neuralbake_client.client import Client
from neuralbake_client.download import DownloadedFile
from neuralbake_client.errors import (
    ApiError,
    ChecksumMismatch,
    Conflict,
    ConnectionFailed,
    InvalidRequest,
    NeuralbakeError,
    NotFound,
    PermissionDenied,
    ServerError,
    TooLarge,
    Unauthenticated,
    Unavailable,
)
from neuralbake_client.models import Asset, FileEntry, Job, JobEvent, JobList, JobState, Manifest, Progress
from neuralbake_client.retry import Retry
from neuralbake_client.transport_grpc import DeadlineExceeded

__all__ = [
    "ApiError",
    "Asset",
    "AsyncClient",
    "ChecksumMismatch",
    "Client",
    "Conflict",
    "ConnectionFailed",
    "DeadlineExceeded",
    "DownloadedFile",
    "FileEntry",
    "InvalidRequest",
    "Job",
    "JobEvent",
    "JobList",
    "JobState",
    "Manifest",
    "NeuralbakeError",
    "NotFound",
    "PermissionDenied",
    "Progress",
    "Retry",
    "ServerError",
    "TooLarge",
    "Unauthenticated",
    "Unavailable",
]
