"""Live Rerun view of a run: ``fwsim run SCENARIO --rerun spawn | connect[=ADDR] | save=PATH.rrd``.

:class:`RerunLive` is a :class:`~fwsim.log.LogWriter` listener: it sees each
record as the run logs it and sends a thinned copy to Rerun, with the entity
paths, timeline (``sim_time``), colours and default blueprint of the replay
(:mod:`fwsim.log.rerun_export`), so a live recording looks like a replayed
one. The MCAP log stays the record; the live view is only a view.

What it sends:

* poses (UAV, ship, camera), time series, detection boxes and target
  estimates: at most ``rate_hz`` (20 Hz) of sim time per topic, buffered and
  sent as columns about every ``send_every_s`` of wall time (0.1 s to a
  viewer, 1 s to a file);
* camera images, events and the camera's pinhole: each one as it comes;
* the UAV's and the ship's paths: growing line strips (one per flight-software
  phase, as in the replay) re-sent about every ``path_every_s`` (1 s) of wall
  time, less often as they grow, so the data sent stays linear in the flight.

A viewer that goes away is found by a flush about once a second (gRPC
targets); the sink then raises, and the LogWriter detaches it with one warning
and goes on.
"""
from __future__ import annotations

import logging
import math
import os
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal
from urllib.parse import urlsplit

import numpy as np
import rerun as rr

from fwsim.interface import topics
from fwsim.log import rerun_export as rx
from fwsim.log.rerun_export import (
    CAMERA_ENTITY,
    DETECTION_COLOUR,
    DETECTION_ENTITY,
    ESTIMATE_COLOUR,
    ESTIMATE_ENTITY,
    EVENTS_ENTITY,
    IMAGE_ENTITY,
    LAYERS,
    PHASE_COLOURS,
    RUN_ENTITY,
    SHIP_SIZE_M,
    SIGNALS,
    TARGET_COLOUR,
    TARGET_ENTITY,
    TARGET_PATH_ENTITY,
    TEXTLOG_LEVELS,
    TIMELINE,
    UAV_ENTITY,
    UAV_PATH_ENTITY,
    ReplayOptions,
)
from fwsim.log.truth import TruthStream

_logger = logging.getLogger("fwsim.log")

#: Rerun's default viewer address (what ``rerun`` listens on and ``connect`` uses).
DEFAULT_PORT = 9876
DEFAULT_URL = f"rerun+http://127.0.0.1:{DEFAULT_PORT}/proxy"
SPEC_HELP = "spawn, connect, connect=ADDR or save=PATH.rrd"

#: /tf child frames drawn live (the UAV comes from /uav/pose, as in the replay).
_TF_ENTITIES = {"camera": CAMERA_ENTITY, "ship": TARGET_ENTITY}


class LiveViewError(ValueError):
    """A bad ``--rerun`` value, or no viewer to show the run in."""


@dataclass(frozen=True)
class LiveTarget:
    """Where a live view goes: ``spawn`` a viewer, ``connect`` to one (gRPC URL), or ``save`` to an .rrd."""

    kind: Literal["spawn", "connect", "save"]
    address: str | None = None  # connect: the viewer's gRPC URL; save: the .rrd path

    def __str__(self) -> str:
        if self.kind == "spawn":
            return f"spawn (viewer on port {DEFAULT_PORT})"
        return f"{self.kind} {self.address}"


def parse_target(text: str) -> LiveTarget:
    """``spawn``, ``connect``, ``connect=ADDR`` (a port, HOST:PORT or a rerun+http://HOST:PORT/proxy URL)
    or ``save=PATH.rrd``; raises :class:`LiveViewError` with a one-line message."""
    kind, eq, arg = str(text).strip().partition("=")
    kind, arg = kind.strip().lower(), arg.strip()
    if kind == "spawn" and not eq:
        return LiveTarget("spawn", DEFAULT_URL)
    if kind == "connect":
        if not eq:
            return LiveTarget("connect", DEFAULT_URL)
        return LiveTarget("connect", _grpc_url(arg, text))
    if kind == "save":
        if not arg or not arg.lower().endswith(".rrd") or arg.endswith(("/", os.sep)):
            raise LiveViewError(f"--rerun {text!r}: save needs a file path ending in .rrd, e.g. save=run.rrd")
        return LiveTarget("save", arg)
    raise LiveViewError(f"--rerun {text!r}: expected {SPEC_HELP}")


