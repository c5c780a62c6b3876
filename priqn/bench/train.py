"""``priqn bench train``: learner updates/s (IQN vs Pr-IQN) and env decisions/s with learning.

Part 1 times ``Learner.update`` on synthetic batch-32 transitions with each preset's
observation size and network, for every agent asked for, and prints each agent's cost
per update as a ratio to IQN's (the issue's target: Pr-IQN ≤ 1.5× IQN). Part 2 runs the
real training loop (vector env workers + learning) for a short budget in a temporary
run folder and reports env decisions/s and updates/s end to end.

``--compile graphs,on`` times every agent once eager (``learner.compile = "off"``) and
once per named setting (``graphs``: CUDA graphs of the eager kernels; ``on``:
torch.compile), taking turns in the same rounds on the same device, and prints each /
eager; ``learner.compile = "auto"`` follows what this measured
(docs/implementation-details.md §12).

``--replay-storage device,pinned`` times, for every preset and agent, replay sampling
alone and sample → update from a full buffer in each ``replay.storage`` against ``host``
(:mod:`priqn.bench.feed`), and prints each / host.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import tempfile
import time
from pathlib import Path
from typing import Any, NamedTuple

from priqn.bench.learners import make_learner


def configure_parser(parser: argparse.ArgumentParser) -> None:
    """Part 1 (the learner's update, replay feeding) and part 2 (the end-to-end loop)."""
    parser.add_argument(
        "--presets", default="default,paper", help="comma-separated training presets (default both)"
    )
    parser.add_argument(
        "--agents", default="iqn,pr-iqn", help="comma-separated agents (first is the baseline)"
    )
    parser.add_argument("--batch-size", type=int, default=32, help="transitions per update")
    parser.add_argument(
        "--seconds",
        type=float,
        default=6.0,
        help="timing per case [s], split in 3 alternating rounds",
    )
    parser.add_argument("--device", default="auto", help="auto | cpu | cuda")
    parser.add_argument(
        "--threads", type=int, default=1, help="torch CPU threads (training's default is 1)"
    )
    parser.add_argument(
        "--replay-storage",
        default="",
        metavar="STORAGES",
        help="also time replay sampling and sample -> update from a full buffer with these "
        "replay.storage settings, comma-separated (device, pinned), against host",
    )
    parser.add_argument(
        "--replay-capacity",
        type=int,
        default=0,
        help="transitions in the buffer of --replay-storage (default: the preset's "
        "replay.capacity)",
    )
    parser.add_argument(
        "--bf16",
        action="store_true",
        help="also time every agent with learner.autocast_bf16 on (part 1)",
    )
    parser.add_argument(
        "--compile",
        nargs="?",
        const="on",
        default="",
        metavar="SETTINGS",
        help="also time every agent with these learner.compile settings, comma-separated "
        "(graphs, on; bare --compile: on), beside eager (part 1)",
    )
    parser.add_argument(
        "--cuda-nondeterministic",
        action="store_true",
        help="on CUDA, also time every case with cuda_deterministic off, beside training's "
        "deterministic kernels (part 1)",
    )
    parser.add_argument(
        "--read-stats",
        action="store_true",
        help="also time every case reading its statistics after every update (a host sync "
        "per update, the learner before issue 61), beside reading them at log time (part 1)",
    )
    _loop_options(parser)


def _loop_options(parser: argparse.ArgumentParser) -> None:
    """Part 2's flags: the end-to-end training loop."""
    parser.add_argument(
        "--loop-steps",
        type=int,
        default=3000,
        help="env decisions of the end-to-end loop (0 skips part 2)",
    )
    parser.add_argument("--net", default="tjunction", help="training pool of the end-to-end loop")
    parser.add_argument(
        "--loop-preset", default="default", help="training preset of the end-to-end loop"
    )
    parser.add_argument(
        "--loop-envs",
        type=int,
        default=0,
        metavar="N",
        help="env workers of the end-to-end loop (default: the preset's num_envs)",
    )
    parser.add_argument(
        "--env-groups",
        type=int,
        default=0,
        metavar="G",
        help="also run the end-to-end loop with its workers in G groups stepping in turn "
        "(env_groups), beside the same loop with all at once",
    )
    parser.add_argument(
        "--loop-compile",
        choices=("auto", "graphs", "on", "off"),
        default="auto",
        help="learner.compile of the end-to-end loop and the replay feed (default auto, as "
        "training; the loop's wall time includes the compiling)",
    )


class Case(NamedTuple):
    """One timed case of :func:`updates_per_second`: an agent and its switches."""

    agent: str
    bf16: bool
    """``learner.autocast_bf16``."""
    compile: str
    """``learner.compile``: ``off`` (eager, the baseline), ``graphs`` or ``on``."""
    deterministic: bool
    """Training's deterministic CUDA kernels (``cuda_deterministic``); False on the CPU."""
    read_each: bool = False
    """Read every update's statistics right away (a host sync per update, as the learner
    did before issue 61); False: never read, as the loop reads only the logged ones."""


def _time_updates(
    learner: Any, batches: list[Any], seconds: float, read_each: bool = False
) -> float:
    import torch

    cuda = learner.device.type == "cuda"
    if cuda:
        torch.cuda.synchronize()
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds or n < 5:
        stats = learner.update(batches[n % 4])
        if read_each:
            dict(stats)
        n += 1
    if cuda:
        torch.cuda.synchronize()
    return n / (time.perf_counter() - t0)


def updates_per_second(
    preset: str,
    agents: list[str],
    batch_size: int,
    seconds: float,
    device: str,
    rounds: int = 3,
    bf16: bool = False,
    compile_settings: tuple[str, ...] = (),
    nondeterministic: bool = False,
    read_stats: bool = False,
) -> list[dict[str, Any]]:
    """Time ``Learner.update`` for one preset, every agent, on synthetic transitions.

    The cases take turns for ``rounds`` rounds of ``seconds / rounds`` each and the best
    round counts, so load from other processes hits all cases alike. ``bf16`` adds each
    agent once more with ``learner.autocast_bf16`` on, right after its float32 case;
    ``compile_settings`` adds each of those once more per ``learner.compile`` setting named
    (the others run with ``"off"``: eager whatever the device). On CUDA every case runs with training's
    deterministic kernels (``cuda_deterministic``), and ``nondeterministic`` adds each once
    more without them. ``read_stats`` adds each once more reading its statistics after
    every update (the host sync per update the learner had before issue 61).
    """
    from priqn.run.train_config import cuda_determinism, select_device

    cuda = select_device(device).type == "cuda"
    cases = [
        Case(a, b, c, d, r)
        for a in agents
        for b in ((False, True) if bf16 else (False,))
        for c in ("off", *compile_settings)
        for d in ((True, False) if nondeterministic and cuda else (cuda,))
        for r in ((False, True) if read_stats else (False,))
    ]
    if cuda:
        cuda_determinism(True)  # before the first CUDA matrix product (cuBLAS's workspace)
    made = {c: make_learner(preset, c.agent, batch_size, device, c.bf16, c.compile) for c in cases}
    best = dict.fromkeys(cases, 0.0)
    for _ in range(rounds):
        for c in cases:
            learner, (_, batches) = made[c]
            if cuda:
                cuda_determinism(c.deterministic)
            best[c] = max(best[c], _time_updates(learner, batches, seconds / rounds, c.read_each))
    if cuda:
        cuda_determinism(True)
    out = []
    for c in cases:
        learner, (cfg, _) = made[c]
        out.append(
            {
                "preset": preset,
                **c._asdict(),
                "obs_px": cfg.env.obs_size_px,
                "device": str(learner.device),
                "updates_per_s": best[c],
                "ms_per_update": 1000.0 / best[c],
            }
        )
    return out


class Loop(NamedTuple):
    """What every end-to-end loop of one :func:`print_loop` shares."""

    net: str
    """Training pool (``--net``)."""
    steps: int
    """Env decisions of each loop."""
    device: str
    """Torch device (auto | cpu | cuda)."""
    compile: str
    """``learner.compile`` (compiling happens inside the timed loop)."""
    preset: str = "default"
    """Training preset."""
    num_envs: int = 0
    """Env workers (0: the preset's)."""


def loop_throughput(
    loop: Loop,
    agent_name: str,
    learning: bool = True,
    overlap: bool = True,
    env_groups: int = 1,
) -> dict[str, Any]:
    """Env decisions/s and updates/s of the real training loop.

    ``learning=False`` runs the same loop (same workers, acting rule, replay) with no
    update at all: the env-only throughput the end-to-end figure is compared with.
    ``overlap=False`` is the serial loop (update after the env step), the baseline.
    ``env_groups`` > 1: the workers in groups that step in turn (the pipelined loop).
    """
    from priqn.run.folder import RunFolder
    from priqn.run.train_config import resolve_config
    from priqn.train import train

    steps = loop.steps
    starts = min(500, steps // 4) if learning else steps + 1
    cfg = resolve_config(
        preset=loop.preset,
        agent=agent_name,
        net=loop.net,
        steps=steps,
        device=loop.device,
        num_envs=loop.num_envs or None,
        values=[
            ("replay.learning_starts", starts),
            ("evaluation.interval_steps", 0),
            ("checkpoint.interval_steps", 10 * steps),
            ("checkpoint.save_replay", False),
            ("overlap_updates", overlap),
            ("learner.compile", loop.compile),
            ("env_groups", env_groups),
        ],
    )
    with tempfile.TemporaryDirectory(prefix="priqn-bench-") as tmp:
        with contextlib.redirect_stdout(io.StringIO()):  # the loop's progress lines
            run_dir = train(cfg, Path(tmp) / "run")
        meta = RunFolder(run_dir).meta()
    wall = float(meta["wall_s"])
    return {
        "agent": agent_name,
        "decisions_per_s": meta["steps_done"] / wall,
        "updates_per_s": meta["updates_done"] / wall,
        "wall_s": wall,
        "num_envs": cfg.num_envs,
        "obs_px": cfg.env.obs_size_px,
        "time_s": meta.get("time_s", {}),
    }


TIME_SECTIONS: tuple[tuple[str, str], ...] = (
    ("env_wait", "waiting for the env workers (step_wait)"),
    ("env_issue", "sending actions (step_async)"),
    ("act", "acting: network forward + acting rule"),
    ("update", "learner updates"),
    ("algorithm1", "  of act + update: Algorithm 1 (optimal subsets)"),
    ("replay_sample", "replay: sampling batches"),
    ("replay_add", "replay: storing transitions"),
    ("logging", "episode stats, tqdm, TensorBoard, metrics.csv"),
    ("checkpoint", "checkpoints"),
)
"""Sections of the training loop's clock (meta.json ``time_s``), in print order."""


def print_time_table(results: list[dict[str, Any]]) -> None:
    """Where the wall time of each end-to-end run went, in % of its wall time."""
    head = "".join(f"{r['agent']:>12}" for r in results)
    print(f"\nwhere the time goes (% of wall time, end to end){'':<6}{head}")
    for key, what in TIME_SECTIONS:
        cells = []
        for r in results:
            sec = r["time_s"].get(key)
            cells.append(f"{'-':>12}" if sec is None else f"{100 * sec / r['wall_s']:>11.1f}%")
        print(f"{what:<56}{''.join(cells)}")


def _case_name(r: dict[str, Any]) -> str:
    """``iqn bf16 comp nondet``: the agent and the switches a timed case has on."""
    nondet = r["device"].startswith("cuda") and not r["deterministic"]
    return r["agent"] + "".join(
        f" {word}"
        for word, on in (("bf16", r["bf16"]), (r["compile"], r["compile"] != "off"),
                         ("nondet", nondet), ("read", r.get("read_each", False)))
        if on
    )  # fmt: skip


def twin_ratios(results: list[dict[str, Any]]) -> list[str]:
    """One line per case that has a twin differing in one switch: each compile setting /
    eager, nondeterministic / deterministic kernels (CUDA), and statistics read at log
    time / read every update, in updates/s."""
    by_case = {Case(**{f: r[f] for f in Case._fields if f in r}): r for r in results}
    lines = []
    for case, base in by_case.items():
        twins = [
            (twin, f"{other.compile} / eager")
            for other, twin in by_case.items()
            if case.compile == "off" != other.compile and other._replace(compile="off") == case
        ]
        if case.deterministic:
            label = "nondeterministic / deterministic"
            twins.append((by_case.get(case._replace(deterministic=False)), label))
        if case.read_each:  # the baseline is the old way: read every update
            twins.append(
                (by_case.get(case._replace(read_each=False)), "at log time / every update")
            )
        for twin, label in twins:
            if twin is None:
                continue
            name = _case_name(base)
            ratio = twin["updates_per_s"] / base["updates_per_s"]
            lines.append(
                f"{name}: {label} on {base['device']}: {ratio:.2f}x updates/s "
                f"({base['ms_per_update']:.2f} -> {twin['ms_per_update']:.2f} ms/update)"
            )
    return lines


def run(args: argparse.Namespace) -> int:
    import torch

    if args.threads > 0:
        torch.set_num_threads(args.threads)
    from priqn.agents.frames import check_storage
    from priqn.bench.feed import feed_rates, print_feed
    from priqn.run.train_config import select_device

    presets = [p for p in args.presets.split(",") if p]
    agents = [a for a in args.agents.split(",") if a]
    others = [s for s in args.replay_storage.split(",") if s and s != "host"]
    storages = ("host", *others) if others else ()
    for s in others:  # one line before anything is timed
        check_storage(s, select_device(args.device))
    print(
        f"priqn bench train: Learner.update at batch {args.batch_size}, "
        f"{torch.get_num_threads()} torch threads, {args.seconds:g} s per case, "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at start"
    )
    print(
        f"{'preset':<8} {'px':>4} {'agent':<18} {'updates/s':>10} {'ms/update':>10} {'x ' + agents[0]:>10}"
    )
    for preset in presets:
        results = updates_per_second(
            preset,
            agents,
            args.batch_size,
            args.seconds,
            args.device,
            bf16=args.bf16,
            compile_settings=tuple(c for c in args.compile.split(",") if c),
            nondeterministic=args.cuda_nondeterministic,
            read_stats=args.read_stats,
        )
        base = results[0]["ms_per_update"]
        for r in results:
            name = _case_name(r)
            print(
                f"{preset:<8} {r['obs_px']:>4} {name:<18} {r['updates_per_s']:>10.1f} "
                f"{r['ms_per_update']:>10.2f} {r['ms_per_update'] / base:>10.2f}",
                flush=True,
            )
        for line in twin_ratios(results):
            print(f"{preset:<8} {line}", flush=True)
        if storages:
            print_feed(
                feed_rates(preset, agents, storages, args.batch_size, args.seconds, args.device,
                           args.replay_capacity, args.loop_compile),
                args.batch_size,
            )  # fmt: skip
    if args.loop_steps > 0:
        print_loop(args, agents)
    return 0


def print_loop(args: argparse.Namespace, agents: list[str]) -> None:
    """Part 2: the end-to-end loop of every agent, with its env-only and serial twins
    (and its pipelined twin with ``--env-groups``)."""
    loop = Loop(
        args.net, args.loop_steps, args.device, args.loop_compile, args.loop_preset, args.loop_envs
    )
    groups = args.env_groups if args.env_groups > 1 else 0
    print(
        f"\nend-to-end training loop ({loop.preset} preset, learning on: one update per "
        f"replay.decisions_per_update decisions), {loop.steps} decisions, net {loop.net}, "
        f"learner.compile = {loop.compile}"
    )
    extra = f" {f'{groups} groups dec/s':>16}" if groups else ""
    print(
        f"{'agent':<13} {'envs':>4} {'decisions/s':>12} {'updates/s':>10} "
        f"{'serial dec/s':>13} {'env-only dec/s':>15}{extra}"
    )
    results = []
    for name in agents:
        # Same workers, same acting, no learning: the ceiling the loop is measured against;
        # the serial loop (update after the step) is the baseline of the overlap.
        env_only = loop_throughput(loop, name, learning=False)
        serial = loop_throughput(loop, name, overlap=False)
        r = loop_throughput(loop, name)
        r["env_only"] = env_only["decisions_per_s"]
        r["serial"] = serial["decisions_per_s"]
        if groups:
            r["pipelined"] = loop_throughput(loop, name, env_groups=groups)["decisions_per_s"]
        results.append(r)
        row = f" {r['pipelined']:>16.1f}" if groups else ""
        print(
            f"{name:<13} {r['num_envs']:>4} {r['decisions_per_s']:>12.1f} "
            f"{r['updates_per_s']:>10.1f} {r['serial']:>13.1f} {r['env_only']:>15.1f}{row}",
            flush=True,
        )
    for r in results:
        piped = (
            f"; {groups} groups / all at once: {r['pipelined'] / r['decisions_per_s']:.2f}"
            if groups
            else ""
        )
        print(
            f"{r['agent']}: end-to-end / env-only: {r['decisions_per_s'] / r['env_only']:.2f}"
            f"   (serial loop: {r['serial'] / r['env_only']:.2f}; overlap / serial: "
            f"{r['decisions_per_s'] / r['serial']:.2f}{piped})"
        )
    print_time_table(results)
