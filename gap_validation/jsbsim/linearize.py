"""A JSBSim aircraft trimmed straight and level and linearised by JSBSim itself, written as a validation
config.

Conventions (``gap-validate linearize --jsbsim AIRCRAFT --speed-kt V --altitude-ft H``):

- **Trim**: the aircraft shipped with the ``jsbsim`` wheel (``jsbsim.FGFDMExec(None)``), initial conditions at
  V knots *true* airspeed (``ic/vt-kts``) and H ft above sea level (``ic/h-sl-ft``; JSBSim's terrain is at sea
  level), flight path angle 0, wings level, heading north, every engine running; JSBSim's full trim
  (``do_trim(1)``: throttle, pitch, roll and yaw controls, attitude). A failed trim is a :class:`ConfigError`.
- **Linearisation**: ``jsbsim.FGLinearization`` about that trim. Its inputs are the normalised *commands*
  (``fcs/aileron-cmd-norm`` ...) and it runs the flight control system in trim mode, where actuators pass
  their input through; so its input matrix is converted to surface radians with the FCS's own static gains at
  trim, ``d(position rad) / d(command norm)``, measured the way FGLinearization perturbs the commands.
- **Inputs** (the config's surfaces, in rad): ``aileron = (left - right) / 2`` of ``fcs/left-aileron-pos-rad``
  and ``fcs/right-aileron-pos-rad``, ``elevator = fcs/elevator-pos-rad``, ``rudder = fcs/rudder-pos-rad``. A
  simulated flight (:mod:`gap_validation.jsbsim.flight`) sets exactly these positions (the two ailerons in the
  ratio the FCS moves them) and logs them. **Outputs**: body rates ``p, q, r`` [rad/s]
  (``velocities/p-rad_sec`` ...).
- **States** kept: FGLinearization's states but heading and position (``Psi``, ``Latitude``, ``Longitude``,
  ``Alt``), which do not feed back into the rates (altitude only through the air density, a mode of > 1000 s):
  ``Vt`` [ft/s], ``Alpha``, ``Theta`` [rad], ``Q`` [rad/s], ``Rpm0`` ... (propeller engines), ``Beta``,
  ``Phi`` [rad], ``P``, ``R`` [rad/s].
- **Check**: the control derivatives of the rate rows are measured again by setting the surface positions
  directly (:func:`surface_derivatives`); they must agree with the converted FGLinearization input matrix, or
  the aircraft's aerodynamics read other properties than the surfaces a flight sets (a ConfigError).
"""
from __future__ import annotations

import contextlib
import difflib
import math
import os
import shutil
import tempfile
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from gap_validation.core.config import FrequencyGrid
from gap_validation.core.errors import ConfigError, DataError

__all__ = [
    "SURFACES",
    "RATES",
    "POSITIONS",
    "CHECKED",
    "DEFAULT_GRID",
    "TrimPoint",
    "Trimmed",
    "Linearization",
    "available_aircraft",
    "jsbsim_version",
    "quiet_jsbsim",
    "trim",
    "linearize",
    "surface_derivatives",
    "surface_values",
    "drift_warnings",
    "config_mapping",
    "config_text",
    "write_config",
]

#: The config's surfaces (inputs, in rad) and rates (outputs, in rad/s), in matrix order.
SURFACES = ("aileron", "elevator", "rudder")
RATES = ("p", "q", "r")
#: FGFCS surface positions a flight sets [rad]: left and right aileron, elevator, rudder.
POSITIONS = (
    "fcs/left-aileron-pos-rad",
    "fcs/right-aileron-pos-rad",
    "fcs/elevator-pos-rad",
    "fcs/rudder-pos-rad",
)
#: Properties tied to the same FGFCS members in degrees (an FCS writing them must be blocked too).
POSITIONS_DEG = tuple(p.replace("-rad", "-deg") for p in POSITIONS)
#: Normalised commands of FGLinearization's inputs DaCmd, DeCmd, DrCmd.
COMMANDS = {
    "aileron": "fcs/aileron-cmd-norm",
    "elevator": "fcs/elevator-cmd-norm",
    "rudder": "fcs/rudder-cmd-norm",
}
_LINEAR_INPUTS = {"aileron": "DaCmd", "elevator": "DeCmd", "rudder": "DrCmd"}
_LINEAR_RATES = {"p": "P", "q": "Q", "r": "R"}
RATE_PROPERTIES = ("velocities/p-rad_sec", "velocities/q-rad_sec", "velocities/r-rad_sec")
_RATE_DOTS = ("accelerations/pdot-rad_sec2", "accelerations/qdot-rad_sec2", "accelerations/rdot-rad_sec2")
#: FGLinearization states left out of the config's model (heading and position).
DROPPED_STATES = ("Psi", "Latitude", "Longitude", "Alt")
#: Aircraft whose trim and linearisation were checked against the nonlinear model (docs/cli.md), with the true
#: airspeeds [kt] at 3000 ft where they trim (the DHC6 trims at 100-140 kt but does not hold its trim:
#: :meth:`Trimmed.drift`).
CHECKED = {"c172x": (60, 120), "J3Cub": (40, 90), "pa28": (80, 100)}
#: Frequency grid of the written config: a light aircraft's dutch roll, roll and short-period modes (1-10
#: rad/s) with an octave below and a decade above. Not lower: the card's sweeps start at half the lowest
#: frequency, and from 0.25 rad/s they pump the phugoid (about 0.2 rad/s) and bank the aircraft beyond the
#: linear range (a c172x at 100 kt: 20 deg of bank, 15 kt of speed, measured 4 dB and 20 deg off the
#: linearisation at 0.5 rad/s).
DEFAULT_GRID = FrequencyGrid(1.0, 30.0, 40)
#: Step of the FCS gain measurement, as FGLinearization perturbs the commands (FGStateSpace::linearize).
_COMMAND_STEP = 1e-4
#: Largest relative disagreement of the surface-set control derivatives with the converted FGLinearization
#: ones.
CONSISTENCY_LIMIT = 0.05
#: Lowest altitude accepted [ft]: above the ground effect and the gear of the shipped light aircraft.
MIN_ALTITUDE_FT = 100.0
#: Largest body rate [rad/s] a trimmed aircraft may reach in 2 s with its surfaces held
#: (:meth:`Trimmed.drift`); above it the trim is not steady in the nonlinear model and a warning says so.
DRIFT_LIMIT_RAD_S = 1e-3


