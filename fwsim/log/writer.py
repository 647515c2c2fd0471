"""LogWriter: one MCAP file per simulation run (topics: docs/guide/logs.md)."""
from __future__ import annotations

import logging
import os
import struct
import sys
import time
import traceback
from itertools import chain
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, MessageIndex, Schema
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from fwsim.interface import topics
from fwsim.log.schema import spec_for

METADATA_NAME = "fwsim"
STATUS_METADATA_NAME = "run_status"
SCENARIO_ATTACHMENT = "scenario.yaml"
#: The scenario actually flown (file + command-line overrides + defaults), as YAML.
EFFECTIVE_SCENARIO_ATTACHMENT = "scenario_effective.yaml"

#: Default uncompressed chunk size: at ~120 msg/s this is a chunk every few
#: seconds of sim time, which bounds what a hard kill loses.
DEFAULT_CHUNK_SIZE = 256 * 1024

#: ``listener(topic, t_s, msg)``: called after each record is written (see LogWriter).
Listener = Callable[[str, float, Any], None]

_logger = logging.getLogger("fwsim.log")

_LEVELS = {name: value for name, value in Log.Level.items()}
_LEVELS.update({"WARN": _LEVELS["WARNING"], "CRITICAL": _LEVELS["FATAL"]})


def _level_value(level: str | int) -> int:
    if isinstance(level, int):
        return level
    try:
        return _LEVELS[level.upper()]
    except KeyError:
        raise ValueError(f"unknown log level {level!r}; use one of {sorted(_LEVELS)}") from None


#: the fwsim metadata key holding the log's epoch: every log time and Foxglove stamp is this + sim time (ns)
EPOCH_KEY = "log_time_epoch_ns"


def _utc_text(epoch_ns: int) -> str:
    from datetime import datetime, timezone
    return datetime.fromtimestamp(epoch_ns * 1e-9, tz=timezone.utc).isoformat(timespec="milliseconds")


def _ns(t_s: float) -> int:
    """Sim time in seconds -> MCAP nanoseconds (MCAP times are unsigned)."""
    ns = int(t_s * 1e9)
    return ns if ns > 0 else 0


def _floats(v) -> list[float]:
    """A vector's elements as Python floats (an array's ``tolist``: iterating it makes a numpy scalar of each)."""
    return v.tolist() if type(v) is np.ndarray and v.dtype == np.float64 else [float(x) for x in v]


_MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # opcode, record length, channel id, sequence, log time, publish time


_INDEX_HEAD = struct.Struct("<BQHI")  # opcode, record length, channel id, records' length


class _MessageIndex(MessageIndex):
    """mcap's MessageIndex written in one ``struct`` call (the library packs each time and offset apart)."""

    def write(self, stream) -> None:
        n = len(self.records)
        stream.write(_INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 6 + 16 * n, self.channel_id, 16 * n))
        stream.write(struct.pack(f"<{2 * n}Q", *chain.from_iterable(self.records)))


