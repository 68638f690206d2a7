"""`make run`: the embedded default end to end. Starts `nbake serve` on a free port with a temporary data
dir, submits a job over HTTP, prints its progress from the event stream, downloads the artifact's files
and stops the server. (A stand-in until the Python SDK exists.)

    python -m services.cli.run_job [--scene cornell_box] [--preset default] [--config '{"spp": 64}']
"""

from __future__ import annotations

import argparse
import json
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx

READY_TIMEOUT_S = 120


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", default="render")
    parser.add_argument("--scene", default="cornell_box", help="built-in scene name or asset id")
    parser.add_argument("--preset", default="default")
    parser.add_argument("--config", default='{"spp": 64}', help="JSON overrides of the preset")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("out/run"), help="where the artifact's files go")
    args = parser.parse_args(argv)
    body = {"kind": args.kind, "scene": args.scene, "preset": args.preset, "config": json.loads(args.config)}
    with (
        tempfile.TemporaryDirectory(prefix="nbake-run-", dir="/tmp") as data_dir,
        serve(Path(data_dir)) as client,
    ):
        response = client.post("/v1/jobs", json={**body, "seed": args.seed})
        if response.is_error:
            print(f"submission refused: {response.json()['detail']}", file=sys.stderr)
            return 1
        job = response.json()
        print(f"submitted {job['id']}: {args.kind} of {args.scene} ({args.preset}, {job['config']})")
        for event in follow(client, job["id"]):
            print(describe(event), flush=True)
        job = client.get(f"/v1/jobs/{job['id']}").json()
        if job["state"] != "SUCCEEDED":
            print(f"job {job['state']}: {job['error'] or ''}", file=sys.stderr)
            return 1
        download(client, job["artifact_id"], args.out)
    return 0


@contextmanager
def serve(data_dir: Path) -> Iterator[httpx.Client]:
    """A server of our own (its own process group, so stopping it stops its Ray cluster too)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    nbake = Path(sys.executable).with_name("nbake")
    command = [
        str(nbake),
        "serve",
        "--port",
        str(port),
        "--data-dir",
        str(data_dir),
        "--log-level",
        "warning",
    ]
    process = subprocess.Popen(command, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    print(f"server {url} (data in {data_dir}), pid {process.pid}")
    try:
        wait_ready(url, process)
        token = (data_dir / "admin-token").read_text().strip()
        with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=60) as client:
            yield client
    finally:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        print("server stopped")


def wait_ready(url: str, process: subprocess.Popen) -> None:
    deadline = time.monotonic() + READY_TIMEOUT_S
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise SystemExit(f"nbake serve exited with status {process.returncode}")
        try:
            if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.25)
    raise SystemExit(f"nbake serve was not ready within {READY_TIMEOUT_S} s")


def follow(client: httpx.Client, job_id: str) -> Iterator[dict]:
    """The job's events from its SSE stream, until the stream ends after the final state."""
    with client.stream("GET", f"/v1/jobs/{job_id}/events", timeout=None) as response:
        for line in response.iter_lines():
            if line.startswith("data:"):
                yield json.loads(line.removeprefix("data:"))


def describe(event: dict) -> str:
    data = event["data"]
    if event["type"] == "state":
        extra = data.get("error") or data.get("artifact_id") or ""
        return f"  [{event['seq']:>3}] {data['state']:<9} {data.get('message') or ''} {extra}".rstrip()
    if event["type"] == "progress":
        rate = f"{data['samples_per_s'] / 1e3:.0f}k samples/s" if data.get("samples_per_s") else ""
        eta = f"ETA {data['eta_s']:.0f} s" if data.get("eta_s") is not None else ""
        return f"  [{event['seq']:>3}] progress  {data['step']}/{data['total']} {rate} {eta}".rstrip()
    return f"  [{event['seq']:>3}] log       {data.get('message', '')}"


def download(client: httpx.Client, artifact_id: str, out: Path) -> None:
    manifest = client.get(f"/v1/artifacts/{artifact_id}").json()
    out.mkdir(parents=True, exist_ok=True)
    print(f"artifact {artifact_id}")
    for entry in manifest["files"]:
        target = out / entry["name"]
        target.write_bytes(client.get(f"/v1/artifacts/{artifact_id}/files/{entry['name']}").content)
        print(f"  {entry['media_type']:<18} {target}")


if __name__ == "__main__":
    sys.exit(main())
