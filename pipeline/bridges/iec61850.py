"""IEC 61850 in: one poller process per server (mms_poller), its events into the hub.

A server that goes away makes its signals stale (they hold their last value); when it
is back, the next good reads make them live. A poller process that dies is started
again. Polling only: the sample's IEDs and most gateways answer reads; buffered reports
would lower the latency below the poll period, and are not used yet.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from itertools import groupby

from .hub import SignalHub
from .inputs import Signal

RESTART_S = 1.0


class MmsPoller:
    """The signals of one server, polled by a process of their own."""

    def __init__(self, host: str, port: int, signals: list[Signal], hub: SignalHub, timeout_ms: int = 1000):
        self.host, self.port, self.signals, self.hub = host, port, signals, hub
        self.by_index = {s.index: s for s in signals}
        self.timeout_ms = timeout_ms
        self._stop = threading.Event()
        self._process: subprocess.Popen | None = None
        self._thread = threading.Thread(target=self._run, name=f"iec61850 {host}:{port}", daemon=True)

    def start(self) -> "MmsPoller":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        process = self._process
        if process is not None and process.poll() is None:
            process.stdin.close()  # the poller ends at EOF
            try:
                process.wait(timeout=3)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        self._thread.join(timeout=5)

    def _job(self) -> str:
        return json.dumps({"timeout_ms": self.timeout_ms, "signals": [
            {"i": s.index, "ref": s.path, "q": s.quality_reference, "fc": s.fc, "period_s": s.period_s}
            for s in self.signals]}) + "\n"

    def _run(self) -> None:
        while not self._stop.is_set():
            self._process = subprocess.Popen(
                [sys.executable, "-m", "pipeline.bridges.mms_poller", self.host, str(self.port)],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, bufsize=1)
            self._process.stdin.write(self._job())
            self._process.stdin.flush()
            for line in self._process.stdout:
                self._event(json.loads(line))
            self._process.wait()
            if not self._stop.is_set():
                self._all_stale(f"the poller of {self.host}:{self.port} stopped (exit {self._process.returncode})")
                self._stop.wait(RESTART_S)

    def _event(self, event: dict) -> None:
        if "down" in event:
            self._all_stale(event["down"])
            return
        signal = self.by_index.get(event.get("i"))
        if signal is None:
            return
        if "error" in event:
            self.hub.fault(signal, event["error"])
            self.hub.stale(signal, event["error"])
        elif not event["good"]:
            self.hub.stale(signal, "its quality is not good")
        else:
            self.hub.receive(signal, event["value"])

    def _all_stale(self, why: str) -> None:
        for s in self.signals:
            self.hub.stale(s, why)


def start_pollers(signals: list[Signal], hub: SignalHub) -> list[MmsPoller]:
    """One poller per server among the iec61850:// signals."""
    mine = sorted((s for s in signals if s.scheme == "iec61850"), key=lambda s: (s.host, s.port, s.index))
    return [MmsPoller(host, port, list(group), hub).start()
            for (host, port), group in groupby(mine, key=lambda s: (s.host, s.port))]
