"""Every error answer is `application/problem+json` (RFC 9457) with a `detail` a person can act on and,
for bad input, the `field` at fault. Bad input is always a 4xx; only a real bug is a 500. The server's own
errors go through the table its gRPC server shares (`services.platform.problem_table`); FastAPI's own errors
are mapped here.
"""

from __future__ import annotations

import json
import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from services.platform.problem_table import ProblemInfo, ProblemTable, internal_problem
from workers.scene.portability.io import dotted_path

PROBLEM_JSON = "application/problem+json"
log = logging.getLogger(__name__)


class Problem(BaseModel):
    type: str = "about:blank"
    title: str
    status: int
    detail: str
    instance: str | None = None
    field: str | None = None


def problem(
    request: Request,
    status: int,
    title: str,
    detail: str,
    field: str | None = None,
    headers=None,
    extensions: dict[str, Any] | None = None,
) -> JSONResponse:
    """The document; `extensions` are members beside the standard ones, which they cannot replace."""
    body = Problem(title=title, status=status, detail=detail, instance=request.url.path, field=field)
    return JSONResponse(
        (extensions or {}) | body.model_dump(exclude_none=True),
        status_code=status,
        media_type=PROBLEM_JSON,
        headers=headers,
    )


PROBLEM_RESPONSES = {
    status: {"model": Problem, "content": {PROBLEM_JSON: {}}, "description": text}
    for status, text in {
        400: "Malformed request",
        401: "Missing or unknown bearer token",
        403: "The token lacks the scope",
        404: "Not found",
        409: "Conflict",
        413: "Request body too large",
        422: "Invalid input (the `field` names it)",
        429: "A quota is used up: retry after `Retry-After` seconds (`quota`, its `limit`, `current` use)",
    }.items()
}


def _document(request: Request, info: ProblemInfo) -> JSONResponse:
    return problem(request, info.status, info.title, info.detail, info.field, info.headers, info.extensions)


def install(app: FastAPI, table: ProblemTable) -> None:
    """Register the handlers that turn every error into a problem document, the server's own by `table`."""

    async def _actionable(request: Request, error: Exception):
        return _document(request, table.problem_for(error))

    for error_type in table.actionable:
        app.add_exception_handler(error_type, _actionable)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, error: RequestValidationError):
        return validation_problem(request, error)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, error: StarletteHTTPException):
        title = {404: "Not found", 405: "Method not allowed", 413: "Request body too large"}
        headers = getattr(error, "headers", None)
        if error.status_code == 405:
            headers = {**(headers or {}), "Allow": ", ".join(allowed_methods(app, request))}
        return problem(
            request,
            error.status_code,
            title.get(error.status_code, "Error"),
            str(error.detail),
            None,
            headers,
        )

    app.add_middleware(BugsAsProblems)


HTTP_METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE")


def allowed_methods(app: FastAPI, request: Request) -> list[str]:
    """Every method some route serves at the request's path (Starlette's 405 names only the first
    route's), found by asking the routes (nested routers included) whether each method would match."""
    return [
        method
        for method in HTTP_METHODS
        if any(
            route.matches({**request.scope, "method": method})[0] == Match.FULL for route in app.router.routes
        )
    ]


class BugsAsProblems:
    """ASGI middleware: a bug becomes a 500 problem document here. Starlette's own last-resort handler
    re-raises after answering, and uvicorn then closes the connection, so the client's next request on
    that keep-alive connection was reset."""

    def __init__(self, app: ASGIApp):
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def tracked(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, receive, tracked)
        except Exception as error:
            if started:  # half an answer is out: only closing the connection can tell the client
                raise
            request = Request(scope)
            log.exception("unhandled error on %s %s", request.method, request.url.path)
            await _document(request, internal_problem(error))(scope, receive, send)


def validation_problem(request: Request, error: RequestValidationError) -> JSONResponse:
    """400 for unparsable JSON (with where it broke); 422 naming the first invalid field otherwise."""
    errors = error.errors()
    first = errors[0] if errors else {"loc": ("body",), "msg": "invalid request", "type": ""}
    if first.get("type") == "json_invalid":
        where = first.get("ctx", {}).get("error", "")
        return problem(request, 400, "Malformed JSON", f"the body is not valid JSON: {where}".rstrip(": "))
    location, *path = first["loc"] or ("body",)
    body = _body(error)
    field = (
        dotted_path(tuple(path), body) if location == "body" else ".".join(str(p) for p in first["loc"][1:])
    )
    field = field or str(location)
    return problem(request, 422, "Invalid input", f"{field}: {first['msg']}", field)


def _body(error: RequestValidationError):
    try:
        return json.loads(error.body) if isinstance(error.body, bytes | str) else error.body
    except ValueError:
        return None