class _FastChunkBuilder:
    """mcap's ChunkBuilder with the message records packed in one ``struct`` call into a bytearray (the
    library builds each through a BytesIO, five packs and a seek: most of a message's cost). The records
    are added by :meth:`_FastWriter.add_message`."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.message_indices: dict[int, MessageIndex] = {}
        self.message_start_time = 0
        self.message_end_time = 0
        self.num_messages = 0

    @property
    def count(self) -> int:
        return len(self.buf)

    def _record(self, record) -> None:
        rb = RecordBuilder()
        record.write(rb)
        self.buf += rb.end()

    def add_channel(self, channel) -> None:
        self._record(channel)

    def add_schema(self, schema) -> None:
        self._record(schema)

    def end(self) -> bytes:
        out = bytes(self.buf)
        self.buf = bytearray()
        return out

    def reset(self) -> None:
        self.message_end_time = 0
        self.message_indices.clear()
        self.message_start_time = 0
        self.buf = bytearray()
        self.num_messages = 0


class _FastWriter(Writer):
    """``mcap.writer.Writer`` whose ``add_message`` packs each record in one call (:class:`_FastChunkBuilder`):
    the same file, byte for byte. It reaches into the writer's private state (its statistics, chunk
    builder and chunk size); ``fast`` is False, and the library's own path is used, if a future ``mcap``
    lays them out otherwise."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        names = ("_Writer__statistics", "_Writer__chunk_builder", "_Writer__chunk_size", "_Writer__finalize_chunk")
        self.fast = all(hasattr(self, n) for n in names) and self._Writer__chunk_builder is not None
        if self.fast:
            self._Writer__chunk_builder = _FastChunkBuilder()
            self._stats = self._Writer__statistics
            self._chunk = self._Writer__chunk_builder
            self._chunk_size = self._Writer__chunk_size

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0):
        if not self.fast:
            return super().add_message(channel_id, log_time, data, publish_time, sequence)
        # the chunk's time range, message index and record (the file's statistics: when the chunk is finished)
        chunk = self._chunk
        if chunk.num_messages == 0 or log_time < chunk.message_start_time:
            chunk.message_start_time = log_time
        if log_time > chunk.message_end_time:
            chunk.message_end_time = log_time
        chunk.num_messages += 1
        buf = chunk.buf
        index = chunk.message_indices.get(channel_id)
        if index is None:
            index = chunk.message_indices[channel_id] = _MessageIndex(channel_id=channel_id, records=[])
        index.records.append((log_time, len(buf)))
        buf += _MESSAGE_HEAD.pack(Opcode.MESSAGE, 22 + len(data), channel_id, sequence, log_time, publish_time)
        buf += data
        if len(buf) > self._chunk_size:
            self._Writer__finalize_chunk()

    def _Writer__finalize_chunk(self):
        chunk = self._chunk if self.fast else None
        if chunk is not None and chunk.num_messages:  # its messages into the file's statistics, as add_message's
            st = self._stats
            if st.message_count == 0 or chunk.message_start_time < st.message_start_time:
                st.message_start_time = chunk.message_start_time
            if chunk.message_end_time > st.message_end_time:
                st.message_end_time = chunk.message_end_time
            counts = st.channel_message_counts
            for channel_id, index in chunk.message_indices.items():
                counts[channel_id] += len(index.records)
            st.message_count += chunk.num_messages
        super()._Writer__finalize_chunk()


class _FlushingFile:
    """File wrapper that hands every write to the OS at once.

    ``mcap.writer.Writer`` only writes whole records (a chunk and its message
    indexes, a metadata record, ...), so this costs a few syscalls per chunk
    and means a SIGKILL loses at most the chunk being built.
    """

    __slots__ = ("_f",)

    def __init__(self, f):
        self._f = f

    def write(self, data: bytes) -> int:
        n = self._f.write(data)
        self._f.flush()
        return n

    def tell(self) -> int:
        return self._f.tell()

    def close(self) -> None:
        self._f.close()


def describe_exception(exc: BaseException) -> str:
    """``"ExcType: message (at file:line)"`` with the innermost traceback frame."""
    text = f"{type(exc).__name__}: {exc}"
    tb = traceback.extract_tb(exc.__traceback__) if exc.__traceback__ else None
    if tb:
        frame = tb[-1]
        fname = frame.filename
        try:
            rel = os.path.relpath(fname)
            if not rel.startswith(".."):
                fname = rel
        except ValueError:  # other drive on Windows
            pass
        text += f" (at {fname}:{frame.lineno})"
    return text


def status_for_exception(exc: BaseException) -> tuple[str, str]:
    """The (status, reason) recorded when ``exc`` ends a run."""
    if isinstance(exc, (KeyboardInterrupt, SystemExit)):
        return "interrupted", describe_exception(exc)
    return "failed", describe_exception(exc)


