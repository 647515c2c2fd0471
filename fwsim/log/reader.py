"""read_log: load a run's MCAP log (also one cut off by a hard kill)."""
from __future__ import annotations

import io
import json
import os
import struct
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import zstandard
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, Metadata, Schema
from mcap.writer import MCAP0_MAGIC

from fwsim.interface import topics
from fwsim.log.writer import EPOCH_KEY, METADATA_NAME, SCENARIO_ATTACHMENT, STATUS_METADATA_NAME

_LEVEL_NAMES = {value: name for name, value in Log.Level.items()}
_MISSING = object()


class RunLog:
    """The contents of one run's log. Build it with :func:`read_log`.

    Attributes:
        path: the file read.
        metadata: every metadata record, ``{record name: {key: value}}``
            (``"fwsim"``: versions, seed, ...; ``"run_status"``).
        status, reason: from the ``run_status`` record; ``"unknown"`` / an
            explanation when the record is missing (file cut off).
        truncated: True when the file ended before its footer; only the
            complete chunks before the cut were read.
        scenario_text: the ``scenario.yaml`` attachment ("" if missing).
        attachments: every attachment, ``{name: bytes}``.
        topics: ``{topic: message count}`` in order of first appearance.
    """

    def __init__(self, path: Path):
        self.path = path
        self.metadata: dict[str, dict[str, str]] = {}
        self.attachments: dict[str, bytes] = {}
        self.truncated = False
        self.truncation_error = ""
        self.corrupted = False  # a record that does not parse (not just a file cut short)
        self.status = "unknown"
        self.reason = ""
        self.scenario_text = ""
        self.effective_scenario_text = ""  # the scenario actually flown (overrides applied); "" if absent
        #: the flown scenario itself (a fwsim.scenario.Scenario) when the log was kept in memory by the run
        #: that flew it (fwsim.sim.loop.RunResult.result_log); None for a file read, whose metrics parse
        #: effective_scenario_text
        self.scenario = None
        self.topics: dict[str, int] = {}
        self.epoch_ns = 0  # log times and Foxglove stamps = epoch + sim time (metadata fwsim.log_time_epoch_ns)
        # topic -> list of (sim time ns, data, channel_id)
        self._messages: dict[str, list[tuple[int, bytes, int]]] = defaultdict(list)
        self._channels: dict[int, Channel] = {}
        self._schemas: dict[int, Schema] = {}
        self._tables: dict[str, dict[str, np.ndarray]] = {}

    def __repr__(self) -> str:
        return (
            f"RunLog({str(self.path)!r}, status={self.status!r}, "
            f"truncated={self.truncated}, topics={self.topics})"
        )

    # -- raw access -------------------------------------------------------
    def encoding(self, topic: str) -> str:
        """The message encoding of ``topic`` ("json", "protobuf")."""
        self._check_topic(topic)
        return next(c.message_encoding for c in self._channels.values() if c.topic == topic)

    def sim_time(self, stamp) -> float:
        """Sim time in seconds of a Foxglove message's ``timestamp`` (stamps count from the log's epoch)."""
        return (stamp.seconds * 1_000_000_000 + stamp.nanos - self.epoch_ns) * 1e-9

    def raw(self, topic: str) -> list[tuple[int, bytes]]:
        """(sim time ns, message bytes) of every message on ``topic``, in file order (the log time less the
        log's epoch)."""
        self._check_topic(topic)
        return [(t, d) for t, d, _ in self._messages[topic]]

    def _check_topic(self, topic: str) -> None:
        if topic not in self.topics:
            raise KeyError(f"no topic {topic!r} in {self.path}; topics: {list(self.topics)}")

    # -- JSON topics ------------------------------------------------------
    def _declared(self, channel_id: int) -> dict[str, tuple[str, int]]:
        """{field: (JSON type, array length or 0)} of the numbers and arrays a JSON channel's schema declares
        (a field left out of a message because it was NaN reads back as NaN)."""
        ch = self._channels.get(channel_id)
        sc = self._schemas.get(ch.schema_id) if ch is not None else None
        try:
            props = json.loads(sc.data).get("properties", {}) if sc is not None else {}
            return {k: (p.get("type"), int(p.get("maxItems", 0))) for k, p in props.items()
                    if p.get("type") in ("number", "array")}
        except (ValueError, TypeError, AttributeError):
            return {}

    def fields(self, topic: str) -> list[str]:
        """The fields of a JSON topic's messages as their schemas declare them (a number or array field may be
        absent from a message where it was NaN)."""
        self._check_topic(topic)
        out: dict[str, None] = {}
        for cid, ch in self._channels.items():
            sc = self._schemas.get(ch.schema_id) if ch.topic == topic else None
            if sc is not None and sc.encoding == "jsonschema":
                try:
                    out.update(dict.fromkeys(json.loads(sc.data).get("properties", {})))
                except (ValueError, AttributeError):
                    pass
        return list(out)

    def schema_name(self, topic: str) -> str:
        """The schema name of ``topic``'s first channel (e.g. ``foxglove.FrameTransform``)."""
        self._check_topic(topic)
        ch = next(c for c in self._channels.values() if c.topic == topic)
        sc = self._schemas.get(ch.schema_id)
        return sc.name if sc is not None else ""

    def rows(self, topic: str) -> list[dict[str, Any]]:
        """The messages of a JSON topic as dicts (a number left out or null -> NaN, arrays stay lists)."""
        if self.encoding(topic) != "json":
            raise ValueError(f"{topic} is not a JSON topic")
        out = []
        declared: dict[int, dict] = {}
        for _, data, cid in self._messages[topic]:
            d = _loads(data)
            if cid not in declared:
                declared[cid] = self._declared(cid)
            for k, (typ, width) in declared[cid].items():
                if k not in d:
                    d[k] = np.nan if typ == "number" else [np.nan] * width
            for k, v in d.items():
                if v is None:
                    d[k] = np.nan
                elif type(v) is list:
                    d[k] = [np.nan if x is None else x for x in v]
            out.append(d)
        return out

    def table(self, topic: str) -> dict[str, np.ndarray]:
        """Column arrays of a JSON topic.

        Numbers -> (n,) float64 (null -> NaN); booleans -> (n,) bool;
        strings -> (n,) object; number arrays -> (n, k) float64. Always has
        "t_s". When a topic carries several message types (e.g. rate and accel
        autopilot commands), columns are the union of their fields and a
        message without a field gets NaN (numbers) or None (strings).
        Cached: do not modify the returned arrays in place.
        """
        cached = self._tables.get(topic)
        if cached is not None:
            return cached
        if self.encoding(topic) != "json":
            raise ValueError(f"{topic} is not a JSON topic; see events()/poses()/raw()")
        msgs = self._messages[topic]
        rows = _loads(b"[" + b",".join(m[1] for m in msgs) + b"]")
        keys: dict[str, None] = {}
        for r in rows:  # a field left out of some messages (NaN there) is still a column
            keys.update(r)
        declared: dict[str, tuple[str, int]] = {}
        for cid in dict.fromkeys(m[2] for m in msgs):
            declared.update(self._declared(cid))
        columns = {k: [r.get(k, _MISSING) for r in rows] for k in keys}
        if "t_s" not in columns:
            columns["t_s"] = [m[0] * 1e-9 for m in msgs]
        table = {k: _to_array(v) for k, v in columns.items()}
        for k, (typ, width) in declared.items():  # declared but NaN in every message
            if k not in table:
                table[k] = np.full(len(msgs), np.nan) if typ == "number" else np.full((len(msgs), width), np.nan)
        self._tables[topic] = table
        return table

    # -- Foxglove topics --------------------------------------------------
    def events(self) -> list[tuple[float, str, str]]:
        """(t_s, level name, text) of every /events entry."""
        if topics.EVENTS not in self.topics:
            return []
        out = []
        for _, data, _ in self._messages[topics.EVENTS]:
            m = Log.FromString(data)
            t_s = self.sim_time(m.timestamp)
            out.append((t_s, _LEVEL_NAMES.get(m.level, str(m.level)), m.message))
        return out

    def poses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t_s (n,), pos_enu_m (n, 3), quat_wxyz (n, 4)) from /uav/pose."""
        msgs = self._messages.get(topics.UAV_POSE, []) if topics.UAV_POSE in self.topics else []
        n = len(msgs)
        t = np.empty(n)
        pos = np.empty((n, 3))
        quat = np.empty((n, 4))
        for i, (_, data, _) in enumerate(msgs):
            m = PoseInFrame.FromString(data)
            t[i] = self.sim_time(m.timestamp)
            p, q = m.pose.position, m.pose.orientation
            pos[i] = (p.x, p.y, p.z)
            quat[i] = (q.w, q.x, q.y, q.z)
        return t, pos, quat


def _loads(data: bytes) -> Any:
    """JSON text to Python: orjson (fast), the standard library for what it refuses (a bare NaN)."""
    try:
        return orjson.loads(data)
    except orjson.JSONDecodeError:
        return json.loads(data)


def _to_array(values: list) -> np.ndarray:
    """One column: floats (None/missing -> NaN), (n, k) floats, bools or objects."""
    first = next((v for v in values if v is not _MISSING and v is not None), None)
    complete = _MISSING not in values
    if type(first) is bool:
        if complete and None not in values:
            return np.array(values, dtype=bool)
    elif type(first) in (int, float):
        try:
            return np.array(
                values if complete else [None if v is _MISSING else v for v in values], dtype=float
            )
        except (TypeError, ValueError):
            pass
    elif type(first) is list:
        width = max(len(v) for v in values if type(v) is list)
        if complete:
            try:
                out = np.array(values, dtype=float)
                if out.shape == (len(values), width):
                    return out
            except (TypeError, ValueError):
                pass
        out = np.full((len(values), width), np.nan)
        for i, v in enumerate(values):
            if type(v) is list and v:
                out[i, : len(v)] = [np.nan if x is None else x for x in v]
        return out
    elif first is None:  # nothing but null: a NaN column
        return np.full(len(values), np.nan)
    arr = np.empty(len(values), dtype=object)
    arr[:] = [None if v is _MISSING else v for v in values]
    return arr


_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel_id, sequence, log_time, publish_time
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, length
_SKIPPED = {
    Opcode.MESSAGE_INDEX, Opcode.CHUNK_INDEX, Opcode.ATTACHMENT_INDEX, Opcode.METADATA_INDEX,
    Opcode.STATISTICS, Opcode.SUMMARY_OFFSET, Opcode.DATA_END,
}


class _Truncated(Exception):
    pass


class LogError(ValueError):
    """A file that is not a readable fwsim log (not MCAP, corrupted, or holding no flight)."""


def _decompress(chunk: Chunk) -> bytes:
    if chunk.compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size
        )
    if chunk.compression == "lz4":
        try:
            import lz4.frame  # only if someone wrote lz4 chunks (fwsim writes zstd)
        except ImportError:
            raise LogError("its chunks are lz4-compressed, which needs the lz4 package (pip install lz4)") from None
        return lz4.frame.decompress(chunk.data)
    if chunk.compression == "":
        return chunk.data
    raise ValueError(f"unsupported chunk compression {chunk.compression!r}")


def _add_record(log: RunLog, opcode: int, body: bytes) -> None:
    """Non-message records, parsed with mcap's own record classes."""
    if opcode == Opcode.CHANNEL:
        ch = Channel.read(ReadDataStream(io.BytesIO(body)))
        log._channels[ch.id] = ch
        log.topics.setdefault(ch.topic, 0)
    elif opcode == Opcode.SCHEMA:
        sc = Schema.read(ReadDataStream(io.BytesIO(body)))
        log._schemas[sc.id] = sc
    elif opcode == Opcode.METADATA:
        md = Metadata.read(ReadDataStream(io.BytesIO(body)))
        log.metadata[md.name] = dict(md.metadata)
    elif opcode == Opcode.ATTACHMENT:
        att = Attachment.read(ReadDataStream(io.BytesIO(body)))
        log.attachments[att.name] = bytes(att.data)
    # Header and unknown records: nothing to keep.


