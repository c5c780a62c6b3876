"""The answer table that opens docs/results.md agrees with the committed reports.

Each row of the table names a report (``docs/results/<name>/report.md``); its estimate,
interval, seeds, paper value and verdict are read back from that report's committed
``tables/*.csv`` and ``meta.json`` (and, for the paper's difference of a sequential
design without a comparisons table, from the design file the report reads), and must
agree to the printed precision. The README's first screen (its first 15 lines) must
state the same numbers and verdicts for the three operating points: `sumo` traffic at
60k decisions, `rude` traffic at 60k, and 240k decisions.
"""

from __future__ import annotations

import csv
import json
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAPER_DECISIONS = 2_000_000
COLUMNS = [
    "question",
    "budget",
    "traffic",
    "seeds",
    "estimate [95 % CI]",
    "paper",
    "verdict",
    "report",
]
ROWS = {  # prose name -> row name of the experiment files
    "IQN": "iqn",
    "Ensemble-IQN": "ensemble",
    "IQN-halving": "iqn-halving",
    "Pr-IQN*": "pr-iqn-qd-tp-eps0.2",
    "FSD": "pr-iqn-fsd-tp-eps0.2",
}
ENDPOINTS = {"success": "success", "violations": "violation"}
EXPERIMENTS = ROOT / "priqn" / "data" / "experiments"


# ------------------------------------------------------------------------ parsing


def plain(text: str) -> str:
    """Markdown emphasis and escapes dropped, Unicode minus as ASCII, spaces collapsed."""
    text = text.replace("\\*", "\0").replace("**", "").replace("\\|", "|")
    text = re.sub(r"(?<![\w*])\*(?!\s)([^*\n]+?)(?<!\s)\*(?![\w*])", r"\1", text)  # *italics*
    text = text.replace("\0", "*").replace("−", "-")
    return " ".join(text.split())


def answer_table(text: str) -> list[dict[str, str]]:
    """The first markdown table of ``text`` whose header is :data:`COLUMNS`."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        cells = [plain(c) for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and cells == COLUMNS:
            rows = []
            for row in lines[i + 2 :]:
                if not row.startswith("|"):
                    break
                values = [c.strip() for c in row.strip().strip("|").split("|")]
                assert len(values) == len(COLUMNS), row
                rows.append(dict(zip(COLUMNS, values, strict=True)))
            return rows
    raise AssertionError(f"no table with the columns {COLUMNS}")


ESTIMATE = re.compile(r"^([+-]?\d+\.\d) \[([+-]?\d+\.\d), ([+-]?\d+\.\d)\]$")


def parse_estimate(cell: str) -> tuple[float, float, float] | None:
    """``−0.9 [−12.2, +10.3]`` -> (-0.9, -12.2, 10.3); None for a row without one."""
    match = ESTIMATE.match(plain(cell))
    return tuple(float(g) for g in match.groups()) if match else None  # type: ignore[return-value]


def parse_budget(cell: str) -> int:
    """``60k (3 %)`` -> 60000, the share of the paper's budget checked on the way."""
    match = re.fullmatch(r"(\d+)k \((\d+) %\)", plain(cell))
    assert match, f"budget {cell!r}: write '60k (3 %)'"
    decisions = int(match[1]) * 1000
    assert int(match[2]) == round(100 * decisions / PAPER_DECISIONS), cell
    return decisions


def parse_question(cell: str) -> tuple[str, str, str]:
    """``Pr-IQN\\* − IQN, success`` -> (a row, b row, endpoint)."""
    match = re.fullmatch(r"(.+?) - (.+?), (success|violations)(?: \(ours\))?", plain(cell))
    assert match, f"question {cell!r}: write 'A − B, success' or 'A − B, violations'"
    return ROWS[match[1]], ROWS[match[2]], ENDPOINTS[match[3]]


def report_dir(cell: str) -> Path:
    match = re.search(r"\]\((results/[^)]+)/report\.md\)", cell)
    assert match, f"report {cell!r}: a link to results/<name>/report.md"
    return ROOT / "docs" / match[1]


def points(value: str | float) -> float:
    return 100 * float(value)


