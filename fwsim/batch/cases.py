"""Generated scenarios: the terminal phase flown from the loiter ring, for sweeps and tests.

:func:`terminal_case` starts the UAV on the Phase 2 loiter circle (R, H) around
the ship's start point, going clockwise round the moving ship (ship on its
right; heading such that the motion relative to the ship runs along the
circle), ``arc_deg`` of arc before the bearing to the ship equals the impact
heading, with the gimbal on the ship. The lock comes at once, the NMPC loiter holds the ring, and the
logged 2 -> 3 switch fires inside its approach window about 10 s in; the dive
takes ~20-25 s. Everything else (UKF, ship model, BPNG gains) is the paper
mission's, so a case isolates the terminal phase of the full chain in ~35 s of
flight instead of ~140 s.
"""
from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import yaml

from fwsim import SCENARIO_DIR
from fwsim.interface.frames import dcm_enu_from_frd, pan_tilt_pointing_at

__all__ = ["terminal_case", "sweep_cases", "sweep_spec", "sweep_rows", "case_line", "CASE_KEYS", "SWEEP_SPEC"]


def _orbit_heading_deg(bearing_rad: float, ship_heading_deg: float, ship_speed_m_s: float,
                       airspeed_m_s: float, wind_enu_m_s=(0.0, 0.0, 0.0)) -> float:
    """Heading (deg, clockwise from North) that moves the UAV clockwise around the moving ship, relative
    to it along the circle (no radial part): the steady loiter the NMPC would settle into. Without it a
    fast ship's loiter can settle into the other orbit, which goes the opposite way round relative to the
    ship (both keep the radius), and reaches the approach window a lap later."""
    t_hat = np.array([math.sin(bearing_rad - math.pi / 2), math.cos(bearing_rad - math.pi / 2)])  # ship on the right
    hs = math.radians(ship_heading_deg)
    # the air-relative motion: V_air = (V_ship - wind) + w t_hat, |V_air| = airspeed; the heading is V_air's
    vs = ship_speed_m_s * np.array([math.sin(hs), math.cos(hs)]) - np.asarray(wind_enu_m_s, float)[:2]
    along = float(vs @ t_hat)
    w = -along + math.sqrt(max(along**2 - float(vs @ vs) + airspeed_m_s**2, 0.0))  # V_uav = V_ship + w t_hat
    v = vs + w * t_hat
    return math.degrees(math.atan2(v[0], v[1]))


def terminal_case(theta_f_deg: float, psi_f_deg: float, ship_heading_deg: float, ship_speed_m_s: float,
                  seed: int = 1, arc_deg: float = 25.0, radius_m: float = 500.0, altitude_m: float = 500.0,
                  duration_s: float = 90.0, airspeed_m_s: float = 22.0, wind_enu_m_s=None) -> dict:
    """A scenario (as a dict, ready for ``yaml.safe_dump`` / ``parse_scenario``) for one terminal case.
    ``wind_enu_m_s``: the world's wind, which the start heading then allows for (none: the scenario's)."""
    d = copy.deepcopy(yaml.safe_load((SCENARIO_DIR / "paper_mission.yaml").read_text()))
    b0 = math.radians(psi_f_deg - arc_deg)  # bearing UAV -> ship at the start; clockwise it grows to psi_f
    pos = np.array([-radius_m * math.sin(b0), -radius_m * math.cos(b0), altitude_m])
    if wind_enu_m_s is not None:
        d.setdefault("world", {})["wind_enu_m_s"] = [float(x) for x in wind_enu_m_s]
    wind = d.get("world", {}).get("wind_enu_m_s", [0.0, 0.0, 0.0])
    heading_deg = _orbit_heading_deg(b0, ship_heading_deg, ship_speed_m_s, airspeed_m_s, wind)
    euler = np.array([0.0, 0.0, math.radians(heading_deg)])
    mount = np.array(d["camera"]["gimbal"]["mount_offset_frd_m"], dtype=float)
    R = dcm_enu_from_frd(euler)
    pan, tilt = pan_tilt_pointing_at(R.T @ (np.zeros(3) - (pos + R @ mount)))
    d.update(name=f"terminal_th{theta_f_deg:+.0f}_psi{psi_f_deg:.0f}_ship{ship_heading_deg:.0f}at{ship_speed_m_s:g}",
             description="terminal phase from the loiter ring (fwsim.batch.cases.terminal_case)", seed=int(seed),
             duration_s=float(duration_s))
    d["initial"] = {"pos_enu_m": [round(float(x), 3) for x in pos], "airspeed_m_s": float(airspeed_m_s),
                    "heading_deg": round(heading_deg % 360.0, 4)}
    d["target"] = {"initial_pos_enu_m": [0.0, 0.0, 0.0], "heading_deg": float(ship_heading_deg),
                   "speed_m_s": float(ship_speed_m_s), "motion": {"model": "constant_velocity"}}
    d["camera"]["gimbal"] = dict(d["camera"]["gimbal"], initial_pan_rad=round(pan, 4), initial_tilt_rad=round(tilt, 4))
    c = d["controllers"]
    c.pop("initial_path", None)
    c["nmpc"] = dict(c["nmpc"], radius_m=float(radius_m), altitude_m=float(altitude_m))
    c["switch"] = dict(c["switch"], dwell_s=5.0, min_loiter_s=5.0)
    c["bpng"] = dict(c["bpng"], impact_flight_path_deg=float(theta_f_deg), impact_heading_deg=float(psi_f_deg))
    return d


