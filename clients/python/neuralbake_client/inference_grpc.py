"""The inference service over gRPC (`neuralbake.v1.InferenceService`): arrays as `Array` messages, the
same token metadata and the same exceptions as the job API's transport. Messages may be as large as the
server accepts (its body limit), not gRPC's 4 MiB default.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import grpc
from neuralbake.v1 import inference_pb2, inference_pb2_grpc
from numpy.typing import ArrayLike

from neuralbake_client.answers import QueryAnswer, RenderedImage, frame_time
from neuralbake_client.arrays import from_bytes, little_endian
from neuralbake_client.models import ModelInfo
from neuralbake_client.transport_grpc import as_dict, call_error, open_channel, struct

UNLIMITED = -1
MESSAGE_OPTIONS = [
    ("grpc.max_receive_message_length", UNLIMITED),
    ("grpc.max_send_message_length", UNLIMITED),
]


def _array_message(name: str, array: ArrayLike) -> inference_pb2.Array:
    wire = little_endian(array)
    return inference_pb2.Array(name=name, dtype=wire.dtype.name, shape=list(wire.shape), data=wire.tobytes())


class GrpcInference:
    def __init__(self, target: str, token: str | None, timeout: float, secure: bool):
        self.channel = open_channel(target, secure, MESSAGE_OPTIONS)
        self.metadata = (("authorization", f"Bearer {token}"),) if token else ()
        self.timeout = timeout
        self.stub = inference_pb2_grpc.InferenceServiceStub(self.channel)

    def close(self) -> None:
        self.channel.close()

    def _call(self, method, request):
        """(response, call): the call carries the trailing metadata."""
        try:
            return method.with_call(request, metadata=self.metadata, timeout=self.timeout)
        except grpc.RpcError as error:
            raise call_error(error) from None

    def models(self) -> list[ModelInfo]:
        response, _ = self._call(self.stub.ListModels, inference_pb2.ListModelsRequest())
        return [ModelInfo.model_validate(as_dict(m)) for m in response.models]

    def load(self, artifact_id: str) -> ModelInfo:
        response, _ = self._call(self.stub.LoadModel, inference_pb2.LoadModelRequest(artifact_id=artifact_id))
        return ModelInfo.model_validate(as_dict(response.model))

    def query(
        self,
        artifact_id: str,
        params: dict[str, Any],
        arrays: Mapping[str, ArrayLike],
        operation: str = "query",
    ) -> QueryAnswer:
        request = inference_pb2.QueryRequest(
            artifact_id=artifact_id,
            params=struct(params),
            arrays=[_array_message(name, array) for name, array in arrays.items()],
            operation=operation,
        )
        response, _ = self._call(self.stub.Query, request)
        answer = {a.name: from_bytes(a.dtype, list(a.shape), a.data) for a in response.arrays}
        meta = as_dict(response.meta) if response.HasField("meta") else {}
        return QueryAnswer(response.artifact_id, response.kind, answer, meta)

    def render(
        self, artifact_id: str, params: dict[str, Any], arrays: Mapping[str, ArrayLike], media_type: str
    ) -> RenderedImage:
        request = inference_pb2.RenderRequest(
            artifact_id=artifact_id,
            params=struct(params),
            media_type=media_type,
            arrays=[_array_message(name, array) for name, array in arrays.items()],
        )
        response, call = self._call(self.stub.Render, request)
        metadata = dict(call.initial_metadata() or ()) | dict(call.trailing_metadata() or ())
        timing = frame_time(metadata.get("server-timing"))
        return RenderedImage(artifact_id, response.media_type, response.data, timing)
