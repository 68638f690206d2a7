"""`Client`: the synchronous SDK over either transport.

`Client("http://host:8080", token)` talks REST; `Client("grpc://host:50051", token)` (or `grpcs://`)
talks gRPC. Both give the same models and exceptions. Calls that a later attempt can fix (server
unreachable, 503 / UNAVAILABLE) are retried with backoff; submissions carry an idempotency key, so a
retried submission never queues the same job twice, and event streams resume after the last event seen.

Queries and renders go to the inference service (`nbake serve-inference`, its own port), over the same
kind of transport; its URL defaults to the job server's host at the inference service's default port.
Its transports (and NumPy) are imported on first use, so job-only callers never load them.
"""

from __future__ import annotations

import json
import os
import queue
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

from neuralbake_client.archive import upload_parts
from neuralbake_client.download import DownloadedFile, download_file
from neuralbake_client.errors import RETRYABLE, NeuralbakeError, WaitTimeout
from neuralbake_client.models import (
    Asset,
    CreatedToken,
    Job,
    JobEvent,
    JobList,
    JobState,
    KindInfo,
    Manifest,
    ModelInfo,
    Progress,
    QuotaLimits,
    SceneInfo,
    TenantQuotas,
    Token,
)
from neuralbake_client.references import artifact_id_of, job_id_of
from neuralbake_client.retry import DEFAULT_RETRY, Retry

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from neuralbake_client.answers import QueryAnswer, RenderedImage
    from neuralbake_client.inference_grpc import GrpcInference
    from neuralbake_client.inference_http import HttpInference
    from neuralbake_client.transport_grpc import GrpcTransport
    from neuralbake_client.transport_http import HttpTransport

JobRef = Job | Manifest | str  # a job, or an artifact (the job that made it): see `references`
ArtifactRef = Job | Manifest | str  # an artifact or its digest, or a job (its artifact)
SceneRef = str | os.PathLike | dict[str, Any]
REST, GRPC = ("http", "https"), ("grpc", "grpcs")
INFERENCE_PORTS = {"http": 8090, "https": 8090, "grpc": 50052, "grpcs": 50052}  # `nbake serve-inference`'s
IMAGE_FORMATS = {"exr": "image/x-exr", "png": "image/png"}


def checked_scheme(url: str) -> str:
    scheme = urlsplit(url).scheme
    if scheme not in REST + GRPC:
        raise ValueError(f"{url!r}: use http(s)://host:port for REST or grpc(s)://host:port for gRPC")
    return scheme


# Each transport is imported only for the scheme in use: a REST caller never loads gRPC, nor a job-only
# caller NumPy.


def transport_for(url: str, token: str | None, timeout: float) -> HttpTransport | GrpcTransport:
    if checked_scheme(url) in REST:
        from neuralbake_client.transport_http import HttpTransport

        return HttpTransport(url, token, timeout)
    from neuralbake_client.transport_grpc import GrpcTransport

    return GrpcTransport(urlsplit(url).netloc, token, timeout, secure=url.startswith("grpcs:"))


def inference_transport_for(url: str, token: str | None, timeout: float) -> HttpInference | GrpcInference:
    if checked_scheme(url) in REST:
        from neuralbake_client.inference_http import HttpInference

        return HttpInference(url, token, timeout)
    from neuralbake_client.inference_grpc import GrpcInference

    return GrpcInference(urlsplit(url).netloc, token, timeout, secure=url.startswith("grpcs:"))


def default_inference_url(url: str) -> str:
    """The job server's host and scheme at the inference service's default port (8090 REST, 50052 gRPC)."""
    parts = urlsplit(url)
    host = parts.hostname or "127.0.0.1"
    host = f"[{host}]" if ":" in host else host
    return f"{parts.scheme}://{host}:{INFERENCE_PORTS[checked_scheme(url)]}"


def _as_list(value: Any) -> Any:
    if hasattr(value, "tolist"):  # NumPy arrays and scalars
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON")


def json_value(value: Any) -> Any:
    """`value` with NumPy arrays and scalars (a camera position, say) made plain JSON."""
    return json.loads(json.dumps(value, default=_as_list))


