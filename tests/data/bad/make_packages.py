"""Writes the package fixtures: tests/data/clean/packages/crate (a clean package) and
tests/data/bad/PKG00x/crate (one broken thing each). The folders are committed; run
this again (`python tests/data/bad/make_packages.py`) only when the writers change.

Each package holds model.config, model.sdf, meshes/*.dae and manifest.json; the heavy
formats (USD, glTF, thumbnail) are left out: the package checks do not read them.
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
TESTS = HERE.parents[1]
sys.path[:0] = [str(TESTS.parent), str(TESTS), str(HERE)]

from assets import base  # noqa: E402
from pipeline.export import collada, manifest, sdf  # noqa: E402

# A file the XXE fixture asks for: the test checks its text never reaches a report.
SECRET_NAME = "xxe_secret.txt"
MESH = "meshes/body__shell__lod0.dae"


def _write_clean(folder: Path) -> None:
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    asset = base()
    collada.write(asset, folder)
    sdf.write(asset, folder)
    _rehash(folder, asset)


def _rehash(folder: Path, asset=None) -> None:
    asset = asset or base()
    outputs = {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
               for p in sorted(folder.rglob("*")) if p.is_file() and p.name != "manifest.json"}
    manifest.write(manifest.content(asset, source={"file": "crate.py", "sha256": ""}, outputs=outputs,
                                    lod_models=[]), folder)


def _edit(folder: Path, rel: str, old: str, new: str) -> None:
    path = folder / rel
    text = path.read_text()
    assert old in text, (rel, old)
    path.write_text(text.replace(old, new, 1))


def main() -> None:
    _write_clean(HERE.parent / "clean" / "packages" / "crate")
    bad = {}

    def pkg(code: str) -> Path:
        folder = HERE / code / "crate"
        _write_clean(folder)
        bad[code] = folder
        return folder

    f = pkg("PKG001")  # model.sdf cut in the middle
    text = (f / "model.sdf").read_text()
    (f / "model.sdf").write_text(text[: len(text) // 2])
    _rehash(f)

    f = pkg("PKG002")  # a mesh URI whose file is gone (and so is its manifest entry)
    (f / MESH).unlink()
    _rehash(f)

    f = pkg("PKG003")  # URIs that leave the package: another model, and ..
    _edit(f, "model.sdf", f"model://crate/{MESH}", "model://other/meshes/x.dae")
    # the crate's hull is a box, written as a <box>: make it a mesh that points out
    box = re.search(r"<box>.*?</box>", (f / "model.sdf").read_text(), re.S).group(0)
    _edit(f, "model.sdf", box, "<mesh><uri>../../../etc/hostname</uri></mesh>")
    _rehash(f)

    f = pkg("PKG004")  # the mesh changed after the manifest was written
    _edit(f, MESH, "<asset>", "<asset><!-- edited -->")

    f = pkg("PKG005")  # an external entity in a COLLADA file
    _edit(f, MESH, "<?xml version='1.0' encoding='utf-8'?>",
          "<?xml version='1.0' encoding='utf-8'?>\n"
          f'<!DOCTYPE COLLADA [<!ENTITY xxe SYSTEM "../../{SECRET_NAME}">]>')
    _edit(f, MESH, "<asset>", "<asset><contributor><author>&xxe;</author></contributor>")
    (f.parent / SECRET_NAME).write_text("TOP-SECRET-7f3a\n")
    _rehash(f)

    f = pkg("PKG006")  # no manifest at all
    (f / "manifest.json").unlink()
    print("\n".join(str(p) for p in bad.values()))


if __name__ == "__main__":
    main()
