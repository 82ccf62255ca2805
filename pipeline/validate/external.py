"""The validators the formats' owners ship, run on written files (DESIGN.md s.7).

Each returns an ExternalResult. A validator that is not installed gives "skipped" with
how to install it, never "passed": a report must not look clean because a tool was
missing. Heavy or optional dependencies (pxr, node, libsdformat) are looked up when a
function runs, so this module imports without them.
"""

from __future__ import annotations

import copy
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Literal

from lxml import etree

from .. import safe_xml

Status = Literal["passed", "failed", "skipped"]

_SDF_HINT = "apt-get install libsdformat12-12 sdformat-sdf ignition-tools (or: bash .ci/install-tools)"
_USD_HINT = "pip install usd-core (a project dependency: reinstall the environment)"
_GLTF_HINT = "bash .ci/install-tools (installs node's gltf-validator into tools/node_modules)"
_COLLADA_HINT = "pip install pycollada lxml (project dependencies: reinstall the environment)"

# The shared library behind `ign sdf -k`; Debian ships the `ign` glue for it (a yaml and
# a ruby file) only in libsdformat-dev, so without it we call the same entry point.
_SDFORMAT_LIBRARY = "libsdformat12.so.12"
_GLTF_MODULE = Path(__file__).resolve().parents[2] / "tools" / "node_modules" / "gltf-validator"
_TIMEOUT_S = 300
# Loading the COLLADA schema is slow: keep one per thread (a schema's error log is per
# instance, so threads must not share one).
_LOCAL = threading.local()
# libxml2 sets up its built-in schema types (anyType and the rest) on a process's first
# schema compile, without a lock: a compile in another thread that meets them half made
# fails with a type "(NULL)" not derived from anyType. Compiles are one per thread:
# they take turns.
_COMPILING = threading.Lock()
# The schema imports xml.xsd from w3.org; pycollada serves its local copy through an lxml
# resolver. lxml reaches a resolver through libxml2's entity loader, one per process,
# which every parse in any thread sets on entry and puts back on exit: a parse that ended
# in another thread while a schema compiled put back libxml2's own loader, the import
# went unanswered, and the compile failed with "xml:base does not resolve" (a report's
# first COLLADA file failed, and passed on rerun). The import names the local copy's
# file instead, which any loader opens.
_XML_XSD_URL = "http://www.w3.org/2001/03/xml.xsd"
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


@dataclass(frozen=True)
class ExternalResult:
    """One external validator's verdict on one file."""

    validator: str
    target: str
    status: Status
    messages: tuple[str, ...] = ()
    install_hint: str = ""


# --- SDF ------------------------------------------------------------------------------

# `ign sdf -k FILE` is ign-tools' ruby glue loading libsdformat12 and calling its
# cmdCheck(FILE) (cmdsdformat12.rb). Starting the glue costs more than checking a model
# file, so the files are checked here by that same call, many in one child process: it
# prints to the C++ streams and may abort, neither of which may touch this process.
# Each file's output goes to a file of its own (fd 1 and 2 pointed there for the
# call); the child reports each exit code on a line of its own stdout.
_CMDCHECK = r"""
import ctypes, os, sys
codes = os.fdopen(os.dup(1), "w")
os.dup2(2, 1)  # whatever else is printed is not a code
try:
    lib = ctypes.CDLL(sys.argv[1])
except OSError as e:
    print("not installed: %s" % e, file=sys.stderr)
    sys.exit(127)
lib.cmdCheck.argtypes = [ctypes.c_char_p]
lib.cmdCheck.restype = ctypes.c_int
flush_all = ctypes.CDLL(None).fflush
for path, log in zip(sys.argv[2::2], sys.argv[3::2]):
    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    flush_all(None)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    code = lib.cmdCheck(path.encode())
    flush_all(None)
    codes.write("%d\n" % code)
    codes.flush()
"""
_SDF_CHECK = "ign sdf -k (libsdformat12 cmdCheck)"


def ign_sdf(path: Path, sdf_path: list[Path]) -> ExternalResult:
    """`ign sdf -k path` with SDF_PATH = sdf_path (folders holding model folders).

    Passes only with exit code 0 and no "Error" in the output (sdformat prints
    "Valid." in cases it could not check). Runs in an empty working directory so that
    model:// URIs resolve through SDF_PATH alone, as in Gazebo.
    """
    return ign_sdf_files([path], sdf_path)[0]


