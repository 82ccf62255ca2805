"""The live twin's protocol: requests parsed and checked against schemas/live.schema.json
(one sub-schema per command), replies and published messages built here. An error is a
reply, {"ok": false, "error": "..."} naming what is wrong, never an exception out of here."""

from __future__ import annotations

import datetime as dt
import json
from functools import lru_cache

from jsonschema import Draft202012Validator
from referencing import Registry, Resource

from ..config import SCHEMA_DIR

PROTOCOL = 1
COMMANDS = ("hello", "get", "set", "clock", "camera", "render", "shutdown")


class BadRequest(ValueError):
    """A request that cannot be served; its message is the reply's error."""


@lru_cache(maxsize=1)
def schema() -> dict:
    return json.loads((SCHEMA_DIR / "live.schema.json").read_text())


@lru_cache(maxsize=None)
def validator(name: str) -> Draft202012Validator:
    """The validator of one $defs entry (request_get, reply_render, published, ...)."""
    doc = schema()
    if name not in doc["$defs"]:
        raise KeyError(name)
    registry = Registry().with_resource(doc["$id"], Resource.from_contents(doc))
    return Draft202012Validator({"$ref": f"{doc['$id']}#/$defs/{name}"}, registry=registry)


def check(name: str, data) -> None:
    """ValueError with the first schema violation of `data` against $defs/name."""
    errors = sorted(validator(name).iter_errors(data), key=lambda e: list(e.absolute_path))
    if errors:
        e = errors[0]
        where = ".".join(str(p) for p in e.absolute_path)
        raise ValueError(f"{where + ': ' if where else ''}{e.message}")


def parse(raw: bytes) -> dict:
    """One request from its bytes: JSON, an object, a known cmd, the cmd's schema."""
    try:
        req = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise BadRequest(f"malformed JSON: {e}") from None
    if not isinstance(req, dict):
        raise BadRequest(f"a request is a JSON object with a \"cmd\", got {type(req).__name__}")
    cmd = req.get("cmd")
    if cmd is None:
        raise BadRequest("missing \"cmd\"")
    if cmd not in COMMANDS:
        raise BadRequest(f"unknown command {cmd!r} (commands: {', '.join(COMMANDS)})")
    try:
        check(f"request_{cmd}", req)
    except ValueError as e:
        raise BadRequest(f"{cmd}: {e}") from None
    return req


def error(message: str) -> dict:
    return {"ok": False, "error": message}


def encode(data: dict) -> bytes:
    """Replies and messages as compact UTF-8 JSON (NaN has no JSON form: null)."""
    return json.dumps(data, separators=(",", ":"), allow_nan=False, default=_plain).encode("utf-8")


def _plain(v):
    import numpy as np

    if isinstance(v, np.generic):
        return v.item()
    raise TypeError(f"{type(v).__name__} is not JSON")


def wall_time() -> str:
    return dt.datetime.now(dt.timezone.utc).isoformat(timespec="microseconds")


def published(seq: int, k: int, sim_time: dt.datetime, values: dict) -> dict:
    return {"seq": seq, "k": k, "sim_time": sim_time.isoformat(), "wall_time": wall_time(), "values": values}