def _read_chunk(log: RunLog, body: bytes) -> None:
    buf = _decompress(Chunk.read(ReadDataStream(io.BytesIO(body))))
    messages, channels = log._messages, log._channels
    head, msg_head = _RECORD_HEAD.unpack_from, _MESSAGE_HEAD.unpack_from
    pos, end = 0, len(buf)
    while pos < end:
        opcode, length = head(buf, pos)
        pos += 9
        if opcode == Opcode.MESSAGE:
            channel_id, _, log_time, _ = msg_head(buf, pos)
            ch = channels.get(channel_id)
            if ch is not None:
                messages[ch.topic].append((log_time, buf[pos + 22 : pos + length], channel_id))
        else:
            _add_record(log, opcode, buf[pos : pos + length])
        pos += length


def _read_records(log: RunLog, f) -> bool:
    """Read the file's records after the leading magic; True once the footer is reached."""
    while True:
        head = f.read(9)
        if len(head) < 9:
            raise _Truncated(f"at byte {f.tell() - len(head)}")
        opcode, length = _RECORD_HEAD.unpack(head)
        if opcode in _SKIPPED:  # indexes and summary: not needed
            f.seek(length, io.SEEK_CUR)
            continue
        body = f.read(length)
        if len(body) < length:
            raise _Truncated(f"inside a record of {length} bytes at byte {f.tell() - len(body) - 9}")
        if opcode == Opcode.FOOTER:
            return True
        if opcode == Opcode.CHUNK:
            _read_chunk(log, body)
        else:
            _add_record(log, opcode, body)


