"""A small client of the live twin (pyzmq): what a robot team's software does, and what
the bench drives `twin serve` with."""

from __future__ import annotations

import json

import zmq


class LiveClient:
    def __init__(self, endpoint: str, timeout_s: float = 600.0):
        self.sock = zmq.Context.instance().socket(zmq.REQ)
        self.sock.setsockopt(zmq.RCVTIMEO, int(timeout_s * 1000))
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(endpoint)

    def call(self, cmd: str, **kw) -> tuple[dict, list[bytes]]:
        """(the reply, its further frames: a render's PNG, mask, depth)."""
        self.sock.send(json.dumps({"cmd": cmd, **kw}).encode())
        first, *frames = self.sock.recv_multipart()
        return json.loads(first), frames

    def __call__(self, cmd: str, **kw) -> dict:
        reply, _ = self.call(cmd, **kw)
        if not reply.get("ok"):
            raise RuntimeError(f"{cmd}: {reply.get('error')}")
        return reply

    def close(self) -> None:
        self.sock.close()
