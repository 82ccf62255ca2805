"""Regenerate every sample source: run each authoring script of this folder, in sorted
order, each in its own Python process (bpy and gmsh keep global state, so one process
per script keeps the scripts independent of each other).

    .venv/bin/python sources/authoring/make_all.py [--out DIR] [--only NAME ...]

Skipped: kit.py, digest.py, make_all.py and modules whose name starts with `_`
(shared helpers). Exit status 1 if any script failed; the others still run.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
NOT_SCRIPTS = {"kit", "digest", "make_all"}


def authoring_scripts(folder: Path = HERE) -> list[Path]:
    """The authoring scripts of `folder`, sorted by name."""
    return [p for p in sorted(folder.glob("*.py"))
            if p.stem not in NOT_SCRIPTS and not p.stem.startswith("_")]


def run_script(script: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(script), "--out", str(out)], cwd=HERE,
                          capture_output=True, text=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE.parent / "assets", help="assets folder to write into")
    parser.add_argument("--only", nargs="*", default=None, help="script names (without .py) to run")
    args = parser.parse_args(argv)
    scripts = authoring_scripts()
    if args.only:
        unknown = sorted(set(args.only) - {s.stem for s in scripts})
        if unknown:
            parser.error(f"no authoring script named {', '.join(unknown)}")
        scripts = [s for s in scripts if s.stem in args.only]
    failed = []
    for script in scripts:
        start = time.monotonic()
        result = run_script(script, args.out.resolve())
        status = "ok" if result.returncode == 0 else f"FAILED (exit {result.returncode})"
        print(f"{script.name:32s} {status} {time.monotonic() - start:6.1f} s", flush=True)
        if result.returncode != 0:
            failed.append(script.name)
            print(result.stderr[-4000:], file=sys.stderr)
    if failed:
        print(f"{len(failed)} script(s) failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
