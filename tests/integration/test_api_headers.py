"""The headers of the job API's responses: every one carries the baseline security headers (JSON, problem
documents, `/docs`, file downloads), the dashboard keeps its own stricter policy, and a tenant's files may
be kept by the browser that fetched them but never by a shared cache."""

from __future__ import annotations

import httpx
import pytest

from tests.integration import test_api_server as api
from tests.integration.test_api_server import QUICK_RENDER, submit

server, client = api.server, api.client  # fixtures


@pytest.fixture(scope="module")
def database():
    """Headers do not depend on the database: SQLite only."""
    return api.DatabaseChoice("sqlite", None)


def assert_security_headers(response: httpx.Response) -> None:
    """nosniff, no Referer, and a policy that forbids framing (data responses: that loads nothing at all)."""
    assert response.headers["x-content-type-options"] == "nosniff", response.url
    assert response.headers["referrer-policy"] == "no-referrer", response.url
    policy = response.headers["content-security-policy"]
    assert "frame-ancestors 'none'" in policy, response.url
    if response.headers["content-type"].startswith(("application/json", "application/problem+json")):
        assert policy.startswith("default-src 'none'"), response.url


def test_json_problem_and_docs_responses_carry_the_security_headers(server, client):
    for response in (
        client.get("/v1/jobs"),
        client.get("/v1/jobs/no-such-job"),  # a problem document
        client.post("/v1/jobs", json={"kind": "nerf"}),
        httpx.get(f"{server.url}/openapi.json"),
        httpx.get(f"{server.url}/docs"),
        httpx.get(f"{server.url}/healthz"),
    ):
        assert_security_headers(response)
    assert "text/html" in httpx.get(f"{server.url}/docs").headers["content-type"]


def test_the_dashboard_keeps_its_own_policy(server):
    page = httpx.get(f"{server.url}/ui/")
    assert page.status_code == 200
    assert "script-src 'self'" in page.headers["content-security-policy"]
    assert page.headers["x-content-type-options"] == "nosniff"


def test_artifact_files_are_private_to_the_browser_that_fetched_them(client):
    job = submit(client, **{**QUICK_RENDER, "config": {"spp": 1}}, force=True)
    job = api.wait_for(client, job["id"], {"SUCCEEDED"})
    for response in (
        client.get(f"/v1/artifacts/{job['artifact_id']}/files/image.exr"),
        client.get(f"/v1/artifacts/{job['artifact_id']}/files/image.exr", headers={"Range": "bytes=0-9"}),
    ):
        assert response.status_code in (200, 206)
        cache = [part.strip() for part in response.headers["cache-control"].split(",")]
        assert "private" in cache and "public" not in cache
        assert_security_headers(response)
