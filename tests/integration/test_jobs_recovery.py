"""Crash recovery: SIGKILL the `nbake serve` process (and with it its Ray cluster) while a job renders,
start it again on the same data dir, and the job finishes from its checkpoint: the same image as an
uninterrupted render, no event lost, and the job queued behind it runs too."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest

from tests.integration import test_api_server as api
from tests.integration.test_api_server import NBAKE, TOKENS, TOKENS_ENV, events, submit, wait_for
from tests.support.ports import free_port
from workers.models.render.config import RenderConfig
from workers.render.render import render
from workers.runtime.checkpoints import COMMIT_MARKER
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene
from workers.scene.importers.image_io import read_exr

database = api.database  # fixture
SEED = 3


class ServeProcess:
    """`nbake serve` in its own session (process group), so a SIGKILL hits the server alone and the
    teardown can still remove anything of the group that outlived it."""

    def __init__(self, data_dir: Path, database: api.DatabaseChoice):
        self.data_dir, self.port = data_dir, free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        env = {**os.environ, "NBAKE_TOKENS": TOKENS_ENV, "NBAKE_MAX_RUNNING": "1"}
        env.pop("RAY_ADDRESS", None)
        if database.url:
            env |= {"NBAKE_DATABASE_URL": database.url, "NBAKE_DATABASE_SCHEMA": database.schema}
        command = [
            NBAKE,
            "serve",
            "--port",
            str(self.port),
            "--data-dir",
            str(data_dir),
            "--log-level",
            "warning",
        ]
        self.log = open(data_dir.parent / f"serve-{self.port}.log", "w")  # noqa: SIM115  (closed in stop)
        self.process = subprocess.Popen(
            command, env=env, stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True
        )
        deadline = time.monotonic() + 120
        while not self._ready():
            assert self.process.poll() is None, f"nbake serve exited: {self.process.returncode}"
            assert time.monotonic() < deadline, "nbake serve was not ready in time"
            time.sleep(0.25)

    def _ready(self) -> bool:
        try:
            return httpx.get(f"{self.url}/readyz", timeout=2).status_code == 200
        except httpx.TransportError:
            return False

    def client(self) -> httpx.Client:
        return httpx.Client(
            base_url=self.url, headers={"Authorization": f"Bearer {TOKENS['admin']}"}, timeout=60
        )

    def kill(self) -> None:
        """SIGKILL the server process only, as a crash would. Its Ray cluster dies with it, except Ray's
        dashboard and runtime-env agents, which linger until `stop` ends the group."""
        self.process.kill()
        self.process.wait()

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.process.kill()
            self._wait_group_gone(timeout=10)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, signal.SIGKILL)  # our own group: Ray processes that outlived us
        self.log.close()

    def _wait_group_gone(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while live_members(self.process.pid) and time.monotonic() < deadline:
            time.sleep(0.2)


def live_members(group: int) -> list[int]:
    """Processes of a process group that still run (zombies waiting for a reaper do not count)."""
    members = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError):
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[2]) == group and fields[0] != "Z":
                members.append(int(stat.parent.name))
    return members


@pytest.fixture
def serve(database) -> Iterator:
    """Start servers on one short-pathed data dir (Ray's sockets live under it); stop them all after."""
    started: list[ServeProcess] = []
    with tempfile.TemporaryDirectory(prefix="nbt-", dir="/tmp") as root:
        data_dir = Path(root) / "data"
        data_dir.mkdir()

        def start() -> ServeProcess:
            started.append(ServeProcess(data_dir, database))
            return started[-1]

        try:
            yield start
        finally:
            for process in started:
                process.stop()


def test_a_killed_server_resumes_its_jobs_from_checkpoints(serve):
    config = {"spp": 384, "checkpoint_interval_s": 0}
    first = serve()
    with first.client() as client:
        running = submit(client, kind="render", scene="cornell_box", preset="quick", config=config, seed=SEED)
        queued = submit(
            client, kind="render", scene="cornell_box", preset="quick", config={"spp": 2}, seed=SEED
        )
        # killed once a checkpoint is committed (progress alone can come before the first commit, and then
        # there is nothing to resume from)
        checkpoints = first.data_dir / "store" / "checkpoints" / running["id"]
        deadline = time.monotonic() + 180
        while not any(checkpoints.glob(f"step-*/{COMMIT_MARKER}")):
            assert time.monotonic() < deadline, "the render committed no checkpoint"
            time.sleep(0.1)
    first.kill()

    second = serve()
    with second.client() as client:
        assert client.get(f"/v1/jobs/{queued['id']}").json()["state"] in ("QUEUED", "RUNNING", "SUCCEEDED")
        stream = events(client, running["id"])
        done = wait_for(client, queued["id"], {"SUCCEEDED"})
        job = client.get(f"/v1/jobs/{running['id']}").json()
        image = client.get(f"/v1/artifacts/{job['artifact_id']}/files/image.exr").content

    assert job["state"] == "SUCCEEDED" and done["state"] == "SUCCEEDED"
    assert [e["seq"] for e in stream] == list(range(1, len(stream) + 1))
    resumed = [
        e["data"]["message"]
        for e in stream
        if "resuming from the checkpoint" in (e["data"].get("message") or "")
    ]
    assert resumed, [e["data"] for e in stream]
    assert any("driver was gone" in (e["data"].get("message") or "") for e in stream)
    assert job["attempts"] == 1  # a server restart is not the job's failure

    assert_uninterrupted_render(image, job["config"], SEED)


def assert_uninterrupted_render(image: bytes, config: dict, seed: int) -> None:
    """`image` (an EXR of cornell_box) is bit-identical to the same render run in one go, in this process."""
    with tempfile.TemporaryDirectory(prefix="nbt-exr-", dir="/tmp") as folder:
        exr = Path(folder) / "image.exr"
        exr.write_bytes(image)
        served = read_exr(exr)
    direct = render(
        compile_scene(get_builtin("cornell_box")), RenderConfig.model_validate(config).settings(seed)
    )
    np.testing.assert_array_equal(served, direct.image)
