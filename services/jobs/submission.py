"""Turning a job request into a stored QUEUED job, in two steps: `check` resolves the request into a
checked job (kind, preset, config and scene validated, each error naming its field, and the work's
idempotency key computed); `persist` reuses the existing job a key names, or plans, admits and inserts a
new one.
"""

from __future__ import annotations

import hashlib
import json
import math
import threading
import uuid
from collections import OrderedDict
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from services.jobs.errors import name_batch_item
from services.jobs.identity import code_version, idempotency_key
from services.jobs.repository import JobRepository
from services.jobs.scenes import ResolvedScene, SceneResolver, scene_field
from services.jobs.states import JobState
from services.jobs.tables import Job, utcnow
from services.jobs.tenants import DEFAULT_TENANT
from services.platform.auth import Principal
from services.platform.errors import InvalidInput, ServiceError
from workers.models.registry import UnknownKind, get_kind
from workers.runtime.contract import Plan, PlanItem
from workers.scene.format.errors import SceneError
from workers.scene.format.spec import MeshShape, SceneSpec
from workers.scene.geometry.budget import scene_triangles
from workers.scene.portability.io import dotted_path
from workers.scene.portability.reference import SceneRef

if TYPE_CHECKING:
    from services.geometry import GeometryProcesses
    from services.jobs.quotas import Quotas

MAX_IDEMPOTENCY_HEADER = 255
MAX_BATCH = 500  # jobs in one batch submission: a build of a few hundred assets x kinds, chunked above it
T = TypeVar("T")
# A scene without mesh files and at most this many triangles is planned in the API process: building it
# takes little (the 85k-triangle default `fractal_tree`: 0.6 s and 26 MB at peak on the busy machine), a child
# process 10 s to start there (and more to import a kind). Larger scenes and any mesh file go to a child.
IN_PROCESS_TRIANGLES = 200_000
PLAN_CACHE_SIZE = 1024  # plans are a few KB; repeated submissions of the same work skip the planning
CREATING_WAIT_S = 30.0  # an identical submission waits this long at most for the first one to finish


class JobRequest(BaseModel):
    """The body of `POST /v1/jobs`."""

    model_config = ConfigDict(extra="forbid")

    kind: str = Field(max_length=64, description="The model kind, e.g. `render`.", examples=["render"])
    scene: Annotated[str, Field(min_length=1, max_length=256)] | dict[str, Any] = Field(
        description="An uploaded asset id (`sha256:...`), a built-in scene name, or an inline SceneSpec.",
        examples=["cornell_box"],
    )
    preset: str = Field("default", max_length=64, description="`quick`, `default` or `paper`.")
    config: dict[str, Any] = Field(default_factory=dict, description="Overrides of the preset's values.")
    seed: int = Field(0, ge=0, le=2**63 - 1, description="Seed of every sampler; part of the job's identity.")
    priority: int = Field(0, ge=-1000, le=1000, description="Higher starts first.")
    force: bool = Field(False, description="Run even if identical work already exists.")


class BatchRequest(BaseModel):
    """The body of `POST /v1/jobs:batch` (and gRPC `SubmitJobs`)."""

    model_config = ConfigDict(extra="forbid")

    jobs: list[JobRequest] = Field(min_length=1, max_length=MAX_BATCH, description="Each as `POST /v1/jobs`.")


@dataclass(frozen=True)
class CheckedJob:
    """A request resolved and checked, before anything is stored: what a new job of it would hold."""

    tenant: str
    kind: str
    preset: str
    config: BaseModel  # the kind's config model: the preset with the request's overrides, validated
    resolved: dict[str, Any]  # config.model_dump(mode="json"): what the job stores and its identity hashes
    scene: ResolvedScene
    seed: int
    priority: int
    force: bool
    code: str  # the code version, part of the identity
    key: str  # the idempotency key (`services.jobs.identity`): the same work, the same key


