"""The REST transport (httpx): JSON bodies, problem+json errors, Server-Sent Events, ranged downloads."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any, BinaryIO

import httpx

from neuralbake_client.errors import ApiError, ConnectionFailed, api_error
from neuralbake_client.models import (
    Asset,
    CreatedToken,
    Job,
    JobEvent,
    JobList,
    KindInfo,
    Manifest,
    QuotaLimits,
    SceneInfo,
    TenantQuotas,
    Token,
)

STREAM_READ_TIMEOUT_S = 60.0  # the server sends a keep-alive comment every 15 s


def problem_error(response: httpx.Response) -> ApiError:
    try:
        body = response.json()
    except ValueError:
        body = {}
    if not isinstance(body, dict):
        body = {}
    detail = body.pop("detail", None) or response.text or response.reason_phrase
    title = body.pop("title", None) or response.reason_phrase
    field = body.pop("field", None)
    body.pop("status", None)
    if "Retry-After" in response.headers:
        body["retry_after"] = response.headers["Retry-After"]
    return api_error(response.status_code, title, str(detail), field, **body)


class HttpTransport:
    def __init__(self, url: str, token: str | None, timeout: float, http: httpx.Client | None = None):
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.http = http or httpx.Client(base_url=url.rstrip("/"), headers=headers, timeout=timeout)

    def close(self) -> None:
        self.http.close()

    # ------------------------------------------------------------------ plumbing

    def send(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        try:
            response = self.http.request(method, path, **kwargs)
        except httpx.TransportError as error:
            raise ConnectionFailed(f"{self.http.base_url}: {error}") from error
        if response.status_code >= 400:
            raise problem_error(response)
        return response

    # ------------------------------------------------------------------ assets

    def upload(self, parts: list[tuple[str, BinaryIO]]) -> Asset:
        for _, stream in parts:
            stream.seek(0)  # a retried upload starts again from the top
        files = [("files", (name, stream, "application/octet-stream")) for name, stream in parts]
        return Asset.model_validate(self.send("POST", "/v1/assets", files=files).json())

    def get_asset(self, asset_id: str) -> Asset:
        return Asset.model_validate(self.send("GET", f"/v1/assets/{asset_id}").json())

    # ------------------------------------------------------------------ jobs

    def submit(self, body: dict[str, Any], idempotency_key: str) -> Job:
        response = self.send("POST", "/v1/jobs", json=body, headers={"Idempotency-Key": idempotency_key})
        job = Job.model_validate(response.json())
        job._reused = response.status_code == 200  # 201: created
        return job

    def submit_many(self, bodies: list[dict[str, Any]], idempotency_key: str) -> list[Job]:
        headers = {"Idempotency-Key": idempotency_key}
        answer = self.send("POST", "/v1/jobs:batch", json={"jobs": bodies}, headers=headers).json()
        jobs = []
        for item in answer["items"]:
            job = Job.model_validate(item["job"])
            job._reused = not item["created"]
            jobs.append(job)
        return jobs

    def get_job(self, job_id: str) -> Job:
        return Job.model_validate(self.send("GET", f"/v1/jobs/{job_id}").json())

    def list_jobs(self, states: list[str], kind: str | None, cursor: str | None, limit: int) -> JobList:
        params: dict[str, Any] = {"state": states, "limit": limit}
        params |= {k: v for k, v in (("kind", kind), ("cursor", cursor)) if v}
        return JobList.model_validate(self.send("GET", "/v1/jobs", params=params).json())

    def cancel(self, job_id: str) -> Job:
        return Job.model_validate(self.send("POST", f"/v1/jobs/{job_id}:cancel").json())

    def events(self, job_id: str, after: int) -> Iterator[JobEvent]:
        """Server-Sent Events after `after` until the server ends the stream (after the final state)."""
        timeout = httpx.Timeout(self.http.timeout.connect, read=STREAM_READ_TIMEOUT_S)
        headers = {"Last-Event-ID": str(after), "Accept": "text/event-stream"}
        try:
            with self.http.stream(
                "GET", f"/v1/jobs/{job_id}/events", headers=headers, timeout=timeout
            ) as response:
                if response.status_code >= 400:
                    response.read()
                    raise problem_error(response)
                data: list[str] = []
                for line in response.iter_lines():
                    if line == "":
                        if data:
                            yield JobEvent.model_validate(json.loads("\n".join(data)))
                        data = []
                    elif line.startswith("data:"):
                        data.append(line[5:].removeprefix(" "))
        except httpx.TransportError as error:
            raise ConnectionFailed(f"{self.http.base_url}: {error}") from error

    # ------------------------------------------------------------------ artifacts

    def manifest(self, artifact_id: str) -> Manifest:
        return Manifest.model_validate(self.send("GET", f"/v1/artifacts/{artifact_id}").json())

    def read_file(self, artifact_id: str, name: str, digest: str, offset: int) -> Iterator[bytes]:
        """The file's bytes from `offset` (a Range request, valid only while the digest matches)."""
        headers = {"Range": f"bytes={offset}-", "If-Range": f'"{digest}"'} if offset else {}
        try:
            with self.http.stream("GET", f"/v1/artifacts/{artifact_id}/files/{name}", headers=headers) as r:
                if r.status_code >= 400:
                    r.read()
                    raise problem_error(r)
                skip = offset if r.status_code == 200 else 0  # the server sent the whole file after all
                for chunk in r.iter_bytes():
                    if skip:
                        dropped = min(skip, len(chunk))
                        chunk, skip = chunk[dropped:], skip - dropped
                    if chunk:
                        yield chunk
        except httpx.TransportError as error:
            raise ConnectionFailed(f"{self.http.base_url}: {error}") from error

    # ------------------------------------------------------------------ tokens (admin)

    def create_token(self, tenant: str, scope: str, name: str) -> CreatedToken:
        body = {"tenant": tenant, "scope": scope, "name": name}
        return CreatedToken.model_validate(self.send("POST", "/v1/tokens", json=body).json())

    def list_kinds(self) -> list[KindInfo]:
        return [KindInfo.model_validate(item) for item in self.send("GET", "/v1/kinds").json()["items"]]

    def get_kind(self, name: str) -> KindInfo:
        return KindInfo.model_validate(self.send("GET", f"/v1/kinds/{name}").json())

    def list_scenes(self) -> list[SceneInfo]:
        return [SceneInfo.model_validate(item) for item in self.send("GET", "/v1/scenes").json()["items"]]

    def list_tokens(self) -> list[Token]:
        return [Token.model_validate(item) for item in self.send("GET", "/v1/tokens").json()["items"]]

    def revoke_token(self, token_id: str) -> None:
        self.send("DELETE", f"/v1/tokens/{token_id}")

    def get_quotas(self, tenant: str) -> TenantQuotas:
        return TenantQuotas.model_validate(self.send("GET", f"/v1/tenants/{tenant}/quotas").json())

    def set_quotas(self, tenant: str, limits: QuotaLimits) -> TenantQuotas:
        body = limits.model_dump()
        return TenantQuotas.model_validate(self.send("PUT", f"/v1/tenants/{tenant}/quotas", json=body).json())
