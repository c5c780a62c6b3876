"""A pre-registered group-sequential experiment over training seeds, replayed from its cells.

The design lives in the experiment file's ``[sequential]`` table
(:class:`priqn.experiment.SequentialSpec`); this module only reads it. From the
run folders it

1. collects one **endpoint** score per (row, training seed): the hold-out success rate
   averaged over the evaluation densities (:func:`collect_scores`), refusing any cell
   trained at a commit the design does not list;
2. **replays AdaStop** look by look on those scores (:func:`replay`): each family gets its
   own ``adastop.MultipleAgentsComparator`` with the design's n, K, B, α, β and seed, and
   look k is taken once every row still in an open comparison has its first k·n seeds
   — the decisions are a pure function of the committed scores, so a report regenerates
   them exactly;
3. says which cells the next look needs (:func:`next_cells`), which is what ``priqn
   sweep`` trains for such an experiment;
4. gives each comparison its pre-registered **verdict word** (:func:`verdict`).

Arrays: ``scores_S`` is one row's per-seed scores in seed order (seed 0 first).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from priqn.analysis import inference
from priqn.episodes import resolve_outcomes
from priqn.errors import PriqnError
from priqn.experiment import cell_dir_name
from priqn.runs import RunFolder, Status

PAPER_TRAINING_DECISIONS = 2_000_000
"""The paper's training budget per run (``priqn/presets/train_paper.toml`` total_steps)."""

DECISIONS: tuple[str, ...] = ("larger", "smaller", "equal", "continue")
"""AdaStop's decision words for ``a`` vs ``b``: a larger, a smaller, not different (only at
the last look with β = 0), or undecided yet."""


@dataclasses.dataclass(frozen=True)
class Score:
    """One cell's endpoint."""

    policy: str
    seed: int
    score: float
    """Hold-out success rate averaged over the evaluation densities."""
    episodes: int
    """Hold-out episodes behind it."""
    git_sha: str
    """The commit the cell trained at (``meta.json``)."""
    run_dir: str
    """The run folder, relative to the working directory when possible."""


def _cell_score(run_dir: Path, policy: str, seed: int) -> Score | None:
    """The endpoint of one complete cell, or None when it is not complete yet."""
    folder = RunFolder(run_dir)
    if not run_dir.is_dir() or folder.recorded_status() != Status.COMPLETE:
        return None
    if folder.recorded_eval_status() != Status.COMPLETE:
        return None
    csv = folder.evaluation_dir() / RunFolder.EVAL_EPISODES
    try:
        episodes = resolve_outcomes(pd.read_csv(csv))
    except (OSError, ValueError, KeyError) as exc:
        raise PriqnError(f"{csv}: unreadable episode table ({exc})") from None
    per_density = episodes.groupby("density")["success"].mean().astype(float)
    return Score(
        policy,
        seed,
        float(per_density.mean()),
        len(episodes),
        str(folder.meta().get("git_sha", "")),
        _relative(run_dir),
    )


