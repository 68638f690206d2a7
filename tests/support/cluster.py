"""A real multi-node Ray cluster on one machine, for the scale-out tests.

Each node is `ray start --block` in its own process group (session), with its own working, temp and
scene-cache folders and its own ports. A node started with `hidden` runs in a mount namespace of its own
(`unshare --mount`) with a private tmpfs over each hidden folder: it cannot see the server's data folder,
so a job that works there works without a shared filesystem. Tests run as root, which `unshare` needs.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shlex
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from tests.support.ports import free_port, worker_port_options

RAY = str(Path(sys.executable).with_name("ray"))
START_TIMEOUT_S = 120
STOP_TIMEOUT_S = 20
START_ATTEMPTS = 3


class NodeDidNotStart(RuntimeError):
    pass


@dataclass
class RayNode:
    name: str
    folder: Path  # working folder; temp/ (Ray's session files), scenes/ (the node's scene cache), log
    process: subprocess.Popen
    cpus: int

    @property
    def scene_cache(self) -> Path:
        return self.folder / "scenes"

    def pids(self) -> list[int]:
        """Every live process of the node (its session: `ray start` and all it started); zombies, which
        only wait for a reaper, do not count."""
        found = []
        for stat in Path("/proc").glob("[0-9]*/stat"):
            with contextlib.suppress(OSError, ValueError, IndexError):
                fields = stat.read_text().rsplit(")", 1)[1].split()
                if int(fields[3]) == self.process.pid and fields[0] != "Z":  # field 6 of stat: session
                    found.append(int(stat.parent.name))
        return found

    def raylet_pid(self) -> int:
        for pid in self.pids():
            with contextlib.suppress(OSError):
                if Path(f"/proc/{pid}/comm").read_text().strip() == "raylet":
                    return pid
        raise LookupError(f"node {self.name} has no raylet running")

    def sees(self, path: Path) -> bool:
        """Whether `path` exists as the node's raylet sees it (in its own mount namespace)."""
        return (Path(f"/proc/{self.raylet_pid()}/root") / path.relative_to("/")).exists()

    def kill_raylet(self) -> None:
        os.kill(self.raylet_pid(), signal.SIGKILL)

    def stop(self) -> None:
        """SIGKILL to every process of the node (a test cluster needs no graceful drain), then reaped."""
        deadline = time.monotonic() + STOP_TIMEOUT_S
        while (pids := self.pids()) and time.monotonic() < deadline:
            for pid in pids:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            time.sleep(0.1)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.process.wait(STOP_TIMEOUT_S)

    def started(self) -> bool:
        """`ray start` reported the node running (its raylet registered with the cluster)."""
        return b"Ray runtime started" in (self.folder / "node.log").read_bytes()


