"""Shape of the code: no function or method in ``priqn/`` longer than one screenful or two.

A function that does not fit in :data:`MAX_LINES` lines is split into named steps; the
few that are better read whole are listed in :data:`ALLOWED`, each with why.
"""

from __future__ import annotations

import ast
from pathlib import Path

import priqn

ROOT = Path(priqn.__file__).resolve().parent

MAX_LINES = 120
"""Longest function or method (``def`` line to last line, docstring included)."""

ALLOWED: dict[str, str] = {
    # "priqn/module.py:qualified.name": "why it reads better in one piece",
}
"""Functions allowed over :data:`MAX_LINES`, each with its justification (none today)."""


def _lengths(node: ast.AST, prefix: str, out: dict[str, int]) -> None:
    """Add the functions under ``node`` to ``out`` as ``prefix + qualified name``."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            name = f"{prefix}{child.name}"
            if not isinstance(child, ast.ClassDef):
                out[name] = child.end_lineno - child.lineno + 1
            _lengths(child, f"{name}.", out)
        else:
            _lengths(child, prefix, out)


def function_lengths() -> dict[str, int]:
    """``"priqn/<path>.py:<qualified name>" -> lines`` of every function and method."""
    out: dict[str, int] = {}
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).as_posix()
        _lengths(ast.parse(path.read_text(encoding="utf-8"), str(path)), f"{rel}:", out)
    return out


def test_functions_are_reasonably_short() -> None:
    lengths = function_lengths()
    assert "priqn/preorder.py:optimal_subsets" in lengths  # the walk finds functions
    assert any(".__init__" in name for name in lengths)  # ... and methods
    long = {name: n for name, n in lengths.items() if n > MAX_LINES and name not in ALLOWED}
    assert not long, (
        f"functions longer than {MAX_LINES} lines (split them, or allow-list them in "
        "tests/test_structure.py with a reason): "
        + ", ".join(f"{name} ({n})" for name, n in sorted(long.items(), key=lambda kv: -kv[1]))
    )


def test_the_allow_list_is_current() -> None:
    """Every allowed function still exists and is still long (else drop its entry)."""
    lengths = function_lengths()
    stale = sorted(name for name in ALLOWED if lengths.get(name, 0) <= MAX_LINES)
    assert not stale, f"drop these from ALLOWED (gone or now short): {stale}"
