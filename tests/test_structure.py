"""Shape of the code: no function or method in ``priqn/`` longer than one screenful or two.

Two limits, both on the ``def`` line to the last line, docstring included:

- :data:`MAX_LINES` (120): a hard limit. A longer function is split into named steps;
  the few that are better read whole are listed in :data:`ALLOWED`, each with why.
- :data:`EXPLAIN_LINES` (80): above it, a function must say why it is long. Convention:
  the comment block directly above the ``def`` (above its decorators, if any) holds a
  line that starts with ``# long:`` and gives the reason, e.g.::

      # long: the report.md template, read top to bottom as the reader sees it
      def report_markdown(...) -> str:

  The aim is shape, not trimming: a function is split where it does several things,
  and left whole, with the comment, where one long sequence really is clearest (a
  Markdown template, a constructor that checks its configuration field by field).
  :data:`UNEXPLAINED` lists the functions above 80 lines that are neither split nor
  commented yet, each with why (none may be added to it in ``priqn/analysis/``).
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


EXPLAIN_LINES = 80
"""Longest function or method without a ``# long:`` comment saying why it is long."""

LONG_COMMENT = "# long:"
"""How the comment directly above a long ``def`` starts (the reason follows it)."""

UNEXPLAINED: dict[str, str] = {
    # "priqn/module.py:qualified.name": "why it has neither been shaped nor commented yet",
}
"""Functions above :data:`EXPLAIN_LINES` with no ``# long:`` comment yet, each with why."""


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


def _explained(node: ast.AST, lines: list[str]) -> bool:
    """Whether the comment block directly above ``node`` (a ``def``, above its decorators)
    has a line ``# long: <reason>``."""
    first = min([node.lineno, *(d.lineno for d in getattr(node, "decorator_list", []))])
    i = first - 2  # 0-based index of the line above
    while i >= 0 and lines[i].strip().startswith("#"):
        text = lines[i].strip()
        if text.startswith(LONG_COMMENT) and text.removeprefix(LONG_COMMENT).strip():
            return True
        i -= 1
    return False


def _unexplained(node: ast.AST, prefix: str, lines: list[str], out: dict[str, int]) -> None:
    """Add the functions under ``node`` above :data:`EXPLAIN_LINES` with no ``# long:``
    comment to ``out``, as in :func:`_lengths`."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            name = f"{prefix}{child.name}"
            n = child.end_lineno - child.lineno + 1
            if not isinstance(child, ast.ClassDef) and n > EXPLAIN_LINES:
                if not _explained(child, lines):
                    out[name] = n
            _unexplained(child, f"{name}.", lines, out)
        else:
            _unexplained(child, prefix, lines, out)


def unexplained_long_functions() -> dict[str, int]:
    """``"priqn/<path>.py:<qualified name>" -> lines`` of every function above
    :data:`EXPLAIN_LINES` without a ``# long:`` comment."""
    out: dict[str, int] = {}
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).as_posix()
        text = path.read_text(encoding="utf-8")
        _unexplained(ast.parse(text, str(path)), f"{rel}:", text.splitlines(), out)
    return out


def test_functions_are_reasonably_short() -> None:
    lengths = function_lengths()
    assert "priqn/agents/subsets.py:optimal_subsets" in lengths  # the walk finds functions
    assert any(".__init__" in name for name in lengths)  # ... and methods
    long = {name: n for name, n in lengths.items() if n > MAX_LINES and name not in ALLOWED}
    assert not long, (
        f"functions longer than {MAX_LINES} lines (split them, or allow-list them in "
        "tests/test_structure.py with a reason): "
        + ", ".join(f"{name} ({n})" for name, n in sorted(long.items(), key=lambda kv: -kv[1]))
    )


def test_long_functions_say_why() -> None:
    """Above :data:`EXPLAIN_LINES` lines: split, or a ``# long:`` comment saying why."""
    assert _explained(  # the convention the docstring documents is the one checked
        ast.parse("# long: a template\ndef f():\n    pass\n").body[0],
        ["# long: a template", "def f():", "    pass"],
    )
    unexplained = unexplained_long_functions()
    assert not [n for n in UNEXPLAINED if n.startswith("priqn/analysis/")]
    found = {name: n for name, n in unexplained.items() if name not in UNEXPLAINED}
    assert not found, (
        f"functions longer than {EXPLAIN_LINES} lines with no '{LONG_COMMENT} <why>' comment "
        "directly above their def (shape them into steps that each read as one idea, or "
        "say why one long sequence is clearest): "
        + ", ".join(f"{name} ({n})" for name, n in sorted(found.items(), key=lambda kv: -kv[1]))
    )


def test_the_allow_list_is_current() -> None:
    """Every allowed function still exists and is still long (else drop its entry); every
    unexplained one is still above :data:`EXPLAIN_LINES` and still has no comment."""
    lengths = function_lengths()
    stale = sorted(name for name in ALLOWED if lengths.get(name, 0) <= MAX_LINES)
    assert not stale, f"drop these from ALLOWED (gone or now short): {stale}"
    unexplained = unexplained_long_functions()
    stale = sorted(name for name in UNEXPLAINED if name not in unexplained)
    assert not stale, f"drop these from UNEXPLAINED (gone, short or commented): {stale}"


# --------------------------------------------------------------------------- the layout

MAX_TOP_LEVEL_MODULES = 12
"""Most modules directly in ``priqn/`` (``__init__.py`` not counted): the public faces and
the frame (cli, config, errors, io, paths, plugins, checks, objectives, preorder, wrappers)
and the two files read top to bottom (experiment, train); everything else has a
sub-package named for its concept (docs/ARCHITECTURE.md)."""


