"""The job state machine: QUEUED -> RUNNING -> SUCCEEDED | FAILED | CANCELLED.

RUNNING -> QUEUED is the bounded retry after an infrastructure failure (a worker or driver died);
QUEUED -> FAILED is a job that cannot even start (its asset vanished). Terminal states are final.
"""

from __future__ import annotations

from enum import StrEnum


class JobState(StrEnum):
    QUEUED = "QUEUED"
    RUNNING = "RUNNING"
    SUCCEEDED = "SUCCEEDED"
    FAILED = "FAILED"
    CANCELLED = "CANCELLED"

    @property
    def terminal(self) -> bool:
        return self in TERMINAL


TERMINAL = frozenset({JobState.SUCCEEDED, JobState.FAILED, JobState.CANCELLED})

TRANSITIONS: dict[JobState, frozenset[JobState]] = {
    JobState.QUEUED: frozenset({JobState.RUNNING, JobState.CANCELLED, JobState.FAILED}),
    JobState.RUNNING: frozenset({JobState.SUCCEEDED, JobState.FAILED, JobState.CANCELLED, JobState.QUEUED}),
    JobState.SUCCEEDED: frozenset(),
    JobState.FAILED: frozenset(),
    JobState.CANCELLED: frozenset(),
}


class InvalidTransition(ValueError):
    """A transition the state machine forbids, e.g. cancelling a finished job."""

    def __init__(self, job_id: str, current: JobState, target: JobState):
        self.job_id, self.current, self.target = job_id, current, target
        super().__init__(f"job {job_id} is {current}; it cannot become {target}")


def check_transition(job_id: str, current: str, target: str) -> None:
    current, target = JobState(current), JobState(target)
    if target not in TRANSITIONS[current]:
        raise InvalidTransition(job_id, current, target)
