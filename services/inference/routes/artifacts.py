"""An artifact's operations, by id: those that answer arrays (`:query`, `mesogan`'s `:generate`) and
`:render`, which answers an image. Bodies are JSON (arrays base64) or binary (a JSON header
line, then raw arrays); see `services.inference.wire` for the format, also documented in OpenAPI.

A query holds its memory (the service's reading pool for its body, then its working memory) until its
answer has been sent, not only until it is computed: a sent answer is a copy of the outputs that lives
in the transport's buffer while a slow client reads it, 16 of them about 90 MB in the memory test.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from typing import Any

import numpy as np
from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, Response
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool
from starlette.types import Receive, Scope, Send

from services.inference import images, wire
from services.inference.errors import MalformedBody
from services.inference.service import InferenceService, server_timing
from services.inference.state import StateDep
from services.platform.auth import CanRead
from services.platform.problems import PROBLEM_RESPONSES
from workers.models.registry import RENDER

router = APIRouter(prefix="/v1/artifacts", tags=["inference"])
ERRORS = {**PROBLEM_RESPONSES, 503: {"description": "No answer within the request timeout; retry"}}

BINARY_DOC = (
    'One line of compact JSON `{"params": {...}, "arrays": {name: {"dtype", "shape"}}}` ending in '
    "`\\n`, then each array's little-endian C-order bytes in the header's order."
)


# A body of parameters and arrays, as JSON or binary.
BODY_CONTENT = {
    "application/json": {"schema": wire.self_contained_schema(wire.QueryBody)},
    wire.OCTET_STREAM: {"schema": {"type": "string", "format": "binary", "description": BINARY_DOC}},
}

# Copies of a body alive while it is received and parsed, before the working pool counts it: binary, the
# received chunks and their join (the arrays are views of it); JSON, the same, the parsed base64 strings
# and the decoded bytes.
RECEIVE_COPIES = {True: 2, False: 3}


class _Held(Response):
    """`answer`, sent; `release` runs once it is sent or the client is gone, whichever comes first."""

    def __init__(self, answer: Response, release: Callable[[], None]) -> None:
        self.answer, self.release = answer, release
        self.background = None  # FastAPI attaches the route's background tasks here; these routes have none

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            await self.answer(scope, receive, send)
        finally:
            self.release()


def _is_binary(content_type: str | None) -> bool:
    return (content_type or "").split(";")[0].strip() == wire.OCTET_STREAM


def _parse(body: bytes, content_type: str | None) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    if _is_binary(content_type):
        return wire.decode_binary(body)
    try:
        parsed = wire.QueryBody.model_validate_json(body or b"{}")
    except ValidationError as error:
        first = error.errors()[0]
        field = ".".join(str(p) for p in first["loc"]) or "body"
        raise MalformedBody(first["msg"], field) from None
    return parsed.params, wire.decode_json(parsed)


async def _respond(
    service: InferenceService, request: Request, answer: Callable[[ExitStack, bytes], Response]
) -> Response:
    """`answer(held, body)` off the event loop, once the service's reading pool holds room for the body's
    copies; that room and whatever `answer` enters into `held` are kept until the response is sent."""
    declared = request.headers.get("content-length", "")
    size = int(declared) if declared.isdigit() else service.settings.max_body_bytes  # BodyLimit holds it
    reading = service.admitted_body(RECEIVE_COPIES[_is_binary(request.headers.get("content-type"))] * size)
    held = ExitStack()  # the thread pushes each release once it holds the bytes, so a cancelled wait too

    def hold() -> None:
        service.reading.acquire(reading, service.settings.request_timeout_s)
        held.callback(service.reading.release, reading)

    try:
        if service.reading.try_acquire(reading):  # without a thread of the pool when nobody waits
            held.callback(service.reading.release, reading)
        else:
            await run_in_threadpool(hold)
        body = await request.body()
        response = await run_in_threadpool(answer, held, body)
    except BaseException as error:
        held.__exit__(type(error), error, error.__traceback__)  # the request is counted under its error
        raise
    return _Held(response, held.close)


def _answer_arrays(
    service: InferenceService,
    held: ExitStack,
    artifact_id: str,
    operation: str,
    body: bytes,
    content_type: str | None,
    binary: bool,
) -> Response:
    """Off the event loop: decoding, the model and encoding, in the service's working memory (entered
    into `held`, so it lasts until the answer is sent)."""
    params, arrays = _parse(body, content_type)
    served, answer = held.enter_context(service.answering(artifact_id, operation, params, arrays, len(body)))
    head = {"artifact_id": artifact_id, "kind": served.loaded.kind, "meta": answer.meta}
    if binary:
        return Response(wire.encode_binary(head, answer.arrays), media_type=wire.OCTET_STREAM)
    return JSONResponse(wire.encode_json(head, answer.arrays))


@router.post(
    "/{artifact_id}:render",
    response_class=Response,
    responses={
        200: {
            "description": "The image: OpenEXR (linear float32, default) or PNG (sRGB) by `Accept`",
            "content": {images.EXR: {}, images.PNG: {}},
        },
        **ERRORS,
    },
    openapi_extra={
        "requestBody": {
            "required": False,
            "description": "`params` (the kind's render parameters) and, for kinds that take them, input "
            "arrays: `prt` an uploaded lat-long `environment` (H, W, 3), `mesogan` an uploaded `mesh` "
            "(triangles, 3, 8): position, normal and UV per corner.",
            "content": BODY_CONTENT,
        }
    },
)
async def render(artifact_id: str, request: Request, state: StateDep, principal: CanRead) -> Response:
    """An image of the artifact, for kinds that make one (a path-traced view takes `params.camera`:
    position, target, up, fov, width, height); `Server-Timing: frame;dur=<ms>` says how long it took."""
    await run_in_threadpool(state.tenancy.artifact, principal, artifact_id)  # another tenant's: 404
    service, content_type = state.service, request.headers.get("content-type")
    media_type = images.media_type_for(request.headers.get("accept"))

    def answer(held: ExitStack, body: bytes) -> Response:
        params, arrays = _parse(body, content_type)
        _, answer = held.enter_context(service.answering(artifact_id, RENDER, params, arrays, len(body)))
        data = images.encode(answer.arrays["image"], media_type)
        return Response(data, media_type=media_type, headers={"Server-Timing": server_timing(answer)})

    return await _respond(service, request, answer)


# After `:render`, which answers an image: routes match in the order they are added.
@router.post(
    "/{artifact_id}:{operation}",
    responses={
        200: {
            "description": "The output arrays, in the request's format (or `Accept`)",
            "content": {
                "application/json": {"schema": wire.self_contained_schema(wire.QueryResult)},
                wire.OCTET_STREAM: {
                    "schema": {"type": "string", "format": "binary", "description": BINARY_DOC}
                },
            },
        },
        **ERRORS,
    },
    openapi_extra={
        "requestBody": {
            "required": True,
            "description": "Kind-specific: `lsnif`'s query takes `origins` and `directions` (N, 3) "
            "world-space rays; `render`'s takes optional `pixels` (N, 2) as (x, y) and `params.layers`; "
            "`mesogan`'s `generate` takes only `params` (`origin`, `size`, `structure`, `seed`).",
            "content": BODY_CONTENT,
        }
    },
)
async def operate(
    artifact_id: str, operation: str, request: Request, state: StateDep, principal: CanRead
) -> Response:
    """An operation of the artifact's kind that answers arrays: `query` (every served kind has one), or
    another the model lists under `/v1/models` (`mesogan`: `generate`, a window of its feature plane);
    an image is `:render`. Concurrent queries of one model are merged into one call where the kind
    allows."""
    await run_in_threadpool(state.tenancy.artifact, principal, artifact_id)  # another tenant's: 404
    service = state.service
    content_type, accept = request.headers.get("content-type"), request.headers.get("accept", "")
    binary = wire.OCTET_STREAM in accept or (_is_binary(content_type) and "json" not in accept)

    def answer(held: ExitStack, body: bytes) -> Response:
        return _answer_arrays(service, held, artifact_id, operation, body, content_type, binary)

    return await _respond(service, request, answer)
