"""``priqn bench env``: env decisions/s against the raw libsumo floor, and vector-env scaling.

Every measurement runs in its own subprocess (libsumo allows one simulation per
process, and a fresh process keeps the measurements independent):

1. **env** — one :class:`~priqn.env.intersection.IntersectionEnv` with the default
   observation, at each density: episodes on pinned scenes (net, command, seed) driven
   by a fixed seeded policy (target speed 3/6/9 m/s, no lateral offset), after every
   net of the pool was parsed and every route drawn once (``preload_nets``), as in a
   long training run. Timed: ``step`` (the ratio below), its parts (SUMO stepping,
   planner, sensors, the risk measure), resets, and whole episodes (reset + steps).
2. **floor** — right after each env episode, in the same process, the same scene
   (same seed, so the same net, traffic and obstacles) is reset and stepped with
   ``libsumo.simulationStep`` only: no planner, no ego ``moveToXY``, no collision
   tests, no sensors, as many decisions as the env episode had, each decision =
   ``decision_interval_s / sim_step_s`` SUMO steps. Interleaving episode by episode
   puts env and floor under the same machine load (in separate processes the floor
   alone drifted by ±25 % on a shared machine).
3. **vector** — ``make_vector_env`` with 1 and with 2 workers, total decisions/s.

The sensors are also timed against their first implementation
(:class:`~priqn.bench.references.sensors.ReferenceSensors`) on the same states: every
``observe`` of a step is repeated by the reference, in alternating order (reference
first on every other decision), outside the step's timing, and the two outputs are
compared byte for byte (``sensors ref ms``, ``sensors mismatches``). ``--sensors numpy``
times the sensors' numpy path instead of the compiled one (numba,
:mod:`priqn.env.sensor_kernels`); either way one observation is made before the timing,
so that the loops are compiled or loaded from numba's cache first.

Each density is measured ``--repeats`` times in fresh processes; the table shows the
run with the median ``env/floor`` ratio (the env's cost over SUMO's own).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple

POLICY_ACTIONS_SPEED = (1, 2, 3)
"""Speed indices the benchmark policy draws from (3, 6, 9 m/s on the default grid)."""


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--family", default="all", help="net pool (default: all)")
    parser.add_argument(
        "--densities",
        default="0.5,0.75,1.0",
        help="comma-separated densities (default: 0.5,0.75,1.0)",
    )
    parser.add_argument("--decisions", type=int, default=400, help="decisions per measurement")
    parser.add_argument("--obs-size", type=int, default=128, help="observation size in px")
    parser.add_argument("--vector-decisions", type=int, default=200, help="vector steps per size")
    parser.add_argument("--max-workers", type=int, default=2, help="largest vector env measured")
    parser.add_argument(
        "--repeats", type=int, default=3, help="env and floor measurements per density (medians)"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of scenes and policy")
    parser.add_argument(
        "--traffic",
        default="sumo",
        help="comma-separated named traffic settings (default: sumo); with several, each "
        "density is measured under each, and the table adds each one's env decisions/s as a "
        "ratio to the first's (e.g. --traffic sumo,rude,tm: what path braking costs)",
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")
    parser.add_argument(
        "--vs",
        choices=("highway",),
        default=None,
        help="also measure HighwayEnv intersection-v0 and -v2 in the same command "
        "(pip install 'priqn[bench]'; the ratio is priqn's decisions/s over theirs)",
    )
    parser.add_argument(
        "--no-sensors-ref",
        action="store_true",
        help="do not time the reference sensors beside the fast ones (their runs warm the "
        "caches of the rest of the step; leave them out for a per-part breakdown alone)",
    )
    parser.add_argument(
        "--sensors",
        choices=("compiled", "numpy"),
        default="compiled",
        help="the sensors' path to time: compiled loops (numba, the default where it is "
        "installed) or numpy; both give the same grids",
    )


def run(args: argparse.Namespace) -> int:
    """Entry point of ``priqn bench env``: the flags checked, then the benchmark in the
    order it prints: each density's env against its floor, the vector env's scaling,
    HighwayEnv beside priqn (``--vs highway``); ``--json`` also writes the results."""
    densities = _checked_densities(args)
    from priqn.env.traffic import traffic_names

    traffics = traffic_names(args.traffic)
    base = {"family": args.family, "obs_size_px": args.obs_size, "seed": args.seed}
    env_base = {
        **base,
        "sensors_ref": not args.no_sensors_ref,
        "sensors_compiled": args.sensors == "compiled",
    }
    results: dict[str, Any] = {
        "config": {
            **base,
            "decisions": args.decisions,
            "repeats": args.repeats,
            "sensors": args.sensors,
            "traffic": traffics,
        },
        "density": {},
        "vector": {},
    }
    print(
        f"priqn bench env: family={args.family} obs={args.obs_size}px "
        f"decisions={args.decisions} repeats={args.repeats} sensors={args.sensors} (medians)"
    )
    print(
        f"{'density':>7} {'env dec/s':>9} {'floor dec/s':>11} {'env/floor':>9} "
        f"{'reset ms':>8} {'episode ms':>10} {'dec/s incl. resets':>18} {'risk us/step':>12}"
        "   env step ms = sumo + sensors + planner + risk + rest   sensors: ref ms, new/ref"
    )
    for traffic in traffics:
        if len(traffics) > 1:
            print(f"traffic {traffic}:")
        for d in densities:
            spec = {
                **env_base, "mode": "env", "density": d, "decisions": args.decisions,
                "traffic": traffic,
            }  # fmt: skip
            row = _median_density(spec, args.repeats)
            if traffic == traffics[0]:
                results["density"][str(d)] = row
            results.setdefault("traffic", {}).setdefault(traffic, {})[str(d)] = row
            print(_density_line(d, row))
    if len(traffics) > 1:
        results["traffic_ratio"] = _traffic_ratios(results["traffic"], traffics, densities)
    results["vector"] = _vector_scaling(base, args.max_workers, args.vector_decisions)
    if args.vs == "highway":
        results["highway"] = _versus_highway(results, densities, args)
    if args.json is not None:
        from priqn.io import atomic_write_json

        atomic_write_json(args.json, results)
    return 0


def _traffic_ratios(
    by_traffic: dict[str, dict[str, Any]], traffics: list[str], densities: list[float]
) -> dict[str, dict[str, float]]:
    """Each setting's env decisions/s over the first setting's, per density (printed)."""
    first = traffics[0]
    print(f"\n{'traffic':>10} " + " ".join(f"{'d=' + format(d, 'g'):>9}" for d in densities)
          + f"   (env decisions/s over {first}'s; below 1 = slower)")  # fmt: skip
    out: dict[str, dict[str, float]] = {}
    for traffic in traffics:
        out[traffic] = {
            str(d): by_traffic[traffic][str(d)]["env"]["decisions_per_s"]
            / by_traffic[first][str(d)]["env"]["decisions_per_s"]
            for d in densities
        }
        print(f"{traffic:>10} " + " ".join(f"{out[traffic][str(d)]:>8.2f}x" for d in densities))
    return out


def _checked_densities(args: argparse.Namespace) -> list[float]:
    """``--densities`` parsed, and every flag checked (one line per mistake)."""
    from priqn.errors import PriqnError

    try:
        densities = [float(d) for d in str(args.densities).split(",") if d.strip()]
    except ValueError:
        raise PriqnError(
            f"--densities {args.densities!r}: expected numbers like 0.5,0.75,1.0"
        ) from None
    from priqn.env.traffic import check_density

    for d in densities:
        check_density(d, "--densities")
    if args.decisions < 10 or args.vector_decisions < 10:
        raise PriqnError("--decisions and --vector-decisions: expected >= 10")
    if args.max_workers < 0:
        raise PriqnError("--max-workers: expected >= 0 (0 skips the vector env)")
    if args.repeats < 1:
        raise PriqnError("--repeats: expected >= 1")
    from priqn.env import sensor_kernels

    if args.sensors == "compiled" and not sensor_kernels.AVAILABLE:
        raise PriqnError("--sensors compiled: numba is not installed (pip install numba)")
    return densities


def _median_density(spec: dict[str, Any], repeats: int) -> dict[str, Any]:
    """One density measured ``repeats`` times (env and floor, each in a fresh process):
    the run with the median (low) ``floor/env`` ratio, and every run's rates."""
    runs = [_child(spec) for _ in range(repeats)]
    ratios = [r["floor"]["decisions_per_s"] / r["env"]["decisions_per_s"] for r in runs]
    mid = runs[ratios.index(statistics.median_low(ratios))]
    env, floor = mid["env"], mid["floor"]
    return {
        "env": env,
        "floor": floor,
        "ratio": floor["decisions_per_s"] / env["decisions_per_s"],
        "ratio_runs": ratios,
        "env_runs": [r["env"]["decisions_per_s"] for r in runs],
        "floor_runs": [r["floor"]["decisions_per_s"] for r in runs],
    }


