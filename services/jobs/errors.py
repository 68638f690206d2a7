"""Errors of the job service that a caller can act on; the API turns each into one problem+json status."""

from __future__ import annotations


class JobServiceError(Exception):
    """Base class: `status` is the HTTP status the API answers with, `field` the input at fault (if any)."""

    status = 400
    title = "Bad request"
    headers: dict[str, str] | None = None

    def __init__(self, detail: str, field: str | None = None):
        self.detail, self.field = detail, field
        super().__init__(f"{field}: {detail}" if field else detail)


class InvalidInput(JobServiceError):
    status, title = 422, "Invalid input"


class JobNotFound(JobServiceError):
    status, title = 404, "Job not found"


class Conflict(JobServiceError):
    status, title = 409, "Conflict"


class KindNotFound(JobServiceError):
    status, title = 404, "Kind not found"
