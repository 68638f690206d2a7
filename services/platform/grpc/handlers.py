"""Rewrapping a gRPC method handler's behaviour, whatever its streaming arity, so that interceptors
(auth, error mapping) can run code inside the worker thread of the call rather than in the poller.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import grpc

Behaviour = Callable[[Any, grpc.ServicerContext], Any]


def arity(handler: grpc.RpcMethodHandler) -> str:
    """`unary_unary`, `unary_stream`, `stream_unary` or `stream_stream`."""
    requests = "stream" if handler.request_streaming else "unary"
    responses = "stream" if handler.response_streaming else "unary"
    return f"{requests}_{responses}"


def rewrap(
    handler: grpc.RpcMethodHandler, around: Callable[[Behaviour, bool], Behaviour]
) -> grpc.RpcMethodHandler:
    """A handler of the same arity whose behaviour is `around(behaviour, response_streaming)`."""
    kind = arity(handler)
    factory = getattr(grpc, f"{kind}_rpc_method_handler")
    return factory(
        around(getattr(handler, kind), handler.response_streaming),
        request_deserializer=handler.request_deserializer,
        response_serializer=handler.response_serializer,
    )
