"""Errors of the job service that a caller can act on; the API turns each into one problem+json status."""

from __future__ import annotations

from services.platform.errors import ServiceError


class JobNotFound(ServiceError):
    status, title = 404, "Job not found"


class KindNotFound(ServiceError):
    status, title = 404, "Kind not found"


def name_batch_item(error: ServiceError, index: int) -> None:
    """Make `error` name its field under `jobs[index]`: the batch submission's name for its index-th job."""
    error.field = f"jobs[{index}].{error.field}" if error.field else f"jobs[{index}]"