def ign_sdf_files(paths: list[Path], sdf_path: list[Path], workers: int = 1,
                  done: Callable[[], None] | None = None) -> list[ExternalResult]:
    """ign_sdf on each of `paths`, in `workers` child processes side by side, each
    checking its share one file after another; the results in the order of `paths`.
    A file whose check ends its process fails, and the files after it are checked in
    a new one. `done` is called as each file's check ends."""
    paths = [Path(p).resolve() for p in paths]
    env = dict(os.environ, SDF_PATH=os.pathsep.join(str(Path(p).resolve()) for p in sdf_path))
    shares = [paths[k::workers] for k in range(max(1, min(workers, len(paths))))]
    if len(shares) == 1:
        checked = [_check_files(shares[0], env, done)]
    else:
        with ThreadPoolExecutor(max_workers=len(shares)) as pool:
            checked = list(pool.map(lambda share: _check_files(share, env, done), shares))
    by_path = {r.target: r for results in checked for r in results}
    return [by_path[str(p)] for p in paths]


def _check_files(paths: list[Path], env: dict, done: Callable[[], None] | None) -> list[ExternalResult]:
    results: list[ExternalResult] = []

    def verdict(r: ExternalResult) -> None:
        results.append(r)
        if done is not None:
            done()

    with tempfile.TemporaryDirectory() as cwd, tempfile.TemporaryDirectory() as logs:
        while len(results) < len(paths):
            rest = paths[len(results):]
            log_files = [Path(logs) / f"{len(results) + i}.txt" for i in range(len(rest))]
            cmd = [sys.executable, "-c", _CMDCHECK, _SDFORMAT_LIBRARY,
                   *(str(a) for pair in zip(rest, log_files) for a in pair)]
            stderr = Path(logs) / "stderr.txt"
            try:
                with open(stderr, "wb") as err:
                    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, env=env, cwd=cwd, text=True)
            except OSError as e:
                for p in rest:
                    verdict(ExternalResult(_SDF_CHECK, str(p), "failed", (f"could not run: {e}",), _SDF_HINT))
                break
            timeout = _TIMEOUT_S + 10 * len(rest)
            timed_out = threading.Event()
            watchdog = threading.Timer(timeout, lambda: (timed_out.set(), proc.kill()))
            watchdog.start()
            try:
                codes = 0
                for path, log, line in zip(rest, log_files, proc.stdout):
                    verdict(_sdf_verdict(path, _read_log(log), int(line)))
                    codes += 1
                code = proc.wait()
            finally:
                watchdog.cancel()
                proc.stdout.close()
            said = _read_log(stderr) if code == 127 else ""
            if said.startswith("not installed"):
                why = said.strip().splitlines()[0]
                for p in rest:
                    verdict(_skipped(_SDF_CHECK, p, why, _SDF_HINT))
                break
            if codes < len(rest):  # the check of the next file ended the process
                ended = (f"timed out after {timeout} s" if timed_out.is_set()
                         else f"the check ended its process (exit code {code})")
                verdict(_sdf_verdict(rest[codes], _read_log(log_files[codes]) + "\n" + ended, code or -1))
    return results


def _read_log(path: Path) -> str:
    try:
        return path.read_text(errors="replace")
    except OSError:
        return ""


def _sdf_verdict(path: Path, text: str, code: int) -> ExternalResult:
    text = _ANSI.sub("", text)
    ok = code == 0 and "Error" not in text and "Valid." in text
    lines = tuple(line.strip() for line in text.splitlines() if line.strip())
    return ExternalResult(_SDF_CHECK, str(path), "passed" if ok else "failed", lines if not ok else (), _SDF_HINT)


# sdformat 12 builds a fresh copy of its whole spec for every <include> it loads, so a
# world's check grows faster than its includes, in time and in memory: a world with
# more includes than this is checked in parts (the size that keeps both low on the
# sample: the figures are in 1bd9b89's message).
WORLD_PART_INCLUDES = 32
# Where one top-level element of a world names another's frame (inside a model, names
# are the model's own).
_WORLD_REFERENCES = "./*[@attached_to or @placement_frame] | ./*/pose[@relative_to] | ./*/placement_frame | ./joint"
# A name that sdformat takes as it is: no scope delimiter, not reserved.
_PLAIN_NAME = re.compile(r"^(?!__)(?!world$)[A-Za-z0-9_][A-Za-z0-9_.-]*$")


