"""How the remote commands reach the servers and how their outcome becomes an exit status.

The job server and token come from `--url` / `--token`, else `NBAKE_URL` / `NBAKE_TOKEN`, else a TOML
config file (`NBAKE_CONFIG`, default `~/.config/nbake/config.toml`, keys `url` and `token`); the inference
service from `--inference-url`, else `NBAKE_INFERENCE_URL`, else the file's `inference_url`, else the job
server's host at the inference service's default port. Exit statuses are what a pipeline branches on:
0 succeeded, 1 job failed, 2 usage or validation error, 3 cancelled, 4 server unreachable or auth error,
5 a build's quality gate failed (`nbake bake`), 6 a wait or a build ran out of time (`--timeout`).

The SDK is imported when a command connects, not when `nbake` starts.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, NoReturn

import typer

from neuralbake_client.errors import (
    ApiError,
    ChecksumMismatch,
    ConnectionFailed,
    NeuralbakeError,
    PermissionDenied,
    ServerError,
    Unauthenticated,
    Unavailable,
)

if TYPE_CHECKING:
    from neuralbake_client.client import Client

SUCCEEDED, FAILED, USAGE, CANCELLED, UNREACHABLE, GATES_FAILED, TIMED_OUT = 0, 1, 2, 3, 4, 5, 6
EXIT_BY_STATE = {"SUCCEEDED": SUCCEEDED, "FAILED": FAILED, "CANCELLED": CANCELLED}  # by JobState
DEFAULT_URL = "http://127.0.0.1:8080"
DEFAULT_CONFIG = Path("~/.config/nbake/config.toml")

UrlOption = Annotated[
    str | None,
    typer.Option(
        "--url",
        help="http(s)://host:port (REST) or grpc(s)://host:port (gRPC). Env NBAKE_URL; default "
        f"from the config file, else {DEFAULT_URL}.",
        show_default=False,
    ),
]
InferenceUrlOption = Annotated[
    str | None,
    typer.Option(
        "--inference-url",
        help="The inference service (`nbake serve-inference`), http(s):// or grpc(s)://. Env "
        "NBAKE_INFERENCE_URL or the config file; default: the job server's host at port 8090 (REST) or "
        "50052 (gRPC).",
        show_default=False,
    ),
]
TokenOption = Annotated[
    str | None,
    typer.Option("--token", help="Bearer token. Env NBAKE_TOKEN or the config file.", show_default=False),
]
JsonOption = Annotated[
    bool, typer.Option("--json", help="One JSON object per line (the default when stdout is not a terminal).")
]


def config_file() -> dict:
    path = Path(os.environ.get("NBAKE_CONFIG") or DEFAULT_CONFIG).expanduser()
    if not path.is_file():
        return {}
    try:
        return tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as error:
        exit_with(USAGE, f"error: {path}: {error}")


def connect(url: str | None, token: str | None, inference_url: str | None = None) -> Client:
    """A client for the servers named by the flags, the environment or the config file (in that order)."""
    from neuralbake_client.client import Client

    file = config_file()
    url = url or os.environ.get("NBAKE_URL") or file.get("url") or DEFAULT_URL
    token = token or os.environ.get("NBAKE_TOKEN") or file.get("token")
    inference_url = inference_url or os.environ.get("NBAKE_INFERENCE_URL") or file.get("inference_url")
    try:
        return Client(url, token, inference_url=inference_url)
    except ValueError as error:
        exit_with(USAGE, f"error: --url: {error}")


def exit_with(code: int, message: str) -> NoReturn:
    typer.echo(message, err=True)
    raise typer.Exit(code)


def exit_code(error: NeuralbakeError) -> int:
    if isinstance(error, ConnectionFailed | Unavailable | Unauthenticated | PermissionDenied | ServerError):
        return UNREACHABLE
    if isinstance(error, ChecksumMismatch):
        return FAILED
    return USAGE


@contextmanager
def remote_errors() -> Iterator[None]:
    """Turn the SDK's exceptions into one `error: ...` line on stderr and the matching exit status."""
    try:
        yield
    except ApiError as error:
        exit_with(exit_code(error), f"error: {error.where}{error.detail} ({error.status} {error.title})")
    except NeuralbakeError as error:
        exit_with(exit_code(error), f"error: {error}")
