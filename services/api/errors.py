"""What each error a caller can act on stands for, whichever API answers: one table, which REST turns into
problem+json (`services.api.problems`) and gRPC into a status code with rich details
(`services.api.grpc.errors`), so the two cannot drift apart. The inference service answers through both.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from sqlalchemy.exc import InterfaceError, OperationalError

from services.artifacts.artifacts import ArtifactNotFound, FileNotFoundInArtifact
from services.artifacts.assets import AssetNotFound
from services.artifacts.staging import UploadError
from services.jobs.errors import JobServiceError
from services.jobs.states import InvalidTransition
from workers.scene.errors import SceneError


@dataclass(frozen=True)
class ProblemInfo:
    status: int  # the HTTP status; gRPC maps it to a code
    title: str
    detail: str
    field: str | None = None
    headers: dict[str, str] | None = None  # only HTTP has somewhere to put them


def _not_found(error: LookupError) -> ProblemInfo:
    return ProblemInfo(404, "Not found", str(error))


DATABASE_RETRY_AFTER_S = 5  # PostgreSQL restarts in seconds; SQLite's "database is locked" clears sooner


def _database_unavailable(_: Exception) -> ProblemInfo:
    """The database cannot be reached (restarting, failing over, or locked): nothing was changed, and the
    same request will work once it is back."""
    return ProblemInfo(
        503,
        "Database unavailable",
        "the job database cannot be reached right now; nothing was changed: retry",
        headers={"Retry-After": str(DATABASE_RETRY_AFTER_S)},
    )


def _upload(error: UploadError) -> ProblemInfo:
    title = "Upload too large" if error.status == 413 else "Unusable upload"
    return ProblemInfo(error.status, title, error.problem, error.field)


_TABLE: dict[type[Exception], Callable[[Any], ProblemInfo]] = {
    JobServiceError: lambda e: ProblemInfo(e.status, e.title, e.detail, e.field, e.headers),
    InvalidTransition: lambda e: ProblemInfo(409, "Conflict", str(e)),
    UploadError: _upload,
    SceneError: lambda e: ProblemInfo(422, "Invalid scene", e.problem, e.field),
    AssetNotFound: _not_found,
    ArtifactNotFound: _not_found,
    FileNotFoundInArtifact: _not_found,
    OperationalError: _database_unavailable,
    InterfaceError: _database_unavailable,
}
ACTIONABLE = tuple(_TABLE)  # REST registers a handler for each: Starlette dispatches on the class


def problem_for(error: Exception) -> ProblemInfo | None:
    """The problem `error` stands for (its most specific class in the table, as Starlette would pick), or
    None for a bug."""
    for cls in type(error).__mro__:
        if cls in _TABLE:
            return _TABLE[cls](error)
    return None


def internal_problem(error: Exception) -> ProblemInfo:
    """A bug: 500, naming only the exception's type, never its message or trace."""
    return ProblemInfo(500, "Internal server error", f"{type(error).__name__}: the server failed")
