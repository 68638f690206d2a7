"""The scheduler: a background thread that hands QUEUED jobs to Ray drivers and follows them to the end.

Each tick it polls the drivers it owns (persisting their events), finishes jobs with an outcome
(publishing the artifact, retrying infrastructure failures a bounded number of times, deleting
checkpoints of finished jobs), passes cancellations on, starts queued jobs within the concurrency limit
(and each tenant's running quota) and renews its leases. RUNNING jobs with no live driver (after a server
restart, or whose owner stopped renewing its lease) are adopted and restarted from their checkpoints with
the same JobSpec. When the Ray cluster is lost, the jobs running on it are infrastructure failures
(retried, so they resume from their checkpoints) and nothing touches Ray until the connection is made
again.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import ray

from services.artifacts.artifacts import ArtifactStore
from services.jobs.metrics import ServiceMetrics
from services.jobs.quotas import Quotas
from services.jobs.ray_connection import RayConnection
from services.jobs.repository import JobRepository
from services.jobs.scenes import SceneResolver
from services.jobs.states import JobState
from services.jobs.tables import Job
from services.platform.errors import ServiceError
from workers.driver.jobs import JobHandle, JobOutcome, JobSpec, attach_job, start_job

WARNING_ANNOTATION = (
    "warning"  # on an artifact whose model the job flagged (e.g. worse than 1-spp path tracing)
)

log = logging.getLogger(__name__)


@dataclass
class SchedulerSettings:
    owner: str  # stable per deployment (host + data dir): a restarted server reclaims its own jobs at once
    work_dir: Path  # per-job output folders
    max_running: int = 1
    lease_s: float = 30.0
    tick_s: float = 0.25


@dataclass
class Running:
    handle: JobHandle
    kind: str
    cancel_sent: bool = False


class Scheduler:
    def __init__(
        self,
        settings: SchedulerSettings,
        jobs: JobRepository,
        artifacts: ArtifactStore,
        scenes: SceneResolver,
        metrics: ServiceMetrics,
        quotas: Quotas,
    ):
        self.settings, self.jobs, self.artifacts, self.scenes, self.metrics = (
            settings,
            jobs,
            artifacts,
            scenes,
            metrics,
        )
        self.quotas = quotas
        self.ray: RayConnection | None = None  # from `start`, when this process is connected to Ray
        self.running: dict[str, Running] = {}
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._next_adoption = 0.0

    # ------------------------------------------------------------------ lifecycle

    def start(self, ray_connection: RayConnection) -> None:
        """Tick on a thread of its own, on the Ray cluster this process is connected to."""
        self.ray = ray_connection
        self._thread = threading.Thread(target=self._loop, name="nbake-scheduler", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop ticking and end this scheduler's drivers (they die with the process anyway; ending them
        here frees their Ray resources at once). Their jobs stay RUNNING: the next start adopts them and
        resumes them from their checkpoints.
        """
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=30)
        for running in self.running.values():
            with contextlib.suppress(Exception):  # a driver that is already gone needs no ending
                running.handle.release()
        self.running.clear()

    def wake(self) -> None:
        """Tick now (a job was submitted or cancelled) instead of at the next interval."""
        self._wake.set()

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                self.tick()
            except Exception:  # a database hiccup must not end scheduling; the next tick retries
                log.exception("scheduler tick failed")
            self._wake.wait(self.settings.tick_s)
            self._wake.clear()

    def tick(self) -> None:
        if not self.ray.check(on_lost=self._lose_running):
            return
        if time.monotonic() >= self._next_adoption:
            self._adopt_orphans()
            self._next_adoption = time.monotonic() + self.settings.lease_s / 3
        self._pass_on_cancellations()
        for job_id in list(self.running):
            self._follow(job_id)
        self._start_queued()
        self.jobs.renew_leases(self.settings.owner, self.running, self.settings.lease_s)

    # ------------------------------------------------------------------ starting

    def _start_queued(self) -> None:
        """Start the next queued jobs this scheduler has room for, none of a tenant at its running quota."""
        free = self.settings.max_running - len(self.running)
        if free <= 0:
            return
        for queued in self.quotas.startable(self.jobs, free):
            job = self.jobs.claim(queued.id, self.settings.owner, self.settings.lease_s)
            if job is None:
                continue
            self.metrics.queue_wait.labels(job.kind).observe(
                (job.started_at - job.created_at).total_seconds()
            )
            self._launch(job, "started")

    def _adopt_orphans(self) -> None:
        for job in self.jobs.orphans(self.settings.owner):
            if job.id in self.running or not self.jobs.take_over(
                job.id, self.settings.owner, self.settings.lease_s
            ):
                continue
            handle = attach_job(job.id)
            if handle is not None:
                self.running[job.id] = Running(handle, job.kind)
            elif job.cancel_requested:
                self._finish(job.id, JobOutcome(state="cancelled"))
            else:
                self._launch(job, "its driver was gone (server restart); resuming from its checkpoint")

    def _launch(self, job: Job, message: str) -> None:
        try:
            spec = self._spec(job)
        except (ServiceError, LookupError, ValueError) as error:
            self._fail(job.id, f"cannot start: {error}")
            return
        try:
            self.running[job.id] = Running(start_job(spec), job.kind)
        except Exception as error:  # Ray refused the actor: the cluster's fault, not the job's
            self._finish(job.id, JobOutcome(state="failed", error=str(error), infrastructure_failure=True))
            return
        started = {"message": message, "attempt": job.attempts, "scheduler": self.settings.owner}
        self.jobs.append_events(job.id, [("log", started)])

    def _spec(self, job: Job) -> JobSpec:
        """Everything the driver reads or writes is in the store, so it may run on any node. The scene is
        read back by the digest the job row holds (BlobNotFound, a LookupError, when the store lost it)."""
        scene = self.scenes.specs.get(job.scene_digest)
        return JobSpec(
            job_id=job.id,
            kind=job.kind,
            scene=scene,
            scene_files=self.scenes.stored_files(job.scene_ref, scene),
            config=job.config,
            seed=job.seed,
            num_gpus=self._gpus(job),
            checkpoint_dir=self.artifacts.checkpoint_dir(job.id),
            output_url=self.artifacts.output_url(job.id),
        )

    @staticmethod
    def _gpus(job: Job) -> float:
        """What the config asks for, when the cluster has it; otherwise the job runs on CPUs. Read from the
        stored config, which submission validated and filled with every default (`KindConfig.num_gpus`)."""
        wanted = job.config["num_gpus"]
        return wanted if 0 < wanted <= ray.cluster_resources().get("GPU", 0) else 0

    # ------------------------------------------------------------------ following

    def _pass_on_cancellations(self) -> None:
        for job_id in self.jobs.cancel_requested(self.running):
            running = self.running[job_id]
            if not running.cancel_sent:
                running.handle.cancel()
                running.cancel_sent = True

    def _follow(self, job_id: str) -> None:
        running = self.running[job_id]
        events = running.handle.poll()
        self.jobs.append_events(
            job_id, [(e.type, e.model_dump(mode="json", exclude_none=True, exclude={"type"})) for e in events]
        )
        for event in events:
            if event.samples_per_s is not None:
                self.metrics.samples_per_s.labels(job_id, running.kind).set(event.samples_per_s)
        outcome = running.handle.outcome()
        if outcome is None and not running.handle.alive():
            outcome = JobOutcome(state="failed", error="the job driver died", infrastructure_failure=True)
        if outcome is not None:
            del self.running[job_id]
            running.handle.release()
            self._finish(job_id, outcome)

    def _lose_running(self) -> None:
        """The cluster is gone and its drivers with it: each running job fails as the infrastructure's
        fault, so it is queued again and resumes from its checkpoint on the cluster that comes back."""
        lost, self.running = self.running, {}
        for job_id in lost:
            error = f"the Ray cluster was lost ({self.ray.name})"
            self._finish(job_id, JobOutcome(state="failed", error=error, infrastructure_failure=True))

    # ------------------------------------------------------------------ finishing

    def _finish(self, job_id: str, outcome: JobOutcome) -> None:
        job = self.jobs.get(job_id)
        if outcome.state == "succeeded":
            try:
                self._succeed(job, outcome)
            except OSError as error:  # the store failed: retry the job (it resumes from its checkpoint)
                self._retry_or_fail(job, f"publishing the artifact failed: {error}")
        elif outcome.state == "cancelled" or job.cancel_requested:
            self._end(job, JobState.CANCELLED, "cancelled")
        elif outcome.infrastructure_failure:
            self._retry_or_fail(job, outcome.error or "infrastructure failure")
        else:
            self._end(job, JobState.FAILED, "failed", error=outcome.error or "the job failed")

    def _succeed(self, job: Job, outcome: JobOutcome) -> None:
        downloads = self.settings.work_dir / job.id / "output"
        manifest = self.artifacts.publish(
            {
                name: (
                    str(self.artifacts.local_output(url, downloads / name)),
                    outcome.media_types.get(name, ""),
                )
                for name, url in outcome.files.items()
            },
            kind=job.kind,
            job_id=job.id,
            scene_hash=job.scene_hash,
            config=job.config,
            code_version=job.code_version,
            metrics=outcome.metrics,
            annotations={WARNING_ANNOTATION: " ".join(outcome.warnings)} if outcome.warnings else None,
        )
        self._end(job, JobState.SUCCEEDED, "succeeded", artifact_id=manifest.artifact_id)

    def _retry_or_fail(self, job: Job, error: str) -> None:
        if job.attempts < job.max_attempts:
            message = f"retrying (attempt {job.attempts + 1} of {job.max_attempts}) after: {error}"
            self.jobs.transition(
                job.id, JobState.QUEUED, message=message, lease_owner=None, lease_expires=None
            )
        else:
            self._end(job, JobState.FAILED, "failed", error=f"{error} (after {job.attempts} attempts)")

    def _fail(self, job_id: str, error: str) -> None:
        self._end(self.jobs.get(job_id), JobState.FAILED, "failed", error=error)

    def _end(self, job: Job, state: JobState, message: str, **fields) -> None:
        """A final state: persisted (and announced), then the job's checkpoints and work files removed."""
        finished = self.jobs.transition(job.id, state, message=message, **fields)
        if finished.started_at is not None:
            seconds = (finished.finished_at - finished.started_at).total_seconds()
            self.metrics.duration.labels(job.kind, state.value).observe(seconds)
        with contextlib.suppress(KeyError):  # only jobs that reported samples/s have a gauge
            self.metrics.samples_per_s.remove(job.id, job.kind)
        self.artifacts.delete_checkpoints(job.id)
        self.artifacts.delete_outputs(job.id)
        shutil.rmtree(self.settings.work_dir / job.id, ignore_errors=True)
