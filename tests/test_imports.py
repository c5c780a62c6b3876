"""The import graph of ``priqn/``: no cycle between modules, none between rooms, layers kept.

A cycle hides behind lazy imports until someone moves one line; these tests read every
module's imports with :mod:`ast`, so a lazy import inside a function counts too. A
*room* is a top-level module or sub-package of ``priqn`` (``priqn.preorder``,
``priqn.agents``, ``priqn.sweep``); rooms import one way, so each can be read (and
moved) with only the rooms below it in mind.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import priqn

ROOT = Path(priqn.__file__).resolve().parent


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def _resolve(name: str, known: dict[str, Path]) -> str | None:
    """The module ``name`` refers to: itself, or the closest enclosing known module."""
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


def _import_nodes(tree: ast.AST, module_level: bool) -> Iterator[ast.Import | ast.ImportFrom]:
    """Every import statement of ``tree``; with ``module_level``, only those that run when
    the module is imported (not inside a function or a lambda)."""
    todo = [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        for child in ast.iter_child_nodes(node):
            lazy = isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if not (module_level and lazy):
                todo.append(child)


def import_graph(module_level: bool = False) -> dict[str, set[str]]:
    """``module -> priqn modules it imports`` (packages count as their ``__init__``);
    ``module_level``: only the imports that run at import time."""
    known = _modules()
    graph: dict[str, set[str]] = {m: set() for m in known}
    for mod, path in known.items():
        is_pkg = path.name == "__init__.py"
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        for node in _import_nodes(tree, module_level):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                if node.level:
                    base = mod if is_pkg else mod.rpartition(".")[0]
                    for _ in range(node.level - 1):
                        base = base.rpartition(".")[0]
                    parent = f"{base}.{node.module}" if node.module else base
                else:
                    parent = node.module or ""
                # ``from pkg import sub`` imports the submodule when there is one.
                targets = [f"{parent}.{a.name}" for a in node.names] + [parent]
            for t in targets:
                if t == "priqn" or t.startswith("priqn."):
                    dep = _resolve(t, known)
                    if dep is not None and dep != mod:
                        graph[mod].add(dep)
    return graph


def room(module: str) -> str:
    """The room of ``module``: ``priqn.agents.network`` -> ``priqn.agents``."""
    return ".".join(module.split(".")[:2])


def room_graph(graph: dict[str, set[str]]) -> dict[str, dict[str, list[tuple[str, str]]]]:
    """``room -> {room it imports: [(module, imported module), ...]}`` (the evidence)."""
    out: dict[str, dict[str, list[tuple[str, str]]]] = {}
    for mod, deps in graph.items():
        edges = out.setdefault(room(mod), {})
        for dep in sorted(deps):
            if room(dep) != room(mod):
                edges.setdefault(room(dep), []).append((mod, dep))
    return out


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def cycle_path(graph: dict[str, set[str]], component: list[str]) -> list[str]:
    """One cycle through a strongly connected ``component``: ``[a, b, ..., a]``."""
    start, members = component[0], set(component)
    parent: dict[str, str] = {}
    frontier = [start]
    while frontier:  # breadth-first inside the component, back to ``start``
        nxt = []
        for v in frontier:
            for w in sorted(graph[v] & members):
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(parent[path[-1]])
                    return [start, *reversed(path[:-1]), start]
                if w not in parent:
                    parent[w] = v
                    nxt.append(w)
        frontier = nxt
    raise AssertionError(f"{component} is not strongly connected")


def test_the_graph_is_read_correctly() -> None:
    graph = import_graph()
    assert "priqn.agents.preorder" in graph["priqn.agents.registry"]  # function-level import
    assert "priqn.agents.preorder" not in import_graph(module_level=True)["priqn.agents.registry"]
    assert "priqn.run.folder" in graph["priqn.train"]
    assert "priqn.agents.config" in graph["priqn.agents.labels"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    three = {"a": {"b", "d"}, "b": {"c"}, "c": {"a"}, "d": set()}
    assert cycle_path(three, ["a", "b", "c"]) == ["a", "b", "c", "a"]
    assert room("priqn.agents.network") == "priqn.agents" and room("priqn") == "priqn"
    rooms = room_graph({"priqn.a.x": {"priqn.b"}, "priqn.b": {"priqn.a.y"}, "priqn.a.y": set()})
    assert rooms["priqn.a"] == {"priqn.b": [("priqn.a.x", "priqn.b")]}


def test_no_import_cycle_in_priqn() -> None:
    found = cycles(import_graph())
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_no_import_cycle_between_rooms() -> None:
    """Rooms (top-level modules and sub-packages of priqn) import one way."""
    rooms = room_graph(import_graph())
    graph = {r: set(edges) for r, edges in rooms.items()}
    messages = []
    for component in cycles(graph):
        path = cycle_path(graph, component)
        steps = [
            f"{a} -> {b} ({', '.join(f'{m} imports {d}' for m, d in rooms[a][b][:3])})"
            for a, b in zip(path, path[1:], strict=False)
        ]
        messages.append(" -> ".join(path) + ":\n  " + "\n  ".join(steps))
    assert not messages, "room-level import cycles:\n" + "\n".join(messages)


TORCH_FREE: tuple[str, ...] = (
    "priqn.agents.config",
    "priqn.agents.labels",
    "priqn.agents.preorder",
    "priqn.config",
    "priqn.paths",
    "priqn.experiment",
    "priqn.run.metrics",
    "priqn.run.folder",
    "priqn.run.session",
    "priqn.run.checkpoint",
    "priqn.run.checkpointer",
    "priqn.run.evaluations",
    "priqn.analysis.load",
    "priqn.sweep.scheduler",
    "priqn.cli",
)
"""What the CLI, the sweep scheduler and the analysis import, and the preorder graph
(its comparators and Algorithm 1 are their own modules): torch stays out of it."""


def _imports_torch_at_module_level(path: Path) -> bool:
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    for node in _import_nodes(tree, module_level=True):
        names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module]
        if any(n == "torch" or str(n).startswith("torch.") for n in names):
            return True
    return False


def test_torch_free_modules_stay_torch_free() -> None:
    """Importing any module of :data:`TORCH_FREE` (with everything it imports at import
    time, parent packages included) never imports torch."""
    graph, known = import_graph(module_level=True), _modules()
    for mod in TORCH_FREE:
        seen, todo = {mod}, [mod]
        while todo:
            m = todo.pop()
            parents = [".".join(m.split(".")[:i]) for i in range(1, m.count(".") + 1)]
            for dep in [*graph[m], *parents]:
                if dep not in seen:
                    seen.add(dep)
                    todo.append(dep)
        heavy = sorted(m for m in seen if _imports_torch_at_module_level(known[m]))
        assert not heavy, f"importing {mod} imports torch through {heavy}"


SWEEP_LAYERS = ("cells", "commit", "process", "backends", "scheduler", "cli")
"""priqn.sweep's modules in import order: each may import only those before it."""


