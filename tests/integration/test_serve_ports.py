"""`nbake serve` takes its ports before Ray starts its own servers on random ports: the gRPC port is held
by a reservation that gRPC can share and nothing else can, and a port in use is a clear error at once. The
inference service's ports too: `nbake serve --inference-port` takes them before Ray and hands them to its
child `nbake serve-inference`, which serves them as they are."""

from __future__ import annotations

import contextlib
import signal
import socket
import time
from concurrent import futures
from pathlib import Path

import grpc
import httpx
import pytest
from grpc_health.v1 import health, health_pb2, health_pb2_grpc
from neuralbake_client.cli.main import app
from typer.testing import CliRunner

from services.cli import serve
from services.platform.ports import http_socket, reserved_port
from tests.support.ports import free_port


def test_a_reserved_port_is_refused_to_others_and_shared_with_grpc():
    reservation = reserved_port("127.0.0.1", 0)
    port = reservation.getsockname()[1]
    for option in (socket.SO_REUSEADDR, None):
        with socket.socket() as other, pytest.raises(OSError):
            if option is not None:
                other.setsockopt(socket.SOL_SOCKET, option, 1)
            other.bind(("127.0.0.1", port))
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=1))
    health_pb2_grpc.add_HealthServicer_to_server(health.HealthServicer(), server)
    assert server.add_insecure_port(f"127.0.0.1:{port}") == port
    reservation.close()
    server.start()
    try:
        with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
            reply = health_pb2_grpc.HealthStub(channel).Check(health_pb2.HealthCheckRequest(), timeout=10)
        assert reply.status == health_pb2.HealthCheckResponse.SERVING
    finally:
        server.stop(None)


SERVE_PORTS = ("--port", "--grpc-port", "--inference-port", "--inference-grpc-port")


@pytest.mark.parametrize("option", SERVE_PORTS)
def test_serve_on_a_port_in_use_fails_before_starting_anything(tmp_path, monkeypatch, option):
    monkeypatch.setenv("NBAKE_TOKENS", "t:admin")
    started: list[Path] = []
    monkeypatch.setattr(serve, "start_ray", started.append)  # the suite's own Ray may already be up
    with http_socket("127.0.0.1", 0) as busy:
        busy.listen()
        ports = {name: str(free_port()) for name in SERVE_PORTS}
        ports[option] = str(busy.getsockname()[1])
        arguments = ["serve", *(part for pair in ports.items() for part in pair), "--outlive-parent"]
        result = CliRunner().invoke(app, [*arguments, "--data-dir", str(tmp_path / "data")])
    assert result.exit_code == 2, result.output
    assert f"error: {option}: cannot listen on 127.0.0.1:{ports[option]}" in result.stderr
    assert started == []  # no cluster was started for a server that cannot listen


@pytest.mark.parametrize("option", ["--port", "--grpc-port"])
def test_serve_inference_on_a_port_in_use_fails_at_once(tmp_path, monkeypatch, option):
    monkeypatch.setenv("NBAKE_TOKENS", "t:admin")
    with http_socket("127.0.0.1", 0) as busy:
        busy.listen()
        ports = {"--port": str(free_port()), "--grpc-port": str(free_port())}
        ports[option] = str(busy.getsockname()[1])
        arguments = ["serve-inference", *(part for pair in ports.items() for part in pair)]
        result = CliRunner().invoke(app, [*arguments, "--data-dir", str(tmp_path / "data")])
    assert result.exit_code == 2, result.output
    assert f"error: {option}: cannot listen on 127.0.0.1:{ports[option]}" in result.stderr


def test_serve_inference_serves_the_sockets_it_is_handed(tmp_path, monkeypatch):
    """`nbake serve --inference-port`'s child (`serve.start_inference`): the ports are bound here, passed as
    file descriptors and closed here; the child answers REST on the bound socket and gRPC on the reserved
    port."""
    monkeypatch.setenv("NBAKE_TOKENS", "t:admin")
    http, reservation = http_socket("127.0.0.1", 0), reserved_port("127.0.0.1", 0)
    port, grpc_port = http.getsockname()[1], reservation.getsockname()[1]
    child = serve.start_inference((http, reservation), "127.0.0.1", tmp_path / "data", "warning")
    assert http.fileno() == -1 and reservation.fileno() == -1  # this process's copies are closed
    try:
        deadline = time.monotonic() + 120
        while True:
            assert child.poll() is None, f"serve-inference exited with {child.returncode}"
            with contextlib.suppress(httpx.TransportError):
                if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=5).status_code == 200:
                    break
            assert time.monotonic() < deadline, "serve-inference never answered on the handed socket"
            time.sleep(0.2)
        with grpc.insecure_channel(f"127.0.0.1:{grpc_port}") as channel:
            reply = health_pb2_grpc.HealthStub(channel).Check(health_pb2.HealthCheckRequest(), timeout=10)
        assert reply.status == health_pb2.HealthCheckResponse.SERVING
        with socket.socket() as other, pytest.raises(OSError):
            other.bind(("127.0.0.1", grpc_port))  # the gRPC server holds it, the reservation closed
    finally:
        child.terminate()
        assert child.wait(30) in (0, -signal.SIGTERM)  # uvicorn shuts down, then re-raises the signal
