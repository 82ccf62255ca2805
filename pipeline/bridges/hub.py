"""Every signal's last value, whether it is stale, and its faults.

Clients (one thread per IED or broker) `receive` into the hub; the live loop `drain`s it
once per step and applies what changed to its inputs. Nothing here blocks on the loop or
the loop on a client: a value received twice between two steps arrives once, as the last.
A stale signal keeps its last value (the twin holds it) and says so; it is live again at
its next good value. A fault (a payload that is no number, an unknown enumeration value,
a reference the server does not have) is counted and logged once per signal.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass

from .decode import BadValue, Stale, to_number
from .inputs import Signal

log = logging.getLogger("twin.inputs")


@dataclass
class SignalState:
    value: float | None = None  # the last good value
    stale: bool = True  # until the first good value
    received: int = 0  # values that came in, good or not
    faults: int = 0
    last_fault: str | None = None
    changed_at: float | None = None  # monotonic seconds of the last value or staleness change


@dataclass(frozen=True)
class Update:
    target: str
    value: float | None
    stale: bool
    signal: str  # the signal's name
    received_at: float  # monotonic seconds


class SignalHub:
    def __init__(self, signals: list[Signal]):
        self.signals = list(signals)
        self.states = {s.index: SignalState() for s in self.signals}
        self._lock = threading.Lock()
        self._changes: dict[str, Update] = {}
        self.on_change = None  # called (from a client's thread) after a change is recorded

    def receive(self, signal: Signal, raw) -> None:
        """A value from the source, as it came (decoded by the client's protocol)."""
        try:
            value = to_number(signal, raw)
        except Stale as e:
            self.stale(signal, str(e))
            return
        except BadValue as e:
            self.fault(signal, str(e))
            return
        now = time.monotonic()
        with self._lock:
            state = self.states[signal.index]
            state.received += 1
            if state.value == value and not state.stale:
                return
            state.value, state.stale, state.changed_at = value, False, now
            self._changes[signal.target] = Update(signal.target, value, False, signal.name, now)
        self._notify()

    def stale(self, signal: Signal, why: str) -> None:
        """The source cannot vouch for the value now (quality, server or broker gone)."""
        now = time.monotonic()
        with self._lock:
            state = self.states[signal.index]
            if state.stale and state.changed_at is not None:
                return
            first = state.changed_at is None
            state.stale, state.changed_at = True, now
            self._changes[signal.target] = Update(signal.target, state.value, True, signal.name, now)
        self._notify()
        if not first:
            log.info("%s: stale (%s); holding %s", signal.name, why, state.value)

    def _notify(self) -> None:
        callback = self.on_change
        if callback is not None:
            callback()

    def fault(self, signal: Signal, message: str) -> None:
        with self._lock:
            state = self.states[signal.index]
            state.received += 1
            state.faults += 1
            first, state.last_fault = state.faults == 1, message
        if first:  # once per signal: a sensor that sends garbage at 10 Hz must not flood the log
            log.warning("%s: %s (counted; further faults of this signal are not logged)", signal.name, message)

    def drain(self) -> list[Update]:
        """What changed since the last drain, one update per target, in target order."""
        with self._lock:
            changes, self._changes = self._changes, {}
        return [changes[t] for t in sorted(changes)]

    def status(self) -> dict[str, dict]:
        """Per signal: value, stale, received, faults, last fault (for `hello`/`get`)."""
        with self._lock:
            return {s.name: {"target": s.target, "value": self.states[s.index].value,
                             "stale": self.states[s.index].stale, "received": self.states[s.index].received,
                             "faults": self.states[s.index].faults, "last_fault": self.states[s.index].last_fault}
                    for s in self.signals}
