"""Job persistence on real SQLite (WAL) and real PostgreSQL: migrations match the models, identical
concurrent submissions make one job, event sequence numbers stay gapless under concurrent writers,
cursor pagination, cancellation and lease rules."""

from __future__ import annotations

import os
import uuid
from concurrent.futures import ThreadPoolExecutor
from datetime import timedelta

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import create_engine, text, update

from services.jobs.db import Database, normalize_url
from services.jobs.repository import JobRepository
from services.jobs.states import JobState
from services.jobs.tables import Base, Job, utcnow
from services.platform.errors import Conflict, InvalidInput

POSTGRES_ENV = "NBAKE_TEST_POSTGRES_URL"


@pytest.fixture(params=["sqlite", "postgresql"])
def db(request, tmp_path):
    if request.param == "sqlite":
        database = Database(f"sqlite:///{tmp_path / 'jobs.db'}")
        schema = None
    else:
        url = os.environ.get(POSTGRES_ENV)
        if not url:
            pytest.skip(f"{POSTGRES_ENV} is not set, so the PostgreSQL variant cannot run (.ci/run sets it)")
        schema = f"nbt_{uuid.uuid4().hex[:12]}"
        database = Database(url, schema)
    database.migrate()
    yield database
    database.dispose()
    if schema:
        engine = create_engine(normalize_url(os.environ[POSTGRES_ENV]))
        with engine.begin() as connection:
            connection.execute(text(f'DROP SCHEMA "{schema}" CASCADE'))
        engine.dispose()


def new_job(key: str = "sha256:k", **fields) -> Job:
    values = dict(
        id=f"job-{uuid.uuid4().hex}",
        kind="render",
        state=JobState.QUEUED,
        scene_ref={"source": "builtin"},
        scene_digest="sha256:" + "5" * 64,
        scene_hash="sha256:s",
        preset="quick",
        config={},
        seed=0,
        priority=0,
        code_version="test",
        idempotency_key=key,
        plan=None,
        attempts=0,
        max_attempts=3,
        cancel_requested=False,
        last_event_seq=0,
        created_at=utcnow(),
    )
    return Job(**(values | fields))


def test_migrations_create_exactly_the_models(db):
    with db.engine.connect() as connection:
        assert compare_metadata(MigrationContext.configure(connection), Base.metadata) == []
    db.migrate()  # a second start is a no-op
    if db.is_sqlite:
        with db.engine.connect() as connection:
            assert connection.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"


@pytest.mark.parametrize("absent", [False, True])  # the key read first, or inserted straight away
def test_identical_concurrent_submissions_make_one_job(db, absent):
    jobs = JobRepository(db)
    with ThreadPoolExecutor(8) as pool:
        results = list(
            pool.map(
                lambda _: jobs.create(new_job("sha256:same"), "content:sha256:same", None, absent), range(24)
            )
        )
    assert sum(created for _, created in results) == 1
    assert len({job.id for job, _ in results}) == 1
    listed, _ = jobs.list([], None, None, 100)
    assert len(listed) == 1


def test_a_failed_job_does_not_block_resubmission_but_a_running_one_does(db):
    jobs = JobRepository(db)
    first, _ = jobs.create(new_job(), "content:sha256:k", None)
    assert jobs.create(new_job(), "content:sha256:k", None)[0].id == first.id
    jobs.claim(first.id, "me", 30)
    jobs.transition(first.id, JobState.FAILED, message="failed", error="boom")
    for absent in (False, True):  # read first, or told nothing reuses the key (a failed job does not)
        second, created = jobs.create(new_job(), "content:sha256:k", None, absent=absent)
        assert created and second.id != first.id
        assert [e.seq for e in jobs.events_after(second.id, 0)] == [1]  # a retried insert numbers anew
        assert jobs.create(new_job(), "content:sha256:k", None)[0].id == second.id
        jobs.request_cancel(second.id)
        first = second


def test_event_sequence_is_gapless_under_concurrent_writers(db):
    jobs = JobRepository(db)
    job, _ = jobs.create(new_job(), None, None)

    def write(i: int) -> None:
        jobs.append_events(job.id, [("log", {"message": f"{i}-{n}"}) for n in range(3)])

    with ThreadPoolExecutor(6) as pool:
        list(pool.map(write, range(30)))
    events = jobs.events_after(job.id, 0, limit=1000)
    assert [e.seq for e in events] == list(range(1, 92))
    assert events[0].type == "state" and events[0].data["state"] == "QUEUED"
    assert [e.seq for e in jobs.events_after(job.id, 90)] == [91]
    assert jobs.get(job.id).last_event_seq == 91


