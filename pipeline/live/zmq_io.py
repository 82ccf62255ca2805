"""The ZeroMQ side of the live twin (pyzmq, asyncio): a ROUTER command socket that REQ
and DEALER clients talk to, and a PUB socket for the published state.

The PUB socket never blocks the clock: past its high-water mark ZeroMQ drops messages
for the slow subscriber (which it does not count; a subscriber sees a gap in `seq`)."""

from __future__ import annotations

import zmq
import zmq.asyncio

PUB_HWM = 1000  # messages queued per subscriber before ZeroMQ drops for it


class ZmqSockets:
    def __init__(self, bind: str, port: int):
        self.ctx = zmq.asyncio.Context()
        self.router = self.ctx.socket(zmq.ROUTER)
        self.router.setsockopt(zmq.ROUTER_MANDATORY, 1)  # a reply to a vanished client raises
        self.router.setsockopt(zmq.LINGER, 0)
        self.pub = self.ctx.socket(zmq.PUB)
        self.pub.setsockopt(zmq.SNDHWM, PUB_HWM)
        self.pub.setsockopt(zmq.LINGER, 0)
        try:
            self.command_port = _bind(self.router, bind, port)
            self.publish_port = _bind(self.pub, bind, port + 1 if port else 0)
        except zmq.ZMQError:
            self.close()
            raise
        self.bind = bind

    @property
    def endpoints(self) -> dict:
        return {"commands": f"tcp://{self.bind}:{self.command_port}", "publish": f"tcp://{self.bind}:{self.publish_port}"}

    async def receive(self) -> tuple[list[bytes], list[bytes]]:
        """(envelope: the routing frames, the client's identity first and the empty
        delimiter of a REQ last; body frames)."""
        frames = await self.router.recv_multipart()
        if b"" in frames[1:]:
            cut = frames.index(b"", 1) + 1
        else:  # a DEALER that sent no delimiter
            cut = 1
        return frames[:cut], frames[cut:]

    async def reply(self, envelope: list[bytes], frames: list[bytes]) -> bool:
        """False when the client is gone (it vanished mid-request)."""
        try:
            await self.router.send_multipart(envelope + frames, flags=zmq.NOBLOCK)
            return True
        except zmq.ZMQError:
            return False

    def publish(self, data: bytes) -> None:
        try:
            self.pub.send(data, flags=zmq.NOBLOCK)
        except zmq.Again:
            pass  # PUB does not raise this; a guard should a transport ever block

    def close(self) -> None:
        for s in (self.router, self.pub):
            s.close(linger=0)
        self.ctx.term()


def _bind(sock, host: str, port: int) -> int:
    if port == 0:
        return sock.bind_to_random_port(f"tcp://{host}")
    sock.bind(f"tcp://{host}:{port}")
    return port
