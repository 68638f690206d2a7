"""The job driver: one named Ray actor per job that runs its kind and answers the service while it works.

The kind runs on a background thread inside the actor, so `poll`, `outcome` and `cancel` are answered at
once. The actor is not detached: it lives while the handle `start_job` returned is held and dies with the
cluster of the service that started it; the service restarts such jobs with `start_job`, and the kind
resumes from its checkpoints.
"""

from __future__ import annotations

import collections
import contextlib
import math
import shutil
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Literal

import fsspec
import ray
from pydantic import BaseModel, ValidationError, model_validator
from ray.exceptions import (
    GetTimeoutError,
    NodeDiedError,
    ObjectLostError,
    OutOfMemoryError,
    RayActorError,
    RaySystemError,
    RayTaskError,
    WorkerCrashedError,
)

from workers.driver import scratch
from workers.driver.placement import remove_reservation, sampler_reserver
from workers.models.registry import get_kind
from workers.runtime.checkpoints import CheckpointStore
from workers.runtime.contract import (
    InfrastructureFailure,
    JobCancelled,
    JobContext,
    Kind,
    RunOutput,
    imported,
)
from workers.runtime.pipeline import run_method
from workers.runtime.resources import ResourceRequest, actor_options
from workers.scene.format.errors import SceneError
from workers.scene.portability.reference import SceneRef
from workers.scene.portability.stored import StoredScene

NAMESPACE = "neuralbake"
MAX_BUFFERED_EVENTS = 10_000  # a service that stops polling loses the oldest events, not the driver's memory
CALL_TIMEOUT_S = 1.0
NAME_RELEASE_TIMEOUT_S = 30.0
CANCEL_GRACE_S = 5.0  # how long a kind may take to notice a cancel before it is abandoned
INFRASTRUCTURE_ERRORS = (
    InfrastructureFailure,
    RayActorError,
    ObjectLostError,
    WorkerCrashedError,
    NodeDiedError,
    OutOfMemoryError,
    RaySystemError,
)
SAMPLER_CPUS = 1.0
CHUNK_BYTES = 1 << 20


class JobSpec(BaseModel):
    """Everything a driver needs; JSON-serialisable."""

    job_id: str
    kind: str
    scene: dict  # SceneSpec.model_dump(mode="json")
    scene_dir: str | None = None  # local directory with the scene's files (meshes, textures)
    scene_files: StoredScene | None = None  # or the files in the store, fetched on the driver's node
    config: dict  # the resolved config the job stored at submission, as JSON
    seed: int
    num_gpus: float = 0
    checkpoint_dir: str  # a local path or an fsspec URL (s3://...); the driver resumes from it if non-empty
    output_dir: str | None = None  # the driver writes the artifact's files here (None: a private temp dir)
    output_url: str | None = None  # then uploads them here (a store URL), for a service on another node

    @model_validator(mode="after")
    def _outputs_land_somewhere(self) -> JobSpec:
        if self.output_dir is None and self.output_url is None:
            raise ValueError("a job needs an output_dir or an output_url for its artifact's files")
        return self


class JobEvent(BaseModel):
    type: Literal["progress", "log"]
    time: float
    step: int | None = None
    total: int | None = None
    loss: float | None = None
    samples_per_s: float | None = None
    eta_s: float | None = None
    message: str | None = None


class JobOutcome(BaseModel):
    state: Literal["succeeded", "failed", "cancelled"]
    error: str | None = None
    files: dict[str, str] = {}  # artifact file name -> its absolute path in output_dir, or its output_url URL
    media_types: dict[str, str] = {}  # artifact file name -> media type
    metrics: dict[str, float] = {}
    infrastructure_failure: bool = False  # True: retrying may help (a worker died); False: the job failed
    warnings: list[str] = []  # what a person must read before using the result (also in the job's log)


def one_line(error: BaseException) -> str:
    """A failure as one line a person can act on; Ray task errors are unwrapped to their cause."""
    if isinstance(error, RayTaskError) and error.cause is not None:
        error = error.cause
    if isinstance(error, ValidationError) and error.errors():
        first = error.errors()[0]
        where = ".".join(str(part) for part in first["loc"])
        return f"invalid {error.title}: {where}: {first['msg']}"
    if isinstance(error, SceneError):
        return f"invalid scene: {error}"
    lines = str(error).strip().splitlines()
    text = lines[0] if lines else ""
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


def run_kind(kind: Kind, ctx: JobContext) -> RunOutput:
    """A training kind's method on the shared pipeline, or a kind's own run function."""
    if kind.method is not None:
        return run_method(imported(kind.method)(), ctx)
    return imported(kind.run_function)(ctx)