class Client:
    """The neuralbake job service and its inference service. Use as a context manager (or call `close()`).

    `inference_url` is where `query`, `generate`, `render`, `load` and `models` go (default: see
    `default_inference_url`).
    """

    def __init__(
        self,
        url: str,
        token: str | None = None,
        *,
        inference_url: str | None = None,
        timeout: float = 30.0,
        retry: Retry = DEFAULT_RETRY,
    ):
        self.url, self.retry = url, retry
        self.inference_url = inference_url or default_inference_url(url)
        checked_scheme(self.inference_url)
        self.transport = transport_for(url, token, timeout)
        self._token, self._timeout = token, timeout
        self._inference: HttpInference | GrpcInference | None = None

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.transport.close()
        if self._inference is not None:
            self._inference.close()

    @property
    def inference(self) -> HttpInference | GrpcInference:
        """The inference service's transport, opened on first use."""
        if self._inference is None:
            self._inference = inference_transport_for(self.inference_url, self._token, self._timeout)
        return self._inference

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
        body = self._job_body(kind, scene, preset, config, seed, priority, force)
        key = f"sdk-{uuid.uuid4()}"  # the same key on every retry of this one submission
        return self.retry.call(lambda: self.transport.submit(body, key))

    def submit_many(self, jobs: list[Mapping[str, Any]]) -> list[Job]:
        """Queue many jobs at once, all or nothing (at most 500): each mapping holds `submit`'s arguments
        (`kind`, `scene`, and optionally `preset`, `config`, `seed`, `priority`, `force`). The server checks
        and plans every job before it stores any, and names the first refusal's field under `jobs[i]`.
        The jobs come back in order, each `reused` when identical work existed."""
        bodies = [self._job_body(**job) for job in jobs]
        key = f"sdk-{uuid.uuid4()}"  # a retried batch gets the same jobs back
        return self.retry.call(lambda: self.transport.submit_many(bodies, key))

    def _job_body(
        self,
        kind: str,
        scene: SceneRef,
        preset: str | None = None,
        config: dict[str, Any] | None = None,
        seed: int | None = None,
        priority: int | None = None,
        force: bool = False,
    ) -> dict[str, Any]:
        """A submission's body; a local scene file or folder (a `Path`) is uploaded for it first."""
        if isinstance(scene, os.PathLike):
            scene = self.upload(scene).asset_id
        body = {"kind": kind, "scene": scene, "config": config or {}, "force": force}
        return body | {
            k: v for k, v in (("preset", preset), ("seed", seed), ("priority", priority)) if v is not None
        }

    def get(self, job: JobRef) -> Job:
        """A job by its id, or the job that made an artifact (see `references`)."""
        ident = self.job_id(job)
        return self.retry.call(lambda: self.transport.get_job(ident))

    def job_id(self, job: JobRef) -> str:
        """The id of a job reference: a job, or an artifact (the job that made it)."""
        return job_id_of(job, self.manifest)

    def artifact_id(self, artifact: ArtifactRef) -> str:
        """The id of an artifact reference: an artifact or its digest, or a job (its artifact)."""
        return artifact_id_of(artifact, self.get)

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
        ident = self.job_id(job)
        return self.retry.call(lambda: self.transport.cancel(ident))

    def events(self, job: JobRef, after: int = 0) -> Iterator[JobEvent]:
        """The job's events (state changes, progress, log lines) after `after`, ending with the final
        state; a dropped connection is resumed after the last event received."""
        ident, delays = self.job_id(job), None
        while True:
            try:
                for event in self.transport.events(ident, after):
                    yield event
                    after, delays = event.seq, None
                    if event.final:
                        return
                return
            except RETRYABLE as error:
                delays = delays or self.retry.delays()
                delay = next(delays, None)
                if delay is None:
                    raise
                time.sleep(self.retry.wait(delay, error))

    def wait(
        self,
        job: JobRef,
        on_progress: Callable[[Progress], None] | None = None,
        *,
        on_event: Callable[[JobEvent], None] | None = None,
        timeout: float | None = None,
    ) -> Job:
        """Follow the job to its final state and return it (SUCCEEDED, FAILED or CANCELLED). With
        `timeout` (seconds), raise `WaitTimeout` when it has not ended by then; the job goes on."""
        events = self.events(job) if timeout is None else self._events_within(job, timeout)
        for event in events:
            if on_event:
                on_event(event)
            if on_progress and event.progress is not None:
                on_progress(event.progress)
        return self.get(job)

    def _events_within(self, job: JobRef, timeout: float) -> Iterator[JobEvent]:
        """`events(job)` until `timeout` seconds have passed. The stream is read in a daemon thread, which
        a blocked read cannot keep from giving up; it ends with the stream (the job's end, or `close()`)."""
        ident, deadline, received = self.job_id(job), time.monotonic() + timeout, queue.Queue()

        def read() -> None:
            try:
                for event in self.events(ident):
                    received.put(event)
            except Exception as error:  # handed to the reader below, which raises it
                received.put(error)
            received.put(None)

        threading.Thread(target=read, name=f"nbake-wait-{ident}", daemon=True).start()
        while True:
            try:
                item = received.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise WaitTimeout(ident, timeout) from None
            if item is None:
                return
            if isinstance(item, Exception):
                raise item
            yield item

    # ------------------------------------------------------------------ artifacts

    def manifest(self, artifact: ArtifactRef) -> Manifest:
        ident = self.artifact_id(artifact)
        return self.retry.call(lambda: self.transport.manifest(ident))

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

    # ------------------------------------------------------------------ tokens and quotas (admin, REST only)

    def create_token(self, tenant: str = "default", scope: str = "read", name: str = "") -> CreatedToken:
        """A new token of `tenant` (its jobs, assets and artifacts are all it sees) with `scope` (read,
        submit or admin). Its secret, `.token`, is in this answer only: the server keeps its hash."""
        return self._rest("tokens and quotas are").create_token(tenant, scope, name)

    def tokens(self) -> list[Token]:
        """Every token of the deployment, without secrets."""
        return self.retry.call(lambda: self._rest("tokens and quotas are").list_tokens())

    def revoke_token(self, token: Token | str) -> None:
        """Revoke a created token by id: its next request gets 401."""
        ident = token.id if isinstance(token, Token) else token
        self.retry.call(lambda: self._rest("tokens and quotas are").revoke_token(ident))

    def quotas(self, tenant: str) -> TenantQuotas:
        """`tenant`'s quotas in force, its own, the deployment's defaults and what its jobs use now."""
        return self.retry.call(lambda: self._rest("tokens and quotas are").get_quotas(tenant))

    def set_quotas(self, tenant: str, limits: QuotaLimits) -> TenantQuotas:
        """Replace `tenant`'s own quotas (a None field: the deployment's default); its quotas now."""
        return self.retry.call(lambda: self._rest("tokens and quotas are").set_quotas(tenant, limits))

    def _rest(self, what: str) -> HttpTransport:
        """The REST transport, for what only the REST API offers (`what`: for the error message)."""
        if not hasattr(self.transport, "create_token"):
            raise NeuralbakeError(f"{what} served over REST only: connect with an http(s):// URL")
        return self.transport

    # ------------------------------------------------------------------ the catalog (REST only)

    def kinds(self) -> list[KindInfo]:
        """The server's model kinds, each with its presets' resolved configs and its config's JSON schema."""
        return self.retry.call(lambda: self._rest("kinds are").list_kinds())

    def kind(self, name: str) -> KindInfo:
        return self.retry.call(lambda: self._rest("kinds are").get_kind(name))

    def scenes(self) -> list[SceneInfo]:
        """The server's built-in scenes, each with the first line of its description."""
        return self.retry.call(lambda: self._rest("scenes are").list_scenes())

    # ------------------------------------------------------------------ inference

    def models(self) -> list[ModelInfo]:
        """The models the inference service holds, least recently used (next to be evicted) first."""
        return self.retry.call(lambda: self.inference.models())

    def load(self, artifact: ArtifactRef) -> ModelInfo:
        """Fetch, verify and load the artifact's model now, so its first query does not wait for it."""
        ident = self.artifact_id(artifact)
        return self.retry.call(lambda: self.inference.load(ident))

    def query(
        self,
        artifact: ArtifactRef,
        arrays: Mapping[str, ArrayLike] | None = None,
        params: dict[str, Any] | None = None,
        operation: str = "query",
    ) -> QueryAnswer:
        """The kind's query: input arrays by name (e.g. `lsnif`: `origins`, `directions` (N, 3)), output
        arrays by name (`answer["hit"]`) and `answer.meta`. Concurrent queries are batched by the server.
        `operation` names another operation of the kind that answers arrays (`/v1/models` lists them)."""
        ident, body = self.artifact_id(artifact), json_value(params or {})
        return self.retry.call(lambda: self.inference.query(ident, body, arrays or {}, operation=operation))

    def generate(self, artifact: ArtifactRef, params: dict[str, Any] | None = None) -> QueryAnswer:
        """The kind's `generate` (`mesogan`: the feature plane of a window of its infinite texture,
        `answer["plane"]` (H, W, C) with `answer.meta["texel"]`, from `params` `origin` and `size` in texels,
        `structure` and `seed`): windows of one seed agree on their overlap, so they tile."""
        return self.query(artifact, None, params, operation="generate")

    def render(
        self,
        artifact: ArtifactRef,
        camera: Mapping[str, Any] | None = None,
        params: dict[str, Any] | None = None,
        *,
        arrays: Mapping[str, ArrayLike] | None = None,
        image_format: str = "exr",
    ) -> RenderedImage:
        """An image of the artifact. `camera` (position, target, up, fov, width, height; for kinds that
        render a view) travels as `params["camera"]`; `arrays` are the kind's inputs, if it takes any
        (`prt`: an uploaded lat-long `environment` (H, W, 3); `mesogan`: an uploaded `mesh` (triangles, 3,
        8) of position, normal and UV per corner); `image_format` is `exr` (linear float32,
        `image.pixels()`) or `png` (sRGB)."""
        if image_format not in IMAGE_FORMATS:
            raise ValueError(f"image_format {image_format!r}: use {' or '.join(IMAGE_FORMATS)}")
        body = json_value({**(params or {}), **({"camera": camera} if camera is not None else {})})
        ident, media_type = self.artifact_id(artifact), IMAGE_FORMATS[image_format]
        return self.retry.call(lambda: self.inference.render(ident, body, arrays or {}, media_type))