def same(printed: float, value: float) -> bool:
    """``printed`` is ``value`` rounded to one decimal."""
    return abs(printed - value) <= 0.05 + 1e-9


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(encoding="utf-8") as f:
        return list(csv.DictReader(f))


# -------------------------------------------------------------- reading a report


def design(folder: Path) -> dict:
    """The experiment file a report was made from (its meta.json names it)."""
    meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
    name = meta.get("experiment") or f"{folder.name}.toml"
    name = name if name.endswith(".toml") else f"{name}.toml"
    return tomllib.loads((EXPERIMENTS / name).read_text(encoding="utf-8"))


def traffic_of(folder: Path) -> str:
    return design(folder).get("experiment", {}).get("traffic", "sumo")


def paper_violations(folder: Path, budget: int, a: str, b: str) -> float:
    """The paper's Table II a − b in violations (collision + off-road), mean over densities."""
    labels = {"pr-iqn-qd-tp-eps0.2": "Pr-IQN QD ✓ 0.2 ✗", "iqn": "IQN"}
    rows = read_csv(folder / "tables" / f"outcome_mix_{budget // 1000}k.csv")

    def mean(label: str) -> float:
        values = [
            float(r["paper"])
            for r in rows
            if r["label"] == label and r["outcome"] in {"collision", "off_road"}
        ]
        assert len(values) == 6, f"{label}: collision and off-road at three densities"
        return sum(values) / 3

    return points(mean(labels[a]) - mean(labels[b]))


def from_report(folder: Path, a: str, b: str, endpoint: str, budget: int) -> dict:
    """Estimate, interval, seeds, paper and verdict of one comparison, as committed."""
    meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
    comparisons = folder / "tables" / "comparisons.csv"
    if comparisons.exists():  # question reports (explain, paper-point)
        rows = [
            r
            for r in read_csv(comparisons)
            if (r["a"], r["b"], r["endpoint"], int(r["budget"])) == (a, b, endpoint, budget)
        ]
        assert len(rows) == 1, f"{folder.name}: {a} − {b} {endpoint} at {budget}: {len(rows)} rows"
        row = rows[0]
        if endpoint == "success":
            paper = points(row["paper_difference"])
        else:
            paper = paper_violations(folder, budget, a, b)
        verdict = meta["verdicts"][row["comparison"]]
        assert verdict == row["verdict"], f"{folder.name}: meta.json and comparisons.csv differ"
        if verdict.startswith(f"{a} "):  # "pr-iqn-qd-tp-eps0.2 violates more": the prose name
            verdict = next(k for k, v in ROWS.items() if v == a) + verdict[len(a) :]
        return {
            "estimate": (points(row["difference"]), points(row["lo"]), points(row["hi"])),
            "seeds": (int(row["seeds_a"]), int(row["seeds_b"])),
            "paper": paper,
            "verdict": verdict,
        }
    # a sequential design's report (headline): the last look of each comparison
    assert endpoint == "success"
    steps = design(folder)["experiment"]["steps"]
    assert steps == budget, f"{folder.name} trains {steps} decisions, the table says {budget}"
    looks = [r for r in read_csv(folder / "tables" / "looks.csv") if (r["a"], r["b"]) == (a, b)]
    assert looks, f"{folder.name}: no comparison {a} − {b}"
    last = max(looks, key=lambda r: int(r["look"]))
    comparison = next(
        c for c in design(folder)["sequential"]["comparison"] if c["name"] == last["name"]
    )
    paper = comparison.get("paper_difference")
    return {
        "estimate": (points(last["diff"]), points(last["lo"]), points(last["hi"])),
        "seeds": (int(last["n_a"]), int(last["n_b"])),
        "paper": None if paper is None else points(paper),
        "verdict": meta["verdicts"][last["name"]],
    }


# ------------------------------------------------------------------------ checks


def results_rows() -> list[dict[str, str]]:
    return answer_table((ROOT / "docs" / "results.md").read_text(encoding="utf-8"))


