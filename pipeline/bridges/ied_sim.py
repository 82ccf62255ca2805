"""A real IEC 61850 server (libiec61850 through pyiec61850-ng) on loopback, for the tests
and the bench: the IED end of `twin serve --inputs`.

`python -m pipeline.bridges.ied_sim MODEL.cfg PORT` prints "ready" once it listens, then
takes commands on stdin, one per line, and answers "ok" to each:
    dbpos REF on|off|intermediate|bad      a double point's stVal (REF: LD/LN.DO.stVal)
    float REF VALUE                        a FLOAT32 attribute (REF: LD/LN.DO.mag.f)
    quality REF good|invalid|questionable  a quality attribute (REF: LD/LN.DO.q)
It stops at the end of its stdin (or when killed: the tests kill it to take it away).
MODEL.cfg is libiec61850's configuration-file model (tests/data/iec61850/bay_ied.cfg).
"""

from __future__ import annotations

import sys

DBPOS = {"on": "DBPOS_ON", "off": "DBPOS_OFF", "intermediate": "DBPOS_INTERMEDIATE_STATE", "bad": "DBPOS_BAD_STATE"}
VALIDITY = {"good": "QUALITY_VALIDITY_GOOD", "invalid": "QUALITY_VALIDITY_INVALID",
            "questionable": "QUALITY_VALIDITY_QUESTIONABLE"}


def main() -> None:
    import pyiec61850.pyiec61850 as L
    from pyiec61850.server.server import IedServer

    server = IedServer(sys.argv[1])
    server.start(int(sys.argv[2]))
    print("ready", flush=True)
    for line in sys.stdin:
        cmd, ref, value = line.split()
        if cmd == "dbpos":
            attribute = server._resolve_attribute(ref)
            L.IedServer_lockDataModel(server._server)
            L.IedServer_updateDbposValue(server._server, attribute, getattr(L, DBPOS[value]))
            L.IedServer_unlockDataModel(server._server)
        elif cmd == "float":
            server.update_float(ref, float(value))
        elif cmd == "quality":
            server.update_quality(ref, getattr(L, VALIDITY[value]))
        print("ok", flush=True)
    server.stop()


if __name__ == "__main__":
    main()