#: metrics of a terminal case that the sweep reports
CASE_KEYS = ["hit", "miss_distance_m", "impact_fpa_error_deg", "impact_heading_error_deg", "switch_time_s",
             "impact_time_s", "estimator_pos_err_max_after_convergence_m", "target_in_fov_fraction_after_lock"]
#: the sweep's batch spec (its cases are the terminal_case arguments)
SWEEP_SPEC = SCENARIO_DIR / "batches" / "terminal_sweep.yaml"
_ARGS = ("theta_f_deg", "psi_f_deg", "ship_heading_deg", "ship_speed_m_s")


def sweep_cases(quick: bool = False) -> list[tuple[float, float, float, float]]:
    """(theta_f, psi_f, ship heading, ship speed) of the terminal sweep (:data:`SWEEP_SPEC`; ``quick``: every
    fifth)."""
    cases = yaml.safe_load(SWEEP_SPEC.read_text())["runs"][0]["cases"]
    out = [tuple(float(c[k]) for k in _ARGS) for c in cases]
    return out[::5] if quick else out


def sweep_spec(out_dir, seed: int = 1, quick: bool = False, overrides: dict | None = None) -> Path:
    """The sweep's batch spec for this seed (``quick``: every fifth case), with ``overrides`` set on every case,
    written into ``out_dir``; its path. A wind override goes to :func:`terminal_case` (its start heading allows
    for the wind)."""
    spec = yaml.safe_load(SWEEP_SPEC.read_text())
    entry = spec["runs"][0]
    overrides = dict(overrides or {})
    wind = overrides.pop("world.wind_enu_m_s", None)
    if quick:
        entry["cases"] = entry["cases"][::5]
    if wind is not None:
        entry["args"] = {**entry.get("args", {}), "wind_enu_m_s": wind}
    entry["seeds"] = [int(seed)]
    if overrides:
        entry["set"] = overrides
    spec["name"] = f"terminal_sweep_seed{seed}" + ("_quick" if quick else "")
    path = Path(out_dir) / f"{spec['name']}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def sweep_rows(batch_rows: list[dict], bounds=(3.0, 3.0)) -> list[dict]:
    """The sweep's rows from the batch summary rows: the case, how the run ended, the :data:`CASE_KEYS`
    metrics and ``ok`` (hit, miss and both impact-angle errors within ``bounds``: metres, degrees)."""
    rows = []
    for r in batch_rows:
        row = {k: r.get(f"case.{k}") for k in _ARGS}
        row.update(wall_s=r.get("wall_time_s"), end=r.get("reason"), log=r.get("log"))
        row.update({k: math.nan if r.get(k) is None else float(r[k]) for k in CASE_KEYS})  # None: no value
        row["ok"] = bool(r.get("status") == "completed" and row["hit"] == 1.0 and row["miss_distance_m"] <= bounds[0]
                         and abs(row["impact_fpa_error_deg"]) <= bounds[1]
                         and abs(row["impact_heading_error_deg"]) <= bounds[1])
        rows.append(row)
    return rows


def case_line(row: dict) -> str:
    """One readable line for a sweep row."""
    return (f"{'ok ' if row['ok'] else 'BAD'} theta_f {row['theta_f_deg']:+4.0f} psi_f {row['psi_f_deg']:3.0f} "
            f"ship {row['ship_heading_deg']:3.0f} deg @ {row['ship_speed_m_s']:4.1f} m/s | hit {row['hit']:.0f} "
            f"miss {row['miss_distance_m']:7.2f} m  fpa err {row['impact_fpa_error_deg']:+6.2f}  "
            f"heading err {row['impact_heading_error_deg']:+6.2f} deg | {row['end']}")
