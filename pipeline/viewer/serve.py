"""`twin view`: build/ over HTTP on the loopback interface, as any static server would
(the pages fetch ../scene/, ../tiles/ and ../runs/ beside viewer/)."""

from __future__ import annotations

import functools
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

# types a browser insists on (module scripts, WebAssembly) or that the system's
# mime.types may not know
TYPES = {".js": "text/javascript", ".mjs": "text/javascript", ".wasm": "application/wasm", ".json": "application/json",
         ".glb": "model/gltf-binary", ".gltf": "model/gltf+json", ".bin": "application/octet-stream",
         ".jsonl": "application/x-ndjson", ".usda": "text/plain", ".sdf": "application/xml"}


class _Handler(SimpleHTTPRequestHandler):
    extensions_map = {**SimpleHTTPRequestHandler.extensions_map, **TYPES}

    def log_message(self, format, *args):  # noqa: A002 (the base class's name)
        pass  # a page load is hundreds of requests


def server(build: Path, port: int = 0, host: str = "127.0.0.1") -> ThreadingHTTPServer:
    """A server of `build` (not yet serving); port 0 picks a free one."""
    handler = functools.partial(_Handler, directory=str(Path(build).resolve()))
    return ThreadingHTTPServer((host, port), handler)


def address(srv: ThreadingHTTPServer) -> str:
    host, port = srv.server_address[:2]
    return f"http://{host}:{port}/"


def in_background(build: Path, port: int = 0) -> ThreadingHTTPServer:
    """A server of `build` running in a daemon thread (tests, the bench); shut it down
    with .shutdown()."""
    srv = server(build, port)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    return srv
