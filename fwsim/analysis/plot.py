"""Figures of one run, drawn from its log (PNG, matplotlib without a display).

Every figure is a function registered with :func:`figure`, naming the topics
it needs; :func:`plot_log` draws those whose topics are in the log and
reports the others as skipped with the reason. A figure can also skip itself
on the data (``raise SkipFigure("no accel-mode ticks")``). To add one of the
paper's figures::

    @figure("tilt_angle", needs=(topics.GIMBAL_STATE,), title="Camera tilt angle")
    def _tilt_angle(log: RunLog) -> Figure:
        fig, axes = _figure(1)
        ...
        return fig

Figures are built with ``matplotlib.figure.Figure`` directly (no pyplot, no
global backend), so plotting works in any process and thread.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

from fwsim.interface import topics
from fwsim.log import RunLog, read_log
from fwsim.log.truth import interp_at

PHASE_COLOURS = ("tab:blue", "tab:orange", "tab:red", "tab:green", "tab:purple", "tab:brown", "tab:pink",
                 "tab:gray", "tab:olive")
DPI = 110


class SkipFigure(Exception):
    """Raised by a figure function when the log has the topics but not the data it needs."""


@dataclass(frozen=True)
class FigureSpec:
    name: str  # file name without .png
    needs: tuple[str, ...]  # topics that must be in the log (with messages)
    title: str
    draw: Callable[[RunLog], Figure]


FIGURES: dict[str, FigureSpec] = {}


def figure(name: str, needs: tuple[str, ...], title: str):
    """Register a figure function ``draw(log) -> Figure``."""
    def register(fn: Callable[[RunLog], Figure]) -> Callable[[RunLog], Figure]:
        FIGURES[name] = FigureSpec(name, tuple(needs), title, fn)
        return fn
    return register


@dataclass
class PlotResult:
    written: list[Path] = field(default_factory=list)
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (figure, why)
    failed: list[tuple[str, str]] = field(default_factory=list)  # (figure, error)


def plot_log(log: RunLog | str | Path, out_dir: str | Path, only: list[str] | None = None) -> PlotResult:
    """Draw every registered figure (or ``only`` these) into ``out_dir/<name>.png``.

    A figure whose topics are missing, or that raises :class:`SkipFigure`, is
    skipped with the reason; one that raises anything else is reported in
    ``failed`` and the others are still drawn.
    """
    if not isinstance(log, RunLog):
        log = read_log(log)
    unknown = [n for n in only or [] if n not in FIGURES]
    if unknown:
        raise ValueError(f"unknown figure(s) {unknown}; known: {list(FIGURES)}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    res = PlotResult()
    for spec in FIGURES.values():
        if only and spec.name not in only:
            continue
        missing = [t for t in spec.needs if not log.topics.get(t)]
        if missing:
            res.skipped.append((spec.name, f"no {', '.join(missing)} in this log"))
            continue
        try:
            fig = spec.draw(log)
        except SkipFigure as exc:
            res.skipped.append((spec.name, str(exc)))
            continue
        except Exception as exc:  # noqa: BLE001 - one broken figure does not stop the others
            res.failed.append((spec.name, f"{type(exc).__name__}: {exc}"))
            continue
        fig.suptitle(f"{spec.title} — {_run_label(log)}", fontsize=10)
        path = out_dir / f"{spec.name}.png"
        fig.savefig(path, dpi=DPI)
        res.written.append(path)
    return res


def figure_names() -> list[str]:
    return list(FIGURES)


# -- helpers ----------------------------------------------------------------

def _with_breaks(t: np.ndarray, rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t, heading deg) with NaN inserted at the wraps (see _heading_deg)."""
    deg = np.mod(np.degrees(np.asarray(rad, float)), 360.0)
    if deg.size < 2:
        return t, deg
    at = np.nonzero(np.abs(np.diff(deg)) > 180.0)[0] + 1
    return np.insert(np.asarray(t, float), at, np.nan), np.insert(deg, at, np.nan)


