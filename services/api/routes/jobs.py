"""`/v1/jobs`: submit, list, read, cancel, and follow a job's events."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Query, Request, Response
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, Field
from starlette.concurrency import run_in_threadpool

from services.api.deps import ServicesDep
from services.api.schemas import EventView, JobList, JobView
from services.api.sse import event_stream
from services.jobs.states import JobState
from services.jobs.submission import BatchRequest, JobRequest
from services.platform.auth import CanRead, CanSubmit
from services.platform.problems import PROBLEM_RESPONSES

router = APIRouter(prefix="/v1/jobs", tags=["jobs"], responses={401: PROBLEM_RESPONSES[401]})


@router.post(
    "",
    status_code=201,
    response_model=JobView,
    responses={200: {"model": JobView, "description": "An identical job of this tenant exists: that job"}}
    | {s: PROBLEM_RESPONSES[s] for s in (400, 403, 409, 413, 422, 429)},
)
async def submit_job(
    body: JobRequest,
    response: Response,
    svc: ServicesDep,
    principal: CanSubmit,
    idempotency_key: Annotated[str | None, Header(max_length=255)] = None,
) -> JobView:
    """Queue a job of the token's tenant (201), or return the tenant's existing identical one (200) unless
    `force` is set."""
    # async, with the database work in one thread: a plain def costs FastAPI a second thread hop to
    # validate the response (the hottest route: a hop is about a tenth of a repeated submission)
    job, created = await run_in_threadpool(svc.submit, body, idempotency_key, principal)
    if not created:
        response.status_code = 200
    response.headers["Location"] = f"/v1/jobs/{job.id}"
    return JobView.of(job)


class BatchItem(BaseModel):
    job: JobView
    created: bool = Field(
        description="False: an identical job (or the key's) already existed; it is that job."
    )


class BatchAnswer(BaseModel):
    items: list[BatchItem] = Field(description="In the order of the request's `jobs`.")


@router.post(
    ":batch",
    response_model=BatchAnswer,
    responses={s: PROBLEM_RESPONSES[s] for s in (400, 403, 409, 413, 422, 429)},
)
async def submit_jobs(
    body: BatchRequest,
    svc: ServicesDep,
    principal: CanSubmit,
    idempotency_key: Annotated[str | None, Header(max_length=255)] = None,
) -> BatchAnswer:
    """Queue many jobs of the token's tenant at once, all or nothing: every job is checked and planned
    before any is stored, then all go in one transaction; the first refusal names its field under
    `jobs[i]`. Identical work that exists is reused, as `POST /v1/jobs` does."""
    answers = await run_in_threadpool(svc.submit_many, body.jobs, idempotency_key, principal)
    return BatchAnswer(items=[BatchItem(job=JobView.of(job), created=created) for job, created in answers])


@router.get(
    "",
    response_model=JobList,
    responses={s: PROBLEM_RESPONSES[s] for s in (403, 422)},
)
def list_jobs(
    svc: ServicesDep,
    principal: CanRead,
    state: Annotated[list[JobState] | None, Query(description="Repeat to match any of several.")] = None,
    kind: Annotated[str | None, Query(max_length=64)] = None,
    cursor: Annotated[
        str | None, Query(max_length=64, description="`next_cursor` of the previous page.")
    ] = None,
    limit: Annotated[int, Query(ge=1, le=200)] = 50,
) -> JobList:
    """The tenant's jobs (every tenant's for an admin token), newest first."""
    states = [s.value for s in state or []]
    jobs, next_cursor = svc.jobs.list(states, kind, cursor, limit, principal.visible_tenant)
    return JobList(items=[JobView.of(job) for job in jobs], next_cursor=next_cursor)


@router.get(
    "/{job_id}",
    response_model=JobView,
    responses={s: PROBLEM_RESPONSES[s] for s in (403, 404)},
)
def get_job(job_id: str, svc: ServicesDep, principal: CanRead) -> JobView:
    return JobView.of(svc.jobs.get(job_id, principal.visible_tenant))


@router.post(
    "/{job_id}:cancel",
    response_model=JobView,
    status_code=202,
    responses={200: {"model": JobView, "description": "A queued job: cancelled at once"}}
    | {s: PROBLEM_RESPONSES[s] for s in (403, 404, 409)},
)
def cancel_job(job_id: str, response: Response, svc: ServicesDep, principal: CanSubmit) -> JobView:
    """A queued job is cancelled at once (200); a running one stops within seconds (202)."""
    job = svc.cancel(job_id, principal)
    if job.state == JobState.CANCELLED:
        response.status_code = 200
    return JobView.of(job)


@router.get(
    "/{job_id}/events",
    response_class=StreamingResponse,
    responses={
        200: {
            "description": "Server-Sent Events: `id` is the event's `seq`, `event` its `type`, `data` an "
            "EventView as JSON. The stream ends after the final state.",
            "content": {"text/event-stream": {"schema": EventView.model_json_schema()}},
        },
    }
    | {s: PROBLEM_RESPONSES[s] for s in (403, 404, 422)},
)
def job_events(
    job_id: str,
    request: Request,
    svc: ServicesDep,
    principal: CanRead,
    last_event_id: Annotated[int | None, Header(ge=0, le=2**31 - 1)] = None,
    after: Annotated[int | None, Query(ge=0, le=2**31 - 1, description="Like Last-Event-ID.")] = None,
) -> StreamingResponse:
    """State changes, progress (step, loss, samples/s, ETA) and log lines; resumable with Last-Event-ID."""
    svc.jobs.get(job_id, principal.visible_tenant)  # 404 before the stream starts (another tenant's too)
    start = max(last_event_id or 0, after or 0)
    return StreamingResponse(
        event_stream(request, svc.jobs, job_id, start, svc.metrics.sse_streams),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )
