"""`nbake serve` takes its ports before Ray starts its own servers on random ports: the gRPC port is held
by a reservation that gRPC can share and nothing else can, and a port in use is a clear error at once."""

from __future__ import annotations

import socket
from concurrent import futures
from pathlib import Path

import grpc
import pytest
from grpc_health.v1 import health, health_pb2, health_pb2_grpc
from neuralbake_client.cli.main import app
from typer.testing import CliRunner

from services.api.ports import http_socket, reserved_port
from services.cli import serve
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


@pytest.mark.parametrize("option", ["--port", "--grpc-port"])
def test_serve_on_a_port_in_use_fails_before_starting_anything(tmp_path, monkeypatch, option):
    monkeypatch.setenv("NBAKE_TOKENS", "t:admin")
    started: list[Path] = []
    monkeypatch.setattr(serve, "start_ray", started.append)  # the suite's own Ray may already be up
    with http_socket("127.0.0.1", 0) as busy:
        busy.listen()
        ports = {"--port": str(free_port()), "--grpc-port": str(free_port())}
        ports[option] = str(busy.getsockname()[1])
        arguments = ["serve", *(part for pair in ports.items() for part in pair), "--outlive-parent"]
        result = CliRunner().invoke(app, [*arguments, "--data-dir", str(tmp_path / "data")])
    assert result.exit_code == 2, result.output
    assert f"error: {option}: cannot listen on 127.0.0.1:{ports[option]}" in result.stderr
    assert started == []  # no cluster was started for a server that cannot listen