def test_cursor_pagination_is_newest_first_without_gaps(db):
    jobs = JobRepository(db)
    ids = [jobs.create(new_job(kind="render" if i % 2 else "lod"), None, None)[0].id for i in range(7)]
    pages, cursor = [], None
    while True:
        page, cursor = jobs.list([], None, cursor, 3)
        pages.append([job.id for job in page])
        if cursor is None:
            break
    assert [len(p) for p in pages] == [3, 3, 1]
    assert [i for p in pages for i in p] == ids[::-1]
    assert [j.id for j in jobs.list([], "lod", None, 10)[0]] == ids[::2][::-1]
    with pytest.raises(InvalidInput, match="cursor"):
        jobs.list([], None, "garbage!", 3)


def test_cancellation_rules(db):
    jobs = JobRepository(db)
    queued, _ = jobs.create(new_job(), None, None)
    assert jobs.request_cancel(queued.id).state == JobState.CANCELLED
    with pytest.raises(Conflict, match="already CANCELLED"):
        jobs.request_cancel(queued.id)
    running, _ = jobs.create(new_job(), None, None)
    jobs.claim(running.id, "me", 30)
    flagged = jobs.request_cancel(running.id)
    assert flagged.state == JobState.RUNNING and flagged.cancel_requested
    assert jobs.cancel_requested([running.id, queued.id]) == {running.id}


def test_claims_and_leases(db):
    jobs = JobRepository(db)
    job, _ = jobs.create(new_job(), None, None)
    claimed = jobs.claim(job.id, "a", 30)
    assert claimed.state == JobState.RUNNING and claimed.attempts == 1 and claimed.lease_owner == "a"
    assert jobs.claim(job.id, "b", 30) is None
    assert [j.id for j in jobs.orphans("a")] == [job.id]  # its own owner (e.g. restarted) adopts at once
    assert jobs.orphans("b") == [] and not jobs.take_over(job.id, "b", 30)
    with db.writing() as session:
        session.execute(
            update(Job).where(Job.id == job.id).values(lease_expires=utcnow() - timedelta(seconds=1))
        )
    assert [j.id for j in jobs.orphans("b")] == [job.id]  # a silent owner's job is adopted by another
    assert jobs.take_over(job.id, "b", 30) and jobs.get(job.id).lease_owner == "b"
    final = jobs.transition(job.id, JobState.SUCCEEDED, message="done", artifact_id="sha256:a")
    assert final.lease_owner is None and final.finished_at is not None
    assert jobs.events_after(job.id, 0)[-1].data["artifact_id"] == "sha256:a"


def test_progress_going_back_after_a_resume_is_a_resume_event(db):
    jobs = JobRepository(db)
    job, _ = jobs.create(new_job("sha256:resume"), None, None)
    jobs.append_events(
        job.id, [("progress", {"step": 10, "total": 40}), ("progress", {"step": 20, "total": 40})]
    )
    jobs.append_events(
        job.id, [("progress", {"step": 12, "total": 40}), ("progress", {"step": 16, "total": 40})]
    )
    events = [(e.type, e.data) for e in jobs.events_after(job.id, 0)]
    progress_and_resume = [(t, d) for t, d in events if t in ("progress", "resume")]
    assert [t for t, _ in progress_and_resume] == ["progress", "progress", "resume", "progress", "progress"]
    assert progress_and_resume[2][1] == {"from_step": 20, "to_step": 12, "attempt": 0}
    assert jobs.get(job.id).progress == {"step": 16, "total": 40}


def test_replicas_starting_together_migrate_one_after_another():
    url = os.environ.get(POSTGRES_ENV)
    if not url:
        pytest.skip(f"{POSTGRES_ENV} is not set, so the PostgreSQL variant cannot run (.ci/run sets it)")
    schema = f"nbt_{uuid.uuid4().hex[:12]}"

    def start_replica(_: int) -> None:
        database = Database(url, schema)
        database.migrate()  # without the advisory lock: "duplicate key ... pg_namespace_nspname_index"
        database.dispose()

    try:
        with ThreadPoolExecutor(4) as pool:
            list(pool.map(start_replica, range(4)))
    finally:
        engine = create_engine(normalize_url(url))
        with engine.begin() as connection:
            connection.execute(text(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE'))
        engine.dispose()
