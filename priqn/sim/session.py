"""One libsumo simulation per process: start, reload for the next episode, close.

libsumo runs SUMO inside this process and allows a single simulation per process,
so a :class:`SumoSession` is the one owner of it. The first episode calls
``libsumo.start``; later episodes call ``libsumo.load`` with the new net and seed,
which restarts the simulation in a few milliseconds without a new process.

The SUMO options are the ones measured to work for a moveToXY-driven ego
(``docs/environment.md``): 0.1 s steps, no teleports, collisions only reported
(we test collisions ourselves), junction collision checks on, the sublane model so
traffic can pass static obstacles on one-lane arms. SUMO writes its reason for a
failed start to the C-level stderr; we capture it and put it in a one-line
:class:`~priqn.errors.PriqnError` that names the net.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import ModuleType

from priqn.errors import PriqnError
from priqn.sim.sumo import simulation_args

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


class SumoSession:
    """The process's libsumo simulation.

    ``start(net, seed)`` the first time, then ``start`` again for each episode (it
    reloads with ``libsumo.load``), ``close()`` at the end. A second session in the
    same process while one is open raises :class:`PriqnError` (libsumo cannot run two).
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
        if _ACTIVE is not None and _ACTIVE is not self:
            raise PriqnError(
                "libsumo already runs a simulation in this process; use one env per process "
                "(priqn.env.vector.make_vector_env runs each env in its own worker)"
            )
        ls = _libsumo()
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
        self.net_file = net
        self.seed = int(seed)
        _ACTIVE = self

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
