"""``priqn play``: watch a trained policy drive, in SUMO's own GUI (``sumo-gui``).

Plays a run's greedy policy on the evaluation scenes ``priqn evaluate`` and ``priqn
inspect`` use (``--net``, ``--density``, ``--command``, ``--seed``, ``--eval-run``,
``--episodes`` mean what they mean for ``priqn inspect``), with the environment in
``render_mode="human"``: the episode runs in sumo-gui through TraCI, with the same
options, seeds and decisions as libsumo's, so it ends the same way with the same
per-objective returns (``tests/test_play.py``). The ego is magenta and followed by the
view; each decision's plan (the Frenet trajectory to the chosen target speed ``v_f`` and
offset ``d_f``) is drawn as a blue line with an orange target point; a label below the
ego names the action and, for Pr-IQN, the size of each preorder level's optimal subset
|S_r| (also in the ego's parameter dialog, ``priqn.subset.<objective>``).

``--record DIR`` saves one sumo-gui screenshot per decision (``DIR/frames/NNNN.png``),
assembles them into ``DIR/play.gif`` (if imageio, the ``gui`` extra, is installed) and
writes ``DIR/episodes.csv``; ``--record FILE.gif`` / ``FILE.mp4`` writes just that
animation (needs imageio). The destination is checked before anything plays. Without a
display, ``--record`` starts a virtual one (``Xvfb``) and stops it again; without ``--record`` it
says how to get one (``xvfb-run -a priqn play ...``). See docs/play.md.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from priqn.errors import PriqnError
from priqn.objectives import OUTCOMES
from priqn.run import checkpointer
from priqn.run.folder import RunFolder
from priqn.tools.inspector import (
    InspectConfig,
    add_scene_arguments,
    inspection_scenes,
    scene_config,
)

ANIMATIONS = (".gif", ".mp4")
"""File endings ``--record`` assembles an animation into (anything else is a folder)."""
FRAME_MS = 250
"""Time each decision's frame shows in a recorded animation [ms] (2 decisions/s = real time)."""
SCREENSHOT_WAIT_S = 20.0
"""How long to wait for sumo-gui to write the last screenshot of an episode [s]."""


@dataclasses.dataclass(frozen=True)
class Record:
    """Where ``--record`` puts the pictures."""

    frames_dir: Path
    """Folder of the per-decision screenshots ``NNNN.png``."""
    animation: Path | None
    """The assembled ``.gif`` or ``.mp4`` (None: a folder without imageio, frames only)."""
    table: Path | None
    """``episodes.csv`` (recording into a folder only)."""

    @classmethod
    def of(cls, target: str, scratch: Path) -> Record:
        """``--record DIR`` → frames, play.gif (with imageio), episodes.csv in DIR;
        ``FILE.gif|.mp4`` → that file. :func:`check_destination` validates ``target``."""
        path = Path(target)
        if path.suffix.lower() in ANIMATIONS:
            return cls(scratch / "frames", path, None)
        gif = path / "play.gif" if has_imageio() else None
        return cls(path / "frames", gif, path / "episodes.csv")


def has_imageio() -> bool:
    """Whether imageio (the ``gui`` extra), which assembles the animations, is installed."""
    try:
        import imageio  # noqa: F401
    except ImportError:
        return False
    return True


def check_destination(target: str) -> None:
    """Fail in one line, before anything plays, unless ``--record target`` can be written:
    a ``.gif``/``.mp4`` needs imageio and a folder it can write in (or create); anything
    else is a folder, which must be one (or creatable). Creates nothing."""
    path = Path(target)
    animation = path.suffix.lower() in ANIMATIONS
    if animation and not has_imageio():
        raise PriqnError(
            f"--record {target}: writing a {path.suffix} needs imageio; install the gui extra "
            "(pip install -e '.[gui]'), or record into a folder (frames and episodes.csv)"
        )
    where = path
    try:
        if animation and path.is_dir():
            raise PriqnError(f"--record {target}: is a folder; expected a file to write")
        if not animation and path.suffix and not path.is_dir():
            raise PriqnError(
                f"--record {target}: expected a folder, or a file ending in "
                f"{' or '.join(ANIMATIONS)}"
            )
        folder = (path.parent if animation else path).absolute()
        where = next(p for p in (folder, *folder.parents) if p.exists())
        if not where.is_dir():
            raise PriqnError(f"--record {target}: {where} is not a folder")
        with tempfile.NamedTemporaryFile(dir=where, prefix=".priqn-play-"):
            pass  # files (and folders) can be made there
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise PriqnError(f"--record {target}: cannot write in {where} ({reason})") from None


@dataclasses.dataclass
class EpisodeResult:
    """How one played episode ended."""

    episode: int
    net: str
    density: float
    command: str
    reset_seed: int
    steps: int
    """Decisions taken."""
    outcome: str
    """success, collision, off_road or timeout."""
    returns: np.ndarray
    """Undiscounted per-objective return (``float32 [N]``, the env's order)."""


