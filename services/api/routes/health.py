"""Open endpoints for orchestrators and scrapers: liveness, readiness, Prometheus metrics."""

from __future__ import annotations

from collections.abc import Callable

import ray
from fastapi import APIRouter
from fastapi.responses import JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from services.api.deps import ServicesDep

router = APIRouter(tags=["health"])
PROBE = "sha256:" + "0" * 64


def readiness(checks: dict[str, Callable[[], object]], **extra) -> JSONResponse:
    """Run every check; 200 when all pass, else 503 naming each failure and why."""
    results = {}
    for name, check in checks.items():
        try:
            check()
            results[name] = "ok"
        except Exception as error:  # any failure means not ready; say which and why
            results[name] = f"{type(error).__name__}: {error}"
    ready = all(value == "ok" for value in results.values())
    body = {"status": "ok" if ready else "unavailable", **extra, "checks": results}
    return JSONResponse(body, 200 if ready else 503)


@router.get("/healthz")
def healthz() -> dict[str, str]:
    """The process answers."""
    return {"status": "ok"}


@router.get("/readyz", responses={503: {"description": "A dependency is unreachable"}})
def readyz(svc: ServicesDep) -> JSONResponse:
    """The database, the artifact store and Ray are all reachable."""
    checks = {"database": svc.db.ping, "store": lambda: svc.blobs.exists(PROBE), "ray": ray.cluster_resources}
    return readiness(checks)


@router.get("/metrics", response_class=Response)
def metrics(svc: ServicesDep) -> Response:
    """Jobs by state, queue wait, job duration and samples/s, in the Prometheus text format."""
    return Response(generate_latest(svc.metrics.registry), media_type=CONTENT_TYPE_LATEST)