def ign_sdf_world(path: Path, sdf_path: list[Path], part_includes: int = WORLD_PART_INCLUDES,
                  workers: int = 2) -> ExternalResult:
    """ign_sdf on what sdformat must see of a world (_reduce_world: of the includes and
    of the placements grouped in models that repeat one another's form, one of each),
    in parts of at most `part_includes` includes when it has more, so that memory
    stays bounded and the check's time
    grows with the forms, not with the placements.

    Each part is that world with only its own share of the includes: every other
    element is in each part, each include checked in the same world as written. What
    a part cannot see: another element's frames (a world whose top-level elements name
    one another's, through `relative_to`, `attached_to` or `placement_frame`, is
    checked whole) and the names of what is not checked (sdformat requires siblings'
    names to be unique; that is checked here, over the whole world). `workers`: parts
    checked at once."""
    path = Path(path)
    try:
        tree = etree.parse(str(path), safe_xml.parser())
    except (OSError, etree.XMLSyntaxError):
        return ign_sdf(path, sdf_path)  # sdformat gives the file's error as it sees it
    world = tree.getroot().find("world")
    if world is None or world.xpath(_WORLD_REFERENCES):
        return ign_sdf(path, sdf_path)
    reduced, stand_in = _reduce_world(tree)
    includes = reduced.getroot().find("world").findall("include")
    if not stand_in and len(includes) <= part_includes:
        return ign_sdf(path, sdf_path)
    duplicates = _duplicate_names(world)
    runs = [list(range(i, min(i + part_includes, len(includes)))) for i in range(0, len(includes), part_includes)]
    runs = runs or [[]]
    with tempfile.TemporaryDirectory() as folder:
        parts = [Path(folder).resolve() / f"{path.stem}.part{k}.sdf" for k in range(1, len(runs) + 1)]
        for part, run in zip(parts, runs):
            _write_part(reduced, run, part)
        results = ign_sdf_files(parts, sdf_path, workers)
    name = results[0].validator + (f", on {stand_in}" if stand_in else "")
    if len(parts) > 1:
        name += f", in {len(parts)} parts of up to {part_includes} includes"
    if results[0].status == "skipped":
        return ExternalResult(results[0].validator, str(path), "skipped", results[0].messages, _SDF_HINT)
    messages = list(duplicates)
    for k, (run, part, r) in enumerate(zip(runs, parts, results), start=1):
        if r.status != "passed":
            span = (f"part {k} (includes {_include_name(includes[run[0]])} .. {_include_name(includes[run[-1]])}): "
                    if len(parts) > 1 else "")
            # the part's temporary path would differ from run to run: the world's name instead
            messages += [f"{span}{m.replace(str(part), path.name)}" for m in r.messages or ("failed",)]
    return ExternalResult(name, str(path), "failed" if messages else "passed", tuple(messages), _SDF_HINT)


def _write_part(tree, keep: list[int], part: Path) -> None:
    """The world with only its includes `keep` (positions in file order), the rest as is."""
    part_tree = copy.deepcopy(tree)
    world = part_tree.getroot().find("world")
    kept = set(keep)
    for k, include in enumerate(world.findall("include")):
        if k not in kept:
            world.remove(include)
    part_tree.write(str(part), xml_declaration=True, encoding="UTF-8")


def _reduce_world(tree) -> tuple[etree._ElementTree, str]:
    """A copy of the world without the includes and the grouped placements whose form
    one kept before has (_include_forms, _reduce_members), and what it keeps of what
    ("" when it keeps everything)."""
    reduced = copy.deepcopy(tree)
    world = reduced.getroot().find("world")
    includes = world.findall("include")
    kept = set(_include_forms(includes))
    for k, include in enumerate(includes):
        if k not in kept:
            world.remove(include)
    frames = removed = 0
    for model in world.findall("model"):
        total, gone = _reduce_members(model)
        frames, removed = frames + total, removed + gone
    said = ([f"{len(kept):,} of {len(includes):,} includes"] if len(kept) < len(includes) else []) + (
        [f"{frames - removed:,} of {frames:,} placements grouped in models"] if removed else [])
    if not said:
        return reduced, ""
    return reduced, " and ".join(said) + " (one of each form: the others differ from it only in a plain name and pose)"