def _density_line(d: float, row: dict[str, Any]) -> str:
    """One density's row of the table: rates, the ratio, resets and episodes, the step's
    parts, the sensors against their reference."""
    env, floor, ratio = row["env"], row["floor"], row["ratio"]
    p, ep = env["parts_ms"], env["episode"]
    return (
        f"{d:>7.2f} {env['decisions_per_s']:>9.1f} {floor['decisions_per_s']:>11.1f} "
        f"{ratio:>8.2f}x {env['reset_ms']:>8.1f} {ep['ms']:>10.1f} "
        f"{ep['decisions_per_s']:>18.1f} {env['risk_us_per_step']:>12.1f}   "
        f"{env['step_ms']:.2f} = {p['sumo_ms']:.2f} + {p['sensors_ms']:.2f} + "
        f"{p['plan_ms']:.2f} + {p['risk_ms']:.2f} + {p['rest_ms']:.2f}   "
        + (
            f"{env['sensors_ref_ms']:.2f}, {p['sensors_ms'] / env['sensors_ref_ms']:.2f} "
            f"(median of pairs {env['sensors_vs_ref']['median_ratio']:.2f})"
            if env["sensors_ref_ms"]
            else "(not timed)"
        )
        + (f"  MISMATCHES {env['sensors_mismatches']}" if env["sensors_mismatches"] else "")
    )