class LogWriter:
    """Writes one run's MCAP log.

    >>> with LogWriter(path, metadata={...}, scenario_text=text) as log:
    ...     log.write_state(state)            # /uav/state, /tf, /uav/pose
    ...     log.write_nav_estimate(est)       # /nav/estimate, and /tf (uav_estimate), /nav/pose once it has a pose
    ...     log.write(topics.AUTOPILOT_STATUS, status_msg)
    ...     log.write_event(t, "phase: terminal")

    Leaving the with-block normally records status "completed"; an exception
    records "failed" (or "interrupted" for KeyboardInterrupt/SystemExit) and
    propagates. ``close()`` may be called any number of times.

    Listeners (``listeners=[fn]`` or ``add_listener(fn)``) see every record
    after it is written, as ``fn(topic, t_s, msg)``: ``msg`` is the dataclass
    given to ``write`` (``write_state`` gives the state on /uav/state, then
    the ``foxglove`` protobuf messages on /tf and /uav/pose; ``write_nav_estimate``
    likewise on /nav/estimate, /tf and /nav/pose), or the protobuf
    message of ``write_transform``, ``write_image``, ``write_calibration`` and
    ``write_event`` (the end-of-run line included). Protobuf messages may be
    reused by the writer: read them during the call, do not keep them. A
    listener that raises is detached with one warning (logger ``fwsim.log``);
    the log goes on. Without listeners a record costs one truth test more.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        metadata: dict[str, str],
        scenario_text: str,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        listeners: Iterable[Listener] = (),
        epoch_ns: int = 0,
        keep: Iterable[str] = (),
    ):
        self.path = Path(path)
        self._init_kept(keep)
        self._t0 = int(epoch_ns)  # log times and stamps = epoch + sim time (Foxglove shows a real date)
        metadata = {**metadata, EPOCH_KEY: str(self._t0), "log_time_epoch_utc": _utc_text(self._t0)}
        self._listeners: list[Listener] = list(listeners)
        self._file = open(self.path, "wb")
        self._closed = False
        try:
            self._mcap = _FastWriter(
                _FlushingFile(self._file),
                chunk_size=chunk_size,
                compression=CompressionType.ZSTD,
            )
            from fwsim import __version__

            self._add_message = self._mcap.add_message  # (channel id, log time, data, publish time, sequence)
            self._mcap.start(profile="", library=f"fwsim/{__version__}")
            self._mcap.add_metadata(METADATA_NAME, {str(k): str(v) for k, v in metadata.items()})
            self._kept_metadata[METADATA_NAME] = {str(k): str(v) for k, v in metadata.items()}
            self._kept_attachments[SCENARIO_ATTACHMENT] = scenario_text.encode("utf-8")
            self._mcap.add_attachment(
                create_time=time.time_ns(),
                log_time=self._t0,
                name=SCENARIO_ATTACHMENT,
                media_type="application/yaml",
                data=scenario_text.encode("utf-8"),
            )
        except BaseException:
            self._file.close()
            self._closed = True
            raise
        self.last_t_s = 0.0
        # (topic, type) -> [channel_id, spec, sequence]
        self._json_channels: dict[tuple[str, type], list] = {}
        self._json_schemas: dict[type, int] = {}
        self._proto_channels: dict[str, list] = {}  # topic -> [channel_id, sequence]
        self._proto_schemas: dict[str, int] = {}
        self._quat = None  # fwsim.interface.frames.quat_enu_from_frd, imported on first use
        # Reused protobuf messages (set fields, serialise; no per-call allocation).
        self._tf = FrameTransform(parent_frame_id=topics.WORLD_FRAME, child_frame_id=topics.UAV_FRAME)
        self._transforms: dict[tuple[str, str], FrameTransform] = {}  # write_transform's, by (parent, child)
        self._pose = PoseInFrame(frame_id=topics.WORLD_FRAME)
        self._nav_msgs = None  # the (FrameTransform, PoseInFrame) write_nav_estimate reuses, made on first use
        self._fix = None  # the LocationFix reused by write_location
        self._log = Log()

    def _init_kept(self, keep: Iterable[str]) -> None:
        """Topics also kept in memory, with the metadata and attachments: :meth:`kept_log` reads them back
        without reading the file (what a run's one-line result needs)."""
        self._keep = frozenset(keep)
        self._kept: dict[str, list[tuple[int, bytes, int]]] = {t: [] for t in self._keep}
        self._kept_channels: dict[int, Any] = {}
        self._kept_schemas: dict[int, Any] = {}
        self._kept_metadata: dict[str, dict[str, str]] = {}
        self._kept_attachments: dict[str, bytes] = {}

    # -- registration -----------------------------------------------------
    def _json_channel(self, topic: str, cls: type, first: Any) -> list:
        spec = spec_for(cls)
        schema_id = self._json_schemas.get(cls)
        if schema_id is None:  # the schema gives each array the length of the type's first message
            schema_id = self._mcap.register_schema(
                name=spec.schema_name, encoding="jsonschema", data=spec.schema_json_for(first)
            )
            self._json_schemas[cls] = schema_id
        channel_id = self._mcap.register_channel(
            topic=topic, message_encoding="json", schema_id=schema_id
        )
        if topic in self._keep:
            self._kept_channels[channel_id] = Channel(id=channel_id, topic=topic, message_encoding="json",
                                                      schema_id=schema_id, metadata={})
            self._kept_schemas[schema_id] = Schema(id=schema_id, name=spec.schema_name, encoding="jsonschema",
                                                   data=spec.schema_json_for(first))
        entry = [channel_id, spec, 0]
        self._json_channels[(topic, cls)] = entry
        return entry

    def _proto_channel(self, topic: str, message_class: Any) -> list:
        name = message_class.DESCRIPTOR.full_name
        schema_id = self._proto_schemas.get(name)
        if schema_id is None:
            fds = build_file_descriptor_set(message_class)
            schema_id = self._mcap.register_schema(
                name=name, encoding="protobuf", data=fds.SerializeToString()
            )
            self._proto_schemas[name] = schema_id
        channel_id = self._mcap.register_channel(
            topic=topic, message_encoding="protobuf", schema_id=schema_id
        )
        entry = [channel_id, 0]
        self._proto_channels[topic] = entry
        return entry

    def _write_proto(self, topic: str, msg: Any, log_time: int) -> None:
        entry = self._proto_channels.get(topic) or self._proto_channel(topic, type(msg))
        entry[1] += 1
        self._add_message(entry[0], log_time, msg.SerializeToString(), log_time, entry[1])
        if self._listeners:
            self._notify(topic, (log_time - self._t0) * 1e-9, msg)

    # -- listeners --------------------------------------------------------
    def add_listener(self, fn: Listener) -> None:
        """Call ``fn(topic, t_s, msg)`` after each record from now on (see the class docstring)."""
        self._listeners.append(fn)

    def remove_listener(self, fn: Listener) -> None:
        if fn in self._listeners:
            self._listeners.remove(fn)

    @property
    def listeners(self) -> tuple[Listener, ...]:
        return tuple(self._listeners)

    def _notify(self, topic: str, t_s: float, msg: Any) -> None:
        for fn in tuple(self._listeners):
            try:
                fn(topic, t_s, msg)
            except Exception as exc:  # a view must never stop the run or its log
                self.remove_listener(fn)
                _logger.warning("%s failed at t = %.2f s on %s and is detached; the run and its log go on: %s: %s",
                                fn, t_s, topic, type(exc).__name__, exc)

    # -- writing ----------------------------------------------------------
    def write(self, topic: str, msg: Any) -> None:
        """Write a dataclass message (first field t_s) as JSON on ``topic``."""
        if self._closed:
            raise ValueError(f"LogWriter for {self.path} is closed")
        entry = self._json_channels.get((topic, type(msg)))
        if entry is None:
            entry = self._json_channel(topic, type(msg), msg)
        entry[2] += 1
        t_s = msg.t_s
        if t_s > self.last_t_s:
            self.last_t_s = t_s
        ns = int(t_s * 1e9)  # _ns(t_s), inline: every message passes here
        ns = self._t0 + (ns if ns > 0 else 0)
        data = entry[1].encode(msg)
        self._add_message(entry[0], ns, data, ns, entry[2])
        if topic in self._keep:
            self._kept[topic].append((ns, data, entry[0]))
        if self._listeners:
            self._notify(topic, t_s, msg)

    def write_state(self, state) -> None:
        """Write an AirframeState on /uav/state (JSON), /tf and /uav/pose (Foxglove)."""
        self.write(topics.UAV_STATE, state)
        self._write_pose(state.t_s, state.pos_enu_m, state.euler_ned_rad, self._tf, topics.UAV_POSE, self._pose)

    def write_nav_estimate(self, est) -> None:
        """Write a NavEstimate on /nav/estimate (JSON) and, once it has a pose, that pose as the truth's is
        written (/tf frame uav_estimate, /nav/pose), so that Foxglove draws the estimate beside the truth."""
        self.write(topics.NAV_ESTIMATE, est)
        pos, euler = est.pos_enu_m, est.euler_ned_rad
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(euler))):
            return  # initialising: no pose yet
        msgs = self._nav_msgs
        if msgs is None:
            msgs = self._nav_msgs = (
                FrameTransform(parent_frame_id=topics.WORLD_FRAME, child_frame_id=topics.UAV_ESTIMATE_FRAME),
                PoseInFrame(frame_id=topics.WORLD_FRAME))
        self._write_pose(est.t_s, pos, euler, msgs[0], topics.NAV_POSE, msgs[1])

    def _write_pose(self, t_s: float, pos_enu_m, euler_ned_rad, tf, pose_topic: str, pose) -> None:
        """A body pose (position ENU, NED Euler angles of the FRD body) on /tf as ``tf`` and on ``pose_topic``
        as ``pose`` (reused messages: every field that changes is set here)."""
        quat = self._quat
        if quat is None:
            from fwsim.interface.frames import quat_enu_from_frd

            quat = self._quat = quat_enu_from_frd
        w, x, y, z = quat(euler_ned_rad).tolist()
        px, py, pz = _floats(pos_enu_m)
        ns = self._t0 + _ns(t_s)
        sec, nanos = divmod(ns, 1_000_000_000)

        tf.timestamp.seconds = sec
        tf.timestamp.nanos = nanos
        tr, rot = tf.translation, tf.rotation
        tr.x, tr.y, tr.z = px, py, pz
        rot.w, rot.x, rot.y, rot.z = w, x, y, z
        self._write_proto(topics.TF, tf, ns)

        pose.timestamp.seconds = sec
        pose.timestamp.nanos = nanos
        pos, ori = pose.pose.position, pose.pose.orientation
        pos.x, pos.y, pos.z = px, py, pz
        ori.w, ori.x, ori.y, ori.z = w, x, y, z
        self._write_proto(pose_topic, pose, ns)

    def add_attachment(self, name: str, data: bytes, media_type: str = "application/octet-stream") -> None:
        """Attach a file (e.g. the effective scenario) to the log."""
        if self._closed:
            raise ValueError(f"LogWriter for {self.path} is closed")
        self._kept_attachments[name] = bytes(data)
        self._mcap.add_attachment(create_time=time.time_ns(), log_time=self._t0, name=name, media_type=media_type,
                                  data=data)

    def write_transform(self, t_s: float, child_frame_id: str, pos, quat_wxyz,
                        parent_frame_id: str = topics.WORLD_FRAME) -> None:
        """A foxglove.FrameTransform on /tf: ``child`` posed in ``parent`` (e.g. the camera, the ship)."""
        ns = self._t0 + _ns(t_s)
        msg = self._transforms.get((parent_frame_id, child_frame_id))
        if msg is None:  # one reused message per pair of frames (every field is set below)
            msg = self._transforms[(parent_frame_id, child_frame_id)] = FrameTransform(
                parent_frame_id=parent_frame_id, child_frame_id=child_frame_id)
        msg.timestamp.seconds, msg.timestamp.nanos = divmod(ns, 1_000_000_000)
        tr = msg.translation
        tr.x, tr.y, tr.z = _floats(pos)
        r = msg.rotation
        r.w, r.x, r.y, r.z = _floats(quat_wxyz)
        self._write_proto(topics.TF, msg, ns)

    def write_location(self, t_s: float, frame_id: str, lat_deg: float, lon_deg: float, alt_m: float) -> None:
        """A foxglove.LocationFix on /uav/fix (Foxglove's map panel)."""
        ns = self._t0 + _ns(t_s)
        msg = self._fix
        if msg is None:
            msg = self._fix = LocationFix(frame_id=frame_id, position_covariance_type=LocationFix.UNKNOWN)
        msg.timestamp.seconds, msg.timestamp.nanos = divmod(ns, 1_000_000_000)
        msg.latitude, msg.longitude, msg.altitude = float(lat_deg), float(lon_deg), float(alt_m)
        self._write_proto(topics.UAV_FIX, msg, ns)

    def write_image_annotations(self, topic: str, t_s: float, boxes) -> None:
        """A foxglove.ImageAnnotations: ``boxes`` of (u0, v0, u1, v1) in the image's pixels, (r, g, b) in [0, 1],
        and a label, drawn as outlined rectangles with their labels (stamped like the image they go on)."""
        from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
        ns = self._t0 + _ns(t_s)
        sec, nanos = divmod(ns, 1_000_000_000)
        msg = ImageAnnotations()
        for (u0, v0, u1, v1), (r, g, b), label in boxes:
            pa = msg.points.add(type=PointsAnnotation.LINE_LOOP, thickness=1.0)
            pa.timestamp.seconds, pa.timestamp.nanos = sec, nanos
            pa.outline_color.r, pa.outline_color.g, pa.outline_color.b, pa.outline_color.a = r, g, b, 1.0
            for u, v in ((u0, v0), (u1, v0), (u1, v1), (u0, v1)):
                pa.points.add(x=float(u), y=float(v))
            text = msg.texts.add(text=label, font_size=10.0)
            text.timestamp.seconds, text.timestamp.nanos = sec, nanos
            text.position.x, text.position.y = float(u0), max(float(v0) - 2.0, 0.0)
            text.text_color.r, text.text_color.g, text.text_color.b, text.text_color.a = r, g, b, 1.0
        self._write_proto(topic, msg, ns)

    def write_scene_models(self, topic: str, t_s: float, models) -> None:
        """A foxglove.SceneUpdate of frame-locked triangle meshes that live for the whole log: ``models`` of
        (entity id, frame id, mesh with ``vertices`` and ``faces`` in that frame, (r, g, b, a)) (Foxglove's 3D
        panel then draws them wherever /tf puts their frames)."""
        from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
        ns = self._t0 + _ns(t_s)
        msg = SceneUpdate()
        for entity_id, frame_id, mesh, (r, g, b, a) in models:
            ent = msg.entities.add(id=entity_id, frame_id=frame_id, frame_locked=True)
            ent.timestamp.seconds, ent.timestamp.nanos = divmod(ns, 1_000_000_000)
            tri = ent.triangles.add()
            tri.pose.orientation.w = 1.0
            tri.color.r, tri.color.g, tri.color.b, tri.color.a = r, g, b, a
            verts = mesh.vertices.tolist()
            for face in mesh.faces.tolist():
                for i in face:
                    x, y, z = verts[i]
                    tri.points.add(x=float(x), y=float(y), z=float(z))
        self._write_proto(topic, msg, ns)

    def write_scene_lines(self, topic: str, t_s: float, lines) -> None:
        """A foxglove.SceneUpdate of line strips that stay for the rest of the log: ``lines`` of (entity id,
        frame id, points (n, 3) in that frame, (r, g, b, a), thickness in pixels). A path sent as one new
        entity per segment costs each point once (Foxglove keeps every entity until the log ends)."""
        from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
        from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
        ns = self._t0 + _ns(t_s)
        msg = SceneUpdate()
        for entity_id, frame_id, points, (r, g, b, a), thickness in lines:
            ent = msg.entities.add(id=entity_id, frame_id=frame_id)
            ent.timestamp.seconds, ent.timestamp.nanos = divmod(ns, 1_000_000_000)
            line = ent.lines.add(type=LinePrimitive.LINE_STRIP, thickness=float(thickness), scale_invariant=True)
            line.pose.orientation.w = 1.0
            line.color.r, line.color.g, line.color.b, line.color.a = r, g, b, a
            for x, y, z in np.asarray(points, float).tolist():
                line.points.add(x=x, y=y, z=z)
        self._write_proto(topic, msg, ns)

    def write_image(self, topic: str, t_s: float, frame_id: str, data: bytes, fmt: str = "jpeg") -> None:
        """A foxglove.CompressedImage (e.g. a rendered camera frame)."""
        ns = self._t0 + _ns(t_s)
        msg = CompressedImage(frame_id=frame_id, data=data, format=fmt)
        msg.timestamp.seconds, msg.timestamp.nanos = divmod(ns, 1_000_000_000)
        self._write_proto(topic, msg, ns)

    def write_calibration(self, topic: str, t_s: float, frame_id: str, width: int, height: int, K) -> None:
        """A foxglove.CameraCalibration (pinhole, no distortion) so viewers can draw the frustum."""
        ns = self._t0 + _ns(t_s)
        K = [float(k) for k in (K.ravel() if hasattr(K, "ravel") else K)]
        P = [K[0], K[1], K[2], 0.0, K[3], K[4], K[5], 0.0, K[6], K[7], K[8], 0.0]
        msg = CameraCalibration(frame_id=frame_id, width=width, height=height, distortion_model="plumb_bob",
                                D=[0.0] * 5, K=K, R=[1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0], P=P)
        msg.timestamp.seconds, msg.timestamp.nanos = divmod(ns, 1_000_000_000)
        self._write_proto(topic, msg, ns)

    def write_event(
        self, t_s: float | None, text: str, level: str | int = "INFO", name: str = "fwsim"
    ) -> None:
        """Write a foxglove.Log on /events (phase switches, warnings, end of run).

        ``t_s=None`` stamps the event with the latest time written so far.
        """
        if self._closed:
            raise ValueError(f"LogWriter for {self.path} is closed")
        self._event(t_s, text, level, name)

    def _event(self, t_s: float | None, text: str, level: str | int, name: str) -> None:
        if t_s is None:
            t_s = self.last_t_s
        elif t_s > self.last_t_s:
            self.last_t_s = t_s
        ns = self._t0 + _ns(t_s)
        log = self._log
        log.timestamp.seconds, log.timestamp.nanos = divmod(ns, 1_000_000_000)
        log.level = _level_value(level)
        log.message = str(text)
        log.name = name
        self._write_proto(topics.EVENTS, log, ns)

    def kept_log(self):
        """The topics given as ``keep``, with the metadata and attachments, as a :class:`fwsim.log.RunLog` read
        from memory: what :func:`fwsim.log.read_log` would give of those topics, without reading the file."""
        from fwsim.log.reader import log_from_records
        return log_from_records(self.path, self._kept, self._kept_channels, self._kept_schemas,
                                self._kept_metadata, self._kept_attachments, complete=self._closed)

    # -- closing ----------------------------------------------------------
    @property
    def closed(self) -> bool:
        return self._closed

    def close(self, status: str | None = None, reason: str = "") -> None:
        """Record the run status and finish the file (summary + footer). Idempotent.

        ``status=None`` (the default) means "completed" unless an exception is
        being handled right now (a ``finally:`` or ``except:`` block), in
        which case the status is derived from it as in ``__exit__``.
        """
        if self._closed:
            return
        if status is None:
            exc = sys.exc_info()[1]
            if exc is None:
                status = "completed"
            else:
                status, exc_reason = status_for_exception(exc)
                reason = reason or exc_reason
        self._closed = True
        try:
            try:
                level = "INFO" if status == "completed" else "ERROR"
                text = f"run {status}" + (f": {reason}" if reason else "")
                self._event(None, text, level, "fwsim")
            finally:
                self._kept_metadata[STATUS_METADATA_NAME] = {"status": str(status), "reason": str(reason)}
                self._mcap.add_metadata(
                    STATUS_METADATA_NAME, {"status": str(status), "reason": str(reason)}
                )
                self._mcap.finish()
        finally:
            self._file.close()

    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc is None:
            self.close("completed")
            return False
        status, reason = status_for_exception(exc)
        try:
            self.close(status, reason)
        except Exception as close_exc:  # never mask the run's own exception
            exc.add_note(f"fwsim.log: closing {self.path} failed too: {close_exc!r}")
        return False

    def __del__(self):
        # A writer dropped without close(): leave the file readable (status
        # unknown is worse than "abandoned"); never raise from a finaliser.
        try:
            if not self._closed:
                self.close("abandoned", "LogWriter garbage-collected without close()")
        except Exception:
            pass