def _jsbsim():
    """The ``jsbsim`` module, or a one-line ConfigError when it is not installed."""
    try:
        import jsbsim
    except ImportError:
        raise ConfigError(
            "JSBSim is not installed: pip install jsbsim (the Python wheel ships the aircraft)"
        ) from None
    return jsbsim


def jsbsim_version() -> str:
    """The installed JSBSim's version (``jsbsim.__version__``)."""
    return str(_jsbsim().__version__)


@contextlib.contextmanager
def quiet_jsbsim() -> Iterator[list[str]]:
    """JSBSim's console messages collected instead of printed, while the block runs (JSBSim's logger is per
    thread).

    Yields
    ------
    list of str
        The messages, one string per line, as JSBSim writes them.
    """
    jsbsim = _jsbsim()
    lines: list[str] = []

    class _Collect(jsbsim.FGLogger):
        def __init__(self) -> None:
            self.part: list[str] = []

        def message(self, message: str) -> None:
            self.part.append(message)

        def flush(self) -> None:
            text = "".join(self.part)
            self.part.clear()
            lines.extend(line.strip() for line in text.splitlines() if line.strip())

    try:
        previous = jsbsim.get_logger()
    except AssertionError:          # no Python logger set yet: JSBSim prints to stdout
        previous = None
    collector = _Collect()
    jsbsim.set_logger(collector)
    try:
        yield lines
    finally:
        collector.flush()
        jsbsim.set_logger(previous if previous is not None else jsbsim.DefaultLogger())


def _root() -> Path:
    return Path(_jsbsim().get_default_root_dir())


def available_aircraft() -> list[str]:
    """Names of the aircraft shipped with the ``jsbsim`` wheel (``aircraft/<name>/<name>.xml``), sorted."""
    folder = _root() / "aircraft"
    try:
        names = [p.name for p in folder.iterdir() if (p / f"{p.name}.xml").is_file()]
    except OSError:
        names = []
    return sorted(names, key=str.lower)


def _check_aircraft(name: str) -> None:
    known = available_aircraft()
    if name in known:
        return
    close = difflib.get_close_matches(name, known, n=3, cutoff=0.6) or \
        [k for k in known if k.lower() == str(name).lower()]
    hint = f"did you mean {', '.join(close)}? " if close else ""
    raise ConfigError(f"unknown JSBSim aircraft {name!r}: {hint}known ones include {', '.join(CHECKED)} "
                      f"({len(known)} shipped with JSBSim {jsbsim_version()}, in {_root() / 'aircraft'})")


def _check_condition(speed_kt: float, altitude_ft: float) -> tuple[float, float]:
    try:
        speed_kt, altitude_ft = float(speed_kt), float(altitude_ft)
    except (TypeError, ValueError):
        raise ConfigError(
            f"speed {speed_kt!r} kt and altitude {altitude_ft!r} ft: expected numbers"
        ) from None
    if not (math.isfinite(speed_kt) and 0.0 < speed_kt <= 2000.0):
        raise ConfigError(f"--speed-kt {speed_kt:g}: expected a true airspeed above 0 and at most 2000 kt")
    if not (math.isfinite(altitude_ft) and MIN_ALTITUDE_FT <= altitude_ft <= 100_000.0):
        raise ConfigError(
            f"--altitude-ft {altitude_ft:g}: expected {MIN_ALTITUDE_FT:g} to 100000 ft above sea level "
            "(JSBSim's terrain is at sea level; near it the gear and ground effect spoil the trim)"
        )
    return speed_kt, altitude_ft


