"""The job API over gRPC beside the REST app: the same `Services`, the same tokens, its own port (the
server itself: `services.platform.grpc.server`).
"""

from __future__ import annotations

import socket
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager, contextmanager

import grpc
from fastapi import FastAPI
from neuralbake.v1 import artifacts_pb2_grpc, assets_pb2_grpc, jobs_pb2_grpc

from services.api.grpc.artifacts import ArtifactServicer
from services.api.grpc.assets import AssetServicer
from services.api.grpc.jobs import JobServicer
from services.api.grpc.scopes import SERVICE_NAMES, needed_scope
from services.api.grpc.streams import StreamTracker
from services.api.services import Services
from services.jobs.problems import JOB_PROBLEMS
from services.platform.grpc.server import GrpcLimits, GrpcServer, GrpcServices, start_grpc

LIMITS = GrpcLimits(
    max_workers=32,  # each open stream (WatchJob, DownloadFile) holds one worker while it runs
    max_message_bytes=4 << 20,  # an upload chunk or a download chunk (1 MiB) with room for framing
    max_concurrent_rpcs=256,
)


def start_grpc_server(
    services: Services, host: str, port: int, reservation: socket.socket | None = None
) -> GrpcServer:
    """Serve the gRPC API on `host:port` (0: any free port; `GrpcServer.port` says which). A `reservation`
    (`services.platform.ports.reserved_port`) held the port until now: it closes once the server has bound
    it."""
    streams = StreamTracker(services.metrics.registry)

    def add(server: grpc.Server) -> None:
        jobs_pb2_grpc.add_JobServiceServicer_to_server(JobServicer(services, streams), server)
        assets_pb2_grpc.add_AssetServiceServicer_to_server(AssetServicer(services, streams), server)
        artifacts_pb2_grpc.add_ArtifactServiceServicer_to_server(ArtifactServicer(services, streams), server)

    served = GrpcServices(add, SERVICE_NAMES, needed_scope, JOB_PROBLEMS)
    return start_grpc(served, services.tokens, LIMITS, host, port, reservation)


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
