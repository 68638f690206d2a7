"""`AsyncClient`: the same operations for asyncio code. Each call runs the synchronous client in a
worker thread (one implementation of retries, resumption and checksums, not two), so the event loop
never blocks; event streams are async iterators.
"""

from __future__ import annotations

import asyncio
import inspect
import os
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from typing import TYPE_CHECKING, Any

from neuralbake_client.client import ArtifactRef, Client, JobRef, SceneRef
from neuralbake_client.download import DownloadedFile
from neuralbake_client.models import Asset, Job, JobEvent, JobList, Manifest, ModelInfo, Progress
from neuralbake_client.retry import DEFAULT_RETRY, Retry

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from neuralbake_client.answers import QueryAnswer, RenderedImage

_END = object()


class AsyncClient:
    """`async with AsyncClient(url, token) as client: job = await client.submit(...)`."""

    def __init__(
        self,
        url: str,
        token: str | None = None,
        *,
        inference_url: str | None = None,
        timeout: float = 30.0,
        retry: Retry = DEFAULT_RETRY,
    ):
        self.sync = Client(url, token, inference_url=inference_url, timeout=timeout, retry=retry)

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def close(self) -> None:
        await asyncio.to_thread(self.sync.close)

    async def upload(self, path: str | os.PathLike) -> Asset:
        return await asyncio.to_thread(self.sync.upload, path)

    async def get_asset(self, asset_id: str) -> Asset:
        return await asyncio.to_thread(self.sync.get_asset, asset_id)

    async def submit(self, kind: str, scene: SceneRef, **options: Any) -> Job:
        return await asyncio.to_thread(self.sync.submit, kind, scene, **options)

    async def submit_many(self, jobs: list[dict[str, Any]]) -> list[Job]:
        return await asyncio.to_thread(self.sync.submit_many, jobs)

    async def get(self, job: JobRef) -> Job:
        return await asyncio.to_thread(self.sync.get, job)

    async def list(self, state=None, kind: str | None = None, **options: Any) -> JobList:
        return await asyncio.to_thread(self.sync.list, state, kind, **options)

    async def cancel(self, job: JobRef) -> Job:
        return await asyncio.to_thread(self.sync.cancel, job)

    async def events(self, job: JobRef, after: int = 0) -> AsyncIterator[JobEvent]:
        stream = self.sync.events(job, after)
        try:
            while (event := await asyncio.to_thread(next, stream, _END)) is not _END:
                yield event
        finally:
            stream.close()

    async def wait(
        self,
        job: JobRef,
        on_progress: Callable[[Progress], Awaitable[None] | None] | None = None,
        *,
        on_event: Callable[[JobEvent], Awaitable[None] | None] | None = None,
    ) -> Job:
        """Like `Client.wait`; the callbacks may be plain functions or coroutines."""
        async for event in self.events(job):
            for callback, value in ((on_event, event), (on_progress, event.progress)):
                if callback is not None and value is not None:
                    result = callback(value)
                    if inspect.isawaitable(result):
                        await result
        return await self.get(job)

    async def manifest(self, artifact: ArtifactRef) -> Manifest:
        return await asyncio.to_thread(self.sync.manifest, artifact)

    async def download(
        self, artifact: ArtifactRef, dest: str | os.PathLike, names: list[str] | None = None
    ) -> list[DownloadedFile]:
        return await asyncio.to_thread(self.sync.download, artifact, dest, names)

    async def models(self) -> list[ModelInfo]:
        return await asyncio.to_thread(self.sync.models)

    async def load(self, artifact: ArtifactRef) -> ModelInfo:
        return await asyncio.to_thread(self.sync.load, artifact)

    async def query(
        self,
        artifact: ArtifactRef,
        arrays: Mapping[str, ArrayLike] | None = None,
        params: dict[str, Any] | None = None,
    ) -> QueryAnswer:
        return await asyncio.to_thread(self.sync.query, artifact, arrays, params)

    async def generate(self, artifact: ArtifactRef, params: dict[str, Any] | None = None) -> QueryAnswer:
        return await asyncio.to_thread(self.sync.generate, artifact, params)

    async def render(
        self, artifact: ArtifactRef, camera: Mapping[str, Any] | None = None, params=None, **options: Any
    ) -> RenderedImage:
        return await asyncio.to_thread(self.sync.render, artifact, camera, params, **options)