def check_row(row: dict[str, str]) -> list[str]:
    """Why one row of the answer table disagrees with its report (empty: it agrees)."""
    folder = report_dir(row["report"])
    budget = parse_budget(row["budget"])
    traffic = plain(row["traffic"]).strip("`")
    bad = []
    if traffic != traffic_of(folder):
        bad.append(f"traffic {traffic}, the report's design {traffic_of(folder)}")
    seeds = re.fullmatch(r"(\d+) vs (\d+)", plain(row["seeds"]))
    assert seeds, f"seeds {row['seeds']!r}: write '20 vs 20'"
    printed_seeds = (int(seeds[1]), int(seeds[2]))
    verdict = plain(row["verdict"])
    if (folder / "tables" / "claims.csv").exists():  # the Table II grid: every other claim
        if design(folder)["experiment"]["steps"] != budget:
            bad.append(f"budget {budget}, the design's {design(folder)['experiment']['steps']}")
        claims = [r for r in read_csv(folder / "tables" / "claims.csv") if r["role"] == "primary"]
        others = [r for r in claims if r["claim"] not in {"star-vs-iqn", "star-vs-ensemble"}]
        counts = re.search(r"(\d+) .*?\((\d+) the paper's, (\d+) ours\)", plain(row["question"]))
        assert counts, f"question {row['question']!r}: 'the other N … (P the paper's, O ours)'"
        paper_n = sum(r["family"] == "paper" for r in others)
        ours_n = sum(r["family"] == "ours" for r in others)
        if (int(counts[1]), int(counts[2]), int(counts[3])) != (len(others), paper_n, ours_n):
            bad.append(f"{counts[0]}: the report has {len(others)} ({paper_n} + {ours_n})")
        if {r["verdict"] for r in others} != {verdict}:
            bad.append(f"verdict {verdict}: the report's {sorted({r['verdict'] for r in others})}")
        if {(int(r["n_first"]), int(r["n_second"])) for r in others} != {printed_seeds}:
            bad.append(f"seeds {printed_seeds}")
        return bad
    a, b, endpoint = parse_question(row["question"])
    truth = from_report(folder, a, b, endpoint, budget)
    estimate = parse_estimate(row["estimate [95 % CI]"])
    assert estimate, f"estimate {row['estimate [95 % CI]']!r}: write '−0.9 [−12.2, +10.3]'"
    for name, printed, value in zip(
        ("estimate", "lo", "hi"), estimate, truth["estimate"], strict=True
    ):
        if not same(printed, value):
            bad.append(f"{name} {printed:+.1f}, the report's {value:+.2f}")
    if printed_seeds != truth["seeds"]:
        bad.append(f"seeds {printed_seeds}, the report's {truth['seeds']}")
    paper = plain(row["paper"])
    if truth["paper"] is None:
        if paper not in {"-", "–"}:
            bad.append(f"paper {paper}: the report has no paper value")
    elif not re.fullmatch(r"[+-]\d+\.\d", paper) or not same(float(paper), truth["paper"]):
        bad.append(f"paper {paper}, the report's {truth['paper']:+.2f}")
    if verdict != truth["verdict"]:
        bad.append(f"verdict {verdict!r}, the report's {truth['verdict']!r}")
    return bad


def test_the_answer_table_has_every_operating_point() -> None:
    rows = results_rows()
    assert len(rows) >= 8
    points_ = {(parse_budget(r["budget"]), plain(r["traffic"]).strip("`")) for r in rows}
    assert {(60000, "sumo"), (60000, "rude"), (240000, "sumo")} <= points_


@pytest.mark.parametrize("index", range(len(results_rows())))
def test_each_row_agrees_with_its_report(index: int) -> None:
    row = results_rows()[index]
    bad = check_row(row)
    assert not bad, f"{plain(row['question'])} ({plain(row['budget'])}): " + "; ".join(bad)


@pytest.mark.parametrize(
    ("cell", "value"),
    [("estimate [95 % CI]", "−0.8 [−12.2, +10.3]"), ("seeds", "19 vs 20"), ("paper", "+14.8")],
)
def test_a_changed_number_fails(cell: str, value: str) -> None:
    row = dict(next(r for r in results_rows() if "headline" in r["report"]))
    row[cell] = value
    assert check_row(row), f"{cell} {value} accepted"