def _relative(path: Path) -> str:
    """``path`` relative to the working directory when inside it (reports stay portable)."""
    try:
        return str(Path(path).absolute().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def collect_scores(exp: Any) -> pd.DataFrame:
    """Endpoint scores of every complete cell of the design's rows and seeds.

    Seeds in ``prior_seeds`` come from ``<prior_runs>/<policy>__seed<k>``, the others from
    the experiment's own folder. A cell trained at a commit not in ``code_commits`` (when
    the design lists any) is refused in one line. Columns: those of :class:`Score`.
    """
    seq = exp.sequential
    if seq.prior_seeds and not Path(seq.prior_runs).is_dir():
        raise PriqnError(
            f"{exp.path} [sequential].prior_runs: {seq.prior_runs} is not a folder here "
            f"({Path.cwd()}); run from the folder it is relative to (the repository root)"
        )
    rows = []
    for pol in exp.policies:
        for seed in [*seq.prior_seeds, *exp.experiment.seeds]:
            root = Path(seq.prior_runs) if seed in seq.prior_seeds else exp.runs_dir
            run_dir = root / cell_dir_name(pol.name, seed)
            score = _cell_score(run_dir, pol.name, seed)
            if score is None:
                continue
            if seq.code_commits and score.git_sha.removesuffix("-dirty") not in seq.code_commits:
                raise PriqnError(
                    f"{run_dir}: trained at commit {score.git_sha[:12]}, which "
                    f"{exp.path} [sequential].code_commits does not list; a sequential "
                    "experiment never mixes code versions (retrain it at the frozen commit)"
                )
            if score.git_sha.endswith("-dirty"):
                raise PriqnError(
                    f"{run_dir}: trained from a checkout with uncommitted changes "
                    f"({score.git_sha}); retrain it from the frozen commit"
                )
            rows.append(dataclasses.asdict(score))
    columns = [f.name for f in dataclasses.fields(Score)]
    return pd.DataFrame(rows, columns=columns)


def density_frame(exp: Any, scores: pd.DataFrame) -> pd.DataFrame:
    """Descriptive only (the endpoint is the mean over densities): per row and evaluation
    density, the hold-out success over the row's scored cells — mean and 95 % t interval
    over training seeds — beside the paper's Table II value for the row's label, if it has
    one. Columns: policy, density, seeds, mean, lo, hi, paper. ``tables/density.csv``."""
    from scipy import stats

    from priqn.analysis.claims import PAPER_DENSITIES, PAPER_SUCCESS

    rows = []
    for policy in [p.name for p in exp.policies]:
        mine = scores[scores["policy"] == policy]
        if mine.empty:
            continue
        success_SD = pd.DataFrame(  # one row per cell (seed), one column per density
            [
                resolve_outcomes(pd.read_csv(RunFolder(d).eval_episodes_path))
                .groupby("density")["success"]
                .mean()
                for d in mine["run_dir"]
            ]
        ).sort_index(axis=1)
        label = RunFolder(mine["run_dir"].iloc[0]).meta().get("labels", {}).get("label")
        paper = dict(zip(PAPER_DENSITIES, PAPER_SUCCESS.get(str(label), ()), strict=False))
        for density, column in success_SD.items():
            x = column.dropna().to_numpy(float)
            half = (
                stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size)
                if x.size >= 2
                else np.nan
            )
            rows.append(
                {
                    "policy": policy,
                    "density": float(density),
                    "seeds": x.size,
                    "mean": x.mean(),
                    "lo": x.mean() - half,
                    "hi": x.mean() + half,
                    "paper": paper.get(float(density), np.nan),
                }
            )
    columns = ["policy", "density", "seeds", "mean", "lo", "hi", "paper"]
    return pd.DataFrame(rows, columns=columns)


def scores_by_policy(scores: pd.DataFrame, policies: list[str]) -> dict[str, np.ndarray]:
    """Policy -> ``scores_S`` of its *contiguous* seeds 0, 1, ... (a gap ends the run)."""
    out = {}
    for policy in policies:
        mine = scores[scores["policy"] == policy].set_index("seed")["score"]
        n = 0
        while n in mine.index:
            n += 1
        out[policy] = mine.reindex(range(n)).to_numpy(dtype=float)
    return out


@dataclasses.dataclass(frozen=True)
class ComparisonLook:
    """One comparison at one look."""

    name: str
    family: str
    a: str
    b: str
    n_a: int
    n_b: int
    """Seeds of each row used at this look."""
    diff: float
    """mean(a) − mean(b) over those seeds."""
    lo: float
    hi: float
    """Welch 95 % interval of the difference (descriptive: not adjusted for the looks)."""
    hi_family: float
    """One-sided Welch upper bound at α / m (m: the family's comparisons), which decides
    "paper's effect ruled out" for a comparison AdaStop left undecided at the last look."""
    decision: str
    """AdaStop's decision after this look (:data:`DECISIONS`)."""
    decided_at: int | None
    """The look (1-based) at which it was decided; None while open."""


