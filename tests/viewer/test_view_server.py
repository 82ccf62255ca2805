"""`twin view` as an attacker sees it: the real server (the CLI, in a subprocess) on a
small build folder, asked for what lies outside the build, for hidden files and
folder listings, with a foreign `Host:`, and started while its default port is taken."""

from __future__ import annotations

import http.client
import re
import socket
import subprocess
import sys
from pathlib import Path

import pytest

SECRET = "root:x:0:0:not-to-be-served"


def _start(out: Path, *args: str) -> tuple[subprocess.Popen, int]:
    proc = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "view", "--out", str(out), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    m = re.search(r"http://127\.0\.0\.1:(\d+)/viewer/index\.html", line)
    if m is None:
        proc.terminate()
        raise AssertionError(f"no address in {line!r}: {proc.communicate(timeout=30)[1][-2000:]}")
    return proc, int(m.group(1))


def _get(port: int, path: str, host: str | None = None) -> tuple[int, bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    try:
        if host is None:
            conn.request("GET", path)  # Host: 127.0.0.1:<port>, as a browser sends it
        else:
            conn.putrequest("GET", path, skip_host=True)
            conn.putheader("Host", host)
            conn.endheaders()
        r = conn.getresponse()
        return r.status, r.read()
    finally:
        conn.close()


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A build folder with a planted symlink, dotfiles and a folder without index,
    served by `twin view --port 0`: (build, port)."""
    root = tmp_path_factory.mktemp("view")
    outside = root / "outside"
    outside.mkdir()
    (outside / "passwd").write_text(SECRET + "\n")
    out = root / "build"
    (out / "viewer" / "app").mkdir(parents=True)
    (out / "viewer" / "index.html").write_text("<html>twinViewerReady</html>\n")
    (out / "viewer" / "app" / "viewer.js").write_text("export const ok = 1;\n")
    (out / "scene").mkdir()
    (out / "scene" / "mini.glb").write_bytes(b"glTF")
    (out / ".state.json").write_text('{"sources": "/home/someone/secret/sources"}\n')
    (out / ".cache").mkdir()
    (out / ".cache" / "entry.json").write_text("{}\n")
    (out / "viewer" / ".env").write_text("TOKEN=1\n")
    (out / "viewer" / "passwd").symlink_to(outside / "passwd")  # a file link out of the build
    (out / "viewer" / "up").symlink_to(outside)  # a folder link out of it
    (out / "viewer" / "same.js").symlink_to(out / "viewer" / "app" / "viewer.js")  # a link that stays inside
    proc, port = _start(out, "--port", "0")
    yield out, port
    proc.terminate()
    proc.wait(timeout=30)


def test_regular_files_of_the_build_are_served(served):
    _, port = served
    status, body = _get(port, "/viewer/index.html")
    assert status == 200 and b"twinViewerReady" in body
    assert _get(port, "/viewer/app/viewer.js")[0] == 200
    assert _get(port, "/scene/mini.glb") == (200, b"glTF")
    assert _get(port, "/viewer/same.js")[0] == 200  # a link inside the build is the file it names
    assert _get(port, "/viewer/")[0] == 200  # a folder's index.html


@pytest.mark.parametrize("path", ["/viewer/passwd", "/viewer/up/passwd", "/viewer/%75p/passwd",
                                  "/viewer/./up/passwd"])
def test_a_symlink_out_of_the_build_is_not_followed(served, path):
    _, port = served
    status, body = _get(port, path)
    assert status == 404, path
    assert SECRET.encode() not in body


@pytest.mark.parametrize("path", ["/.state.json", "/%2estate.json", "/.cache/entry.json", "/viewer/.env"])
def test_dotfiles_are_not_served(served, path):
    _, port = served
    status, body = _get(port, path)
    assert status == 404, path
    assert b"secret" not in body and b"TOKEN" not in body


@pytest.mark.parametrize("path", ["/", "/scene/", "/viewer/app/", "/viewer/up/", "/viewer"])
def test_folders_are_not_listed(served, path):
    _, port = served
    status, body = _get(port, path)
    assert status == 404, path
    assert b"mini.glb" not in body and b"viewer.js" not in body and b"passwd" not in body


def test_only_a_loopback_host_at_this_port_is_answered(served):
    _, port = served
    for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"LOCALHOST:{port}", f"[::1]:{port}"):
        assert _get(port, "/viewer/index.html", host)[0] == 200, host
    # what a page of a rebound name sends, or one aimed at another port
    for host in (f"attacker.example:{port}", "attacker.example", f"127.0.0.1.nip.io:{port}", "127.0.0.1",
                 f"127.0.0.1:{port + 1}", f"localhost.attacker.example:{port}", ""):
        status, body = _get(port, "/viewer/index.html", host)
        assert status in (403, 421), host
        assert b"twinViewerReady" not in body


def test_a_taken_default_port_is_not_an_error(tmp_path):
    DEFAULT_PORT = 8000  # the documented default (twin view --help)

    out = tmp_path / "build"
    (out / "viewer").mkdir(parents=True)
    (out / "viewer" / "index.html").write_text("<html>twinViewerReady</html>\n")
    holder = socket.socket()
    try:
        holder.bind(("127.0.0.1", DEFAULT_PORT))
        holder.listen()
    except OSError:
        pass  # someone else holds it: taken all the same
    try:
        proc, port = _start(out)
        try:
            assert port != DEFAULT_PORT
            assert _get(port, "/viewer/index.html")[0] == 200
        finally:
            proc.terminate()
            _, err = proc.communicate(timeout=30)
        assert f"port {DEFAULT_PORT} is taken" in err
    finally:
        holder.close()
