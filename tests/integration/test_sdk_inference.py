"""Trained artifacts from the SDK and from `nbake query` / `nbake render`, against a real
`nbake serve --inference-port` (the job server starts the inference service as its own process): a tiny
render job's artifact is loaded, listed, queried and rendered over REST and gRPC, and the answers equal
the artifact's files as downloaded. Errors arrive as the same typed exceptions and exit statuses as the
job commands'."""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np
import pytest
from neuralbake_client import AsyncClient, Client, ConnectionFailed, InvalidRequest, Job, NotFound, Retry
from PIL import Image

from tests.integration.test_api_server import NBAKE, TOKENS, TOKENS_ENV
from tests.integration.test_grpc_server import TINY, Served
from tests.support.ports import free_port
from workers.scene.importers.image_io import read_exr

START_TIMEOUT_S = 180


@dataclass
class WithInference:
    served: Served
    inference_url: str
    inference_grpc_url: str
    job: Job  # a succeeded tiny render
    stored: np.ndarray  # its image.exr as downloaded

    def urls(self, transport: str) -> tuple[str, str]:
        if transport == "rest":
            return self.served.url, self.inference_url
        return self.served.grpc_url, self.inference_grpc_url


def wait_ready(process: subprocess.Popen, log: Path, *urls: str) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    for url in urls:
        while True:
            if process.poll() is not None:
                raise RuntimeError(f"nbake serve exited: {log.read_text()[-3000:]}")
            try:
                if httpx.get(f"{url}/readyz", timeout=5).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError(f"{url} did not become ready: {log.read_text()[-3000:]}")
            time.sleep(0.5)


@pytest.fixture(scope="module")
def server(tmp_path_factory) -> Iterator[WithInference]:
    data_dir = tmp_path_factory.mktemp("with-inference")
    ports = [free_port() for _ in range(4)]
    command = [NBAKE, "serve", "--port", str(ports[0]), "--grpc-port", str(ports[1])]
    command += ["--inference-port", str(ports[2]), "--inference-grpc-port", str(ports[3])]
    command += ["--data-dir", str(data_dir), "--log-level", "warning"]
    env = os.environ | {"NBAKE_TOKENS": TOKENS_ENV, "NBAKE_MAX_RUNNING": "1", "NBAKE_INFERENCE_DEVICE": "cpu"}
    env.pop("RAY_ADDRESS", None)
    log = data_dir / "serve.log"
    with log.open("wb") as sink:
        process = subprocess.Popen(
            command, stdout=sink, stderr=subprocess.STDOUT, env=env, start_new_session=True
        )
    served = Served(process, f"http://127.0.0.1:{ports[0]}", f"127.0.0.1:{ports[1]}", data_dir)
    try:
        inference_url = f"http://127.0.0.1:{ports[2]}"
        wait_ready(process, log, served.url, inference_url)
        with Client(served.url, TOKENS["admin"]) as sdk:
            job = sdk.wait(sdk.submit("render", "cornell_box", preset="quick", config=TINY))
            assert job.artifact_id, job.error
            (image,) = sdk.download(job, data_dir / "downloaded", ["image.exr"])
        yield WithInference(served, inference_url, f"grpc://127.0.0.1:{ports[3]}", job, read_exr(image.path))
    finally:
        served.stop()  # SIGTERM: `nbake serve` stops its inference process too


@pytest.fixture(params=["rest", "grpc"])
def client(request, server) -> Iterator[Client]:
    url, inference_url = server.urls(request.param)
    with Client(url, TOKENS["read"], inference_url=inference_url) as sdk:
        yield sdk


# ---------------------------------------------------------------------------------------------- SDK


def test_load_models_query_and_render(client, server):
    artifact = server.job.artifact_id
    loaded = client.load(artifact)
    assert loaded.artifact_id == artifact and loaded.kind == "render"
    assert set(loaded.operations) == {"query", "render"} and loaded.bytes > 0
    assert artifact in [m.artifact_id for m in client.models()]

    pixels = np.array([[0, 0], [31, 31], [10, 5]], np.int64)
    answer = client.query(server.job, {"pixels": pixels}, {"layers": ["image", "depth"]})
    assert (
        answer.artifact_id == artifact
        and answer.kind == "render"
        and set(answer.arrays) == {"image", "depth"}
    )
    np.testing.assert_array_equal(answer["image"], server.stored[pixels[:, 1], pixels[:, 0]])
    assert answer["depth"].shape == (3, 1) and answer["depth"].dtype == np.float32
    whole = client.query(artifact, params={"layers": ["albedo"]})
    assert whole["albedo"].shape == (32, 32, 3)

    image = client.render(artifact)
    assert image.media_type == "image/x-exr" and image.frame_time_s is not None and image.frame_time_s >= 0
    np.testing.assert_array_equal(image.pixels(), server.stored)
    own_view = client.render(artifact, camera={"position": [0, 1, 4.0], "width": 32, "height": 32})
    np.testing.assert_array_equal(own_view.pixels(), server.stored)  # a render artifact has one view
    png = client.render(artifact, params={"layer": "albedo"}, image_format="png")
    assert png.media_type == "image/png" and png.data.startswith(b"\x89PNG")


