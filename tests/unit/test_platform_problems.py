"""A `ServiceError`'s extension members (a used-up quota's name, limit and use) and its Retry-After reach
the caller both ways: as problem+json members and a header over REST, and as ErrorInfo metadata,
`RetryInfo` and `QuotaFailure` details over gRPC; the standard members cannot be overwritten by them."""

from __future__ import annotations

import grpc
from fastapi import FastAPI
from fastapi.testclient import TestClient
from google.rpc import error_details_pb2, status_pb2

from services.platform import problems
from services.platform.errors import ServiceError
from services.platform.grpc.errors import to_status
from services.platform.problem_table import PLATFORM_PROBLEMS


class UsedUp(ServiceError):
    status, title = 429, "Quota exceeded"
    headers = {"Retry-After": "7"}  # noqa: RUF012
    extensions = {"quota": "max_queued", "limit": 2, "current": 2, "status": 500}  # noqa: RUF012


def test_extension_members_and_retry_after_over_rest():
    app = FastAPI()
    problems.install(app, PLATFORM_PROBLEMS)

    @app.post("/work")
    def work() -> None:
        raise UsedUp("two jobs queued, the limit: retry once one has started")

    answer = TestClient(app).post("/work")
    assert (answer.status_code, answer.headers["Retry-After"]) == (429, "7")
    assert answer.headers["content-type"] == problems.PROBLEM_JSON
    body = answer.json()
    assert (body["quota"], body["limit"], body["current"]) == ("max_queued", 2, 2)
    assert body["status"] == 429 and body["title"] == "Quota exceeded"  # not the extension's 500


def test_extension_members_retry_info_and_quota_failure_over_grpc():
    status = to_status(PLATFORM_PROBLEMS.problem_for(UsedUp("two jobs queued")))
    assert status.code == grpc.StatusCode.RESOURCE_EXHAUSTED
    details = {}
    for packed in status_pb2.Status.FromString(status.trailing_metadata[0][1]).details:
        for kind in (
            error_details_pb2.ErrorInfo,
            error_details_pb2.RetryInfo,
            error_details_pb2.QuotaFailure,
        ):
            message = kind()
            if packed.Unpack(message):
                details[kind.__name__] = message
    metadata = details["ErrorInfo"].metadata
    assert (metadata["quota"], metadata["limit"], metadata["current"]) == ("max_queued", "2", "2")
    assert (metadata["status"], metadata["retry_after"]) == ("429", "7")
    assert details["RetryInfo"].retry_delay.seconds == 7
    (violation,) = details["QuotaFailure"].violations
    assert (violation.subject, violation.description) == ("max_queued", "two jobs queued")
