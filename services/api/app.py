"""The FastAPI application factory: routes, problem+json errors, body limits, and the services'
lifecycle (migrations, tokens and the scheduler start with the app and stop with it).
"""

from __future__ import annotations

import gc
from contextlib import asynccontextmanager

from fastapi import FastAPI

from services.api.routes import artifacts, assets, catalog, health, jobs, quotas, tokens
from services.api.services import Services
from services.api.settings import ServiceSettings
from services.dashboard import mount_dashboard
from services.jobs.problems import JOB_PROBLEMS
from services.jobs.ray_connection import RayConnection
from services.platform import headers, problems
from services.platform.limits import MULTIPART_OVERHEAD, BodyLimit


def create_app(settings: ServiceSettings, ray_connection: RayConnection | None = None) -> FastAPI:
    """The app; `ray_connection` says how to connect to Ray again when the cluster is lost (by default,
    to the cluster `ray.init` joined, at the same address)."""
    services = Services.build(settings, ray_connection)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        services.start()
        # What start-up made (some 400k objects: torch, Ray and the kinds are imported) lives as long as
        # the process: out of the collector's sight, a full collection no longer walks it (~170 ms each,
        # every few seconds under load: the submissions' p99)
        gc.freeze()
        try:
            yield
        finally:
            services.stop()

    app = FastAPI(
        title="neuralbake",
        version="1",
        summary="Train neural rendering representations of 3D scenes on Ray.",
        description="Upload a scene, submit a job (`render`, later neural kinds), follow its events, "
        "download its artifact. Errors are `application/problem+json`. The web dashboard is at `/ui`.",
        lifespan=lifespan,
    )
    app.state.services, app.state.tokens = services, services.tokens
    problems.install(app, JOB_PROBLEMS)
    app.add_middleware(
        BodyLimit,
        json_bytes=settings.max_json_bytes,
        upload_bytes=settings.upload_limits.max_total_bytes + MULTIPART_OVERHEAD,
        upload_paths=("/v1/assets",),
    )
    headers.install(app)
    for module in (jobs, assets, artifacts, catalog, tokens, quotas, health):
        app.include_router(module.router)
    mount_dashboard(app)
    return app
