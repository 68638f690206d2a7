"""`Client`: the synchronous SDK over either transport.

`Client("http://host:8080", token)` talks REST; `Client("grpc://host:50051", token)` (or `grpcs://`)
talks gRPC. Both give the same models and exceptions. Calls that a later attempt can fix (server
unreachable, 503 / UNAVAILABLE) are retried with backoff; submissions carry an idempotency key, so a
retried submission never queues the same job twice, and event streams resume after the last event seen.
"""

from __future__ import annotations

import os
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from neuralbake_client.archive import upload_parts
from neuralbake_client.download import DownloadedFile, download_file
from neuralbake_client.errors import RETRYABLE, NeuralbakeError
from neuralbake_client.models import Asset, Job, JobEvent, JobList, JobState, Manifest, Progress
from neuralbake_client.retry import DEFAULT_RETRY, Retry
from neuralbake_client.transport_grpc import GrpcTransport
from neuralbake_client.transport_http import HttpTransport

JobRef = Job | str
ArtifactRef = Job | Manifest | str
SceneRef = str | os.PathLike | dict[str, Any]


def job_id(job: JobRef) -> str:
    return job.id if isinstance(job, Job) else job


def artifact_id(artifact: ArtifactRef) -> str:
    if isinstance(artifact, Manifest):
        return artifact.artifact_id
    if isinstance(artifact, Job):
        if artifact.artifact_id is None:
            raise NeuralbakeError(f"job {artifact.id} is {artifact.state} and has no artifact")
        return artifact.artifact_id
    return artifact


def transport_for(url: str, token: str | None, timeout: float) -> HttpTransport | GrpcTransport:
    scheme = urlsplit(url).scheme
    if scheme in ("http", "https"):
        return HttpTransport(url, token, timeout)
    if scheme in ("grpc", "grpcs"):
        return GrpcTransport(urlsplit(url).netloc, token, timeout, secure=scheme == "grpcs")
    raise ValueError(f"{url!r}: use http(s)://host:port for REST or grpc(s)://host:port for gRPC")


class Client:
    """The neuralbake job service. Use as a context manager (or call `close()`)."""

    def __init__(
        self, url: str, token: str | None = None, *, timeout: float = 30.0, retry: Retry = DEFAULT_RETRY
    ):
        self.url, self.retry = url, retry
        self.transport = transport_for(url, token, timeout)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.transport.close()

    # ------------------------------------------------------------------ assets

    def upload(self, path: str | os.PathLike) -> Asset:
        """Upload a scene: a directory (sent as one tar.gz), a scene file, or a zip/tar archive."""
        with ExitStack() as streams:
            parts = upload_parts(path)
            for _, stream in parts:
                streams.callback(stream.close)
            return self.retry.call(lambda: self.transport.upload(parts))

    def get_asset(self, asset_id: str) -> Asset:
        return self.retry.call(lambda: self.transport.get_asset(asset_id))

    # ------------------------------------------------------------------ jobs

    def submit(
        self,
        kind: str,
        scene: SceneRef,
        *,
        preset: str | None = None,
        config: dict[str, Any] | None = None,
        seed: int | None = None,
        priority: int | None = None,
        force: bool = False,
    ) -> Job:
        """Queue a job, or get the existing identical one (unless `force`).

        `scene` is a built-in scene name or an asset id (str), an inline SceneSpec (dict), or a local
        scene file or directory (a `Path`), which is uploaded first.
        """
        if isinstance(scene, os.PathLike):
            scene = self.upload(scene).asset_id
        body = {"kind": kind, "scene": scene, "config": config or {}, "force": force}
        body |= {
            k: v for k, v in (("preset", preset), ("seed", seed), ("priority", priority)) if v is not None
        }
        key = f"sdk-{uuid.uuid4()}"  # the same key on every retry of this one submission
        return self.retry.call(lambda: self.transport.submit(body, key))

    def get(self, job: JobRef) -> Job:
        return self.retry.call(lambda: self.transport.get_job(job_id(job)))

    def list(
        self,
        state: JobState | str | list[JobState | str] | None = None,
        kind: str | None = None,
        *,
        limit: int = 50,
        cursor: str | None = None,
    ) -> JobList:
        """One page of jobs, newest first; pass `next_cursor` as `cursor` for the next page."""
        states = [state] if isinstance(state, str) else list(state or [])
        names = [JobState(s).value for s in states]
        return self.retry.call(lambda: self.transport.list_jobs(names, kind, cursor, limit))

    def jobs(self, state=None, kind: str | None = None, *, page_size: int = 50) -> Iterator[Job]:
        """Every matching job, newest first, fetching pages as needed."""
        cursor = None
        while True:
            page = self.list(state, kind, limit=page_size, cursor=cursor)
            yield from page.items
            if page.next_cursor is None:
                return
            cursor = page.next_cursor

    def cancel(self, job: JobRef) -> Job:
        """A queued job is cancelled at once; a running one stops within seconds (see `wait`)."""
        return self.retry.call(lambda: self.transport.cancel(job_id(job)))

    def events(self, job: JobRef, after: int = 0) -> Iterator[JobEvent]:
        """The job's events (state changes, progress, log lines) after `after`, ending with the final
        state; a dropped connection is resumed after the last event received."""
        ident, delays = job_id(job), None
        while True:
            try:
                for event in self.transport.events(ident, after):
                    yield event
                    after, delays = event.seq, None
                    if event.final:
                        return
                return
            except RETRYABLE:
                delays = delays or self.retry.delays()
                delay = next(delays, None)
                if delay is None:
                    raise
                time.sleep(delay)

    def wait(
        self,
        job: JobRef,
        on_progress: Callable[[Progress], None] | None = None,
        *,
        on_event: Callable[[JobEvent], None] | None = None,
    ) -> Job:
        """Follow the job to its final state and return it (SUCCEEDED, FAILED or CANCELLED)."""
        for event in self.events(job):
            if on_event:
                on_event(event)
            if on_progress and event.progress is not None:
                on_progress(event.progress)
        return self.get(job)

    # ------------------------------------------------------------------ artifacts

    def manifest(self, artifact: ArtifactRef) -> Manifest:
        return self.retry.call(lambda: self.transport.manifest(artifact_id(artifact)))

    def download(
        self,
        artifact: ArtifactRef,
        dest: str | os.PathLike,
        names: list[str] | None = None,
        on_bytes: Callable[[int], None] | None = None,
    ) -> list[DownloadedFile]:
        """Download the artifact's files (or `names`) into `dest`, resuming partial files and checking
        each against the manifest's sha256; files already there and intact are not fetched again."""
        manifest = artifact if isinstance(artifact, Manifest) else self.manifest(artifact)
        entries = [manifest.file(name) for name in names] if names else manifest.files
        folder = Path(dest)
        return [
            download_file(self.transport, manifest.artifact_id, entry, folder, self.retry, on_bytes)
            for entry in entries
        ]
