"""Baking a pipeline (see `pipeline`): every (asset, kind) item becomes a job, at most `concurrency` at
once, within the build's timeout; each artifact's metrics are checked against its gates.

What changed is all that is sent: an item whose asset digest and config digest equal the previous lock's
entry takes that entry's artifact (after checking the server still has it) without a submission; an
asset already uploaded (same digest in the lock) is not uploaded again; and a submission of work the
server already did comes back as that job (`reused`). A build that times out leaves its jobs running:
the next build finds them as identical work.
"""

from __future__ import annotations

import re
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

from pydantic import BaseModel, Field

from neuralbake_client.build_lock import BuildLock, LockEntry
from neuralbake_client.client import Client
from neuralbake_client.errors import ApiError, NotFound
from neuralbake_client.gates import Gate, GateResult
from neuralbake_client.models import Job
from neuralbake_client.pipeline import Item, Pipeline, Source, items
from neuralbake_client.states import JobState

PASSED, GATES_FAILED, FAILED, CANCELLED, TIMED_OUT, REFUSED = (
    "passed",
    "gates_failed",
    "failed",
    "cancelled",
    "timed_out",
    "refused",
)
POLL_S = (0.5, 2.0)  # first and longest wait between polls of the jobs in flight


class ItemResult(BaseModel):
    """One item's outcome: `passed`, `gates_failed`, `failed` / `cancelled` (its job), `timed_out` (the
    build's timeout came first) or `refused` (the server refused its upload or submission: `error`)."""

    name: str
    asset: str
    kind: str
    outcome: str | None = None
    job_id: str | None = None
    artifact_id: str | None = None
    submitted: bool = Field(False, description="This build sent a submission (new or reused work).")
    reused: bool = Field(False, description="The artifact came from the lock or from identical work.")
    metrics: dict[str, float] = Field(default_factory=dict)
    gates: list[GateResult] = Field(default_factory=list)
    error: str | None = None
    seconds: float = 0.0

    @property
    def done(self) -> bool:
        return self.outcome is not None


class BuildResult(BaseModel):
    items: list[ItemResult]
    seconds: float
    lock: BuildLock = Field(description="The lock of this build: every item that has an artifact.")

    def count(self, outcome: str) -> int:
        return sum(1 for item in self.items if item.outcome == outcome)

    @property
    def passed(self) -> bool:
        return all(item.outcome == PASSED for item in self.items)

    @property
    def submitted(self) -> int:
        return sum(1 for item in self.items if item.submitted)


