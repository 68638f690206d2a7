"""The objects one server instance is made of, built from its settings and shared by every route."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import ray

from services.api.settings import ServiceSettings
from services.artifacts.artifacts import ArtifactStore
from services.artifacts.assets import asset_ids
from services.artifacts.store import BlobStore
from services.geometry import GeometryProcesses
from services.jobs.db import Database
from services.jobs.metrics import ServiceMetrics
from services.jobs.quotas import Quotas
from services.jobs.ray_connection import RayConnection
from services.jobs.repository import JobRepository
from services.jobs.scenes import SceneResolver
from services.jobs.scheduler import Scheduler, SchedulerSettings
from services.jobs.submission import JobRequest, Submitter
from services.jobs.tables import Job
from services.jobs.tenants import Tenancy
from services.jobs.tokens import DatabaseTokens
from services.platform.auth import Principal, configured_tokens, generated_admin_token


@dataclass
class Services:
    settings: ServiceSettings
    db: Database
    jobs: JobRepository
    blobs: BlobStore
    artifacts: ArtifactStore
    scenes: SceneResolver
    submitter: Submitter
    metrics: ServiceMetrics
    scheduler: Scheduler
    geometry: GeometryProcesses
    tenancy: Tenancy
    tokens: DatabaseTokens
    quotas: Quotas
    ray_connection: RayConnection | None = None  # None: the one `ray.init` made, joined again as it was
    admin_token_file: Path | None = None

    @classmethod
    def build(cls, settings: ServiceSettings, ray_connection: RayConnection | None = None) -> Services:
        data_dir = settings.data_dir
        data_dir.mkdir(parents=True, exist_ok=True)
        db = Database(settings.db_url, settings.database_schema)
        jobs = JobRepository(db)
        blobs = BlobStore(settings.store)
        artifacts = ArtifactStore(blobs, settings.store)  # checkpoints in the store: any node resumes a job
        tenancy = Tenancy(db)
        geometry = GeometryProcesses()
        scenes = SceneResolver(blobs, settings.store, data_dir / "scenes", tenancy, geometry)
        metrics = ServiceMetrics(jobs.count_by_state)
        scheduler_settings = SchedulerSettings(
            owner=settings.owner,
            work_dir=data_dir / "work",
            max_running=settings.max_running,
            lease_s=settings.lease_s,
        )
        quotas = Quotas(db, settings.tenant_quotas)
        scheduler = Scheduler(scheduler_settings, jobs, artifacts, scenes, metrics, quotas)
        submitter = Submitter(jobs, scenes, settings.max_attempts, geometry, settings.max_job_seconds, quotas)
        return cls(
            settings,
            db,
            jobs,
            blobs,
            artifacts,
            scenes,
            submitter,
            metrics,
            scheduler,
            geometry,
            tenancy,
            DatabaseTokens(db),
            quotas,
            ray_connection,
        )

    def start(self) -> None:
        """Migrate the database, install the tokens, give assets from before tenants to the default tenant,
        start scheduling (Ray must be initialised for that; an API-only replica does not use Ray)."""
        if self.settings.scheduling and not ray.is_initialized():
            raise RuntimeError("ray.init() first: the scheduler runs jobs on Ray")
        self.db.migrate(self.scenes.specs)
        tokens = configured_tokens(self.settings.tokens, self.settings.tokens_file)
        if not tokens:
            token, self.admin_token_file = generated_admin_token(self.settings.data_dir)
            tokens = {token: "admin"}
        self.tokens.store_configured(tokens)
        self.tenancy.adopt_unowned_assets(asset_ids(self.settings.store))
        if self.settings.scheduling:
            self.scheduler.start(self.ray_connection or RayConnection.current())

    def stop(self) -> None:
        self.scheduler.stop()
        self.geometry.stop()
        self.db.dispose()

    def submit(
        self, request: JobRequest, idempotency_key: str | None = None, principal: Principal | None = None
    ) -> tuple[Job, bool]:
        """`Submitter.submit`, counted; a new job wakes the scheduler rather than waiting for its tick."""
        job, created = self.submitter.submit(request, idempotency_key, principal)
        self.metrics.submissions.labels(str(created).lower()).inc()
        if created:
            self.scheduler.wake()
        return job, created

    def submit_many(
        self,
        requests: list[JobRequest],
        idempotency_key: str | None = None,
        principal: Principal | None = None,
    ) -> list[tuple[Job, bool]]:
        """`Submitter.submit_many`, counted like single submissions; new jobs wake the scheduler once."""
        answers = self.submitter.submit_many(requests, idempotency_key, principal)
        for _, created in answers:
            self.metrics.submissions.labels(str(created).lower()).inc()
        if any(created for _, created in answers):
            self.scheduler.wake()
        return answers

    def cancel(self, job_id: str, principal: Principal | None = None) -> Job:
        """Request the cancellation and wake the scheduler, which stops a running job's driver."""
        job = self.jobs.request_cancel(job_id, principal and principal.visible_tenant)
        self.scheduler.wake()
        return job
