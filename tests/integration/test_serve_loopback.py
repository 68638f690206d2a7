"""`nbake serve` on 127.0.0.1 listens on loopback only, its embedded Ray cluster included: found by
probing, the cluster's GCS and raylet bound every interface. Checked on the shared real server of
test_grpc_server, by the sockets its process tree holds open."""

from __future__ import annotations

import time

from tests.integration import test_grpc_server as grpc_server
from tests.support.sockets import listeners, process_tree

served = grpc_server.served  # fixture


RAY_START_SECONDS = 60  # the server starts its Ray cluster beside serving: CI once looked before it had


def test_nbake_serve_and_its_ray_cluster_listen_on_loopback_only(served):
    deadline = time.monotonic() + RAY_START_SECONDS
    found = listeners(process_tree(served.process.pid))
    while (
        not {"gcs_server", "raylet"} <= {listener.process for listener in found}
        and time.monotonic() < deadline
    ):
        time.sleep(0.5)
        found = listeners(process_tree(served.process.pid))
    assert {"gcs_server", "raylet"} <= {listener.process for listener in found}, found
    exposed = [listener for listener in found if not listener.is_loopback]
    assert not exposed, f"listening beyond loopback: {exposed}"