def _include_forms(includes: list) -> list[int]:
    """Positions of the includes sdformat must see: the first of each form (the include
    without its <name> and <pose> texts), and every include whose name or pose is not
    plain (a name as _PLAIN_NAME, a pose of six finite numbers), which sdformat judges
    alone. sdformat loads an include from its URI and its other elements, and takes a
    plain name and pose as they are; the names' uniqueness is checked over the world."""
    firsts: set[bytes] = set()
    out = []
    for k, include in enumerate(includes):
        if not (_plain_name(include.findtext("name")) and _plain_pose(include.findtext("pose"))):
            out.append(k)
            continue
        form = b"".join(_c14n(c, blank=c.tag in ("name", "pose")) for c in include) + _c14n(include, empty=True)
        if form not in firsts:
            firsts.add(form)
            out.append(k)
    return out


# A link's visuals and collisions posed relative to a frame, and every naming of a frame
# in a model (no unions: libxml2 merges a union's node sets in time that grows with the
# square of their size).
_POSED = ("link/visual/pose[@relative_to]", "link/collision/pose[@relative_to]")
_NAMING = (".//@*[local-name() = 'relative_to' or local-name() = 'attached_to' or local-name() = 'placement_frame'"
           " or local-name() = 'canonical_link']", ".//*[self::parent or self::child or self::placement_frame]/text()")


def _reduce_members(model) -> tuple[int, int]:
    """Remove from a model the frames of its own (a placement each, as the scene's
    grouped models hold them) whose form a frame kept before has, with the visuals and
    collisions posed relative to them. A frame's form: the frame without its name and
    pose text, and its elements with its name in theirs written as a placeholder. A
    frame whose name or pose is not plain, whose name another frame has too, or that
    anything but such an element's pose names, is kept. Returns (frames, removed)."""
    frames = model.findall("frame")
    if len(frames) < 2:
        return len(frames), 0
    posed: dict[str, list] = {}
    for pose in (p for query in _POSED for p in model.xpath(query)):
        posed.setdefault(pose.get("relative_to"), []).append(pose.getparent())
    named = Counter(str(v).strip() for query in _NAMING for v in model.xpath(query))
    named.subtract({tag: len(items) for tag, items in posed.items()})  # what anything but those poses names
    named.update(Counter(f.get("name") for f in frames) - Counter(set(f.get("name") for f in frames)))  # shared
    firsts: set[bytes] = set()
    removed = 0
    for frame in frames:
        tag = frame.get("name") or ""
        if named[tag] > 0 or not _plain_name(tag) or not _plain_pose(frame.findtext("pose")):
            continue
        form = _c14n(frame, blank=True, unnamed=True) + b"".join(
            item.getparent().get("name", "").encode() + _renamed(item, tag) for item in posed.get(tag, []))
        if form not in firsts:
            firsts.add(form)
            continue
        model.remove(frame)
        for item in posed.get(tag, []):
            item.getparent().remove(item)
        removed += 1
    return len(frames), removed


def _c14n(el, *, blank: bool = False, empty: bool = False, unnamed: bool = False) -> bytes:
    """Canonical bytes of an element. blank: without its text and its children's
    texts; empty: without its children; unnamed: without its name attribute."""
    if not (blank or empty or unnamed):
        return etree.tostring(el, method="c14n", with_tail=False)
    el = copy.deepcopy(el)
    el.tail = None
    if empty:
        el[:] = []
    if unnamed:
        el.attrib.pop("name", None)
    for sub in el.iter(tag=etree.Element):
        if blank:
            sub.text = None
    return etree.tostring(el, method="c14n")


def _renamed(item, name: str) -> bytes:
    """Canonical bytes of an element posed relative to the frame `name` (a plain name:
    XML writes it as it is), with that name where it begins a name or is the
    relative_to written as a placeholder."""
    return (_c14n(item).replace(f'name="{name}'.encode(), b'name="\xef\xbf\xbd')
            .replace(f'relative_to="{name}"'.encode(), b'relative_to="\xef\xbf\xbd"'))


def _plain_name(text: str | None) -> bool:
    return text is not None and _PLAIN_NAME.match(text.strip()) is not None


def _plain_pose(text: str | None) -> bool:
    if text is None:
        return True
    values = text.split()
    try:
        return len(values) == 6 and all(math.isfinite(float(v)) for v in values)
    except ValueError:
        return False


