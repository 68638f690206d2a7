"""A parent that dies takes `nbake serve` with it, Ray cluster and all: the parent here is a small Python
process that starts the server and is then SIGKILLed, as a CI timeout would kill a test run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from tests.integration.test_api_server import NBAKE
from tests.support.ports import free_port
from tests.support.sockets import listeners, process_tree

PARENT = """
import subprocess, sys
server = subprocess.Popen(sys.argv[2:], stderr=open(sys.argv[1], "w"))
print(server.pid, flush=True)
server.wait()
"""


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow  # a real `nbake serve` with its Ray cluster: about a minute on the shared 2-core machine
def test_a_killed_parent_takes_the_server_and_its_ray_cluster_with_it(tmp_path):
    port, log = free_port(), tmp_path / "server.log"
    command = [NBAKE, "serve", "--port", str(port), "--grpc-port", str(free_port())]
    command += ["--data-dir", str(tmp_path / "data"), "--log-level", "warning"]
    env = {**os.environ, "NBAKE_TOKENS": "t:admin"}
    parent = subprocess.Popen(
        [sys.executable, "-c", PARENT, str(log), *command], stdout=subprocess.PIPE, text=True, env=env
    )
    server = int(parent.stdout.readline())
    tree: set[int] = set()
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=5).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert time.monotonic() < deadline and parent.poll() is None, "the server did not start"
            time.sleep(0.5)
        tree = process_tree(server)
        names = {Path(f"/proc/{pid}/comm").read_text().strip() for pid in tree if alive(pid)}
        assert {"gcs_server", "raylet"} <= names, names  # the server's own Ray cluster
        exposed = [found for found in listeners(tree) if not found.is_loopback]
        assert not exposed, f"`nbake serve` on 127.0.0.1 listens beyond loopback: {exposed}"
        parent.kill()
        parent.wait()
        deadline = time.monotonic() + 90
        while any(alive(pid) for pid in tree) and time.monotonic() < deadline:
            time.sleep(0.5)
        survivors = {pid: Path(f"/proc/{pid}/comm").read_text().strip() for pid in tree if alive(pid)}
        assert not survivors, f"still running after their parent died: {survivors}"
        assert f"the parent process {parent.pid} exited" in log.read_text()  # the server says why it stopped
    finally:
        for pid in tree | {server}:  # only processes this test started
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
        if parent.poll() is None:
            parent.kill()
