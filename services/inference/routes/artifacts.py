"""Queries and renders of an artifact, by id. Bodies are JSON (arrays base64) or binary (a JSON header
line, then raw arrays); see `services.inference.wire` for the format, also documented in OpenAPI."""

from __future__ import annotations

from typing import Any

import numpy as np
from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field, ValidationError
from starlette.concurrency import run_in_threadpool

from services.api.auth import CanRead
from services.api.problems import PROBLEM_RESPONSES
from services.inference import images, wire
from services.inference.errors import MalformedBody
from services.inference.service import server_timing
from services.inference.state import StateDep
from workers.models.registry import QUERY, RENDER

router = APIRouter(prefix="/v1/artifacts", tags=["inference"])
ERRORS = {**PROBLEM_RESPONSES, 503: {"description": "No answer within the request timeout; retry"}}

BINARY_DOC = (
    'One line of compact JSON `{"params": {...}, "arrays": {name: {"dtype", "shape"}}}` ending in '
    "`\\n`, then each array's little-endian C-order bytes in the header's order."
)


class RenderBody(BaseModel):
    params: dict[str, Any] = Field(default_factory=dict, description="the kind's typed render parameters")


def _is_binary(content_type: str | None) -> bool:
    return (content_type or "").split(";")[0].strip() == wire.OCTET_STREAM


async def _parse(request: Request) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    body = await request.body()
    if _is_binary(request.headers.get("content-type")):
        return wire.decode_binary(body)
    try:
        parsed = wire.QueryBody.model_validate_json(body or b"{}")
    except ValidationError as error:
        first = error.errors()[0]
        field = ".".join(str(p) for p in first["loc"]) or "body"
        raise MalformedBody(first["msg"], field) from None
    return parsed.params, wire.decode_json(parsed)


@router.post(
    "/{artifact_id}:query",
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
            "description": "Kind-specific: `lsnif` takes `origins` and `directions` (N, 3) world-space rays; "
            "`render` takes optional `pixels` (N, 2) as (x, y) and `params.layers`.",
            "content": {
                "application/json": {"schema": wire.self_contained_schema(wire.QueryBody)},
                wire.OCTET_STREAM: {
                    "schema": {"type": "string", "format": "binary", "description": BINARY_DOC}
                },
            },
        }
    },
)
async def query(artifact_id: str, request: Request, state: StateDep, principal: CanRead) -> Response:
    """Batched kind-specific queries: concurrent requests for one model are merged into one call."""
    await run_in_threadpool(state.tenancy.artifact, principal, artifact_id)  # another tenant's: 404
    params, arrays = await _parse(request)
    served, answer = await run_in_threadpool(state.service.call, artifact_id, QUERY, params, arrays)
    head = {"artifact_id": artifact_id, "kind": served.loaded.kind, "meta": answer.meta}
    accept = request.headers.get("accept", "")
    if wire.OCTET_STREAM in accept or (
        _is_binary(request.headers.get("content-type")) and "json" not in accept
    ):
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
)
async def render(
    artifact_id: str, request: Request, state: StateDep, principal: CanRead, body: RenderBody | None = None
) -> Response:
    """An image of the artifact, for kinds that make one (a path-traced view takes `params.camera`:
    position, target, up, fov, width, height); `Server-Timing: frame;dur=<ms>` says how long it took."""
    await run_in_threadpool(state.tenancy.artifact, principal, artifact_id)  # another tenant's: 404
    params = body.params if body else {}
    _, answer = await run_in_threadpool(state.service.call, artifact_id, RENDER, params, {})
    media_type = images.media_type_for(request.headers.get("accept"))
    data = await run_in_threadpool(images.encode, answer.arrays["image"], media_type)
    return Response(data, media_type=media_type, headers={"Server-Timing": server_timing(answer)})
