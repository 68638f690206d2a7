"""Errors a caller can act on, whichever server raises them: each carries the HTTP status and title the
server answers with (problem+json over REST, a status with details over gRPC)."""

from __future__ import annotations


class ServiceError(Exception):
    """Base class: `status` is the HTTP status the API answers with, `field` the input at fault (if any)."""

    status = 400
    title = "Bad request"
    headers: dict[str, str] | None = None

    def __init__(self, detail: str, field: str | None = None):
        self.detail, self.field = detail, field
        super().__init__(f"{field}: {detail}" if field else detail)


class InvalidInput(ServiceError):
    status, title = 422, "Invalid input"


class Conflict(ServiceError):
    status, title = 409, "Conflict"