@dataclass(frozen=True)
class TrimPoint:
    """The trimmed flight condition.

    Attributes
    ----------
    aircraft : str
        JSBSim aircraft name.
    speed_kt, altitude_ft : float
        True airspeed [kt] and altitude above sea level [ft] asked for.
    calibrated_kt, mach : float
        Calibrated airspeed [kt] and Mach number at trim.
    alpha_deg, beta_deg, theta_deg, phi_deg : float
        Angle of attack, sideslip, pitch and bank attitude at trim [deg].
    throttle : tuple of float
        Throttle command of each engine [0-1].
    positions_rad : dict
        Surface position property -> value at trim [rad] (:data:`POSITIONS`).
    surfaces_rad : dict
        ``aileron``, ``elevator``, ``rudder`` at trim [rad] (the config's quantities).
    commands : dict
        Normalised commands at trim (``aileron``, ``elevator``, ``rudder``; pitch trim etc. are in the FCS).
    residuals : dict
        Accelerations left by the trim (``udot``, ``vdot``, ``wdot`` [ft/s^2], ``pdot``, ``qdot``, ``rdot``
        [rad/s^2]).
    dt_s : float
        JSBSim's integration step [s] (1/120 s by default).
    version : str
        JSBSim version.
    """

    aircraft: str
    speed_kt: float
    altitude_ft: float
    calibrated_kt: float
    mach: float
    alpha_deg: float
    beta_deg: float
    theta_deg: float
    phi_deg: float
    throttle: tuple[float, ...]
    positions_rad: dict
    surfaces_rad: dict
    commands: dict
    residuals: dict
    dt_s: float
    version: str

    def describe(self) -> str:
        """One line: aircraft, speed, altitude, attitude, throttle, trim surfaces."""
        surfaces = ", ".join(f"{k} {math.degrees(v):+.2f} deg" for k, v in self.surfaces_rad.items())
        throttle = "/".join(f"{t:.3f}" for t in self.throttle)
        return (f"{self.aircraft} at {self.speed_kt:g} kt true ({self.calibrated_kt:.1f} kt calibrated, Mach "
                f"{self.mach:.3f}), {self.altitude_ft:g} ft: alpha {self.alpha_deg:.2f} deg, theta "
                f"{self.theta_deg:.2f} deg, throttle {throttle}, {surfaces}")


