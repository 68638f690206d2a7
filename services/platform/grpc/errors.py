"""A server's errors as gRPC statuses: the problem its table (`services.platform.problem_table`) gives
REST too (status, title, detail, field, extension members), carried as a status code, a message and rich
details (`google.rpc.ErrorInfo` with the problem, `google.rpc.BadRequest` naming the field,
`google.rpc.RetryInfo` for a Retry-After, `google.rpc.QuotaFailure` naming a used-up quota), so a client
can act on it exactly as over HTTP.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator

import grpc
from google.protobuf import any_pb2, duration_pb2
from google.rpc import error_details_pb2, status_pb2
from grpc_status import rpc_status
from pydantic import ValidationError

from services.platform.grpc.handlers import Behaviour, rewrap
from services.platform.problem_table import ProblemInfo, ProblemTable, internal_problem
from workers.scene.portability.io import dotted_path

DOMAIN = "neuralbake"
log = logging.getLogger(__name__)

CODES = {
    400: grpc.StatusCode.INVALID_ARGUMENT,
    401: grpc.StatusCode.UNAUTHENTICATED,
    403: grpc.StatusCode.PERMISSION_DENIED,
    404: grpc.StatusCode.NOT_FOUND,
    409: grpc.StatusCode.FAILED_PRECONDITION,
    413: grpc.StatusCode.RESOURCE_EXHAUSTED,
    422: grpc.StatusCode.INVALID_ARGUMENT,
    429: grpc.StatusCode.RESOURCE_EXHAUSTED,
    503: grpc.StatusCode.UNAVAILABLE,
}


def problem_of(error: Exception, table: ProblemTable) -> ProblemInfo | None:
    """The problem an error stands for in `table`, or None for a bug. A request message that fails its
    model (as `JobRequest`) is this adapter's own bad input, like a REST body failing validation."""
    if isinstance(error, ValidationError):
        first = error.errors()[0]
        field = dotted_path(first["loc"], None) or "request"
        return ProblemInfo(422, "Invalid input", f"{field}: {first['msg']}", field)
    return table.problem_for(error)


def to_status(problem: ProblemInfo) -> grpc.Status:
    retry_after = (problem.headers or {}).get("Retry-After")
    info = error_details_pb2.ErrorInfo(
        reason=problem.title.upper().replace(" ", "_"),
        domain=DOMAIN,
        metadata={name: str(value) for name, value in (problem.extensions or {}).items()}
        | {"status": str(problem.status), "title": problem.title}
        | ({"field": problem.field} if problem.field else {})
        | ({"retry_after": retry_after} if retry_after else {}),  # what the SDK reads, as over HTTP
    )
    details = [info]
    if problem.field:
        violation = error_details_pb2.BadRequest.FieldViolation(
            field=problem.field, description=problem.detail
        )
        details.append(error_details_pb2.BadRequest(field_violations=[violation]))
    if retry_after:
        delay = duration_pb2.Duration(seconds=int(retry_after))
        details.append(error_details_pb2.RetryInfo(retry_delay=delay))
    if quota := (problem.extensions or {}).get("quota"):
        used_up = error_details_pb2.QuotaFailure.Violation(subject=quota, description=problem.detail)
        details.append(error_details_pb2.QuotaFailure(violations=[used_up]))
    packed = []
    for detail in details:
        wrapper = any_pb2.Any()
        wrapper.Pack(detail)
        packed.append(wrapper)
    code = CODES.get(problem.status, grpc.StatusCode.INVALID_ARGUMENT)
    message = f"{problem.field}: {problem.detail}" if problem.field else problem.detail
    return rpc_status.to_status(status_pb2.Status(code=code.value[0], message=message, details=packed))


def abort(context: grpc.ServicerContext, error: Exception, table: ProblemTable):
    """End the call with the status `error` maps to in `table`; a bug is INTERNAL (and logged), never a
    leaked trace."""
    if context.code() is not None:  # already aborted (e.g. by an inner layer): keep that status
        raise error
    problem = problem_of(error, table)
    if problem is None:
        log.error("unhandled error in a gRPC call", exc_info=error)
        context.abort(grpc.StatusCode.INTERNAL, internal_problem(error).detail)
    context.abort_with_status(to_status(problem))


class ErrorMapping(grpc.ServerInterceptor):
    """Turns exceptions raised by a call (or while streaming its responses) into statuses by `table`."""

    def __init__(self, table: ProblemTable):
        self.table = table

    def intercept_service(self, continuation, handler_call_details):
        handler = continuation(handler_call_details)
        return None if handler is None else rewrap(handler, self._mapped)

    def _mapped(self, behaviour: Behaviour, streaming: bool) -> Behaviour:
        if streaming:

            def stream(request, context) -> Iterator:
                try:
                    yield from behaviour(request, context)
                except Exception as error:
                    abort(context, error, self.table)

            return stream

        def unary(request, context):
            try:
                return behaviour(request, context)
            except Exception as error:
                abort(context, error, self.table)

        return unary
