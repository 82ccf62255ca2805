"""The pages in a real browser: tools/viewer_check.mjs (playwright-core driving Debian's
Chromium, headless, WebGL through SwiftShader) on a build folder served on the
loopback interface. The tests and the bench call it; nothing downloads a browser."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from . import libs, serve

DRIVER = Path(__file__).resolve().parents[2] / "tools" / "viewer_check.mjs"
HINT = "bash .ci/install-tools (Debian's chromium; playwright-core, three and cesium into tools/node_modules)"


def chromium() -> Path:
    return Path(os.environ.get("CHROMIUM", "/usr/bin/chromium"))


def missing() -> list[str]:
    """What a page check needs and this machine lacks."""
    have = libs.manifests()
    needs = (("node", shutil.which("node")), ("chromium", chromium().is_file()),
             ("playwright-core", (libs.NODE_MODULES / "playwright-core" / "package.json").is_file()),
             ("three", have["three"]), ("cesium", have["cesium"]))
    return [name for name, ok in needs if not ok]


def run(build: Path, page: str = "index.html", *, screenshot: Path | None = None, size=(1280, 800),
        timeout_s: int = 600, script: str | None = None) -> dict:
    """Open build/viewer/<page> (index.html: the scene; globe.html: the tiles) once it
    is served; returns the driver's JSON (ready, stats, page errors, ready_ms, memory,
    and `eval`: the value of `script`, a page expression, once the page is ready)."""
    lacking = missing()
    if lacking:
        raise RuntimeError(f"missing {', '.join(lacking)}: {HINT}")
    srv = serve.in_background(build)
    script_file = None
    try:
        args = [shutil.which("node"), str(DRIVER), "--url", f"{serve.address(srv)}viewer/{page}",
                "--mode", "globe" if page == "globe.html" else "viewer", "--width", str(size[0]),
                "--height", str(size[1]), "--timeout", str(timeout_s * 1000)]
        if screenshot is not None:
            args += ["--screenshot", str(screenshot)]
        if script is not None:
            with tempfile.NamedTemporaryFile("w", suffix=".js", delete=False) as f:
                f.write(script)
            script_file = Path(f.name)
            args += ["--eval", str(script_file)]
        proc = subprocess.run(args, capture_output=True, text=True, timeout=3 * timeout_s,
                              env={**os.environ, "CHROMIUM": str(chromium())})
    finally:
        srv.shutdown()
        srv.server_close()
        if script_file is not None:
            script_file.unlink(missing_ok=True)
    lines = proc.stdout.strip().splitlines()
    if not lines:
        raise RuntimeError(f"viewer_check printed nothing: {proc.stderr[-2000:]}")
    return json.loads(lines[-1])
