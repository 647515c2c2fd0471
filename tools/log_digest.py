"""Did a change move the flight? Compare two runs' logs topic by topic, message for message.

    python tools/log_digest.py A.mcap B.mcap            # every topic the two logs share
    python tools/log_digest.py A.mcap B.mcap --topics /uav/state,/fsw/estimate
    python tools/log_digest.py DIR_A DIR_B              # every log of the same name in both folders

For each topic in both logs it prints ``same`` (every message identical, byte
for byte) or where the streams first differ (message index, sim time and, for
JSON topics, the first fields that differ with both values). Topics in only
one log are listed apart (a change that adds a topic, such as a new decision
log, leaves the others to compare). Exit code 1 when any shared topic differs.

A restructuring that keeps behaviour leaves every shared topic ``same`` on the
same machine; ``fwsim compare`` judges metrics against tolerances instead.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from fwsim.log import read_log

#: topics whose messages carry wall-clock quantities (they differ run to run)
WALL_CLOCK_FIELDS = {"/fsw/nmpc": ("solve_ms",)}


def _first_difference(a: bytes, b: bytes, encoding: str) -> str:
    if encoding != "json":
        return f"{len(a)} vs {len(b)} bytes"
    da, db = json.loads(a), json.loads(b)
    keys = [k for k in dict.fromkeys([*da, *db]) if da.get(k) != db.get(k)]
    return "; ".join(f"{k}: {da.get(k)!r} vs {db.get(k)!r}" for k in keys[:3]) + (" ..." if len(keys) > 3 else "")


def _absent(v) -> bool:
    """A value that stands for NaN: null, or an array holding one (logs before NaN fields were left out)."""
    return v is None or (type(v) is list and None in v)


def _unstamped(msg, epoch_ns: int):
    """A protobuf message with every google.protobuf.Timestamp in it counted from ``epoch_ns`` (sim time)."""
    for fd, value in msg.ListFields():
        if fd.message_type is None:
            continue
        items = [value] if hasattr(value, "ListFields") else value  # one message, or a repeated field
        for item in items:
            if fd.message_type.full_name == "google.protobuf.Timestamp":
                ns = item.seconds * 1_000_000_000 + item.nanos - epoch_ns
                item.seconds, item.nanos = divmod(ns, 1_000_000_000)
            elif hasattr(item, "ListFields"):
                _unstamped(item, epoch_ns)
    return msg


def _proto_class(schema_name: str):
    """The Foxglove protobuf class of a schema name (foxglove.FrameTransform), or None."""
    import importlib
    if not schema_name.startswith("foxglove."):
        return None
    name = schema_name.split(".", 1)[1]
    try:
        return getattr(importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2"), name)
    except (ImportError, AttributeError):
        return None


def _normalised(topic: str, data: bytes, encoding: str, keep: set[str] | None, proto=None,
                epoch_ns: int = 0) -> bytes:
    """JSON messages on the fields both logs have, less wall-clock fields and NaN fields (left out or null);
    Foxglove messages with their stamps in sim time (logs start at different epochs); others as they are."""
    if encoding != "json":
        if proto is None or not epoch_ns:
            return data
        return _unstamped(proto.FromString(data), epoch_ns).SerializeToString(deterministic=True)
    d = json.loads(data)
    drop = set(WALL_CLOCK_FIELDS.get(topic, ()))
    return json.dumps({k: v for k, v in d.items() if k not in drop and (keep is None or k in keep)
                       and not _absent(v)}, sort_keys=True).encode()


def _fields(log, topic: str, raw: list, encoding: str) -> set[str] | None:
    if encoding != "json":
        return None
    declared = set(log.fields(topic))
    return declared | (set(json.loads(raw[0][1])) if raw else set())


def compare_logs(path_a: Path, path_b: Path, topics: list[str] | None = None, out=sys.stdout) -> bool:
    """Print the comparison of two logs; True when every shared (or asked) topic is the same.

    JSON topics are compared on the fields both logs' messages have (a change that adds a field is listed,
    not counted as a difference)."""
    a, b = read_log(path_a), read_log(path_b)
    shared = [t for t in a.topics if t in b.topics]
    if topics:
        shared = [t for t in topics if t in a.topics and t in b.topics]
    same = True
    for t in shared:
        ra, rb = a.raw(t), b.raw(t)
        enc = a.encoding(t)
        fa, fb = _fields(a, t, ra, enc), _fields(b, t, rb, enc)
        keep = fa & fb if fa is not None and fb is not None else None
        extra = "" if keep is None or fa == fb else \
            f" [fields only in A: {sorted(fa - fb)}, only in B: {sorted(fb - fa)}]"
        n = min(len(ra), len(rb))
        proto = _proto_class(a.schema_name(t)) if enc == "protobuf" and a.epoch_ns != b.epoch_ns else None
        k = next((i for i in range(n) if ra[i][0] != rb[i][0]
                  or _normalised(t, ra[i][1], enc, keep, proto, a.epoch_ns)
                  != _normalised(t, rb[i][1], enc, keep, proto, b.epoch_ns)), None)
        if k is None and len(ra) == len(rb):
            print(f"  same     {t} ({len(ra)} messages){extra}", file=out)
            continue
        same = False
        if k is None:
            print(f"  DIFFERS  {t}: {len(ra)} vs {len(rb)} messages (equal up to {n}){extra}", file=out)
        else:
            print(f"  DIFFERS  {t}: message {k} at t = {ra[k][0] * 1e-9:.3f} s: "
                  f"{_first_difference(ra[k][1], rb[k][1], enc)}{extra}", file=out)
    only_a = [t for t in a.topics if t not in b.topics]
    only_b = [t for t in b.topics if t not in a.topics]
    if only_a:
        print(f"  only in A ({path_a.name}): {', '.join(only_a)}", file=out)
    if only_b:
        print(f"  only in B ({path_b.name}): {', '.join(only_b)}", file=out)
    if (a.status, a.reason) != (b.status, b.reason):
        same = False
        print(f"  DIFFERS  end: {a.status}: {a.reason} vs {b.status}: {b.reason}", file=out)
    return same


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a", type=Path, help="a log, or a folder of logs")
    ap.add_argument("b", type=Path, help="the other log, or folder")
    ap.add_argument("--topics", help="comma-separated topics (default: every shared topic)")
    args = ap.parse_args(argv)
    topics = args.topics.split(",") if args.topics else None
    if args.a.is_dir():
        pairs = [(p, args.b / p.name) for p in sorted(args.a.glob("*.mcap")) if (args.b / p.name).is_file()]
        if not pairs:
            print(f"no logs of the same name in {args.a} and {args.b}", file=sys.stderr)
            return 2
    else:
        pairs = [(args.a, args.b)]
    bad = 0
    for pa, pb in pairs:
        print(pa.name)
        bad += not compare_logs(pa, pb, topics)
    print(f"{len(pairs) - bad} of {len(pairs)} logs the same on every shared topic")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