class Submitter:
    """Plans run in `geometry`'s child processes when given (a server: plans may build meshes), and are
    cached per kind, scene content and resolved config. A new job is admitted by the tenant's `quotas`."""

    def __init__(
        self,
        jobs: JobRepository,
        scenes: SceneResolver,
        max_attempts: int,
        geometry: GeometryProcesses | None = None,
        max_job_seconds: float = math.inf,
        quotas: Quotas | None = None,
    ):
        self.jobs, self.scenes, self.max_attempts, self.geometry = jobs, scenes, max_attempts, geometry
        self.max_job_seconds, self.quotas = max_job_seconds, quotas
        self._plans: OrderedDict[tuple[str, str, str], Plan] = OrderedDict()
        self._plans_lock = threading.Lock()
        self._creating: dict[str, threading.Event] = {}  # content keys being created by this process
        self._creating_lock = threading.Lock()

    def submit(
        self, request: JobRequest, header_key: str | None = None, principal: Principal | None = None
    ) -> tuple[Job, bool]:
        """(job, created): created is False when an idempotency key named an existing job of the same
        tenant. The job is `principal`'s tenant's (the default tenant's without one), and may name only
        assets that tenant sees."""
        return self.persist(self.check(request, principal or Principal(DEFAULT_TENANT, "admin")), header_key)

    def check(self, request: JobRequest, principal: Principal) -> CheckedJob:
        """The request as a checked job of `principal`'s tenant: kind, preset, config and scene validated
        (InvalidInput naming the field at fault) and the work's identity computed. Nothing is stored."""
        try:
            kind = get_kind(request.kind)
        except UnknownKind as error:
            raise InvalidInput(str(error), "kind") from None
        if request.preset not in kind.presets:
            known = ", ".join(kind.presets)
            raise InvalidInput(f"unknown preset {request.preset!r}; known presets: {known}", "preset")
        check_finite(request.config, "config")
        try:
            config = kind.resolve_config(request.preset, request.config)
        except ValidationError as error:
            first = error.errors()[0]
            field = dotted_path(first["loc"], request.config)
            raise InvalidInput(first["msg"], f"config.{field}" if field else "config") from None
        except ValueError as error:
            raise InvalidInput(str(error), "config") from None
        scene = self.scenes.resolve(request.scene, principal)
        # the identity hashes the validated config, not the request: an unknown key was refused above, so
        # none is dropped to make this submission equal to an earlier job's
        resolved = config.model_dump(mode="json")
        code = code_version()
        return CheckedJob(
            tenant=principal.tenant,
            kind=kind.name,
            preset=request.preset,
            config=config,
            resolved=resolved,
            scene=scene,
            seed=request.seed,
            priority=request.priority,
            force=request.force,
            code=code,
            key=idempotency_key(kind.name, scene.content_hash, resolved, request.seed, code),
        )

    def persist(self, checked: CheckedJob, header_key: str | None = None) -> tuple[Job, bool]:
        """The job an idempotency key names (created False), else a new one: planned (InvalidInput when the
        plan is refused), its scene stored, admitted by the tenant's quotas and inserted. A repeat of
        existing work is answered before it is planned."""
        content_key = None if checked.force else f"{checked.tenant}/content:{checked.key}"  # per tenant
        header = _header_key(header_key)
        header = header and f"{checked.tenant}/{header}"
        reusing = header is None and content_key is not None
        if reusing and (existing := self.jobs.reusable(content_key)):
            return existing, False  # the same work exists: validated and planned when it was submitted
        with self._first(content_key if reusing else None) as first:
            if not first and (existing := self.jobs.reusable(content_key)):
                return existing, False  # an identical submission of this process has just made it
            job = self._new_job(checked)
            admit = self.quotas.admit if self.quotas else None  # once no existing job is reused
            return self.jobs.create(job, content_key, header, absent=reusing, admit=admit)

    def submit_many(
        self,
        requests: Sequence[JobRequest],
        header_key: str | None = None,
        principal: Principal | None = None,
    ) -> list[tuple[Job, bool]]:
        """A build's jobs at once, all or nothing: every request is checked and every new job planned before
        anything is stored, then all are inserted in one transaction (quotas count the batch's own jobs);
        the first refusal names its field under `jobs[i]`. `header_key` keys the batch: the same key again
        returns the same jobs."""
        principal = principal or Principal(DEFAULT_TENANT, "admin")
        checked = [_at(index, self.check, request, principal) for index, request in enumerate(requests)]
        answers: dict[int, tuple[Job, bool]] = {}
        entries: list[tuple[int, Job, str | None, str | None]] = []
        header = _header_key(header_key)
        for index, job in enumerate(checked):
            content_key = None if job.force else f"{job.tenant}/content:{job.key}"
            item_header = header and f"{job.tenant}/{header}/{index}"
            existing = None if item_header or content_key is None else self.jobs.reusable(content_key)
            if existing is not None:
                answers[index] = (existing, False)  # planned when it was submitted
                continue
            entries.append((index, _at(index, self._new_job, job), content_key, item_header))
        admit = self.quotas.admit if self.quotas else None
        created = self.jobs.create_many([entry[1:] for entry in entries], admit=admit)
        answers |= {entry[0]: answer for entry, answer in zip(entries, created, strict=True)}
        return [answers[index] for index in range(len(checked))]

    def _new_job(self, checked: CheckedJob) -> Job:
        """The row of a new QUEUED job; its scene is put in the store once the plan is accepted."""
        plan = self._checked_plan(checked.kind, checked.scene, checked.config, checked.resolved)
        return Job(
            id=f"job-{uuid.uuid4().hex}",
            tenant=checked.tenant,
            kind=checked.kind,
            state=JobState.QUEUED,
            scene_ref=checked.scene.ref,
            scene_digest=self.scenes.store(checked.scene),
            scene_hash=checked.scene.content_hash,
            preset=checked.preset,
            config=checked.resolved,
            seed=checked.seed,
            priority=checked.priority,
            code_version=checked.code,
            idempotency_key=checked.key,
            plan=plan,
            attempts=0,
            max_attempts=self.max_attempts,
            cancel_requested=False,
            last_event_seq=0,
            created_at=utcnow(),
        )

    @contextmanager
    def _first(self, content_key: str | None) -> Iterator[bool]:
        """Whether this is the first submission in this process creating the work `content_key` names. A
        later identical one waits for it (at most `CREATING_WAIT_S`) and then reads its job, instead of
        racing it into the database: there the loser waits on the key's index for the first to commit, then
        fails, rolls back and retries (a repeat arriving while the work is new, in the load bench)."""
        if content_key is None:
            yield True
            return
        with self._creating_lock:
            running = self._creating.get(content_key)
            first = running is None
            if first:
                running = self._creating[content_key] = threading.Event()
        if not first:
            running.wait(CREATING_WAIT_S)
            yield False
            return
        try:
            yield True
        finally:
            with self._creating_lock:
                del self._creating[content_key]
            running.set()

    def _checked_plan(self, kind_name: str, scene: ResolvedScene, config, resolved: dict) -> dict[str, Any]:
        """The plan as stored in the job row; InvalidInput when the scene is refused or the plan's estimate
        exceeds `max_job_seconds`."""
        try:
            triangles = scene_triangles(scene.spec)  # before anything is built, here or in a child
            plan = self._plan(kind_name, scene, config, resolved, in_process=_small(scene.spec, triangles))
        except SceneError as error:
            raise InvalidInput(error.problem, scene_field(error)) from None
        except ValueError as error:
            raise InvalidInput(str(error), "config") from None
        if plan.estimated_seconds > self.max_job_seconds:
            raise InvalidInput(
                f"the plan estimates {plan.estimated_seconds:.3g} s ({plan.summary}), over the limit of "
                f"{self.max_job_seconds:g} s (max_job_seconds): lower the config's sizes",
                "config",
            )
        stored = plan.model_dump(mode="json")  # a copy: the cached plan stays as planned
        stored["items"].extend(
            PlanItem(
                name="scene import", choice=note, reason="what the scene's importer defaulted or ignored"
            ).model_dump(mode="json")
            for note in scene.spec.notes
        )
        return stored

    def _plan(self, kind_name: str, scene: ResolvedScene, config, resolved: dict, in_process: bool) -> Plan:
        key = (kind_name, scene.content_hash, json.dumps(resolved, sort_keys=True))
        with self._plans_lock:
            if key in self._plans:
                self._plans.move_to_end(key)
                return self._plans[key]
        ref = SceneRef(scene.spec, self.scenes.scene_dir(scene.ref))
        if self.geometry is None or in_process:
            plan = make_plan(kind_name, ref, config)
        else:
            plan = self.geometry.run("scene", make_plan, kind_name, ref, config)
        with self._plans_lock:
            self._plans[key] = plan
            while len(self._plans) > PLAN_CACHE_SIZE:
                self._plans.popitem(last=False)
        return plan


