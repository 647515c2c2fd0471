"""Scores computed from a log (never from the objects of a live run).

Inner-loop tracking errors are RMS over every logged tick of the
``/autopilot/status`` topic (set-point minus what the loop saw).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fwsim.log import RunLog, read_log


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else math.nan


def compute_metrics(log: RunLog | str | Path) -> dict[str, float | str]:
    """Metrics of one run as a flat dict (numbers, plus status and reason)."""
    if not isinstance(log, RunLog):
        log = read_log(log)
    st = log.table("/uav/state")
    m: dict[str, float | str] = {"status": log.status, "end_reason": log.reason}
    t = st["t_s"]
    m["flight_time_s"] = float(t[-1] - t[0]) if t.size else 0.0
    m["airspeed_min_m_s"] = float(np.min(st["airspeed_m_s"]))
    m["airspeed_max_m_s"] = float(np.max(st["airspeed_m_s"]))
    m["bank_abs_max_deg"] = float(np.degrees(np.max(np.abs(st["euler_ned_rad"][:, 0]))))
    m["sideslip_abs_max_deg"] = float(np.degrees(np.max(np.abs(st["beta_rad"]))))
    m["height_min_m"] = float(np.min(st["height_above_sea_m"]))
    if "/autopilot/status" in log.topics:
        ap = log.table("/autopilot/status")
        m["airspeed_err_rms_m_s"] = _rms(ap["airspeed_sp_m_s"] - ap["airspeed_m_s"])
        err = np.degrees(ap["body_rates_sp_frd_rad_s"] - ap["body_rates_frd_rad_s"])
        m["roll_rate_err_rms_deg_s"] = _rms(err[:, 0])
        m["pitch_rate_err_rms_deg_s"] = _rms(err[:, 1])
        accel = ap["mode"] == "accel"
        if np.any(accel):
            a_err = np.linalg.norm(ap["accel_sp_enu_m_s2"][accel] - ap["accel_enu_m_s2"][accel], axis=1)
            m["accel_err_rms_m_s2"] = _rms(a_err)
    if "/camera/frame" in log.topics:
        fr = log.table("/camera/frame")
        in_fov = fr["in_fov"].astype(bool)
        visible = fr["visible_px"] > 0
        m["camera_frames"] = float(len(in_fov))
        m["target_in_fov_fraction"] = float(np.mean(in_fov)) if len(in_fov) else math.nan
        m["target_visible_fraction"] = float(np.mean(visible)) if len(visible) else math.nan
        m["occluded_frames"] = float(np.sum(in_fov & ~visible))  # in view but hidden by the UAV
        m["partly_occluded_frames"] = float(np.sum(visible & (fr["occluded_fraction"] > 0)))
    if "/camera/detection" in log.topics:
        det = log.table("/camera/detection")
        m["detections"] = float(np.sum(det["detected"].astype(bool)))
    return m
