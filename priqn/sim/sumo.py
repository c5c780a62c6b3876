"""Finding SUMO: binaries, version, and the environment SUMO's tools expect.

SUMO comes from the pinned ``eclipse-sumo`` wheel (import name ``sumo``), which
ships the binaries under ``sumo.SUMO_HOME/bin``. The user never has to set
``SUMO_HOME``: :func:`binary` finds programs through the package, and
:func:`subprocess_env` hands SUMO's own processes a ``SUMO_HOME`` so they find
their schemas and type maps (and do not warn about it).

Also here: :func:`simulation_args`, the ``sumo`` command-line options this project
measured to work for an ego driven with ``moveToXY`` (docs/environment.md), so the
environment starts every simulation the same way.
"""

from __future__ import annotations

import functools
import os
import re
import subprocess
from collections.abc import Sequence
from pathlib import Path

from priqn.errors import PriqnError

_INSTALL_HINT = "install the pinned SUMO wheels: pip install -e . (eclipse-sumo, sumolib, libsumo)"


@functools.lru_cache(maxsize=1)
def sumo_home() -> Path:
    """``SUMO_HOME`` of the installed ``eclipse-sumo`` package (a user's ``SUMO_HOME`` is ignored)."""
    try:
        import sumo  # the eclipse-sumo wheel
    except ImportError as exc:
        raise PriqnError(
            f"SUMO not found: cannot import the 'sumo' package; {_INSTALL_HINT}"
        ) from exc
    home = Path(sumo.SUMO_HOME)
    if not (home / "bin").is_dir():
        raise PriqnError(f"{home}: SUMO installation has no bin/ folder; {_INSTALL_HINT}")
    return home


@functools.cache
def binary(name: str) -> str:
    """Absolute path of SUMO program ``name`` (``"netconvert"``, ``"sumo"``, ...)."""
    bin_dir = sumo_home() / "bin"
    for candidate in (bin_dir / name, bin_dir / f"{name}.exe"):
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return str(candidate)
    available = sorted(p.name for p in bin_dir.iterdir() if p.is_file())
    raise PriqnError(
        f"{bin_dir}: no SUMO program {name!r} (available: {', '.join(available) or 'none'}); "
        f"{_INSTALL_HINT}"
    )


def subprocess_env() -> dict[str, str]:
    """A copy of ``os.environ`` with ``SUMO_HOME`` pointing at the installed package."""
    env = dict(os.environ)
    env["SUMO_HOME"] = str(sumo_home())
    return env


@functools.lru_cache(maxsize=1)
def sumo_version() -> str:
    """SUMO release, e.g. ``"1.28.0"``, read from ``netconvert --version`` (cached)."""
    exe = binary("netconvert")
    try:
        out = subprocess.run(
            [exe, "--version"], capture_output=True, text=True, env=subprocess_env(), timeout=60
        ).stdout
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise PriqnError(f"{exe}: cannot run ({exc}); {_INSTALL_HINT}") from exc
    match = re.search(r"netconvert\s+v?(\d+(?:\.\d+)+)", out)
    if not match:
        first = out.strip().splitlines()[0] if out.strip() else "no output"
        raise PriqnError(f"{exe} --version: cannot read the SUMO version from {first!r}")
    return match.group(1)


def simulation_args(
    net_file: str | Path,
    *,
    seed: int,
    step_length_s: float = 0.1,
    lateral_resolution_m: float | None = None,
    extra: Sequence[str] = (),
) -> list[str]:
    """Command line for ``libsumo.start`` / ``sumo`` on one net (docs/environment.md).

    Teleports off, collisions only warned about (the environment runs its own
    oriented-box test), junction collisions checked, no warnings on stderr.
    ``lateral_resolution_m`` turns on the sublane model, which NPCs need to pass a
    static obstacle on a one-lane arm. ``seed`` goes to SUMO's ``--seed``.
    """
    net = Path(net_file)
    if not net.is_file():
        raise PriqnError(f"{net}: no such net file; run 'priqn scenario generate'")
    if step_length_s <= 0:
        raise PriqnError(f"step_length_s: must be > 0, got {step_length_s}")
    args = [
        binary("sumo"),
        "--net-file", str(net),
        "--step-length", f"{step_length_s:g}",
        "--seed", str(int(seed)),
        "--time-to-teleport", "-1",
        "--collision.action", "warn",
        "--collision.check-junctions", "true",
        "--collision.mingap-factor", "0",
        "--no-warnings", "true",
        "--no-step-log", "true",
        "--xml-validation", "never",
    ]  # fmt: skip
    if lateral_resolution_m is not None:
        if lateral_resolution_m <= 0:
            raise PriqnError(f"lateral_resolution_m: must be > 0, got {lateral_resolution_m}")
        args += ["--lateral-resolution", f"{lateral_resolution_m:g}"]
    return args + list(extra)
