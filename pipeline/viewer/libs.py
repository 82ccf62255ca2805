"""The pages' libraries: three.js and CesiumJS, copied from tools/node_modules (npm,
pinned in tools/package-lock.json, installed by .ci/install-tools) into
build/viewer/lib/, so the pages load nothing from the network.

A library is known by its package.json: npm installs a version's files unchanged
(its integrity hash is in the lock), so the build task's key takes that file alone
and not the thousands it copies.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

NODE_MODULES = Path(__file__).resolve().parents[2] / "tools" / "node_modules"
HINT = "bash .ci/install-tools (or: cd tools && npm ci), then build again"
LIB = "viewer/lib"

# package -> the files and folders the pages load, relative to the package folder
FILES = {
    "three": ("LICENSE", "build/three.module.js", "build/three.core.js", "examples/jsm/loaders/GLTFLoader.js",
              "examples/jsm/utils/BufferGeometryUtils.js", "examples/jsm/utils/SkeletonUtils.js",
              "examples/jsm/controls/OrbitControls.js"),
    "cesium": ("LICENSE.md", "Build/Cesium/Cesium.js", "Build/Cesium/Workers", "Build/Cesium/Assets",
               "Build/Cesium/ThirdParty", "Build/Cesium/Widgets"),
}
# where each lands under viewer/lib/<package>/ (Cesium's Build/Cesium/ is its base URL)
STRIP = {"three": "", "cesium": "Build/Cesium/"}


def manifests(modules: Path = NODE_MODULES) -> dict[str, Path | None]:
    """package.json of each library, None where it is not installed."""
    return {name: (p if (p := Path(modules) / name / "package.json").is_file() else None) for name in sorted(FILES)}


def versions(modules: Path = NODE_MODULES) -> dict[str, str | None]:
    return {name: (json.loads(p.read_text())["version"] if p else None) for name, p in manifests(modules).items()}


def copy(staging: Path, modules: Path = NODE_MODULES) -> dict:
    """The libraries into staging/viewer/lib/; a library that is not installed gets a
    MISSING.txt instead (the pages show it and how to install it)."""
    lib = Path(staging) / LIB
    lib.mkdir(parents=True, exist_ok=True)
    copied = {}
    for name, package_json in manifests(modules).items():
        dest = lib / name
        dest.mkdir(exist_ok=True)
        if package_json is None:
            (dest / "MISSING.txt").write_text(f"{name} was not installed when the viewer was built: {HINT}\n")
            copied[name] = None
            continue
        root = package_json.parent
        for rel in FILES[name]:
            src, target = root / rel, dest / rel.removeprefix(STRIP[name])
            target.parent.mkdir(parents=True, exist_ok=True)
            if src.is_dir():
                shutil.copytree(src, target, dirs_exist_ok=True)
            else:
                shutil.copyfile(src, target)
        copied[name] = json.loads(package_json.read_text())["version"]
    return {"libraries": copied}
