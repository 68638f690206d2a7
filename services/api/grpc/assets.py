"""`neuralbake.v1.AssetService`: uploads arrive as a client stream of chunks, are spooled to anonymous
temporary files (names from the client never touch the file system here) and then go through the same
`ingest_upload` as REST uploads, which checks names, archives, limits and the scene.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from contextlib import ExitStack
from typing import TYPE_CHECKING, BinaryIO

from neuralbake.v1 import assets_pb2, assets_pb2_grpc

from services.api.grpc.messages import asset_message
from services.api.grpc.streams import StreamTracker
from services.artifacts.staging import PAYLOAD_TOO_LARGE, UploadError
from services.artifacts.uploads import ingest_upload, load_asset, save_asset
from services.platform.grpc.auth import principal

if TYPE_CHECKING:  # annotations only: the inference service reuses this package
    from services.api.services import Services


class AssetServicer(assets_pb2_grpc.AssetServiceServicer):
    def __init__(self, services: Services, streams: StreamTracker):
        self.svc, self.streams = services, streams

    def UploadAsset(self, request_iterator: Iterator[assets_pb2.UploadAssetRequest], context):
        limits = self.svc.settings.upload_limits
        work = self.svc.settings.data_dir
        parts: list[tuple[str, BinaryIO]] = []
        received = 0
        with self.streams.track("UploadAsset"), ExitStack() as spools:
            for chunk in request_iterator:  # raises once the client has gone: the spools are closed
                received += len(chunk.data)
                if received > limits.max_total_bytes:
                    raise UploadError(
                        "files", f"the upload exceeds {limits.max_total_bytes} bytes", PAYLOAD_TOO_LARGE
                    )
                if not parts or parts[-1][0] != chunk.path:
                    parts.append((chunk.path, spools.enter_context(tempfile.TemporaryFile(dir=work))))
                parts[-1][1].write(chunk.data)
            for _, spool in parts:
                spool.seek(0)
            asset = ingest_upload(parts, self.svc.blobs, limits, work_dir=work, geometry=self.svc.geometry)
        self.svc.tenancy.own_asset(principal(context).tenant, asset.asset_id)
        save_asset(asset, self.svc.blobs, self.svc.settings.store)
        return assets_pb2.UploadAssetResponse(asset=asset_message(asset))

    def GetAsset(self, request, context):
        asset_id = self.svc.tenancy.asset(principal(context), request.asset_id)
        asset = load_asset(asset_id, self.svc.settings.store)
        return assets_pb2.GetAssetResponse(asset=asset_message(asset))