def _vector_scaling(base: dict[str, Any], max_workers: int, decisions: int) -> dict[str, Any]:
    """The vector env with 1 to ``max_workers`` workers (none for 0), each in a fresh
    process: its table printed, ``workers -> measurement`` returned."""
    out: dict[str, Any] = {}
    if max_workers:
        print(f"{'workers':>7} {'dec/s':>9} {'speed-up':>9}")
    one = None
    for n in range(1, max_workers + 1):
        vec = _child({**base, "mode": "vector", "workers": n, "decisions": decisions})
        one = one or vec["decisions_per_s"]
        out[str(n)] = vec
        print(f"{n:>7d} {vec['decisions_per_s']:>9.1f} {vec['decisions_per_s'] / one:>8.2f}x")
    return out


HIGHWAY_ENVS: tuple[str, ...] = ("intersection-v0", "intersection-v2")
"""HighwayEnv's intersection tasks measured by ``--vs highway`` (v2 is its newest)."""


def _versus_highway(
    results: dict[str, Any], densities: list[float], args: argparse.Namespace
) -> dict[str, Any]:
    """HighwayEnv beside priqn: decisions/s (incl. resets) and simulated seconds per second."""
    import importlib.util

    from priqn.errors import PriqnError

    if importlib.util.find_spec("highway_env") is None:
        raise PriqnError(
            "--vs highway: HighwayEnv is not installed; pip install 'priqn[bench]' (highway-env)"
        )
    out: dict[str, Any] = {}
    ours = {d: _with_resets(results["density"][str(d)]["env"]) for d in densities}
    decision_s = 0.5  # priqn's decision interval (EnvConfig.decision_interval_s)
    print(
        f"\n{'env':>24} {'dec/s incl. resets':>18} {'sim s / wall s':>14} "
        + " ".join(f"{'priqn d=' + format(d, 'g'):>11}" for d in densities)
        + "   (ratio: priqn decisions/s over theirs, resets included)"
    )
    for env_id in HIGHWAY_ENVS:
        res = _child(
            {"mode": "highway", "env_id": env_id, "decisions": args.decisions, "seed": args.seed}
        )
        out[env_id] = res
        ratios = " ".join(f"{ours[d] / res['decisions_per_s']:>10.1f}x" for d in densities)
        print(
            f"{env_id:>24} {res['decisions_per_s']:>18.1f} "
            f"{res['decisions_per_s'] * res['decision_s']:>14.1f} {ratios}"
        )
    for d in densities:
        print(
            f"{'priqn density ' + format(d, 'g'):>24} {ours[d]:>18.1f} {ours[d] * decision_s:>14.1f}"
        )
    return out


def _with_resets(env: dict[str, Any]) -> float:
    """priqn's decisions/s with every episode's reset counted (as HighwayEnv's is)."""
    ms = env["decisions"] * env["step_ms"] + len(env["episodes"]) * env["reset_ms"]
    return 1e3 * env["decisions"] / ms