def load_policy(run_dir: Path) -> Any:
    """The run's greedy policy on the CPU; a file that fails to load is one line."""
    run = RunFolder(run_dir)
    if not run.is_run():
        raise PriqnError(f"{run_dir}: not a run folder (no {run.CONFIG})")
    try:
        return checkpointer.load_policy(run, device="cpu")
    except PriqnError:
        raise
    except Exception as exc:  # a foreign or damaged file the loaders did not catch
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PriqnError(f"{run_dir}: the policy failed to load ({first})") from exc


def subset_text(policy: Any, decision: Any) -> tuple[str, dict[str, str]]:
    """|S_r| of each preorder level and of the leaf in ``decision`` (the policy's
    :class:`~priqn.agents.policy.Decision` for one state; Pr-IQN), as a label and as ego
    parameters; ('', {}) for agents without a preorder."""
    sizes_BS = decision.subset_sizes_BS
    if sizes_BS is None or decision.subsets_BLA is None:
        return "", {}
    names = policy.subset_size_names
    sizes = {name: int(size) for name, size in zip(names, sizes_BS[0], strict=True)}
    text = "|S| " + " ".join(f"{name} {size}" for name, size in sizes.items())
    return text, {f"priqn.subset.{name}": str(size) for name, size in sizes.items()}


def _outcome(info: dict[str, Any]) -> str:
    for key in OUTCOMES:
        if info.get(key):
            return key
    return "running"


def _wait_for(path: Path, timeout_s: float) -> None:
    """Wait until sumo-gui has written ``path`` (it saves screenshots in its own thread)."""
    deadline = time.monotonic() + timeout_s
    while not (path.is_file() and path.stat().st_size > 0):
        if time.monotonic() > deadline:
            raise PriqnError(f"{path}: sumo-gui did not write the screenshot")
        time.sleep(0.05)


def play_episodes(
    policy: Any, env: Any, scenes: list[Any], frames_dir: Path | None = None
) -> list[EpisodeResult]:
    """Play each scene greedily exactly as ``priqn evaluate`` does (same reset and acting
    seeds, same acting call). With sumo-gui (``env.gui``) each decision's subset sizes are
    shown, and with ``frames_dir`` one screenshot per decision is saved (plus the end)."""
    from tqdm import tqdm

    view, results, frame = getattr(env, "gui", None), [], 0
    for episode, scene in enumerate(tqdm(scenes, desc="play", unit="episode", disable=None)):
        rng = np.random.default_rng(scene.act_seed)
        obs, info = env.reset(seed=scene.reset_seed, options=scene.reset_options())
        done, steps = False, 0
        while not done:
            if view is not None and frames_dir is not None:
                # written after the next SUMO step: the state as this decision's plan starts
                view.screenshot(frames_dir / f"{frame:04d}.png")
                frame += 1
            batch = {k: np.asarray(v)[None] for k, v in obs.items()}
            decision = policy.decide(batch, rng)  # the same acting call as evaluate
            action = int(decision.actions_B[0])
            if view is not None:
                view.note, view.params = subset_text(policy, decision)
            obs, _, terminated, truncated, info = env.step(action)
            steps += 1
            done = bool(terminated or truncated)
        if view is not None and frames_dir is not None:  # the end of the episode
            view.screenshot(frames_dir / f"{frame:04d}.png")
            view.session.sim.simulationStep()  # the episode is over: this only draws
            _wait_for(frames_dir / f"{frame:04d}.png", SCREENSHOT_WAIT_S)
            frame += 1
        results.append(
            EpisodeResult(
                episode=episode,
                net=scene.net,
                density=float(scene.density),
                command=str(info["command"]),
                reset_seed=int(scene.reset_seed),
                steps=steps,
                outcome=_outcome(info),
                returns=np.asarray(info["returns"], np.float32).copy(),
            )
        )
    return results


def assemble(frames_dir: Path, out: Path, frame_ms: int = FRAME_MS) -> Path:
    """The screenshots of ``frames_dir`` (``NNNN.png``, in order) as a GIF or MP4 (imageio)."""
    try:
        import imageio.v3 as iio
    except ImportError:
        raise PriqnError(
            f"{out}: assembling frames needs imageio; install the gui extra: pip install -e '.[gui]'"
        ) from None
    frames = [iio.imread(p)[..., :3] for p in sorted(frames_dir.glob("*.png"))]
    if not frames:
        raise PriqnError(f"{frames_dir}: no frames were recorded")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.stem}.tmp{out.suffix}")
    if out.suffix.lower() == ".mp4":
        try:
            iio.imwrite(tmp, frames, fps=1000.0 / frame_ms, codec="libx264", macro_block_size=8)
        except Exception as exc:  # no ffmpeg plugin (imageio-ffmpeg) or codec
            tmp.unlink(missing_ok=True)
            raise PriqnError(
                f"{out}: cannot write MP4 ({type(exc).__name__}: {exc}); install the gui "
                "extra (pip install -e '.[gui]', imageio-ffmpeg) or record a .gif"
            ) from None
    else:
        iio.imwrite(tmp, frames, extension=".gif", duration=frame_ms, loop=0)
    tmp.replace(out)
    return out