@dataclasses.dataclass(frozen=True)
class Look:
    """One interim analysis."""

    k: int
    """Look number, 1-based."""
    seeds_per_row: dict[str, int]
    """Seeds each row had in play at this look."""
    comparisons: tuple[ComparisonLook, ...]
    level_spent: dict[str, float]
    """Family -> α spent so far (AdaStop's linear spending: at most α k / K)."""
    needed: dict[str, float]
    """Family -> the |mean difference| (endpoint units) a comparison left open at this look
    had to exceed to be decided here: AdaStop's boundary over the k blocks, divided by k.
    ``inf`` when the look had too few splits to reject anything; absent once the family
    was finished at an earlier look."""


@dataclasses.dataclass(frozen=True)
class Replay:
    """The experiment as far as its committed cells go."""

    looks: tuple[Look, ...]
    """Looks taken, in order."""
    decisions: dict[str, str]
    """Comparison name -> decision after the last look taken."""
    finished: bool
    """Every comparison decided (or the last look taken)."""
    open_rows: tuple[str, ...]
    """Rows that still need seeds (in an open comparison)."""
    next_look: int | None
    """The next look (1-based) that needs cells; None when finished."""


def two_sided_comparator() -> type:
    """``adastop.MultipleAgentsComparator`` with its permutation distribution made two-sided.

    adastop 0.1.3 (and its repository's head, checked 2026-11-25) compares the statistic
    ``max |mean_a - mean_b|`` with the permutation distribution of the *signed* max
    ``max (mean_a - mean_b)``. For one comparison that distribution is symmetric, so the
    boundary sits at its 1 - α quantile where the two-sided test needs 1 - α / 2: every
    look rejects at about twice its level (the headline design's families: 11 % / 12 % of
    400 null data sets at α 0.05, 4.5 % / 4.75 % corrected). Here the distribution the
    boundary is read from is the max of the absolute differences, as in the AdaStop paper;
    the signed sums the later looks add to are kept (docs/statistics.md, "Sequential
    experiments").
    """
    try:
        from adastop import MultipleAgentsComparator
    except ModuleNotFoundError:
        raise PriqnError(
            "the sequential design needs the adastop package: pip install adastop==0.1.3"
        ) from None

    class TwoSidedComparator(MultipleAgentsComparator):
        def compute_mean_diffs(self, k: int, Z: list) -> dict[str, np.ndarray]:  # noqa: N803
            signed = super().compute_mean_diffs(k, Z)  # kept in self.mean_diffs
            return {comp: np.abs(np.asarray(d)) for comp, d in signed.items()}

    return TwoSidedComparator


def _family_comparator(seq: Any, comparisons: list[Any]) -> tuple[Any, list[str]]:
    """A fresh (two-sided) AdaStop comparator of one family and its agent order."""
    MultipleAgentsComparator = two_sided_comparator()  # noqa: N806 - a class
    agents: list[str] = []
    for c in comparisons:
        for row in (c.a, c.b):
            if row not in agents:
                agents.append(row)
    pairs = np.array([(agents.index(c.a), agents.index(c.b)) for c in comparisons])
    comparator = MultipleAgentsComparator(
        n=seq.seeds_per_look,
        K=len(seq.interims),
        B=seq.permutations,
        comparisons=pairs,
        alpha=seq.alpha,
        beta=seq.beta,
        seed=seq.seed,
    )
    return comparator, agents


