"""Runs a Markdown file's examples (`doc_blocks`) in order, as a user would type them, against a real
`nbake serve`. The conventions, which the docs are written to:

- **Folder.** Every file runs in a fresh folder of its own, where `assets` links to the checkout's, so
  the docs' relative paths (`assets/scenes/example.yaml`, `out/...`) resolve. `nbake` and `python` are
  the environment's; no `NBAKE_*` variable or config file of the machine leaks in.
- **Server.** A `nbake serve ...` line starts the file's server in the background (its output goes to
  `serve.log` in the folder). A file without one gets `DEFAULT_SERVE` before its first block that runs,
  and `NBAKE_URL` and `NBAKE_TOKEN` naming it. The documented ports (REST 8080, gRPC 50051, inference
  8090 and 50052) are rewritten in every block to free ones, which the server is given as flags; as the
  inference service's default port is the SDK's, not the docs', `NBAKE_INFERENCE_URL` always names it.
  The server stops when the file is done.
- **Shell blocks.** Each command (a line; `\\` continues it) runs in bash with `-e -o pipefail` and must
  exit 0; variables it exports carry over to the next ones.
- **Python blocks** run as a script in a subprocess with the same environment and must exit 0.
- **Placeholders.** The words `JOB` and `ARTIFACT` stand for the id and the artifact id of the last job
  a command printed (a JSON line with a `job`: without a terminal `nbake` prints JSON lines), and
  `TOKEN_ID` for the id of the last token `nbake tokens create` printed. Using one before a command has
  printed it fails the run.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx

from tests.support.doc_blocks import Block
from tests.support.ports import free_port

DOCUMENTED_PORTS = {"port": 8080, "grpc-port": 50051, "inference-port": 8090, "inference-grpc-port": 50052}
DEFAULT_SERVE = "nbake serve --data-dir nbake-data --inference-port 8090"
PLACEHOLDER = re.compile(r"\b(JOB|ARTIFACT|TOKEN_ID)\b")
COMMAND_TIMEOUT_S = 1200
START_TIMEOUT_S = 180
STOP_TIMEOUT_S = 60
TAIL = 3000


def commands(code: str) -> list[str]:
    """The block's commands: lines joined over `\\` continuations, without blank and comment lines."""
    joined = re.sub(r"\s*\\\n\s*", " ", code)
    lines = (line.strip() for line in joined.splitlines())
    return [line for line in lines if line and not line.startswith("#")]


def captured(stdout: str) -> dict[str, str]:
    """The placeholders' values a command printed, the last of each."""
    values = {}
    for line in stdout.splitlines():
        with contextlib.suppress(ValueError):
            record = json.loads(line)
            if not isinstance(record, dict):
                continue
            job = record.get("job")
            if isinstance(job, dict):
                values["JOB"] = job["id"]
                if job.get("artifact_id"):
                    values["ARTIFACT"] = job["artifact_id"]
            if record.get("event") == "token":
                values["TOKEN_ID"] = record["id"]
    return values


