"""Following one job's events until its final state, read from the database (so every replica can serve
any job). The REST SSE stream and gRPC `WatchJob` share this loop; each only sends and waits its own way.
"""

from __future__ import annotations

from collections.abc import Iterator

from services.jobs.repository import JobRepository
from services.jobs.states import TERMINAL, JobState
from services.jobs.tables import Event

POLL_S = 0.2  # how often a follower with nothing new looks again (and notices its caller has gone)


def follow(jobs: JobRepository, job_id: str, after: int) -> Iterator[list[Event]]:
    """Batches of the job's events after sequence number `after`, in order, ending with its final state
    event. An empty batch means nothing new yet: the caller waits about `POLL_S` (or stops) before asking
    for the next one. A synchronous generator, so an async caller runs each step in a thread."""
    while True:
        events = jobs.events_after(job_id, after)
        for count, event in enumerate(events, 1):
            if event.type == "state" and event.data.get("state") in TERMINAL:
                yield events[:count]
                return
        if events:
            yield events
            after = events[-1].seq
            continue
        job = jobs.get(job_id)
        if JobState(job.state).terminal and job.last_event_seq <= after:
            return  # resumed after the final event: nothing more will come
        yield []
