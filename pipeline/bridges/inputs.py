"""`twin serve --inputs FILE`: external signals mapped onto the twin's settable inputs.

```toml
scl = "substation.scd"                               # optional: checks every reference
[[signal]]
source = "mqtt://127.0.0.1:1883/site/RE-A1/oil"      # broker and topic
json_pointer = "/level"                              # optional: a field of a JSON payload
target = "render.reactor_A1.oil_level_tank"          # NODE.PORT, as `set` takes it
scale = 1.0                                          # optional: value * scale + offset
offset = 0.0
[[signal]]
source = "iec61850://127.0.0.1:10102/IED1LD0/XCBR1.Pos.stVal"
target = "render.breaker_52_1A.open"
map = { off = 1.0, on = 0.0, intermediate = 0.5 }    # Dbpos; bad-state -> stale
period_s = 0.5                                       # poll period
```

Every problem of the file is found before anything connects and reported at once, in
one error naming each signal.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote, urlsplit

from .. import config
from ..errors import UserError

DEFAULT_PORTS = {"mqtt": 1883, "iec61850": 102}
DBPOS = ("intermediate", "off", "on", "bad")  # IEC 61850-7-3 double point, by code
_DEFAULT_FC = {"stVal": "ST", "q": "ST", "t": "ST", "mag": "MX", "cVal": "MX", "instMag": "MX", "instCVal": "MX"}


@dataclass(frozen=True)
class Signal:
    index: int  # its place in the file, from 1
    source: str  # as written
    scheme: str  # "mqtt" | "iec61850"
    host: str
    port: int
    path: str  # MQTT: the topic; IEC 61850: the object reference LD/LN.DO.DA
    target: str  # NODE.PORT
    json_pointer: str | None = None
    scale: float = 1.0
    offset: float = 0.0
    map: dict[str, float] | None = field(default=None, hash=False)
    period_s: float = 1.0
    fc: str | None = None

    @property
    def name(self) -> str:
        return f"signal[{self.index}] ({self.source})"

    @property
    def endpoint(self) -> tuple[str, str, int]:
        return self.scheme, self.host, self.port

    @property
    def quality_reference(self) -> str:
        """The `q` beside an IEC 61850 attribute: LN.DO.q for LN.DO.stVal and LN.DO.mag.f."""
        ld, _, rest = self.path.partition("/")
        parts = rest.split(".")
        return f"{ld}/{parts[0]}.{parts[1]}.q" if len(parts) >= 3 else ""


def _parse_source(source: str) -> tuple[str, str, int, str]:
    """(scheme, host, port, path); raises ValueError saying what is wrong."""
    url = urlsplit(source)
    if url.scheme not in DEFAULT_PORTS:
        raise ValueError(f"unknown scheme {url.scheme!r} (mqtt:// or iec61850://)")
    if not url.hostname:
        raise ValueError("no host")
    try:
        port = url.port or DEFAULT_PORTS[url.scheme]
    except ValueError:
        raise ValueError("the port is not a number from 1 to 65535") from None
    if url.query or url.fragment or url.username or url.password:
        raise ValueError("no query, fragment or credentials in a source (put them nowhere in this file)")
    path = unquote(url.path.lstrip("/"))
    if url.scheme == "mqtt":
        if not path:
            raise ValueError("no topic")
        if "+" in path or "#" in path:
            raise ValueError("a signal is one topic: no + or # wildcards")
    else:
        ld, slash, rest = path.partition("/")
        parts = rest.split(".")
        if not ld or not slash or len(parts) < 3 or not all(parts):
            raise ValueError("an IEC 61850 source names LD/LN.DO.DA (e.g. IED1LD0/XCBR1.Pos.stVal)")
    return url.scheme, url.hostname, port, path


def _fc_of(path: str) -> str | None:
    attribute = path.partition("/")[2].split(".")[2]
    return _DEFAULT_FC.get(attribute)


def read_inputs(path: Path, settable: Collection[str] | None = None) -> list[Signal]:
    """The signals of an inputs file. `settable`: the twin's settable ports (NODE.PORT),
    None to leave targets unchecked. Raises one UserError listing every problem."""
    path = Path(path)
    data = config.read_toml(path)
    config.validate(data, "inputs", path)
    known = None
    if "scl" in data:
        from .scl import references

        scl_path = (path.parent / data["scl"]).resolve()
        known = references(scl_path)
    signals, problems = [], []
    for i, raw in enumerate(data["signal"], start=1):
        where = f"signal[{i}] ({raw['source']})"
        try:
            scheme, host, port, ref = _parse_source(raw["source"])
        except ValueError as e:
            problems.append(f"{where}: source: {e}")
            continue
        fc = raw.get("fc")
        if scheme == "iec61850":
            if raw.get("json_pointer") is not None:
                problems.append(f"{where}: json_pointer is for MQTT payloads; an IEC 61850 value is one attribute")
            if known is not None:
                if ref not in known:
                    problems.append(f"{where}: {ref} is not in the data model of {data['scl']}")
                    continue
                if fc is not None and known[ref] != fc:
                    problems.append(f"{where}: fc {fc} but {data['scl']} declares {ref} under {known[ref]}")
                fc = fc or known[ref]
            fc = fc or _fc_of(ref)
            if fc is None:
                problems.append(f"{where}: fc: not known for {ref}: give `fc` or an `scl` file")
        if settable is not None and raw["target"] not in settable:
            problems.append(f"{where}: target {raw['target']!r} is not a settable port of the twin")
        signals.append(Signal(index=i, source=raw["source"], scheme=scheme, host=host, port=port, path=ref,
                              target=raw["target"], json_pointer=raw.get("json_pointer"),
                              scale=float(raw.get("scale", 1.0)), offset=float(raw.get("offset", 0.0)),
                              map=dict(raw["map"]) if "map" in raw else None,
                              period_s=float(raw.get("period_s", 1.0)), fc=fc))
    targets: dict[str, str] = {}
    for s in signals:
        if s.target in targets:
            problems.append(f"{s.name}: target {s.target!r} is already fed by {targets[s.target]}")
        targets.setdefault(s.target, s.name)
    if problems:
        if len(problems) == 1:
            sig, _, message = problems[0].partition(": ")
            raise UserError(path, sig, message)
        raise UserError(path, None, f"{len(problems)} problems:\n  " + "\n  ".join(problems))
    return signals