def _include_name(include) -> str:
    name = include.findtext("name")
    return name.strip() if name else (include.findtext("uri") or "?").strip()


def _duplicate_names(world) -> list[str]:
    """Names two siblings share where sdformat requires them unique (SDF 1.7+): the
    world's models, includes, actors, lights and frames; a model's links, joints,
    frames and models; a link's visuals, and its collisions."""
    out = _shared(world, ("model", "include", "actor", "light", "frame"), "elements of the world")
    for model in world.findall("model"):
        out += _shared(model, ("link", "joint", "frame", "model"), f"elements of model {model.get('name')!r}")
        for link in model.findall("link"):
            for kind in ("visual", "collision"):
                out += _shared(link, (kind,), f"{kind}s of link {link.get('name')!r} of model {model.get('name')!r}")
    return out


def _shared(parent, kinds: tuple[str, ...], what: str) -> list[str]:
    seen: dict[str, int] = {}
    for child in parent:
        if not isinstance(child.tag, str) or child.tag not in kinds:
            continue
        name = child.findtext("name") if child.tag == "include" else child.get("name")
        if name:
            seen[name.strip()] = seen.get(name.strip(), 0) + 1
    return [f"Error: the name {n!r} is used by {c} {what}" for n, c in sorted(seen.items()) if c > 1]


# --- USD ------------------------------------------------------------------------------

def usd_validation(path: Path) -> ExternalResult:
    """pxr.UsdValidation with every registered validator; only errors fail. Also checks
    metersPerUnit == 1 and upAxis == Z, which the validators only require to exist.
    Instances are validated through their prototypes, once per prototype: an instance's
    prims are its prototype's (the stage's own traversal would go through every
    instance's proxies, the placements of a scene times its models' prims)."""
    name = "pxr.UsdValidation"
    try:
        from pxr import Usd, UsdGeom, UsdValidation
    except ImportError as e:
        return _skipped(name, path, f"pxr not importable: {e}", _USD_HINT)
    stage = Usd.Stage.Open(str(path))
    if stage is None:
        return ExternalResult(name, str(path), "failed", ("USD could not open the file",), _USD_HINT)
    context = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    errors = list(context.Validate(stage, Usd.PrimDefaultPredicate))
    for prototype in stage.GetPrototypes():
        errors += context.Validate(Usd.PrimRange(prototype))
    messages = [f"{e.GetName()}: {e.GetMessage()}" for e in errors
                if e.GetType() == UsdValidation.ValidationErrorType.Error]
    if UsdGeom.GetStageMetersPerUnit(stage) != 1.0:
        messages.append(f"metersPerUnit is {UsdGeom.GetStageMetersPerUnit(stage)}, expected 1")
    if UsdGeom.GetStageUpAxis(stage) != UsdGeom.Tokens.z:
        messages.append(f"upAxis is {UsdGeom.GetStageUpAxis(stage)}, expected Z")
    return ExternalResult(name, str(path), "failed" if messages else "passed", tuple(sorted(messages)), _USD_HINT)


# --- glTF -----------------------------------------------------------------------------

# One node process validates every file: node's start-up costs more than a small glb.
_GLTF_SCRIPT = r"""
const fs = require("fs");
const path = require("path");
const validator = require(process.argv[1]);
const files = JSON.parse(fs.readFileSync(0, "utf8"));
(async () => {
  const out = [];
  for (const file of files) {
    try {
      const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
        uri: path.basename(file),
        maxIssues: 100,
        externalResourceFunction: (uri) => new Promise((resolve, reject) => {
          fs.readFile(path.resolve(path.dirname(file), decodeURIComponent(uri)),
                      (err, data) => err ? reject(err.toString()) : resolve(new Uint8Array(data)));
        }),
      });
      const errors = report.issues.messages.filter((m) => m.severity === 0)
        .map((m) => `${m.code}: ${m.message}${m.pointer ? " at " + m.pointer : ""}`);
      out.push({file, numErrors: report.issues.numErrors, errors});
    } catch (e) {
      out.push({file, numErrors: 1, errors: [String(e)]});
    }
  }
  process.stdout.write(JSON.stringify(out));
})();
"""


