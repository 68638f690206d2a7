"""An S3 bucket served by moto's server mode on a free loopback port: the one emulated part of the
scale-out tests (every client talks real S3 protocol over HTTP to it, through s3fs and botocore).

Clients find it through the standard AWS variables (`AWS_ENDPOINT_URL` and test credentials), set in this
process and handed to any process the tests start, as Kubernetes would hand them to pods from a Secret.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx

from tests.support.ports import free_port

MOTO_SERVER = str(Path(sys.executable).with_name("moto_server"))
START_TIMEOUT_S = 60


@dataclass
class S3Server:
    endpoint: str
    env: dict[str, str]  # what a client process needs to reach it

    def bucket(self) -> str:
        """A new, empty bucket."""
        import fsspec

        name = f"nbake-{uuid.uuid4().hex[:12]}"
        fsspec.filesystem("s3").mkdir(name)
        return name


@contextlib.contextmanager
def moto_s3() -> Iterator[S3Server]:
    """moto's S3 server in its own process; this process's AWS variables point at it until exit."""
    port = free_port()
    endpoint = f"http://127.0.0.1:{port}"
    process = subprocess.Popen(
        [MOTO_SERVER, "-H", "127.0.0.1", "-p", str(port)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    env = {
        "AWS_ENDPOINT_URL": endpoint,
        "AWS_ACCESS_KEY_ID": "nbake-test",
        "AWS_SECRET_ACCESS_KEY": "nbake-test-secret",
        "AWS_DEFAULT_REGION": "us-east-1",
    }
    saved = {name: os.environ.get(name) for name in env}
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"{endpoint}/moto-api/", timeout=1).status_code < 500:
                    break
            if process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"moto_server did not start on {endpoint}")
            time.sleep(0.1)
        os.environ.update(env)
        yield S3Server(endpoint, env)
    finally:
        import fsspec

        fsspec.get_filesystem_class("s3").clear_instance_cache()  # cached clients know this endpoint
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        process.terminate()
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