def test_a_changed_verdict_fails() -> None:
    row = dict(next(r for r in results_rows() if "paper-point" in r["report"]))
    row["verdict"] = "**reproduced**"
    assert check_row(row)


# ------------------------------------------------------------ the README's first screen


def readme_bullets() -> list[str]:
    """The bullets of the README's first 15 lines, each joined to one line of plain text."""
    first = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()[:15]
    bullets: list[str] = []
    for line in first:
        if line.startswith("- "):
            bullets.append(line[2:])
        elif bullets and line.startswith("  "):
            bullets[-1] += " " + line.strip()
        elif bullets and not line.startswith("  "):
            bullets.append("")  # a bullet ends at an unindented line
    return [plain(re.sub(r"<!--.*?-->", "", b)) for b in bullets if b]


def operating_point(bullet: str) -> tuple[int, str] | None:
    """(decisions, traffic) a README bullet opens with, e.g. (60000, 'rude')."""
    budget = re.search(r"(\d{2,3}),000 decisions \((\d+) % of", bullet)
    traffic = re.search(r"`([\w-]+)` traffic", bullet)
    if not (budget and traffic):
        return None
    decisions = int(budget[1]) * 1000
    assert int(budget[2]) == round(100 * decisions / PAPER_DECISIONS), bullet
    return decisions, traffic[1]


def readme_disagreements(bullets: list[str], rows: list[dict[str, str]]) -> list[str]:
    """What the README's first screen leaves out or states otherwise than the table."""
    by_point = {operating_point(b): b for b in bullets if operating_point(b)}
    bad = []
    for row in rows:
        question = plain(row["question"])
        if not re.fullmatch(r"Pr-IQN\* - IQN, (success|violations)", question):
            continue
        point = (parse_budget(row["budget"]), plain(row["traffic"]).strip("`"))
        bullet = by_point.get(point)
        if bullet is None:
            bad.append(f"no bullet for {point}")
            continue
        estimate = plain(row["estimate [95 % CI]"])
        clause = next((c for c in bullet.split("; ") if estimate in c), None)
        if clause is None:
            bad.append(f"{point} {question}: {estimate} not stated")
            continue
        endpoint = question.rsplit(", ", 1)[1]
        n_a, n_b = plain(row["seeds"]).split(" vs ")
        seeds = {f"{n_a} vs {n_b}"} | ({f"{n_a} training seeds per row"} if n_a == n_b else set())
        if endpoint not in clause:
            bad.append(f"{point}: the clause with {estimate} does not say {endpoint}")
        if not any(s in clause for s in seeds):
            bad.append(f"{point} {question}: seeds {plain(row['seeds'])} not in {clause!r}")
        if plain(row["verdict"]) not in clause:
            bad.append(f"{point} {question}: verdict {plain(row['verdict'])!r} not in {clause!r}")
        if plain(row["paper"]) not in " ".join(bullets + [readme_intro()]):
            bad.append(f"the paper's {plain(row['paper'])} ({question}) not on the first screen")
    return bad


def readme_intro() -> str:
    first = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()[:15]
    return plain(" ".join(line for line in first if not line.startswith(("- ", "  "))))


def test_readme_first_screen_states_the_table() -> None:
    bullets = readme_bullets()
    assert {operating_point(b) for b in bullets} >= {
        (60000, "sumo"),
        (60000, "rude"),
        (240000, "sumo"),
    }, "one bullet per operating point in the README's first 15 lines"
    bad = readme_disagreements(bullets, results_rows())
    assert not bad, "README's first screen vs docs/results.md's answer table:\n" + "\n".join(bad)
    for bullet in bullets:  # every answer links its report
        if operating_point(bullet):
            assert re.search(r"\(docs/results/[\w/-]+/report\.md\)", bullet), bullet


def test_a_readme_with_another_verdict_fails() -> None:
    bullets = [b.replace("inconclusive at 20 seeds", "reproduced") for b in readme_bullets()]
    assert readme_disagreements(bullets, results_rows())
    bullets = [b.replace("+15.5", "+15.6") for b in readme_bullets()]
    assert readme_disagreements(bullets, results_rows())