def replay(exp: Any, scores: pd.DataFrame) -> Replay:
    """AdaStop, look by look, on the committed scores (see the module docstring)."""
    import contextlib
    import io

    seq = exp.sequential
    n, K = seq.seeds_per_look, len(seq.interims)
    policies = [p.name for p in exp.policies]
    by_policy = scores_by_policy(scores, policies)
    families = seq.families()
    state = {f: _family_comparator(seq, cs) for f, cs in families.items()}
    decisions = {c.name: "continue" for c in seq.comparisons}
    decided_at: dict[str, int] = {}
    looks: list[Look] = []
    for k in range(K):
        open_rows = {
            r for c in seq.comparisons if decisions[c.name] == "continue" for r in (c.a, c.b)
        }
        if not open_rows or any(len(by_policy[r]) < (k + 1) * n for r in open_rows):
            break
        level: dict[str, float] = {}
        needed: dict[str, float] = {}
        for family, comps in families.items():
            comparator, agents = state[family]
            if comparator.is_finished:
                level[family] = float(comparator.level_spent)
                continue
            values = {
                a: by_policy[a][: (k + 1) * n]
                if a in open_rows
                else by_policy[a][: min(len(by_policy[a]), (k + 1) * n)]
                for a in agents
            }
            with contextlib.redirect_stdout(io.StringIO()):  # adastop prints "Step k"
                comparator.partial_compare(values, verbose=False)
            for c, pair in zip(comps, comparator.comparisons, strict=True):
                word = comparator.decisions[str(pair)]
                if word != "continue" and decisions[c.name] == "continue":
                    decided_at[c.name] = k + 1
                decisions[c.name] = word
            level[family] = float(comparator.level_spent)
            needed[family] = float(comparator.boundary[-1][1]) / (k + 1)
        seeds_now = {r: min(len(by_policy[r]), (k + 1) * n) for r in policies}
        looks.append(
            Look(
                k + 1,
                seeds_now,
                _look_rows(seq, by_policy, seeds_now, decisions, decided_at),
                level,
                needed,
            )
        )
    open_rows = tuple(
        r
        for r in policies
        if any(decisions[c.name] == "continue" and r in (c.a, c.b) for c in seq.comparisons)
    )
    finished = not open_rows
    return Replay(
        tuple(looks),
        dict(decisions),
        finished,
        open_rows,
        None if finished else len(looks) + 1,
    )


def _look_rows(
    seq: Any,
    by_policy: dict[str, np.ndarray],
    seeds_now: dict[str, int],
    decisions: dict[str, str],
    decided_at: dict[str, int],
) -> tuple[ComparisonLook, ...]:
    out = []
    for c in seq.comparisons:
        a, b = by_policy[c.a][: seeds_now[c.a]], by_policy[c.b][: seeds_now[c.b]]
        lo, hi = inference.welch_interval(a, b)
        m = sum(x.family == c.family for x in seq.comparisons)
        out.append(
            ComparisonLook(
                c.name,
                c.family,
                c.a,
                c.b,
                a.size,
                b.size,
                float(a.mean() - b.mean()),
                lo,
                hi,
                inference.upper_bound(a, b, seq.alpha / m),
                decisions[c.name],
                decided_at.get(c.name),
            )
        )
    return tuple(out)


def next_cells(exp: Any, result: Replay, scores: pd.DataFrame) -> list[tuple[str, int]]:
    """(policy, seed) cells the next look needs that are not among ``scores`` (the complete
    cells, :func:`collect_scores`, which ``result`` was replayed from), in seed order."""
    if result.next_look is None:
        return []
    seq = exp.sequential
    upto = result.next_look * seq.seeds_per_look
    done = {(p, s) for p, s in scores[["policy", "seed"]].itertuples(index=False)}
    return [
        (row, seed) for seed in range(upto) for row in result.open_rows if (row, seed) not in done
    ]


def verdict(exp: Any, result: Replay, comparison: Any) -> str:
    """The pre-registered verdict word of one comparison (headline.toml, "verdicts")."""
    decision = result.decisions[comparison.name]
    look = result.looks[-1] if result.looks else None
    n = (
        0
        if look is None
        else min(look.seeds_per_row[comparison.a], look.seeds_per_row[comparison.b])
    )
    paper = comparison.paper_difference
    if decision == "larger":
        return "reproduced" if paper is not None else "a better"
    if decision == "smaller":
        return "contradicted" if paper is not None else "a worse"
    if decision == "continue":
        return f"open: look {result.next_look} pending"
    # "equal": not decided by the last look taken.
    if paper is not None and look is not None:
        row = next(x for x in look.comparisons if x.name == comparison.name)
        if row.hi_family < paper - inference.TIE_TOLERANCE:
            return "paper's effect ruled out"
        return f"inconclusive at {n} seeds"
    return f"no difference found at {n} seeds" if paper is None else f"inconclusive at {n} seeds"


