"""Replay a run's MCAP log as a Rerun recording (``.rrd``), with a default layout.

Everything goes on one timeline, ``sim_time`` (seconds from the start of the
run). Entities (world frame ENU, metres; ``world`` is Z-up):

    world/uav                 Transform3D: pose of the body (FRD) in the world
    world/uav/body            Boxes3D: fuselage and wing (drawn ``marker_scale`` times life size)
    world/uav/axes            Arrows3D: body x (forward, red), y (right, green), z (down, blue)
    world/uav_path            LineStrips3D: the whole flight, coloured by flight-software phase
    world/target, .../hull    Transform3D + Boxes3D of the ship; world/target_path
    world/camera              Transform3D + Pinhole (frustum) of the gimbal camera
    world/target_estimate     Points3D: the flight software's target estimate (/fsw/estimate)
    world/uav_estimate        Points3D: the navigation filter's UAV position (/nav/estimate), beside world/uav;
                              world/uav_estimate_path its path
    camera/image              EncodedImage: rendered camera frames (with camera/detection boxes)
    plots/...                 Scalars: airspeed, altitude, roll/pitch, inner-loop set-points vs actual,
                              distance to the target, gimbal angles, target estimate error, the navigation
                              filter's position error per axis (estimate - truth)
    events                    TextLog: the run's /events
    scenario                  TextDocument: the scenario file the run flew

Each group is a *layer* (:data:`LAYERS`): a function that logs its entities
when the topics it needs are in the log and returns the blueprint views it
adds; a layer without its topics is skipped and reported. Add one with the
:func:`layer` decorator.

The entity paths, time series (:class:`Series`), colours, layer views
(:data:`VIEWS`) and the helpers that log the static models are shared with
the live view of a run (:mod:`fwsim.log.rerun_live`), so both look alike; a
new layer that the live view should draw needs a handler there too.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from fwsim.interface import topics
from fwsim.log.reader import RunLog, read_log
from fwsim.log.truth import truth_at

TIMELINE = "sim_time"

#: The paper's UAV (fuselage 1 m, span 2.4 m) and ship (55 x 25 x 25 m).
UAV_LENGTH_M, UAV_SPAN_M = 1.0, 2.4
SHIP_SIZE_M = (55.0, 25.0, 25.0)
PHASE_COLOURS = [(150, 150, 150), (31, 119, 180), (255, 127, 14), (214, 39, 40), (44, 160, 44), (148, 103, 189)]
TARGET_COLOUR = (23, 190, 207)
ESTIMATE_COLOUR = (255, 0, 255)
NAV_ESTIMATE_COLOUR = (255, 200, 0)
DETECTION_COLOUR = (255, 60, 60)
#: /events levels (foxglove.Log names) -> rr.TextLog levels
TEXTLOG_LEVELS = {"DEBUG": "DEBUG", "INFO": "INFO", "WARNING": "WARN", "ERROR": "ERROR", "FATAL": "CRITICAL"}

# Entity paths (shared with the live view, fwsim/log/rerun_live.py).
WORLD_ENTITY = "world"
UAV_ENTITY = "world/uav"
UAV_BODY_ENTITY = "world/uav/body"
UAV_AXES_ENTITY = "world/uav/axes"
UAV_PATH_ENTITY = "world/uav_path"
TARGET_ENTITY = "world/target"
HULL_ENTITY = "world/target/hull"
TARGET_PATH_ENTITY = "world/target_path"
CAMERA_ENTITY = "world/camera"
ESTIMATE_ENTITY = "world/target_estimate"
NAV_ESTIMATE_ENTITY = "world/uav_estimate"
NAV_ESTIMATE_PATH_ENTITY = "world/uav_estimate_path"
IMAGE_ENTITY = "camera/image"
DETECTION_ENTITY = "camera/detection"
EVENTS_ENTITY = "events"
SCENARIO_ENTITY = "scenario"
RUN_ENTITY = "run"


@dataclass(frozen=True)
class Series:
    """One time series: entity path, legend name, colour, and whether it is a (thin) set-point line."""
    path: str
    name: str
    colour: tuple[int, int, int] | None = None
    setpoint: bool = False


AIRSPEED = Series("plots/airspeed/truth", "airspeed (truth)", (31, 119, 180))
AIRSPEED_SP = Series("plots/airspeed/setpoint", "airspeed set-point", (255, 127, 14), True)
HEIGHT = Series("plots/altitude/height", "height above sea", (44, 160, 44))
ROLL = Series("plots/attitude/roll", "roll φ [deg]", (214, 39, 40))
PITCH = Series("plots/attitude/pitch", "pitch θ [deg]", (31, 119, 180))
P_ACTUAL = Series("plots/rates/p/actual", "p", (31, 119, 180))
P_SP = Series("plots/rates/p/setpoint", "p set-point", (255, 127, 14), True)
Q_ACTUAL = Series("plots/rates/q/actual", "q", (31, 119, 180))
Q_SP = Series("plots/rates/q/setpoint", "q set-point", (255, 127, 14), True)
DISTANCE = Series("plots/target/distance", "distance [m]")
PAN = Series("plots/gimbal/pan", "pan [deg]", (148, 103, 189))
TILT = Series("plots/gimbal/tilt", "tilt [deg]", (140, 86, 75))
ESTIMATE_ERROR = Series("plots/estimate/position_error", "|estimate - truth| [m]", ESTIMATE_COLOUR)
#: The navigation filter's position error per axis (the replay's nav_estimate layer; not in SIGNALS: it is
#: against the UAV's truth, per axis, and the live view does not draw it).
NAV_ERRORS = (Series("plots/nav/position_error/east", "east [m]", (214, 39, 40)),
              Series("plots/nav/position_error/north", "north [m]", (44, 160, 44)),
              Series("plots/nav/position_error/up", "up [m]", (31, 119, 180)))

#: The blueprint views each layer adds (when it has its data).
VIEWS: dict[str, Callable[[], list]] = {
    "uav": lambda: [rrb.Spatial3DView(origin=WORLD_ENTITY, name="3D (ENU, body axes FRD)")],
    "target": lambda: [],
    "camera": lambda: [rrb.Spatial2DView(origin="camera", name="camera")],
    "estimate": lambda: [rrb.TimeSeriesView(origin="plots/estimate", name="target estimate error [m]")],
    "nav_estimate": lambda: [rrb.TimeSeriesView(origin="plots/nav", name="navigation error (estimate - truth) [m]")],
    "flight_plots": lambda: [rrb.TimeSeriesView(origin="plots/airspeed", name="airspeed [m/s]"),
                             rrb.TimeSeriesView(origin="plots/altitude", name="height [m]"),
                             rrb.TimeSeriesView(origin="plots/attitude", name="roll, pitch [deg]")],
    "inner_loops": lambda: [rrb.TimeSeriesView(origin="plots/rates/p", name="roll rate p [deg/s]"),
                            rrb.TimeSeriesView(origin="plots/rates/q", name="pitch rate q [deg/s]")],
    "target_plots": lambda: [rrb.TimeSeriesView(origin="plots/target", name="distance to target [m]")],
    "gimbal_plots": lambda: [rrb.TimeSeriesView(origin="plots/gimbal", name="gimbal [deg]")],
    "events": lambda: [rrb.TextLogView(origin=EVENTS_ENTITY, name="events")],
}


@dataclass
class ReplayOptions:
    marker_scale: float = 10.0  # UAV body drawn this many times life size (a 1 m fuselage is invisible at 1 km)
    frustum_m: float = 60.0  # how far the camera frustum is drawn
    application_id: str = "fwsim"


@dataclass
class ReplayResult:
    rrd_path: Path
    layers: list[str] = field(default_factory=list)  # logged
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (layer, why)


@dataclass(frozen=True)
class Layer:
    name: str
    needs: tuple[str, ...]
    log: Callable[[RunLog, rr.RecordingStream, ReplayOptions], list]  # returns blueprint views


LAYERS: dict[str, Layer] = {}


def layer(name: str, needs: tuple[str, ...]):
    """Register ``fn(log, rec, options) -> [blueprint views]`` as a replay layer."""
    def register(fn):
        LAYERS[name] = Layer(name, tuple(needs), fn)
        return fn
    return register


class SkipLayer(Exception):
    """Raised by a layer that has its topics but not the data it needs."""


def _time(t_s: np.ndarray) -> list[rr.TimeColumn]:
    return [rr.TimeColumn(TIMELINE, duration=np.asarray(t_s, dtype=float))]


def series_style(rec: rr.RecordingStream, series: Series) -> None:
    """A series' legend name, colour and line width (static)."""
    rec.log(series.path, rr.SeriesLines(names=series.name, colors=[series.colour] if series.colour else None,
                                        widths=1.0 if series.setpoint else 2.0), static=True)