class DocRun:
    """One Markdown file's run: its folder, its server, its environment and its placeholders' values."""

    def __init__(self, folder: Path, checkout: Path):
        self.folder = folder
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "assets").symlink_to(checkout / "assets")
        self.ports = {name: free_port() for name in DOCUMENTED_PORTS}
        bin_dir = str(Path(sys.executable).parent)
        self.env = {k: v for k, v in os.environ.items() if not k.startswith("NBAKE_") and k != "RAY_ADDRESS"}
        self.env |= {
            "PATH": f"{bin_dir}:{self.env.get('PATH', '')}",
            "NBAKE_CONFIG": str(folder / "none.toml"),
            "NBAKE_INFERENCE_URL": f"http://127.0.0.1:{self.ports['inference-port']}",
        }
        self.values: dict[str, str] = {}
        self.server: subprocess.Popen | None = None

    def __enter__(self) -> DocRun:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ the file

    def run(self, blocks: list[Block], slow: bool) -> None:
        """Run the blocks marked `run` (and `run slow` if `slow`) in order."""
        chosen = [b for b in blocks if b.action == "run" and (slow or not b.slow)]
        serves_itself = any(c.startswith("nbake serve ") for b in chosen for c in commands(b.code))
        for block in chosen:
            if self.server is None and not serves_itself:
                self.serve(DEFAULT_SERVE, block)
                self.env |= self.urls()
            if block.language == "sh":
                for command in commands(block.code):
                    self.shell(command, block)
            else:
                self.python(block)

    def code(self, text: str, block: Block) -> str:
        """`text` with the documented ports made this run's and the placeholders filled in."""
        for name, port in DOCUMENTED_PORTS.items():
            text = re.sub(rf"\b{port}\b", str(self.ports[name]), text)

        def value(found: re.Match) -> str:
            if found[1] not in self.values:
                raise AssertionError(f"{block}: {found[1]} is used before a command printed one")
            return self.values[found[1]]

        return PLACEHOLDER.sub(value, text)

    def shell(self, command: str, block: Block) -> None:
        if command.startswith("nbake serve "):
            self.serve(command, block)
            return
        script = self.code(command, block)
        env_file = self.folder / ".example-env"
        done = subprocess.run(
            ["bash", "-e", "-o", "pipefail", "-c", f"{script}\nenv -0 > {shlex.quote(str(env_file))}"],
            cwd=self.folder,
            env=self.env,
            capture_output=True,
            text=True,
            timeout=COMMAND_TIMEOUT_S,
        )
        self.check(done, block, script)
        self.env = dict(item.split("=", 1) for item in env_file.read_text().split("\0") if "=" in item)
        self.values |= captured(done.stdout)

    def python(self, block: Block) -> None:
        script = self.folder / f"example_{block.path.stem}_{block.line}.py"
        script.write_text(self.code(block.code, block))
        done = subprocess.run(
            [sys.executable, str(script)],
            cwd=self.folder,
            env=self.env,
            capture_output=True,
            text=True,
            timeout=COMMAND_TIMEOUT_S,
        )
        self.check(done, block, script.name)

    def check(self, done: subprocess.CompletedProcess, block: Block, what: str) -> None:
        if done.returncode != 0:
            raise AssertionError(
                f"{block}: `{what}` exited {done.returncode}\nstdout: {done.stdout[-TAIL:]}\n"
                f"stderr: {done.stderr[-TAIL:]}"
            )

    # ------------------------------------------------------------------ the server

    def urls(self) -> dict[str, str]:
        token = (self.folder / "nbake-data" / "admin-token").read_text().strip()
        return {"NBAKE_URL": f"http://127.0.0.1:{self.ports['port']}", "NBAKE_TOKEN": token}

    def serve(self, command: str, block: Block) -> None:
        """Start the documented `nbake serve` with this run's ports; wait until it and its inference
        service are ready."""
        if self.server is not None:
            raise AssertionError(f"{block}: a second `nbake serve` in one file")
        args = shlex.split(self.code(command, block), comments=True)
        for name, port in self.ports.items():
            if f"--{name}" not in args:
                args += [f"--{name}", str(port)]
        log = self.folder / "serve.log"
        with log.open("ab") as output:
            self.server = subprocess.Popen(
                args,
                cwd=self.folder,
                env=self.env,
                stdout=output,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        deadline = time.monotonic() + START_TIMEOUT_S
        while not self.ready():
            if self.server.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(
                    f"{block}: `{' '.join(args)}` did not get ready:\n{log.read_text()[-TAIL:]}"
                )
            time.sleep(0.5)

    def ready(self) -> bool:
        try:
            return all(
                httpx.get(f"http://127.0.0.1:{self.ports[name]}/readyz", timeout=2).status_code == 200
                for name in ("port", "inference-port")
            )
        except httpx.TransportError:
            return False

    def stop(self) -> None:
        """SIGTERM, SIGKILL after a grace period, then whatever is left of the server's session (its
        inference service, its Ray cluster)."""
        if self.server is None:
            return
        if self.server.poll() is None:
            self.server.terminate()
            try:
                self.server.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.server.kill()
                self.server.wait()
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.server.pid, signal.SIGKILL)
        self.server = None