class Trimmed:
    """A JSBSim aircraft trimmed straight and level (see the module's conventions), ready to fly.

    Parameters
    ----------
    aircraft : str
        JSBSim aircraft name (e.g. ``c172x``).
    speed_kt : float
        True airspeed [kt].
    altitude_ft : float
        Altitude above sea level [ft].

    Raises
    ------
    ConfigError
        Unknown aircraft (naming a few known ones), a condition out of range, no engine, or a failed trim (one
        line naming aircraft, speed and altitude).
    """

    def __init__(self, aircraft: str, speed_kt: float, altitude_ft: float) -> None:
        jsbsim = _jsbsim()
        speed_kt, altitude_ft = _check_condition(speed_kt, altitude_ft)
        _check_aircraft(aircraft)
        self.aircraft = aircraft
        where = f"{aircraft} at {speed_kt:g} kt true airspeed, {altitude_ft:g} ft"
        # the aircraft's own <output> elements (c172x: a CSV file) write into a directory of ours, removed
        # with us
        self._output_dir = tempfile.mkdtemp(prefix="gap_validation_jsbsim_")
        weakref.finalize(self, shutil.rmtree, self._output_dir, True)
        with quiet_jsbsim() as messages:
            fdm = jsbsim.FGFDMExec(None)
            fdm.set_debug_level(0)
            fdm.set_output_path(self._output_dir)
            if not fdm.load_model(aircraft):
                raise ConfigError(f"JSBSim cannot load aircraft {aircraft!r}" + _reason(messages))
            fdm.disable_output()
            if fdm.get_propulsion().get_num_engines() < 1:
                raise ConfigError(
                    f"JSBSim aircraft {aircraft!r} has no engine: it cannot trim in level flight "
                    f"(known ones include {', '.join(CHECKED)})"
                )
            fdm["ic/h-sl-ft"] = altitude_ft
            fdm["ic/vt-kts"] = speed_kt
            fdm["ic/gamma-deg"] = 0.0
            fdm["ic/phi-deg"] = 0.0
            fdm["ic/psi-true-deg"] = 0.0
            if not fdm.run_ic():
                raise ConfigError(f"JSBSim cannot start {where}" + _reason(messages))
            fdm["propulsion/set-running"] = -1
            try:
                fdm.do_trim(1)
            except jsbsim.TrimFailureError:
                raise ConfigError(
                    f"JSBSim cannot trim {where} (straight and level{_reason(messages, ': ')}); "
                    "try another speed"
                ) from None
            except jsbsim.BaseError as err:
                raise ConfigError(
                    f"JSBSim cannot trim {where}: {str(err).strip() or type(err).__name__}"
                ) from None
        self.fdm = fdm
        self.point = self._point(speed_kt, altitude_ft)
        self._nodes = None

    def _point(self, speed_kt: float, altitude_ft: float) -> TrimPoint:
        fdm = self.fdm
        engines = fdm.get_propulsion().get_num_engines()
        positions = {p: float(fdm[p]) for p in POSITIONS}
        return TrimPoint(
            aircraft=self.aircraft, speed_kt=speed_kt, altitude_ft=altitude_ft,
            calibrated_kt=float(fdm["velocities/vc-kts"]), mach=float(fdm["velocities/mach"]),
            alpha_deg=float(fdm["aero/alpha-deg"]), beta_deg=float(fdm["aero/beta-deg"]),
            theta_deg=float(fdm["attitude/theta-deg"]), phi_deg=float(fdm["attitude/phi-deg"]),
            throttle=tuple(float(fdm[f"fcs/throttle-cmd-norm[{i}]"]) for i in range(engines)),
            positions_rad=positions, surfaces_rad=surface_values(positions),
            commands={s: float(fdm[COMMANDS[s]]) for s in SURFACES},
            residuals={k: float(fdm[p]) for k, p in (
                ("udot", "accelerations/udot-ft_sec2"), ("vdot", "accelerations/vdot-ft_sec2"),
                ("wdot", "accelerations/wdot-ft_sec2"), ("pdot", "accelerations/pdot-rad_sec2"),
                ("qdot", "accelerations/qdot-rad_sec2"), ("rdot", "accelerations/rdot-rad_sec2"))},
            dt_s=float(fdm.get_delta_t()), version=jsbsim_version())

    # -- the FCS
    # ----------------------------------------------------------------------------------------------
    def fcs_gains(self) -> np.ndarray:
        """``G[j, k] = d position_k / d command_j`` at trim [rad per normalised command]: rows aileron,
        elevator, rudder commands; columns :data:`POSITIONS`.

        Measured as FGLinearization perturbs its inputs: the FCS run in trim mode (actuators pass their input
        through) with integration suspended, commands moved by +-1e-4 and +-2e-4, the 5-point difference. The
        commands and the FCS are restored afterwards (the aircraft's state does not move).
        """
        fdm = self.fdm
        h = _COMMAND_STEP
        gains = np.zeros((len(SURFACES), len(POSITIONS)))
        with quiet_jsbsim():
            fdm.suspend_integration()
            fdm.set_trim_status(True)
            try:
                for j, surface in enumerate(SURFACES):
                    base = float(fdm[COMMANDS[surface]])
                    values = {}
                    for k in (1, 2, -1, -2):
                        fdm[COMMANDS[surface]] = base + k * h
                        fdm.run()
                        values[k] = np.array([float(fdm[p]) for p in POSITIONS])
                    fdm[COMMANDS[surface]] = base
                    fdm.run()
                    gains[j] = (8.0 * (values[1] - values[-1]) - (values[2] - values[-2])) / (12.0 * h)
            finally:
                fdm.set_trim_status(False)
                fdm.resume_integration()
        return gains

    def surface_split(self) -> tuple[np.ndarray, np.ndarray]:
        """The FCS's static map at trim as the config's surfaces see it.

        Returns
        -------
        command_gains : ndarray
            Per surface (aileron, elevator, rudder): d surface [rad] / d command [norm].
        split : ndarray
            ``split[j]``: how far each of :data:`POSITIONS` moves per rad of surface j (the ailerons in the
            FCS's ratio; e.g. 1, -1, 0, 0 for symmetric ailerons).

        Raises
        ------
        ConfigError
            A command that does not move its surface at trim (saturated, or not wired), or an FCS that moves
            one surface with another's command (interconnect): not supported.
        """
        gains = self.fcs_gains()
        quantity = np.array([[0.5, -0.5, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
        own = np.array([[1, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=bool)
        command_gains = np.einsum("jk,jk->j", gains, quantity)
        scale = np.max(np.abs(gains))
        for j, surface in enumerate(SURFACES):
            if abs(command_gains[j]) < 1e-6:
                raise ConfigError(
                    f"JSBSim aircraft {self.aircraft!r}: the {surface} command does not move the "
                    f"{surface} at trim ({COMMANDS[surface]} -> d position = 0; saturated or not "
                    "wired to the FCS surface positions)"
                )
            cross = np.abs(gains[j][~own[j]])
            if cross.size and np.max(cross) > 1e-3 * scale:
                other = [POSITIONS[k] for k in range(len(POSITIONS))
                         if not own[j, k] and abs(gains[j, k]) > 1e-3 * scale]
                raise ConfigError(
                    f"JSBSim aircraft {self.aircraft!r}: its FCS moves {', '.join(other)} with the "
                    f"{surface} command (an interconnect): not supported"
                )
        split = gains / command_gains[:, None]
        split[~own] = 0.0
        return command_gains, split

    # -- setting the surfaces directly
    # ------------------------------------------------------------------------
    def hold_surfaces(self) -> None:
        """Take the surface positions away from the FCS: from now on only :meth:`set_positions` moves them.

        The FGFCS position properties (rad and deg) lose their WRITE attribute, so the FCS's actuators (with
        their lags, rate limits, free play) write into nothing; :meth:`set_positions` lifts it for its own
        write.
        """
        jsbsim = _jsbsim()
        manager = self.fdm.get_property_manager()
        self._nodes = [manager.get_node(p) for p in POSITIONS]
        self._write = jsbsim.Attribute.WRITE
        for path in POSITIONS + POSITIONS_DEG:
            manager.get_node(path).set_attribute(self._write, False)

    def set_positions(self, values) -> None:
        """Set the four :data:`POSITIONS` [rad] (after :meth:`hold_surfaces`).

        Parameters
        ----------
        values : sequence of float
            Left aileron, right aileron, elevator, rudder [rad].
        """
        write = self._write
        for node, value in zip(self._nodes, values):
            node.set_attribute(write, True)
            node.set_double_value(float(value))
            node.set_attribute(write, False)

    def position_nodes(self) -> tuple[list, object]:
        """The :data:`POSITIONS` property nodes and the WRITE attribute to lift around a write (after
        :meth:`hold_surfaces`), for a loop that writes only the surfaces that move (:meth:`set_positions`
        writes all four)."""
        return self._nodes, self._write

    def drift(self, seconds: float = 2.0) -> float:
        """Largest body rate [rad/s] the aircraft reaches when flown ``seconds`` with its surfaces held at
        trim.

        A steady trim stays below 1e-4 rad/s (c172x, J3Cub, pa28: about 1e-6); the DHC6's turboprops in JSBSim
        1.3.3 lose half their trimmed thrust within a second and the aircraft rolls away (0.015 rad/s in 2 s).
        Flies this instance: call it on a twin, not on the aircraft to be flown.

        Parameters
        ----------
        seconds : float
            How long to fly [s].
        """
        base = [self.point.positions_rad[p] for p in POSITIONS]
        self.hold_surfaces()
        self.set_positions(base)
        nodes = self.rate_nodes()
        largest = 0.0
        with quiet_jsbsim():
            for _ in range(max(1, int(round(seconds / self.point.dt_s)))):
                self.fdm.run()
                largest = max(largest, *(abs(n.get_double_value()) for n in nodes))
        return largest if math.isfinite(largest) else float("inf")

    def rate_nodes(self) -> list:
        """Property nodes of the body rates p, q, r [rad/s] (``node.get_double_value()``)."""
        manager = self.fdm.get_property_manager()
        return [manager.get_node(p) for p in RATE_PROPERTIES]


def _reason(messages: list[str], prefix: str = " (JSBSim: ") -> str:
    useful = [
        m for m in messages if not m.startswith(("JSBSim Flight Dynamics", "[JSBSim-ML", "JSBSim startup"))
    ]
    if not useful:
        return ""
    text = useful[-1].rstrip(".")
    return f"{prefix}{text}{')' if prefix.startswith(' (') else ''}"


def surface_values(positions: dict) -> dict:
    """The config's surfaces [rad] from the FGFCS positions: aileron = (left - right) / 2, elevator, rudder.

    Parameters
    ----------
    positions : dict
        :data:`POSITIONS` property -> value [rad].
    """
    return {"aileron": 0.5 * (positions[POSITIONS[0]] - positions[POSITIONS[1]]),
            "elevator": positions[POSITIONS[2]], "rudder": positions[POSITIONS[3]]}


def trim(aircraft: str, speed_kt: float, altitude_ft: float) -> Trimmed:
    """The aircraft trimmed straight and level at ``speed_kt`` true airspeed and ``altitude_ft``.

    Parameters
    ----------
    aircraft : str
        JSBSim aircraft name (e.g. ``c172x``, ``J3Cub``, ``DHC6``, ``pa28``).
    speed_kt : float
        True airspeed [kt].
    altitude_ft : float
        Altitude above sea level [ft].
    """
    return Trimmed(aircraft, speed_kt, altitude_ft)


@dataclass
class Linearization:
    """The linear model of a trimmed JSBSim aircraft, surfaces [rad] to body rates [rad/s].

    Attributes
    ----------
    point : TrimPoint
        The trim.
    a, b, c, d : ndarray
        ``x' = A x + B u``, ``y = C x + D u``: states :attr:`states`, inputs :data:`SURFACES` [rad], outputs
        :data:`RATES` [rad/s].
    states : tuple of str
        State names (FGLinearization's, :data:`DROPPED_STATES` left out); units in :attr:`state_units`.
    state_units : tuple of str
    command_gains : ndarray
        FCS gains at trim, d surface [rad] / d command [norm], per surface.
    split : ndarray
        How the four FGFCS positions move per rad of each surface (:meth:`Trimmed.surface_split`).
    consistency : float
        Largest relative difference of the rate rows of ``B`` from the control derivatives measured by setting
        the surfaces directly (:func:`surface_derivatives`).
    drift_rad_s : float
        Largest body rate reached in 2 s flown from the trim with the surfaces held (:meth:`Trimmed.drift`).
    full : dict
        FGLinearization's own result: ``A``, ``B``, ``C``, ``D``, ``x_names``, ``u_names``, ``y_names``,
        ``x_units``.
    """

    point: TrimPoint
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    states: tuple[str, ...]
    state_units: tuple[str, ...]
    command_gains: np.ndarray
    split: np.ndarray
    consistency: float
    drift_rad_s: float = 0.0
    full: dict = field(default_factory=dict)

    @property
    def warnings(self) -> list[str]:
        """One-line warnings about the linearisation (a trim the nonlinear model does not hold)."""
        return drift_warnings(self.point, self.drift_rad_s)

    def poles(self) -> np.ndarray:
        """Eigenvalues of ``A`` [rad/s], sorted by real part."""
        poles = np.linalg.eigvals(self.a)
        return poles[np.lexsort((poles.imag, poles.real))]


def drift_warnings(point: TrimPoint, drift_rad_s: float) -> list[str]:
    """The warning (a list of at most one line) when the trim is not steady (:data:`DRIFT_LIMIT_RAD_S`).

    Parameters
    ----------
    point : TrimPoint
        The trim.
    drift_rad_s : float
        From :meth:`Trimmed.drift`.
    """
    if drift_rad_s <= DRIFT_LIMIT_RAD_S:
        return []
    return [
        f"JSBSim {point.aircraft} does not stay in its trim at {point.speed_kt:g} kt, {point.altitude_ft:g} "
        "ft: "
        f"flown with the surfaces held it reaches {drift_rad_s:.2g} rad/s of body rate within 2 s (its "
        "engine or "
        "another state leaves the trimmed condition); the linearisation describes a point the nonlinear "
        "model "
        "does not hold"
    ]


def surface_derivatives(trimmed: Trimmed, split: np.ndarray, step_rad: float = 1e-3) -> np.ndarray:
    """Control derivatives of the body rates, ``d (p', q', r') / d surface`` [1/s^2], measured by setting the
    surface positions directly (central difference of ``step_rad``, integration suspended).

    Parameters
    ----------
    trimmed : Trimmed
        A trimmed aircraft (its surfaces are held afterwards and returned to trim).
    split : ndarray
        From :meth:`Trimmed.surface_split`.
    step_rad : float
        Surface step [rad].

    Returns
    -------
    ndarray
        3 x 3: rows p, q, r; columns aileron, elevator, rudder.
    """
    fdm = trimmed.fdm
    base = np.array([trimmed.point.positions_rad[p] for p in POSITIONS])
    trimmed.hold_surfaces()
    out = np.zeros((len(RATES), len(SURFACES)))
    with quiet_jsbsim():
        fdm.suspend_integration()
        try:
            for j in range(len(SURFACES)):
                dots = []
                for sign in (1.0, -1.0):
                    trimmed.set_positions(base + sign * step_rad * split[j])
                    for _ in range(3):       # alpha-dot and friends settle on the frozen state
                        fdm.run()
                    dots.append(np.array([float(fdm[p]) for p in _RATE_DOTS]))
                out[:, j] = (dots[0] - dots[1]) / (2.0 * step_rad)
            trimmed.set_positions(base)
            fdm.run()
        finally:
            fdm.resume_integration()
    return out


def linearize(aircraft: str, speed_kt: float, altitude_ft: float) -> Linearization:
    """Trim the aircraft and linearise it with ``jsbsim.FGLinearization``; inputs converted to surface
    radians.

    Parameters
    ----------
    aircraft : str
        JSBSim aircraft name.
    speed_kt : float
        True airspeed [kt].
    altitude_ft : float
        Altitude above sea level [ft].

    Raises
    ------
    ConfigError
        Bad aircraft or condition, a failed trim, or surfaces that cannot be set (see the module's "Check").
    """
    jsbsim = _jsbsim()
    trimmed = trim(aircraft, speed_kt, altitude_ft)
    command_gains, split = trimmed.surface_split()
    with quiet_jsbsim():
        # leaves the FDM re-initialised with dt 0: not flown afterwards
        lin = jsbsim.FGLinearization(trimmed.fdm)
        full = {"A": np.array(lin.system_matrix, float), "B": np.array(lin.input_matrix, float),
                "C": np.array(lin.output_matrix, float), "D": np.array(lin.feedforward_matrix, float),
                "x_names": tuple(lin.x_names), "u_names": tuple(lin.u_names), "y_names": tuple(lin.y_names),
                "x_units": tuple(lin.x_units)}
    names = list(full["x_names"])
    if not np.all(np.isfinite(full["A"])) or not np.all(np.isfinite(full["B"])):
        raise ConfigError(
            f"JSBSim's linearisation of {aircraft} at {speed_kt:g} kt, {altitude_ft:g} ft is not finite"
        )
    keep = [i for i, n in enumerate(names) if n not in DROPPED_STATES]
    try:
        inputs = [list(full["u_names"]).index(_LINEAR_INPUTS[s]) for s in SURFACES]
        rows = [list(full["y_names"]).index(_LINEAR_RATES[r]) for r in RATES]
    except ValueError as err:
        raise ConfigError(
            f"JSBSim's linearisation of {aircraft}: unexpected inputs or outputs ({err})"
        ) from None
    a = full["A"][np.ix_(keep, keep)]
    b = full["B"][np.ix_(keep, inputs)] / command_gains
    c = full["C"][np.ix_(rows, keep)]
    d = full["D"][np.ix_(rows, inputs)] / command_gains
    # the rate rows of B against derivatives measured by setting the surfaces themselves (a fresh trim: the
    # linearisation leaves its FDM re-initialised)
    measured = surface_derivatives(trim(aircraft, speed_kt, altitude_ft), split)
    drift = trim(aircraft, speed_kt, altitude_ft).drift()
    rate_rows = [names.index(_LINEAR_RATES[r]) for r in RATES]
    converted = full["B"][np.ix_(rate_rows, inputs)] / command_gains
    scale = np.max(np.abs(converted), axis=0)
    consistency = float(np.max(np.abs(measured - converted) / np.where(scale > 0, scale, 1.0)))
    if not consistency <= CONSISTENCY_LIMIT:
        raise ConfigError(
            f"JSBSim aircraft {aircraft!r}: setting the surface positions ({', '.join(POSITIONS)}) does "
            f"not reproduce FGLinearization's control derivatives ({100 * consistency:.0f} % apart): its "
            "aerodynamics read other properties; not supported"
        )
    return Linearization(point=trimmed.point, a=a, b=b, c=c, d=d, states=tuple(names[i] for i in keep),
                         state_units=tuple(full["x_units"][i] for i in keep), command_gains=command_gains,
                         split=split, consistency=consistency, drift_rad_s=drift, full=full)


# ------------------------------------------------------------------------------------------------ the config
#: The config's signals (DESIGN.md default topics): surface joint -> input, rate -> IMU field.
#: Topic of the true airspeed (std_msgs/Float64, m/s) in the configs :func:`config_mapping` writes.
AIRSPEED_TOPIC = "/airspeed"
#: Knots to metres per second.
KT_TO_M_S = 0.514444
INPUT_FIELDS = {
    "aileron": "position[aileron]",
    "elevator": "position[elevator]",
    "rudder": "position[rudder]",
}
OUTPUT_FIELDS = {"p": "angular_velocity.x", "q": "angular_velocity.y", "r": "angular_velocity.z"}
#: SISO channels: name -> (surface, rate).
CHANNELS = {"roll": ("aileron", "p"), "pitch": ("elevator", "q"), "yaw": ("rudder", "r")}
#: The MIMO channel: name -> (surfaces, rates).
MIMO_CHANNEL = ("lateral", ("aileron", "rudder"), ("p", "r"))


def _signal(topic: str, field_text: str) -> dict:
    return {"topic": topic, "field": field_text}


def config_mapping(
    lin: Linearization,
    grid: FrequencyGrid = DEFAULT_GRID,
    *,
    surface_topic: str = "/control_surfaces",
    imu_topic: str = "/imu",
    airspeed_topic: str | None = None,
) -> dict:
    """The validation config (DESIGN.md) of the linearisation, as a mapping: SISO ``roll``, ``pitch``, ``yaw``
    and the MIMO ``lateral`` (aileron and rudder to p and r).

    Parameters
    ----------
    lin : Linearization
        From :func:`linearize`.
    grid : FrequencyGrid
        Frequency grid of every channel.
    surface_topic, imu_topic : str
        JointState topic of the surfaces, Imu topic of the rates.
    airspeed_topic : str or None
        Float64 topic of the true airspeed [m/s], each channel's ``airspeed`` with the trim's as ``trim_m_s``
        (the inputs' deviations scaled by the dynamic pressure ratio); None (default): no ``airspeed`` key.
    """
    a, b, c = (_rounded(m) for m in (lin.a, lin.b, lin.c))
    frequencies = {
        "min_rad_s": float(grid.min_rad_s),
        "max_rad_s": float(grid.max_rad_s),
        "count": int(grid.count),
    }
    channels: dict = {}
    airspeed = None if airspeed_topic is None else {
        "topic": airspeed_topic, "field": "data",
        "trim_m_s": float(f"{lin.point.speed_kt * KT_TO_M_S:.6g}")}
    for name, (surface, rate) in CHANNELS.items():
        channels[name] = {
            "input": _signal(surface_topic, INPUT_FIELDS[surface]),
            "output": _signal(imu_topic, OUTPUT_FIELDS[rate]),
            "frequencies": dict(frequencies),
            "model": {"state_space": {"A": a, "B": b, "C": c, "input": SURFACES.index(surface),
                                      "output": RATES.index(rate)}},
        }
        if airspeed is not None:
            channels[name]["airspeed"] = dict(airspeed)
    name, surfaces, rates = MIMO_CHANNEL
    cols = [SURFACES.index(s) for s in surfaces]
    rows = [RATES.index(r) for r in rates]
    channels[name] = {
        "inputs": [_signal(surface_topic, INPUT_FIELDS[s]) for s in surfaces],
        "outputs": [_signal(imu_topic, OUTPUT_FIELDS[r]) for r in rates],
        "frequencies": dict(frequencies),
        "model": {"state_space": {"A": a, "B": [[row[j] for j in cols] for row in b],
                                  "C": [c[i] for i in rows]}},
    }
    if airspeed is not None:
        channels[name]["airspeed"] = dict(airspeed)
    point = lin.point
    return {
        "aircraft": f"JSBSim {point.aircraft}",
        "description": (
            f"FGLinearization of {point.aircraft} at {point.speed_kt:g} kt true airspeed, "
            f"{point.altitude_ft:g} ft (JSBSim {point.version}); surfaces [rad] to body rates "
            "[rad/s]"
        ),
        "channels": channels,
    }


def _rounded(matrix: np.ndarray) -> list[list[float]]:
    return [[float(f"{x:.9g}") + 0.0 for x in row] for row in np.asarray(matrix, float)]


def _flow(value) -> str:
    """A YAML flow value of numbers, strings, lists and mappings."""
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_flow(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_flow(v) for v in value) + "]"
    if isinstance(value, str):
        return f'"{value}"' if any(ch in value for ch in "[]{}:,#") else value
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _matrix_block(name: str, rows: list, indent: str, anchor: str | None = None) -> list[str]:
    head = f"{indent}{name}:" + (f" &{anchor}" if anchor else "")
    return [head] + [f"{indent}  - {_flow(row)}" for row in rows]


def config_text(
    lin: Linearization, grid: FrequencyGrid = DEFAULT_GRID, airspeed_topic: str | None = None
) -> str:
    """The config of :func:`config_mapping` as YAML text with a header comment (aircraft, condition, trim,
    conventions, JSBSim version); the SISO channels share one A, B, C through YAML anchors.

    Parameters
    ----------
    lin : Linearization
        From :func:`linearize`.
    grid : FrequencyGrid
        Frequency grid of every channel.
    airspeed_topic : str, optional
        Each channel's ``airspeed`` on this topic (:func:`config_mapping`).
    """
    data = config_mapping(lin, grid, airspeed_topic=airspeed_topic)
    p = lin.point
    poles = ", ".join(_pole_text(z) for z in lin.poles())
    residual = max(abs(v) for v in p.residuals.values())
    gains = ", ".join(f"{s} {math.degrees(g):.4g} deg" for s, g in zip(SURFACES, lin.command_gains))
    header = [
        f"# JSBSim {p.aircraft}, linearised by JSBSim {p.version} (jsbsim.FGLinearization) with gap-validate "
        "linearize",
        f"#   condition: {p.speed_kt:g} kt TRUE airspeed ({p.calibrated_kt:.1f} kt calibrated, Mach "
        f"{p.mach:.3f}), "
        f"{p.altitude_ft:g} ft above sea level,",
        "#              straight and level (flight path 0, wings level, heading north), engines running",
        f"#   trim (do_trim full): alpha {p.alpha_deg:.3f} deg, theta {p.theta_deg:.3f} deg, "
        f"beta {p.beta_deg:.3f} deg, throttle {'/'.join(f'{t:.4f}' for t in p.throttle)},",
        "#     surfaces "
        + ", ".join(f"{k} {v:+.5f} rad" for k, v in p.surfaces_rad.items())
        + f"; largest residual acceleration {residual:.2g}",
        "#   inputs: surface deflections [rad]: aileron = (fcs/left-aileron-pos-rad - "
        "fcs/right-aileron-pos-rad)/2,",
        "#     elevator = fcs/elevator-pos-rad, rudder = fcs/rudder-pos-rad (deviations from trim in the "
        "model; the",
        "#     logged JointState positions are absolute). FGLinearization's inputs are normalised commands: "
        "its B was",
        f"#     divided by the FCS gains at trim (d surface / d command: {gains}). FCS actuator dynamics",
        "#     (lags, rate limits, free play) are NOT in the model (FGLinearization runs the FCS in trim "
        "mode);",
        "#     gap-validate simulate --jsbsim sets the surfaces directly, so they are not in its flights "
        "either.",
        "#   outputs: body rates p, q, r [rad/s] (velocities/p-rad_sec ...), IMU angular_velocity.x/y/z "
        "(FRD).",
        *(
            [
                f"#   airspeed: true airspeed [m/s] on {airspeed_topic} (std_msgs/Float64); the inputs' "
                "deviations from",
                f"#     trim are scaled by (airspeed / {p.speed_kt * KT_TO_M_S:.6g})^2, the dynamic pressure "
                "relative to the",
                "#     trim's (the control power; the modes move with speed too).",
            ]
            if airspeed_topic
            else []
        ),
        f"#   states: {', '.join(f'{s} [{u}]' for s, u in zip(lin.states, lin.state_units))}",
        "#     (FGLinearization's Psi, Latitude, Longitude, Alt left out: they do not feed back into the "
        "rates)",
        f"#   poles [rad/s]: {poles}",
        f"#   check: rate rows of B vs surface-set control derivatives agree to "
        f"{100 * lin.consistency:.2g} %",
        f"#   grid {grid.min_rad_s:g}-{grid.max_rad_s:g} rad/s: surfaces and IMU at >= 20 Hz resolve it "
        "(the estimator uses up to a quarter of a stream's rate).",
    ] + [f"#   WARNING: {w}" for w in lin.warnings]
    lines = header + [f"aircraft: {_flow(data['aircraft'])}", f"description: {_flow(data['description'])}",
                      "channels:"]
    first = True
    for name, ch in data["channels"].items():
        lines.append(f"  {name}:")
        if "input" in ch:
            lines += [f"    input:  {_flow(ch['input'])}", f"    output: {_flow(ch['output'])}"]
        else:
            lines.append("    inputs:")
            lines += [f"      - {_flow(s)}" for s in ch["inputs"]]
            lines.append("    outputs:")
            lines += [f"      - {_flow(s)}" for s in ch["outputs"]]
        if "airspeed" in ch:
            lines.append(f"    airspeed: {_flow(ch['airspeed'])}")
        lines.append(f"    frequencies: {_flow(ch['frequencies'])}")
        ss = ch["model"]["state_space"]
        lines += ["    model:", "      state_space:"]
        if "input" in ss:
            if first:
                lines += _matrix_block("A", ss["A"], "        ", "A")
                lines += _matrix_block("B", ss["B"], "        ", "B")
                lines += _matrix_block("C", ss["C"], "        ", "C")
                first = False
            else:
                lines += ["        A: *A", "        B: *B", "        C: *C"]
            lines += [f"        input: {ss['input']}        # {SURFACES[ss['input']]}",
                      f"        output: {ss['output']}       # {RATES[ss['output']]}"]
        else:
            lines.append("        A: *A")
            lines += _matrix_block("B", ss["B"], "        ")
            lines += _matrix_block("C", ss["C"], "        ")
    return "\n".join(lines) + "\n"


def _pole_text(z: complex) -> str:
    if abs(z.imag) < 1e-9:
        return f"{z.real:.4g}"
    return f"{z.real:.4g}{z.imag:+.4g}j"


def write_config(lin: Linearization, path: str | os.PathLike, grid: FrequencyGrid = DEFAULT_GRID,
                 airspeed_topic: str | None = None) -> Path:
    """Write :func:`config_text` to ``path`` atomically.

    Parameters
    ----------
    lin : Linearization
        From :func:`linearize`.
    path : path
        The config file.
    grid : FrequencyGrid
        Frequency grid of every channel.
    airspeed_topic : str, optional
        Each channel's ``airspeed`` on this topic (:func:`config_mapping`).

    Raises
    ------
    DataError
        When the file cannot be written.
    """
    from gap_validation.core.atomic import atomic_write_text

    path = Path(path)
    try:
        atomic_write_text(path, config_text(lin, grid, airspeed_topic))
    except OSError as err:
        raise DataError(f"{path}: cannot write config ({err.strerror or err})") from None
    return path
