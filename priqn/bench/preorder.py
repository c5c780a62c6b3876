"""``priqn bench preorder``: batched optimal subsets vs a per-state reference loop.

Times :func:`priqn.preorder.optimal_subsets` on a batch of random quantiles
``[B, N, K, A]`` against
:func:`priqn.bench.references.subsets.reference_optimal_subsets`, a straightforward
per-state implementation of Algorithm 1 in plain Python + numpy (one state at a
time, one objective at a time, the relations as numpy matrices, written the way the
paper writes it; the tests check the batched core against the same oracle). Both must
return the same subsets (checked every run). Where
``priqn.agents.network`` is importable it also times one forward pass of the agent's
network at the same batch, since the subsets run after every forward pass.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    import torch

    from priqn.preorder import Preorder


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-B", "--batch", type=int, default=256, help="states per batch (256)")
    parser.add_argument("-K", "--quantiles", type=int, default=32, help="quantiles per action (32)")
    parser.add_argument("-A", "--actions", type=int, default=25, help="actions (25 = 5 x 5)")
    parser.add_argument(
        "--preorder",
        default="total",
        help="'total', 'partial' or a TOML file with a [preorder] table (default total)",
    )
    parser.add_argument("--comparator", default="qd", help="qd | mv | cvar | fsd (default qd)")
    parser.add_argument("--eps", type=float, default=0.2, help="tolerance for every objective")
    parser.add_argument(
        "--repeats", type=int, default=50, help="timed calls of the batched version"
    )
    parser.add_argument(
        "--reference-repeats", type=int, default=3, help="timed passes of the per-state loop"
    )
    parser.add_argument("--device", default="cpu", help="torch device of the batched version")
    parser.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch CPU threads (default 1: stable on a shared machine; 0 = torch's choice)",
    )
    parser.add_argument("--obs-size", type=int, default=128, help="BEV/LiDAR size for the network")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random quantiles")


def _timeit(fn: Callable[[], Any], repeats: int, sync: Callable[[], None]) -> tuple[float, float]:
    """Median and minimum seconds per call over ``repeats`` calls (after one warm-up)."""
    fn()
    sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    times.sort()
    return times[len(times) // 2], times[0]


def _network_forward_time(
    batch: int, n_heads: int, k: int, a: int, obs_size: int, device: Any, repeats: int, sync: Any
) -> tuple[float | None, str]:
    """Median seconds of one no-grad forward pass of the agent network, or (None, why)."""
    import torch

    try:
        from priqn.agents.network import QuantileNetwork, tau_grid
    except Exception as exc:  # noqa: BLE001 - any import problem means "unavailable"
        return None, f"priqn.agents.network not importable ({type(exc).__name__}: {exc})"
    try:
        shapes = {
            "bev": (4, obs_size, obs_size),
            "lidar": (2, obs_size, obs_size),
            "command": (3,),
            "kinematics": (4,),
        }
        net = QuantileNetwork(shapes, {"bev": 1 / 255, "lidar": 1 / 255}, a, n_heads).to(device)
        net.eval()
        gen = torch.Generator().manual_seed(0)
        obs = {
            "bev": torch.randint(0, 256, (batch, *shapes["bev"]), generator=gen, dtype=torch.uint8),
            "lidar": torch.randint(
                0, 256, (batch, *shapes["lidar"]), generator=gen, dtype=torch.uint8
            ),
            "command": torch.eye(3)[torch.randint(0, 3, (batch,), generator=gen)],
            "kinematics": torch.randn(batch, 4, generator=gen),
        }
        obs = {key: v.to(device) for key, v in obs.items()}
        taus = tau_grid(k, device=device).expand(batch, k)
        with torch.no_grad():
            median, _ = _timeit(lambda: net(obs, taus), repeats, sync)
    except Exception as exc:  # noqa: BLE001 - the network's API may still be moving
        return None, f"network forward failed ({type(exc).__name__}: {exc})"
    return median, (
        f"QuantileNetwork forward, obs {obs_size}x{obs_size}, H={n_heads}, K={k}, A={a}, no grad"
    )


def run(args: argparse.Namespace) -> int:
    """Entry point of ``priqn bench preorder``: the flags checked, the batched subsets timed
    and checked against the per-state reference on one random batch, the network's
    forward pass timed beside them; 1 when the subsets differ."""
    import torch

    from priqn.preorder import Preorder

    device = _checked_device(args)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    po = Preorder.resolve(args.preorder)
    b, n, k, a = args.batch, len(po), args.quantiles, args.actions
    quantiles_np = _random_quantiles((b, n, k, a), args.seed)
    subsets = _time_subsets(quantiles_np, po, args, device, sync)
    t_net, net_note = _network_forward_time(
        b, n, k, a, args.obs_size, device, max(3, min(args.repeats, 10)), sync
    )
    _print_subsets(args, po, device, subsets)
    t_batched = subsets.batched[0]
    if t_net is None:
        print(f"  network forward pass:           unavailable: {net_note}")
    else:
        print(f"  network forward pass:           {t_net * 1e3:9.3f} ms/batch  ({net_note})")
        print(
            f"  optimal_subsets / forward pass: {t_batched / t_net:9.3f}"
            f"  ({100 * t_batched / t_net:.1f}% of one forward pass)"
        )
    if not math.isfinite(subsets.reference[0] / t_batched):
        return 1
    return 0 if subsets.agree else 1


def _checked_device(args: argparse.Namespace) -> torch.device:
    """The flags checked, torch's CPU threads set (``--threads``); the ``--device`` the
    batched version runs on, once torch has allocated on it."""
    import torch

    from priqn.errors import PriqnError

    for name in ("batch", "quantiles", "actions", "repeats", "reference_repeats"):
        if getattr(args, name) < 1:
            raise PriqnError(f"--{name.replace('_', '-')}: expected a positive integer")
    if args.threads < 0:
        raise PriqnError("--threads: expected 0 (torch's choice) or a positive integer")
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    try:
        device = torch.device(args.device)
        torch.empty(1, device=device)
    except (RuntimeError, AssertionError) as exc:
        raise PriqnError(f"--device {args.device!r}: not available here ({exc})") from None
    return device


def _random_quantiles(shape: tuple[int, int, int, int], seed: int) -> Any:
    """Random sorted quantiles ``[B, N, K, A]`` (float64): per-action means and spreads
    that differ, so the subsets are neither all nor one action."""
    import numpy as np

    b, n, k, a = shape
    rng = np.random.default_rng(seed)
    loc = rng.normal(0.0, 1.0, size=(b, n, 1, a))
    spread = rng.uniform(0.2, 1.5, size=(b, n, 1, a))
    return loc + spread * np.sort(rng.normal(size=(b, n, k, a)), axis=2)


class _SubsetTimes(NamedTuple):
    """The batched optimal subsets against the per-state reference on one batch."""

    batched: tuple[float, float]
    """Median and minimum seconds per batch of :func:`priqn.preorder.optimal_subsets`."""
    reference: tuple[float, float]
    """The same of :func:`priqn.bench.references.subsets.reference_optimal_subsets`."""
    agree: bool
    """Both give the same subsets (compared in float64)."""
    sizes: list[float]
    """Mean number of optimal actions per objective (``|S_r|``)."""


def _time_subsets(
    quantiles_np: Any,
    po: Preorder,
    args: argparse.Namespace,
    device: torch.device,
    sync: Callable[[], None],
) -> _SubsetTimes:
    """Time the batched subsets (float32 on ``device``, ``--repeats`` calls) and the
    per-state reference (``--reference-repeats`` passes) on ``quantiles_np``, and check
    that they agree."""
    import numpy as np
    import torch

    from priqn.bench.references.subsets import reference_optimal_subsets
    from priqn.preorder import optimal_subsets

    q64 = torch.from_numpy(quantiles_np)
    q = q64.to(device=device, dtype=torch.float32)

    def batched() -> Any:
        return optimal_subsets(q, po, comparator=args.comparator, eps=args.eps)

    t_batched = _timeit(batched, args.repeats, sync)
    ref_args = (po, args.eps, args.comparator)
    t_ref = _timeit(
        lambda: reference_optimal_subsets(quantiles_np, *ref_args), args.reference_repeats, sync
    )
    # Same subsets? Compare in float64 so rounding cannot flip a relation at ε.
    ref_sets, ref_leaf = reference_optimal_subsets(quantiles_np, *ref_args)
    out64 = optimal_subsets(q64.to(device), po, comparator=args.comparator, eps=args.eps)
    agree = bool(
        np.array_equal(out64.per_objective.cpu().numpy(), ref_sets)
        and np.array_equal(out64.leaf.cpu().numpy(), ref_leaf)
    )
    sizes = batched().per_objective.float().sum(-1).mean(0).cpu().tolist()
    return _SubsetTimes(t_batched, t_ref, agree, sizes)


def _print_subsets(
    args: argparse.Namespace, po: Preorder, device: torch.device, times: _SubsetTimes
) -> None:
    """The table's head: the batch, the preorder, the device, the subsets' sizes, both
    timings, the speed-up against its target, and whether the subsets agree."""
    import torch

    b, n, k, a = args.batch, len(po), args.quantiles, args.actions
    (t_batched, t_batched_min), (t_ref, t_ref_min) = times.batched, times.reference
    threads = torch.get_num_threads()
    print(
        f"priqn bench preorder: B={b} N={n} K={k} A={a} comparator={args.comparator} eps={args.eps}"
    )
    print(f"  preorder:  {po.describe()}")
    print(f"  device:    {device} (torch {torch.__version__}, {threads} CPU threads)")
    print(
        "  mean |S_r| per objective: "
        + ", ".join(f"{name}={v:.2f}" for name, v in zip(po.objectives, times.sizes, strict=True))
    )
    print(
        f"  batched optimal_subsets:        {t_batched * 1e3:9.3f} ms/batch (min {t_batched_min * 1e3:.3f})"
        f"  = {t_batched / b * 1e6:.2f} us/state"
    )
    print(
        f"  per-state reference (numpy):    {t_ref * 1e3:9.3f} ms/batch (min {t_ref_min * 1e3:.3f})"
        f"  = {t_ref / b * 1e6:.2f} us/state"
    )
    print(
        f"  speed-up batched vs reference:  {t_ref / t_batched:9.1f}x medians,"
        f" {t_ref_min / t_batched_min:.1f}x minima"
        f"  (target >= 100x){'' if t_ref / t_batched >= 100 else '  BELOW TARGET'}"
    )
    print(f"  same subsets as the reference:  {'yes' if times.agree else 'NO'}")