@dataclass
class LocalCluster:
    """A head node and more nodes; `address` is what `RAY_ADDRESS` takes."""

    folder: Path
    env: dict[str, str]  # every node's environment (the store's credentials, PYTHONPATH)
    address: str = ""
    nodes: list[RayNode] = field(default_factory=list)

    def __post_init__(self) -> None:
        # Ray's token authentication, with this cluster's own token: a client needs it to join, as every
        # node and `nbake serve` would get it from a Secret (and ~/.ray/auth_token is left alone)
        self.env = {**self.env, "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32)}

    @property
    def client_env(self) -> dict[str, str]:
        """What a process joining the cluster (`nbake serve`) adds to its environment."""
        return {**self.env, "RAY_ADDRESS": self.address}

    def start_head(self, cpus: int, name: str = "head", hidden: tuple[Path, ...] = ()) -> RayNode:
        """The head node; a head started again after `stop` (under a new name) takes the address of the one
        before, as a restarted head pod behind its service name would: the same cluster address, a new
        cluster. `hidden`: folders the head cannot see, as for `add_node`."""
        restarted = bool(self.address)

        def head_args() -> list[str]:
            if not restarted:
                self.address = f"127.0.0.1:{free_port()}"
            return [
                "--head",
                f"--port={self.address.rpartition(':')[2]}",
                "--include-dashboard=false",
                f"--dashboard-port={free_port()}",  # Ray's minimal dashboard runs anyway: not on 8265
                f"--ray-client-server-port={free_port()}",
            ]

        return self._start_retrying(name, cpus, head_args, hidden)

    def add_node(self, name: str, cpus: int, hidden: tuple[Path, ...] = ()) -> RayNode:
        return self._start_retrying(name, cpus, lambda: [f"--address={self.address}"], hidden)

    def _start_retrying(self, name: str, cpus: int, args, hidden: tuple[Path, ...]) -> RayNode:
        """`ray start` gives a raylet 30 s to register, which a machine busy with other work can miss: a
        node that did not start is tried again, up to START_ATTEMPTS."""
        for attempt in range(1, START_ATTEMPTS + 1):
            try:
                return self._start(name, cpus, args(), hidden)
            except NodeDidNotStart:
                if attempt == START_ATTEMPTS:
                    raise
                failed = self.nodes.pop()
                failed.stop()
                failed.folder.rename(failed.folder.with_name(f"{name}-failed-{attempt}"))
        raise AssertionError("unreachable")

    def _start(self, name: str, cpus: int, args: list[str], hidden: tuple[Path, ...]) -> RayNode:
        folder = self.folder / name
        (folder / "temp").mkdir(parents=True)
        command = [RAY, "start", "--block", "--disable-usage-stats", f"--num-cpus={cpus}", "--num-gpus=0"]
        command += [f"--temp-dir={folder / 'temp'}", "--node-ip-address=127.0.0.1", *args]
        for option in (
            "--node-manager-port",
            "--object-manager-port",
            "--dashboard-agent-listen-port",
            "--dashboard-agent-grpc-port",
            "--runtime-env-agent-port",
            "--metrics-export-port",
        ):
            command.append(f"{option}={free_port()}")
        command += worker_port_options()
        if hidden:
            mounts = " && ".join(f"mount -t tmpfs nbake-hidden {shlex.quote(str(p))}" for p in hidden)
            command = ["unshare", "--mount", "--propagation", "private", "--", "sh", "-c",
                       f"{mounts} && exec {shlex.join(command)}"]  # fmt: skip
        env = {**os.environ, **self.env, "NBAKE_SCENE_CACHE": str(folder / "scenes")}
        with open(folder / "node.log", "wb") as log:
            process = subprocess.Popen(
                command, cwd=folder, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True
            )
        node = RayNode(name, folder, process, cpus)
        self.nodes.append(node)
        deadline = time.monotonic() + START_TIMEOUT_S
        while not node.started():
            if process.poll() is not None or time.monotonic() > deadline:
                log = (folder / "node.log").read_text()[-3000:]
                raise NodeDidNotStart(f"Ray node {name} did not start:\n{log}")
            time.sleep(0.2)
        return node

    def query(self, expression: str) -> object:
        """Evaluate a Python expression over `ray` (connected to this cluster) in a client process of its
        own: this test process may already be a driver of another Ray cluster."""
        script = (
            "import json, ray\n"
            "from ray.util.placement_group import placement_group_table\n"
            f"ray.init(address={self.address!r}, log_to_driver=False, logging_level='ERROR')\n"
            f"print('RESULT=' + json.dumps({expression}, default=str))\n"
        )
        env = {**os.environ, **self.env}
        env.pop("RAY_ADDRESS", None)
        output = subprocess.run(
            [sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True, timeout=120
        ).stdout
        return json.loads(next(line for line in output.splitlines() if line.startswith("RESULT="))[7:])

    def alive_nodes(self) -> list[dict]:
        return self.query("[n for n in ray.nodes() if n['Alive']]")

    def stop(self) -> None:
        for node in reversed(self.nodes):
            node.stop()


class ServeReplica:
    """`nbake serve` joined to a cluster through `RAY_ADDRESS`, in its own session, on its own data dir."""

    def __init__(self, data_dir: Path, env: dict[str, str], log_name: str = "serve"):
        self.data_dir = data_dir
        self.env = env
        self.log_path = data_dir.parent / f"{log_name}.log"
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.process: subprocess.Popen | None = None

    def start(self) -> ServeReplica:
        command = [str(Path(sys.executable).with_name("nbake")), "serve", "--port", str(self.port)]
        command += [
            "--grpc-port",
            str(free_port()),
            "--data-dir",
            str(self.data_dir),
            "--log-level",
            "warning",
        ]
        with open(self.log_path, "ab") as log:
            self.process = subprocess.Popen(
                command,
                env={**os.environ, **self.env},
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        deadline = time.monotonic() + START_TIMEOUT_S
        while not self.ready():
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"nbake serve did not get ready:\n{self.log_path.read_text()[-3000:]}")
            time.sleep(0.25)
        return self

    def ready(self) -> bool:
        import httpx

        try:
            return httpx.get(f"{self.url}/readyz", timeout=2).status_code == 200
        except httpx.TransportError:
            return False

    def stop(self, grace_s: float = STOP_TIMEOUT_S) -> None:
        """SIGTERM (the scheduler stops and leaves its jobs RUNNING for the next start), SIGKILL after
        `grace_s`, then whatever is left of its session."""
        if self.process is None:
            return
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=grace_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, signal.SIGKILL)  # anything of its session that outlived it
        self.process = None
