"""Property-based requests generated from the server's own OpenAPI document (schemathesis strategies,
driven by hypothesis): whatever they send, the server answers without a 5xx, and every error is
problem+json. The server runs without a scheduler, so generated jobs (some legitimately huge) stay
queued instead of burning the CPUs."""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings

from tests.integration.test_api_server import TOKENS, DatabaseChoice, ServerThread, settings_for

HEADERS = {"Authorization": f"Bearer {TOKENS['admin']}"}
EXAMPLES_PER_OPERATION = 25


@pytest.fixture(scope="module")
def api_only(ray_cluster, tmp_path_factory):
    data_dir = tmp_path_factory.mktemp("schemathesis")
    with ServerThread(settings_for(data_dir, DatabaseChoice("sqlite", None), scheduling=False)) as running:
        yield running


def test_generated_requests_never_get_a_server_error(api_only):
    schema = schemathesis.openapi.from_url(f"{api_only.url}/openapi.json")
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 11
    for operation in operations:

        @given(case=operation.as_strategy())
        @settings(
            max_examples=EXAMPLES_PER_OPERATION,
            deadline=None,
            database=None,
            suppress_health_check=list(HealthCheck),
        )
        def no_server_error(case):
            # Generated job ids never name a job, so the SSE route answers 404 at once instead of streaming.
            response = case.call(base_url=api_only.url, headers=HEADERS, timeout=30)
            where = f"{case.method} {case.formatted_path}"
            assert response.status_code < 500, f"{where}: {response.status_code} {response.text}"
            if response.status_code >= 400:
                assert response.headers["content-type"] == ["application/problem+json"], where

        no_server_error()
