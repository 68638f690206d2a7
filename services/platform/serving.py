"""Running a server's app under uvicorn on a socket taken beforehand (`services.platform.ports`), the same
way for every server command."""

from __future__ import annotations

import contextlib
import socket
import sys

import uvicorn
from uvicorn.config import STARTUP_FAILURE

GRACEFUL_SHUTDOWN_S = 5


def serve_app(app, http: socket.socket, log_level: str) -> None:
    """Serve `app` on the bound `http` socket until the process is told to stop; exit with uvicorn's
    start-up failure status if the app never started (its lifespan failed)."""
    host, port = http.getsockname()[:2]
    config = uvicorn.Config(
        app, host=host, port=port, log_level=log_level, timeout_graceful_shutdown=GRACEFUL_SHUTDOWN_S
    )
    server = uvicorn.Server(config)
    with contextlib.suppress(KeyboardInterrupt):  # uvicorn has shut down gracefully by then
        server.run(sockets=[http])
    if not server.started:
        sys.exit(STARTUP_FAILURE)