def top_level_modules() -> list[str]:
    """The modules directly in ``priqn/``, ``__init__.py`` left out."""
    return sorted(p.name for p in ROOT.glob("*.py") if p.name != "__init__.py")


def class_homes() -> dict[str, list[str]]:
    """``class name -> ["priqn/<path>.py", ...]``: every module of ``priqn/`` defining a
    class of that name (nested classes included)."""
    out: dict[str, list[str]] = {}
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).as_posix()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.ClassDef):
                homes = out.setdefault(node.name, [])
                if rel not in homes:
                    homes.append(rel)
    return out


def test_few_top_level_modules() -> None:
    """The layout shows the architecture: at most :data:`MAX_TOP_LEVEL_MODULES` modules
    beside the sub-packages."""
    modules = top_level_modules()
    assert "train.py" in modules and "__init__.py" not in modules
    assert len(modules) <= MAX_TOP_LEVEL_MODULES, (
        f"{len(modules)} top-level modules in priqn/ (at most {MAX_TOP_LEVEL_MODULES}): "
        f"{', '.join(modules)}; move one into the sub-package of its concept"
    )


def test_each_class_name_names_one_thing() -> None:
    """No class name is defined in two modules of ``priqn/`` (one concept, one home)."""
    homes = class_homes()
    assert "priqn/run/folder.py" in homes["RunFolder"]  # the walk finds classes
    twice = {name: paths for name, paths in homes.items() if len(paths) > 1}
    assert not twice, "class names defined in more than one module (rename one): " + "; ".join(
        f"{name} in {', '.join(paths)}" for name, paths in sorted(twice.items())
    )


EPISODES_READER = "priqn/analysis/load.py"
"""The one module that reads an evaluation's ``episodes.csv`` (``load.read_episodes``)."""


def csv_reads_of_episodes() -> dict[str, list[int]]:
    """``path -> lines`` of every ``read_csv(...)`` / ``DictReader(...)`` call in ``priqn/``
    whose arguments name an episodes table (``episodes`` in their source text)."""
    out: dict[str, list[int]] = {}
    for path in sorted(ROOT.rglob("*.py")):
        source = path.read_text(encoding="utf-8")
        rel = path.relative_to(ROOT.parent).as_posix()
        for node in ast.walk(ast.parse(source, str(path))):
            func = getattr(node, "func", None)
            name = getattr(func, "attr", None) or getattr(func, "id", None)
            if isinstance(node, ast.Call) and name in ("read_csv", "DictReader"):
                args = " ".join(ast.get_source_segment(source, a) or "" for a in node.args)
                if "episodes" in args.lower() or "EVAL_EPISODES" in args:
                    out.setdefault(rel, []).append(node.lineno)
    return out


def test_one_reader_of_episodes_csv() -> None:
    """Reports, the sweep and the tools read ``episodes.csv`` through
    ``priqn.analysis.load.read_episodes`` only (one error message, one outcome rule)."""
    reads = csv_reads_of_episodes()
    assert EPISODES_READER in reads  # the walk finds the reader itself
    others = {path: lines for path, lines in reads.items() if path != EPISODES_READER}
    assert not others, f"episodes.csv read outside {EPISODES_READER}: {others}"


MAX_METHODS = 30
"""Most methods (properties included) defined in one class body of ``priqn/``: a class
with more holds more than one concept (``RunFolder`` held 56 before its split into
``run/`` folder, session, checkpointer, evaluations and metrics)."""


def method_counts() -> dict[str, int]:
    """``"priqn/<path>.py:<class>" -> functions defined directly in its body``."""
    out: dict[str, int] = {}
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).as_posix()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.ClassDef):
                defs = (ast.FunctionDef, ast.AsyncFunctionDef)
                out[f"{rel}:{node.name}"] = sum(isinstance(n, defs) for n in node.body)
    return out


def test_no_class_is_a_god_object() -> None:
    """No class of ``priqn/`` defines more than :data:`MAX_METHODS` methods."""
    counts = method_counts()
    assert counts["priqn/run/folder.py:RunFolder"] > 10  # the walk counts methods
    big = {name: n for name, n in counts.items() if n > MAX_METHODS}
    assert not big, f"classes with more than {MAX_METHODS} methods (split by concept): {big}"


def test_each_command_has_one_home() -> None:
    """One home per command, one style (docs/ARCHITECTURE.md, "Why these homes"):
    ``configure_parser`` and ``run`` in a package's ``cli.py``, or in the one module that
    is the command (``train.py``, a tool of ``tools/``, ``bench``'s sub-commands); no other
    module defines ``configure_parser``."""
    from priqn.cli import COMMANDS

    whole_modules = {"priqn.train", "priqn.sweep", "priqn.bench"}  # sweep: re-exports its cli
    homes = {"priqn/sweep/cli.py"}
    for command, (module, _) in COMMANDS.items():
        ok = module.endswith(".cli") or module.startswith("priqn.tools.")
        assert ok or module in whole_modules, f"priqn {command}: {module} is no command home"
        if module != "priqn.sweep":
            homes.add(
                module.replace(".", "/") + ("/__init__.py" if module == "priqn.bench" else ".py")
            )
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).as_posix()
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        if any(isinstance(n, ast.FunctionDef) and n.name == "configure_parser" for n in tree.body):
            assert rel in homes or rel.startswith("priqn/bench/"), (
                f"{rel} defines configure_parser but is no command's home"
            )
