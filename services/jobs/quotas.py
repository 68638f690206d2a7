"""Per-tenant quotas: how many jobs a tenant may have queued, how many running, how much estimated compute
its queued and running jobs may add up to (the sum of their plans' `estimated_seconds`), and the highest
priority it may ask for. A deployment-wide default (`ServiceSettings.tenant_quotas`) holds for every
tenant; a `tenant_quotas` row overrides it field by field (NULL: the default).

Where each is enforced: the queued, compute and priority limits when a job is created, inside the
transaction that inserts it, so a submission that reuses existing work never counts; one tenant's
admissions take turns (SQLite's writers do anyway; on PostgreSQL an advisory lock per tenant), so two
concurrent submissions cannot both take the last place. The running limit is the scheduler's, which
starts none of a tenant's queued jobs while it is at its limit.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime

from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy import func, select, text
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from services.jobs.db import Database
from services.jobs.repository import JobRepository
from services.jobs.states import JobState
from services.jobs.tables import Job, TenantQuota, utcnow
from services.platform.errors import InvalidInput, ServiceError

MAX_COUNT = 1_000_000  # a bound that fits every database's integer column
MAX_COMPUTE_S = 1e12
SET_ATTEMPTS = 2
RETRY_AFTER_S = (1, 3600)  # a Retry-After within these bounds
ADMISSION_LOCK = "nbake-quota:"  # + the tenant: the advisory lock its admissions take turns on
IDLE_RETRY_AFTER_S = 60  # when none of the tenant's jobs runs, so nothing says when room will be made


class QuotaLimits(BaseModel):
    """A tenant's limits; None: no limit of that kind. As a request body, None means the default."""

    model_config = ConfigDict(extra="forbid")

    max_running: int | None = Field(
        None, ge=0, le=MAX_COUNT, description="Jobs running at once (0 holds every queued job of the tenant)."
    )
    max_queued: int | None = Field(None, ge=0, le=MAX_COUNT, description="Jobs waiting to start.")
    max_compute_s: float | None = Field(
        None, ge=0, le=MAX_COMPUTE_S, description="Estimated seconds of its queued and running jobs."
    )
    max_priority: int | None = Field(
        None, ge=-1000, le=1000, description="The highest `priority` it may ask."
    )

    def over(self, override: QuotaLimits) -> QuotaLimits:
        """These limits with `override`'s set fields in place."""
        return self.model_copy(update=override.model_dump(exclude_none=True))


class QuotaUse(BaseModel):
    """What a tenant's jobs hold now."""

    running: int = Field(0, description="Jobs running.")
    queued: int = Field(0, description="Jobs waiting to start.")
    compute_s: float = Field(0.0, description="The plans' estimated seconds of its queued and running jobs.")


class QuotaExceeded(ServiceError):
    """429: waiting helps (a job of the tenant ends and makes room). The problem names the quota, its limit
    and the tenant's use beside the detail; no field of the request is at fault."""

    status, title = 429, "Quota exceeded"

    def __init__(self, quota: str, limit: float, current: float, detail: str, retry_after_s: int):
        super().__init__(detail)
        self.headers = {"Retry-After": str(retry_after_s)}
        self.extensions = {"quota": quota, "limit": limit, "current": current}


class OverPriorityCeiling(InvalidInput):
    """422 naming `priority`, the ceiling the problem's `limit`: waiting would not help."""

    def __init__(self, job: Job, ceiling: int):
        super().__init__(
            f"{job.priority} is over tenant {job.tenant!r}'s priority ceiling of {ceiling} (max_priority)",
            "priority",
        )
        self.extensions = {"quota": "max_priority", "limit": ceiling}