# --------------------------------------------------------------------------- the report


def looks_frame(result: Replay) -> pd.DataFrame:
    """One row per (look, comparison): ``tables/looks.csv``."""
    rows = [
        {
            "look": look.k,
            **dataclasses.asdict(c),
            "level_spent": look.level_spent[c.family],
            "needed": look.needed.get(c.family, np.nan),
        }
        for look in result.looks
        for c in look.comparisons
    ]
    fields = [f.name for f in dataclasses.fields(ComparisonLook)]
    columns = ["look", *fields, "level_spent", "needed"]
    return pd.DataFrame(rows, columns=columns).astype({"decided_at": "Int64"})


def figure(exp: Any, scores: pd.DataFrame) -> Any:
    """Per-seed endpoint of every row (dots: filled = this experiment's cells, open = the
    prior grid's), the row mean (bar) with its 95 % t interval, and where Pr-IQN* would
    sit if the paper's difference to each baseline held (diamonds on the compared row)."""
    from scipy import stats

    from priqn.analysis.figures import legend_above, plt

    seq = exp.sequential
    policies = [p.name for p in exp.policies]
    fig, ax = plt.subplots(figsize=(7.5, 0.55 * len(policies) + 1.6))
    means = {}
    for i, policy in enumerate(policies):
        mine = scores[scores["policy"] == policy]
        x = mine["score"].to_numpy(float)
        prior = mine["seed"].isin(seq.prior_seeds).to_numpy()
        ax.plot(x[~prior], np.full((~prior).sum(), i), "o", color="tab:blue", ms=5, alpha=0.8)
        ax.plot(x[prior], np.full(prior.sum(), i), "o", mfc="none", mec="tab:blue", ms=5)
        if len(x):
            means[policy] = float(x.mean())
            ax.plot([x.mean()] * 2, [i - 0.3, i + 0.3], color="black", lw=1.8)
        if len(x) >= 2:
            half = stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x))
            ax.plot([x.mean() - half, x.mean() + half], [i + 0.32] * 2, color="black", lw=0.9)
    diamonds = sorted(
        (means[c.b] + c.paper_difference, policies.index(c.a), c.b)
        for c in seq.comparisons
        if c.paper_difference is not None and c.b in means
    )
    for x, row, baseline in diamonds:
        ax.plot(x, row - 0.38, "D", mfc="none", mec="tab:red", ms=6)
        # A row's leftmost label sits to its left, the others to their right: no overlap.
        first = min(d[0] for d in diamonds if d[1] == row) == x
        ax.annotate(
            f"vs {baseline}",
            (x, row - 0.38),
            xytext=(-6, 0) if first else (6, 0),
            textcoords="offset points",
            ha="right" if first else "left",
            va="center",
            fontsize=6,
            color="tab:red",
        )
    counts = scores.groupby("policy")["seed"].nunique()
    ax.set_yticks(
        range(len(policies)), [f"{p} ({int(counts.get(p, 0))} seeds)" for p in policies], fontsize=8
    )
    ax.set_ylim(len(policies) - 0.5, -0.7)
    ax.set_xlim(0, 1)
    ax.grid(axis="x", color="0.9")
    ax.set_xlabel("hold-out success rate, mean over densities (one dot per training seed)")
    handles = [
        plt.Line2D([], [], ls="", marker="o", color="tab:blue", label="seed (this experiment)"),
        plt.Line2D(
            [], [], ls="", marker="o", mfc="none", mec="tab:blue", label="seed (prior grid)"
        ),
        plt.Line2D([], [], color="black", lw=1.8, label="mean; thin: 95 % t interval"),
        plt.Line2D(
            [],
            [],
            ls="",
            marker="D",
            mfc="none",
            mec="tab:red",
            label="where a would be at the paper's difference",
        ),
    ]
    legend_above(ax, handles, f"{exp.experiment.name}: per-seed success of each row", ncol=2)
    return fig


