"""A load generator that costs the machine little: HTTP/1.1 keep-alive requests written and parsed on raw
asyncio streams, one connection per simulated client. httpx's async client spends about as much CPU per
request as the server does, and on the shared 2-core machine that CPU is taken from the server measured.

Only what the benches send and the servers answer is handled: a body with Content-Length out, a
Content-Length or chunked body back, and Server-Sent Events as the job server chunks them.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from dataclasses import dataclass
from typing import Any


@dataclass
class Reply:
    status: int
    headers: dict[str, str]
    body: bytes

    def json(self) -> Any:
        return json.loads(self.body)


class Connection:
    """One keep-alive connection to `host:port`; reopened after the server closes it."""

    def __init__(self, host: str, port: int, headers: dict[str, str] | None = None):
        self.host, self.port = host, port
        self.headers = "".join(f"{name}: {value}\r\n" for name, value in (headers or {}).items())
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None

    async def request(
        self,
        method: str,
        path: str,
        body: Any = None,
        headers: dict | None = None,
        content: bytes | None = None,
        content_type: str = "application/json",
    ) -> Reply:
        """`body` is sent as JSON; `content` as it is, with `content_type`."""
        if self._writer is None:
            self._reader, self._writer = await asyncio.open_connection(self.host, self.port)
        payload = content if content is not None else None if body is None else json.dumps(body).encode()
        extra = "".join(f"{name}: {value}\r\n" for name, value in (headers or {}).items())
        head = f"{method} {path} HTTP/1.1\r\nHost: {self.host}:{self.port}\r\n{self.headers}{extra}"
        if payload is not None:
            head += f"Content-Type: {content_type}\r\nContent-Length: {len(payload)}\r\n"
        self._writer.write(head.encode() + b"\r\n" + (payload or b""))
        try:
            reply = await self._read_reply()
        except (OSError, asyncio.IncompleteReadError):
            await self.close()
            raise
        if reply.headers.get("connection", "").lower() == "close":
            await self.close()
        return reply

    async def events(self, path: str, on_event) -> int:
        """GET a Server-Sent Events stream and call `on_event(id, event, data)` for each event until the
        server ends the stream (this connection is then closed); the HTTP status."""
        assert self._writer is None, "a stream takes a connection of its own"
        self._reader, self._writer = await asyncio.open_connection(self.host, self.port)
        head = f"GET {path} HTTP/1.1\r\nHost: {self.host}:{self.port}\r\n{self.headers}"
        self._writer.write(head.encode() + b"Accept: text/event-stream\r\n\r\n")
        status = int((await self._reader.readuntil(b"\r\n")).split(b" ", 2)[1])
        while await self._reader.readuntil(b"\r\n") != b"\r\n":
            pass
        fields: dict[str, str] = {}
        try:
            while size := int((await self._reader.readuntil(b"\r\n")).split(b";")[0], 16):
                chunk = (await self._reader.readexactly(size + 2))[:-2].decode()
                for line in chunk.split("\n"):  # the server sends whole events per chunk
                    if line == "":
                        if "data" in fields:
                            on_event(int(fields["id"]), fields["event"], json.loads(fields["data"]))
                        fields = {}
                    elif not line.startswith(":"):
                        name, _, value = line.partition(":")
                        fields[name] = value.removeprefix(" ")
        finally:
            await self.close()
        return status

    async def _read_reply(self) -> Reply:
        assert self._reader is not None
        status_line = await self._reader.readuntil(b"\r\n")
        status = int(status_line.split(b" ", 2)[1])
        headers = {}
        while (line := await self._reader.readuntil(b"\r\n")) != b"\r\n":
            name, _, value = line.decode("latin-1").partition(":")
            headers[name.strip().lower()] = value.strip()
        if headers.get("transfer-encoding", "").lower() == "chunked":
            body = bytearray()
            while size := int((await self._reader.readuntil(b"\r\n")).split(b";")[0], 16):
                body += await self._reader.readexactly(size)
                await self._reader.readexactly(2)
            await self._reader.readuntil(b"\r\n")
            return Reply(status, headers, bytes(body))
        return Reply(status, headers, await self._reader.readexactly(int(headers.get("content-length", 0))))

    async def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            with contextlib.suppress(OSError):
                await self._writer.wait_closed()
        self._reader = self._writer = None
