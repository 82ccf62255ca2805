"""The house's shape, read from pipeline's own imports (ast, every import statement,
inside functions too): no import circle between its folders and top-level modules,
geometry standing on nothing but `ir` and the modules below it, no module over 600
lines."""

from __future__ import annotations

import ast
from functools import lru_cache
from pathlib import Path
from helpers import ROOT

PIPELINE = ROOT / "pipeline"
MAX_LINES = 600
# What geometry may import from pipeline besides itself: ir and the two modules that
# stand on nothing in pipeline (ir itself imports digest; errors holds UserError).
# Checks, parallelism and memos are handed to geometry's steps, never imported.
BELOW_GEOMETRY = {"ir", "errors", "digest"}


def _modules() -> list[Path]:
    return sorted(p for p in PIPELINE.rglob("*.py") if "__pycache__" not in p.parts)


def _dotted(path: Path) -> str:
    parts = list(path.relative_to(PIPELINE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(path: Path) -> set[str]:
    """The dotted names a module imports from pipeline (a `from x import y` gives both
    x and x.y: y may be a module)."""
    package = _dotted(path) if path.name == "__init__.py" else _dotted(path).rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([node.module] if node.module else []))
            out |= {base} | {f"{base}.{a.name}" for a in node.names}
    return {name for name in out if name == "pipeline" or name.startswith("pipeline.")}


def unit(name: str) -> str | None:
    """The folder or top-level module of pipeline a dotted name lies in (None: the
    package itself, or a name that is no module, such as pipeline.__version__)."""
    parts = name.split(".")
    if len(parts) < 2:
        return None
    first = parts[1]
    return first if (PIPELINE / first).is_dir() or (PIPELINE / f"{first}.py").is_file() else None


@lru_cache(maxsize=1)
def unit_graph() -> dict[str, dict[str, list[str]]]:
    """{unit: {unit it imports: [the importing module -> imported name, ...]}} (read
    once: do not change it)."""
    graph: dict[str, dict[str, list[str]]] = {}
    for path in _modules():
        source = unit(_dotted(path))
        if source is None:
            continue
        graph.setdefault(source, {})
        for name in sorted(imported(path)):
            target = unit(name)
            if target is not None and target != source:
                graph[source].setdefault(target, []).append(f"{_dotted(path)} -> {name}")
    return graph


def cycles(graph: dict[str, dict[str, list[str]]]) -> list[list[str]]:
    """The strongly connected components of more than one unit (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_graph_reads_relative_and_absolute_imports():
    graph = unit_graph()
    assert "geometry" in graph["builder"] and "ir" in graph["geometry"]
    assert cycles({"a": {"b": []}, "b": {"c": []}, "c": {"a": []}, "d": {"a": []}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b": []}, "b": {}}) == []


def test_no_import_circle_between_pipelines_folders():
    graph = unit_graph()
    found = cycles(graph)
    why = [f"{a} -> {b}: {graph[a][b][0]}" for c in found for a in c for b in c if b in graph.get(a, {})]
    assert not found, f"import circles {found}: " + "; ".join(why)


def test_geometry_stands_only_on_ir_and_below():
    graph = unit_graph()
    extra = {u: edges for u, edges in graph["geometry"].items() if u not in BELOW_GEOMETRY}
    assert not extra, f"geometry imports {sorted(extra)}: {[e for edges in extra.values() for e in edges]}"
    for below in sorted(BELOW_GEOMETRY):
        assert set(graph.get(below, {})) <= BELOW_GEOMETRY, (below, graph[below])


def test_no_module_over_600_lines():
    long = {str(p.relative_to(PIPELINE.parent)): n for p in _modules()
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert not long, f"over {MAX_LINES} lines: {long}"



MAX_ENGINE_FUNCTION = 60


def long_functions(folder: Path, limit: int) -> dict[str, int]:
    """{module:function: lines} of every function (methods and nested ones too) in
    `folder` longer than `limit` lines, docstring and comments included."""
    out = {}
    for path in sorted(folder.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > limit:
                    out[f"{path.relative_to(folder)}:{node.name}"] = n
    return out


def test_no_engine_function_over_60_lines(tmp_path):
    """The engine stays readable step by step: no function in engine/ over 60 lines."""
    long = long_functions(PIPELINE / "engine", MAX_ENGINE_FUNCTION)
    assert not long, f"over {MAX_ENGINE_FUNCTION} lines: {long}"
    (tmp_path / "m.py").write_text("def f():\n" + "    x = 1\n" * 60 + "\n\ndef g():\n    pass\n")
    assert long_functions(tmp_path, MAX_ENGINE_FUNCTION) == {"m.py:f": 61}  # the check sees one


# --- modules, the engine, perception ---------------------------------------------

# What the engine may import: the modules that know no domain (errors, files, digests,
# a worker's scratch folder and fork_join's share of the cores). A task's domain
# reaches it only through the task's action, which the builder hands it.
ENGINE_MAY_IMPORT = {"engine", "errors", "files", "digest", "fork_join", "scratch"}


@lru_cache(maxsize=1)
def module_graph() -> dict[str, set[str]]:
    """{module: the pipeline modules it imports}, packages' __init__ included; an
    imported name that is not a module counts as its module."""
    modules = {_dotted(p) for p in _modules()}
    graph: dict[str, set[str]] = {}
    for path in _modules():
        name = _dotted(path)
        targets = set()
        for imp in imported(path):
            while imp and imp not in modules:
                imp = imp.rpartition(".")[0]
            if imp and imp != name:
                targets.add(imp)
        graph[name] = targets
    return graph


def _is_package_of(a: str, b: str) -> bool:
    return b.startswith(a + ".")


def test_no_import_circle_between_modules():
    """No two modules import each other through any chain (a package's __init__ importing
    its own modules is how a package is made, not a circle)."""
    graph = {m: {t for t in ts if not _is_package_of(t, m) and not _is_package_of(m, t)}
             for m, ts in module_graph().items()}
    found = cycles({m: {t: [] for t in ts} for m, ts in graph.items()})
    assert not found, f"module circles: {found}"
    assert cycles({"p.a": {"p.b": []}, "p.b": {"p.a": []}}) == [["p.a", "p.b"]]


def test_the_engine_imports_no_domain_folder():
    graph = unit_graph()
    extra = {u: edges for u, edges in graph["engine"].items() if u not in ENGINE_MAY_IMPORT}
    assert not extra, f"engine imports {sorted(extra)}: {[e for edges in extra.values() for e in edges]}"


def _imports_bpy(path: Path) -> bool:
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
            [node.module or ""] if isinstance(node, ast.ImportFrom) else []
        if any(n == "bpy" or n.startswith("bpy.") for n in names):
            return True
    return False


def reaches(start: str, graph: dict[str, set[str]]) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        m = todo.pop()
        for t in graph.get(m, ()):
            if t not in seen:
                seen.add(t)
                todo.append(t)
    return seen


def test_perception_reaches_no_module_that_imports_bpy():
    """The reader and the baseline run where Blender is not installed: nothing perception
    imports, at any depth and inside functions too, imports bpy."""
    graph = module_graph()
    with_bpy = {_dotted(p) for p in _modules() if _imports_bpy(p)}
    assert "pipeline.render.cycles" in with_bpy  # the check sees a lazy `import bpy`
    bad = {m: sorted(reaches(m, graph) & with_bpy) for m in graph if m.startswith("pipeline.perception")}
    bad = {m: b for m, b in bad.items() if b or m in with_bpy}
    assert not bad, f"perception reaches bpy: {bad}"


def test_every_import_of_pipeline_names_a_module_that_exists():
    """Lazy imports inside functions run only when their branch does: a relative import
    left one level off by a move would fail first in a user's hands."""
    modules = {_dotted(p) for p in _modules()}
    broken = []
    for path in _modules():
        package = _dotted(path) if path.name == "__init__.py" else _dotted(path).rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("pipeline")):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(up + ([node.module] if node.module else []))
                if base not in modules:
                    broken.append(f"{_dotted(path)}:{node.lineno}: from {'.' * node.level}{node.module or ''}")
            elif isinstance(node, ast.Import):
                broken += [f"{_dotted(path)}:{node.lineno}: import {a.name}" for a in node.names
                           if a.name.startswith("pipeline") and a.name not in modules]
    assert not broken, broken
