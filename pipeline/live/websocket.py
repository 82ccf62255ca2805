"""The browsers' side of the live twin (the `websockets` package): the live page at /,
the twin's description at /hello.json, and at /ws the published messages, the first
one a snapshot of every port (as a late subscriber's `get` would give).

Each browser has a bounded queue: the clock puts without waiting, a full queue drops
the message and counts it; the next message a browser receives says how many it missed."""

from __future__ import annotations

import asyncio
import http
import json
from pathlib import Path
from typing import Callable

from websockets.asyncio.server import ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

PAGE = Path(__file__).resolve().parent / "page.html"
QUEUE = 64  # messages a browser may fall behind before its messages drop


class _Client:
    def __init__(self):
        self.queue: asyncio.Queue[str] = asyncio.Queue(QUEUE)
        self.dropped = 0  # since its last delivered message


class WebSocketFeed:
    def __init__(self, hello: Callable[[], dict], snapshot: Callable[[], dict]):
        self.hello, self.snapshot = hello, snapshot
        self.clients: set[_Client] = set()
        self.dropped = 0  # over all browsers, since the start
        self.server = None
        self.port: int | None = None
        self._handlers: set[asyncio.Task] = set()

    async def start(self, bind: str, port: int) -> int:
        self.server = await serve(self._handler, bind, port, process_request=self._http, compression=None)
        self.port = self.server.sockets[0].getsockname()[1]
        return self.port

    def publish(self, message: dict) -> None:
        """Queue `message` for every browser, never waiting."""
        for c in self.clients:
            if c.queue.full():
                c.dropped += 1
                self.dropped += 1
                continue
            c.queue.put_nowait(_with_dropped(message, c))

    async def _handler(self, ws: ServerConnection) -> None:
        c = _Client()
        self.clients.add(c)
        self._handlers.add(asyncio.current_task())
        try:
            await ws.send(json.dumps(self.snapshot(), separators=(",", ":")))
            while True:
                await ws.send(await c.queue.get())
        except ConnectionClosed:
            pass
        finally:
            self.clients.discard(c)
            self._handlers.discard(asyncio.current_task())

    def _http(self, ws: ServerConnection, request: Request) -> Response | None:
        path = request.path.split("?")[0]
        if path == "/ws":
            return None  # the WebSocket handshake goes on
        if path in ("/", "/index.html"):
            return _response(PAGE.read_bytes(), "text/html; charset=utf-8")
        if path == "/hello.json":
            return _response(json.dumps(self.hello(), separators=(",", ":")).encode(), "application/json")
        return ws.respond(http.HTTPStatus.NOT_FOUND, "not found\n")

    async def close(self) -> None:
        if self.server is not None:
            # a handler waits on its queue, which nothing fills once the clock stops
            for task in list(self._handlers):
                task.cancel()
            self.server.close()
            try:
                await asyncio.wait_for(self.server.wait_closed(), 10)
            except asyncio.TimeoutError:
                pass


def _with_dropped(message: dict, c: _Client) -> str:
    if c.dropped:
        message = {**message, "dropped": c.dropped}
        c.dropped = 0
    return json.dumps(message, separators=(",", ":"))


def _response(body: bytes, kind: str) -> Response:
    headers = Headers([("Content-Type", kind), ("Content-Length", str(len(body))), ("Cache-Control", "no-store")])
    return Response(200, "OK", headers, body)