def test_inference_errors_are_typed(client, server):
    artifact = server.job.artifact_id
    with pytest.raises(InvalidRequest) as unknown_layer:
        client.render(artifact, params={"layer": "nope"})
    assert unknown_layer.value.status == 422 and "albedo" in unknown_layer.value.detail
    camera = {"position": np.array([0, 1, 4.0]), "target": [0, 1, 0], "fov": 40, "width": 8, "height": 8}
    with pytest.raises(InvalidRequest) as other_size:  # the camera travels as params.camera
        client.render(artifact, camera=camera)
    assert other_size.value.field == "params.camera.width"
    with pytest.raises(
        InvalidRequest
    ) as no_arrays:  # arrays travel with a render (prt's map, mesogan's mesh)
        client.render(artifact, arrays={"environment": np.ones((4, 8, 3), np.float32)})
    assert no_arrays.value.field == "arrays.environment" and "no arrays" in no_arrays.value.detail
    with pytest.raises(InvalidRequest) as bad_shape:
        client.query(artifact, {"pixels": np.zeros((4, 3), np.int64)})
    assert bad_shape.value.field == "arrays.pixels"
    with pytest.raises(NotFound):
        client.query("sha256:" + "0" * 64, {})


def test_async_client_and_an_unreachable_inference_service(server):
    async def run():
        url, inference_url = server.urls("grpc")
        async with AsyncClient(url, TOKENS["read"], inference_url=inference_url) as sdk:
            models, answer, image = await asyncio.gather(
                sdk.models(),
                sdk.query(server.job, {"pixels": [[1, 2]]}),
                sdk.render(server.job, image_format="png"),
            )
        return models, answer, image

    models, answer, image = asyncio.run(run())
    assert models and answer["image"].shape == (1, 3) and image.data.startswith(b"\x89PNG")
    nowhere = f"http://127.0.0.1:{free_port()}"
    retry = Retry(attempts=2, backoff_s=0.05)
    with Client(server.served.url, TOKENS["read"], inference_url=nowhere, retry=retry) as sdk:
        with pytest.raises(ConnectionFailed):
            sdk.models()
        assert sdk.get(server.job).state == "SUCCEEDED"  # the job server is still there


# ---------------------------------------------------------------------------------------------- CLI


def nbake(env: dict, *args: str | Path) -> subprocess.CompletedProcess:
    return subprocess.run([NBAKE, *map(str, args)], capture_output=True, text=True, timeout=180, env=env)


@pytest.fixture(params=["rest", "grpc"])
def env(request, server, tmp_path) -> dict:
    url, inference_url = server.urls(request.param)
    clean = {k: v for k, v in os.environ.items() if not k.startswith("NBAKE_")}
    return clean | {
        "NBAKE_URL": url,
        "NBAKE_TOKEN": TOKENS["read"],
        "NBAKE_INFERENCE_URL": inference_url,
        "NBAKE_CONFIG": str(tmp_path / "none.toml"),
    }


def test_nbake_query_reads_npy_and_writes_npz(env, server, tmp_path):
    pixels = np.array([[0, 0], [31, 31]], np.int64)
    np.save(tmp_path / "pixels.npy", pixels)
    out = tmp_path / "answer.npz"
    done = nbake(
        env, "query", server.job.id, "-i", tmp_path / "pixels.npy", "--set", "layers=[image]", "-o", out
    )
    assert done.returncode == 0, done.stderr
    (line,) = [json.loads(text) for text in done.stdout.splitlines()]
    assert line["event"] == "answer" and line["artifact_id"] == server.job.artifact_id
    assert line["arrays"] == {"image": {"dtype": "float32", "shape": [2, 3]}}
    with np.load(out) as answer:
        np.testing.assert_array_equal(answer["image"], server.stored[pixels[:, 1], pixels[:, 0]])

    bad = nbake(
        env,
        "query",
        server.job.artifact_id,
        "-i",
        f"pixels={tmp_path / 'pixels.npy'}",
        "-o",
        out,
        "--set",
        "x=1",
    )
    assert bad.returncode == 2 and "params.x" in bad.stderr


def test_nbake_render_writes_exr_and_png(env, server, tmp_path):
    artifact = server.job.artifact_id
    done = nbake(env, "render", artifact, "-o", tmp_path / "image.exr")
    assert done.returncode == 0, done.stderr
    (line,) = [json.loads(text) for text in done.stdout.splitlines()]
    assert line["event"] == "rendered" and line["media_type"] == "image/x-exr"
    np.testing.assert_array_equal(read_exr(tmp_path / "image.exr"), server.stored)
    png = nbake(env, "render", "-o", tmp_path / "albedo.png", artifact, "--set", "layer=albedo")
    assert png.returncode == 0, png.stderr
    with Image.open(tmp_path / "albedo.png") as opened:
        assert opened.size == (32, 32)

    assert line["frame_time_ms"] >= 0
    camera = nbake(env, "render", artifact, "--camera", "{position: [0, 1, 4]}", "-o", tmp_path / "v.png")
    assert camera.returncode == 0, camera.stderr
    resized = nbake(env, "render", artifact, "--camera", "{width: 8, height: 8}", "-o", tmp_path / "v.png")
    assert resized.returncode == 2 and "params.camera.width" in resized.stderr
    np.save(tmp_path / "environment.npy", np.ones((4, 8, 3), np.float32))
    upload = nbake(env, "render", artifact, "-i", tmp_path / "environment.npy", "-o", tmp_path / "u.exr")
    assert upload.returncode == 2 and "arrays.environment" in upload.stderr  # sent; a render takes none
    unreachable = env | {"NBAKE_INFERENCE_URL": f"http://127.0.0.1:{free_port()}"}
    assert nbake(unreachable, "render", artifact, "-o", tmp_path / "x.exr").returncode == 4
