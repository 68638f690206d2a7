"""`/v1/assets`: upload a scene with its files (or one zip/tar archive), read an asset's listing back."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, File, Response, UploadFile

from services.api.deps import ServicesDep
from services.artifacts.uploads import Asset, ingest_upload, load_asset, save_asset
from services.platform.auth import CanRead, CanSubmit
from services.platform.problems import PROBLEM_RESPONSES

router = APIRouter(prefix="/v1/assets", tags=["assets"], responses={401: PROBLEM_RESPONSES[401]})


@router.post(
    "",
    status_code=201,
    response_model=Asset,
    responses={s: PROBLEM_RESPONSES[s] for s in (400, 403, 413, 422)},
)
def upload_asset(
    files: Annotated[
        list[UploadFile],
        File(description="The scene file (scene.yaml/.json) with its meshes and textures, or one archive."),
    ],
    response: Response,
    svc: ServicesDep,
    principal: CanSubmit,
) -> Asset:
    """Store the files content-addressed (sha256); the scene is validated now (errors name the field).
    The asset becomes visible to the token's tenant (the same files of another tenant share the storage,
    not the visibility)."""
    parts = [(upload.filename or "", upload.file) for upload in files]
    asset = ingest_upload(
        parts, svc.blobs, svc.settings.upload_limits, work_dir=svc.settings.data_dir, geometry=svc.geometry
    )
    svc.tenancy.own_asset(principal.tenant, asset.asset_id)
    save_asset(asset, svc.blobs, svc.settings.store)
    response.headers["Location"] = f"/v1/assets/{asset.asset_id}"
    return asset


@router.get(
    "/{asset_id}",
    response_model=Asset,
    responses={s: PROBLEM_RESPONSES[s] for s in (403, 404)},
)
def get_asset(asset_id: str, svc: ServicesDep, principal: CanRead) -> Asset:
    return load_asset(svc.tenancy.asset(principal, asset_id), svc.settings.store)
