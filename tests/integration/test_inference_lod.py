"""A `lod` artifact served by `nbake serve-inference`: first scattering events of rays at a chosen LoD and
the voxels' prefiltered throughput, equal to the kind's in-process `infer`; requests with and without
the optional `incident` input arriving together are answered separately, each correctly."""

from __future__ import annotations

from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from services.inference.wire import decode_binary
from tests.integration.test_inference_server import (
    Server,
    binary_query,
    install_tokens,
    run_and_publish,
    start_server,
)
from workers.models.lod.infer import LodQuery
from workers.scene.builtin import get_builtin


@pytest.fixture(scope="module")
def server(tmp_path_factory) -> Iterator[Server]:
    data_dir = tmp_path_factory.mktemp("inference-lod")
    store = ArtifactStore(BlobStore(str(data_dir / "store")), str(data_dir / "store"))
    scene = get_builtin("menger_sponge")
    scene = scene.model_copy(update={"camera": scene.camera.model_copy(update={"width": 32, "height": 32})})
    lod = run_and_publish(
        store, tmp_path_factory.mktemp("jobs"), "lod", scene, {"samplers": 0, "train": {"steps": 20}}, seed=5
    )
    install_tokens(data_dir)
    running = start_server(data_dir, ["--max-wait-ms", "50"], lod)
    try:
        yield running
    finally:
        running.stop()


def rays(n: int, seed: int) -> dict[str, np.ndarray]:
    """Rays from around the sponge (centre (0, 0.5, 0), side 1) towards it, and incident directions."""
    rng = np.random.default_rng(seed)
    targets = np.array([0.0, 0.5, 0.0]) + rng.uniform(-0.6, 0.6, (n, 3))
    origins = targets + rng.normal(size=(n, 3)) * 3
    return {"origins": origins, "directions": targets - origins, "incident": rng.normal(size=(n, 3))}


def in_process(server: Server, arrays: dict, level: int) -> dict[str, np.ndarray]:
    model = server.lsnif.in_process()  # the fixture's only artifact sits in the first slot
    return model.answer("query", LodQuery(level=level), arrays).arrays


def test_lod_queries_equal_in_process_inference_at_every_level(server):
    arrays = rays(2000, seed=1)
    with server.client() as client:
        for level in range(3):
            reference = in_process(server, arrays, level)
            assert 0.2 < reference["hit"].mean() < 1.0
            response = binary_query(client, server.lsnif.artifact_id, arrays, {"level": level})
            assert response.status_code == 200, response.text
            answer = decode_binary(response.content)[1]
            assert set(answer) == {"hit", "distance", "voxel", "throughput"}
            for name, value in reference.items():
                np.testing.assert_array_equal(answer[name], value, err_msg=name)
            hit = answer["hit"]
            assert np.all(answer["voxel"][hit] >= 0) and np.all(answer["voxel"][~hit] == -1)
            assert np.all(answer["throughput"] >= 0) and np.all(answer["throughput"][~hit] == 0)
        response = binary_query(client, server.lsnif.artifact_id, arrays, {"level": 7})
        assert response.status_code == 422 and "params.level" in response.text


def test_requests_with_and_without_optional_inputs_are_not_merged(server):
    def ask(seed: int) -> tuple[dict, dict]:
        arrays = rays(300, seed)
        if seed % 2:
            del arrays["incident"]
        with server.client() as client:
            response = binary_query(client, server.lsnif.artifact_id, arrays, {"level": 1})
            assert response.status_code == 200, response.text
            return decode_binary(response.content)[1], in_process(server, arrays, 1)

    with ThreadPoolExecutor(8) as pool:
        for answer, reference in pool.map(ask, range(16)):
            assert set(answer) == set(reference)
            for name, value in reference.items():
                np.testing.assert_array_equal(answer[name], value, err_msg=name)