class Baker:
    """One build: `run()` bakes `pipeline`'s items with `client`, against the `previous` lock."""

    def __init__(
        self,
        client: Client,
        pipeline: Pipeline,
        base: Path,
        previous: BuildLock,
        *,
        refresh: bool = False,
        on_update: Callable[[ItemResult], None] | None = None,
    ):
        self.client, self.pipeline, self.previous, self.refresh = client, pipeline, previous, refresh
        self.items = items(pipeline, base)
        self.on_update = on_update or (lambda _: None)
        self._uploads: dict[str, str | ApiError] = {}  # asset digest -> asset id, or why it was refused
        self.results: dict[str, ItemResult] = {}  # by item name
        self.flying: dict[str, tuple[Item, str, float]] = {}  # item name -> (item, job id, when submitted)

    def run(self) -> BuildResult:
        started = time.monotonic()
        deadline = started + self.pipeline.timeout
        self.results = {
            item.name: ItemResult(name=item.name, asset=item.source.label, kind=item.entry.kind)
            for item in self.items
        }
        waiting = deque(self.items)
        poll = POLL_S[0]
        while waiting or self.flying:
            if waiting and time.monotonic() < deadline:
                self._start(waiting)
            for name, (item, job_id, since) in list(self.flying.items()):
                job = self.client.get(job_id)
                if job.state.terminal:
                    del self.flying[name]
                    self._finish(item, job, time.monotonic() - since)
                    poll = POLL_S[0]
            if time.monotonic() >= deadline:
                for result in self.results.values():
                    if not result.done:
                        result.outcome = TIMED_OUT
                        self.on_update(result)
                break
            if self.flying:
                time.sleep(min(poll, max(0.0, deadline - time.monotonic())))
                poll = min(POLL_S[1], poll * 1.5)
        ordered = [self.results[item.name] for item in self.items]
        return BuildResult(items=ordered, seconds=time.monotonic() - started, lock=self._lock(ordered))

    # ------------------------------------------------------------------ starting items

    def _start(self, waiting: deque[Item]) -> None:
        """Start waiting items until `concurrency` are in flight: each from the lock when it has them
        unchanged, the others submitted together as one batch."""
        batch: list[tuple[Item, str]] = []
        while waiting and len(self.flying) + len(batch) < self.pipeline.concurrency:
            item = waiting.popleft()
            if self._from_lock(item):
                continue
            try:
                batch.append((item, self._scene(item.source, self.previous.entries.get(item.name))))
            except ApiError as error:
                self._refuse(item, error)
        while batch:
            try:
                jobs = self.client.submit_many([self._request(item, scene) for item, scene in batch])
            except ApiError as error:  # all or nothing: the item at fault is refused, the rest tried again
                index = _item_index(error.field)
                if index is not None and index < len(batch):
                    self._refuse(batch.pop(index)[0], error)
                else:
                    for item, _ in batch:
                        self._refuse(item, error)
                    batch = []
                continue
            for (item, _), job in zip(batch, jobs, strict=True):
                result = self.results[item.name]
                result.job_id, result.submitted, result.reused = job.id, True, job.reused
                if job.state.terminal:
                    self._finish(item, job, 0.0)
                else:
                    self.flying[item.name] = (item, job.id, time.monotonic())
                    self.on_update(result)
            return

    def _from_lock(self, item: Item) -> bool:
        """Whether the lock's artifact serves `item` (same asset content and kind entry, still on the
        server); if so the item is done, checked against its gates."""
        entry = self.previous.entries.get(item.name)
        unchanged = (
            entry is not None
            and entry.asset_digest == item.source.digest
            and entry.config_digest == item.config_digest
        )
        if not unchanged or self.refresh:
            return False
        try:
            manifest = self.client.manifest(entry.artifact_id)
        except NotFound:  # the server lost it (or it is another deployment): bake it again
            return False
        result = self.results[item.name]
        result.job_id, result.artifact_id, result.reused = entry.job_id, entry.artifact_id, True
        self._check(item, result, manifest.metrics)
        self.on_update(result)
        return True

    @staticmethod
    def _request(item: Item, scene: str) -> dict:
        kind = item.entry
        fields = {"preset": kind.preset, "seed": kind.seed, "priority": kind.priority}
        return {"kind": kind.kind, "scene": scene, "config": kind.config} | {
            name: value for name, value in fields.items() if value is not None
        }

    def _refuse(self, item: Item, error: ApiError) -> None:
        """The server refused the item's upload or submission; a server error or a refused token is not
        the item's fault and stops the whole build."""
        if error.status >= 500 or error.status in (401, 403):
            raise error
        result = self.results[item.name]
        result.outcome, result.error = REFUSED, f"{error.status} {error.title}: {error.where}{error.detail}"
        self.on_update(result)

    def _scene(self, source: Source, entry: LockEntry | None) -> str:
        """What to submit for `source`: its name, or the id of its upload (the lock's, if the server still
        has it; uploaded once per build otherwise)."""
        if source.path is None:
            return source.label
        known = self._uploads.get(source.digest)
        if known is None and entry is not None and entry.asset_digest == source.digest:
            try:
                known = self.client.get_asset(entry.scene).asset_id
            except NotFound:
                known = None
        if known is None:
            try:
                known = self.client.upload(source.path).asset_id
            except ApiError as error:  # refused for every kind of this asset, uploaded once
                known = error
            self._uploads[source.digest] = known
        if isinstance(known, ApiError):
            raise known
        return known

    def _finish(self, item: Item, job: Job, seconds: float) -> None:
        result = self.results[item.name]
        result.job_id, result.artifact_id, result.seconds = job.id, job.artifact_id, seconds
        if job.state != JobState.SUCCEEDED:
            result.outcome = FAILED if job.state == JobState.FAILED else CANCELLED
            result.error = job.error
        else:
            self._check(item, result, self.client.manifest(job.artifact_id).metrics)
        self.on_update(result)

    def _check(self, item: Item, result: ItemResult, metrics: dict[str, float]) -> None:
        previous = self.previous.entries.get(item.name)
        before = previous.metrics if previous is not None else None
        result.metrics = metrics
        result.gates = [Gate.parse(text).check(metrics, before) for text in item.entry.gates]
        result.outcome = PASSED if all(gate.passed for gate in result.gates) else GATES_FAILED

    def _lock(self, results: list[ItemResult]) -> BuildLock:
        entries = {}
        for item, result in zip(self.items, results, strict=True):
            if result.artifact_id is None:
                continue
            previous = self.previous.entries.get(item.name)
            known = self._uploads.get(item.source.digest)
            scene = known if isinstance(known, str) else previous.scene if previous else item.source.label
            entries[item.name] = LockEntry(
                asset=item.source.label,
                kind=item.entry.kind,
                asset_digest=item.source.digest,
                config_digest=item.config_digest,
                scene=scene,
                job_id=result.job_id,
                artifact_id=result.artifact_id,
                metrics=result.metrics,
            )
        return BuildLock(entries=entries)


def _item_index(field: str | None) -> int | None:
    """i of a batch refusal's field `jobs[i]...`: which item the server refused."""
    match = re.match(r"jobs\[(\d+)\]", field or "")
    return int(match[1]) if match else None
