"""The gRPC server a server runs beside its REST app, on its own port: interceptors map errors to
statuses (outermost) and check tokens; the standard health service reports SERVING while the server runs;
server reflection lets `grpcurl` and friends discover the API. Messages are capped in size and calls share
a bounded worker pool.
"""

from __future__ import annotations

import socket
from collections.abc import Callable
from concurrent import futures
from dataclasses import dataclass

import grpc
from grpc_health.v1 import health, health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection

from services.platform.auth import TokenStore
from services.platform.grpc.auth import TokenAuth
from services.platform.grpc.errors import ErrorMapping
from services.platform.problem_table import ProblemTable

STOP_GRACE_S = 5.0
HEALTH = health_pb2.DESCRIPTOR.services_by_name["Health"].full_name


@dataclass(frozen=True)
class GrpcServices:
    """What one server serves over gRPC: `add(server)` registers its servicers, `names` are their full
    service names (for health and reflection), `scope_for(method)` the scope a method needs (None: open),
    and `table` what each error stands for."""

    add: Callable[[grpc.Server], None]
    names: tuple[str, ...]
    scope_for: Callable[[str], str | None]
    table: ProblemTable


@dataclass(frozen=True)
class GrpcLimits:
    max_workers: int  # each call (an open stream too) holds one worker while it runs
    max_message_bytes: int
    max_concurrent_rpcs: int | None = None  # beyond it, RESOURCE_EXHAUSTED; None: the workers bound it
    thread_name: str = "nbake-grpc"


@dataclass
class GrpcServer:
    server: grpc.Server
    health: health.HealthServicer
    port: int

    def stop(self) -> None:
        self.health.enter_graceful_shutdown()
        self.server.stop(STOP_GRACE_S).wait()


def start_grpc(
    services: GrpcServices,
    tokens: TokenStore,
    limits: GrpcLimits,
    host: str,
    port: int,
    reservation: socket.socket | None = None,
) -> GrpcServer:
    """Serve `services` on `host:port` (0: any free port; `GrpcServer.port` says which), checking tokens
    against `tokens`. A `reservation` (`services.platform.ports.reserved_port`) held the port until now: it
    closes once the server has bound it."""
    server = grpc.server(
        futures.ThreadPoolExecutor(max_workers=limits.max_workers, thread_name_prefix=limits.thread_name),
        interceptors=[ErrorMapping(services.table), TokenAuth(tokens, services.scope_for)],
        options=[
            ("grpc.max_receive_message_length", limits.max_message_bytes),
            ("grpc.max_send_message_length", limits.max_message_bytes),
        ],
        maximum_concurrent_rpcs=limits.max_concurrent_rpcs,
    )
    services.add(server)
    checker = health.HealthServicer()
    health_pb2_grpc.add_HealthServicer_to_server(checker, server)
    reflection.enable_server_reflection((*services.names, HEALTH, reflection.SERVICE_NAME), server)
    address = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    try:
        bound = server.add_insecure_port(address)
    finally:
        if reservation is not None:
            reservation.close()
    server.start()
    for name in ("", *services.names):
        checker.set(name, health_pb2.HealthCheckResponse.SERVING)
    return GrpcServer(server, checker, bound)