def _scalars(rec: rr.RecordingStream, series: Series, t_s: np.ndarray, values: np.ndarray) -> None:
    """One time series: its style (static) and its values."""
    series_style(rec, series)
    rec.send_columns(series.path, indexes=_time(t_s),
                     columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=float)))


def log_uav_model(rec: rr.RecordingStream, marker_scale: float) -> None:
    """World axes (ENU, Z up) and the UAV's body boxes and axes (static, under world/uav)."""
    rec.log(WORLD_ENTITY, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    s = marker_scale
    rec.log(UAV_BODY_ENTITY, rr.Boxes3D(
        centers=[[0.0, 0.0, 0.0], [0.05 * s, 0.0, 0.0]],
        half_sizes=[[0.5 * UAV_LENGTH_M * s, 0.06 * s, 0.06 * s], [0.12 * s, 0.5 * UAV_SPAN_M * s, 0.015 * s]],
        colors=[(230, 230, 230), (200, 200, 255)], fill_mode="solid", labels=["fuselage", "wing"]), static=True)
    L = 1.2 * UAV_LENGTH_M * s
    rec.log(UAV_AXES_ENTITY, rr.Arrows3D(vectors=[[L, 0, 0], [0, L, 0], [0, 0, L]],
                                         colors=[(255, 0, 0), (0, 200, 0), (0, 0, 255)],
                                         labels=["x fwd", "y right", "z down"]), static=True)


def log_ship_model(rec: rr.RecordingStream, size_m: tuple[float, float, float]) -> None:
    """The ship's hull box in its frame (bow, port, up), waterline at z = 0 (static)."""
    L, W, H = size_m
    rec.log(HULL_ENTITY, rr.Boxes3D(centers=[[0, 0, 0.5 * H]], half_sizes=[[0.5 * L, 0.5 * W, 0.5 * H]],
                                    colors=[TARGET_COLOUR], labels=["ship"]), static=True)


def log_pinhole(rec: rr.RecordingStream, K: np.ndarray, width: int, height: int, frustum_m: float) -> None:
    """The camera's pinhole model (optical frame RDF) on world/camera (static): the frustum in 3D."""
    rec.log(CAMERA_ENTITY, rr.Pinhole(image_from_camera=K, resolution=[width, height],
                                      camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=frustum_m),
            static=True)


def log_path(rec: rr.RecordingStream, entity: str, strips: list, colours: list, labels: list | None = None) -> None:
    """A trajectory as line strips (static: the latest call is the whole path)."""
    rec.log(entity, rr.LineStrips3D(strips, colors=colours, labels=labels, radii=rr.Radius.ui_points(1.5)),
            static=True)


def phase_label(phase: int, name: str) -> str:
    return f"phase {phase}: {name}"


def detection_box(rec: rr.RecordingStream, found: bool, box: np.ndarray, scale: float) -> None:
    """The detector's box on the camera image (scaled to the rendered size), or a clear when none."""
    if found and np.all(np.isfinite(box)):
        rec.log(DETECTION_ENTITY, rr.Boxes2D(mins=[box[:2] * scale], sizes=[(box[2:] - box[:2]) * scale],
                                             colors=[DETECTION_COLOUR], labels=["detection"]))
    else:
        rec.log(DETECTION_ENTITY, rr.Clear(recursive=False))


def _tf(log: RunLog, child: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(t_s, translation (n, 3), quaternion xyzw (n, 4)) of one child frame on /tf."""
    if not log.topics.get(topics.TF):
        return None
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
    t, pos, quat = [], [], []
    for _, data in log.raw(topics.TF):
        m = FrameTransform.FromString(data)
        if m.child_frame_id != child:
            continue
        t.append(log.sim_time(m.timestamp))
        pos.append((m.translation.x, m.translation.y, m.translation.z))
        quat.append((m.rotation.x, m.rotation.y, m.rotation.z, m.rotation.w))
    if not t:
        return None
    return np.array(t), np.array(pos), np.array(quat)


def _phase_strips(log: RunLog, t: np.ndarray, pos: np.ndarray) -> tuple[list[np.ndarray], list, list[str]]:
    """The path cut into one strip per stretch of constant phase."""
    if not log.topics.get(topics.FSW_STATUS) or "phase" not in log.table(topics.FSW_STATUS):
        return [pos], [PHASE_COLOURS[1]], ["path"]
    fsw = log.table(topics.FSW_STATUS)
    phase = np.nan_to_num(fsw["phase"], nan=-1).astype(int)
    names = {int(p): str(n) for p, n in zip(phase, fsw.get("phase_name", phase))}
    i = np.clip(np.searchsorted(fsw["t_s"], t + 1e-9, side="right") - 1, 0, len(phase) - 1)
    ph = phase[i]
    cuts = np.flatnonzero(np.diff(ph)) + 1
    strips, colours, labels = [], [], []
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(ph)]):
        strips.append(pos[a: min(b + 1, len(pos))])  # overlap one point so the strips join
        colours.append(PHASE_COLOURS[ph[a] % len(PHASE_COLOURS)])
        labels.append(phase_label(ph[a], names.get(int(ph[a]), '?')))
    return strips, colours, labels


# -- layers -------------------------------------------------------------------

@layer("uav", needs=(topics.UAV_POSE,))
def _uav(log: RunLog, rec: rr.RecordingStream, opt: ReplayOptions) -> list:
    t, pos, q_wxyz = log.poses()  # q_enu_from_frd: body FRD into world ENU
    quat = q_wxyz[:, [1, 2, 3, 0]]  # Rerun wants x, y, z, w
    log_uav_model(rec, opt.marker_scale)
    strips, colours, labels = _phase_strips(log, t, pos)
    log_path(rec, UAV_PATH_ENTITY, strips, colours, labels)
    rec.send_columns(UAV_ENTITY, indexes=_time(t),
                     columns=rr.Transform3D.columns(translation=pos, quaternion=quat))
    return VIEWS["uav"]()


@layer("target", needs=(topics.TARGET_STATE,))
def _target(log: RunLog, rec: rr.RecordingStream, opt: ReplayOptions) -> list:
    tg = log.table(topics.TARGET_STATE)
    pos = tg["pos_enu_m"]
    log_path(rec, TARGET_PATH_ENTITY, [pos], [TARGET_COLOUR])
    tf = _tf(log, "ship")
    if tf is not None:  # the ship frame (bow, port, up) as the loop logged it
        t, p, q = tf
    else:  # from the heading: the ship frame is ENU turned about z by (pi/2 - heading)
        t, p = tg["t_s"], pos
        half = 0.5 * (np.pi / 2 - tg["heading_ned_rad"])
        q = np.column_stack([np.zeros_like(half), np.zeros_like(half), np.sin(half), np.cos(half)])
    rec.send_columns(TARGET_ENTITY, indexes=_time(t), columns=rr.Transform3D.columns(translation=p, quaternion=q))
    log_ship_model(rec, _ship_size(log))
    return VIEWS["target"]()


def _ship_size(log: RunLog) -> tuple[float, float, float]:
    import yaml
    try:
        tgt = (yaml.safe_load(log.scenario_text) or {}).get("target") or {}
        L, W, H = SHIP_SIZE_M
        return float(tgt.get("length_m", L)), float(tgt.get("width_m", W)), float(tgt.get("height_m", H))
    except (yaml.YAMLError, AttributeError, TypeError, ValueError):
        return SHIP_SIZE_M


@layer("camera", needs=(topics.TF, topics.CAMERA_CALIBRATION))
def _camera(log: RunLog, rec: rr.RecordingStream, opt: ReplayOptions) -> list:
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    tf = _tf(log, "camera")
    if tf is None:
        raise SkipLayer("no 'camera' frame on /tf")
    t, p, q = tf
    cal = CameraCalibration.FromString(log.raw(topics.CAMERA_CALIBRATION)[0][1])
    K = np.array(cal.K, dtype=float).reshape(3, 3)
    rec.send_columns(CAMERA_ENTITY, indexes=_time(t), columns=rr.Transform3D.columns(translation=p, quaternion=q))
    log_pinhole(rec, K, cal.width, cal.height, opt.frustum_m)
    scale = 1.0
    if log.topics.get(topics.CAMERA_IMAGE):
        from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
        times, blobs = [], []
        for _, data in log.raw(topics.CAMERA_IMAGE):
            m = CompressedImage.FromString(data)
            times.append(log.sim_time(m.timestamp))
            blobs.append(bytes(m.data))
        width = jpeg_width(blobs[0])
        scale = width / cal.width if width else 1.0
        for ti, blob in zip(times, blobs):
            rec.set_time(TIMELINE, duration=ti)
            rec.log(IMAGE_ENTITY, rr.EncodedImage(contents=blob, media_type="image/jpeg"))
        rec.reset_time()
    if log.topics.get(topics.CAMERA_DETECTION):
        det = log.table(topics.CAMERA_DETECTION)
        found = det["detected"].astype(bool) if "detected" in det else np.isfinite(det["u_px"])
        for ti, ok, box in zip(det["t_s"], found, det["bbox_px"]):
            rec.set_time(TIMELINE, duration=float(ti))
            detection_box(rec, bool(ok), box, scale)
        rec.reset_time()
    if log.topics.get(topics.CAMERA_IMAGE) or log.topics.get(topics.CAMERA_DETECTION):
        return VIEWS["camera"]()
    return []


def jpeg_width(blob: bytes) -> int | None:
    """Width in pixels of a JPEG image (None if it cannot be decoded)."""
    try:
        import cv2
        img = cv2.imdecode(np.frombuffer(blob, np.uint8), cv2.IMREAD_UNCHANGED)
        return int(img.shape[1]) if img is not None else None
    except Exception:  # noqa: BLE001 - no scale then
        return None


@dataclass(frozen=True)
class Signal:
    """One plotted time series and where it comes from, for the replay and the live view alike.

    The value is ``field`` of each ``topic`` message (its column ``index`` for a vector), in degrees when
    ``degrees``; with ``minus_truth``, the distance from that field of the truth (``/target/state``)
    interpolated to the message's time (:mod:`fwsim.log.truth`)."""

    series: Series
    layer: str
    topic: str
    field: str
    index: int | None = None
    degrees: bool = False
    minus_truth: str | None = None

    def column(self, table: dict) -> np.ndarray:
        """The values from a topic's table (replay)."""
        v = np.asarray(table[self.field], dtype=float)
        v = v[:, self.index] if self.index is not None else v
        return np.degrees(v) if self.degrees else v

    def value(self, msg):
        """The value of one message (live view); a vector when ``minus_truth`` (the distance comes later)."""
        v = getattr(msg, self.field)
        if self.minus_truth is not None:
            return np.asarray(v, dtype=float)
        v = float(v[self.index]) if self.index is not None else float(v)
        return float(np.degrees(v)) if self.degrees else v


#: Every plotted time series: the replay's layers and the live view are both made from this table.
SIGNALS: tuple[Signal, ...] = (
    Signal(ESTIMATE_ERROR, "estimate", topics.FSW_ESTIMATE, "pos_enu_m", minus_truth="pos_enu_m"),
    Signal(AIRSPEED, "flight_plots", topics.UAV_STATE, "airspeed_m_s"),
    Signal(HEIGHT, "flight_plots", topics.UAV_STATE, "height_above_sea_m"),
    Signal(ROLL, "flight_plots", topics.UAV_STATE, "euler_ned_rad", 0, degrees=True),
    Signal(PITCH, "flight_plots", topics.UAV_STATE, "euler_ned_rad", 1, degrees=True),
    Signal(AIRSPEED_SP, "inner_loops", topics.AUTOPILOT_STATUS, "airspeed_sp_m_s"),
    Signal(P_ACTUAL, "inner_loops", topics.AUTOPILOT_STATUS, "body_rates_frd_rad_s", 0, degrees=True),
    Signal(P_SP, "inner_loops", topics.AUTOPILOT_STATUS, "body_rates_sp_frd_rad_s", 0, degrees=True),
    Signal(Q_ACTUAL, "inner_loops", topics.AUTOPILOT_STATUS, "body_rates_frd_rad_s", 1, degrees=True),
    Signal(Q_SP, "inner_loops", topics.AUTOPILOT_STATUS, "body_rates_sp_frd_rad_s", 1, degrees=True),
    Signal(DISTANCE, "target_plots", topics.UAV_STATE, "pos_enu_m", minus_truth="pos_enu_m"),
    Signal(PAN, "gimbal_plots", topics.GIMBAL_STATE, "pan_rad", degrees=True),
    Signal(TILT, "gimbal_plots", topics.GIMBAL_STATE, "tilt_rad", degrees=True),
)


def signal_needs(layer_name: str) -> tuple[str, ...]:
    """The topics a layer's signals read (the truth's too when one is relative to it)."""
    out = []
    for sig in SIGNALS:
        if sig.layer == layer_name:
            out += [sig.topic] + ([topics.TARGET_STATE] if sig.minus_truth else [])
    return tuple(dict.fromkeys(out))


def _plot_signals(log: RunLog, rec: rr.RecordingStream, layer_name: str) -> None:
    for sig in SIGNALS:
        if sig.layer != layer_name or (sig.minus_truth and not log.topics.get(topics.TARGET_STATE)):
            continue
        table = log.table(sig.topic)
        t = table["t_s"]
        v = sig.column(table)
        if sig.minus_truth:
            v = np.linalg.norm(v - truth_at(log, t, sig.minus_truth), axis=1)
        _scalars(rec, sig.series, t, v)


@layer("estimate", needs=(topics.FSW_ESTIMATE,))
def _estimate(log: RunLog, rec: rr.RecordingStream, opt: ReplayOptions) -> list:
    est = log.table(topics.FSW_ESTIMATE)
    if "pos_enu_m" not in est:
        raise SkipLayer(f"{topics.FSW_ESTIMATE} has no pos_enu_m")
    t, pos = est["t_s"], est["pos_enu_m"]
    ok = np.all(np.isfinite(pos), axis=1)
    rec.send_columns(ESTIMATE_ENTITY, indexes=_time(t[ok]),
                     columns=rr.Points3D.columns(positions=pos[ok], radii=np.full(ok.sum(), 4.0),
                                                 colors=np.tile(ESTIMATE_COLOUR, (ok.sum(), 1))))
    if log.topics.get(topics.TARGET_STATE):
        _plot_signals(log, rec, "estimate")
        return VIEWS["estimate"]()
    return []


def _plot_layer(name: str) -> None:
    """Register a layer that is nothing but its signals' time series."""
    @layer(name, needs=signal_needs(name))
    def _log(log: RunLog, rec: rr.RecordingStream, opt: ReplayOptions) -> list:
        _plot_signals(log, rec, name)
        return VIEWS[name]()


for _name in ("flight_plots", "inner_loops", "target_plots", "gimbal_plots"):
    _plot_layer(_name)


@layer("nav_estimate", needs=(topics.NAV_ESTIMATE,))
def _nav_estimate(log: RunLog, rec: rr.RecordingStream, opt: ReplayOptions) -> list:
    """The navigation filter's UAV position beside the truth's (a point that moves, its path), and its position
    error per axis against the truth interpolated to the estimate's times."""
    nav = log.table(topics.NAV_ESTIMATE)
    if "pos_enu_m" not in nav:
        raise SkipLayer(f"{topics.NAV_ESTIMATE} has no pos_enu_m")
    t, pos = nav["t_s"], nav["pos_enu_m"]
    ok = np.all(np.isfinite(pos), axis=1)
    if not ok.any():
        raise SkipLayer(f"{topics.NAV_ESTIMATE} has no position (the filter never initialised)")
    t, pos = t[ok], pos[ok]
    n = len(t)
    log_path(rec, NAV_ESTIMATE_PATH_ENTITY, [pos], [NAV_ESTIMATE_COLOUR], ["estimate"])
    rec.send_columns(NAV_ESTIMATE_ENTITY, indexes=_time(t),
                     columns=rr.Points3D.columns(positions=pos, radii=np.full(n, 3.0),
                                                 colors=np.tile(NAV_ESTIMATE_COLOUR, (n, 1)),
                                                 labels=["estimate"] * n))
    if not log.topics.get(topics.UAV_STATE):
        return []
    err = pos - truth_at(log, t, "pos_enu_m", topics.UAV_STATE)
    for k, series in enumerate(NAV_ERRORS):
        _scalars(rec, series, t, err[:, k])
    return VIEWS["nav_estimate"]()


@layer("events", needs=(topics.EVENTS,))
def _events(log: RunLog, rec: rr.RecordingStream, opt: ReplayOptions) -> list:
    events = log.events()
    rec.send_columns(EVENTS_ENTITY, indexes=_time(np.array([e[0] for e in events])),
                     columns=rr.TextLog.columns(text=[e[2] for e in events],
                                                level=[TEXTLOG_LEVELS.get(e[1], "INFO") for e in events]))
    return VIEWS["events"]()


# -- the recording ----------------------------------------------------------

def export_rrd(log: RunLog | str | Path, rrd_path: str | Path, options: ReplayOptions | None = None) -> ReplayResult:
    """Write the log as a Rerun recording with a default blueprint; returns what was logged."""
    if not isinstance(log, RunLog):
        log = read_log(log)
    opt = options or ReplayOptions()
    rrd_path = Path(rrd_path)
    rrd_path.parent.mkdir(parents=True, exist_ok=True)
    meta = log.metadata.get("fwsim", {})
    # No sink yet: the stream buffers what is logged until save(), which then
    # writes it with the default blueprint built from the layers that ran.
    rec = rr.RecordingStream(opt.application_id, recording_id=log.path.stem)
    res = ReplayResult(rrd_path)
    views: list = []
    try:
        if log.scenario_text:
            log_scenario(rec, log.scenario_text)
        rec.log(RUN_ENTITY, rr.TextDocument(
            f"status: {log.status}\nreason: {log.reason}\nscenario: {meta.get('scenario', '?')}, "
            f"seed {meta.get('seed', '?')}\nfwsim {meta.get('fwsim_version', '?')}, "
            f"jsbsim {meta.get('jsbsim_version', '?')}\nlog: {log.path}"), static=True)
        for ly in LAYERS.values():
            missing = [t for t in ly.needs if not log.topics.get(t)]
            if missing:
                res.skipped.append((ly.name, f"no {', '.join(missing)} in this log"))
                continue
            try:
                views += [(ly.name, v) for v in ly.log(log, rec, opt)]
            except SkipLayer as exc:
                res.skipped.append((ly.name, str(exc)))
                continue
            res.layers.append(ly.name)
        rec.save(rrd_path, default_blueprint=default_blueprint(views))
        rec.flush()
    finally:
        rec.disconnect()
    return res


def log_scenario(rec: rr.RecordingStream, scenario_text: str) -> None:
    """The scenario file the run flew, as a YAML block (static)."""
    rec.log(SCENARIO_ENTITY, rr.TextDocument(f"```yaml\n{scenario_text}\n```", media_type="text/markdown"),
            static=True)


def blueprint_for(layers) -> rrb.Blueprint:
    """The default blueprint of a recording whose ``layers`` (names in :data:`LAYERS`) all have their data."""
    wanted = set(layers)
    return default_blueprint([(name, v) for name in LAYERS if name in wanted for v in VIEWS[name]()])


def default_blueprint(views: list[tuple[str, object]]) -> rrb.Blueprint:
    """3D view (and camera, events) on the left, the time series stacked on the right."""
    spatial = [v for _, v in views if not isinstance(v, (rrb.TimeSeriesView, rrb.TextLogView))]
    series = [v for _, v in views if isinstance(v, rrb.TimeSeriesView)]
    texts = [v for _, v in views if isinstance(v, rrb.TextLogView)]
    left = spatial + texts or [rrb.TextDocumentView(origin="run", name="run")]
    shares = [3.0 if isinstance(v, rrb.Spatial3DView) else 1.0 for v in left]
    columns = [rrb.Vertical(*left, row_shares=shares)]
    if series:
        columns.append(rrb.Vertical(*series))
    return rrb.Blueprint(rrb.Horizontal(*columns, column_shares=[3, 2][: len(columns)]),
                         rrb.TimePanel(state="expanded"), collapse_panels=False)
