"""SUMO's own GUI (``sumo-gui``) driven through TraCI, for people to watch an episode.

Training and evaluation run SUMO inside the process with libsumo
(:class:`priqn.sim.session.SumoSession`). To *watch* an episode, :class:`GuiSession`
starts the ``sumo-gui`` program of the installed ``eclipse-sumo`` wheel (found through
the package, :func:`priqn.sim.sumo.binary`, never through a user's ``SUMO_HOME``) with
the very same command-line options (:func:`priqn.sim.sumo.simulation_args`) and talks
to it over a TraCI socket. Its :attr:`GuiSession.sim` is a ``traci`` connection, whose
API is libsumo's, so the environment runs unchanged on it: same scene, same seed, same
decisions, same returns (``tests/test_play.py`` checks this).

Also here: :class:`GuiView`, the drawing a person sees on top of the simulation (the
ego tracked, the planned trajectory and target of each decision, a text label above the
ego), and :func:`virtual_display`, an ``Xvfb`` display started on a free display number
for machines without a screen (headless recording), stopped again on exit.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import itertools
import os
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from priqn.errors import PriqnError
from priqn.sim.session import EXTRA_OPTIONS, check_net
from priqn.sim.sumo import binary, simulation_args, subprocess_env

VIEW = "View #0"
"""sumo-gui's default view id."""
NO_DISPLAY_HINT = (
    "no display for sumo-gui (DISPLAY is not set): run under a virtual display, e.g. "
    "'xvfb-run -a priqn play ...' (Debian/Ubuntu: apt-get install -y xvfb)"
)
"""The one line shown when sumo-gui has no screen to open on."""
CONNECT_TIMEOUT_S = 60.0
"""How long sumo-gui may take to open its TraCI port [s]."""
_RETRY_S = 0.2

# A partial view scheme (sumo-gui keeps its defaults for everything not named): POI and
# polygon names drawn as text, a white background, vehicles drawn as boxes at real size.
_SCHEME = """<viewsettings>
    <scheme name="priqn">
        <background backgroundColor="white" showGrid="0"/>
        <vehicles vehicleQuality="2" vehicle_minSize="1" vehicle_exaggeration="1"
                  vehicleName_show="0"/>
        <pois poi_minSize="0" poi_exaggeration="1"
              poiName_show="0" poiType_show="1" poiType_size="{text_px}"
              poiType_color="black" poiType_bgColor="white" poiType_constantSize="1"/>
        <polys poly_minSize="0" poly_exaggeration="1" polyName_show="0"/>
        <legend showSizeLegend="0"/>
    </scheme>
    <delay value="{delay_ms}"/>
</viewsettings>
"""


def display_available() -> bool:
    """Whether an X display is set for GUI programs (``DISPLAY``, read when called)."""
    return bool(os.environ.get("DISPLAY"))


