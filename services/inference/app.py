"""The inference app factory: REST routes, problem+json errors (the job server's handlers), a body limit,
and in its lifespan the gRPC `InferenceService` on its own port (when one is given)."""

from __future__ import annotations

import socket
from contextlib import asynccontextmanager

from fastapi import FastAPI

from services.inference.grpc_server import start_grpc_inference
from services.inference.routes import artifacts, health, models
from services.inference.service import InferenceService
from services.inference.settings import InferenceSettings
from services.inference.state import InferenceState
from services.jobs.db import Database
from services.jobs.problems import JOB_PROBLEMS
from services.platform import headers, problems
from services.platform.limits import BodyLimit


def create_inference_app(
    settings: InferenceSettings,
    grpc_host: str = "127.0.0.1",
    grpc_port: int | None = None,
    reservation: socket.socket | None = None,
):
    """The app; with a `grpc_port`, its lifespan serves gRPC there too (a `reservation` of that port, from
    `services.platform.ports.reserved_port`, closes once gRPC has bound it)."""
    shared = settings.shared
    state = InferenceState(InferenceService(settings), Database(shared.db_url, shared.database_schema))

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        grpc_server = None
        if grpc_port is not None:
            grpc_server = start_grpc_inference(
                state, grpc_host, grpc_port, settings.max_body_bytes, reservation
            )
            app.state.grpc_port = grpc_server.port
        try:
            yield
        finally:
            if grpc_server is not None:
                grpc_server.stop()
            state.db.dispose()

    app = FastAPI(
        title="neuralbake inference",
        version="1",
        summary="Serve trained neuralbake artifacts: batched queries and renders.",
        description="Loads artifacts from the job server's store by id (verified), keeps them in an LRU "
        "cache bounded by a memory budget and merges concurrent queries for one model. Arrays travel as "
        "base64 in JSON or as a binary body (a JSON header line, then raw arrays). Errors are "
        "`application/problem+json`.",
        lifespan=lifespan,
    )
    app.state.inference, app.state.tokens = state, state.tokens
    problems.install(app, JOB_PROBLEMS)
    app.add_middleware(
        BodyLimit, json_bytes=settings.max_body_bytes, upload_bytes=settings.max_body_bytes, upload_paths=()
    )
    headers.install(app)
    for module in (models, artifacts, health):
        app.include_router(module.router)
    return app