def looks_figure(exp: Any, result: Replay) -> Any:
    """The monitoring chart: one panel per comparison, its estimate at each look taken (dot,
    Welch 95 % interval) inside the band AdaStop would not decide at that look (grey, ±the
    look's ``needed``), with 0 and the paper's difference marked. A dot outside its band is
    a decision; the looks still to come are empty slots. None before the first look."""
    from priqn.analysis.figures import plt

    if not result.looks:
        return None
    seq = exp.sequential
    comps = seq.comparisons
    ncols = min(2, len(comps))
    nrows = -(-len(comps) // ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(3.9 * ncols, 2.5 * nrows + 0.6), sharey=True, squeeze=False
    )
    K = len(seq.interims)
    for ax, c in zip(axes.flat, comps, strict=False):
        ax.axhline(0, color="0.6", lw=0.8)
        if c.paper_difference is not None:
            ax.axhline(100 * c.paper_difference, color="tab:red", ls="--", lw=1)
        for look in result.looks:
            row = next(x for x in look.comparisons if x.name == c.name)
            needed = look.needed.get(c.family)
            if needed is not None and row.decided_at in (None, look.k):
                if np.isfinite(needed):
                    ax.fill_between(
                        [look.k - 0.3, look.k + 0.3],
                        -100 * needed,
                        100 * needed,
                        color="0.88",
                        lw=0,
                        zorder=0,
                    )
                else:  # too few splits to reject anything: the whole column
                    ax.axvspan(look.k - 0.3, look.k + 0.3, color="0.88", lw=0, zorder=0)
            decided = row.decided_at is not None and row.decided_at <= look.k
            ax.errorbar(
                look.k,
                100 * row.diff,
                yerr=[[100 * (row.diff - row.lo)], [100 * (row.hi - row.diff)]],
                fmt="o",
                color="tab:orange" if decided else "black",
                ms=4,
                lw=1,
                capsize=2,
            )
        ax.set_xticks(range(1, K + 1), [f"{n}" for n in seq.interims], fontsize=8)
        ax.set_xlim(0.4, K + 0.6)
        ax.set_xlabel("seeds per row at the look", fontsize=8)
        ax.set_title(f"{c.name}: {verdict(exp, result, c)}", fontsize=8)
        ax.tick_params(axis="y", labelsize=8)
    for ax in axes.flat[len(comps) :]:
        ax.set_visible(False)
    for ax in axes[:, 0]:
        ax.set_ylabel("difference, points", fontsize=8)
    handles = [
        plt.Line2D([], [], color="black", marker="o", ms=4, lw=1, label="estimate, 95 % Welch"),
        plt.Line2D([], [], color="tab:orange", marker="o", ms=4, lw=1, label="decided"),
        plt.Rectangle((0, 0), 1, 1, color="0.88", label="not decided at that look"),
        plt.Line2D([], [], color="tab:red", ls="--", lw=1, label="paper's difference"),
    ]
    top = 1 - 0.45 / fig.get_figheight()  # room for the title and the legend's row
    fig.suptitle(f"{exp.experiment.name}: each comparison look by look", y=0.995, fontsize=10)
    fig.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, 1 - 0.3 / fig.get_figheight()),
        ncol=4,
        fontsize=7,
        frameon=False,
    )
    fig.tight_layout(rect=(0, 0, 1, top))
    return fig


def _needed(x: float) -> str:
    """A look's boundary in points, or why the look could not reject."""
    return "none possible (too few splits)" if not np.isfinite(x) else f"{100 * x:.1f} points"


def _pts(x: float) -> str:
    return f"{100 * x:+.1f}"


