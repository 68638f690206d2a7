"""The inference service killed (SIGKILL) while clients are querying it, then restarted on the same ports:
SDK clients with retries get every answer, and every answer is right (the stored image's pixels)."""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from neuralbake_client import Client
from neuralbake_client.retry import Retry

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from tests.integration.test_api_server import NBAKE, TOKENS
from tests.integration.test_inference_server import install_tokens, run_and_publish
from tests.support.ports import free_port
from workers.scene.generators.builtin import BUILTIN_SCENES
from workers.scene.importers.image_io import read_exr

CLIENTS = 4
RETRY = Retry(attempts=60, backoff_s=0.25, max_backoff_s=1.0)  # rides out a restart of some seconds


def start(data_dir: Path, http_port: int, grpc_port: int) -> subprocess.Popen:
    command = [NBAKE, "serve-inference", "--port", str(http_port), "--grpc-port", str(grpc_port)]
    command += ["--data-dir", str(data_dir), "--device", "cpu", "--log-level", "warning"]
    process = subprocess.Popen(command, start_new_session=True)
    deadline = time.monotonic() + 300
    while True:
        try:
            if httpx.get(f"http://127.0.0.1:{http_port}/readyz", timeout=5).status_code == 200:
                return process
        except httpx.TransportError:
            pass
        assert process.poll() is None and time.monotonic() < deadline, "serve-inference did not start"
        time.sleep(0.2)


@pytest.mark.slow  # a render job, then the service started twice: a few minutes on the shared machine
def test_clients_with_retries_get_right_answers_across_a_killed_service(tmp_path):
    store = ArtifactStore(BlobStore(str(tmp_path / "store")), str(tmp_path / "store"))
    overrides = {"samplers": 0, "width": 16, "height": 12, "spp": 2}
    artifact = run_and_publish(
        store, tmp_path / "jobs", "render", BUILTIN_SCENES["cornell_box"](), overrides, 1
    )
    stored = read_exr(artifact.folder / "image.exr")
    install_tokens(tmp_path)
    ports = free_port(), free_port()
    url = f"http://127.0.0.1:{ports[0]}"
    process = start(tmp_path, *ports)
    answers, failures, stop = [], [], threading.Event()

    def client_loop(number: int) -> None:
        rng = np.random.default_rng(number)
        with Client("http://127.0.0.1:9", TOKENS["read"], inference_url=url, retry=RETRY) as sdk:
            while not stop.is_set():
                pixels = np.stack([rng.integers(0, 16, 8), rng.integers(0, 12, 8)], axis=1)
                try:
                    answer = sdk.query(artifact.artifact_id, {"pixels": pixels}, {"layers": ["image"]})
                except Exception as error:  # recorded: the test fails on any
                    failures.append(repr(error))
                    return
                answers.append(np.array_equal(answer["image"], stored[pixels[:, 1], pixels[:, 0]]))

    threads = [threading.Thread(target=client_loop, args=(n,)) for n in range(CLIENTS)]
    try:
        for thread in threads:
            thread.start()
        while len(answers) < 20 and not failures:
            time.sleep(0.1)
        before = len(answers)
        os.killpg(process.pid, signal.SIGKILL)  # the group this test started: the service, mid-request
        process.wait()
        process = start(tmp_path, *ports)
        deadline = time.monotonic() + 120
        while len(answers) < before + 20 and not failures and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        stop.set()
        for thread in threads:
            thread.join(120)
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert not failures, failures
    assert len(answers) >= before + 20  # answers came after the restart too
    assert all(answers), f"{answers.count(False)} wrong answers"
