"""The server's connection to its Ray cluster, lost when the cluster dies and made again when it is back.

The server is a Ray driver. When every process of its cluster is killed, Ray's own calls from the driver
block until `gcs_rpc_server_reconnect_timeout_s` (60 s) and then end the whole process, API included; a
cluster restarted on the same address is a new cluster, which the old connection cannot use. So the
scheduler asks `check` before any Ray work: it probes the cluster's GCS with a bounded call and, on the
first failure, disconnects (`ray.shutdown`, in time, before Ray ends the process), then connects again
with exponential backoff until that works: to the cluster at `RAY_ADDRESS` once it answers, or, for the
server's embedded cluster, to a new one it starts. The API reads `ready` instead of calling Ray,
so it keeps answering (and reports Ray not ready) during the outage.

Where this falls short: a driver whose raylet died survives `ray.shutdown` only while its parent process
lives (Ray takes an orphaned driver's broken raylet socket for its own death), so a server started with
`--outlive-parent` whose parent exited ends at the disconnect; a blocking Ray call the scheduler began
between two probes (creating or looking up a named actor) still ends the process after the 60 s; in both
cases the next start resumes the jobs from their checkpoints.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from collections.abc import Callable

import ray
from ray._private.worker import global_worker

PROBE_KEY = b"nbake-probe"  # a key nobody writes: reading it proves the GCS answers
PROBE_TIMEOUT_S = 1.0
PROBE_INTERVAL_S = 1.0
FIRST_BACKOFF_S = 0.5
MAX_BACKOFF_S = 10.0

log = logging.getLogger(__name__)


class RayConnection:
    """Whether the scheduler may use Ray now; called from the scheduler's thread only, read from any."""

    def __init__(self, name: str, connect: Callable[[], None]) -> None:
        self.name = name  # the cluster, as messages name it
        self._connect = connect  # connects this process to the cluster again (`ray.init`)
        self._lock = threading.Lock()
        self._connected = ray.is_initialized()
        self._next_probe = 0.0
        self._backoff = FIRST_BACKOFF_S
        self._problem = "" if self._connected else "not connected yet"

    @classmethod
    def joining(cls, address: str) -> RayConnection:
        """A cluster of its own at `address` (kept as given: a name, not the GCS's resolved IP)."""

        def join() -> None:
            reachable(address)
            ray.init(address=address, log_to_driver=False)

        return cls(address, join)

    @classmethod
    def current(cls) -> RayConnection:
        """The connection `ray.init` made: joined again at `RAY_ADDRESS` when set, else at the same GCS."""
        return cls.joining(os.environ.get("RAY_ADDRESS") or ray.get_runtime_context().gcs_address)

    def check(self, on_lost: Callable[[], None]) -> bool:
        """True when the cluster answered a probe within the last second; otherwise reconnect (after the
        backoff) and say False. `on_lost` runs once when the cluster is found gone, before the disconnect,
        to drop whatever ran on it (handles to its actors among them).
        """
        now = time.monotonic()
        if now < self._next_probe:
            return self._connected
        if self._connected:
            self._probe(now, on_lost)
        else:
            self._reconnect(now)
        return self._connected

    def ready(self) -> None:
        """Raise, saying why, unless the last probe found the cluster (for the readiness endpoint)."""
        with self._lock:
            if not self._connected:
                raise ConnectionError(f"Ray cluster {self.name} unreachable: {self._problem}")

    def _probe(self, now: float, on_lost: Callable[[], None]) -> None:
        try:
            global_worker.gcs_client.internal_kv_get(PROBE_KEY, None, timeout=PROBE_TIMEOUT_S)
        except Exception as error:  # any failure to answer is a lost cluster
            self._lose(f"{type(error).__name__}: {error}", on_lost)
            return
        self._next_probe = now + PROBE_INTERVAL_S

    def _lose(self, problem: str, on_lost: Callable[[], None]) -> None:
        log.warning("lost the Ray cluster %s (%s); connecting again when it is back", self.name, problem)
        with self._lock:
            self._connected, self._problem = False, problem
        try:
            on_lost()
        finally:
            ray.shutdown()
        self._backoff = FIRST_BACKOFF_S
        self._next_probe = time.monotonic() + self._backoff

    def _reconnect(self, now: float) -> None:
        try:
            self._connect()
        except Exception as error:  # not back yet: try again later, less often
            if ray.is_initialized():
                ray.shutdown()
            with self._lock:
                self._problem = f"{type(error).__name__}: {error}"
            self._next_probe = now + self._backoff
            self._backoff = min(self._backoff * 2, MAX_BACKOFF_S)
            return
        log.warning("connected to the Ray cluster %s again", self.name)
        with self._lock:
            self._connected, self._problem = True, ""
        self._backoff = FIRST_BACKOFF_S
        self._next_probe = time.monotonic() + PROBE_INTERVAL_S


def reachable(address: str) -> None:
    """A TCP connection to the GCS port first: `ray.init` on a dead address retries for a long while."""
    host, _, port = address.rpartition(":")
    if port.isdigit():  # not for a name Ray resolves itself ("auto")
        socket.create_connection((host.strip("[]"), int(port)), timeout=PROBE_TIMEOUT_S).close()
