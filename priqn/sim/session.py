"""One libsumo simulation per process: start, reload for the next episode, close.

libsumo runs SUMO inside this process and allows a single simulation per process,
so a :class:`SumoSession` is the one owner of it. The first episode calls
``libsumo.start``; later episodes call ``libsumo.load`` with the new net and seed,
which restarts the simulation in a few milliseconds without a new process.

The SUMO options are :func:`priqn.sim.sumo.simulation_args`, measured to work for a
moveToXY-driven ego (``docs/environment.md``): 0.1 s steps, no teleports, collisions
only reported (we test collisions ourselves), junction collision checks on, the
sublane model so traffic can pass static obstacles on one-lane arms. SUMO writes its
reason for a failed start to the C-level stderr; we capture it and put it in a
one-line :class:`~priqn.errors.PriqnError` that names the net. :func:`check_net` loads
each net once with the ``sumo`` binary in a subprocess first, because libsumo crashes
the whole process on some malformed nets.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import ModuleType

from priqn.errors import PriqnError
from priqn.sim.sumo import binary, simulation_args, subprocess_env

EXTRA_OPTIONS: tuple[str, ...] = ("--duration-log.disable", "true")
"""Options added to :func:`priqn.sim.sumo.simulation_args` (which holds the measured set)."""

_ACTIVE: SumoSession | None = None


def _libsumo() -> ModuleType:
    import libsumo  # lazy: importing priqn never loads SUMO

    return libsumo


@contextlib.contextmanager
def _captured_stderr() -> Iterator[list[str]]:
    """Redirect the C-level stderr (fd 2) to a temp file; yields a list filled on exit."""
    captured: list[str] = []
    try:
        saved = os.dup(2)
    except OSError:  # no fd 2 (unusual embedders): run without capturing
        yield captured
        return
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield captured
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            captured.append(tmp.read().decode("utf-8", "replace"))


def _sumo_message(exc: BaseException, stderr_text: str) -> str:
    lines = [ln.strip() for ln in stderr_text.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("Error")] or lines
    text = " ".join(errors) if errors else ""
    return f"{text} ({exc})" if text else str(exc)


_CHECKED: set[tuple[str, int, int]] = set()


def check_net(net_file: str | os.PathLike) -> None:
    """Let the ``sumo`` binary load ``net_file`` once (per process, per file version).

    libsumo crashes the whole process on some malformed nets (e.g. a ``<net>`` without a
    version); a throw-away ``sumo --end 0`` in a subprocess turns that into a one-line
    :class:`PriqnError` naming the net and SUMO's message. ~0.1 s, once per net.
    """
    net = Path(net_file)
    try:
        st = net.stat()
    except OSError:
        raise PriqnError(
            f"{net}: SUMO net not found; run 'priqn scenario generate' first"
        ) from None
    key = (str(net.resolve()), st.st_mtime_ns, st.st_size)
    if key in _CHECKED:
        return
    cmd = [binary("sumo"), "-n", str(net), "--end", "0", "--xml-validation", "never",
           "--no-step-log", "true", "--duration-log.disable", "true", "--no-warnings", "true"]  # fmt: skip
    try:
        proc = subprocess.run(
            cmd, capture_output=True, text=True, env=subprocess_env(), timeout=120
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise PriqnError(f"{net}: could not run SUMO to check the net ({exc})") from exc
    if proc.returncode != 0:
        if proc.returncode < 0:
            why = f"SUMO crashed reading it (signal {-proc.returncode}); is it a valid .net.xml?"
        else:
            why = _sumo_message(RuntimeError(f"exit status {proc.returncode}"), proc.stderr)
        raise PriqnError(f"{net}: SUMO failed to start: {why}")
    _CHECKED.add(key)


class SumoSession:
    """The process's libsumo simulation.

    ``start(net, seed)`` the first time, then ``start`` again for each episode (it
    reloads with ``libsumo.load``), ``close()`` at the end. libsumo runs one simulation
    per process: a second session that starts takes the simulation over, and the
    first one then reports ``is_open`` False and ``taken_over`` True.
    """

    def __init__(self, step_length_s: float = 0.1, lateral_resolution_m: float | None = 0.8):
        self.step_length_s = float(step_length_s)
        """Simulation step [s]."""
        self.lateral_resolution_m = lateral_resolution_m
        """Sublane width [m] (None = no sublane model)."""
        self.net_file: Path | None = None
        """The net of the running simulation (None before ``start`` / after ``close``)."""
        self.seed: int | None = None
        """SUMO ``--seed`` of the running simulation."""
        self._open = False
        self.taken_over = False
        """True when another session in this process started a simulation over this one's."""

    @property
    def is_open(self) -> bool:
        """Whether this session currently owns a running simulation."""
        return self._open

    @property
    def sim(self) -> ModuleType:
        """The ``libsumo`` module (use only while the session is open)."""
        return _libsumo()

    def start(self, net_file: str | os.PathLike, seed: int, extra: Sequence[str] = ()) -> None:
        """Start (first call) or reload (later calls) SUMO on ``net_file`` with ``--seed seed``.

        Raises :class:`PriqnError` naming the net and SUMO's own message if SUMO refuses.
        """
        global _ACTIVE
        net = Path(net_file)
        if not net.is_file():
            raise PriqnError(f"{net}: SUMO net not found; run 'priqn scenario generate' first")
        check_net(net)
        ls = _libsumo()
        if _ACTIVE is not None and _ACTIVE is not self:
            # libsumo holds one simulation per process: take it over; the other session
            # learns it was closed (``is_open`` False, ``taken_over`` True).
            _ACTIVE._open = False
            _ACTIVE.taken_over = True
            self._open = True  # reuse the running simulation via load()
        argv = simulation_args(
            net,
            seed=int(seed),
            step_length_s=self.step_length_s,
            lateral_resolution_m=self.lateral_resolution_m,
            extra=(*EXTRA_OPTIONS, *extra),
        )
        with _captured_stderr() as err:
            try:
                if self._open:
                    ls.load(argv[1:])
                else:
                    ls.start(argv)
                failure = None
            except Exception as exc:  # libsumo.TraCIException / FatalTraCIError
                failure = exc
        if failure is not None:
            self._open = False
            _ACTIVE = None
            with contextlib.suppress(Exception):
                ls.close()
            raise PriqnError(
                f"{net}: SUMO failed to start: {_sumo_message(failure, err[0] if err else '')}"
            ) from failure
        self._open = True
        self.taken_over = False
        self.net_file = net
        self.seed = int(seed)
        _ACTIVE = self

    def close_after_failure(self) -> None:
        """Close after a libsumo error mid-episode, so the next ``start`` begins afresh.

        libsumo keeps pending ``moveToXY`` requests in process-wide state that survives
        ``close`` and ``load``; the next simulation's first step then touches the removed
        vehicle and crashes the process. One step (errors ignored) applies them first.
        """
        if self._open:
            with contextlib.suppress(Exception):
                _libsumo().simulationStep()
        self.close()

    def close(self) -> None:
        """End the simulation (safe to call twice)."""
        global _ACTIVE
        if self._open:
            with contextlib.suppress(Exception):
                _libsumo().close()
        self._open = False
        self.net_file = None
        if _ACTIVE is self:
            _ACTIVE = None

    def __enter__(self) -> SumoSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
