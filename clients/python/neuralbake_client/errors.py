"""Exceptions that carry the server's problem detail (RFC 9457 over HTTP, rich status over gRPC), so the
caller sees the same `status`, `title`, `detail` and `field` whichever transport it uses.
"""

from __future__ import annotations

from typing import Any


class NeuralbakeError(Exception):
    """Base class of every error this package raises."""


class ApiError(NeuralbakeError):
    """The server answered with a problem. `status` is the HTTP status (also for gRPC calls)."""

    status: int = 0

    def __init__(self, status: int, title: str, detail: str, field: str | None = None, **extra: Any):
        self.status, self.title, self.detail, self.field, self.extra = status, title, detail, field, extra
        super().__init__(f"{status} {title}: {self.where}{detail}")

    @property
    def retry_after(self) -> float | None:
        """Seconds the server asked the caller to wait before trying again (`Retry-After`), if it did."""
        value = self.extra.get("retry_after")
        try:
            return max(0.0, float(value)) if value is not None else None
        except (TypeError, ValueError):  # an HTTP date: waiting the usual backoff is as good
            return None

    @property
    def where(self) -> str:
        """`field: ` when the detail does not already start with the field, so a message names it once."""
        return f"{self.field}: " if self.field and not self.detail.startswith(self.field) else ""

    @property
    def problem(self) -> dict[str, Any]:
        body = {"status": self.status, "title": self.title, "detail": self.detail, "field": self.field}
        return {k: v for k, v in body.items() if v is not None} | self.extra


class InvalidRequest(ApiError):
    """400 / 422 (INVALID_ARGUMENT): `field` names the input at fault."""


class Unauthenticated(ApiError):
    """401 (UNAUTHENTICATED): no token, or one the server does not know."""


class PermissionDenied(ApiError):
    """403 (PERMISSION_DENIED): the token lacks the scope (read < submit < admin)."""


class NotFound(ApiError):
    """404 (NOT_FOUND)."""


class Conflict(ApiError):
    """409 (FAILED_PRECONDITION), e.g. cancelling a finished job."""


class TooLarge(ApiError):
    """413 (RESOURCE_EXHAUSTED): an upload or body over the server's limits."""


class TooManyRequests(ApiError):
    """429 (a tenant's quota of queued jobs or compute is used up): retried after the server's
    `Retry-After` before it reaches the caller."""


class ServerError(ApiError):
    """500: a bug on the server."""


class Unavailable(ApiError):
    """503 (UNAVAILABLE): retried with backoff before it reaches the caller."""


class ConnectionFailed(NeuralbakeError):
    """The server could not be reached (after the retries)."""


class WaitTimeout(NeuralbakeError):
    """`wait(timeout=...)` ran out of time; the job itself goes on (`job_id` names it)."""

    def __init__(self, job_id: str, timeout: float):
        self.job_id, self.timeout = job_id, timeout
        super().__init__(f"job {job_id} has not ended after {timeout:g} s; it goes on running")


class ChecksumMismatch(NeuralbakeError):
    """A downloaded file's sha256 differs from the manifest's digest (the partial file is discarded)."""


BY_STATUS: dict[int, type[ApiError]] = {
    400: InvalidRequest,
    401: Unauthenticated,
    403: PermissionDenied,
    404: NotFound,
    409: Conflict,
    413: TooLarge,
    422: InvalidRequest,
    429: TooManyRequests,
    500: ServerError,
    503: Unavailable,
}


def api_error(status: int, title: str, detail: str, field: str | None = None, **extra: Any) -> ApiError:
    cls = BY_STATUS.get(
        status, ServerError if status >= 500 else InvalidRequest if status >= 400 else ApiError
    )
    return cls(status, title, detail, field, **extra)


RETRYABLE = (Unavailable, TooManyRequests, ConnectionFailed)
