"""The embedded Ray cluster of `nbake serve` listens on loopback only: found by probing, its GCS and raylet
bound every interface even with `--host 127.0.0.1`."""

from __future__ import annotations

import json
import subprocess
import sys

from tests.support.sockets import Listener

START_EMBEDDED_RAY = """
import dataclasses, json, os, sys
from pathlib import Path
import ray
from services.cli.serve import start_ray
from tests.support.sockets import listeners, process_tree
start_ray(Path(sys.argv[1]))
try:
    assert ray.get(ray.remote(lambda: os.getpid()).remote())  # a worker process listens too
    print(json.dumps([dataclasses.asdict(found) for found in listeners(process_tree(os.getpid()))]))
finally:
    ray.shutdown()
"""


def test_the_embedded_ray_cluster_listens_on_loopback_only(tmp_path):
    done = subprocess.run(
        [sys.executable, "-c", START_EMBEDDED_RAY, str(tmp_path / "data")],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    found = [Listener(**fields) for fields in json.loads(done.stdout.strip().splitlines()[-1])]
    assert {"gcs_server", "raylet"} <= {listener.process for listener in found}, found
    exposed = [listener for listener in found if not listener.is_loopback]
    assert not exposed, f"listening beyond loopback: {exposed}"
