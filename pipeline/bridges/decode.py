"""A received value to the number a port takes.

MQTT payloads are text: a JSON document (a `json_pointer` picks a field, RFC 6901) or a
bare number, `true`/`false`, or an enumeration name. IEC 61850 values come decoded
(float, int, bool, or a double point's name). An enumeration goes through the signal's
`map`; a double point in bad state, like a quality that is not good, makes the signal
stale rather than wrong.
"""

from __future__ import annotations

import json
import math

from .inputs import Signal


class BadValue(ValueError):
    """A payload the signal cannot turn into a number: counted and logged, never raised
    past the bridge."""


class Stale(Exception):
    """The source says its value is not to be trusted (double point bad-state)."""


def pointer(document, path: str):
    """RFC 6901: the part of `document` at `path` ("" is the whole)."""
    if path == "":
        return document
    node = document
    for token in path[1:].split("/"):
        token = token.replace("~1", "/").replace("~0", "~")
        if isinstance(node, dict):
            if token not in node:
                raise BadValue(f"no {token!r} in the payload at {path}")
            node = node[token]
        elif isinstance(node, list):
            if not token.isdigit() or int(token) >= len(node):
                raise BadValue(f"no item {token!r} in the payload at {path}")
            node = node[int(token)]
        else:
            raise BadValue(f"the payload has no field {path}")
    return node


def mqtt_value(signal: Signal, payload: bytes):
    """The raw value an MQTT payload carries for `signal`."""
    try:
        text = payload.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise BadValue("the payload is not UTF-8 text") from None
    if signal.json_pointer is not None:
        try:
            document = json.loads(text)
        except json.JSONDecodeError as e:
            raise BadValue(f"the payload is not JSON ({e.msg})") from None
        return pointer(document, signal.json_pointer)
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text  # a bare enumeration name


def to_number(signal: Signal, raw) -> float:
    """`raw` through the signal's map, then value * scale + offset. Raises BadValue or Stale."""
    if signal.map is not None:
        if raw == "bad":
            raise Stale("double point in bad state")
        key = raw if isinstance(raw, str) else json.dumps(raw)
        if key not in signal.map:
            raise BadValue(f"{raw!r} is not one of the map's values ({', '.join(sorted(signal.map))})")
        value = signal.map[key]
    elif isinstance(raw, bool):
        value = 1.0 if raw else 0.0
    elif isinstance(raw, (int, float)):
        value = float(raw)
    else:
        raise BadValue(f"{raw!r} is not a number (give the signal a `map` for enumerations)")
    value = value * signal.scale + signal.offset
    if not math.isfinite(value):
        raise BadValue(f"{raw!r} gives a value that is not finite")
    return value