def _clip_transient(ax, *series: np.ndarray, margin: float = 0.3) -> None:
    """Y limits from the 1st-99th percentile of the series (the lock transient, whose 2-sigma bound can reach
    hundreds of metres, would otherwise flatten the converged error); says so on the axis when it clips."""
    vals = np.concatenate([np.ravel(np.asarray(s, float)) for s in series]) if series else np.zeros(0)
    vals = vals[np.isfinite(vals)]
    if vals.size < 10:
        return
    lo, hi = np.percentile(vals, [1.0, 99.0])
    pad = margin * max(hi - lo, 1e-6)
    lo, hi = lo - pad, hi + pad
    if vals.min() < lo or vals.max() > hi:
        ax.set_ylim(lo, hi)
        ax.text(0.99, 0.97, f"axis clipped (extremes {vals.min():.3g} .. {vals.max():.3g})", transform=ax.transAxes,
                ha="right", va="top", fontsize=7, color="0.4")


def _run_label(log: RunLog) -> str:
    meta = log.metadata.get("fwsim", {})
    return f"{meta.get('scenario', log.path.stem)} (seed {meta.get('seed', '?')}, {log.status})"


def _figure(rows: int, cols: int = 1, height: float = 2.2, sharex: bool = True) -> tuple[Figure, np.ndarray]:
    fig = Figure(figsize=(8.0 if cols == 1 else 11.0, 1.2 + height * rows), layout="constrained")
    axes = fig.subplots(rows, cols, sharex=sharex, squeeze=False)
    for ax in axes.ravel():
        ax.grid(True, alpha=0.3)
    return fig, axes[:, 0] if cols == 1 else axes


