"""Property-based requests from the inference service's own OpenAPI document (schemathesis strategies,
driven by hypothesis), against a real `nbake serve-inference` holding one small render artifact: whatever
they send, it answers without a 5xx, and every error is problem+json. Half the cases name the real
artifact, so the generated bodies reach the operations instead of stopping at a 404."""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from tests.integration.test_api_server import TOKENS
from tests.integration.test_inference_server import install_tokens, run_and_publish, start_server
from workers.scene.generators.builtin import BUILTIN_SCENES

HEADERS = {"Authorization": f"Bearer {TOKENS['read']}"}
EXAMPLES_PER_OPERATION = 25


@pytest.fixture(scope="module")
def inference(tmp_path_factory):
    data_dir = tmp_path_factory.mktemp("inference-schemathesis")
    store = ArtifactStore(BlobStore(str(data_dir / "store")), str(data_dir / "store"))
    overrides = {"samplers": 0, "width": 16, "height": 12, "spp": 2}
    artifact = run_and_publish(
        store, tmp_path_factory.mktemp("jobs"), "render", BUILTIN_SCENES["cornell_box"](), overrides, seed=1
    )
    install_tokens(data_dir)
    running = start_server(data_dir, ["--max-rows", "4096"], artifact)
    try:
        yield running, artifact.artifact_id
    finally:
        running.stop()


@pytest.mark.slow  # a render job, a server and ~100 generated requests: minutes on the shared machine
def test_generated_requests_never_get_a_server_error(inference):
    server, artifact_id = inference
    schema = schemathesis.openapi.from_url(f"{server.url}/openapi.json")
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 4
    for operation in operations:

        @given(case=operation.as_strategy(), real=...)
        @settings(
            max_examples=EXAMPLES_PER_OPERATION,
            deadline=None,
            database=None,
            suppress_health_check=list(HealthCheck),
        )
        def no_server_error(case, real: bool):
            if real and case.path_parameters and "artifact_id" in case.path_parameters:
                case.path_parameters["artifact_id"] = artifact_id
            response = case.call(base_url=server.url, headers=HEADERS, timeout=60)
            where = f"{case.method} {case.formatted_path}"
            assert response.status_code < 500, f"{where}: {response.status_code} {response.text[:500]}"
            if response.status_code >= 400:
                assert response.headers["content-type"] == ["application/problem+json"], where

        no_server_error()
