"""The ``priqn`` command line.

Each sub-command lives in its own module exposing ``configure_parser(parser)`` and
``run(args) -> int``. Only the chosen command's module is imported, so ``priqn
--help`` is instant and SUMO / torch load only for commands that need them.
A :class:`~priqn.errors.PriqnError` is printed as one line, exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import textwrap
from collections.abc import Sequence
from typing import Any

from priqn import __version__
from priqn.errors import PriqnError, did_you_mean

COMMANDS: dict[str, tuple[str, str]] = {
    "scenario": ("priqn.sim.cli", "generate SUMO nets from scenario families; draw a net"),
    "train": ("priqn.train", "train one agent into runs/<name>/"),
    "evaluate": ("priqn.evaluation.cli", "evaluate trained runs on the hold-out nets"),
    "report": (
        "priqn.analysis.cli",
        "tables, rliable statistics and figures from evaluated runs",
    ),
    "sweep": ("priqn.sweep", "train + evaluate + report a whole experiment grid"),
    "mechanism": (
        "priqn.tools.mechanism",
        "replay Pr-IQN cells: safety removals and the safety head's calibration",
    ),
    "probe": (
        "priqn.tools.standing_probe",
        "a scripted ego stands inside the junction: how often each traffic setting hits it",
    ),
    "inspect": (
        "priqn.tools.inspector",
        "why a policy acted: per-objective quantiles and optimal subsets",
    ),
    "play": ("priqn.tools.play", "watch a trained policy drive in sumo-gui; record it"),
    "diff": ("priqn.tools.diff", "are two runs the same training, bit for bit?"),
    "bench": (
        "priqn.bench",
        "speed as ratios to a baseline in the same command (env, preorder, train, sweep, "
        "replay, loop)",
    ),
}


class _HelpFormatter(argparse.HelpFormatter):
    """Argparse's formatter, but never breaking a line at a hyphen: experiment names,
    agent names and globs ('paper-point', 'pr-iqn-qd-*') stay whole to copy."""

    def _split_lines(self, text: str, width: int) -> list[str]:
        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)


def _top_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="priqn",
        description="Preordered distributional RL (Pr-IQN) for driving at SUMO intersections.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="commands:\n"
        + "\n".join(f"  {name:<10} {text}" for name, (_, text) in COMMANDS.items())
        + "\n\nRun 'priqn COMMAND --help' for a command's options.",
    )
    parser.add_argument("command", choices=sorted(COMMANDS), metavar="COMMAND")
    parser.add_argument("--version", action="version", version=f"priqn {__version__}")
    return parser


def command_parser(command: str) -> tuple[argparse.ArgumentParser, Any]:
    """The parser of ``priqn COMMAND`` and the module that runs it (imported here)."""
    module_name, text = COMMANDS[command]
    parser = argparse.ArgumentParser(
        prog=f"priqn {command}", description=text, formatter_class=_HelpFormatter
    )
    module = importlib.import_module(module_name)
    module.configure_parser(parser)
    return parser, module


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``priqn`` console script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    top = _top_parser()
    if not argv or argv[0].startswith("-"):
        top.parse_args(argv or ["--help"])
        return 0
    command, rest = argv[0], argv[1:]
    if command not in COMMANDS:
        top.error(
            f"unknown command {command!r} (choose from {', '.join(COMMANDS)})"
            + did_you_mean(command, COMMANDS)
        )
    try:
        parser, module = command_parser(command)
        args = parser.parse_args(rest)
        return int(module.run(args) or 0)
    except PriqnError as exc:
        print(f"priqn: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("priqn: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
