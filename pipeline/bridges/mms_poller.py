"""The process that polls one IEC 61850 server (`python -m pipeline.bridges.mms_poller`).

libiec61850's Python bindings hold the interpreter's lock for the whole of a blocking
call (a connect to a server that accepts and never answers blocks until its timeout), so an MMS client
in the twin's own process would stop its clock. It runs here instead, one process per
server, and speaks JSON lines: its parent writes one line, the signals to poll
({"signals": [{"i", "ref", "q", "fc", "period_s"}], "timeout_ms"}), and reads events:

    {"up": true}                          connected (again)
    {"down": "why"}                       connection lost or refused; retrying with back-off
    {"i": 3, "value": 63.5, "good": true} a value read (good: its quality's validity is good)
    {"i": 3, "error": "why"}              the server has no such attribute, or a type we cannot read

It ends when its parent closes its stdin (the parent is gone or done).
"""

from __future__ import annotations

import json
import sys
import threading
import time

BACKOFF_S = (0.2, 5.0)  # first retry, then doubling up to this


def _emit(event: dict) -> None:
    sys.stdout.write(json.dumps(event, separators=(",", ":")) + "\n")
    sys.stdout.flush()


class Lost(Exception):
    """The connection is gone (the server or the network): reconnect."""


def _read(L, con, ref: str, fc: int):
    """(value, error): a float, int, bool or double-point name, or why not. Raises Lost."""
    result = L.IedConnection_readObject(con, ref, fc)
    value, error = result if isinstance(result, tuple) else (result, L.IED_ERROR_OK)
    if error in (L.IED_ERROR_NOT_CONNECTED, L.IED_ERROR_CONNECTION_LOST, L.IED_ERROR_TIMEOUT):
        raise Lost(f"IedClientError {error}")
    if error != L.IED_ERROR_OK or not value:
        return None, f"read failed (IedClientError {error})"
    try:
        kind = L.MmsValue_getType(value)
        if kind == L.MMS_FLOAT:
            return float(L.MmsValue_toDouble(value)), None
        if kind == L.MMS_BOOLEAN:
            return bool(L.MmsValue_getBoolean(value)), None
        if kind == L.MMS_INTEGER:
            return int(L.MmsValue_toInt64(value)), None
        if kind == L.MMS_UNSIGNED:
            return int(L.MmsValue_toUint32(value)), None
        if kind == L.MMS_BIT_STRING and L.MmsValue_getBitStringSize(value) == 2:
            names = {L.DBPOS_INTERMEDIATE_STATE: "intermediate", L.DBPOS_OFF: "off", L.DBPOS_ON: "on",
                     L.DBPOS_BAD_STATE: "bad"}
            return names[L.Dbpos_fromMmsValue(value)], None
        if kind == L.MMS_BIT_STRING:
            return int(L.MmsValue_getBitStringAsInteger(value)), None
        if kind == L.MMS_DATA_ACCESS_ERROR:
            return None, "the server has no such attribute (data access error)"
        return None, f"an MMS value of type {kind} is not a number"
    finally:
        L.MmsValue_delete(value)


def _quality_good(L, con, ref: str, fc: int) -> bool:
    if not ref:
        return True
    result = L.IedConnection_readObject(con, ref, fc)
    value, error = result if isinstance(result, tuple) else (result, L.IED_ERROR_OK)
    if error in (L.IED_ERROR_NOT_CONNECTED, L.IED_ERROR_CONNECTION_LOST, L.IED_ERROR_TIMEOUT):
        raise Lost(f"IedClientError {error}")
    if error != L.IED_ERROR_OK or not value:
        return True  # no q beside it: nothing says the value is bad
    try:
        if L.MmsValue_getType(value) != L.MMS_BIT_STRING:
            return True
        return (L.Quality_fromMmsValue(value) & 0x3) == L.QUALITY_VALIDITY_GOOD
    finally:
        L.MmsValue_delete(value)


def poll(host: str, port: int, signals: list[dict], timeout_ms: int, stopped: threading.Event) -> None:
    import pyiec61850.pyiec61850 as L

    fcs = {s["i"]: getattr(L, f"IEC61850_FC_{s['fc']}") for s in signals}
    backoff = BACKOFF_S[0]
    while not stopped.is_set():
        con = L.IedConnection_create()
        L.IedConnection_setConnectTimeout(con, timeout_ms)
        L.IedConnection_setRequestTimeout(con, timeout_ms)
        result = L.IedConnection_connect(con, host, port)
        error = result[1] if isinstance(result, tuple) else result
        if error != L.IED_ERROR_OK:
            L.IedConnection_destroy(con)
            _emit({"down": f"cannot connect to {host}:{port} (IedClientError {error})"})
            stopped.wait(backoff)
            backoff = min(backoff * 2, BACKOFF_S[1])
            continue
        _emit({"up": True})
        backoff = BACKOFF_S[0]
        try:
            _poll_connected(L, con, signals, fcs, stopped)
        except Lost as e:
            _emit({"down": f"connection to {host}:{port} lost ({e})"})
            stopped.wait(BACKOFF_S[0])  # a server that accepts and drops at once is not hammered
        L.IedConnection_close(con)
        L.IedConnection_destroy(con)


def _poll_connected(L, con, signals: list[dict], fcs: dict, stopped: threading.Event) -> None:
    due = {s["i"]: 0.0 for s in signals}
    while not stopped.is_set():
        now = time.monotonic()
        for s in signals:
            if due[s["i"]] > now:
                continue
            due[s["i"]] = now + s["period_s"]
            value, why = _read(L, con, s["ref"], fcs[s["i"]])
            if why is not None:
                _emit({"i": s["i"], "error": why})
            else:
                _emit({"i": s["i"], "value": value, "good": _quality_good(L, con, s["q"], fcs[s["i"]])})
        if L.IedConnection_getState(con) != L.IED_STATE_CONNECTED:
            raise Lost("the connection closed")
        stopped.wait(max(0.0, min(due.values()) - time.monotonic()))


def main() -> None:
    host, port = sys.argv[1], int(sys.argv[2])
    job = json.loads(sys.stdin.readline())
    stopped = threading.Event()

    def watch_parent() -> None:
        sys.stdin.read()  # returns at EOF: the parent closed the pipe or died
        stopped.set()

    threading.Thread(target=watch_parent, daemon=True).start()
    try:
        poll(host, port, job["signals"], int(job.get("timeout_ms", 1000)), stopped)
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()
