"""JSBSim wrapper: the only module that touches ``fdm[...]``.

It loads an aircraft from the project's ``aircraft/`` folder (whatever the
working directory), sets initial conditions from the world ENU frame, trims
with JSBSim's own trim, applies actuator commands and returns the truth state
in the project's frames (docs/design/architecture.md, "Frames and conventions").

The world ENU frame maps to JSBSim's WGS84 geodetic coordinates through a
``frames.GeoOrigin`` anchored on the sea surface: z is the altitude above sea
level, so the sea is exactly z = 0.
"""
from __future__ import annotations

import hashlib
import math
import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fwsim import AIRCRAFT_DIR
from fwsim.interface.frames import GeoOrigin, enu_from_ned
from fwsim.interface.messages import ActuatorCommand, AirframeState

# JSBSim prints a banner on construction unless told otherwise.
os.environ.setdefault("JSBSIM_DEBUG", "0")
import jsbsim  # noqa: E402

FT = 0.3048  # metres per foot
G0_M_S2 = 9.80665


class AirframeError(RuntimeError):
    """The aircraft cannot be loaded, trimmed or has diverged."""


@dataclass(frozen=True, slots=True)
class TrimResult:
    """What JSBSim's trim found: surfaces (normalised) and throttle."""

    ok: bool
    throttle_norm: float
    elevator_norm: float
    aileron_norm: float
    rudder_norm: float
    alpha_rad: float
    message: str = ""


def aircraft_file(name: str, aircraft_dir: Path = AIRCRAFT_DIR) -> Path:
    """Path of an aircraft's JSBSim XML; a clear error when it does not exist."""
    path = Path(aircraft_dir) / name / f"{name}.xml"
    if not path.is_file():
        known = sorted(p.name for p in Path(aircraft_dir).iterdir() if (p / f"{p.name}.xml").is_file())
        raise AirframeError(f"aircraft '{name}' not found in {aircraft_dir} (known: {', '.join(known)})")
    return path


def aircraft_hash(name: str, aircraft_dir: Path = AIRCRAFT_DIR) -> str:
    """SHA-256 over the aircraft's folder (XML, engines, parameter file), for the log."""
    folder = aircraft_file(name, aircraft_dir).parent
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        if p.is_file() and "__pycache__" not in p.parts:
            h.update(p.relative_to(folder).as_posix().encode())
            h.update(p.read_bytes())
    return h.hexdigest()


#: JSBSim properties read each tick (state()) and written (step()), in this order
_STATE = ("position/lat-geod-rad", "position/long-gc-rad", "position/h-sl-meters",
          "velocities/v-north-fps", "velocities/v-east-fps", "velocities/v-down-fps",
          "attitude/phi-rad", "attitude/theta-rad", "attitude/psi-rad",
          "velocities/p-rad_sec", "velocities/q-rad_sec", "velocities/r-rad_sec",
          "accelerations/a-pilot-x-ft_sec2", "accelerations/a-pilot-y-ft_sec2", "accelerations/a-pilot-z-ft_sec2",
          "fcs/aileron-pos-rad", "fcs/elevator-pos-rad", "fcs/rudder-pos-rad",
          "velocities/vt-fps", "aero/alpha-rad", "aero/beta-rad", "fcs/motor-throttle-norm")
_COMMANDS = ("fcs/aileron-cmd-norm", "fcs/elevator-cmd-norm", "fcs/rudder-cmd-norm", "fcs/throttle-cmd-norm")


@contextmanager
def _stdout_to(lines: list[str]):
    """What is written to file descriptor 1 inside the block (JSBSim's C++ output, which its debug level does
    not silence: "Sorry, udot doesn't appear to be trimmable"), taken off the terminal and appended to
    ``lines`` (stripped, empty lines dropped) at the end of the block."""
    import ctypes
    import sys
    import tempfile
    try:
        libc = ctypes.CDLL(None)
        sys.stdout.flush()
        libc.fflush(None)
        saved = os.dup(1)
    except (OSError, AttributeError, ValueError):  # no C library to flush, or no descriptor 1: left alone
        yield
        return
    with tempfile.TemporaryFile() as f:
        os.dup2(f.fileno(), 1)
        try:
            yield
        finally:
            libc.fflush(None)
            os.dup2(saved, 1)
            os.close(saved)
            f.seek(0)
            lines += [ln.strip() for ln in f.read().decode("utf-8", "replace").splitlines() if ln.strip()]