def _density_lines(frame: pd.DataFrame, steps: int | None) -> list[str]:
    """The report's per-density section (descriptive) from :func:`density_frame`; ``steps``:
    the cells' training decisions (the paper's values come from the paper preset's)."""
    if frame.empty:
        return []
    densities = sorted(frame["density"].unique())
    lines = [
        "## Per density (descriptive)",
        "",
        "Hold-out success by traffic density, mean [95 % t interval] over each row's "
        "committed seeds, with the paper's Table II value where the row is one of its rows "
        f"(trained for {PAPER_TRAINING_DECISIONS:,} decisions; these cells for "
        f"{f'{steps:,}' if steps else 'their preset'}). The decisions above use the mean over "
        "densities only.",
        "",
        "| row | seeds | " + " | ".join(f"density {d:g}" for d in densities) + " |",
        "|:--|--:|" + "|".join(":--" for _ in densities) + "|",
    ]
    for policy, rows in frame.groupby("policy", sort=False):
        cells = []
        for r in rows.sort_values("density").itertuples():
            text = f"{r.mean:.3f} [{r.lo:.3f}, {r.hi:.3f}]"
            if np.isfinite(r.paper):
                text += f" (paper {r.paper:.3f})"
            cells.append(text)
        lines.append(f"| {policy} | {int(rows['seeds'].iloc[0])} | " + " | ".join(cells) + " |")
    return [*lines, ""]


def report_markdown(exp: Any, scores: pd.DataFrame, result: Replay, command: str) -> str:
    """``report.md`` of a sequential experiment."""
    seq, e = exp.sequential, exp.experiment
    policies = [p.name for p in exp.policies]
    counts = scores.groupby("policy")["seed"].nunique()
    last = result.looks[-1] if result.looks else None
    lines = [
        f"# {e.name}: pre-registered sequential experiment",
        "",
        f"Made by `{command}` from the cells' run folders and the design in `{exp.path.name}` "
        "(committed before any of its own cells trained).",
        "",
        f"- **Question**: {e.description}",
        f"- **Endpoint**: per training seed, hold-out success rate averaged over the densities "
        f"{exp.evaluate.get('densities')}.",
        f"- **Method**: {seq.method} with a two-sided boundary (docs/statistics.md), looks at "
        f"{list(seq.interims)} seeds per row (n = {seq.seeds_per_look} new seeds a look), "
        f"α = {seq.alpha:g} per family (spent linearly over the looks), β = {seq.beta:g}, "
        f"{seq.permutations} permutations, seed {seq.seed}.",
        f"- **Seeds**: {list(seq.prior_seeds)} from `{seq.prior_runs}`, the rest from "
        f"`{_relative(exp.runs_dir)}`; code commits allowed: "
        f"{', '.join(c[:12] for c in seq.code_commits) or 'any'}.",
        f"- **Budget**: {e.steps} decisions per cell ({e.preset} preset); every verdict holds "
        "at this budget only.",
        "",
        "## Verdicts so far",
        "",
        "| comparison | family | paper | estimate [95% CI], points | seeds | AdaStop | verdict |",
        "|:--|:--|--:|:--|:--|:--|:--|",
    ]
    for c in seq.comparisons:
        row = None if last is None else next(x for x in last.comparisons if x.name == c.name)
        paper = "–" if c.paper_difference is None else _pts(c.paper_difference)
        if row is None:
            est, seeds = "no look yet", f"{int(counts.get(c.a, 0))} vs {int(counts.get(c.b, 0))}"
        else:
            est = f"{_pts(row.diff)} [{_pts(row.lo)}, {_pts(row.hi)}]"
            seeds = f"{row.n_a} vs {row.n_b}"
        decided = result.decisions[c.name]
        if row is not None and row.decided_at:
            decided += f" (look {row.decided_at})"
        lines.append(
            f"| {c.name} | {c.family} | {paper} | {est} | {seeds} | {decided} | "
            f"**{verdict(exp, result, c)}** |"
        )
    lines += [
        "",
        "Intervals are Welch t 95 % over training seeds, descriptive (not adjusted for the "
        "looks); the decisions are AdaStop's, which control each family's error over all "
        "looks. *paper's effect ruled out* needs a comparison left undecided at the last look "
        "and a one-sided Welch bound at α / m below the paper's difference.",
        "",
        "![per-seed success](figures/headline.png) ([pdf](figures/headline.pdf))",
        "",
        "## Looks",
        "",
    ]
    if result.looks:
        lines += [
            "Each comparison look by look: a dot outside its look's grey band is decided "
            "there (the band is ± the |difference| it needed).",
            "",
            "![each comparison look by look](figures/looks.png) ([pdf](figures/looks.pdf))",
            "",
        ]
    if not result.looks:
        lines += [
            f"No look yet: the first needs {seq.interims[0]} seeds of every row "
            f"({', '.join(f'{p}: {int(counts.get(p, 0))}' for p in policies)}).",
            "",
        ]
    for look in result.looks:
        spent = ", ".join(f"{f} {v:.4f}" for f, v in look.level_spent.items())
        needed = ", ".join(f"{f} {_needed(v)}" for f, v in look.needed.items())
        lines += [
            f"**Look {look.k}** — seeds per row: "
            + ", ".join(f"{p} {n}" for p, n in look.seeds_per_row.items())
            + f"; α spent: {spent}"
            + (
                f"; |difference| an open comparison needed to be decided: {needed}."
                if needed
                else "."
            ),
            "",
            "| comparison | estimate [95% CI], points | decision |",
            "|:--|:--|:--|",
            *[
                f"| {c.name} | {_pts(c.diff)} [{_pts(c.lo)}, {_pts(c.hi)}] | {c.decision} |"
                for c in look.comparisons
            ],
            "",
        ]
    lines += _density_lines(density_frame(exp, scores), e.steps)
    nxt = next_cells(exp, result, scores)
    lines += [
        "## Next",
        "",
        "The design is finished: every comparison is decided or the last look is taken."
        if result.finished
        else f"Look {result.next_look} needs {len(nxt)} more cell(s): "
        + ", ".join(cell_dir_name(p, s) for p, s in nxt)
        + f" (`priqn sweep {e.name} --code <frozen worktree>`).",
        "",
        "## Cells",
        "",
        "| row | seed | success (endpoint) | episodes | commit | run folder |",
        "|:--|--:|--:|--:|:--|:--|",
        *[
            f"| {r.policy} | {r.seed} | {r.score:.3f} | {r.episodes} | `{r.git_sha[:12]}` | "
            f"`{r.run_dir}` |"
            for r in scores.sort_values(["policy", "seed"], kind="mergesort").itertuples()
        ],
        "",
        "Files: `tables/scores.csv`, `tables/looks.csv`, `tables/density.csv`, "
        "`figures/headline.{png,pdf}`, "
        "`figures/looks.{png,pdf}` (from the first look on), `meta.json`.",
        "",
    ]
    return "\n".join(lines)