def _at(t_src: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The latest ``values`` sample at or before each time ``t`` (zero-order hold)."""
    i = np.searchsorted(t_src, t + 1e-9, side="right") - 1
    return values[np.clip(i, 0, len(values) - 1)]


def _phases(log: RunLog, t: np.ndarray) -> tuple[np.ndarray, dict[int, str]] | None:
    """A phase index at each time ``t`` and ``{index: label}``, if /fsw/status is logged.

    Indices number the distinct (phase, phase_name) pairs in order of first
    appearance, so sub-phases (``acquisition:search``, ``acquisition:orbit``)
    get their own colours.
    """
    if not log.topics.get(topics.FSW_STATUS):
        return None
    fsw = log.table(topics.FSW_STATUS)
    if "phase" not in fsw:
        return None
    phase = np.nan_to_num(fsw["phase"], nan=-1).astype(int)
    names = fsw["phase_name"] if "phase_name" in fsw else np.full(len(phase), "", dtype=object)
    keys: dict[tuple[int, str], int] = {}
    index = np.array([keys.setdefault((int(p), str(n)), len(keys)) for p, n in zip(phase, names)], dtype=int)
    labels = {i: f"phase {p}: {n}" if n else f"phase {p}" for (p, n), i in keys.items()}
    return _at(fsw["t_s"], index, t), labels


def _coloured_path(ax, x: np.ndarray, y: np.ndarray, phase: tuple | None, label: str = "UAV") -> None:
    """A path coloured by phase (one legend entry per phase), or one colour."""
    if phase is None:
        ax.plot(x, y, color=PHASE_COLOURS[0], lw=1.2, label=label)
    else:
        ph, names = phase
        segs = np.stack([np.column_stack([x[:-1], y[:-1]]), np.column_stack([x[1:], y[1:]])], axis=1)
        colours = [PHASE_COLOURS[p % len(PHASE_COLOURS)] for p in ph[:-1]]
        ax.add_collection(LineCollection(segs, colors=colours, linewidths=1.4))
        for p in sorted(set(ph.tolist())):
            ax.plot([], [], color=PHASE_COLOURS[p % len(PHASE_COLOURS)], lw=1.4, label=names.get(p, "?"))
        ax.autoscale_view()
    ax.plot(x[:1], y[:1], "o", color="k", ms=4, label="start")
    ax.plot(x[-1:], y[-1:], "x", color="k", ms=6, label="end")


def _target_track(log: RunLog, ax, axis: int) -> None:
    if log.topics.get(topics.TARGET_STATE):
        p = log.table(topics.TARGET_STATE)["pos_enu_m"]
        ax.plot(p[:, 0], p[:, axis], color="tab:cyan", lw=2.0, label="target")
        ax.plot(p[-1:, 0], p[-1:, axis], "s", color="tab:cyan", ms=5)


# -- figures from the state and the inner loops ---------------------------------

@figure("trajectory_xy", needs=(topics.UAV_STATE,), title="Trajectory, top view (x East, y North)")
def _trajectory_xy(log: RunLog) -> Figure:
    st = log.table(topics.UAV_STATE)
    pos = st["pos_enu_m"]
    fig, (ax,) = _figure(1, height=5.5)
    _coloured_path(ax, pos[:, 0], pos[:, 1], _phases(log, st["t_s"]))
    _target_track(log, ax, 1)
    ax.set_xlabel("x East [m]")
    ax.set_ylabel("y North [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(fontsize=8, loc="best")
    return fig


@figure("trajectory_xz", needs=(topics.UAV_STATE,), title="Trajectory, side view (x East, z Up)")
def _trajectory_xz(log: RunLog) -> Figure:
    st = log.table(topics.UAV_STATE)
    pos = st["pos_enu_m"]
    fig, (ax,) = _figure(1, height=4.0)
    _coloured_path(ax, pos[:, 0], pos[:, 2], _phases(log, st["t_s"]))
    _target_track(log, ax, 2)
    ax.set_xlabel("x East [m]")
    ax.set_ylabel("z Up [m]")
    ax.legend(fontsize=8, loc="best")
    return fig


@figure("altitude_airspeed", needs=(topics.UAV_STATE,), title="Altitude and airspeed")
def _altitude_airspeed(log: RunLog) -> Figure:
    st = log.table(topics.UAV_STATE)
    t = st["t_s"]
    fig, (a1, a2) = _figure(2)
    a1.plot(t, st["height_above_sea_m"], label="height above sea")
    a1.set_ylabel("height [m]")
    a2.plot(t, st["airspeed_m_s"], label="airspeed (truth)")
    if log.topics.get(topics.AUTOPILOT_STATUS):
        ap = log.table(topics.AUTOPILOT_STATUS)
        a2.plot(ap["t_s"], ap["airspeed_sp_m_s"], "--", label="set-point")
    a2.set_ylabel("airspeed [m/s]")
    a2.set_xlabel("sim time [s]")
    a2.legend(fontsize=8)
    return fig


@figure("attitude", needs=(topics.UAV_STATE,), title="Attitude (roll, pitch, yaw; NED Euler angles)")
def _attitude(log: RunLog) -> Figure:
    st = log.table(topics.UAV_STATE)
    t, eul = st["t_s"], np.degrees(st["euler_ned_rad"])
    fig, axes = _figure(3)
    for ax, k, name in zip(axes, range(2), ("roll φ", "pitch θ")):
        ax.plot(t, eul[:, k])
        ax.set_ylabel(f"{name} [deg]")
    axes[2].plot(*_with_breaks(t, st["euler_ned_rad"][:, 2]))  # wrapped as the course is: [0, 360)
    axes[2].set_ylabel("yaw ψ [deg]")
    axes[2].set_ylim(0.0, 360.0)
    axes[-1].set_xlabel("sim time [s]")
    return fig


@figure("inner_loops", needs=(topics.AUTOPILOT_STATUS,), title="Inner loops: set-points vs actual")
def _inner_loops(log: RunLog) -> Figure:
    ap = log.table(topics.AUTOPILOT_STATUS)
    t = ap["t_s"]
    sp, act = np.degrees(ap["body_rates_sp_frd_rad_s"]), np.degrees(ap["body_rates_frd_rad_s"])
    fig, axes = _figure(3)
    for ax, k, name in zip(axes, (0, 1), ("roll rate p", "pitch rate q")):
        ax.plot(t, act[:, k], label="actual")
        ax.plot(t, sp[:, k], "--", label="set-point")
        ax.set_ylabel(f"{name} [deg/s]")
    axes[2].plot(t, ap["airspeed_m_s"], label="actual")
    axes[2].plot(t, ap["airspeed_sp_m_s"], "--", label="set-point")
    axes[2].set_ylabel("airspeed [m/s]")
    axes[2].set_xlabel("sim time [s]")
    axes[0].legend(fontsize=8)
    return fig


@figure("accel_tracking", needs=(topics.AUTOPILOT_STATUS,), title="Acceleration mode: commanded vs achieved (ENU)")
def _accel_tracking(log: RunLog) -> Figure:
    ap = log.table(topics.AUTOPILOT_STATUS)
    mode = ap.get("mode")
    accel = np.array([m == "accel" for m in mode]) if mode is not None else np.zeros(0, bool)
    if not accel.any():
        raise SkipFigure("no acceleration-mode ticks in /autopilot/status")
    t = ap["t_s"]
    sp = np.where(accel[:, None], ap["accel_sp_enu_m_s2"], np.nan)
    act = np.where(accel[:, None], ap["accel_enu_m_s2"], np.nan)
    fig, axes = _figure(3)
    for ax, k, name in zip(axes, range(3), ("East", "North", "Up")):
        ax.plot(t, act[:, k], label="achieved")
        ax.plot(t, sp[:, k], "--", label="commanded")
        ax.set_ylabel(f"a {name} [m/s²]")
    axes[-1].set_xlabel("sim time [s]")
    axes[0].legend(fontsize=8)
    return fig


@figure("velocity_direction", needs=(topics.UAV_STATE,),
        title="Velocity direction: flight-path angle and course (NED Euler angles of the velocity)")
def _velocity_direction(log: RunLog) -> Figure:
    st = log.table(topics.UAV_STATE)
    t, v = st["t_s"], st["vel_enu_m_s"]
    gamma = np.degrees(np.arctan2(v[:, 2], np.hypot(v[:, 0], v[:, 1])))  # positive climbing
    fig, (a1, a2) = _figure(2)
    a1.plot(t, gamma)
    a1.set_ylabel("flight path γ [deg]")
    a2.plot(*_with_breaks(t, np.arctan2(v[:, 0], v[:, 1])))  # clockwise from North, [0, 360) as the yaw
    a2.set_ylabel("course χ [deg]")
    a2.set_ylim(0.0, 360.0)
    a2.set_xlabel("sim time [s]")
    return fig


# -- figures of the paper that need the target, gimbal, camera, estimator --------

@figure("distance_to_target", needs=(topics.UAV_STATE, topics.TARGET_STATE),
        title="Distance from the UAV to the target")
def _distance_to_target(log: RunLog) -> Figure:
    st, tg = log.table(topics.UAV_STATE), log.table(topics.TARGET_STATE)
    t = st["t_s"]
    rel = st["pos_enu_m"] - interp_at(t, tg["t_s"], tg["pos_enu_m"])
    fig, (a1, a2) = _figure(2)
    a1.plot(t, np.linalg.norm(rel, axis=1), label="range")
    a1.plot(t, np.hypot(rel[:, 0], rel[:, 1]), "--", label="horizontal")
    a1.set_ylabel("distance [m]")
    a1.legend(fontsize=8)
    a2.plot(t, rel[:, 2])
    a2.set_ylabel("height above target [m]")
    a2.set_xlabel("sim time [s]")
    return fig


@figure("gimbal_angles", needs=(topics.GIMBAL_STATE,), title="Gimbal pan and tilt angles")
def _gimbal_angles(log: RunLog) -> Figure:
    g = log.table(topics.GIMBAL_STATE)
    t = g["t_s"]
    fig, (a1, a2) = _figure(2)
    a1.plot(t, np.degrees(g["pan_rad"]))
    a1.set_ylabel("pan [deg]")
    a2.plot(t, np.degrees(g["tilt_rad"]))
    a2.set_ylabel("tilt [deg]")
    a2.set_xlabel("sim time [s]")
    return fig


def _principal_point(log: RunLog) -> tuple[float, float] | None:
    if not log.topics.get(topics.CAMERA_CALIBRATION):
        return None
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    cal = CameraCalibration.FromString(log.raw(topics.CAMERA_CALIBRATION)[0][1])
    return float(cal.K[2]), float(cal.K[5])


@figure("pixel_errors", needs=(topics.CAMERA_DETECTION,), title="Target pixel error from the image centre")
def _pixel_errors(log: RunLog) -> Figure:
    det = log.table(topics.CAMERA_DETECTION)
    centre = _principal_point(log)
    if centre is None:
        raise SkipFigure(f"no {topics.CAMERA_CALIBRATION} (principal point) in this log")
    found = det["detected"].astype(bool) if "detected" in det else np.isfinite(det["u_px"])
    if not found.any():
        raise SkipFigure("the detector never found the target")
    t = det["t_s"]
    eu = np.where(found, det["u_px"] - centre[0], np.nan)
    ev = np.where(found, det["v_px"] - centre[1], np.nan)
    fig, (a1, a2) = _figure(2)
    a1.plot(t, eu, ".", ms=2, label="detection - principal point")
    a1.set_ylabel("u - cx [px]")
    a2.plot(t, ev, ".", ms=2)
    a2.set_ylabel("v - cy [px]")
    if log.topics.get(topics.FSW_IBVS) and "pixel_err_px" in log.table(topics.FSW_IBVS):
        ib = log.table(topics.FSW_IBVS)
        a1.plot(ib["t_s"], ib["pixel_err_px"][:, 0], lw=1.0, label=f"{topics.FSW_IBVS} pixel_err_px")
        a2.plot(ib["t_s"], ib["pixel_err_px"][:, 1], lw=1.0)
    a1.legend(fontsize=8)
    a2.set_xlabel("sim time [s]")
    a2.set_xlim(t[0], t[-1])  # the whole run, also where the target was not detected
    a1.set_title(f"detected in {found.sum()} of {found.size} frames", fontsize=9)
    return fig


def _phase_lines(log: RunLog, top, bottom) -> None:
    """A dotted line on both axes at each phase change, labelled on the top one."""
    if not log.topics.get(topics.FSW_STATUS):
        return
    fsw = log.table(topics.FSW_STATUS)
    if "phase" not in fsw:
        return
    ph = np.nan_to_num(fsw["phase"], nan=-1).astype(int)
    for k in np.flatnonzero(np.diff(ph)) + 1:
        for ax in (top, bottom):
            ax.axvline(fsw["t_s"][k], color="k", lw=0.6, ls=":")
        top.text(fsw["t_s"][k], 101.0, f" phase {ph[k]}", fontsize=7, va="top")


@figure("ship_visibility", needs=(topics.CAMERA_FRAME, topics.UAV_STATE, topics.TARGET_STATE),
        title="The ship in the camera: seen, hidden behind the airframe, out of view")
def _ship_visibility(log: RunLog) -> Figure:
    """Top: the share of the ship's pixels the camera saw in each frame (0 out of view), the stretches in view
    but wholly hidden by the UAV's own airframe shaded red, out of view grey. Bottom: where the ship lay in the
    UAV's body frame (truth): its angle below the wing plane (the body x-y plane; negative above it) and its
    azimuth off the nose. The camera hangs under the fuselage: the wing hides a ship above the plane to the
    side, the nose one above it ahead."""
    from fwsim.interface.frames import dcm_enu_from_frd
    from fwsim.analysis.metrics import lock_time_s, longest_gap_s, seen_frames
    fr, st, tg = log.table(topics.CAMERA_FRAME), log.table(topics.UAV_STATE), log.table(topics.TARGET_STATE)
    t = fr["t_s"]
    if t.size < 2:
        raise SkipFigure("fewer than two camera frames")
    in_fov, seen = seen_frames(fr)
    ship_px = np.maximum(fr["ship_px"].astype(float), 1.0)
    share = np.where(in_fov, fr["visible_px"] / ship_px, 0.0)
    fig, (a1, a2) = _figure(2, height=2.6)
    a1.plot(t, 100.0 * share, lw=0.8, color="tab:blue", label="ship's pixels seen")
    for mask, colour, label in ((in_fov & ~seen, "tab:red", "in view, hidden by the airframe"),
                                (~in_fov, "0.6", "out of view")):
        if mask.any():
            a1.fill_between(t, 0.0, 100.0, where=mask, color=colour, alpha=0.3, step="mid", lw=0, label=label)
    a1.set_ylabel("seen [% of pixels]")
    a1.set_ylim(-2.0, 102.0)
    lock_t = lock_time_s(log)
    _phase_lines(log, a1, a2)
    locked = math.isfinite(lock_t)
    after = t >= (lock_t if locked else t[0])
    if after.any():
        a1.set_title(f"{'after the lock' if locked else 'no lock: all frames'}: seen in "
                     f"{100 * np.mean(seen[after]):.1f} % of the frames, in view in "
                     f"{100 * np.mean(in_fov[after]):.1f} %; longest stretch unseen "
                     f"{longest_gap_s(t[after], seen[after]):.1f} s", fontsize=9)
    a1.legend(fontsize=7, loc="lower left")
    pos = interp_at(t, st["t_s"], st["pos_enu_m"])
    euler = _at(st["t_s"], st["euler_ned_rad"], t)
    ship = interp_at(t, tg["t_s"], tg["pos_enu_m"])
    below, az = np.full(t.size, np.nan), np.full(t.size, np.nan)
    for k in range(t.size):
        r = dcm_enu_from_frd(euler[k]).T @ (ship[k] - pos[k])
        n = float(np.linalg.norm(r))
        if n > 0.0:
            below[k] = np.degrees(np.arcsin(np.clip(r[2] / n, -1.0, 1.0)))
            az[k] = np.degrees(np.arctan2(r[1], r[0]))
    a2.plot(t, below, lw=0.9, color="tab:green", label="ship below the wing plane [deg]")
    a2.axhline(0.0, color="k", lw=0.5)
    a2.set_ylabel("below the wing plane [deg]")
    a2b = a2.twinx()
    a2b.plot(t, az, lw=0.7, color="tab:purple", alpha=0.7, label="azimuth off the nose [deg]")
    a2b.set_ylabel("azimuth off the nose [deg]")
    a2b.set_ylim(-180.0, 180.0)
    a2.legend(fontsize=7, loc="lower left")
    a2b.legend(fontsize=7, loc="lower right")
    a2.set_xlabel("sim time [s]")
    a2.set_xlim(t[0], t[-1])
    return fig


@figure("target_estimate", needs=(topics.FSW_ESTIMATE, topics.TARGET_STATE), title="Target estimate vs truth, ±2σ")
def _target_estimate(log: RunLog) -> Figure:
    est, tg = log.table(topics.FSW_ESTIMATE), log.table(topics.TARGET_STATE)
    if "pos_enu_m" not in est:
        raise SkipFigure(f"{topics.FSW_ESTIMATE} has no pos_enu_m")
    t = est["t_s"]
    fig, axes = _figure(2, 2, height=2.6)
    for col, (fld, std_fld, what, unit) in enumerate((("pos_enu_m", "pos_std_m", "position", "m"),
                                                     ("vel_enu_m_s", "vel_std_m_s", "velocity", "m/s"))):
        if fld not in est:
            continue
        std = est.get(std_fld)
        for row, axis in enumerate(("East", "North")):
            ax = axes[row, col]
            ax.plot(t, interp_at(t, tg["t_s"], tg[fld][:, row]), "k--", lw=1.0, label="truth")
            ax.plot(t, est[fld][:, row], lw=1.2, label="estimate")
            if std is not None:
                lo, hi = est[fld][:, row] - 2 * std[:, row], est[fld][:, row] + 2 * std[:, row]
                ax.fill_between(t, lo, hi, alpha=0.25, lw=0, label="±2σ")
            _clip_transient(ax, est[fld][:, row], interp_at(t, tg["t_s"], tg[fld][:, row]))
            ax.set_ylabel(f"{what} {axis} [{unit}]", fontsize=9)
    for ax in axes[-1]:
        ax.set_xlabel("sim time [s]")
    axes[0, 0].legend(fontsize=8)
    return fig


@figure("target_estimate_error", needs=(topics.FSW_ESTIMATE, topics.TARGET_STATE),
        title="Target estimate error, horizontal (estimate - truth)")
def _target_estimate_error(log: RunLog) -> Figure:
    """Horizontal (x, y) errors, as fwsim.analysis.metrics scores them: the filter estimates a point
    at its configured plane height, the truth is the waterline centre."""
    est, tg = log.table(topics.FSW_ESTIMATE), log.table(topics.TARGET_STATE)
    if "pos_enu_m" not in est:
        raise SkipFigure(f"{topics.FSW_ESTIMATE} has no pos_enu_m")
    t = est["t_s"]
    fig, (a1, a2) = _figure(2)
    err = (est["pos_enu_m"] - interp_at(t, tg["t_s"], tg["pos_enu_m"]))[:, :2]
    a1.plot(t, err[:, 0], label="x (East)")
    a1.plot(t, err[:, 1], label="y (North)")
    a1.plot(t, np.linalg.norm(err, axis=1), "k", lw=0.8, label="|horizontal error|")
    if "pos_std_m" in est:
        a1.plot(t, 2 * np.linalg.norm(est["pos_std_m"][:, :2], axis=1), "--", label="2σ (norm)")
    a1.set_ylabel("position error [m]")
    _clip_transient(a1, err, np.linalg.norm(err, axis=1))
    a1.legend(fontsize=8)
    if "vel_enu_m_s" in est:
        verr = (est["vel_enu_m_s"] - interp_at(t, tg["t_s"], tg["vel_enu_m_s"]))[:, :2]
        a2.plot(t, verr[:, 0], label="x (East)")
        a2.plot(t, verr[:, 1], label="y (North)")
        _clip_transient(a2, verr)
        a2.legend(fontsize=8)
    a2.set_ylabel("velocity error [m/s]")
    a2.set_xlabel("sim time [s]")
    return fig


@figure("navigation_error", needs=(topics.NAV_ESTIMATE, topics.UAV_STATE),
        title="Navigation error (the INS's estimate - truth), ±2σ")
def _navigation_error(log: RunLog) -> Figure:
    """The onboard INS against the truth, as fwsim.analysis.metrics scores it: attitude (roll, pitch, yaw),
    position and velocity errors per axis, each with the filter's own ±2σ band."""
    nav, st = log.table(topics.NAV_ESTIMATE), log.table(topics.UAV_STATE)
    keep = nav["mode"] != "initialising"
    if not keep.any():
        raise SkipFigure("the INS never initialised")
    nav = {k: v[keep] for k, v in nav.items()}
    t = nav["t_s"]
    euler = np.array(st["euler_ned_rad"], dtype=float)
    euler[:, 2] = np.unwrap(euler[:, 2])
    att = np.degrees((nav["euler_ned_rad"] - interp_at(t, st["t_s"], euler) + np.pi) % (2 * np.pi) - np.pi)
    rows = ((att, np.degrees(nav["att_std_rad"]), ("roll", "pitch", "yaw"), "attitude error [deg]"),
            (nav["pos_enu_m"] - interp_at(t, st["t_s"], st["pos_enu_m"]), nav["pos_std_m"], ("E", "N", "U"),
             "position error [m]"),
            (nav["vel_enu_m_s"] - interp_at(t, st["t_s"], st["vel_enu_m_s"]), nav["vel_std_m_s"], ("E", "N", "U"),
             "velocity error [m/s]"))
    fig, axes = _figure(3, 3, height=2.0)
    for r, (err, std, names, label) in enumerate(rows):
        for c in range(3):
            ax = axes[r, c]
            ax.fill_between(t, -2 * std[:, c], 2 * std[:, c], color="0.85", label="±2σ")
            ax.plot(t, err[:, c], lw=0.8, label=names[c])
            _clip_transient(ax, err[:, c], 2 * std[:, c])
            ax.legend(fontsize=7, loc="upper right")
            if c == 0:
                ax.set_ylabel(label, fontsize=8)
            if r == 2:
                ax.set_xlabel("sim time [s]")
    return fig
