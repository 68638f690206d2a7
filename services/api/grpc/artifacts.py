"""`neuralbake.v1.ArtifactService`: manifests, and files streamed in chunks from any offset (a client
resumes an interrupted download by asking again from the bytes it has)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

from neuralbake.v1 import artifacts_pb2, artifacts_pb2_grpc

from services.api.grpc.messages import manifest_message
from services.api.grpc.streams import StreamTracker
from services.platform.errors import InvalidInput
from services.platform.grpc.auth import principal

if TYPE_CHECKING:  # annotations only: the inference service reuses this package
    from services.api.services import Services

CHUNK_BYTES = 1 << 20  # well under the message limit; large enough that framing costs nothing


class ArtifactServicer(artifacts_pb2_grpc.ArtifactServiceServicer):
    def __init__(self, services: Services, streams: StreamTracker):
        self.svc, self.streams = services, streams

    def GetManifest(self, request, context):
        artifact_id = self.svc.tenancy.artifact(principal(context), request.artifact_id)
        manifest = self.svc.artifacts.manifest(artifact_id)
        return artifacts_pb2.GetManifestResponse(manifest=manifest_message(manifest))

    def DownloadFile(self, request, context) -> Iterator[artifacts_pb2.DownloadFileResponse]:
        artifact_id = self.svc.tenancy.artifact(principal(context), request.artifact_id)
        entry = self.svc.artifacts.file(artifact_id, request.name)
        if not 0 <= request.offset <= entry.size:
            raise InvalidInput(f"must be 0 to the file's size {entry.size}", "offset")
        self.svc.blobs.verify(entry.digest)
        offset = request.offset
        with self.streams.track("DownloadFile"), self.svc.blobs.open(entry.digest) as stream:
            stream.seek(offset)
            while offset < entry.size and context.is_active():
                data = stream.read(min(CHUNK_BYTES, entry.size - offset))
                if not data:
                    break
                yield artifacts_pb2.DownloadFileResponse(
                    offset=offset, data=data, size=entry.size, digest=entry.digest
                )
                offset += len(data)