def write_report(exp: Any, out_dir: str | Path, command: str | None = None) -> Path:
    """Write the sequential experiment's report into ``out_dir``; returns ``report.md``.

    Deterministic: the same committed cells give byte-identical files."""
    from priqn.analysis.figures import save_figure
    from priqn.io import atomic_write_json, atomic_write_text

    out = Path(out_dir)
    scores = collect_scores(exp)
    result = replay(exp, scores)
    command = command or f"priqn report {_relative(exp.runs_dir)} --out {_relative(out)}"
    csv_kw: dict[str, Any] = {"index": False, "float_format": "%.10g", "lineterminator": "\n"}
    atomic_write_text(out / "tables" / "scores.csv", scores.to_csv(**csv_kw))
    atomic_write_text(out / "tables" / "looks.csv", looks_frame(result).to_csv(**csv_kw))
    atomic_write_text(out / "tables" / "density.csv", density_frame(exp, scores).to_csv(**csv_kw))
    save_figure(figure(exp, scores), out / "figures", "headline")
    monitoring = looks_figure(exp, result)
    if monitoring is not None:
        save_figure(monitoring, out / "figures", "looks")
    report = out / "report.md"
    atomic_write_text(report, report_markdown(exp, scores, result, command))
    atomic_write_json(
        out / "meta.json",
        {
            "command": command,
            "experiment": exp.path.name,
            "looks": len(result.looks),
            "decisions": result.decisions,
            "verdicts": {c.name: verdict(exp, result, c) for c in exp.sequential.comparisons},
            "finished": result.finished,
            "cells": len(scores),
        },
    )
    return report
