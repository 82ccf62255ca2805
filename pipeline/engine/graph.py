"""Tasks and their keys: inputs (file content hashes) + parameters (sorted JSON) +
code version + what the dependencies made -> outputs. A task whose key is unchanged
does not run (DESIGN.md s.5).

Content decides. mtime and size only skip re-hashing a file whose (size, mtime_ns)
matches what the last build hashed; a fresh CI checkout just hashes everything once.
A dependency enters a key by the digest of the files it made, not by its own key
(early cutoff): a task that reran and made the same bytes (a .blend saved again
unchanged, a refactor of a reader) leaves the tasks after it up to date.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from ..digest import sha256_file


def canonical_json(data: Any) -> str:
    """The one text of a parameter set: sorted keys, no whitespace, repr floats."""
    return json.dumps(data, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def output_digest(files: dict[str, str]) -> str:
    """What a task made, as one hash: its files (paths relative to the build folder)
    and their content hashes."""
    return sha256_text(canonical_json(files))


class FileHasher:
    """Content hashes with a (size, mtime_ns) pre-check carried between builds."""

    def __init__(self, memo: dict[str, list] | None = None):
        self.memo: dict[str, list] = dict(memo or {})
        self.seen: set[str] = set()  # the paths hashed in this build

    def kept(self) -> dict[str, list]:
        """The memo of the files this build hashed: a moved or deleted file's entry
        goes, so the state file does not grow with every folder the sources were in."""
        return {k: v for k, v in sorted(self.memo.items()) if k in self.seen}

    def __call__(self, path: Path) -> str:
        path = Path(path)
        st = path.stat()
        key = str(path.resolve())
        self.seen.add(key)
        seen = self.memo.get(key)
        if seen and seen[0] == st.st_size and seen[1] == st.st_mtime_ns:
            return seen[2]
        digest = sha256_file(path)
        self.memo[key] = [st.st_size, st.st_mtime_ns, digest]
        return digest


@dataclass
class Task:
    """One unit of work.

    inputs:  source files read (absolute paths); their content hashes enter the key,
             each named by input_name.
    deps:    names of tasks whose outputs this task reads (the digests of what they
             made enter this key).
    params:  JSON-serialisable parameters; enter the key as sorted JSON.
    code:    code version of the steps the action runs (engine.code).
    outputs: paths relative to the build folder, each produced by this task alone.
    cost:    a scheduling hint only (longest first); it never changes what a task makes.
    warm:    modules the action imports: a worker that is idle while this task waits
             on others imports them beforehand (a hint as well, not in the key).
    action:  a picklable callable `action(**args)` run in a worker; it writes the
             outputs into the staging folder it is given and returns a JSON-able dict.
    problem: why the task cannot run, found by the planner (a UserError): the build
             reports it as the task's failure without running it.
    previous_ok: dependencies whose failure does not block the task: it runs on
             what such a dependency's last success left in the build folder (if
             all of it is in place) instead.
    reads_in: the folder of the files an action opens beyond its inputs (a source's
             textures, .bin, .mtl), which it cannot name before it runs. Its result's
             "opened" names them (path relative to this folder -> sha256 of the bytes
             read); the state keeps them beside the outputs, and the next build keys
             the task on their content then (`opened`), as make does a depfile.
             Relative names: the key does not depend on where the folder is.
    """

    name: str
    stage: str
    action: Callable[..., dict]
    args: dict
    inputs: tuple[Path, ...] = ()
    deps: tuple[str, ...] = ()
    params: Any = None
    code: str = ""
    outputs: tuple[str, ...] = ()
    cost: float = 0.0  # expected work (any unit): longer tasks start first; not in the key
    warm: tuple[str, ...] = ()  # modules to import ahead in an idle worker; not in the key
    problem: Exception | None = None  # the planner's reason the task cannot run
    previous_ok: tuple[str, ...] = ()  # deps whose last good outputs stand in when they fail
    reads_in: Path | None = None  # not in the key: the files' names and content are
    key: str = ""
    input_hashes: dict[str, str] = field(default_factory=dict)
    opened: dict[str, str | None] = field(default_factory=dict)  # in reads_in -> content hash (None: gone)
    base_key: str = ""

    def compute_key(self, hasher: FileHasher, dep_digests: dict[str, str], root: Path,
                    roots: dict[str, Path] | None = None, opened: dict | None = None) -> str:
        """`dep_digests`: output_digest of each dependency, as made or restored;
        `roots`: folders inputs are named under (input_name), else relative to `root`;
        `opened`: the files in `reads_in` the last run opened (their names; the state's
        record of it), hashed now."""
        self.input_hashes = {input_name(p, root, roots): hasher(p) for p in self.inputs}
        self.opened = {rel: _hash_or_none(hasher, self.reads_in / rel) for rel in sorted(opened or {})} \
            if self.reads_in is not None else {}
        return self._key(dep_digests)

    def settle(self, opened: dict[str, str], dep_digests: dict[str, str]) -> str:
        """The key of what the run just made: the files it reports it opened, with
        the hashes of the bytes it read (an edit during the run is seen next time)."""
        if self.reads_in is not None:
            self.opened = {str(rel): None if h is None else str(h) for rel, h in sorted(opened.items())}
            self._key(dep_digests)
        return self.key

    def _key(self, dep_digests: dict[str, str]) -> str:
        material = {
            "name": self.name,
            "inputs": self.input_hashes,
            "deps": {d: dep_digests[d] for d in sorted(self.deps)},
            "params": self.params,
            "code": self.code,
        }
        # the key without the opened files: a cache keeps under it which files the
        # task opened, for a build folder that has no record of its own
        self.base_key = sha256_text(canonical_json(material))
        self.key = sha256_text(canonical_json({**material, "opened": self.opened})) if self.opened else self.base_key
        return self.key


def _hash_or_none(hasher: FileHasher, path: Path) -> str | None:
    try:
        return hasher(path)
    except OSError:  # gone since the last run (the reader says what it misses)
        return None


def input_name(path: Path, root: Path, roots: dict[str, Path] | None = None) -> str:
    """An input's name in a key: `<label>/<path inside it>` under the first of `roots`
    (label -> folder) that holds it, so a key does not change when those folders move
    (a CI runner that checks the sources out elsewhere shares the cache); else its
    path relative to `root` (the build folder)."""
    # as spelled first (a symlinked tools/node_modules is inside the code's folder),
    # then with links resolved
    for spelling in (lambda q: Path(os.path.abspath(q)), lambda q: Path(q).resolve()):
        for label, folder in (roots or {}).items():
            try:
                return f"<{label}>/{spelling(path).relative_to(spelling(folder)).as_posix()}"
            except ValueError:
                continue
    try:
        return os.path.relpath(Path(path).resolve(), root.resolve())
    except ValueError:
        return str(path)


class GraphError(Exception):
    pass


def check_graph(tasks: list[Task]) -> list[Task]:
    """Tasks in dependency order; each output has exactly one producer, no cycles."""
    by_name: dict[str, Task] = {}
    producers: dict[str, str] = {}
    for t in tasks:
        if t.name in by_name:
            raise GraphError(f"two tasks named {t.name}")
        by_name[t.name] = t
        for out in t.outputs:
            if out in producers:
                raise GraphError(f"output {out} has two producers: {producers[out]} and {t.name}")
            producers[out] = t.name
    order: list[Task] = []
    state: dict[str, int] = {}

    def visit(name: str, chain: tuple[str, ...]):
        if state.get(name) == 2:
            return
        if state.get(name) == 1:
            raise GraphError("dependency cycle: " + " -> ".join((*chain, name)))
        if name not in by_name:
            raise GraphError(f"{chain[-1] if chain else '?'} depends on unknown task {name}")
        state[name] = 1
        for d in sorted(by_name[name].deps):
            visit(d, (*chain, name))
        state[name] = 2
        order.append(by_name[name])

    for t in sorted(tasks, key=lambda t: t.name):
        visit(t.name, ())
    return order


def explain(task: Task, previous: dict | None, cached: bool, dep_digests: dict[str, str]) -> dict:
    """Why a task runs or is skipped, from the key material of the last build."""
    if previous is None:
        reason = "restored from cache" if cached else "new"
        return {"task": task.name, "ran": not cached, "reason": reason, "changed": []}
    if previous.get("key") == task.key:
        return {"task": task.name, "ran": False, "reason": "up to date", "changed": []}
    changed = []
    old_inputs = previous.get("inputs", {})
    for path in sorted(set(old_inputs) | set(task.input_hashes)):
        if old_inputs.get(path) != task.input_hashes.get(path):
            changed.append(f"input {path}")
    old_opened = previous.get("opened", {})
    for path in sorted(set(old_opened) | set(task.opened)):
        if old_opened.get(path) != task.opened.get(path):
            changed.append(f"opened {path}")
    for dep in sorted(set(previous.get("deps", {})) | set(task.deps)):
        if previous.get("deps", {}).get(dep) != dep_digests.get(dep):
            changed.append(f"dependency {dep}")
    if canonical_json(previous.get("params")) != canonical_json(task.params):
        changed.append("parameters")
    if previous.get("code") != task.code:
        changed.append("code")
    if cached:
        return {"task": task.name, "ran": False, "reason": "restored from cache", "changed": changed}
    reason = "changed: " + ", ".join(changed) if changed else "key changed"
    return {"task": task.name, "ran": True, "reason": reason, "changed": changed}


def record(task: Task, dep_digests: dict[str, str], files: dict[str, str]) -> dict:
    """What the state file keeps of a task to explain the next build and to key the
    tasks after it (`files`: what it made, path -> content hash)."""
    return {
        "key": task.key,
        "digest": output_digest(files),
        "files": sorted(files),
        "inputs": task.input_hashes,
        "deps": {d: dep_digests[d] for d in sorted(task.deps)},
        "params": task.params,
        "code": task.code,
        "outputs": list(task.outputs),
        **({"opened": task.opened} if task.opened else {}),
    }
