"""A `mesogan` artifact as users reach it: `nbake serve-inference` in its own process serving an artifact
placed in its store by hand (untrained weights: the plumbing, not quality). `generate`, which
`/v1/models` lists, answers over REST (JSON and binary), gRPC and the SDK (both transports, and async),
equal to the kind's `infer` in this process; a window larger than the working budget is a 413 before it
runs, an operation the kind lacks a 400 naming those it has.
Tiled `query` windows agree with one large window between texel centres, through the service as a user
tiles them."""

from __future__ import annotations

import asyncio
import base64
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import grpc
import numpy as np
import pytest
import torch
from google.protobuf import struct_pb2
from neuralbake.v1 import inference_pb2, inference_pb2_grpc
from neuralbake_client import AsyncClient, Client

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from services.inference.wire import OCTET_STREAM, decode_binary, encode_binary
from tests.integration.test_api_server import NBAKE, TOKENS
from tests.integration.test_grpc_server import details, rpc_error
from tests.integration.test_inference_server import Server, install_tokens, start_server
from workers.models.mesogan import KIND, artifact
from workers.models.mesogan.networks import MesoGAN
from workers.models.registry import get_inference
from workers.scene.generators.builtin import get_builtin

WINDOW = {"origin": [-3, 5], "size": [12, 7], "seed": 4, "structure": {"length": 0.5}}
AUTH = (("authorization", f"Bearer {TOKENS['read']}"),)
WORKING_BYTES = 64 << 20  # a 192^2 window fits; quick's generator takes ~140 MB for 512^2


@pytest.fixture(scope="module")
def served(tmp_path_factory) -> Iterator[tuple[Server, str, Path]]:
    """The server, the artifact's id and its folder."""
    data_dir = tmp_path_factory.mktemp("mesogan-inference")
    folder = tmp_path_factory.mktemp("artifact")
    config = KIND.resolve_config("quick", {})
    torch.manual_seed(0)
    files = artifact.save(folder, config, MesoGAN(config), get_builtin("fur_ball"))
    store = ArtifactStore(BlobStore(str(data_dir / "store")), str(data_dir / "store"))
    manifest = store.publish(
        files, kind="mesogan", job_id="by-hand", scene_hash="", config={}, code_version="", metrics={}
    )
    install_tokens(data_dir)
    running = start_server(data_dir, ["--working-bytes", str(WORKING_BYTES)])
    try:
        yield running, manifest.artifact_id, folder
    finally:
        running.stop()


def in_process(folder: Path, operation: str, params: dict, arrays: dict | None = None):
    inference = get_inference("mesogan")
    typed = inference.operations[operation].params.model_validate(params)
    return inference.load(folder, "cpu").answer(operation, typed, arrays or {})


