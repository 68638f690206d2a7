"""`InferenceService` over gRPC, beside the REST app on its own port: the same service core (cache,
batching, limits), and the same server base, token check and error statuses as the job server's gRPC API
(`services.platform.grpc`)."""

from __future__ import annotations

import socket

import grpc
import numpy as np
from google.protobuf import struct_pb2
from neuralbake.v1 import inference_pb2, inference_pb2_grpc
from pydantic import ValidationError

from services.inference import images
from services.inference.errors import MalformedBody, UnsupportedOperation
from services.inference.service import ModelInfo, server_timing
from services.inference.state import InferenceState
from services.inference.wire import ArrayHeader, array_bytes, decode_array
from services.jobs.problems import JOB_PROBLEMS
from services.platform.grpc.auth import principal
from services.platform.grpc.server import GrpcLimits, GrpcServer, GrpcServices, start_grpc
from services.platform.grpc.structs import json_values
from workers.models.registry import QUERY, RENDER

SERVICE = inference_pb2.DESCRIPTOR.services_by_name["InferenceService"].full_name
MAX_WORKERS = 96  # calls block while their batch runs: enough threads for many concurrent clients


def needed_scope(method: str) -> str | None:
    """Every InferenceService call needs scope `read`; health and reflection stay open."""
    return "read" if method.startswith(f"/{SERVICE}/") else None


def _model(info: ModelInfo) -> inference_pb2.Model:
    return inference_pb2.Model(**info.model_dump())


def _struct(values: dict) -> struct_pb2.Struct:
    message = struct_pb2.Struct()
    message.update(values)
    return message


def _arrays(messages) -> dict[str, np.ndarray]:
    arrays = {}
    for message in messages:
        if message.name in arrays:
            raise MalformedBody("named twice", f"arrays.{message.name}")
        try:
            header = ArrayHeader(dtype=message.dtype, shape=list(message.shape))
        except ValidationError as error:  # a dimension past int32: refused like the REST header
            raise MalformedBody(error.errors()[0]["msg"], f"arrays.{message.name}.shape") from None
        arrays[message.name] = decode_array(f"arrays.{message.name}", header, message.data)
    return arrays


def _array_message(name: str, array: np.ndarray) -> inference_pb2.Array:
    return inference_pb2.Array(
        name=name, dtype=array.dtype.name, shape=list(array.shape), data=array_bytes(array)
    )


class InferenceServicer(inference_pb2_grpc.InferenceServiceServicer):
    def __init__(self, state: InferenceState):
        self.service, self.tenancy = state.service, state.tenancy

    def ListModels(self, request, context):
        caller = principal(context)
        models = [m for m in self.service.models() if self.tenancy.sees_artifact(caller, m.artifact_id)]
        return inference_pb2.ListModelsResponse(models=[_model(m) for m in models])

    def LoadModel(self, request, context):
        artifact_id = self.tenancy.artifact(principal(context), request.artifact_id)
        return inference_pb2.LoadModelResponse(model=_model(self.service.served(artifact_id).info()))

    def Query(self, request, context):
        """Any operation that answers arrays, as REST's `:{operation}` (`query` by default)."""
        self.tenancy.artifact(principal(context), request.artifact_id)  # another tenant's: NOT_FOUND
        operation = request.operation or QUERY
        if operation == RENDER:
            raise UnsupportedOperation("render answers an image: call Render", "operation")
        params = json_values(request.params, "params")
        arrays = _arrays(request.arrays)
        size = request.ByteSize()
        with self.service.answering(request.artifact_id, operation, params, arrays, size) as (served, answer):
            return inference_pb2.QueryResponse(
                artifact_id=request.artifact_id,
                kind=served.loaded.kind,
                meta=_struct(answer.meta),
                arrays=[_array_message(name, array) for name, array in answer.arrays.items()],
            )

    def Render(self, request, context):
        self.tenancy.artifact(principal(context), request.artifact_id)  # another tenant's: NOT_FOUND
        params, arrays = json_values(request.params, "params"), _arrays(request.arrays)
        media_type = images.media_type_for(request.media_type)
        size = request.ByteSize()
        with self.service.answering(request.artifact_id, RENDER, params, arrays, size) as (_, answer):
            context.set_trailing_metadata((("server-timing", server_timing(answer)),))
            return inference_pb2.RenderResponse(
                media_type=media_type, data=images.encode(answer.arrays["image"], media_type)
            )


def start_grpc_inference(
    state: InferenceState,
    host: str,
    port: int,
    max_message_bytes: int,
    reservation: socket.socket | None = None,
) -> GrpcServer:
    """Serve InferenceService on `host:port` (0: any free port; `.port` says which). A `reservation`
    (`services.platform.ports.reserved_port`) held the port until now: it closes once the server has bound
    it."""

    def add(server: grpc.Server) -> None:
        inference_pb2_grpc.add_InferenceServiceServicer_to_server(InferenceServicer(state), server)

    served = GrpcServices(add, (SERVICE,), needed_scope, JOB_PROBLEMS)
    limits = GrpcLimits(MAX_WORKERS, max_message_bytes, thread_name="nbake-inference-grpc")
    return start_grpc(served, state.tokens, limits, host, port, reservation)
