"""Persistence of jobs and their events. Every state change and its `state` event commit together,
so a change is stored before anyone (an SSE stream, a poll) can see it announced.
"""

from __future__ import annotations

import base64
import binascii
from collections.abc import Callable, Collection, Iterable, Sequence
from datetime import timedelta
from typing import Any

from sqlalchemy import bindparam, func, or_, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from services.jobs.db import Database
from services.jobs.errors import JobNotFound, name_batch_item
from services.jobs.states import JobState, check_transition
from services.jobs.tables import Event, IdempotencyKey, Job, utcnow
from services.platform.errors import Conflict, InvalidInput, ServiceError

INSERT_ATTEMPTS = 3  # concurrent identical submissions on PostgreSQL: the loser retries and finds the winner
REUSABLE = (JobState.QUEUED, JobState.RUNNING, JobState.SUCCEEDED)
# Built once (a repeated submission runs nothing else): the states are plain comparisons (an IN list is
# re-expanded at every execution).
_REUSABLE_JOB = (
    select(Job)
    .join(IdempotencyKey, IdempotencyKey.job_id == Job.id)
    .where(IdempotencyKey.key == bindparam("key"), or_(*(Job.state == state for state in REUSABLE)))
)


def encode_cursor(seq: int) -> str:
    return base64.urlsafe_b64encode(str(seq).encode()).decode().rstrip("=")


def decode_cursor(cursor: str) -> int:
    try:
        return int(base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)).decode())
    except (ValueError, binascii.Error, UnicodeDecodeError):
        raise InvalidInput("not a cursor returned by this API", "cursor") from None


