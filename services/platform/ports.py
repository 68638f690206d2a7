"""The server's ports, taken before Ray starts. `ray.init` brings up a GCS, a raylet and agents that bind
random free ports; a server that binds its own ports only after them can find one taken (a CI run lost its
gRPC port to a raylet this way, and the server exited at start-up). So `nbake serve` binds its HTTP socket
and reserves its gRPC port first, and a port in use is an error before anything has started.
"""

from __future__ import annotations

import socket


def _bound(host: str, port: int, option: int) -> socket.socket:
    bound = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    bound.setsockopt(socket.SOL_SOCKET, option, 1)
    try:
        bound.bind((host, port))
    except OSError:
        bound.close()
        raise
    return bound


def http_socket(host: str, port: int) -> socket.socket:
    """A socket bound to `host:port` (0: any free port), for uvicorn to listen on."""
    return _bound(host, port, socket.SO_REUSEADDR)


def reserved_port(host: str, port: int) -> socket.socket:
    """`host:port` (0: any free port) held for the gRPC server: bound with SO_REUSEPORT and never listening,
    so no other process can bind it, while gRPC, which binds with SO_REUSEPORT too, can. Close it once the
    gRPC server has bound.
    """
    return _bound(host, port, socket.SO_REUSEPORT)
