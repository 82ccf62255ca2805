"""Every client an inputs file needs, started together and stopped together."""

from __future__ import annotations

from .hub import SignalHub
from .iec61850 import start_pollers
from .inputs import Signal
from .mqtt import start_subscribers


class Feeds:
    """`with Feeds(signals) as feeds:` the clients run; `feeds.hub.drain()` gives what
    changed since the last call."""

    def __init__(self, signals: list[Signal]):
        self.hub = SignalHub(signals)
        self.clients: list = []

    def __enter__(self) -> "Feeds":
        self.clients = start_subscribers(self.hub.signals, self.hub) + start_pollers(self.hub.signals, self.hub)
        return self

    def __exit__(self, *exc) -> None:
        for client in self.clients:
            client.stop()