def run_job(spec: JobSpec, emit: Callable[[JobEvent], None], cancel: threading.Event) -> JobOutcome:
    """Run the spec's kind to its outcome; every failure becomes an outcome, none escapes."""

    def log(message: str) -> None:
        emit(JobEvent(type="log", time=time.time(), message=message))

    if spec.output_dir is None:
        scratch.sweep()  # what drivers on this node that were ended from outside left behind
    output_dir = Path(spec.output_dir) if spec.output_dir else scratch.make(spec.job_id)
    try:
        kind = get_kind(spec.kind)
        ctx = JobContext(
            job_id=spec.job_id,
            scene=SceneRef.from_json(spec.scene, spec.scene_dir, spec.scene_files),
            config=kind.stored_config(spec.config),
            seed=spec.seed,
            output_dir=output_dir,
            checkpoints=CheckpointStore(spec.checkpoint_dir, keep=2),
            reserve_samplers=sampler_reserver(spec.job_id, SAMPLER_CPUS, cancel, log),
            on_progress=lambda **fields: emit(JobEvent(type="progress", time=time.time(), **fields)),
            on_log=log,
            cancel_requested=cancel,
        )
        output = run_kind(kind, ctx)
        files = {name: path for name, (path, _) in output.files.items()}
        if spec.output_url is not None:
            files = upload_outputs(files, spec.output_url)
    except JobCancelled:
        return JobOutcome(state="cancelled")
    except INFRASTRUCTURE_ERRORS as error:
        return JobOutcome(state="failed", error=one_line(error), infrastructure_failure=True)
    except Exception as error:
        emit(JobEvent(type="log", time=time.time(), message=traceback.format_exc(limit=8)))
        return JobOutcome(state="failed", error=one_line(error))
    finally:
        if spec.output_dir is None:
            shutil.rmtree(output_dir, ignore_errors=True)
    return JobOutcome(
        state="succeeded",
        files=files,
        media_types={name: media_type for name, (_, media_type) in output.files.items()},
        # A figure over an empty set (an asset no pixel sees) is NaN in the report and absent here: the
        # artifact's manifest is canonical JSON, which has no NaN.
        metrics={name: value for name, value in output.metrics.items() if math.isfinite(value)},
        warnings=output.warnings,
    )


def upload_outputs(files: dict[str, str], output_url: str) -> dict[str, str]:
    """Copy the artifact's files (name -> local path or URL) to `output_url`; name -> uploaded URL.

    A store that fails here is the infrastructure's fault: the job is retried and resumes from its
    checkpoints rather than failing."""
    fs, root = fsspec.core.url_to_fs(output_url)
    uploaded = {}
    try:
        for name, path in files.items():
            target = f"{root.rstrip('/')}/{name}"
            fs.makedirs(target.rsplit("/", 1)[0], exist_ok=True)
            with fsspec.open(path, "rb") as source, fs.open(target, "wb") as out:
                shutil.copyfileobj(source, out, CHUNK_BYTES)
            uploaded[name] = fs.unstrip_protocol(target)
    except OSError as error:
        raise InfrastructureFailure(f"uploading the output {name!r} to the store failed: {error}") from error
    return uploaded


@ray.remote
class JobDriver:
    """Runs one job on a background thread; buffers its events until the service polls them."""

    def __init__(self, spec: dict) -> None:
        self.spec = JobSpec.model_validate(spec)
        self.events: collections.deque[JobEvent] = collections.deque(maxlen=MAX_BUFFERED_EVENTS)
        self.lock = threading.Lock()
        self.cancel_requested = threading.Event()
        self.result: JobOutcome | None = None
        self.thread = threading.Thread(target=self._run, name=f"job-{self.spec.job_id}", daemon=True)
        self.thread.start()

    def _emit(self, event: JobEvent) -> None:
        with self.lock:
            self.events.append(event)

    def _finish(self, outcome: JobOutcome) -> None:
        with self.lock:
            if self.result is None:  # the first outcome stands: a late one from an abandoned run is dropped
                self.result = outcome

    def _run(self) -> None:
        self._finish(run_job(self.spec, self._emit, self.cancel_requested))

    def _cancel_overdue(self) -> None:
        """A kind stuck inside one item (say, waiting for samplers the cluster cannot place) is abandoned:
        the job reports cancelled now, and releasing the driver ends it and its sampler actors with it."""
        if self.thread.is_alive():
            self._emit(JobEvent(type="log", time=time.time(), message="cancel: the job did not stop in time"))
            self._finish(JobOutcome(state="cancelled"))

    def poll(self, max_events: int) -> list[dict]:
        with self.lock:
            count = min(max_events, len(self.events))
            return [self.events.popleft().model_dump(mode="json") for _ in range(count)]

    def outcome(self) -> dict | None:
        return None if self.result is None else self.result.model_dump(mode="json")

    def cancel(self) -> None:
        if not self.cancel_requested.is_set():
            self.cancel_requested.set()
            timer = threading.Timer(CANCEL_GRACE_S, self._cancel_overdue)
            timer.daemon = True
            timer.start()

    def ping(self) -> bool:
        return True

    def remove_scratch(self) -> None:
        """Remove the job's private folder before the driver is ended (its `finally` will not run)."""
        scratch.remove_own()


