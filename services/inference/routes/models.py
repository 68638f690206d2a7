"""What is loaded, and warming a model before its first query."""

from __future__ import annotations

from fastapi import APIRouter
from starlette.concurrency import run_in_threadpool

from services.inference.service import ModelInfo
from services.inference.state import StateDep
from services.platform.auth import CanRead
from services.platform.problems import PROBLEM_RESPONSES

router = APIRouter(prefix="/v1/models", tags=["models"])


@router.get("", responses=PROBLEM_RESPONSES)
def list_models(state: StateDep, principal: CanRead) -> list[ModelInfo]:
    """Loaded models of the token's tenant, least recently used first: the next to be evicted when the
    memory budget is full."""
    return [m for m in state.service.models() if state.tenancy.sees_artifact(principal, m.artifact_id)]


@router.post("/{artifact_id}:load", responses=PROBLEM_RESPONSES)
async def load_model(artifact_id: str, state: StateDep, principal: CanRead) -> ModelInfo:
    """Fetch, verify and load an artifact now, so its first query does not pay for it."""
    await run_in_threadpool(state.tenancy.artifact, principal, artifact_id)
    served = await run_in_threadpool(state.service.served, artifact_id)
    return served.info()
