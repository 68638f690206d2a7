"""The sockets a server command listens on, taken before anything else starts (`services.platform.ports`):
bound by the command itself, or handed down by the parent that bound them (`nbake serve --inference-port`
binds the inference service's ports before its Ray cluster starts and passes them to the child process)."""

from __future__ import annotations

import socket
from collections.abc import Callable

from services.cli.errors import fail


def taken(option: str, bind: Callable[[str, int], socket.socket], host: str, port: int) -> socket.socket:
    """The port, bound now, or the error of a port in use."""
    try:
        return bind(host, port)
    except OSError as error:
        fail(option, f"cannot listen on {host}:{port}: {error.strerror}")


def inherited(option: str, descriptor: int) -> socket.socket:
    """The socket a parent passed as file descriptor `descriptor`, or the error of one that is not."""
    try:
        handed = socket.socket(fileno=descriptor)
    except OSError as error:
        fail(option, f"file descriptor {descriptor} is not a socket: {error.strerror}")
    if handed.type != socket.SOCK_STREAM:
        handed.detach()
        fail(option, f"file descriptor {descriptor} is not a TCP socket")
    return handed
