"""`twin view`: build/ over HTTP on the loopback interface (the pages fetch ../scene/,
../tiles/ and ../runs/ beside viewer/).

Only what a page needs leaves the machine's loopback, and only to a page of its own:
- regular files inside the build, nothing else: a symlink that leads out of the build
  (one planted in build/viewer/ could serve /etc/passwd), a dotfile or dot-folder
  (.state.json holds absolute source paths, .cache/ every build's inputs) and a folder
  listing are all "404 not found";
- a request whose `Host:` is not this server's loopback address and port is refused
  (421): a web page that rebinds its own name to 127.0.0.1 (DNS rebinding) sends its
  own name there, so it cannot read the model through the user's browser.
"""

from __future__ import annotations

import email.utils
import errno
import functools
import os
import stat
import threading
from http import HTTPStatus
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

DEFAULT_PORT = 8000
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")

# types a browser insists on (module scripts, WebAssembly) or that the system's
# mime.types may not know
TYPES = {".js": "text/javascript", ".mjs": "text/javascript", ".wasm": "application/wasm", ".json": "application/json",
         ".glb": "model/gltf-binary", ".gltf": "model/gltf+json", ".bin": "application/octet-stream",
         ".jsonl": "application/x-ndjson", ".usda": "text/plain", ".sdf": "application/xml"}


class _Handler(SimpleHTTPRequestHandler):
    extensions_map = {**SimpleHTTPRequestHandler.extensions_map, **TYPES}

    def log_message(self, format, *args):  # noqa: A002 (the base class's name)
        pass  # a page load is hundreds of requests

    def send_head(self):
        if not self._host_is_ours():
            self.send_error(HTTPStatus.MISDIRECTED_REQUEST, "only this machine's loopback address is served")
            return None
        path = self._regular_file()
        if path is None:
            self.send_error(HTTPStatus.NOT_FOUND, "File not found")
            return None
        try:
            # O_NOFOLLOW: a symlink put in place after the check is not followed either
            f = os.fdopen(os.open(path, os.O_RDONLY | os.O_NOFOLLOW), "rb")
        except OSError:
            self.send_error(HTTPStatus.NOT_FOUND, "File not found")
            return None
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            f.close()
            self.send_error(HTTPStatus.NOT_FOUND, "File not found")
            return None
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-type", self.guess_type(path))
        self.send_header("Content-Length", str(st.st_size))
        self.send_header("Last-Modified", email.utils.formatdate(st.st_mtime, usegmt=True))
        self.end_headers()
        return f

    def list_directory(self, path):  # never reached through send_head; kept shut all the same
        self.send_error(HTTPStatus.NOT_FOUND, "File not found")
        return None

    def _host_is_ours(self) -> bool:
        hosts = self.headers.get_all("Host") or []
        if len(hosts) != 1:
            return False
        port = self.server.server_address[1]
        wanted = {f"{name}:{port}" for name in LOOPBACK_NAMES}
        if port == 80:  # a browser leaves the default port out
            wanted.update(LOOPBACK_NAMES)
        return hosts[0].strip().lower() in wanted

    def _regular_file(self) -> str | None:
        """The real path of the regular file the request names inside the build (a
        folder's index.html for a URL ending in /), or None."""
        root = os.path.realpath(self.directory)
        wanted = self.translate_path(self.path)  # URL-decoded; ../ never climbs above root
        if any(part.startswith(".") for part in Path(os.path.relpath(wanted, root)).parts):
            return None
        if os.path.isdir(wanted):
            if not self.path.split("?", 1)[0].split("#", 1)[0].endswith("/"):
                return None
            wanted = os.path.join(wanted, "index.html")
        real = os.path.realpath(wanted)
        if os.path.commonpath([root, real]) != root:
            return None  # a symlink somewhere on the way leads out of the build
        if any(part.startswith(".") for part in Path(os.path.relpath(real, root)).parts):
            return None  # or into a hidden corner of it
        return real if os.path.isfile(real) else None


def server(build: Path, port: int | None = 0, host: str = "127.0.0.1") -> ThreadingHTTPServer:
    """A server of `build` (not yet serving). port 0 picks a free one; None tries
    DEFAULT_PORT and picks a free one when another program holds it."""
    handler = functools.partial(_Handler, directory=str(Path(build).resolve()))
    if port is None:
        try:
            return ThreadingHTTPServer((host, DEFAULT_PORT), handler)
        except OSError as e:
            if e.errno != errno.EADDRINUSE:
                raise
            port = 0
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
