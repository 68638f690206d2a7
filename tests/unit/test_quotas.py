"""Per-tenant quotas in the job database, on real SQLite and real PostgreSQL: a job is admitted in the
transaction that inserts it (queued jobs, estimated compute, priority ceiling), reusing existing work
never counts, a tenant's own quotas override the deployment's default field by field, and the scheduler's
next jobs leave out a tenant at its running limit."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import pytest

from services.jobs.quotas import QuotaExceeded, QuotaLimits, Quotas
from services.jobs.repository import JobRepository
from services.jobs.states import JobState
from services.platform.errors import InvalidInput
from tests.unit.test_jobs_repository import db, new_job  # noqa: F401 (db is a fixture)

DEFAULTS = QuotaLimits(max_queued=3, max_compute_s=100.0, max_priority=10)


def planned(seconds: float, key: str, tenant: str = "acme", **fields):
    return new_job(key, tenant=tenant, plan={"estimated_seconds": seconds, "items": []}, **fields)


def submit(jobs: JobRepository, quotas: Quotas, job, content_key: str | None = None):
    return jobs.create(job, content_key, None, admit=quotas.admit)


def test_queued_jobs_over_the_limit_are_refused_with_the_quota_its_limit_and_use(db):  # noqa: F811
    jobs, quotas = JobRepository(db), Quotas(db, DEFAULTS)
    first, _ = submit(jobs, quotas, planned(1, "k0"), "acme/content:k0")
    for n in (1, 2):
        submit(jobs, quotas, planned(1, f"k{n}"))
    with pytest.raises(QuotaExceeded) as refused:
        submit(jobs, quotas, planned(1, "k3"))
    error = refused.value
    assert (error.status, error.field) == (429, None)
    assert error.extensions == {"quota": "max_queued", "limit": 3, "current": 3}
    assert int(error.headers["Retry-After"]) >= 1
    # identical work is the existing job, at the limit too: reuse never counts
    reused, created = submit(jobs, quotas, planned(1, "k0"), "acme/content:k0")
    assert reused.id == first.id and not created
    submit(jobs, quotas, planned(1, "b0", tenant="bolt"))  # another tenant's queue is its own
    jobs.request_cancel(first.id)
    submit(jobs, quotas, planned(1, "k3"))  # a place is free again
    assert quotas.use("acme").model_dump() == {"running": 0, "queued": 3, "compute_s": 3.0}


def test_estimated_compute_counts_queued_and_running_jobs(db):  # noqa: F811
    jobs, quotas = JobRepository(db), Quotas(db, DEFAULTS)
    running, _ = submit(jobs, quotas, planned(60, "k0"))
    jobs.claim(running.id, "me", 30)
    submit(jobs, quotas, planned(30, "k1"))
    with pytest.raises(QuotaExceeded) as refused:
        submit(jobs, quotas, planned(20, "k2"))
    assert refused.value.extensions == {"quota": "max_compute_s", "limit": 100.0, "current": 90.0}
    assert 1 <= int(refused.value.headers["Retry-After"]) <= 60  # when the running job should end
    submit(jobs, quotas, planned(10, "k3"))  # exactly at the limit
    with pytest.raises(InvalidInput, match="by itself") as alone:  # waiting would never help
        submit(jobs, quotas, planned(101, "k4", tenant="bolt"))
    assert alone.value.field == "config"


def test_a_priority_over_the_ceiling_is_refused_naming_the_field_and_ceiling(db):  # noqa: F811
    jobs, quotas = JobRepository(db), Quotas(db, DEFAULTS)
    submit(jobs, quotas, planned(1, "k0", priority=10))
    with pytest.raises(InvalidInput, match="ceiling of 10") as refused:
        submit(jobs, quotas, planned(1, "k1", priority=11))
    assert refused.value.field == "priority"
    assert refused.value.extensions == {"quota": "max_priority", "limit": 10}
    assert quotas.use("acme").queued == 1


def test_a_tenants_own_quotas_override_the_default_field_by_field(db):  # noqa: F811
    jobs, quotas = JobRepository(db), Quotas(db, DEFAULTS)
    limits = quotas.set("acme", QuotaLimits(max_queued=1, max_priority=500))
    assert limits == QuotaLimits(max_queued=1, max_compute_s=100.0, max_priority=500)
    own, updated_at = quotas.override("acme")
    assert own == QuotaLimits(max_queued=1, max_priority=500) and updated_at is not None
    assert quotas.override("bolt") == (QuotaLimits(), None)
    submit(jobs, quotas, planned(1, "k0", priority=500))
    with pytest.raises(QuotaExceeded):
        submit(jobs, quotas, planned(1, "k1"))
    for n in range(3):
        submit(jobs, quotas, planned(1, f"b{n}", tenant="bolt"))  # the default's three
    quotas.set("acme", QuotaLimits())  # back to the default
    submit(jobs, quotas, planned(1, "k1"))


def test_the_scheduler_starts_none_of_a_tenants_jobs_while_it_is_at_its_running_limit(db):  # noqa: F811
    jobs, quotas = JobRepository(db), Quotas(db, QuotaLimits())
    quotas.set("acme", QuotaLimits(max_running=2))
    quotas.set("idle", QuotaLimits(max_running=0))
    acme = [submit(jobs, quotas, planned(1, f"a{n}", priority=5))[0].id for n in range(10)]
    held = submit(jobs, quotas, planned(1, "i0", tenant="idle", priority=9))[0].id
    bolt = [submit(jobs, quotas, planned(1, f"b{n}", tenant="bolt"))[0].id for n in range(3)]

    def start(free: int) -> list[str]:
        started = [job.id for job in quotas.startable(jobs, free)]
        for job_id in started:
            assert jobs.claim(job_id, "me", 30) is not None
        return started

    assert start(1) == acme[:1]
    assert start(4) == [acme[1], *bolt]  # acme's second place, then bolt's: acme's others wait
    assert start(4) == []  # acme at 2 running, idle at 0, bolt's all started
    jobs.transition(acme[0], JobState.SUCCEEDED, message="done")
    assert start(4) == acme[2:3]  # one place freed, one job of acme started
    quotas.set("idle", QuotaLimits(max_running=1))
    assert start(4) == [held]
    running = jobs.list([JobState.RUNNING], None, None, 50, "acme")[0]
    assert len(running) == 2 and quotas.use("acme").running == 2


def test_concurrent_submissions_of_a_tenant_never_pass_its_queued_quota(db):  # noqa: F811
    jobs, quotas = JobRepository(db), Quotas(db, QuotaLimits(max_queued=3))

    def attempt(n: int) -> bool:
        try:
            submit(jobs, quotas, planned(1, f"k{n}"))
        except QuotaExceeded:
            return False
        return True

    with ThreadPoolExecutor(8) as pool:
        admitted = list(pool.map(attempt, range(24)))
    assert sum(admitted) == 3 and quotas.use("acme").queued == 3