def _measure_highway(spec: dict[str, Any]) -> dict[str, Any]:
    """HighwayEnv ``env_id`` with random actions, resets included (child process)."""
    import gymnasium
    import highway_env  # noqa: F401 - registers the envs

    env = gymnasium.make(spec["env_id"])
    cfg = env.unwrapped.config
    env.reset(seed=spec["seed"])
    env.action_space.seed(spec["seed"])
    done, episodes = 0, 0
    t0 = time.perf_counter()
    while done < spec["decisions"]:
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        done += 1
        if term or trunc:
            episodes += 1
            env.reset()
    wall = time.perf_counter() - t0
    env.close()
    return {
        "decisions": done,
        "episodes": episodes,
        "decisions_per_s": done / wall,
        "decision_s": 1.0 / float(cfg["policy_frequency"]),
        "observation": str(cfg["observation"]["type"]),
    }


def _child(spec: dict[str, Any]) -> dict[str, Any]:
    """Run one measurement in a fresh Python process; its last stdout line is JSON."""
    from priqn.errors import PriqnError

    code = "import json, sys; from priqn.bench.env import measure; print(json.dumps(measure(json.loads(sys.argv[1]))))"
    proc = subprocess.run(
        [sys.executable, "-c", code, json.dumps(spec)], capture_output=True, text=True, timeout=3600
    )
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise PriqnError(f"bench env: the {spec['mode']} measurement failed: {tail}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _scenes(env: Any, seed: int, density: float) -> Any:
    """Endless (seed, options) pairs: the pool's nets in turn, commands drawn per scene."""
    import numpy as np

    rng = np.random.default_rng(seed)
    pool = env.net_pool
    i = 0
    while True:
        yield int(rng.integers(2**31)), {"net": pool[i % len(pool)], "density": density}
        i += 1


def measure(spec: dict[str, Any]) -> dict[str, Any]:
    """One measurement (runs in the child process); see the module docstring."""
    mode = spec["mode"]
    if mode == "highway":
        return _measure_highway(spec)
    from priqn.env.config import EnvConfig
    from priqn.env.intersection import IntersectionEnv

    cfg = EnvConfig(family=spec["family"], obs_size_px=spec["obs_size_px"])
    if spec.get("traffic"):
        from priqn.env.traffic import traffic_setting

        cfg = traffic_setting(spec["traffic"]).apply(cfg)
    if mode == "vector":
        return _measure_vector(cfg, spec)
    env = IntersectionEnv(cfg)
    try:
        env.preload_nets()  # parse every net and draw every route once: resets are timed warm
        if mode == "env":
            return _measure_env(env, spec)
        raise ValueError(f"unknown bench mode {mode!r}")
    finally:
        env.close()


def _measure_env(env: Any, spec: dict[str, Any]) -> dict[str, Any]:
    """The ``env`` measurement (child process): episodes on the pinned scenes until
    ``spec["decisions"]``, each followed by its floor; ``{"env": ..., "floor": ...}``."""
    import numpy as np

    from priqn.env.sensors import Sensors

    policy = np.random.default_rng(spec["seed"] + 1)
    compiled = spec.get("sensors_compiled", True)
    if env._sensors.compiled != compiled:  # the env's own choice is numba where installed
        env._sensors = env._render_sensors = Sensors(env._sensors.cfg, compiled=compiled)
    env.reset(seed=spec["seed"])  # the first observation compiles (or loads) the loops
    parts = _time_parts(env, sensors_ref=spec.get("sensors_ref", True))
    sim_step = parts.pop("simulation_step")  # the unwrapped libsumo step, for the floor
    episodes: list[_TimedScene] = []
    done = 0
    for seed, options in _scenes(env, spec["seed"], spec["density"]):
        ep = _time_episode(env, seed, options, policy, spec["decisions"] - done, sim_step)
        episodes.append(ep)
        done += ep.steps
        if done >= spec["decisions"]:
            break
    floor_s = sum(ep.floor_s for ep in episodes)
    floor = {"decisions": done, "decisions_per_s": done / floor_s, "step_ms": 1e3 * floor_s / done}
    return {"env": _env_result(parts, episodes, done), "floor": floor}


class _TimedScene(NamedTuple):
    """One scene of the ``env`` measurement: the env's episode and its floor."""

    seed: int
    options: dict[str, Any]
    steps: int
    """Decisions taken (up to the budget left)."""
    reset_s: float
    step_s: float
    """Seconds in ``env.step``, the reference sensors' time included."""
    floor_s: float
    """Seconds of the same scene stepped by SUMO alone, as many decisions."""
    ended: bool
    """The episode terminated or was truncated (it is whole)."""


def _time_episode(
    env: Any, seed: int, options: dict[str, Any], policy: Any, budget: int, sim_step: Any
) -> _TimedScene:
    """One scene: reset and step the env with the benchmark policy until the episode ends
    or ``budget`` decisions are taken; then the same scene reset and stepped with
    ``sim_step`` (libsumo alone) for as many decisions."""
    n_off = env.config.n_offsets
    t0 = time.perf_counter()
    env.reset(seed=seed, options=options)
    reset_s = time.perf_counter() - t0
    steps, step_s, ended = 0, 0.0, False
    while steps < budget:
        a = int(policy.choice(POLICY_ACTIONS_SPEED)) * n_off + n_off // 2
        t0 = time.perf_counter()
        _, _, term, trunc, _ = env.step(a)
        step_s += time.perf_counter() - t0
        steps += 1
        if term or trunc:
            ended = True
            break
    env.reset(seed=seed, options=options)  # the floor: the same scene, SUMO alone
    t0 = time.perf_counter()
    for _ in range(steps * env.config.substeps):
        sim_step()
    return _TimedScene(seed, options, steps, reset_s, step_s, time.perf_counter() - t0, ended)


def _env_result(parts: dict[str, Any], episodes: list[_TimedScene], done: int) -> dict[str, Any]:
    """The env's side of the measurement from its episodes and the step's timed
    ``parts`` (:func:`_time_parts`): rates, resets, the step's parts per decision (the
    rest is what no timer covers), the sensors against the reference, whole episodes."""
    import numpy as np

    step_s = sum(ep.step_s for ep in episodes)
    sim_steps = parts.pop("risk_steps")
    ref_s, mismatches = parts.pop("sensors_ref_ms"), parts.pop("sensors_mismatches")
    pairs = np.array(parts.pop("sensors_pairs")).reshape(-1, 2)  # (new, reference) seconds
    step_s -= parts.pop("excluded_s")  # the reference sensors ran inside env.step
    risk_s = parts["risk_ms"]
    parts_ms = {k: 1e3 * v / done for k, v in parts.items()}
    parts_ms["rest_ms"] = 1e3 * step_s / done - sum(parts_ms.values())
    whole = [(ep.steps, ep.reset_s + ep.step_s) for ep in episodes if ep.ended]
    n_whole = max(sum(d for d, _ in whole), 1)
    t_whole = sum(t for _, t in whole)
    return {
        "decisions": done,
        "decisions_per_s": done / step_s,
        "step_ms": 1e3 * step_s / done,
        "reset_ms": 1e3 * sum(ep.reset_s for ep in episodes) / len(episodes),
        "parts_ms": parts_ms,
        "risk_us_per_step": 1e6 * risk_s / max(sim_steps, 1),
        "sensors_ref_ms": 1e3 * ref_s / done,
        "sensors_mismatches": mismatches,
        "sensors_vs_ref": {
            "mean_ratio": float(pairs[:, 0].sum() / pairs[:, 1].sum()) if len(pairs) else 0.0,
            "median_ratio": float(np.median(pairs[:, 0] / pairs[:, 1])) if len(pairs) else 0.0,
            "new_median_ms": float(1e3 * np.median(pairs[:, 0])) if len(pairs) else 0.0,
            "ref_median_ms": float(1e3 * np.median(pairs[:, 1])) if len(pairs) else 0.0,
        },
        "episode": {
            "count": len(whole),
            "decisions": n_whole / max(len(whole), 1),
            "ms": 1e3 * t_whole / max(len(whole), 1),
            "decisions_per_s": n_whole / t_whole if t_whole else 0.0,
        },
        "episodes": [[ep.seed, ep.options, ep.steps] for ep in episodes],
    }


def _time_parts(env: Any, sensors_ref: bool = True) -> dict[str, Any]:
    """Wrap SUMO stepping, the planner, the sensors and the risk measure with timers.

    Returns the dict the wrappers add seconds to while ``env.step`` runs (resets are
    not counted); ``risk_steps`` counts the SUMO steps the risk measure covered and
    ``simulation_step`` is the unwrapped libsumo step. ``sensors_ref_ms`` times the
    reference sensors on the same inputs (``excluded_s``: their time inside the step,
    with the comparison, to take off the step's; ``sensors_pairs``: (new, reference)
    seconds of each observation, whose median ratio resists a loaded machine's
    preemptions), ``sensors_mismatches`` counts the observations where the two differ.
    """
    import libsumo

    from priqn.env import measures, planner

    totals: dict[str, Any] = {
        "sumo_ms": 0.0, "plan_ms": 0.0, "sensors_ms": 0.0, "risk_ms": 0.0, "risk_steps": 0,
        "simulation_step": libsumo.simulationStep, "sensors_ref_ms": 0.0,
        "sensors_mismatches": 0, "excluded_s": 0.0, "sensors_pairs": [],
    }  # fmt: skip
    in_step = [False]

    def timed(fn: Any, key: str) -> Any:
        def wrapper(*a: Any, **k: Any) -> Any:
            if not in_step[0]:
                return fn(*a, **k)
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                totals[key] += time.perf_counter() - t0

        return wrapper

    risk = timed(measures.conflict_times_s, "risk_ms")

    def counted_risk(ego: Any, steps: Any, *a: Any, **k: Any) -> Any:
        totals["risk_steps"] += len(steps)
        return risk(ego, steps, *a, **k)

    step = env.step

    def stepping(action: Any) -> Any:
        in_step[0] = True
        try:
            return step(action)
        finally:
            in_step[0] = False

    libsumo.simulationStep = timed(libsumo.simulationStep, "sumo_ms")
    planner.plan = timed(planner.plan, "plan_ms")
    measures.conflict_times_s = counted_risk
    if sensors_ref:
        env._sensors.observe = _with_reference(env._sensors, in_step, totals)
    else:
        env._sensors.observe = timed(env._sensors.observe, "sensors_ms")
    env.step = stepping
    return totals


def _with_reference(sensors: Any, in_step: list[bool], totals: dict[str, Any]) -> Any:
    """``sensors.observe``, timed into ``totals["sensors_ms"]``, with the reference sensors
    timed on the same inputs (alternating which runs first) and compared byte for byte."""
    import numpy as np

    from priqn.bench.references.sensors import ReferenceSensors

    new, ref = sensors.observe, ReferenceSensors(sensors.cfg).observe
    calls = [0]

    def observe(*a: Any, **k: Any) -> Any:
        if not in_step[0]:
            return new(*a, **k)
        t_in = time.perf_counter()
        if not calls[0]:  # the reference's first call pays one-off costs (~0.4 s): untimed
            ref(*a, **k)
        calls[0] += 1
        out, took = {}, {}
        for name in ("ref", "new") if calls[0] % 2 else ("new", "ref"):
            t0 = time.perf_counter()
            out[name] = (ref if name == "ref" else new)(*a, **k)
            took[name] = time.perf_counter() - t0
        same = all(np.array_equal(x, y) for x, y in zip(out["new"], out["ref"], strict=True))
        totals["sensors_ms"] += took["new"]
        totals["sensors_ref_ms"] += took["ref"]
        totals["sensors_pairs"].append((took["new"], took["ref"]))
        totals["sensors_mismatches"] += not same
        totals["excluded_s"] += time.perf_counter() - t_in - took["new"]
        return out["new"]

    return observe


def _measure_vector(cfg: Any, spec: dict[str, Any]) -> dict[str, Any]:
    import numpy as np

    from priqn.env.vector import make_vector_env

    n = int(spec["workers"])
    venv = make_vector_env(cfg, n, seed=spec["seed"])
    policy = np.random.default_rng(spec["seed"] + 1)
    n_off = cfg.n_offsets
    try:
        venv.call("preload_nets")
        venv.reset()
        for _ in range(5):  # warm-up
            venv.step(policy.choice(POLICY_ACTIONS_SPEED, size=n) * n_off + n_off // 2)
        t0 = time.perf_counter()
        for _ in range(spec["decisions"]):
            venv.step(policy.choice(POLICY_ACTIONS_SPEED, size=n) * n_off + n_off // 2)
        dt = time.perf_counter() - t0
    finally:
        venv.close()
    return {
        "workers": n,
        "decisions": n * spec["decisions"],
        "decisions_per_s": n * spec["decisions"] / dt,
    }
