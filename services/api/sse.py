"""A job's events as Server-Sent Events, by the loop `services.jobs.following` shares with gRPC WatchJob.

The stream resumes after `Last-Event-ID` (the per-job event sequence number) and ends after the job's
final state event; comments keep idle connections open through proxies.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator

from fastapi import Request
from prometheus_client import Gauge
from starlette.concurrency import iterate_in_threadpool

from services.api.schemas import EventView
from services.jobs.following import POLL_S, follow
from services.jobs.repository import JobRepository

KEEPALIVE_S = 15.0


def format_event(view: EventView) -> str:
    return f"id: {view.seq}\nevent: {view.type}\ndata: {json.dumps(view.model_dump(mode='json'))}\n\n"


async def event_stream(
    request: Request, jobs: JobRepository, job_id: str, after: int, active: Gauge
) -> AsyncIterator[str]:
    """Counted in `active` from its first byte until it ends, however it ends (a client that leaves
    cancels it: the count must come back down, or streams leak)."""
    active.inc()
    try:
        last_sent = time.monotonic()
        yield "retry: 1000\n\n"
        async for events in iterate_in_threadpool(follow(jobs, job_id, after)):  # database reads off the loop
            for event in events:
                view = EventView(
                    job_id=job_id, seq=event.seq, type=event.type, time=event.time, data=event.data
                )
                yield format_event(view)
            if events:
                last_sent = time.monotonic()
                continue
            if await request.is_disconnected():
                return
            if time.monotonic() - last_sent > KEEPALIVE_S:
                yield ": keep-alive\n\n"
                last_sent = time.monotonic()
            await asyncio.sleep(POLL_S)
    finally:
        active.dec()
