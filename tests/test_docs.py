"""Docs that cannot drift: every ``priqn …`` command in README.md and docs/*.md parses.

Each command line is parsed by the real argument parser, built the way ``priqn``
builds it (:data:`priqn.cli.COMMANDS`, each module's ``configure_parser``), and never
run: an unknown verb, an unknown option or a missing required one fails the test.

Where commands are collected:

- fenced code blocks (any language but ``python`` / ``toml`` / ``text``...): every shell
  segment (split at ``&&``, ``||``, ``;``, ``|``) whose program is ``priqn`` (also
  ``.venv/bin/priqn``), after joining ``\\`` continuations and dropping ``# comments``;
- inline code spans that start with ``priqn``. Synopses are expanded: ``[--opt X]``
  is parsed with the option, ``a|b`` (``a\\|b`` in a table) as each alternative, and a
  ``...`` / ``…`` token is dropped.

``priqn VERB`` or ``priqn VERB SUB`` alone names a command (checked as a name: the verb
and sub-command exist); an ALL-CAPS placeholder given to a typed option
(``--snapshot N``) is accepted as a placeholder.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import io
import itertools
import re
import shlex
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from priqn import cli

ROOT = Path(__file__).resolve().parent.parent
NOT_SHELL = {"python", "py", "toml", "text", "json", "bibtex", "csv", "yaml", "diff"}
SEPARATORS = {"&&", "||", ";", "|", "(", ")", "$(", "&"}


def doc_files() -> list[Path]:
    """README.md and every docs/*.md."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


# --------------------------------------------------------------------- collecting


def _shell_segments(line: str) -> Iterator[list[str]]:
    """The simple commands of one shell line (tokens, comments dropped)."""
    lexer = shlex.shlex(line, posix=True, punctuation_chars="&;|()")
    lexer.whitespace_split = True
    lexer.commenters = "#"
    segment: list[str] = []
    for token in lexer:
        if token in SEPARATORS or set(token) <= set("&;|()"):
            yield segment
            segment = []
        else:
            segment.append(token)
    yield segment


def _priqn_argv(tokens: list[str]) -> list[str] | None:
    """The arguments after ``priqn`` if this simple command runs priqn, else None."""
    while tokens and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*=.*", tokens[0]):
        tokens = tokens[1:]  # VAR=value before the program
    if not tokens or Path(tokens[0]).name != "priqn":
        return None
    argv = tokens[1:]
    for i, token in enumerate(argv):  # a redirection ends the arguments
        if token in {">", ">>", "2>", "2>&1", "<"} or token.startswith((">", "2>")):
            return argv[:i]
    return argv


def code_block_commands(text: str) -> Iterator[tuple[int, list[str]]]:
    """``(line number, argv)`` of each priqn command in the fenced code blocks."""
    lang: str | None = None
    pending, start = "", 0
    for number, line in enumerate(text.splitlines(), 1):
        fence = re.match(r"^\s*(```|~~~)\s*([\w+-]*)", line)
        if fence:
            lang = None if lang is not None else fence.group(2).lower()
            continue
        if lang is None or lang in NOT_SHELL:
            continue
        stripped = re.sub(r"^\s*\$\s+", "", line)
        if not pending:
            start = number
        if stripped.rstrip().endswith("\\"):
            pending += stripped.rstrip()[:-1] + " "
            continue
        full, pending = pending + stripped, ""
        for segment in _shell_segments(full):
            argv = _priqn_argv(segment)
            if argv is not None:
                yield start, [w for w in map(_unbracket, argv) if w not in {"", "..."}]


def _unbracket(token: str) -> str:
    """``[--opt`` -> ``--opt``, ``X]`` -> ``X``; brackets inside a value are kept."""
    if token.startswith("["):
        token = token[1:]
    while token.endswith("]") and token.count("]") > token.count("["):
        token = token[:-1]
    return token


def _synopsis_tokens(text: str) -> list[str]:
    """Shell words of a synopsis, optional ``[...]`` groups opened, ``...`` dropped."""
    lexer = shlex.shlex(text, posix=False)
    lexer.whitespace_split = True
    words = []
    for raw in lexer:
        word = raw if raw[:1] in {"'", '"'} else _unbracket(raw)
        if word and word not in {"...", "…", "[", "]"}:
            words.extend(shlex.split(word) or [""])
    return words


def _expand_synopsis(span: str) -> list[list[str]]:
    """Every concrete argv a synopsis such as ``priqn a [--x X] b|c`` stands for."""
    tokens = _synopsis_tokens(span.replace("\\|", "|"))
    choices = [t.split("|") if re.fullmatch(r"[\w.-]+(\|[\w.-]+)+", t) else [t] for t in tokens]
    return [list(combo) for combo in itertools.product(*choices)]


def inline_commands(text: str) -> Iterator[tuple[int, list[str]]]:
    """``(line number, argv)`` of each inline ``priqn …`` span outside code blocks.

    A span may wrap over lines. ``priqn VERB: message`` (priqn's error format) is output,
    not a command, and a bare ``priqn`` names the program.
    """
    lines, in_block = [], False
    for line in text.splitlines():
        if re.match(r"^\s*(```|~~~)", line):
            in_block = not in_block
            line = ""
        lines.append("" if in_block else line)
    prose = "\n".join(lines)
    for match in re.finditer(r"`([^`]+)`", prose):
        number = prose.count("\n", 0, match.start()) + 1
        span = re.sub(r"^(\.venv/bin/)?priqn\b", "priqn", " ".join(match.group(1).split()))
        if not span.startswith("priqn ") or re.match(r"priqn [\w-]+:", span):
            continue
        for tokens in _expand_synopsis(span):
            yield number, tokens[1:]


Command = tuple[str, list[str], bool]
"""``("file:line", argv, inline)``: where, the arguments after ``priqn``, prose or block."""


def commands_in(text: str, where: str = "x") -> list[Command]:
    """Every priqn command of one markdown text."""
    block = [(f"{where}:{n}", argv, False) for n, argv in code_block_commands(text)]
    return block + [(f"{where}:{n}", argv, True) for n, argv in inline_commands(text)]


def all_commands() -> list[Command]:
    """Every priqn command in README.md and docs/*.md."""
    out: list[Command] = []
    for path in doc_files():
        out += commands_in(path.read_text(encoding="utf-8"), path.relative_to(ROOT).as_posix())
    return out


# ----------------------------------------------------------------------- parsing


PLACEHOLDER = re.compile(r"invalid \w+ value: '([A-Z][A-Z0-9_]*)'")
"""A typed option given a placeholder (``--snapshot N``): parsed again with a number."""


def _parser(argv: list[str]) -> tuple[argparse.ArgumentParser, list[str]]:
    """The parser ``priqn`` would use for ``argv``, and the arguments it gets."""
    if not argv or argv[0].startswith("-"):
        return cli._top_parser(), argv
    return cli.command_parser(argv[0])[0], argv[1:]


def parse_error(argv: list[str], inline: bool = False) -> str | None:
    """Why ``priqn argv`` would not parse (argparse's message), or None if it parses.

    ``priqn VERB`` and ``priqn VERB SUB`` (plain words, no options) name a command: a
    missing required argument is fine there, an unknown verb or sub-command is not. In
    prose (``inline``), ``priqn sweep --ray`` names an option: a missing required
    *positional* is fine there; a missing required option (``--out``) never is.
    """
    if argv and not argv[0].startswith("-") and argv[0] not in cli.COMMANDS:
        return f"unknown command {argv[0]!r} (priqn.cli.COMMANDS: {', '.join(cli.COMMANDS)})"
    parser, rest = _parser(argv)
    naming = len(argv) <= 2 and all(re.fullmatch(r"[a-z][a-z0-9_-]*", a) for a in argv)
    for _ in range(len(rest) + 1):
        err, out = io.StringIO(), io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
                parser.parse_args(rest)
            return None
        except SystemExit as exc:  # argparse errors exit 2; --help / --version exit 0
            if exc.code in (0, None):
                return None
        message = err.getvalue().strip().splitlines()[-1]
        placeholder = PLACEHOLDER.search(message)
        if placeholder and placeholder.group(1) in rest:
            rest = [("1" if a == placeholder.group(1) else a) for a in rest]
            continue
        required = re.search(r"the following arguments are required: (.*)", message)
        if required and naming:
            return None
        if required and inline and not any(n.startswith("-") for n in required[1].split(", ")):
            return None
        return message
    return "placeholders did not resolve"


def check(commands: list[Command]) -> list[str]:
    """One line per command that does not parse."""
    bad = []
    for where, argv, inline in commands:
        error = parse_error(argv, inline)
        if error:
            bad.append(f"{where}: priqn {shlex.join(argv)}\n    {error}")
    return bad


# ------------------------------------------------------------------------- tests


def test_the_docs_have_commands() -> None:
    """The collector finds commands in blocks and inline spans (else the test is empty)."""
    commands = all_commands()
    assert len(commands) > 50
    assert any(argv[:1] == ["sweep"] for _, argv, _ in commands)
    assert any(where.startswith("README.md") for where, _, _ in commands)


def test_every_documented_command_parses() -> None:
    bad = check(all_commands())
    assert not bad, "commands in the docs that priqn's parser refuses:\n" + "\n".join(bad)


@pytest.mark.parametrize(
    "markdown",
    [
        "See `priqn inspect results/table2_cpu/iqn__seed0 --net holdout/fourway_00\n"
        "--density 0.5`.\n",  # --out is required (a span over two lines)
        "```bash\npriqn inspect runs/x --net holdout/fourway_00\n```\n",  # --out is required
        "```bash\n.venv/bin/priqn frobnicate now\n```\n",  # unknown verb
        "Run `priqn sweep smoke --no-such-flag`.\n",  # unknown option
        "Run `priqn bench env|preorder|nope`.\n",  # one alternative is no sub-command
        "```bash\ncd x && priqn train \\\n  --agent\n```\n",  # --agent needs a value
        "```bash\npriqn sweep --ray\n```\n",  # a block is run: the experiment is missing
        "Mention `priqn inspect --net holdout/tjunction_00`.\n",  # a required option is not
    ],
)
def test_a_bad_command_fails(markdown: str) -> None:
    commands = commands_in(markdown)
    assert commands, "the bad command was not collected"
    assert check(commands), f"accepted: {commands}"


def test_good_commands_pass() -> None:
    text = (
        "```bash\n.venv/bin/pip install -e . && .venv/bin/priqn sweep smoke  # comment\n```\n"
        "Then `priqn report runs/ --out reports/x/ [--seed 0]` and `priqn inspect`.\n"
        "`priqn --version`, `priqn evaluate RUN --snapshot N`, `priqn bench env|preorder`,\n"
        "`priqn sweep --ray`\n"
    )
    commands = commands_in(text)
    assert len(commands) == 8
    assert not check(commands)


# ------------------------------------------------------------- what ships, in help


def _help(verb: str) -> str:
    parser, _ = _parser([verb])
    return " ".join(parser.format_help().split())


def test_sweep_help_lists_every_shipped_experiment() -> None:
    from priqn.paths import EXPERIMENTS, shipped

    names = sorted(p.stem for p in shipped(EXPERIMENTS).glob("*.toml"))
    assert {"headline", "table2", "smoke"} <= set(names)
    assert ", ".join(names) in _help("sweep")


def test_train_help_lists_every_preset() -> None:
    from priqn.run.train_config import PRESETS

    assert "right-of-way" in PRESETS
    assert " | ".join(PRESETS) in _help("train")


# ---------------------------------------------------------------------- version


def test_one_version_everywhere() -> None:
    """pyproject.toml types it; the package, ``priqn --version`` and the changelog read it."""
    import tomllib
    from importlib.metadata import version

    import priqn

    typed = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert version("priqn") == priqn.__version__ == typed, "reinstall: pip install -e ."
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        cli._top_parser().parse_args(["--version"])
    assert out.getvalue().strip() == f"priqn {typed}"
    changelog = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    releases = re.findall(r"^## \[(\d+\.\d+\.\d+)\] - \d{4}-\d{2}-\d{2}$", changelog, re.M)
    assert releases and releases[0] == typed, "CHANGELOG.md's newest release is the version"
    citation = (ROOT / "CITATION.cff").read_text(encoding="utf-8")
    assert re.search(rf"^version: {re.escape(typed)}$", citation, re.M), "CITATION.cff"


def test_ci_runs_the_readme_test_command_verbatim() -> None:
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    marker = next(i for i, line in enumerate(ci) if "the README's test command, verbatim" in line)
    command = ci[marker + 1].strip()
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert f"```bash\n{command}\n```" in readme, command


# ------------------------------------------------- numbers come from committed reports

REGION = re.compile(r"<!-- numbers: (\S+) -->(.*?)<!-- end numbers -->", re.S)
NUMBER = re.compile(r"[+-]?\d+(?:\.\d+)?")


def _normal(text: str) -> str:
    """Unicode minus as ASCII, thousands separators dropped (2,000,000 -> 2000000)."""
    return re.sub(r"(?<=\d),(?=\d{3}\b)", "", text.replace("−", "-"))


def unsourced_numbers(text: str) -> list[str]:
    """Numbers in ``<!-- numbers: FILE -->`` regions that FILE does not contain.

    Checked: every number with a decimal point or at least four digits (estimates,
    interval ends, budgets), as a whole token with its sign.
    """
    bad = []
    for source, region in REGION.findall(text):
        report = _normal((ROOT / source).read_text(encoding="utf-8"))
        for number in NUMBER.findall(_normal(region)):
            if "." not in number and len(number.lstrip("+-")) < 4:
                continue
            if not re.search(rf"(?<![\d.]){re.escape(number)}(?!\d)", report):
                bad.append(f"{number} (not in {source})")
    return bad


def test_readme_states_the_answer_in_its_first_screen() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    first = "\n".join(readme.splitlines()[:25])
    assert REGION.search(first), "the first 25 lines hold a sourced region with the answer"
    for words in ("20 training seeds per row", "60,000", "ruled out"):
        assert words in first, words
    assert len(readme.splitlines()) <= 250


def test_readme_numbers_come_from_the_reports() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(REGION.findall(readme)) >= 2
    assert not unsourced_numbers(readme)


def test_a_number_not_in_the_report_fails() -> None:
    text = (
        "<!-- numbers: docs/results/headline/report.md -->−0.9 [−12.2, +10.4]<!-- end numbers -->"
    )
    assert unsourced_numbers(text) == ["+10.4 (not in docs/results/headline/report.md)"]


def test_holm_family_sizes_in_the_docs_match_the_claims_table() -> None:
    import csv

    path = ROOT / "docs/results/table2_cpu/tables/claims.csv"
    with path.open(encoding="utf-8") as f:
        rows = [r for r in csv.DictReader(f) if r["role"] == "primary"]
    paper = sum(r["family"] == "paper" for r in rows)
    ours = sum(r["family"] == "ours" for r in rows)
    results = " ".join((ROOT / "docs/results.md").read_text(encoding="utf-8").split())
    assert f"family ({paper} comparisons) and within ours ({ours})" in results
    statistics = " ".join((ROOT / "docs/statistics.md").read_text(encoding="utf-8").split())
    assert f"{paper + ours} primary comparisons ({paper} + {ours})" in statistics


def test_readme_example_drives_a_committed_run(tmp_path: Path) -> None:
    """The README's example that loads a committed run and drives one hold-out episode runs
    as printed (in its own process: libsumo holds one simulation per process) and prints
    the episode's outcome."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"<!-- example: drive -->\n```python\n(.*?)```", readme, re.S)
    assert block, "README.md: the '<!-- example: drive -->' python block is missing"
    script = tmp_path / "drive.py"
    script.write_text(block[1], encoding="utf-8")
    out = subprocess.run(
        [sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr[-2000:]
    shown = ast.literal_eval(out.stdout.strip().splitlines()[-1])
    assert set(shown) == {"success", "collision", "off_road", "timeout", "episode_steps"}
    assert sum(bool(shown[k]) for k in ("success", "collision", "off_road", "timeout")) == 1
    assert shown["episode_steps"] >= 1
