"""The gRPC server beside the REST app: the same `Services`, the same tokens, its own port.

Interceptors map errors to statuses (outermost) and check tokens; the standard health service reports
SERVING while the server runs; server reflection lets `grpcurl` and friends discover the API. Messages
are capped in size and calls share a bounded worker pool (beyond it, RESOURCE_EXHAUSTED).
"""

from __future__ import annotations

import socket
from collections.abc import AsyncIterator, Iterator
from concurrent import futures
from contextlib import asynccontextmanager, contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING

import grpc
from fastapi import FastAPI
from grpc_health.v1 import health, health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection
from neuralbake.v1 import (
    artifacts_pb2,
    artifacts_pb2_grpc,
    assets_pb2,
    assets_pb2_grpc,
    jobs_pb2,
    jobs_pb2_grpc,
)

from services.api.grpc.artifacts import ArtifactServicer
from services.api.grpc.assets import AssetServicer
from services.api.grpc.auth import TokenAuth
from services.api.grpc.errors import ErrorMapping
from services.api.grpc.jobs import JobServicer
from services.api.grpc.streams import StreamTracker

if TYPE_CHECKING:  # the inference service reuses this server without the job service's Services
    from services.api.services import Services

MAX_MESSAGE_BYTES = 4 << 20  # an upload chunk or a download chunk (1 MiB) with room for framing
MAX_WORKERS = 32  # each open stream (WatchJob, DownloadFile) holds one worker while it runs
MAX_CONCURRENT_RPCS = 256
STOP_GRACE_S = 5.0
SERVICE_NAMES = tuple(
    service.full_name
    for module in (jobs_pb2, assets_pb2, artifacts_pb2)
    for service in module.DESCRIPTOR.services_by_name.values()
)


@dataclass
class GrpcServer:
    server: grpc.Server
    health: health.HealthServicer
    port: int

    def stop(self) -> None:
        self.health.enter_graceful_shutdown()
        self.server.stop(STOP_GRACE_S).wait()


def start_grpc_server(
    services: Services, host: str, port: int, reservation: socket.socket | None = None
) -> GrpcServer:
    """Serve the gRPC API on `host:port` (0: any free port; `GrpcServer.port` says which). A `reservation`
    (`services.api.ports.reserved_port`) held the port until now: it closes once the server has bound it.
    """
    server = grpc.server(
        futures.ThreadPoolExecutor(max_workers=MAX_WORKERS, thread_name_prefix="nbake-grpc"),
        interceptors=[ErrorMapping(), TokenAuth(services.db)],
        options=[
            ("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
            ("grpc.max_send_message_length", MAX_MESSAGE_BYTES),
        ],
        maximum_concurrent_rpcs=MAX_CONCURRENT_RPCS,
    )
    streams = StreamTracker(services.metrics.registry)
    jobs_pb2_grpc.add_JobServiceServicer_to_server(JobServicer(services, streams), server)
    assets_pb2_grpc.add_AssetServiceServicer_to_server(AssetServicer(services, streams), server)
    artifacts_pb2_grpc.add_ArtifactServiceServicer_to_server(ArtifactServicer(services, streams), server)
    checker = health.HealthServicer()
    health_pb2_grpc.add_HealthServicer_to_server(checker, server)
    reflection.enable_server_reflection(
        (*SERVICE_NAMES, health_pb2.DESCRIPTOR.services_by_name["Health"].full_name, reflection.SERVICE_NAME),
        server,
    )
    address = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    try:
        bound = server.add_insecure_port(address)
    finally:
        if reservation is not None:
            reservation.close()
    server.start()
    for name in ("", *SERVICE_NAMES):
        checker.set(name, health_pb2.HealthCheckResponse.SERVING)
    return GrpcServer(server, checker, bound)


@contextmanager
def grpc_serving(
    services: Services, host: str, port: int, reservation: socket.socket | None = None
) -> Iterator[GrpcServer]:
    running = start_grpc_server(services, host, port, reservation)
    try:
        yield running
    finally:
        running.stop()


def with_grpc(app: FastAPI, host: str, port: int, reservation: socket.socket | None = None) -> FastAPI:
    """`app`, whose lifespan also runs the gRPC server: it starts after the services (migrations, tokens,
    scheduler) are up and stops before they shut down, so it never answers from a half-built service.
    """
    inner = app.router.lifespan_context

    @asynccontextmanager
    async def lifespan(application: FastAPI) -> AsyncIterator:
        async with inner(application) as state:
            with grpc_serving(application.state.services, host, port, reservation):
                yield state

    app.router.lifespan_context = lifespan
    return app
