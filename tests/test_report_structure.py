"""Shape of the reports (issue 60, "one pipeline"): one writer of report files, one
meta.json schema, modules a reader can hold in mind.

- Only :mod:`priqn.analysis.artifacts` writes files in ``priqn/analysis/`` (no
  ``savefig``, ``atomic_write_*``, ``write_text`` or ``write_bytes`` call elsewhere): report folders through
  its ``render``, a replay's cached rows through its ``write_csv`` / ``write_json``.
  A run's training curve is drawn in :mod:`priqn.run.curve`, not here.
- Every committed ``docs/results/**/meta.json`` has the schema's common keys.
- No module in ``priqn/analysis/`` (or ``priqn/agents/``) is over :data:`MAX_MODULE_LINES`.
- Every report kind is built from sections, and no report kind's module imports another's
  (issue 69).
"""

from __future__ import annotations

import ast
import json
from pathlib import Path

import priqn
from priqn.analysis.artifacts import META_SCHEMA
from priqn.analysis.reports import REPORTS

PACKAGE = Path(priqn.__file__).resolve().parent
REPO = PACKAGE.parent

WRITERS = frozenset(
    {"savefig", "atomic_write_text", "atomic_write_bytes", "atomic_write_json", "write_text",
     "write_bytes"}
)  # fmt: skip
"""Calls that write a file; in ``priqn/analysis/`` only the artifacts module makes them."""

ALLOWED_WRITERS: dict[str, str] = {
    "priqn/analysis/artifacts.py": "the one writer of a report's files",
}
"""Where a writing call is allowed: a whole module, or ``module:function``."""

MAX_MODULE_LINES = 800
"""Longest module in ``priqn/analysis/`` and ``priqn/agents/``."""

META_KEYS = frozenset({"schema", "kind", "command", "experiment"})
"""The keys every report's meta.json has (:meth:`priqn.analysis.artifacts.ReportFolder.meta`)."""


def _called_name(call: ast.Call) -> str | None:
    """The name a call is made by: ``f(...)`` -> ``f``, ``x.f(...)`` -> ``f``."""
    func = call.func
    if isinstance(func, ast.Name):
        return func.id
    return func.attr if isinstance(func, ast.Attribute) else None


def _writing_calls(path: Path) -> list[str]:
    """``module:function:name`` of every writing call (:data:`WRITERS`) in ``path``, the
    function being the outermost ``def`` around it (``<module>`` at the top level)."""
    rel = path.relative_to(REPO).as_posix()
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    found = []

    def walk(node: ast.AST, where: str) -> None:
        for child in ast.iter_child_nodes(node):
            inner = where
            if where == "<module>" and isinstance(child, (ast.FunctionDef, ast.ClassDef)):
                inner = child.name
            if isinstance(child, ast.Call) and _called_name(child) in WRITERS:
                found.append(f"{rel}:{inner}:{_called_name(child)}")
            walk(child, inner)

    walk(tree, "<module>")
    return found


def _listed(call: str, where: dict[str, str]) -> bool:
    """Whether ``module:function:name`` falls under an entry of ``where``."""
    module, function, _ = call.split(":")
    return module in where or f"{module}:{function}" in where


def test_only_the_artifacts_module_writes_report_files() -> None:
    calls = [c for p in sorted((PACKAGE / "analysis").glob("*.py")) for c in _writing_calls(p)]
    assert any(c.startswith("priqn/analysis/artifacts.py:") for c in calls)  # the walk finds them
    stray = [c for c in calls if not _listed(c, ALLOWED_WRITERS)]
    assert not stray, f"write report files through ReportFolder (analysis/artifacts.py): {stray}"


def test_every_committed_meta_json_has_the_schema_keys() -> None:
    metas = sorted((REPO / "docs" / "results").rglob("meta.json"))
    assert metas
    for path in metas:
        meta = json.loads(path.read_text())
        where = path.relative_to(REPO)
        assert META_KEYS <= set(meta), f"{where}: lacks {sorted(META_KEYS - set(meta))}"
        assert meta["schema"] == META_SCHEMA, where
        assert meta["kind"] in REPORTS, where
        assert meta["experiment"] is None or isinstance(meta["experiment"], str), where
        assert not str(meta["experiment"]).endswith(".toml"), f"{where}: a name, not a file"


def test_every_committed_report_file_belongs_to_a_regenerable_report() -> None:
    """Every file under docs/results/ lies in a folder with a meta.json, so that
    tests/test_results.py (which finds reports by their meta.json) regenerates it; a
    report that cannot be regenerated from git belongs in docs/history/."""
    results = REPO / "docs" / "results"
    orphans = []
    for path in sorted(p for p in results.rglob("*") if p.is_file()):
        folders = [f for f in path.parents if f == results or results in f.parents]
        if not any((f / "meta.json").is_file() for f in folders):
            orphans.append(path.relative_to(REPO).as_posix())
    assert not orphans, f"no meta.json in these files' report folders: {orphans[:5]}"


def _long_modules(folder: str) -> dict[str, int]:
    lengths = {
        p.relative_to(REPO).as_posix(): len(p.read_text(encoding="utf-8").splitlines())
        for p in sorted((PACKAGE / folder).glob("*.py"))
    }
    assert lengths  # the walk finds modules
    return {name: n for name, n in lengths.items() if n > MAX_MODULE_LINES}


def test_no_analysis_module_is_over_800_lines() -> None:
    long = _long_modules("analysis")
    assert not long, f"split these modules (at most {MAX_MODULE_LINES} lines): {long}"


def test_no_agents_module_is_over_800_lines() -> None:
    """Fails on a checkout where priqn/agents/preorder.py (982 lines at 7a20280) is not yet
    split: that split is another change of issue 60."""
    long = _long_modules("agents")
    assert not long, f"split these modules (at most {MAX_MODULE_LINES} lines): {long}"


REPORT_MODULES = frozenset(
    {"report", "sequential_report", "questions_report", "calibration", "horizon",
     "design_report", "mechanism", "standstill", "collisions", "traffic_report"}
)  # fmt: skip
"""The modules that build a report kind's sections (:data:`REPORTS`' builders)."""


def _imported_analysis_modules(path: Path) -> set[str]:
    """The ``priqn.analysis`` modules ``path`` imports, anywhere in it (lazy imports too)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.ImportFrom) and node.module == "priqn.analysis":
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("priqn.analysis."):
            found.add(node.module.split(".")[2])
        elif isinstance(node, ast.Import):
            found |= {
                a.name.split(".")[2] for a in node.names if a.name.startswith("priqn.analysis.")
            }
    return found


def test_every_kind_is_built_from_sections_and_no_report_module_imports_another() -> None:
    """Issue 69: each kind is a builder of a ``Report`` (one renderer writes it); a kind's
    module shares code with another only through frames, estimates or figures modules."""
    assert all(callable(kind.build) for kind in REPORTS.values())
    crossing = {
        name: sorted(
            (_imported_analysis_modules(PACKAGE / "analysis" / f"{name}.py") & REPORT_MODULES)
            - {name}
        )
        for name in sorted(REPORT_MODULES)
    }
    assert not {k: v for k, v in crossing.items() if v}, crossing
