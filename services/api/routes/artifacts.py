"""`/v1/artifacts`: an artifact's manifest and its files (ETag, Range, Content-Length)."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import Response

from services.api.deps import ServicesDep
from services.api.files import blob_response
from services.artifacts.manifest import Manifest
from services.artifacts.media_types import MEDIA_TYPES
from services.platform.auth import CanRead
from services.platform.problems import PROBLEM_RESPONSES

router = APIRouter(
    prefix="/v1/artifacts",
    tags=["artifacts"],
    responses={s: PROBLEM_RESPONSES[s] for s in (401, 403, 404)},
)


@router.get("/{artifact_id}", response_model=Manifest)
def get_manifest(artifact_id: str, svc: ServicesDep, principal: CanRead) -> Manifest:
    """The OCI-style manifest: files (media types, digests, sizes); kind, job, scene, config, metrics.
    Only artifacts of the token's tenant's jobs are found (all of them with an admin token)."""
    return svc.artifacts.manifest(svc.tenancy.artifact(principal, artifact_id))


@router.get(
    "/{artifact_id}/files/{name:path}",
    response_class=Response,
    responses={
        200: {
            "description": "The file, with the media type of its manifest entry",
            "content": {media_type: {} for media_type in MEDIA_TYPES},
        },
        206: {"description": "The requested byte range"},
        304: {"description": "Not modified (If-None-Match)"},
        416: {"description": "Range not satisfiable"},
    },
)
def get_file(artifact_id: str, name: str, request: Request, svc: ServicesDep, principal: CanRead) -> Response:
    entry = svc.artifacts.file(svc.tenancy.artifact(principal, artifact_id), name)
    return blob_response(request, svc.blobs, entry)