@contextlib.contextmanager
def virtual_display(size: tuple[int, int] = (1280, 1024)) -> Iterator[str]:
    """Start ``Xvfb`` on a free display number; yields ``":N"`` and sets ``DISPLAY`` meanwhile.

    ``Xvfb -displayfd`` picks the free number itself (no race with other displays). The
    server is stopped and ``DISPLAY`` restored on exit. One line if ``Xvfb`` is missing.
    """
    exe = shutil.which("Xvfb")
    if exe is None:
        raise PriqnError(
            "Xvfb: not found on PATH; recording without a display needs it "
            "(Debian/Ubuntu: apt-get install -y xvfb), or run with a display"
        )
    read_fd, write_fd = os.pipe()
    cmd = [exe, "-displayfd", str(write_fd), "-screen", "0", f"{size[0]}x{size[1]}x24",
           "-nolisten", "tcp"]  # fmt: skip
    proc = subprocess.Popen(
        cmd, pass_fds=(write_fd,), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    os.close(write_fd)
    try:
        with os.fdopen(read_fd, "rb") as pipe:
            number = pipe.readline().decode().strip()  # written once the server is ready
        if not number.isdigit():
            proc.kill()
            err = (proc.communicate(timeout=10)[1] or b"").decode(errors="replace").strip()
            raise PriqnError(f"Xvfb: could not start a virtual display ({err or 'no display'})")
        display = f":{number}"
        saved = os.environ.get("DISPLAY")
        os.environ["DISPLAY"] = display
        try:
            yield display
        finally:
            if saved is None:
                os.environ.pop("DISPLAY", None)
            else:
                os.environ["DISPLAY"] = saved
    finally:
        _stop(proc)


def _stop(proc: subprocess.Popen) -> None:
    """End ``proc`` (Xvfb or sumo-gui) if it still runs: SIGTERM, then SIGKILL after 10 s."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@dataclasses.dataclass(frozen=True)
class GuiOptions:
    """How sumo-gui shows an episode (``IntersectionEnv(render_mode="human", gui=...)``)."""

    delay_ms: float = 100.0
    """Pause sumo-gui makes after each simulation step [ms] (0 = as fast as it draws)."""
    window_px: tuple[int, int] = (960, 720)
    """Size of the sumo-gui window, so of its screenshots [px]."""
    zoom: float = 300.0
    """View zoom [%] around the tracked ego (100 = the whole net)."""
    text_px: int = 40
    """Height of the text label above the ego [px]."""

    def __post_init__(self) -> None:
        if not self.delay_ms >= 0:
            raise PriqnError(f"gui delay_ms: expected >= 0, got {self.delay_ms}")
        if len(self.window_px) != 2 or min(self.window_px) < 64:
            raise PriqnError(f"gui window_px: expected (width, height) >= 64, got {self.window_px}")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return int(s.getsockname()[1])


class GuiSession:
    """A ``sumo-gui`` process and its TraCI connection; the same interface as ``SumoSession``.

    ``start(net, seed)`` launches sumo-gui the first time and reloads it (``traci.load``)
    for later episodes; ``close()`` ends the program. Several may run at once (each is
    its own process), unlike libsumo.
    """

    _labels = itertools.count()

    def __init__(
        self,
        step_length_s: float = 0.1,
        lateral_resolution_m: float | None = 0.8,
        options: GuiOptions | None = None,
    ):
        self.step_length_s = float(step_length_s)
        """Simulation step [s]."""
        self.lateral_resolution_m = lateral_resolution_m
        """Sublane width [m] (None = no sublane model)."""
        self.options = options or GuiOptions()
        """How the GUI shows the episode."""
        self.net_file: Path | None = None
        """The net of the running simulation (None before ``start`` / after ``close``)."""
        self.seed: int | None = None
        """SUMO ``--seed`` of the running simulation."""
        self.taken_over = False
        """Always False: every GUI session has its own SUMO process."""
        self._conn: Any = None
        self._proc: subprocess.Popen | None = None
        self._tmp = tempfile.TemporaryDirectory(prefix="priqn-gui-")
        self._log = Path(self._tmp.name) / "sumo-gui.log"

    @property
    def is_open(self) -> bool:
        """Whether sumo-gui runs and is connected."""
        return self._conn is not None

    @property
    def sim(self) -> Any:
        """The TraCI connection (libsumo's API: ``.vehicle``, ``.simulationStep``, ``.gui``)."""
        if self._conn is None:
            raise PriqnError("sumo-gui: not running (start() first, or it was closed)")
        return self._conn

    def _argv(self, net: Path, seed: int, extra: Sequence[str]) -> list[str]:
        settings = Path(self._tmp.name) / "view.xml"
        settings.write_text(
            _SCHEME.format(text_px=self.options.text_px, delay_ms=self.options.delay_ms)
        )
        w, h = self.options.window_px
        gui = ["--gui-settings-file", str(settings), "--window-size", f"{w},{h}",
               "--window-pos", "0,0", "--start", "true", "--quit-on-end", "false"]  # fmt: skip
        return simulation_args(
            net,
            seed=int(seed),
            step_length_s=self.step_length_s,
            lateral_resolution_m=self.lateral_resolution_m,
            extra=(*EXTRA_OPTIONS, *gui, *extra),
        )

    def start(self, net_file: str | os.PathLike, seed: int, extra: Sequence[str] = ()) -> None:
        """Start sumo-gui on ``net_file`` (first call) or reload it (later calls).

        Raises :class:`PriqnError` in one line without a display, or naming the net and
        SUMO's message if sumo-gui refuses it.
        """
        net = Path(net_file)
        if not net.is_file():
            raise PriqnError(f"{net}: SUMO net not found; run 'priqn scenario generate' first")
        check_net(net)
        argv = self._argv(net, seed, extra)
        if self._conn is None:
            self._launch(argv)
        else:
            import traci.exceptions

            try:
                self._conn.load(argv[1:])
            except (traci.exceptions.TraCIException, traci.exceptions.FatalTraCIError) as exc:
                self.close()
                raise PriqnError(f"{net}: sumo-gui failed to load it: {self._why(exc)}") from exc
        self.net_file = net
        self.seed = int(seed)

    def _launch(self, argv: list[str]) -> None:
        import traci
        import traci.exceptions

        if not display_available():
            raise PriqnError(NO_DISPLAY_HINT)
        port = _free_port()
        cmd = [binary("sumo-gui"), *argv[1:], "--remote-port", str(port)]
        with open(self._log, "wb") as log:
            self._proc = subprocess.Popen(
                cmd, stdout=log, stderr=subprocess.STDOUT, env=subprocess_env()
            )
        label = f"priqn-gui-{os.getpid()}-{next(self._labels)}"
        retries = int(CONNECT_TIMEOUT_S / _RETRY_S)
        try:  # traci prints while it waits for the port: keep that off the user's screen
            with contextlib.redirect_stdout(io.StringIO()):
                self._conn = traci.connect(port, retries, "localhost", self._proc, _RETRY_S,
                                           None, True, label)  # fmt: skip
        except (traci.exceptions.TraCIException, traci.exceptions.FatalTraCIError) as exc:
            self.close()
            raise PriqnError(f"{argv[2]}: sumo-gui did not start: {self._why(exc)}") from exc

    def _why(self, exc: BaseException | None) -> str:
        text = self._log.read_text(errors="replace") if self._log.is_file() else ""
        lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
        errors = [ln for ln in lines if ln.startswith("Error")] or lines[-3:]
        msg = " ".join(errors)
        if exc is not None:
            msg = f"{msg} ({exc})" if msg else str(exc)
        return msg or "no message"

    def close_after_failure(self) -> None:
        """Close after an error mid-episode (the next ``start`` launches sumo-gui afresh)."""
        self.close()

    def close(self) -> None:
        """End sumo-gui (safe to call twice)."""
        conn, proc = self._conn, self._proc
        self._conn = self._proc = None
        self.net_file = None
        if conn is not None:
            with contextlib.suppress(Exception):
                conn.close(wait=False)
        if proc is not None:
            _stop(proc)

    def __enter__(self) -> GuiSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()
            self._tmp.cleanup()


EGO_COLOUR = (255, 0, 255, 255)
"""The ego's colour in the GUI (magenta: no other vehicle uses it)."""
PLAN_COLOUR = (0, 160, 255, 255)
"""The planned trajectory of the current decision."""
TARGET_COLOUR = (255, 140, 0, 255)
"""The plan's end point (target speed and offset reached)."""


class GuiView:
    """What a person sees on top of the simulation: the ego tracked, each decision's plan.

    Drawing objects (polygons, POIs) are not vehicles: the actors the environment reads
    (a vehicle context subscription) do not see them, so the episode is unchanged.
    """

    def __init__(self, session: GuiSession, ego_id: str):
        self.session = session
        self.ego_id = ego_id
        """SUMO id of the vehicle the view follows."""
        self._label_text = ""
        self.note = ""
        """Extra text for the label, set by the caller before a decision (e.g. subset sizes)."""
        self.params: dict[str, str] = {}
        """Extra ego parameters for the GUI's dialog, set by the caller before a decision."""

    def on_reset(self, lane_shapes: Sequence[np.ndarray] = ()) -> None:
        """After the episode is set up: colour the ego and follow it."""
        sim, opts = self.session.sim, self.session.options
        sim.vehicle.setColor(self.ego_id, EGO_COLOUR)
        sim.gui.trackVehicle(VIEW, self.ego_id)
        sim.gui.setZoom(VIEW, opts.zoom)
        self._label_text = ""

    def show_plan(self, xy_P2: np.ndarray, text: str) -> None:
        """Draw the decision's plan (centre line [P, 2] in metres) and its target point;
        label the ego with ``text`` and :attr:`note`."""
        sim = self.session.sim
        shape = [(float(x), float(y)) for x, y in xy_P2]
        if "priqn.plan" in sim.polygon.getIDList():
            sim.polygon.setShape("priqn.plan", shape)
        else:
            sim.polygon.add("priqn.plan", shape, PLAN_COLOUR, fill=False, layer=110, lineWidth=0.4)
        x, y = shape[-1]
        if "priqn.target" in sim.poi.getIDList():
            sim.poi.setPosition("priqn.target", x, y)
        else:
            sim.poi.add("priqn.target", x, y, TARGET_COLOUR, layer=111, width=1.6, height=1.6)
        self.label(f"{text}; {self.note}" if self.note else text, action=text, **self.params)

    def label(self, text: str, **params: str) -> None:
        """Text shown above the ego (a POI's type, drawn by the view scheme); ``params``
        also go into the ego's parameter dialog (``vehicle.setParameter``)."""
        sim = self.session.sim
        x, y = sim.vehicle.getPosition(self.ego_id)
        if "priqn.label" in sim.poi.getIDList():
            sim.poi.setPosition("priqn.label", x, y - 7.0)
            if text != self._label_text:
                sim.poi.setType("priqn.label", text)
        else:
            sim.poi.add("priqn.label", x, y - 7.0, (0, 0, 0, 0), poiType=text, layer=112)
        self._label_text = text
        for key, value in params.items():
            sim.vehicle.setParameter(self.ego_id, key, value)

    def screenshot(self, path: str | os.PathLike) -> None:
        """Ask sumo-gui for a picture of the view; it writes it after the next simulation step."""
        self.session.sim.gui.screenshot(VIEW, str(path), *self.session.options.window_px)