def _finish(log: RunLog) -> None:
    """Counts, sim time and the run's status and scenario, once the records are read."""
    # Channels whose messages were all lost in the cut still show (count 0).
    for topic in log.topics:
        log.topics[topic] = len(log._messages.get(topic, ()))
    try:
        log.epoch_ns = int(log.metadata.get(METADATA_NAME, {}).get(EPOCH_KEY, 0))
    except ValueError:
        log.epoch_ns = 0
    if log.epoch_ns:  # sim time from here on
        e = log.epoch_ns
        for topic, msgs in log._messages.items():
            log._messages[topic] = [(t - e, d, c) for t, d, c in msgs]
    status = log.metadata.get(STATUS_METADATA_NAME)
    if status is not None:
        log.status = status.get("status", "unknown")
        log.reason = status.get("reason", "")
    else:
        log.status = "unknown"
        log.reason = "no run_status record (file cut off before the writer closed it)"
    try:
        effective = log.attachments.get("scenario_effective.yaml")
        if effective is not None:
            log.effective_scenario_text = effective.decode("utf-8")
        scenario = log.attachments.get(SCENARIO_ATTACHMENT)
        if scenario is not None:
            log.scenario_text = scenario.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise LogError(f"{log.path}: corrupted (its scenario attachment is not UTF-8 text: {exc.reason})") from None


