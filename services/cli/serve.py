"""`nbake serve`: the embedded default in one process tree (FastAPI under uvicorn, a local Ray cluster,
a SQLite job database and a local artifact directory), or parts of a scale-out via `NBAKE_*` and
`RAY_ADDRESS`.
"""

from __future__ import annotations

import ipaddress
import os
import shutil
import socket
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Annotated

import ray
import ray._private.ray_constants as ray_constants
import typer

from services.api.app import create_app
from services.api.grpc.server import with_grpc
from services.api.settings import ServiceSettings
from services.cli.errors import fail
from services.cli.lifetime import OutliveParent, die_with_parent
from services.cli.listening import taken
from services.jobs.ray_connection import RayConnection
from services.platform.auth import configured_tokens, generated_admin_token
from services.platform.ports import http_socket, reserved_port
from services.platform.serving import serve_app

RAY_TEMP_DIR_MAX = 40  # Ray's socket paths below its temp dir must stay under the 107-byte AF_UNIX limit


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def serve_command(
    host: Annotated[
        str, typer.Option(help="Address to listen on; a non-loopback one needs tokens.")
    ] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="TCP port.")] = 8080,
    grpc_port: Annotated[int, typer.Option(min=0, max=65535, help="TCP port of the gRPC API.")] = 50051,
    data_dir: Annotated[
        Path, typer.Option(help="Job database, artifact store, checkpoints, tokens.", envvar="NBAKE_DATA_DIR")
    ] = Path("nbake-data"),
    max_running: Annotated[
        int | None, typer.Option(min=1, help="Jobs running at once (NBAKE_MAX_RUNNING).")
    ] = None,
    log_level: Annotated[str, typer.Option(help="uvicorn log level.")] = "info",
    inference_port: Annotated[
        int | None,
        typer.Option(min=0, max=65535, help="Also start `nbake serve-inference` on this port (own process)."),
    ] = None,
    inference_grpc_port: Annotated[
        int, typer.Option(min=0, max=65535, help="gRPC port of that inference process.")
    ] = 50052,
    outlive_parent: OutliveParent = False,
) -> None:
    """Serve the REST API (OpenAPI at /docs) and run submitted jobs on Ray.

    Tokens: NBAKE_TOKENS=token:scope,... or NBAKE_TOKENS_FILE (scopes read, submit, admin). With none,
    an admin token is generated into DATA_DIR/admin-token. Database: NBAKE_DATABASE_URL (default SQLite
    in DATA_DIR); store: NBAKE_STORE_URL (default DATA_DIR/store).
    """
    if not outlive_parent:
        die_with_parent()
    try:
        settings = ServiceSettings.from_env(data_dir, max_running=max_running)
        tokens = configured_tokens(settings.tokens, settings.tokens_file)
    except (ValueError, OSError) as error:
        fail("tokens", str(error))
    if not tokens and not is_loopback(host):
        fail("--host", f"{host} is not a loopback address: configure NBAKE_TOKENS or NBAKE_TOKENS_FILE first")
    data_dir.mkdir(parents=True, exist_ok=True)
    if not tokens:
        _, path = generated_admin_token(data_dir)
        typer.echo(f"admin token: {path}", err=True)
    http = taken("--port", http_socket, host, port)
    grpc_reservation = taken("--grpc-port", reserved_port, host, grpc_port)
    inference_sockets = None
    if inference_port is not None:
        inference_sockets = (
            taken("--inference-port", http_socket, host, inference_port),
            taken("--inference-grpc-port", reserved_port, host, inference_grpc_port),
        )
    port, grpc_port = http.getsockname()[1], grpc_reservation.getsockname()[1]
    typer.echo(f"dashboard: http://{url_host(host)}:{port}/ui", err=True)
    ray_connection, ray_temp = start_ray(data_dir)
    inference = None
    if inference_sockets is not None:
        inference = start_inference(inference_sockets, host, data_dir, log_level)
    try:
        app = with_grpc(create_app(settings, ray_connection), host, grpc_port, grpc_reservation)
        serve_app(app, http, log_level)
    finally:
        if inference is not None:
            inference.terminate()
            inference.wait(30)
        ray.shutdown()
        if ray_temp is not None:
            shutil.rmtree(ray_temp, ignore_errors=True)


def url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def start_inference(
    sockets: tuple[socket.socket, socket.socket], host: str, data_dir: Path, log_level: str
) -> subprocess.Popen:
    """`nbake serve-inference` as a child process, serving the REST socket and the reserved gRPC port this
    process took before Ray started (file descriptors the child inherits; ours close once it has them)."""
    http, reservation = sockets
    ports = http.getsockname()[1], reservation.getsockname()[1]
    command = [str(Path(sys.executable).with_name("nbake")), "serve-inference", "--host", host]
    command += ["--http-fd", str(http.fileno()), "--grpc-fd", str(reservation.fileno())]
    command += ["--data-dir", str(data_dir), "--log-level", log_level]
    try:
        child = subprocess.Popen(command, pass_fds=(http.fileno(), reservation.fileno()))
    finally:
        for held in sockets:
            held.close()
    typer.echo(f"inference: http://{url_host(host)}:{ports[0]} (gRPC port {ports[1]})", err=True)
    return child


def start_ray(data_dir: Path) -> tuple[RayConnection, Path | None]:
    """Join `RAY_ADDRESS`, or start a local cluster on loopback with its session files under the data dir
    (or, if that path is too long for Ray's sockets, a private /tmp folder: returned, to be removed on exit).
    The connection makes the same again when the cluster is lost: joins the address once it answers, or
    starts a new local cluster.
    """
    if os.environ.get("RAY_ADDRESS"):
        ray.init(address=os.environ["RAY_ADDRESS"], log_to_driver=False)
        return RayConnection.joining(os.environ["RAY_ADDRESS"]), None
    temp_dir = (data_dir / "ray").resolve()
    private = len(str(temp_dir)) > RAY_TEMP_DIR_MAX
    if private:
        temp_dir = Path(tempfile.mkdtemp(prefix="nbake-ray-", dir="/tmp"))
    single_machine_ray()

    def start_local() -> None:
        ray.init(address="local", include_dashboard=False, _temp_dir=str(temp_dir), log_to_driver=False)

    start_local()
    return RayConnection("embedded in this server", start_local), temp_dir if private else None


def single_machine_ray() -> None:
    """Make the embedded cluster's node address 127.0.0.1, so its GCS, raylet, object manager and workers
    listen on loopback only. Ray otherwise takes the address that routes outward as the node's (even a
    `_node_ip_address="127.0.0.1"` is replaced by it) and its gRPC servers then bind every interface; its
    single-machine mode (`RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`, read once at import, hence both) keeps
    loopback. No other node ever joins the embedded cluster, so nothing needs it reachable from outside.
    """
    os.environ[ray_constants.ENABLE_RAY_CLUSTERS_ENV_VAR] = "0"
    ray_constants.ENABLE_RAY_CLUSTER = False