def test_generate_is_served_over_rest_grpc_and_the_sdk(served):
    server, artifact_id, folder = served
    expected = in_process(folder, "generate", WINDOW)
    plane = expected.arrays["plane"]
    assert plane.shape == (12, 7, KIND.resolve_config("quick", {}).plane_channels)

    with server.client() as client:
        loaded = client.post(f"/v1/models/{artifact_id}:load").json()
        assert loaded["operations"] == ["generate", "query", "render"]
        as_json = client.post(f"/v1/artifacts/{artifact_id}:generate", json={"params": WINDOW})
        assert as_json.status_code == 200, as_json.text
        body = as_json.json()
        assert body["kind"] == "mesogan" and body["meta"] == expected.meta
        encoded = body["arrays"]["plane"]
        decoded = np.frombuffer(base64.b64decode(encoded["data"]), encoded["dtype"]).reshape(encoded["shape"])
        np.testing.assert_array_equal(decoded, plane)
        binary = client.post(
            f"/v1/artifacts/{artifact_id}:generate",
            content=encode_binary({"params": WINDOW}, {}),
            headers={"Content-Type": OCTET_STREAM},
        )
        np.testing.assert_array_equal(decode_binary(binary.content)[1]["plane"], plane)

        empty = client.post(f"/v1/artifacts/{artifact_id}:generate", json={"params": {"size": [0, 4]}})
        assert empty.status_code == 422 and empty.json()["field"] == "params.size", empty.text
        # A window's memory follows its size: one beyond the working budget is refused before it runs.
        fits = client.post(f"/v1/artifacts/{artifact_id}:generate", json={"params": {"size": [192, 192]}})
        assert fits.status_code == 200, fits.text
        large = client.post(f"/v1/artifacts/{artifact_id}:generate", json={"params": {"size": [512, 512]}})
        assert large.status_code == 413 and large.json()["field"] == "params", large.text
        assert f"budget is {WORKING_BYTES:,} bytes" in large.json()["detail"], large.text
        unknown = client.post(f"/v1/artifacts/{artifact_id}:grow", json={})
        problem = unknown.json()
        assert unknown.status_code == 400 and unknown.headers["content-type"] == "application/problem+json"
        assert "does not support grow (it supports: generate, query, render)" in problem["detail"], problem

    with grpc.insecure_channel(server.grpc_target) as channel:
        stub = inference_pb2_grpc.InferenceServiceStub(channel)
        params = struct_pb2.Struct()
        params.update(WINDOW)
        request = inference_pb2.QueryRequest(artifact_id=artifact_id, params=params, operation="generate")
        (array,) = stub.Query(request, metadata=AUTH, timeout=60).arrays
        answer = np.frombuffer(array.data, array.dtype).reshape(tuple(array.shape))
        np.testing.assert_array_equal(answer, plane)
        request.operation = "render"
        refused = rpc_error(stub.Query, request, metadata=AUTH, timeout=60)
        assert (
            refused.code() == grpc.StatusCode.INVALID_ARGUMENT
            and details(refused)["violation"] == "operation"
        )

    for url in (server.url, f"grpc://{server.grpc_target}"):
        with Client(url, TOKENS["read"], inference_url=url) as sdk:
            generated = sdk.generate(artifact_id, WINDOW)
            assert generated.kind == "mesogan" and generated.meta == expected.meta, url
            np.testing.assert_array_equal(generated["plane"], plane, err_msg=url)

    async def generate_async():
        async with AsyncClient(server.url, TOKENS["read"], inference_url=server.url) as sdk:
            return await sdk.generate(artifact_id, WINDOW)

    np.testing.assert_array_equal(asyncio.run(generate_async())["plane"], plane)


def test_tiled_queries_through_the_service_agree_with_one_large_query(served):
    server, artifact_id, _ = served
    texel = KIND.resolve_config("quick", {}).texel
    # Two windows side by side (x in [-8, 0) and [0, 8) texels) and one over both; points every 1/8 texel
    # across their common border, on three rows.
    x, y = np.meshgrid(np.arange(-24, 24) / 8 * texel, np.array([-1.3, 0.2, 2.9]) * texel, indexing="ij")
    points = np.stack([x.ravel(), y.ravel(), np.full(x.size, 0.6)], -1).astype(np.float32)
    right = points[:, 0] >= 0
    with Client(server.url, TOKENS["read"], inference_url=server.url) as sdk:

        def density(window: list[int], mine: np.ndarray) -> np.ndarray:
            params = {"window": window, "seed": 2}
            return sdk.query(artifact_id, {"points": points[mine]}, params)["density"]

        whole = density([-8, -4, 16, 8], np.ones(len(points), bool))
        tiled = np.empty_like(whole)
        tiled[~right], tiled[right] = density([-8, -4, 8, 8], ~right), density([0, -4, 8, 8], right)
    assert np.ptp(whole) > 0.05
    np.testing.assert_allclose(tiled, whole, rtol=0, atol=1e-5 * np.ptp(whole))


def test_generate_from_the_command_line(served, tmp_path):
    server, artifact_id, folder = served
    out = tmp_path / "plane.npz"
    window = ["origin=[-3,5]", "size=[12,7]", "seed=4", "structure.length=0.5"]
    done = subprocess.run(
        [NBAKE, "query", artifact_id, "--operation", "generate", "-o", str(out)]
        + [arg for item in window for arg in ("--set", item)]
        + ["--inference-url", server.url, "--token", TOKENS["read"]],
        capture_output=True,
        text=True,
        timeout=120,
        env={k: v for k, v in os.environ.items() if not k.startswith("NBAKE_")},
    )
    assert done.returncode == 0, done.stderr
    expected = in_process(folder, "generate", WINDOW).arrays["plane"]
    np.testing.assert_array_equal(np.load(out)["plane"], expected)