def read_log(path: str | os.PathLike) -> RunLog:
    """Read a run's MCAP log.

    The file is read in one sequential (non-seeking) pass that does not need
    the summary section, so a file cut off by a hard kill reads too: the pass
    stops at the first incomplete record and everything before it (complete
    chunks, metadata, attachments) is returned with ``truncated=True``.
    Messages are kept in file order (= the order they were written).
    """
    log = RunLog(Path(path))
    footer_seen = False
    with open(log.path, "rb") as f:
        magic = f.read(len(MCAP0_MAGIC))
        if not magic or magic != MCAP0_MAGIC[: len(magic)]:
            raise LogError(f"{log.path} is not an MCAP file")
        try:
            if len(magic) < len(MCAP0_MAGIC):
                raise _Truncated("inside the leading magic")
            footer_seen = _read_records(log, f)
        except _Truncated as e:
            log.truncation_error = f"cut off {e}"
        except LogError as e:  # readable, but not here
            raise LogError(f"{log.path}: {e}") from None
        except Exception as e:  # noqa: BLE001 - a record that does not parse: the file is damaged there
            log.truncation_error = f"corrupted at byte {f.tell()}: {type(e).__name__}: {e}"
            log.corrupted = True
    log.truncated = not footer_seen
    _finish(log)
    return log


def log_from_records(path, messages: dict[str, list[tuple[int, bytes, int]]], channels: dict[int, Channel],
                     schemas: dict[int, Schema], metadata: dict[str, dict[str, str]],
                     attachments: dict[str, bytes], complete: bool) -> RunLog:
    """A :class:`RunLog` of records held in memory (:meth:`fwsim.log.LogWriter.kept_log`): messages as
    ``(log time ns, data, channel id)`` by topic, as :func:`read_log` collects them from the file."""
    log = RunLog(Path(path))
    log._channels.update(channels)
    log._schemas.update(schemas)
    for ch in channels.values():
        log.topics.setdefault(ch.topic, 0)
    for topic, msgs in messages.items():
        if msgs:
            log._messages[topic] = list(msgs)
    log.metadata.update({k: dict(v) for k, v in metadata.items()})
    log.attachments.update(attachments)
    log.truncated = not complete
    _finish(log)
    return log


def read_flight_log(path: str | os.PathLike) -> RunLog:
    """:func:`read_log` for the tools that score or show a flight: LogError (one line) unless the file holds
    at least one UAV state."""
    log = read_log(path)
    if not log.topics.get("/uav/state"):
        why = log.truncation_error or "no /uav/state messages"
        raise LogError(f"{log.path}: holds no flight to read ({why})")
    return log