def _at(index: int, step: Callable[..., T], *args: Any) -> T:
    """`step(*args)` for the batch's `index`-th request, a refusal naming its field under `jobs[i]`."""
    try:
        return step(*args)
    except ServiceError as error:
        name_batch_item(error, index)
        raise


def check_finite(data: Any, field: str) -> None:
    """InvalidInput naming the first infinite or NaN number (JSON's `1e309` parses to infinity); walked
    without recursion, however deep the body nests."""
    stack = [(data, field)]
    while stack:
        value, where = stack.pop()
        if isinstance(value, float) and not math.isfinite(value):
            raise InvalidInput("must be a finite number", where)
        if isinstance(value, dict):
            stack.extend((child, f"{where}.{key}") for key, child in reversed(value.items()))
        elif isinstance(value, list):
            stack.extend((child, f"{where}[{i}]") for i, child in reversed(list(enumerate(value))))


def _small(spec: SceneSpec, triangles: int) -> bool:
    return triangles <= IN_PROCESS_TRIANGLES and not any(isinstance(o.shape, MeshShape) for o in spec.objects)


def make_plan(kind_name: str, scene: SceneRef, config) -> Plan:
    """The kind's plan (a module-level function, so a child process can run it)."""
    return get_kind(kind_name).plan(scene, config)


def _header_key(value: str | None) -> str | None:
    """Stored hashed, so any length and character set fits the column."""
    if value is None:
        return None
    if not 0 < len(value) <= MAX_IDEMPOTENCY_HEADER:
        raise InvalidInput(f"must be 1 to {MAX_IDEMPOTENCY_HEADER} characters", "Idempotency-Key")
    return "header:sha256:" + hashlib.sha256(value.encode()).hexdigest()