def test_sweep_package_imports_run_one_way() -> None:
    graph = import_graph()
    rank = {f"priqn.sweep.{m}": i for i, m in enumerate(SWEEP_LAYERS)}
    for mod, i in rank.items():
        later = sorted(d for d in graph[mod] if rank.get(d, -1) >= i or d == "priqn.sweep")
        assert not later, f"{mod} imports {later} (order: {' -> '.join(SWEEP_LAYERS)})"
    child = graph["priqn.sweep.child"]
    assert not child & {"priqn.sweep", "priqn.sweep.scheduler", "priqn.sweep.cli"}, child


def test_the_experiment_file_is_below_its_readers() -> None:
    """priqn.experiment (the grid's schema) imports neither the sweep nor the analysis, so
    both can read an experiment; the analysis never imports the sweep."""
    graph = import_graph()
    above = sorted(
        d for d in graph["priqn.experiment"] if room(d) in ("priqn.sweep", "priqn.analysis")
    )
    assert not above, f"priqn.experiment imports {above}"
    for mod in (m for m in graph if room(m) == "priqn.analysis"):
        assert not {d for d in graph[mod] if room(d) == "priqn.sweep"}, mod


def test_the_run_folder_knows_only_files() -> None:
    """run/folder.py and the modules that work on a run folder's files (session,
    checkpointer, evaluations) are handed provenance (priqn.run.provenance) and never read
    a net or ask SUMO; the checkpoint format stays torch-free at import (analysis reads run
    folders)."""
    graph = import_graph()
    for mod in ("folder", "session", "checkpointer", "evaluations"):
        mod = f"priqn.run.{mod}"
        below = sorted(d for d in graph[mod] if d.startswith(("priqn.sim", "priqn.env")))
        assert not below, f"{mod} imports {below}"
    assert (
        "priqn.run.checkpoint" in graph["priqn.run.checkpointer"]
        and "priqn.run.checkpoint" in graph["priqn.train"]
    )
    text = _modules()["priqn.run.checkpoint"].read_text(encoding="utf-8")
    assert "\nimport torch" not in text, "priqn.run.checkpoint imports torch at module level"


def test_the_analysis_replays_nothing() -> None:
    """No module of priqn.analysis imports torch, SUMO or the rooms that play a policy
    (env, sim, tools) -- at import or inside a function: it makes tables and figures from
    files. Replaying decisions (priqn mechanism) is tools/' (docs/ARCHITECTURE.md)."""
    banned = ("torch", "libsumo", "traci", "sumolib", "priqn.env", "priqn.sim", "priqn.tools")
    found = []
    for mod, path in _modules().items():
        if room(mod) != "priqn.analysis":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        for node in _import_nodes(tree, module_level=False):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module]
            found += [f"{mod}: {n}" for n in names if str(n).startswith(banned)]
    assert not found, "the analysis imports what replays: " + ", ".join(found)