def gltf_validator(paths: list[Path], *, module_dir: Path | None = None) -> list[ExternalResult]:
    """The Khronos glTF validator on each file, in one node process; 0 errors passes.

    module_dir: the gltf-validator npm package folder (default tools/node_modules/...).
    Returns one result per path, in the order given.
    """
    name = "gltf-validator"
    module = Path(module_dir) if module_dir is not None else _GLTF_MODULE
    files = [str(Path(p).resolve()) for p in paths]
    node = shutil.which("node")
    if node is None or not (module / "package.json").is_file():
        why = "`node` not found on PATH" if node is None else f"no gltf-validator in {module}"
        return [_skipped(name, Path(f), why, _GLTF_HINT) for f in files]
    if not files:
        return []
    try:
        out = subprocess.run([node, "-e", _GLTF_SCRIPT, str(module.resolve())], input=json.dumps(files),
                             capture_output=True, text=True, timeout=_TIMEOUT_S)
        reports = {r["file"]: r for r in json.loads(out.stdout)}
    except (OSError, subprocess.TimeoutExpired, ValueError) as e:
        detail = f"validator did not run: {e}"
        return [ExternalResult(name, f, "failed", (detail,), _GLTF_HINT) for f in files]
    results = []
    for f in files:
        r = reports.get(f, {"numErrors": 1, "errors": ["no report"]})
        ok = r["numErrors"] == 0
        results.append(ExternalResult(name, f, "passed" if ok else "failed",
                                      () if ok else tuple(r["errors"]) or (f"{r['numErrors']} errors",),
                                      _GLTF_HINT))
    return results


# --- COLLADA --------------------------------------------------------------------------

def collada_schema(path: Path) -> ExternalResult:
    """pycollada's COLLADA 1.4.1 schema validator on the file, parsed without entity
    resolution, DTD loading or network access (a .dae is untrusted input)."""
    name = "pycollada ColladaValidator"
    try:
        import collada.schema  # noqa: F401 - the schema's files are pycollada's
    except ImportError as e:
        return _skipped(name, path, f"pycollada not importable: {e}", _COLLADA_HINT)
    try:
        tree = etree.parse(str(path), safe_xml.parser())
    except (OSError, etree.XMLSyntaxError) as e:
        return ExternalResult(name, str(path), "failed", (f"not well-formed XML: {e}",), _COLLADA_HINT)
    if safe_xml.has_doctype(tree):
        # COLLADA needs no DTD; one here can only declare entities (XXE, billion laughs).
        return ExternalResult(name, str(path), "failed",
                              ("document declares a DOCTYPE; entities are not resolved",), _COLLADA_HINT)
    schema = getattr(_LOCAL, "collada", None)
    try:
        if schema is None:
            with _COMPILING:
                schema = _LOCAL.collada = _collada_schema_instance()
    except (OSError, etree.Error) as e:
        return ExternalResult(name, str(path), "failed", (f"the COLLADA schema did not compile: {e}",),
                              _COLLADA_HINT)
    try:
        if schema.validate(tree):
            return ExternalResult(name, str(path), "passed", (), _COLLADA_HINT)
    except etree.Error as e:  # lxml raises on trees it cannot validate at all
        return ExternalResult(name, str(path), "failed", (f"schema validation error: {e}",), _COLLADA_HINT)
    messages = tuple(f"line {e.line}: {e.message}" for e in schema.error_log) or ("schema validation failed",)
    return ExternalResult(name, str(path), "failed", messages, _COLLADA_HINT)


def _collada_schema_instance() -> etree.XMLSchema:
    """pycollada's COLLADA 1.4.1 schema, compiled with its xml.xsd import pointing at
    pycollada's own copy on disk: no resolver, no network, whatever loader is set."""
    from importlib import resources

    folder = resources.files("collada").joinpath("resources")
    xml_xsd = Path(str(folder.joinpath("xsd.xml")))
    if not xml_xsd.is_file():
        raise OSError(f"pycollada's copy of xml.xsd is not a file: {xml_xsd}")
    text = folder.joinpath("schema-1.4.1.xml").read_bytes()
    if text.count(_XML_XSD_URL.encode()) != 1:
        raise OSError(f"pycollada's COLLADA schema does not import {_XML_XSD_URL} once")
    text = text.replace(_XML_XSD_URL.encode(), xml_xsd.as_uri().encode())
    return etree.XMLSchema(etree.fromstring(text, safe_xml.parser()))


def _skipped(validator: str, path: Path, why: str, hint: str) -> ExternalResult:
    return ExternalResult(validator, str(path), "skipped", (f"not installed: {why}",), hint)
