"""``priqn bench env``: env decisions/s against the raw libsumo floor, and vector-env scaling.

Every measurement runs in its own subprocess (libsumo allows one simulation per
process, and a fresh process keeps the measurements independent):

1. **env** — one :class:`~priqn.env.intersection.IntersectionEnv` with the default
   observation, at each density: episodes on pinned scenes (net, command, seed) driven
   by a fixed seeded policy (target speed 3/6/9 m/s, no lateral offset); the time of
   ``step`` only (resets are timed separately, after every net of the pool was parsed
   once, as in a long training run).
2. **floor** — the same scenes (same seeds, so the same net, traffic and obstacles)
   stepped with ``libsumo.simulationStep`` only: no planner, no ego ``moveToXY``, no
   collision tests, no sensors, the same number of decisions per episode, each
   decision = ``decision_interval_s / sim_step_s`` SUMO steps.
3. **vector** — ``make_vector_env`` with 1 and with 2 workers, total decisions/s.

The ratio env / floor is the env's overhead over SUMO itself (target: <= 3).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

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
    parser.add_argument("--seed", type=int, default=0, help="seed of scenes and policy")
    parser.add_argument("--json", type=Path, default=None, help="also write the results here")


def run(args: argparse.Namespace) -> int:
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
    if args.max_workers < 1:
        raise PriqnError("--max-workers: expected >= 1")
    base = {"family": args.family, "obs_size_px": args.obs_size, "seed": args.seed}
    results: dict[str, Any] = {
        "config": {**base, "decisions": args.decisions},
        "density": {},
        "vector": {},
    }
    print(f"priqn bench env: family={args.family} obs={args.obs_size}px decisions={args.decisions}")
    print(
        f"{'density':>8} {'env dec/s':>10} {'floor dec/s':>12} {'env/floor':>10} {'reset ms':>9}"
        "   env step ms = sumo + sensors + planner + rest"
    )
    for d in densities:
        env = _child({**base, "mode": "env", "density": d, "decisions": args.decisions})
        floor = _child({**base, "mode": "floor", "density": d, "episodes": env["episodes"]})
        ratio = floor["decisions_per_s"] / env["decisions_per_s"]
        results["density"][str(d)] = {"env": env, "floor": floor, "ratio": ratio}
        p = env["parts_ms"]
        print(
            f"{d:>8.2f} {env['decisions_per_s']:>10.1f} {floor['decisions_per_s']:>12.1f} "
            f"{ratio:>9.2f}x {env['reset_ms']:>9.1f}   {env['step_ms']:.2f} = {p['sumo_ms']:.2f} "
            f"+ {p['sensors_ms']:.2f} + {p['plan_ms']:.2f} + {p['rest_ms']:.2f}"
        )
    print(f"{'workers':>8} {'dec/s':>10} {'speed-up':>10}")
    one = None
    for n in range(1, args.max_workers + 1):
        vec = _child({**base, "mode": "vector", "workers": n, "decisions": args.vector_decisions})
        one = one or vec["decisions_per_s"]
        results["vector"][str(n)] = vec
        print(f"{n:>8d} {vec['decisions_per_s']:>10.1f} {vec['decisions_per_s'] / one:>9.2f}x")
    if args.json is not None:
        from priqn.io import atomic_write_json

        atomic_write_json(args.json, results)
    return 0


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
    import numpy as np

    from priqn.env.intersection import EnvConfig, IntersectionEnv

    cfg = EnvConfig(family=spec["family"], obs_size_px=spec["obs_size_px"])
    mode = spec["mode"]
    if mode == "vector":
        return _measure_vector(cfg, spec)
    env = IntersectionEnv(cfg)
    n_off = cfg.n_offsets
    policy = np.random.default_rng(spec["seed"] + 1)
    try:
        env.preload_nets()  # parse every net once: resets are timed warm
        if mode == "env":
            parts = _time_parts(env)
            episodes, step_s, reset_s, done = [], 0.0, 0.0, 0
            for seed, options in _scenes(env, spec["seed"], spec["density"]):
                t0 = time.perf_counter()
                env.reset(seed=seed, options=options)
                reset_s += time.perf_counter() - t0
                steps = 0
                while done < spec["decisions"]:
                    a = int(policy.choice(POLICY_ACTIONS_SPEED)) * n_off + n_off // 2
                    t0 = time.perf_counter()
                    _, _, term, trunc, _ = env.step(a)
                    step_s += time.perf_counter() - t0
                    steps += 1
                    done += 1
                    if term or trunc:
                        break
                episodes.append([seed, options, steps])
                if done >= spec["decisions"]:
                    break
            parts = {k: 1e3 * v / done for k, v in parts.items()}
            parts["rest_ms"] = 1e3 * step_s / done - sum(parts.values())
            return {
                "decisions": done,
                "decisions_per_s": done / step_s,
                "step_ms": 1e3 * step_s / done,
                "reset_ms": 1e3 * reset_s / len(episodes),
                "parts_ms": parts,
                "episodes": episodes,
            }
        if mode == "floor":
            sub = cfg.substeps
            total, floor_s = 0, 0.0
            for seed, options, steps in spec["episodes"]:
                env.reset(seed=seed, options=options)
                sim = env._session.sim
                t0 = time.perf_counter()
                for _ in range(steps * sub):
                    sim.simulationStep()
                floor_s += time.perf_counter() - t0
                total += steps
            return {
                "decisions": total,
                "decisions_per_s": total / floor_s,
                "step_ms": 1e3 * floor_s / total,
            }
        raise ValueError(f"unknown bench mode {mode!r}")
    finally:
        env.close()


def _time_parts(env: Any) -> dict[str, float]:
    """Wrap the env's SUMO stepping, planner and sensors with timers (seconds, summed).

    Includes resets' SUMO steps only for the one set-up step per episode (negligible).
    """
    import libsumo

    totals = {"sumo_ms": 0.0, "plan_ms": 0.0, "sensors_ms": 0.0}

    def timed(fn: Any, key: str) -> Any:
        def wrapper(*a: Any, **k: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                totals[key] += time.perf_counter() - t0

        return wrapper

    from priqn.env import planner

    libsumo.simulationStep = timed(libsumo.simulationStep, "sumo_ms")
    planner.plan = timed(planner.plan, "plan_ms")
    env._sensors.observe = timed(env._sensors.observe, "sensors_ms")
    return totals


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
