"""Open endpoints for orchestrators and scrapers: liveness, readiness, Prometheus metrics."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from services.api.deps import ServicesDep
from services.platform.readiness import PROBE, readiness

router = APIRouter(tags=["health"])


@router.get("/healthz")
def healthz() -> dict[str, str]:
    """The process answers."""
    return {"status": "ok"}


@router.get("/readyz", responses={503: {"description": "A dependency is unreachable"}})
def readyz(svc: ServicesDep) -> JSONResponse:
    """The database, the artifact store and (where jobs are scheduled) Ray are all reachable. Ray's state
    is the scheduler's last probe: a Ray call here would block for a minute while the cluster is down."""
    checks = {"database": svc.db.ping, "store": lambda: svc.blobs.exists(PROBE)}
    if svc.settings.scheduling:
        checks["ray"] = svc.scheduler.ray.ready
    return readiness(checks)


@router.get("/metrics", response_class=Response)
def metrics(svc: ServicesDep) -> Response:
    """Jobs by state, queue wait, job duration and samples/s, in the Prometheus text format."""
    return Response(generate_latest(svc.metrics.registry), media_type=CONTENT_TYPE_LATEST)
