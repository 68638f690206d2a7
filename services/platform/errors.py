"""Errors a caller can act on, whichever server raises them: each carries the HTTP status and title the
server answers with (problem+json over REST, a status with details over gRPC)."""

from __future__ import annotations

from typing import Any


class ServiceError(Exception):
    """Base class: `status` is the HTTP status the API answers with, `field` the input at fault (if any)."""

    status = 400
    title = "Bad request"
    headers: dict[str, str] | None = None
    extensions: dict[str, Any] | None = None  # more members of the problem (RFC 9457), e.g. a quota's limit

    def __init__(self, detail: str, field: str | None = None):
        self.detail, self.field = detail, field
        super().__init__(f"{field}: {detail}" if field else detail)


class InvalidInput(ServiceError):
    status, title = 422, "Invalid input"


class Conflict(ServiceError):
    status, title = 409, "Conflict"