def _grpc_url(addr: str, text: str) -> str:
    bad = LiveViewError(f"--rerun {text!r}: ADDR is a port, HOST:PORT or a rerun+http://HOST:PORT/proxy URL")
    if addr.isdigit():
        url = f"rerun+http://127.0.0.1:{addr}/proxy"
    elif addr.startswith(("rerun://", "rerun+http://", "rerun+https://")):
        url = addr
    elif ":" in addr and "/" not in addr:
        url = f"rerun+http://{addr}/proxy"
    else:
        raise bad
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError:
        raise bad from None
    if not parts.hostname or port is None or not 0 < port < 65536 or parts.path.rstrip("/") != "/proxy":
        raise bad
    return url


def _check_reachable(url: str, kind: str, timeout_s: float = 2.0) -> None:
    parts = urlsplit(url)
    try:
        socket.create_connection((parts.hostname, parts.port), timeout=timeout_s).close()
    except OSError as exc:
        hint = "start one with `rerun`, or use --rerun spawn or --rerun save=PATH.rrd" if kind == "connect" else \
            "the spawned viewer did not start; use --rerun save=PATH.rrd"
        raise LiveViewError(f"--rerun {kind}: no Rerun viewer at {url} ({exc.strerror or exc}); {hint}") from None


def _viewer_executable() -> str | None:
    """The ``rerun`` command installed beside this Python (rerun-sdk's), else None (searched on PATH)."""
    exe = Path(sys.executable).with_name("rerun.exe" if os.name == "nt" else "rerun")
    return str(exe) if exe.is_file() else None


#: Replay layers the live view does not draw (their views would stay empty): the navigation estimate beside the
#: truth is the replay's only.
_REPLAY_ONLY = ("nav_estimate",)


def live_layers(scenario=None) -> list[str]:
    """The replay layers a run of ``scenario`` fills (all those the live view draws without a scenario)."""
    names = [name for name in LAYERS if name not in _REPLAY_ONLY]
    if scenario is not None and getattr(scenario.controllers, "kind", "mission") != "mission":
        names.remove("estimate")  # only the mission's flight software estimates the target
    return names


class _Strip:
    __slots__ = ("points", "colour", "label", "phase")

    def __init__(self, points: list, colour, label: str, phase: int | None):
        self.points, self.colour, self.label, self.phase = points, colour, label, phase


