"""What each error a caller can act on stands for, whichever API answers: one table per server, which REST
turns into problem+json (`services.platform.problems`) and gRPC into a status code with rich details
(`services.platform.grpc.errors`), so the two cannot drift apart. The platform's own rows cover its error
base and an unreachable database; a server adds the rows of the errors its domain raises
(`services.jobs.problems`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from sqlalchemy.exc import InterfaceError, OperationalError

from services.platform.errors import ServiceError


@dataclass(frozen=True)
class ProblemInfo:
    status: int  # the HTTP status; gRPC maps it to a code
    title: str
    detail: str
    field: str | None = None
    headers: dict[str, str] | None = None  # only HTTP has somewhere to put them
    extensions: dict[str, Any] | None = None  # members beside the standard ones (RFC 9457 extensions)


Rule = Callable[[Any], ProblemInfo]


def not_found(error: LookupError) -> ProblemInfo:
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


class ProblemTable:
    """Error class -> the rule that says which problem an error of it stands for."""

    def __init__(self, rules: Mapping[type[Exception], Rule]):
        self._rules = dict(rules)

    def including(self, rules: Mapping[type[Exception], Rule]) -> ProblemTable:
        """This table with more rows (a server's own errors)."""
        return ProblemTable(self._rules | dict(rules))

    @property
    def actionable(self) -> tuple[type[Exception], ...]:
        """Every class with a row: REST registers a handler for each, since Starlette dispatches on it."""
        return tuple(self._rules)

    def problem_for(self, error: Exception) -> ProblemInfo | None:
        """The problem `error` stands for (its most specific class in the table, as Starlette would pick),
        or None for a bug."""
        for cls in type(error).__mro__:
            if cls in self._rules:
                return self._rules[cls](error)
        return None


PLATFORM_PROBLEMS = ProblemTable(
    {
        ServiceError: lambda e: ProblemInfo(e.status, e.title, e.detail, e.field, e.headers, e.extensions),
        OperationalError: _database_unavailable,
        InterfaceError: _database_unavailable,
    }
)


def internal_problem(error: Exception) -> ProblemInfo:
    """A bug: 500, naming only the exception's type, never its message or trace."""
    return ProblemInfo(500, "Internal server error", f"{type(error).__name__}: the server failed")
