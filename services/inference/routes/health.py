"""Open endpoints for orchestrators and scrapers: liveness, readiness, Prometheus metrics."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from services.inference.state import StateDep
from services.platform.readiness import PROBE, readiness

router = APIRouter(tags=["health"])


@router.get("/healthz")
def healthz() -> dict[str, str]:
    """The process answers."""
    return {"status": "ok"}


@router.get("/readyz", responses={503: {"description": "The token database or the store is unreachable"}})
def readyz(state: StateDep) -> JSONResponse:
    """The job database's tokens (start `nbake serve` once to create them) and the artifact store."""

    checks = {"tokens": state.tokens.check, "store": lambda: state.service.blobs.exists(PROBE)}
    return readiness(checks, device=state.service.device)


@router.get("/metrics", response_class=Response)
def metrics(state: StateDep) -> Response:
    """Requests, latency, batch sizes and cache hits, in the Prometheus text format."""
    return Response(generate_latest(state.service.metrics.registry), media_type=CONTENT_TYPE_LATEST)
