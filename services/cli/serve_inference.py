"""`nbake serve-inference`: the thin inference service in its own process and port, reading the same
store and token database as `nbake serve` (same data dir or the same `NBAKE_*` settings)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from services.cli.errors import fail
from services.cli.lifetime import OutliveParent, die_with_parent
from services.cli.listening import inherited, taken
from services.inference.app import create_inference_app
from services.inference.settings import InferenceSettings
from services.platform.ports import http_socket, reserved_port
from services.platform.serving import serve_app


def serve_inference_command(
    host: Annotated[str, typer.Option(help="Address to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="TCP port of the REST API.")] = 8090,
    grpc_port: Annotated[
        int, typer.Option(min=0, max=65535, help="TCP port of the gRPC InferenceService.")
    ] = 50052,
    data_dir: Annotated[
        Path, typer.Option(help="The job server's data dir (store and tokens).", envvar="NBAKE_DATA_DIR")
    ] = Path("nbake-data"),
    memory_bytes: Annotated[
        int | None, typer.Option(min=1, help="Memory budget of loaded models (NBAKE_INFERENCE_MEMORY_BYTES).")
    ] = None,
    working_bytes: Annotated[
        int | None,
        typer.Option(
            min=1 << 20,
            help="Memory requests in flight may allocate between them; larger queries get a 413 "
            "(NBAKE_INFERENCE_WORKING_BYTES).",
        ),
    ] = None,
    reading_bytes: Annotated[
        int | None,
        typer.Option(
            min=1 << 20,
            help="Memory REST bodies being received may take between them (NBAKE_INFERENCE_READING_BYTES).",
        ),
    ] = None,
    max_waiting: Annotated[
        int | None, typer.Option(min=0, help="Requests waiting for working memory; more get a 503.")
    ] = None,
    chunk_rows: Annotated[
        int | None, typer.Option(min=1, help="Rows one model call runs at a time (bounds activations).")
    ] = None,
    max_wait_ms: Annotated[
        float | None, typer.Option(min=0, help="How long a batch waits for more requests.")
    ] = None,
    max_rows: Annotated[
        int | None, typer.Option(min=1, help="Rows (rays, pixels) one request may ask for.")
    ] = None,
    torch_threads: Annotated[int | None, typer.Option(min=1, help="Intra-op threads per model call.")] = None,
    device: Annotated[
        str | None, typer.Option(help="auto (CUDA when present), cpu or cuda[:n] (NBAKE_INFERENCE_DEVICE).")
    ] = None,
    log_level: Annotated[str, typer.Option(help="uvicorn log level.")] = "info",
    http_fd: Annotated[
        int | None, typer.Option(hidden=True, help="A bound REST socket handed down by `nbake serve`.")
    ] = None,
    grpc_fd: Annotated[
        int | None, typer.Option(hidden=True, help="A reserved gRPC port handed down by `nbake serve`.")
    ] = None,
    outlive_parent: OutliveParent = False,
) -> None:
    """Serve trained artifacts for queries and renders, over REST and gRPC.

    REST: GET /v1/models, POST /v1/artifacts/{id}:query and :render (OpenAPI at /docs); gRPC: the
    InferenceService. Tokens are the job server's (start `nbake serve` once)."""
    if not outlive_parent:
        die_with_parent()
    try:
        settings = InferenceSettings.from_env(
            data_dir,
            memory_budget_bytes=memory_bytes,
            working_bytes=working_bytes,
            reading_bytes=reading_bytes,
            max_waiting=max_waiting,
            chunk_rows=chunk_rows,
            max_wait_ms=max_wait_ms,
            max_rows=max_rows,
            torch_threads=torch_threads,
            device=device,
        )
    except ValueError as error:
        fail("settings", str(error))
    # Both ports are taken before the app loads models or opens the database, so a port in use is an error
    # at once, and neither can be lost to another process while it starts (`services.platform.ports`).
    if http_fd is not None:
        http = inherited("--http-fd", http_fd)
    else:
        http = taken("--port", http_socket, host, port)
    if grpc_fd is not None:
        reservation = inherited("--grpc-fd", grpc_fd)
    else:
        reservation = taken("--grpc-port", reserved_port, host, grpc_port)
    app = create_inference_app(settings, host, reservation.getsockname()[1], reservation)
    serve_app(app, http, log_level)