class JobRepository:
    def __init__(self, db: Database):
        self.db = db

    # ------------------------------------------------------------------ submission

    def reusable(self, content_key: str) -> Job | None:
        """The queued, running or succeeded job that `content_key` names, in one query. A repeat of
        existing work is answered from this read alone, before any write transaction (on SQLite, before
        waiting for the single writer) and before the work is planned: most of a burst of retries."""
        with self.db.reading() as session:
            return session.scalars(_REUSABLE_JOB, {"key": content_key}).one_or_none()

    def create(
        self,
        job: Job,
        content_key: str | None,
        header_key: str | None,
        absent: bool = False,
        admit: Callable[[Session, Job], None] | None = None,
    ) -> tuple[Job, bool]:
        """Insert `job`, or return the job an idempotency key already names: (job, created).

        `content_key` (None with `force`) reuses a queued, running or succeeded job with the same work;
        `header_key` reuses whatever job that key named and refuses a different request under it. Keys are
        inserted, never overwritten blindly: of concurrent identical submissions one inserts, the others
        hit the primary key, roll back, retry and find it.

        `absent`: the caller has just found no job under `content_key` (`reusable`), so the first attempt
        inserts the key without reading it first, a round trip less. If it is there after all (failed work
        this job takes over, or a concurrent identical submission), that insert fails and the retry reads it.

        `admit` (the tenant's quotas) may refuse the job by raising, in the transaction that would insert it:
        only once no existing job is reused, so reusing one never counts against them.
        """
        for attempt in range(INSERT_ATTEMPTS):
            try:
                with self.db.writing() as session:
                    read = not (absent and attempt == 0)
                    return self._create(session, job, content_key, header_key, read, admit)
            except IntegrityError:
                if attempt == INSERT_ATTEMPTS - 1:
                    raise
                job = _fresh_copy(job)
        raise AssertionError("unreachable")

    def create_many(
        self,
        entries: Sequence[tuple[Job, str | None, str | None]],
        admit: Callable[[Session, Job], None] | None = None,
    ) -> list[tuple[Job, bool]]:
        """`create` for each (job, content key, header key) in one transaction: every job is inserted or
        reused, or none is. An entry's refusal (a quota, a key reused for another request) is raised with
        its field under `jobs[i]`, the batch request's name for it. Identical entries give one job."""
        for attempt in range(INSERT_ATTEMPTS):
            try:
                with self.db.writing() as session:
                    answers = []
                    for index, (job, content_key, header_key) in enumerate(entries):
                        try:
                            answers.append(self._create(session, job, content_key, header_key, True, admit))
                        except ServiceError as error:
                            name_batch_item(error, index)
                            raise
                    return answers
            except IntegrityError:  # a concurrent submission inserted one of the keys: retry, reusing it
                if attempt == INSERT_ATTEMPTS - 1:
                    raise
                entries = [(_fresh_copy(job), content, header) for job, content, header in entries]
        raise AssertionError("unreachable")

    def _create(
        self,
        session: Session,
        job: Job,
        content_key: str | None,
        header_key: str | None,
        read_key: bool,
        admit: Callable[[Session, Job], None] | None,
    ) -> tuple[Job, bool]:
        request_hash = job.idempotency_key
        if header_key is not None and (row := _locked_key(session, header_key)) is not None:
            if row.request_hash != request_hash:
                raise Conflict(
                    "this Idempotency-Key was used for a different request; use a new key", "Idempotency-Key"
                )
            return self._job(session, row.job_id), False
        content = _locked_key(session, content_key) if content_key is not None and read_key else None
        if content is not None and (existing := self._job(session, content.job_id)).state in REUSABLE:
            if header_key is not None:
                session.add(IdempotencyKey(key=header_key, job_id=existing.id, request_hash=request_hash))
            return existing, False
        if admit is not None:
            admit(session, job)
        submitted = self._event(job, "state", {"state": job.state, "message": "submitted"})
        session.add(job)  # numbered first, so its row goes in as it stays: no UPDATE after the INSERT
        session.flush()  # before the rows that refer to it (no ORM relationship orders the tables)
        session.add(submitted)
        if content is not None:  # the work failed or was cancelled before: this job takes the key over
            content.job_id = job.id
        elif content_key is not None:
            session.add(IdempotencyKey(key=content_key, job_id=job.id, request_hash=request_hash))
        if header_key is not None:
            session.add(IdempotencyKey(key=header_key, job_id=job.id, request_hash=request_hash))
        return job, True

    # ------------------------------------------------------------------ reading

    def get(self, job_id: str, tenant: str | None = None) -> Job:
        """The job; JobNotFound also when `tenant` is given and the job is another tenant's."""
        with self.db.reading() as session:
            return self._job(session, job_id, tenant=tenant)

    def list(
        self,
        states: Sequence[str],
        kind: str | None,
        cursor: str | None,
        limit: int,
        tenant: str | None = None,
    ) -> tuple[list[Job], str | None]:
        """Newest first, only `tenant`'s when given; `next_cursor` is None on the last page."""
        query = select(Job).order_by(Job.seq.desc()).limit(limit + 1)
        if tenant is not None:
            query = query.where(Job.tenant == tenant)
        if states:
            query = query.where(Job.state.in_(list(states)))
        if kind:
            query = query.where(Job.kind == kind)
        if cursor:
            query = query.where(Job.seq < decode_cursor(cursor))
        with self.db.reading() as session:
            jobs = list(session.scalars(query))
        more = len(jobs) > limit
        return jobs[:limit], encode_cursor(jobs[limit - 1].seq) if more else None

    def events_after(self, job_id: str, after: int, limit: int = 500) -> list[Event]:
        query = (
            select(Event).where(Event.job_id == job_id, Event.seq > after).order_by(Event.seq).limit(limit)
        )
        with self.db.reading() as session:
            return list(session.scalars(query))

    def count_by_state(self) -> dict[str, int]:
        with self.db.reading() as session:
            rows = session.execute(select(Job.state, func.count()).group_by(Job.state)).all()
        return {state: count for state, count in rows}

    def queued(self, limit: int, held: Collection[str] = (), skip: Collection[str] = ()) -> list[Job]:
        """The next jobs to start, none of the `held` tenants' nor those `skip` names: highest priority
        first, then oldest."""
        query = (
            select(Job)
            .where(Job.state == JobState.QUEUED)
            .order_by(Job.priority.desc(), Job.seq)
            .limit(limit)
        )
        if held:
            query = query.where(Job.tenant.not_in(sorted(held)))
        if skip:
            query = query.where(Job.id.not_in(list(skip)))
        with self.db.reading() as session:
            return list(session.scalars(query))

    def orphans(self, owner: str) -> list[Job]:
        """RUNNING jobs this scheduler owns (e.g. before a restart) or whose owner stopped renewing."""
        query = select(Job).where(
            Job.state == JobState.RUNNING,
            (Job.lease_owner == owner) | (Job.lease_expires < utcnow()) | Job.lease_owner.is_(None),
        )
        with self.db.reading() as session:
            return list(session.scalars(query))

    # ------------------------------------------------------------------ changing

    def transition(self, job_id: str, target: JobState, *, message: str | None = None, **fields: Any) -> Job:
        """Check, persist and announce (as a `state` event) one state change, in one transaction."""
        with self.db.writing() as session:
            return self._transition(session, self._job(session, job_id, lock=True), target, message, fields)

    def claim(self, job_id: str, owner: str, lease_s: float) -> Job | None:
        """QUEUED -> RUNNING for this scheduler, unless another one (or a cancel) got there first."""
        with self.db.writing() as session:
            job = self._job(session, job_id, lock=True)
            if job.state != JobState.QUEUED:
                return None
            fields = {
                "attempts": job.attempts + 1,
                "started_at": job.started_at or utcnow(),
                "lease_owner": owner,
                "lease_expires": utcnow() + timedelta(seconds=lease_s),
            }
            return self._transition(session, job, JobState.RUNNING, "started", fields)

    def take_over(self, job_id: str, owner: str, lease_s: float) -> bool:
        """Adopt an orphaned RUNNING job (atomically: two schedulers cannot both adopt it)."""
        with self.db.writing() as session:
            job = self._job(session, job_id, lock=True)
            if job.state != JobState.RUNNING:
                return False
            expired = job.lease_expires is None or job.lease_expires < utcnow()
            if job.lease_owner not in (owner, None) and not expired:
                return False
            job.lease_owner, job.lease_expires = owner, utcnow() + timedelta(seconds=lease_s)
            return True

    def renew_leases(self, owner: str, job_ids: Iterable[str], lease_s: float) -> None:
        ids = list(job_ids)
        if not ids:
            return
        with self.db.writing() as session:
            session.execute(
                update(Job)
                .where(Job.id.in_(ids), Job.lease_owner == owner)
                .values(lease_expires=utcnow() + timedelta(seconds=lease_s))
            )

    def request_cancel(self, job_id: str, tenant: str | None = None) -> Job:
        """A queued job is cancelled now; a running one is flagged for the scheduler to stop."""
        with self.db.writing() as session:
            job = self._job(session, job_id, lock=True, tenant=tenant)
            state = JobState(job.state)
            if state.terminal:
                raise Conflict(
                    f"job {job_id} is already {state}; only queued or running jobs can be cancelled"
                )
            if state == JobState.RUNNING:
                if not job.cancel_requested:
                    job.cancel_requested = True
                    self._append(session, job, "log", {"message": "cancellation requested"})
                return job
            return self._transition(session, job, JobState.CANCELLED, "cancelled while queued", {})

    def cancel_requested(self, job_ids: Iterable[str]) -> set[str]:
        ids = list(job_ids)
        if not ids:
            return set()
        with self.db.reading() as session:
            query = select(Job.id).where(Job.id.in_(ids), Job.cancel_requested.is_(True))
            return set(session.scalars(query))

    def append_events(self, job_id: str, events: Sequence[tuple[str, dict[str, Any]]]) -> None:
        """Persist driver events (type, data) in order; the latest progress is also kept on the job.

        Progress behind the latest one means the job resumed from a checkpoint (a new attempt after a
        crash): a `resume` event (from which step, back to which, in which attempt) comes before it, so a
        follower reads a resume, not a regression.
        """
        if not events:
            return
        with self.db.writing() as session:
            job = self._job(session, job_id, lock=True)
            for kind, data in events:
                if kind == "progress" and _steps_back(job.progress, data):
                    resumed = {"from_step": job.progress["step"], "to_step": data["step"]}
                    self._append(session, job, "resume", resumed | {"attempt": job.attempts})
                self._append(session, job, kind, data)
                if kind == "progress":
                    job.progress = data

    # ------------------------------------------------------------------ helpers

    def _transition(
        self, session: Session, job: Job, target: JobState, message: str | None, fields: dict[str, Any]
    ) -> Job:
        check_transition(job.id, job.state, target)
        previous, job.state = job.state, target
        for name, value in fields.items():
            setattr(job, name, value)
        if target.terminal:
            job.finished_at, job.lease_owner, job.lease_expires = utcnow(), None, None
        data = {"state": target, "previous": previous, "attempt": job.attempts, "message": message}
        data |= {k: v for k, v in (("error", job.error), ("artifact_id", job.artifact_id)) if v}
        self._append(session, job, "state", data)
        return job

    @staticmethod
    def _job(session: Session, job_id: str, lock: bool = False, tenant: str | None = None) -> Job:
        query = select(Job).where(Job.id == job_id)
        if tenant is not None:  # another tenant's job is not found, exactly like one that does not exist
            query = query.where(Job.tenant == tenant)
        job = session.scalars(query.with_for_update() if lock else query).one_or_none()
        if job is None:
            raise JobNotFound(f"no job {job_id!r}", "job_id")
        return job

    @classmethod
    def _append(cls, session: Session, job: Job, kind: str, data: dict[str, Any]) -> None:
        session.add(cls._event(job, kind, data))

    @staticmethod
    def _event(job: Job, kind: str, data: dict[str, Any]) -> Event:
        """The job's next event (its number taken)."""
        job.last_event_seq += 1
        return Event(job_id=job.id, seq=job.last_event_seq, type=kind, data=data, time=utcnow())


def _steps_back(latest: dict[str, Any] | None, progress: dict[str, Any]) -> bool:
    step, before = progress.get("step"), (latest or {}).get("step")
    return isinstance(step, int) and isinstance(before, int) and step < before


def _locked_key(session: Session, key: str) -> IdempotencyKey | None:
    return session.get(IdempotencyKey, key, with_for_update=True)


def _fresh_copy(job: Job) -> Job:
    """A new, unsaved Job with the same column values (the old instance belongs to a rolled-back session) and
    no event yet (the rolled-back attempt had numbered its first one)."""
    columns = {c.key: getattr(job, c.key) for c in Job.__table__.columns if c.key not in ("seq",)}
    return Job(**columns | {"last_event_seq": 0})
