"""What `twin validate` judged before, kept by content: build/.validate/results.json.

A package's verdicts (the external validators' on its files, Gazebo's on its meshes
and model bounds) are kept under a key made of the bytes of every file in its folder
and in its LOD variants' folders, and of the versions of everything that judged them:
the pipeline's validate code (engine.code: every module it imports, and the pinned
libraries), the libsdformat library, pycollada with lxml and
libxml2, usd-core, the gltf-validator package, the gzprobe binary and node. A changed
byte in a package or any other version of a tool finds no entry, so the package is
checked again: an entry is never trusted across validator versions.

Only packages are kept: a scene's verdicts depend on every package it places, and
the Gazebo world's figures (parse time, memory, real-time factor) are measured on
each run. The package checks (manifest hashes, XML, URIs) run every time: they are
what says a package's files are the ones its manifest names.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import asdict
from functools import lru_cache
from pathlib import Path

from ..digest import sha256_file
from ..files import atomic_write
from ..findings import Finding
from .external import ExternalResult

FOLDER = ".validate"
FILE = "results.json"
FORMAT = 1
# where the loader looks for the SDF library (external._CMDCHECK loads it)
_LIBRARY_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib", "/usr/local/lib")


def _file_version(path: Path | None) -> str:
    """A tool file's real name and content hash ("absent" without it)."""
    if path is None or not Path(path).is_file():
        return "absent"
    real = Path(path).resolve()
    return f"{real.name}:{sha256_file(real)}"


def _library(name: str) -> Path | None:
    dirs = [d for d in os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep) if d] + list(_LIBRARY_DIRS)
    return next((Path(d) / name for d in dirs if (Path(d) / name).is_file()), None)


@lru_cache(maxsize=1)
def _library_versions() -> tuple[tuple[str, str], ...]:
    from lxml import etree

    from . import external, gazebo

    versions = {
        "sdformat": _file_version(_library(external._SDFORMAT_LIBRARY)),
        "libxml2": ".".join(map(str, etree.LIBXML_VERSION)), "lxml": ".".join(map(str, etree.LXML_VERSION)),
        "gltf-validator": _file_version(external._GLTF_MODULE / "package.json"),
        "node": _file_version(Path(shutil.which("node")) if shutil.which("node") else None),
        "gzprobe": _file_version(gazebo.PROBE),
    }
    try:
        import collada

        versions["pycollada"] = str(getattr(collada, "__version__", "")) + ":" + _file_version(
            Path(collada.__file__).parent / "resources" / "schema-1.4.1.xml")
    except ImportError:
        versions["pycollada"] = "absent"
    try:
        from pxr import Usd

        versions["usd"] = ".".join(map(str, Usd.GetVersion()))
    except ImportError:
        versions["usd"] = "absent"
    return tuple(sorted(versions.items()))


def tool_versions() -> dict[str, str]:
    """Every judge's version, this code's included."""
    from ..engine.code import code_of

    return {"code": code_of("pipeline.validate.report"), **dict(_library_versions())}


def folder_digest(folders: list[Path], hashes: dict[str, str] | None = None) -> str:
    """One hash of every file under `folders` (names relative to each folder's parent,
    so a package and its variants hash alike wherever the build folder is).
    `hashes`: filled with str(path) -> sha256 of each file."""
    h = hashlib.sha256()
    for folder in folders:
        for path in sorted(p for p in Path(folder).rglob("*") if p.is_file() or p.is_symlink()):
            rel = path.relative_to(Path(folder).parent).as_posix()
            digest = sha256_file(path) if path.is_file() else "dangling:" + os.readlink(path)
            if hashes is not None:
                hashes[str(path)] = digest
            h.update(rel.encode() + b"\0" + digest.encode() + b"\0")
    return h.hexdigest()


class ResultCache:
    """Package verdicts by key (package name, file digest, tool versions)."""

    def __init__(self, out: Path, versions: dict[str, str] | None = None):
        self.path = Path(out) / FOLDER / FILE
        self.out = Path(out)
        self.versions = tool_versions() if versions is None else versions
        self._tools = hashlib.sha256(json.dumps(self.versions, sort_keys=True).encode()).hexdigest()
        self._entries = self._read()
        self._used: dict[str, dict] = {}
        self.hashes: dict[str, str] = {}  # str(path) -> sha256 of the files keyed so far

    def _read(self) -> dict:
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return {}
        ok = isinstance(data, dict) and data.get("format") == FORMAT and data.get("tools") == self._tools
        return data.get("entries", {}) if ok and isinstance(data.get("entries"), dict) else {}

    def key(self, package: str, folders: list[Path]) -> str:
        return hashlib.sha256(f"{self._tools}\0{package}\0{folder_digest(folders, self.hashes)}".encode()).hexdigest()

    def get(self, key: str) -> tuple[list[ExternalResult], list[Finding]] | None:
        """The package's external results (targets made absolute under this build
        folder) and Gazebo findings, or None when it was not judged as it is."""
        entry = self._entries.get(key)
        if not isinstance(entry, dict):
            return None
        try:
            results = [ExternalResult(r["validator"], str(self.out / r["target"]), r["status"],
                                      tuple(r["messages"]), r["install_hint"]) for r in entry["external"]]
            found = [Finding.from_dict(f) for f in entry["gazebo"]]
        except (KeyError, TypeError):
            return None
        self._used[key] = entry
        return results, found

    def put(self, key: str, results: list[ExternalResult], found: list[Finding]) -> None:
        """Keep a package's verdicts, unless a tool was missing (a skipped run must
        run again once the tool is there)."""
        if any(r.status == "skipped" for r in results):
            return
        root = str(self.out.resolve()) + os.sep
        rows = []
        for r in results:
            row = asdict(r)
            row["target"] = os.path.relpath(Path(r.target).resolve(), self.out.resolve())
            row["messages"] = [m.replace(root, "") for m in r.messages]
            rows.append(row)
        self._used[key] = {"external": rows, "gazebo": [f.as_dict() for f in found]}

    def save(self) -> None:
        """Write the entries this run used or made (a replaced package's old entry goes)."""
        data = {"format": FORMAT, "tools": self._tools, "versions": self.versions,
                "entries": dict(sorted(self._used.items()))}
        atomic_write(self.path, json.dumps(data, sort_keys=True, separators=(",", ":")) + "\n")