class RerunLive:
    """A LogWriter listener that streams a run to Rerun as it flies.

    >>> live = RerunLive("save=run.rrd", scenario=scenario, scenario_text=text)
    >>> try:
    ...     run(scenario, text, log_path, listeners=[live])
    ... finally:
    ...     live.close()

    The constructor opens the target (spawns the viewer, checks that the
    viewer to connect to is listening, or opens the file) and raises
    :class:`LiveViewError` when it cannot. After an error while the run
    flies, the sink is ``failed`` and raises; the LogWriter then detaches it.
    """

    def __init__(self, target: LiveTarget | str, *, scenario=None, scenario_text: str = "",
                 log_path: str | os.PathLike | None = None, recording_id: str | None = None,
                 options: ReplayOptions | None = None, rate_hz: float = 20.0, send_every_s: float | None = None,
                 path_every_s: float = 1.0, health_every_s: float = 1.0, flush_timeout_s: float = 5.0):
        self.target = parse_target(target) if isinstance(target, str) else target
        self.options = options or ReplayOptions()
        self.layers = live_layers(scenario)
        self.failed = False
        self.closed = False
        self._min_dt = 1.0 / rate_hz - 1e-9
        self._grpc = self.target.kind != "save"
        if send_every_s is None:  # a viewer wants small steps; a file is read later
            send_every_s = 0.1 if self._grpc else 1.0
        self._send_every_s = send_every_s
        self._path_every_s = path_every_s
        self._health_every_s = health_every_s
        self._flush_timeout_s = flush_timeout_s

        self._init_buffers(scenario)
        self._end_line = ""
        self._run_text = self._describe(scenario, log_path)
        now = time.monotonic()
        self._next_send = now + send_every_s
        self._next_path = now + path_every_s
        self._next_health = now + health_every_s

        self._handlers = {
            topics.UAV_POSE: self._on_pose, topics.TF: self._on_tf, topics.FSW_STATUS: self._on_fsw,
            topics.TARGET_STATE: self._on_target, topics.CAMERA_CALIBRATION: self._on_calibration,
            topics.CAMERA_IMAGE: self._on_image, topics.CAMERA_DETECTION: self._on_detection,
            topics.EVENTS: self._on_event, topics.FSW_ESTIMATE: self._on_estimate,
        }

        self._rec = rr.RecordingStream(self.options.application_id, recording_id=recording_id)
        try:
            self._open(rx.blueprint_for(self.layers))
            self._log_static(scenario, scenario_text)
        except BaseException:
            self._disconnect()
            raise


    def _init_buffers(self, scenario) -> None:
        """The per-stream buffers the sink batches its sends in."""
        self._last_t: dict[str, float] = {}  # per-topic decimation
        self._scalars: dict[str, tuple[list, list]] = {}
        self._signals: dict[str, list] = {}  # topic -> the rx.SIGNALS drawn from it
        self._truth: dict[str, tuple[str, TruthStream]] = {}  # signal path -> (truth field, values waiting)
        for sig in SIGNALS:
            if sig.layer in self.layers:
                self._signals.setdefault(sig.topic, []).append(sig)
                if sig.minus_truth is not None:
                    self._truth[sig.series.path] = (sig.minus_truth, TruthStream())
        self._poses: dict[str, tuple[list, list, list]] = {}
        self._estimates: tuple[list, list] = ([], [])
        self._detections: tuple[list, list, list, list] = ([], [], [], [])  # t, boxes at t (0/1), centres, halves
        self._strips = [_Strip([], PHASE_COLOURS[1], "path", None)]
        self._target_points: list = []
        self._last_pose: tuple | None = None  # (t, translation, quaternion) of the newest UAV pose
        self._pose_sent = True
        self._cal_width: int | None = None
        self._image_scale: float | None = None
        if scenario is not None:
            cam = scenario.camera
            if cam.render.width_px and cam.width_px:
                self._image_scale = cam.render.width_px / cam.width_px

    def __str__(self) -> str:
        return f"the Rerun live view ({self.target})"

    # -- opening ------------------------------------------------------------
    def _open(self, blueprint) -> None:
        rec, kind, address = self._rec, self.target.kind, self.target.address
        if kind == "save":
            path = Path(address)
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                rec.save(path, default_blueprint=blueprint)
            except (OSError, RuntimeError) as exc:
                raise LiveViewError(f"--rerun save: cannot write {path}: {exc}") from None
        elif kind == "connect":
            _check_reachable(address, kind)
            rec.connect_grpc(address, default_blueprint=blueprint)
        else:
            if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                         or os.environ.get("WAYLAND_DISPLAY")):
                raise LiveViewError("--rerun spawn: no display for a viewer window (DISPLAY and WAYLAND_DISPLAY "
                                    "are unset); use --rerun save=PATH.rrd, or --rerun connect=ADDR to a viewer "
                                    "elsewhere")
            try:  # connects to the viewer already on the port, if there is one
                rr.spawn(port=DEFAULT_PORT, executable_path=_viewer_executable(), recording=rec,
                         default_blueprint=blueprint, hide_welcome_screen=True)
            except RuntimeError as exc:
                raise LiveViewError(f"--rerun spawn: {str(exc).splitlines()[0]}") from None
            _check_reachable(address, kind)

    def _describe(self, scenario, log_path) -> str:
        import fwsim
        name = getattr(scenario, "name", "?")
        seed = getattr(scenario, "seed", "?")
        return (f"scenario: {name}, seed {seed}\nfwsim {fwsim.__version__}\nlog: {log_path or '?'}\n"
                f"live view ({self.target.kind}); the log is the record: `fwsim replay` it for the full data")

    def _log_static(self, scenario, scenario_text: str) -> None:
        rec = self._rec
        if scenario_text:
            rx.log_scenario(rec, scenario_text)
        rec.log(RUN_ENTITY, rr.TextDocument(f"status: running\n{self._run_text}"), static=True)
        rx.log_uav_model(rec, self.options.marker_scale)
        tgt = getattr(scenario, "target", None)
        rx.log_ship_model(rec, (tgt.length_m, tgt.width_m, tgt.height_m) if tgt is not None else SHIP_SIZE_M)
        for sig in SIGNALS:
            if sig.layer in self.layers:
                rx.series_style(rec, sig.series)

    # -- the listener ---------------------------------------------------------
    def __call__(self, topic: str, t_s: float, msg: Any) -> None:
        handler = self._handlers.get(topic)
        signals = self._signals.get(topic)
        if (handler is None and signals is None) or self.closed or self.failed:
            return
        try:
            if handler is not None:
                handler(t_s, msg)
            if signals is not None and self._due(topic, t_s):
                self._on_signals(signals, t_s, msg)
            now = time.monotonic()
            if now >= self._next_send:
                self._send(now)
        except Exception:
            self.failed = True
            raise

    def _due(self, key: str, t_s: float) -> bool:
        if t_s - self._last_t.get(key, -math.inf) >= self._min_dt:
            self._last_t[key] = t_s
            return True
        return False

    def _scalar(self, series, t_s: float, value: float) -> None:
        buf = self._scalars.get(series.path)
        if buf is None:
            buf = self._scalars[series.path] = ([], [])
        buf[0].append(t_s)
        buf[1].append(value)

    def _pose(self, entity: str, t_s: float, translation: tuple, quat_xyzw: tuple) -> None:
        buf = self._poses.get(entity)
        if buf is None:
            buf = self._poses[entity] = ([], [], [])
        buf[0].append(t_s)
        buf[1].append(translation)
        buf[2].append(quat_xyzw)

    def _on_pose(self, t_s: float, msg) -> None:
        p, o = msg.pose.position, msg.pose.orientation
        pos, quat = (p.x, p.y, p.z), (o.x, o.y, o.z, o.w)
        self._last_pose = (t_s, pos, quat)
        self._pose_sent = self._due("uav", t_s)
        if self._pose_sent:
            self._pose(UAV_ENTITY, t_s, pos, quat)
            self._strips[-1].points.append(pos)

    def _on_tf(self, t_s: float, msg) -> None:
        entity = _TF_ENTITIES.get(msg.child_frame_id)
        if entity is not None and self._due(entity, t_s):
            tr, r = msg.translation, msg.rotation
            self._pose(entity, t_s, (tr.x, tr.y, tr.z), (r.x, r.y, r.z, r.w))

    def _on_signals(self, signals, t_s: float, msg) -> None:
        """The time series drawn from this message (rx.SIGNALS); those relative to the truth wait for it."""
        for sig in signals:
            if sig.minus_truth is None:
                self._scalar(sig.series, t_s, sig.value(msg))
            else:
                self._truth[sig.series.path][1].add(t_s, sig.value(msg))

    def _flush_truth(self, final: bool = False) -> None:
        """Plot the truth-relative values whose truth has arrived (all of them at the end)."""
        series = {sig.series.path: sig.series for sig in SIGNALS}
        for path, (_, stream) in self._truth.items():
            for t, value, truth in stream.ready(final):
                self._scalar(series[path], t, float(np.linalg.norm(value - truth)))

    def _on_fsw(self, t_s: float, st) -> None:
        phase = int(st.phase) if st.phase == st.phase else -1
        label = rx.phase_label(phase, st.phase_name)
        cur = self._strips[-1]
        if cur.phase == phase:
            cur.label = label  # the latest sub-phase name, as the replay's legend
            return
        colour = PHASE_COLOURS[phase % len(PHASE_COLOURS)]
        if cur.phase is None:  # the path before the first status takes its phase
            cur.phase, cur.colour, cur.label = phase, colour, label
        else:  # a new strip, joined to the last one by its last point
            self._strips.append(_Strip(cur.points[-1:], colour, label, phase))

    def _on_target(self, t_s: float, tg) -> None:
        for field, stream in self._truth.values():  # every truth sample: the interpolation needs them all
            stream.push(t_s, getattr(tg, field))
        self._flush_truth()
        if self._due("target_path", t_s):
            self._target_points.append(tuple(float(c) for c in tg.pos_enu_m))

    def _on_estimate(self, t_s: float, est) -> None:
        pos = est.pos_enu_m
        if np.all(np.isfinite(pos)) and self._due("estimate_points", t_s):
            self._estimates[0].append(t_s)
            self._estimates[1].append(tuple(float(c) for c in pos))

    def _on_calibration(self, t_s: float, cal) -> None:
        K = np.array(cal.K, dtype=float).reshape(3, 3)
        rx.log_pinhole(self._rec, K, cal.width, cal.height, self.options.frustum_m)
        self._cal_width = cal.width

    def _on_image(self, t_s: float, img) -> None:
        blob = bytes(img.data)
        if self._image_scale is None:
            width = rx.jpeg_width(blob)
            self._image_scale = width / self._cal_width if width and self._cal_width else 1.0
        self._rec.set_time(TIMELINE, duration=t_s)
        self._rec.log(IMAGE_ENTITY, rr.EncodedImage(contents=blob, media_type="image/jpeg"))

    def _on_detection(self, t_s: float, det) -> None:
        if not self._due(topics.CAMERA_DETECTION, t_s):
            return
        t, n, centres, halves = self._detections
        box = np.asarray(det.bbox_px, dtype=float) * (self._image_scale or 1.0)
        t.append(t_s)
        if det.detected and np.all(np.isfinite(box)):
            n.append(1)
            centres.append(0.5 * (box[:2] + box[2:]))
            halves.append(0.5 * (box[2:] - box[:2]))
        else:  # no box at this time: an empty one (the replay logs a Clear)
            n.append(0)

    def _on_event(self, t_s: float, msg) -> None:
        from foxglove_schemas_protobuf.Log_pb2 import Log
        text = msg.message
        level = TEXTLOG_LEVELS.get(Log.Level.Name(msg.level) if msg.level in Log.Level.values() else "", "INFO")
        self._rec.set_time(TIMELINE, duration=t_s)
        self._rec.log(EVENTS_ENTITY, rr.TextLog(text, level=level))
        if msg.name == "fwsim" and text.startswith(("run completed", "run failed", "run interrupted",
                                                    "run abandoned")):
            self._end_line = text

    # -- sending --------------------------------------------------------------
    def _send(self, now: float, final: bool = False) -> None:
        rec = self._rec
        if final:
            self._flush_truth(final=True)
        for path, (t, v) in self._scalars.items():
            if t:
                rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=t)],
                                 columns=rr.Scalars.columns(scalars=np.asarray(v, dtype=float)))
                t.clear()
                v.clear()
        for entity, (t, tr, q) in self._poses.items():
            if t:
                rec.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=t)],
                                 columns=rr.Transform3D.columns(translation=tr, quaternion=q))
                t.clear()
                tr.clear()
                q.clear()
        t, n, centres, halves = self._detections
        if t:
            k = len(centres)
            rec.send_columns(DETECTION_ENTITY, indexes=[rr.TimeColumn(TIMELINE, duration=t)],
                             columns=rr.Boxes2D.columns(centers=np.reshape(centres, (k, 2)),
                                                        half_sizes=np.reshape(halves, (k, 2)),
                                                        colors=np.tile(DETECTION_COLOUR, (k, 1)),
                                                        labels=["detection"] * k).partition(n))
            for buf in self._detections:
                buf.clear()
        t, pos = self._estimates
        if t:
            n = len(t)
            rec.send_columns(ESTIMATE_ENTITY, indexes=[rr.TimeColumn(TIMELINE, duration=t)],
                             columns=rr.Points3D.columns(positions=pos, radii=np.full(n, 4.0),
                                                         colors=np.tile(ESTIMATE_COLOUR, (n, 1))))
            t.clear()
            pos.clear()
        self._next_send = now + self._send_every_s
        if final or now >= self._next_path:
            self._send_paths()
            n = sum(len(s.points) for s in self._strips) + len(self._target_points)
            self._next_path = now + max(self._path_every_s, n / 2000.0)
        if self._grpc and not final and now >= self._next_health:
            rec.flush(timeout_sec=self._flush_timeout_s)  # raises when the viewer has gone
            self._next_health = time.monotonic() + self._health_every_s

    def _send_paths(self) -> None:
        strips = [s for s in self._strips if s.points]
        if strips:
            rx.log_path(self._rec, UAV_PATH_ENTITY, [np.asarray(s.points) for s in strips],
                        [s.colour for s in strips], [s.label for s in strips])
        if self._target_points:
            rx.log_path(self._rec, TARGET_PATH_ENTITY, [np.asarray(self._target_points)], [TARGET_COLOUR])

    # -- closing --------------------------------------------------------------
    def close(self) -> None:
        """Send what is buffered (and the run's end), flush and disconnect. Idempotent; never raises."""
        if self.closed:
            return
        self.closed = True
        if not self.failed:
            try:
                if self._last_pose is not None and not self._pose_sent:  # the run's last pose, always
                    t, pos, quat = self._last_pose
                    self._pose(UAV_ENTITY, t, pos, quat)
                    self._strips[-1].points.append(pos)
                self._send(time.monotonic(), final=True)
                status, _, reason = self._end_line[4:].partition(": ") if self._end_line else ("ended", "", "")
                self._rec.log(RUN_ENTITY, rr.TextDocument(f"status: {status}\nreason: {reason}\n{self._run_text}"),
                              static=True)
                self._rec.flush(timeout_sec=self._flush_timeout_s if self._grpc else 60.0)
            except Exception as exc:  # noqa: BLE001 - the run is over; say what is missing and go on
                self.failed = True
                _logger.warning("%s: the end of the run may be missing from it: %s: %s", self, type(exc).__name__,
                                exc)
        self._disconnect()

    def _disconnect(self) -> None:
        try:
            self._rec.disconnect()
        except Exception:  # noqa: BLE001
            pass

    def __enter__(self) -> "RerunLive":
        return self

    def __exit__(self, *exc) -> bool:
        self.close()
        return False