@contextlib.contextmanager
def _display(record: bool) -> Iterator[None]:
    """Use the display there is; without one, a virtual one when recording, else one line."""
    from priqn.sim.gui import display_available, virtual_display

    if display_available():
        yield
    elif record:
        with virtual_display():
            yield
    else:
        raise PriqnError(
            "no display for sumo-gui (DISPLAY is not set): run 'xvfb-run -a priqn play ...' "
            "(Debian/Ubuntu: apt-get install -y xvfb), or add --record DIR to record headless"
        )


def play_run(
    run_dir: str | Path,
    cfg: InspectConfig,
    *,
    record: str | None = None,
    delay_ms: float | None = None,
    render_mode: str | None = "human",
) -> list[EpisodeResult]:
    """Play ``run_dir``'s policy on the configured scenes in sumo-gui (``render_mode=None``:
    the same episodes through libsumo, for comparison); returns how each episode ended."""
    from priqn.env.intersection import IntersectionEnv

    run_dir = Path(run_dir)
    if record is not None:  # before the policy, the scenes and a long episode
        check_destination(record)
    policy = load_policy(run_dir)
    scenes, eval_cfg = inspection_scenes(run_dir, cfg)
    env_cfg = dataclasses.replace(policy.env_config, family=eval_cfg.family, nets=(), junction="")
    if eval_cfg.max_episode_steps:
        env_cfg = dataclasses.replace(env_cfg, max_episode_steps=eval_cfg.max_episode_steps)
    with tempfile.TemporaryDirectory(prefix="priqn-play-") as scratch:
        rec = None if record is None else Record.of(record, Path(scratch))
        if rec is not None:
            rec.frames_dir.mkdir(parents=True, exist_ok=True)
            for old in rec.frames_dir.glob("*.png"):
                old.unlink()
        gui = None
        if render_mode == "human":
            gui = {"delay_ms": float(delay_ms if delay_ms is not None else (0 if rec else 100))}
        with _display(rec is not None) if render_mode == "human" else contextlib.nullcontext():
            env = IntersectionEnv(env_cfg, render_mode=render_mode, gui=gui)
            try:
                results = play_episodes(
                    policy, env, scenes, None if rec is None or gui is None else rec.frames_dir
                )
            finally:
                env.close()
        if rec is not None and gui is not None:
            if rec.animation is not None:
                assemble(rec.frames_dir, rec.animation)
            if rec.table is not None:
                _write_table(results, policy.agent.objectives, rec.table)
    return results


def _write_table(results: list[EpisodeResult], objectives: Any, path: Path) -> None:
    import pandas as pd

    from priqn.io import atomic_write_text

    rows = []
    for r in results:
        row = {k: v for k, v in dataclasses.asdict(r).items() if k != "returns"}
        row.update({f"return_{o}": float(r.returns[i]) for i, o in enumerate(objectives)})
        rows.append(row)
    atomic_write_text(path, pd.DataFrame(rows).to_csv(index=False))


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="a run folder made by 'priqn train' (committed cells too)")
    add_scene_arguments(parser, "play")
    parser.add_argument(
        "--delay",
        type=float,
        metavar="MS",
        help="sumo-gui's pause after each 0.1 s simulation step [ms] (default: 100; "
        "0 when recording without a display)",
    )
    parser.add_argument(
        "--record",
        metavar="DIR|FILE.gif|FILE.mp4",
        help="save a screenshot per decision: DIR gets frames/, play.gif (with imageio) and "
        "episodes.csv; a .gif or .mp4 file gets the animation (needs the gui extra); works "
        "without a display (starts Xvfb)",
    )


def run(args: argparse.Namespace) -> int:
    cfg = scene_config(args)
    if args.delay is not None and not args.delay >= 0:
        raise PriqnError(f"--delay {args.delay:g}: expected a pause >= 0 ms")
    results = play_run(args.run, cfg, record=args.record, delay_ms=args.delay)
    for r in results:
        returns = ", ".join(f"{x:.3f}" for x in r.returns)
        print(
            f"priqn play: episode {r.episode} on {r.net} (density {r.density:g}, {r.command}): "
            f"{r.outcome} after {r.steps} decisions; returns [{returns}]"
        )
    if args.record:
        print(f"priqn play: recorded into {args.record}")
        if Path(args.record).suffix.lower() not in ANIMATIONS and not has_imageio():
            print("priqn play: no play.gif (needs imageio: pip install -e '.[gui]')")
    return 0