def actor_name(job_id: str) -> str:
    return f"nbake-job-{job_id}"


class JobHandle:
    """The service's view of one driver.

    Keep the handle `start_job` returned while the job runs (dropping it ends the driver), and call
    `release` once the outcome is stored: that ends the driver's process and any actor it still owns.
    """

    def __init__(self, job_id: str, actor: ray.actor.ActorHandle) -> None:
        self.job_id = job_id
        self.actor = actor

    def _call(self, method, *args, default):
        """A driver call answered within about a second; `default` when it is slow (e.g. still starting)."""
        try:
            return ray.get(method.remote(*args), timeout=CALL_TIMEOUT_S)
        except GetTimeoutError:
            return default

    def poll(self, max_events: int = 1000) -> list[JobEvent]:
        """Drain the buffered events (none if the driver is gone: `outcome` says why)."""
        try:
            events = self._call(self.actor.poll, max_events, default=[])
        except RayActorError:
            return []
        return [JobEvent.model_validate(event) for event in events]

    def outcome(self) -> JobOutcome | None:
        """None while the job runs; a failed, retryable outcome when the driver itself died."""
        try:
            result = self._call(self.actor.outcome, default=None)
        except RayActorError as error:
            return JobOutcome(
                state="failed",
                error=f"the job driver died: {one_line(error)}",
                infrastructure_failure=True,
            )
        return None if result is None else JobOutcome.model_validate(result)

    def cancel(self) -> None:
        """Ask the driver to stop; its kind stops within one work item and closes its sampler actors."""
        with contextlib.suppress(RayActorError):  # a dead driver is already stopped
            self._call(self.actor.cancel, default=None)

    def alive(self) -> bool:
        try:
            return self._call(self.actor.ping, default=True)  # a slow answer is a busy or starting driver
        except RayActorError:
            return False

    def release(self) -> None:
        """End the driver process and free its samplers' reservation (after its outcome was stored)."""
        with contextlib.suppress(RayActorError):  # a dead driver's folder goes with the node's next job
            self._call(self.actor.remove_scratch, default=None)
        ray.kill(self.actor, no_restart=True)
        remove_reservation(self.job_id)


def start_job(spec: JobSpec) -> JobHandle:
    """Start the job's driver and return at once.

    A driver still running this job id is returned as it is; one that already finished (a retry after a
    failure, say) is ended first, so the new start runs the job again from its checkpoints.
    """
    existing = attach_job(spec.job_id)
    if existing is not None:
        if existing.outcome() is None:
            return existing
        existing.release()
        _wait_until_gone(spec.job_id)
    options = actor_options(ResourceRequest(cpus=0, gpus=spec.num_gpus))
    actor = JobDriver.options(
        name=actor_name(spec.job_id), namespace=NAMESPACE, max_restarts=0, **options
    ).remote(spec.model_dump(mode="json"))
    return JobHandle(spec.job_id, actor)


def _wait_until_gone(job_id: str) -> None:
    """Ray frees a killed actor's name asynchronously; a new driver can only take it once it is free."""
    deadline = time.monotonic() + NAME_RELEASE_TIMEOUT_S
    while attach_job(job_id) is not None:
        if time.monotonic() > deadline:
            raise RuntimeError(f"the finished driver of job {job_id} did not exit; retry the start later")
        time.sleep(0.05)


def attach_job(job_id: str) -> JobHandle | None:
    """The live driver of `job_id`, or None (e.g. after a server restart, when its cluster is gone)."""
    try:
        actor = ray.get_actor(actor_name(job_id), namespace=NAMESPACE)
    except ValueError:
        return None
    return JobHandle(job_id, actor)
