"""A task's code: the pipeline modules its action's module imports, found from their
import statements, and one hash of their text (the code version in its key).

An import anywhere in a module counts, at its top or inside a function, followed
from module to module within the pipeline package; importing a.b.c runs a/__init__
and a/b/__init__ too, so they count as well. Libraries stay out of the walk: their
pins are in the version instead (`pinned_libraries`). So an edit of any module a
task runs reruns it, and an edit elsewhere (the planner, another task's step) does
not. What the walk cannot see is a module named in a computed string (importlib):
the pipeline's task code names none.

Parsing whole modules would cost a no-op build more than the rest of its plan, so
only the lines that start an import statement are parsed (`import_statements`); a
test holds them to a full ast walk of every module. A line in a string that reads
as an import counts too: a script a task runs in a child (`python -c`) is its code.
The walk reads each module once a process (`modules_used` is cached); the version
reads their text each time it is asked, so an edit between two plans of one process
is seen as long as it adds no import.
"""

from __future__ import annotations

import ast
import hashlib
import json
import re
from functools import lru_cache
from pathlib import Path

PACKAGE = "pipeline"
ROOT = Path(__file__).resolve().parents[2]  # the folder that holds the pipeline package


def module_file(name: str, root: Path = ROOT) -> Path | None:
    """The source file of module `name` (a package's __init__.py), None if there is none."""
    base = Path(root, *name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


# the start of a line that begins an import statement
_IMPORT_LINE = re.compile(r"^[ \t]*(?:import[ \t]|from[ \t][^\n]*?[ \t]import\b)", re.M)
_MAX_LINES = 40  # the longest import statement the scan tries


def import_statements(text: str) -> list[ast.Import | ast.ImportFrom]:
    """The import statements of a module's source text, each parsed on its own with
    as many of the lines after it as it takes (parentheses, backslashes); a line
    that only looks like one is skipped."""
    found = []
    for match in _IMPORT_LINE.finditer(text):
        lines = text[match.start():].split("\n", _MAX_LINES)[:_MAX_LINES]
        for count in range(1, len(lines) + 1):
            try:
                body = ast.parse("\n".join(lines[:count]).strip()).body
            except SyntaxError:
                continue
            found += [node for node in body if isinstance(node, (ast.Import, ast.ImportFrom))]
            break
    return found


def _is_package(name: str, root: Path) -> bool:
    return (Path(root, *name.split(".")) / "__init__.py").is_file()


def _absolute(module: str, target: str | None, level: int, root: Path) -> str:
    """The module a `from <level dots><target> import ...` in `module` names."""
    if level == 0:
        return target or ""
    parts = module.split(".")
    package = parts if _is_package(module, root) else parts[:-1]
    base = package[:len(package) - (level - 1)]
    return ".".join(base + ([target] if target else []))


def _ours(name: str) -> bool:
    return name == PACKAGE or name.startswith(PACKAGE + ".")


@lru_cache(maxsize=None)
def direct_imports(module: str, root: Path = ROOT) -> frozenset[str]:
    """The pipeline modules `module`'s import statements name: `from x import y` names
    x.y when that is a module, x when y is a name in it."""
    path = module_file(module, root)
    if path is None:
        return frozenset()
    found = set()
    for node in import_statements(path.read_text()):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if _ours(alias.name))
        elif isinstance(node, ast.ImportFrom):
            base = _absolute(module, node.module, node.level, root)
            if not _ours(base):
                continue
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                found.add(sub if module_file(sub, root) is not None else base)
    return frozenset(found)


def _with_parents(name: str) -> list[str]:
    """pipeline.a.b -> [pipeline, pipeline.a, pipeline.a.b]: the modules importing it runs."""
    parts = name.split(".")
    return [".".join(parts[:k]) for k in range(1, len(parts) + 1)]


@lru_cache(maxsize=None)
def modules_used(module: str, root: Path = ROOT) -> tuple[str, ...]:
    """`module` and every pipeline module it imports, transitively (sorted names of
    modules that exist)."""
    seen: set[str] = set()
    todo = _with_parents(module)
    while todo:
        name = todo.pop()
        if name in seen or module_file(name, root) is None:
            continue
        seen.add(name)
        for imported in direct_imports(name, root):
            todo.extend(_with_parents(imported))
    return tuple(sorted(seen))


def code_version(*modules: str, root: Path = ROOT) -> str:
    """Hash of the source text of the named modules (a package: its __init__.py) and
    of the pinned libraries (`pinned_libraries`), so a change to a step's code reruns
    exactly the tasks that run that step, and an upgrade of a library reruns every
    task."""
    h = hashlib.sha256()
    h.update(json.dumps(pinned_libraries(), sort_keys=True, separators=(",", ":")).encode())
    for name in sorted(set(modules)):
        h.update(name.encode())
        path = module_file(name, root)
        h.update(path.read_bytes() if path is not None else b"<absent>")
    return h.hexdigest()


def code_of(module: str, root: Path = ROOT) -> str:
    """The code version of `module` and of every pipeline module it imports: the code
    part of the key of a task whose action lives in `module`."""
    return code_version(*modules_used(module, root), root=root)


@lru_cache(maxsize=None)
def pinned_libraries() -> list[str]:
    """The project's pinned requirements (pyproject.toml beside the package, or the
    installed package's metadata): what meshoptimizer, fcpw or libigl compute is part
    of a task's result, so a new pin must not reuse entries made with the old one.
    A library installed by hand at another version than its pin is not seen: reading
    every installed version would slow every no-op build."""
    import tomllib

    try:
        project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
        if project.get("name") == "substation-twin":
            extras = project.get("optional-dependencies", {})
            return sorted(project.get("dependencies", []) + extras.get("blender", []))
    except (OSError, KeyError, ValueError):
        pass
    from importlib import metadata

    try:
        return sorted(metadata.requires("substation-twin") or [])
    except metadata.PackageNotFoundError:
        return []
