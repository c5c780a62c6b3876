"""The import graph of ``priqn/`` has no cycle (module-level and function-level imports).

A cycle hides behind lazy imports until someone moves one line; this test reads every
module's imports with :mod:`ast`, so a lazy import inside a function counts too.
"""

from __future__ import annotations

import ast
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


def import_graph() -> dict[str, set[str]]:
    """``module -> priqn modules it imports`` (packages count as their ``__init__``)."""
    known = _modules()
    graph: dict[str, set[str]] = {m: set() for m in known}
    for mod, path in known.items():
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
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


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
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


def test_the_graph_is_read_correctly() -> None:
    graph = import_graph()
    assert "priqn.preorder" in graph["priqn.agents.registry"]  # function-level import
    assert "priqn.runs" in graph["priqn.train"]
    assert "priqn.agents.config" in graph["priqn.labels"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycle_in_priqn() -> None:
    found = cycles(import_graph())
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_torch_free_modules_stay_torch_free() -> None:
    """What the CLI, the sweep scheduler and the analysis import must not pull in torch."""
    graph = import_graph()
    light = ("priqn.agents.config", "priqn.labels", "priqn.config", "priqn.paths")
    for mod in light:
        text = _modules()[mod].read_text(encoding="utf-8")
        assert "import torch" not in text, mod
        heavy = {d for d in graph[mod] if d in ("priqn.agents.network", "priqn.preorder")}
        assert not heavy, f"{mod} imports {heavy}"


SWEEP_LAYERS = ("experiment", "cells", "process", "backends", "scheduler", "cli")
"""priqn.sweep's modules in import order: each may import only those before it."""


def test_sweep_package_imports_run_one_way() -> None:
    graph = import_graph()
    rank = {f"priqn.sweep.{m}": i for i, m in enumerate(SWEEP_LAYERS)}
    for mod, i in rank.items():
        later = sorted(d for d in graph[mod] if rank.get(d, -1) >= i or d == "priqn.sweep")
        assert not later, f"{mod} imports {later} (order: {' -> '.join(SWEEP_LAYERS)})"
    child = graph["priqn.sweep.child"]
    assert not child & {"priqn.sweep", "priqn.sweep.scheduler", "priqn.sweep.cli"}, child


def test_the_run_folder_knows_only_files() -> None:
    """runs.py is handed provenance (priqn.provenance) and never reads a net or asks SUMO;
    the checkpoint format stays torch-free at import (analysis reads run folders)."""
    graph = import_graph()
    below = sorted(d for d in graph["priqn.runs"] if d.startswith(("priqn.sim", "priqn.env")))
    assert not below, f"priqn.runs imports {below}"
    assert "priqn.checkpoint" in graph["priqn.runs"] and "priqn.checkpoint" in graph["priqn.train"]
    text = _modules()["priqn.checkpoint"].read_text(encoding="utf-8")
    assert "\nimport torch" not in text, "priqn.checkpoint imports torch at module level"
