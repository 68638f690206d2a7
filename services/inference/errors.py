"""The inference service's errors a caller can act on. They are service errors (status, title,
detail, field), so the REST problem handlers and the gRPC error mapping of `services.platform` serve them
unchanged."""

from __future__ import annotations

from services.platform.errors import ServiceError


class InvalidQuery(ServiceError):
    """A body whose arrays or parameters do not fit the operation (shape, dtype, NaN, unknown names)."""

    status, title = 422, "Invalid query"


class MalformedBody(ServiceError):
    status, title = 400, "Malformed body"


class UnsupportedOperation(ServiceError):
    status, title = 400, "Unsupported operation"


class RequestTooLarge(ServiceError):
    """More rows than a request may hold, or more working memory than the whole budget."""

    status, title = 413, "Request too large"


class ArtifactRefused(ServiceError):
    """The artifact exists but cannot be served: a file fails its digest, or it exceeds the memory budget."""

    status, title = 409, "Artifact refused"


class Overloaded(ServiceError):
    status, title = 503, "Timed out"
    headers = {"Retry-After": "1"}  # noqa: RUF012


class QueueFull(Overloaded):
    """Too many requests already wait for working memory: refused before its body is held any longer."""

    title = "Too many requests waiting"