class Airframe:
    """One JSBSim aircraft flying in the world ENU frame."""

    def __init__(self, aircraft: str = "fwuav", *, dt_s: float = 1.0 / 120.0,
                 origin: GeoOrigin | None = None, wind_enu_m_s=(0.0, 0.0, 0.0),
                 aircraft_dir: Path = AIRCRAFT_DIR):
        self.name = aircraft
        self.dt_s = float(dt_s)
        self.origin = origin or GeoOrigin(0.0, 0.0)
        xml = aircraft_file(aircraft, aircraft_dir)
        fdm = jsbsim.FGFDMExec(None)
        fdm.set_debug_level(0)
        fdm.set_aircraft_path(str(Path(aircraft_dir)))
        fdm.set_engine_path(str(xml.parent / "engine"))
        fdm.set_systems_path(str(xml.parent / "systems"))
        if not fdm.load_model(aircraft):
            raise AirframeError(f"JSBSim could not load aircraft '{aircraft}' from {xml}")
        fdm.set_dt(self.dt_s)
        self._fdm = fdm
        self._getters = None  # property nodes' getters of _STATE, made on the first state() (after loading)
        self._setters = None
        self._mass_kg = fdm["inertia/mass-slugs"] * 14.5939029
        self._wind_enu = np.asarray(wind_enu_m_s, dtype=float)
        self.trim: TrimResult | None = None
        self.t_s = 0.0

    # ------------------------------------------------------------------ set-up
    @property
    def mass_kg(self) -> float:
        return self._mass_kg

    @staticmethod
    def jsbsim_version() -> str:
        return jsbsim.__version__

    def reset(self, pos_enu_m, airspeed_m_s: float, heading_ned_rad: float,
              flight_path_rad: float = 0.0, trim: bool = True) -> AirframeState:
        """Place the aircraft and (by default) trim it with JSBSim's trim.

        Straight flight at ``airspeed_m_s`` along ``heading_ned_rad`` (true
        heading, clockwise from North) on the flight-path angle
        ``flight_path_rad`` (positive climbing). Raises AirframeError when the
        trim fails (with JSBSim's reason) so a scenario never starts out of
        balance without saying so.
        """
        fdm = self._fdm
        lat, lon, alt = self.origin.geodetic_from_enu(np.asarray(pos_enu_m, dtype=float))
        fdm["ic/lat-geod-rad"] = lat
        fdm["ic/long-gc-rad"] = lon
        fdm["ic/h-sl-ft"] = alt / FT
        fdm["ic/terrain-elevation-ft"] = 0.0
        for axis in ("north", "east", "down"):  # trimmed in still air; the wind comes after (below)
            fdm[f"atmosphere/wind-{axis}-fps"] = 0.0
        fdm["ic/vt-fps"] = airspeed_m_s / FT
        fdm["ic/psi-true-rad"] = heading_ned_rad
        fdm["ic/gamma-rad"] = flight_path_rad
        for prop in ("fcs/aileron-cmd-norm", "fcs/elevator-cmd-norm", "fcs/rudder-cmd-norm",
                     "fcs/pitch-trim-cmd-norm", "fcs/roll-trim-cmd-norm", "fcs/yaw-trim-cmd-norm"):
            fdm[prop] = 0.0
        fdm["fcs/throttle-cmd-norm"] = 0.3
        if not fdm.run_ic():
            raise AirframeError("JSBSim rejected the initial conditions")
        fdm["propulsion/set-running"] = -1
        self.t_s = 0.0
        if trim:
            said: list[str] = []
            try:
                with _stdout_to(said):  # JSBSim's trim prints why it failed; that goes into the error instead
                    fdm["simulation/do_simple_trim"] = 1  # full trim
            except Exception as exc:  # JSBSim raises a generic error
                why = "; ".join(line.removeprefix("Sorry, ") for line in said)
                raise AirframeError(
                    f"JSBSim trim failed at {airspeed_m_s:.1f} m/s, flight path "
                    f"{math.degrees(flight_path_rad):.1f} deg, altitude {alt:.0f} m: {exc}"
                    + (f" ({why})" if why else "")) from exc
            self.trim = TrimResult(
                ok=True,
                throttle_norm=fdm["fcs/throttle-cmd-norm"],
                elevator_norm=fdm["fcs/pitch-trim-cmd-norm"],
                aileron_norm=fdm["fcs/roll-trim-cmd-norm"],
                rudder_norm=fdm["fcs/yaw-trim-cmd-norm"],
                alpha_rad=fdm["aero/alpha-rad"],
            )
        else:
            self.trim = TrimResult(False, fdm["fcs/throttle-cmd-norm"], 0.0, 0.0, 0.0,
                                   fdm["aero/alpha-rad"], "not trimmed")
        if np.any(self._wind_enu != 0.0):
            self._add_wind()
        return self.state()

    def _add_wind(self) -> None:
        """Put the trimmed aircraft into the scenario's wind with its air-relative state unchanged.

        JSBSim's run_ic() sets the atmosphere's wind from the initial conditions': set on the atmosphere
        before it, the wind was zeroed and did nothing. Given to the initial conditions (JSBSim ignores
        writes to ic/vw-north-fps and ic/vw-east-fps; ic/vw-mag-fps with ic/vw-dir-deg take), the
        initial airspeed came out at 6 m/s with 180 deg of alpha and the trim failed. So: trim in still
        air, restart from the same attitude with the ground velocity plus the wind, then set the wind on
        the atmosphere.
        """
        fdm = self._fdm
        wind_ned = np.array([self._wind_enu[1], self._wind_enu[0], -self._wind_enu[2]])
        v_ned = np.array([fdm["velocities/v-north-fps"], fdm["velocities/v-east-fps"],
                          fdm["velocities/v-down-fps"]]) + wind_ned / FT
        fdm["ic/phi-rad"] = fdm["attitude/phi-rad"]
        fdm["ic/theta-rad"] = fdm["attitude/theta-rad"]
        fdm["ic/psi-true-rad"] = fdm["attitude/psi-rad"]
        fdm["ic/vn-fps"], fdm["ic/ve-fps"], fdm["ic/vd-fps"] = (float(x) for x in v_ned)
        fdm["ic/vw-mag-fps"] = math.hypot(wind_ned[0], wind_ned[1]) / FT
        fdm["ic/vw-dir-deg"] = math.degrees(math.atan2(wind_ned[1], wind_ned[0]))
        if not fdm.run_ic():
            raise AirframeError("JSBSim rejected the initial conditions with the wind")
        for axis, w in zip(("north", "east", "down"), wind_ned):
            fdm[f"atmosphere/wind-{axis}-fps"] = w / FT

    # ------------------------------------------------------------------ stepping
    def step(self, act: ActuatorCommand) -> AirframeState:
        """Apply actuator commands and advance JSBSim by one dt."""
        set_ail, set_elev, set_rud, set_thr = self._setters or self._commands()
        set_ail(act.aileron_norm)
        set_elev(act.elevator_norm)
        set_rud(act.rudder_norm)
        set_thr(act.throttle_norm)
        if not self._fdm.run():
            raise AirframeError("JSBSim stopped running")
        self.t_s += self.dt_s
        return self.state()

    def _commands(self):
        """Setters of the four command properties (JSBSim's property nodes, looked up once)."""
        if self._setters is None:
            pm = self._fdm.get_property_manager()
            self._setters = tuple(pm.get_node(n).set_double_value for n in _COMMANDS)
        return self._setters

    def state(self) -> AirframeState:
        """The truth state in the project's frames (every property read through its node, once per call)."""
        if self._getters is None:
            pm = self._fdm.get_property_manager()
            self._getters = tuple(pm.get_node(n).get_double_value for n in _STATE)
        (lat, lon, h, vn, ve, vd, phi, theta, psi, p, q, r, fx, fy, fz, ail, elev, rud, vt, alpha, beta,
         thr) = [g() for g in self._getters]
        if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(h) and math.isfinite(phi)
                and math.isfinite(theta) and math.isfinite(psi) and math.isfinite(vt)):
            raise AirframeError(f"JSBSim state diverged at t = {self.t_s:.3f} s (non-finite position or attitude)")
        # AirframeState's fields in order (positional: a quarter of the constructor's cost at 120 Hz); the height
        # above the sea is the position's z, which enu_from_geodetic takes straight from h
        return AirframeState(
            self.t_s,  # t_s
            self.origin.enu_from_geodetic(lat, lon, h),  # pos_enu_m
            np.array([ve * FT, vn * FT, -(vd * FT)]),  # vel_enu_m_s: enu_from_ned of the NED velocity in m/s
            np.array([phi, theta, psi]),  # euler_ned_rad
            np.array([p, q, r]),  # body_rates_frd_rad_s
            vt * FT,  # airspeed_m_s
            alpha,  # alpha_rad
            beta,  # beta_rad
            np.array([fx * FT, fy * FT, fz * FT]),  # specific_force_frd_m_s2
            thr,  # throttle_norm
            np.array([ail, elev, rud]),  # surfaces_rad
            h,  # height_above_sea_m
        )

    def set_turbulence(self, turb_type: int, severity: int, wind_at_20ft_m_s: float, seed: int) -> None:
        """Switch on JSBSim's own turbulence (FGWinds: 3 Milspec, 4 Tustin; severity = its probability-of-
        exceedance curve 1..7) with its own random stream seeded by ``seed``. Call after the trim."""
        fdm = self._fdm
        fdm["atmosphere/randomseed"] = int(seed)
        fdm["atmosphere/turb-type"] = int(turb_type)
        fdm["atmosphere/turbulence/milspec/windspeed_at_20ft_AGL-fps"] = float(wind_at_20ft_m_s) / FT
        fdm["atmosphere/turbulence/milspec/severity"] = int(severity)

    def cosine_gust(self, velocity_enu_m_s, duration_s: float) -> None:
        """Start JSBSim's 1 - cos gust in the local frame: up to ``velocity_enu_m_s`` at half ``duration_s``,
        none again at its end."""
        fdm = self._fdm
        e, n, u = (float(v) for v in velocity_enu_m_s)
        peak = math.sqrt(e * e + n * n + u * u)
        fdm["atmosphere/cosine-gust/startup-duration-sec"] = 0.5 * duration_s
        fdm["atmosphere/cosine-gust/steady-duration-sec"] = 0.0
        fdm["atmosphere/cosine-gust/end-duration-sec"] = 0.5 * duration_s
        fdm["atmosphere/cosine-gust/magnitude-ft_sec"] = peak / FT
        fdm["atmosphere/cosine-gust/frame"] = 3  # local north-east-down
        fdm["atmosphere/cosine-gust/X-velocity-ft_sec"] = n / peak
        fdm["atmosphere/cosine-gust/Y-velocity-ft_sec"] = e / peak
        fdm["atmosphere/cosine-gust/Z-velocity-ft_sec"] = -u / peak
        fdm["atmosphere/cosine-gust/start"] = 1

    def air(self) -> tuple[np.ndarray, np.ndarray]:
        """(the air's velocity: steady wind + gusts + turbulence, the turbulence alone), world ENU, m/s."""
        fdm = self._fdm
        total = [fdm[f"atmosphere/total-wind-{a}-fps"] for a in ("north", "east", "down")]
        turb = [fdm[f"atmosphere/turb-{a}-fps"] for a in ("north", "east", "down")]
        return enu_from_ned(np.array(total) * FT), enu_from_ned(np.array(turb) * FT)

    def property(self, name: str) -> float:
        """Read any JSBSim property (for diagnostics and tests)."""
        return self._fdm[name]