class Quotas:
    """Every tenant's quotas, read from the job database over the deployment's `defaults`."""

    def __init__(self, db: Database, defaults: QuotaLimits):
        self.db, self.defaults = db, defaults

    # ------------------------------------------------------------------ setting and reading

    def set(self, tenant: str, override: QuotaLimits) -> QuotaLimits:
        """Replace `tenant`'s override (None fields: the default's); its limits now."""
        for attempt in range(SET_ATTEMPTS):
            try:
                with self.db.writing() as session:
                    row = session.get(TenantQuota, tenant, with_for_update=True)
                    if row is None:
                        row = TenantQuota(tenant=tenant)
                        session.add(row)
                    for name, value in override.model_dump().items():
                        setattr(row, name, value)
                    row.updated_at = utcnow()
                break
            except IntegrityError:  # another replica inserted the tenant's first row meanwhile: update it
                if attempt == SET_ATTEMPTS - 1:
                    raise
        return self.defaults.over(override)

    def override(self, tenant: str) -> tuple[QuotaLimits, datetime | None]:
        """`tenant`'s own override (all None without one) and when it was set."""
        with self.db.reading() as session:
            row = session.get(TenantQuota, tenant)
        return _override(row), row and row.updated_at

    def limits(self, session: Session, tenant: str) -> QuotaLimits:
        return self.defaults.over(_override(session.get(TenantQuota, tenant)))

    def use(self, tenant: str) -> QuotaUse:
        with self.db.reading() as session:
            return _use(session, tenant)

    # ------------------------------------------------------------------ admission (at submission)

    def admit(self, session: Session, job: Job) -> None:
        """Raise unless `job`'s tenant may queue it now: QuotaExceeded (429) while its queued jobs or their
        compute are at the limit; InvalidInput (422) for what waiting cannot fix (a priority over the
        ceiling, a job whose estimate alone is over the compute limit). Run in the transaction that
        inserts the job, after any reuse of existing work."""
        limits = self.limits(session, job.tenant)
        if limits.max_priority is not None and job.priority > limits.max_priority:
            raise OverPriorityCeiling(job, limits.max_priority)
        estimate = float((job.plan or {}).get("estimated_seconds", 0.0))
        if limits.max_compute_s is not None and estimate > limits.max_compute_s:
            raise InvalidInput(
                f"the plan estimates {estimate:.3g} s, over tenant {job.tenant!r}'s compute quota of "
                f"{limits.max_compute_s:g} s (max_compute_s) by itself: lower the config's sizes",
                "config",
            )
        if limits.max_queued is None and limits.max_compute_s is None:
            return
        _take_turns(session, job.tenant)
        use = _use(session, job.tenant)
        if limits.max_queued is not None and use.queued + 1 > limits.max_queued:
            raise QuotaExceeded(
                "max_queued",
                limits.max_queued,
                use.queued,
                f"tenant {job.tenant!r} has {use.queued} queued jobs, its limit (max_queued): retry once "
                "one has started, or cancel one",
                _retry_after(session, job.tenant),
            )
        if limits.max_compute_s is not None and use.compute_s + estimate > limits.max_compute_s:
            raise QuotaExceeded(
                "max_compute_s",
                limits.max_compute_s,
                use.compute_s,
                f"tenant {job.tenant!r}'s queued and running jobs are estimated at {use.compute_s:.6g} s; "
                f"this one's {estimate:.3g} s more would pass its compute quota of "
                f"{limits.max_compute_s:g} s (max_compute_s): retry once one has finished",
                _retry_after(session, job.tenant),
            )

    # ------------------------------------------------------------------ the running limit (scheduling)

    def startable(self, jobs: JobRepository, free: int) -> list[Job]:
        """The next queued jobs (at most `free`, in the queue's order) whose tenants are below their
        running limit, counting these jobs as started: what the scheduler starts next. A tenant that
        reaches its limit among them is left out of the next read, until `free` are found or none is left."""
        room, chosen = self._running_room(), []
        while len(chosen) < free:
            wanted = free - len(chosen)
            batch = jobs.queued(wanted, held=room.held, skip=[job.id for job in chosen])
            taken = [job for job in batch if room.take(job.tenant)]
            chosen += taken
            if len(batch) < wanted:  # the queue's end; else either `free` are found or a tenant is held
                break
        return chosen

    def _running_room(self) -> RunningRoom:
        """How many more jobs each tenant may start now, from every scheduler's RUNNING jobs."""
        with self.db.reading() as session:
            counts = select(Job.tenant, func.count()).where(_running).group_by(Job.tenant)
            running = Counter(dict(session.execute(counts).all()))
            own = select(TenantQuota.tenant, TenantQuota.max_running).where(
                TenantQuota.max_running.is_not(None)
            )
            overrides = dict(session.execute(own).all())
        return RunningRoom(running, overrides, self.defaults.max_running)


@dataclass
class RunningRoom:
    """Running jobs per tenant against their running limits, counted up as the scheduler starts jobs."""

    running: Counter
    limits: dict[str, int]  # the tenants with an override
    default: int | None
    refused: set[str] = field(default_factory=set)

    def limit(self, tenant: str) -> int | None:
        return self.limits.get(tenant, self.default)

    @property
    def held(self) -> set[str]:
        """The tenants at their limit: those `take` refused, and those with a running job or an override
        (any other one has none running, so it is at its limit only with a default of 0)."""
        return self.refused | {t for t in {*self.running, *self.limits} if not self.allows(t)}

    def allows(self, tenant: str) -> bool:
        limit = self.limit(tenant)
        return limit is None or self.running[tenant] < limit

    def take(self, tenant: str) -> bool:
        """Whether `tenant` may start one more job; counted as started if so."""
        if not self.allows(tenant):
            self.refused.add(tenant)
            return False
        self.running[tenant] += 1
        return True


_running = Job.state == JobState.RUNNING
_queued = Job.state == JobState.QUEUED
_estimate = func.coalesce(Job.plan["estimated_seconds"].as_float(), 0.0)


def _override(row: TenantQuota | None) -> QuotaLimits:
    if row is None:
        return QuotaLimits()
    return QuotaLimits(**{name: getattr(row, name) for name in QuotaLimits.model_fields})


def _take_turns(session: Session, tenant: str) -> None:
    """On PostgreSQL, one tenant's admissions take turns (an advisory lock on its name until the inserting
    transaction ends), so two cannot both see the last place free; SQLite's writers take turns already."""
    if session.get_bind().dialect.name == "postgresql":
        session.execute(
            text("SELECT pg_advisory_xact_lock(hashtext(:key))"), {"key": ADMISSION_LOCK + tenant}
        )


def _use(session: Session, tenant: str) -> QuotaUse:
    query = (
        select(Job.state, func.count(), func.sum(_estimate))
        .where(Job.tenant == tenant, _running | _queued)
        .group_by(Job.state)
    )
    rows = {state: (count, seconds or 0.0) for state, count, seconds in session.execute(query)}
    running, queued = rows.get(JobState.RUNNING, (0, 0.0)), rows.get(JobState.QUEUED, (0, 0.0))
    compute_s = round(float(running[1] + queued[1]), 3)
    return QuotaUse(running=running[0], queued=queued[0], compute_s=compute_s)


def _retry_after(session: Session, tenant: str) -> int:
    """Seconds until the tenant's first running job is estimated to end (when it makes room), bounded."""
    query = select(Job.started_at, _estimate).where(Job.tenant == tenant, _running)
    now = utcnow()
    remaining = [
        seconds - (now - started).total_seconds()
        for started, seconds in session.execute(query)
        if started is not None
    ]
    if not remaining:
        return IDLE_RETRY_AFTER_S
    low, high = RETRY_AFTER_S
    return int(min(high, max(low, min(remaining))))
