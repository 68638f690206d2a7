"""Clients that leave in the middle of a stream leak nothing: SSE followers of a job that never ends are
counted while they follow and the count returns to zero once their connections are cut (reset, not
closed politely). An API-only server (no scheduler) keeps the job queued, so the streams stay open."""

from __future__ import annotations

import socket
import struct
import time

from tests.integration.test_api_server import (
    QUICK_RENDER,
    TOKENS,
    DatabaseChoice,
    ServerThread,
    settings_for,
    submit,
)

FOLLOWERS = 20


def active_streams(client) -> float:
    text = client.get("/metrics").text
    return sum(
        float(line.split()[-1]) for line in text.splitlines() if line.startswith("nbake_sse_active_streams ")
    )


def open_follower(host: str, port: int, job_id: str) -> socket.socket:
    """A raw SSE request, read until the stream has started."""
    connection = socket.create_connection((host, port), timeout=30)
    request = (
        f"GET /v1/jobs/{job_id}/events HTTP/1.1\r\nHost: {host}\r\n"
        f"Authorization: Bearer {TOKENS['read']}\r\nAccept: text/event-stream\r\n\r\n"
    )
    connection.sendall(request.encode())
    received = b""
    while b"retry: 1000" not in received:
        chunk = connection.recv(4096)
        assert chunk, received
        received += chunk
    return connection


def wait_until(predicate, timeout: float = 60) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.2)
    return True


def test_sse_followers_that_disconnect_leak_no_streams(tmp_path):
    settings = settings_for(tmp_path / "data", DatabaseChoice("sqlite", None), scheduling=False)
    with ServerThread(settings) as server, server.client("admin") as client:
        job = submit(client, **QUICK_RENDER)
        host, port = server.socket.getsockname()
        followers = [open_follower(host, port, job["id"]) for _ in range(FOLLOWERS)]
        assert wait_until(lambda: active_streams(client) == FOLLOWERS), active_streams(client)
        for connection in followers:  # a reset, as a killed client or a dropped network gives
            connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            connection.close()
        assert wait_until(lambda: active_streams(client) == 0), active_streams(client)
        assert client.get(f"/v1/jobs/{job['id']}").status_code == 200  # the server still answers
