"""JSON Schemas and fast JSON encoders generated from message dataclasses.

Shared by the writer (schema + encoding) and the docs. Everything is computed
once per dataclass type and cached; a message is encoded by ``orjson`` (the
dataclass and its numpy arrays in C); ``as_dict`` is the same encoding in
Python, for readers of one message.

A number field whose value is not finite (NaN, +-inf), or an array field
whose elements all are, is left out of that message, so every message
validates against its schema: the schema declares ``"type": "number"`` (one
type per property, which Foxglove's parser needs; it rejects ``["number",
"null"]``) and lists only the fields that are always there as ``required``.
Foxglove then shows a gap in a plot where the value was NaN; the reader turns
an absent field back into NaN. An array that is only partly NaN keeps its
numbers and writes the NaN elements as null: such a message does not validate
(no message of the project's own is like that). Arrays carry their length in the schema
(``minItems`` = ``maxItems``, from the first message of the type), so even a
field that is NaN in every message reads back with its width.
"""
from __future__ import annotations

import dataclasses
import inspect
import json
import re
import types
import typing
from functools import lru_cache
from operator import attrgetter
from typing import Any, Callable, Literal

import numpy as np
import orjson

# Field kinds used by the encoder.
FLOAT, VECTOR, INT, BOOL, OTHER = range(5)

#: Unit suffixes of field names, longest first (``_m_s2`` before ``_m_s``).
UNIT_SUFFIXES: tuple[tuple[str, str], ...] = (
    ("_m_s2", "metres per second squared"),
    ("_rad_s2", "radians per second squared"),
    ("_deg_s2", "degrees per second squared"),
    ("_rad_s", "radians per second"),
    ("_deg_s", "degrees per second"),
    ("_m_s", "metres per second"),
    ("_km_h", "kilometres per hour"),
    ("_rad", "radians"),
    ("_deg", "degrees"),
    ("_norm", "normalised"),
    ("_pct", "percent"),
    ("_ms", "milliseconds"),
    ("_us", "microseconds"),
    ("_ns", "nanoseconds"),
    ("_km", "kilometres"),
    ("_mm", "millimetres"),
    ("_m", "metres"),
    ("_s", "seconds"),
    ("_hz", "hertz"),
    ("_px", "pixels"),
    ("_kg", "kilograms"),
    ("_pa", "pascals"),
    ("_n", "newtons"),
)

#: Frame tokens inside field names.
FRAME_TOKENS: dict[str, str] = {
    "enu": "world frame (ENU)",
    "ned": "NED frame",
    "frd": "body frame (FRD)",
    "flu": "body frame (FLU)",
}


def describe_field(name: str) -> str:
    """A human description of a field from its name's unit suffix and frame token."""
    if name == "t_s":
        return "simulation time, seconds"
    parts = []
    for suffix, unit in UNIT_SUFFIXES:
        if name.endswith(suffix) and len(name) > len(suffix):
            parts.append(unit)
            break
    tokens = name.split("_")
    for tok, frame in FRAME_TOKENS.items():
        if tok in tokens:
            parts.append(frame)
    return ", ".join(parts) if parts else name.replace("_", " ")


def _is_ndarray(tp: Any) -> bool:
    return tp is np.ndarray or typing.get_origin(tp) is np.ndarray


def _strip_optional(tp: Any) -> Any:
    origin = typing.get_origin(tp)
    if origin is typing.Union or origin is types.UnionType:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return tp


def _classify(cls: type, name: str, tp: Any) -> tuple[int, dict]:
    """(kind, JSON Schema property without description) for one annotation."""
    tp = _strip_optional(tp)
    origin = typing.get_origin(tp)
    if tp is float or tp is np.float64 or tp is np.float32:
        return FLOAT, {"type": "number"}
    if tp is bool or tp is np.bool_:
        return BOOL, {"type": "boolean"}
    if tp is int or (isinstance(tp, type) and issubclass(tp, np.integer)):
        return INT, {"type": "integer"}
    if tp is str:
        return OTHER, {"type": "string"}
    if _is_ndarray(tp):
        return VECTOR, {"type": "array", "items": {"type": "number"}}
    if origin in (tuple, list) and all(
        a in (float, int, Ellipsis) for a in typing.get_args(tp)
    ):
        return VECTOR, {"type": "array", "items": {"type": "number"}}
    if origin is Literal:
        values = list(typing.get_args(tp))
        if all(isinstance(v, str) for v in values):
            return OTHER, {"type": "string", "enum": values}
        if all(isinstance(v, bool) for v in values):
            return BOOL, {"type": "boolean", "enum": values}
        if all(isinstance(v, int) for v in values):
            return INT, {"type": "integer", "enum": values}
    raise TypeError(
        f"fwsim.log: cannot log field {cls.__name__}.{name} of type {tp!r}; "
        "supported: float, int, bool, str, Literal[...], np.ndarray, tuple/list of numbers"
    )


class MessageSpec:
    """What the writer needs to know about one dataclass type (computed once)."""

    __slots__ = ("cls", "names", "kinds", "getter", "schema_name", "schema_json", "_schema", "_drop")

    def __init__(self, cls: type):
        if not dataclasses.is_dataclass(cls):
            raise TypeError(f"fwsim.log: {cls!r} is not a dataclass")
        hints = typing.get_type_hints(cls)
        flds = dataclasses.fields(cls)
        if not flds or flds[0].name != "t_s":
            raise TypeError(f"fwsim.log: first field of {cls.__name__} must be t_s")
        props: dict[str, dict] = {}
        kinds = []
        required = []
        for f in flds:
            tp = hints.get(f.name, f.type)
            kind, prop = _classify(cls, f.name, tp)
            if f.name == "t_s" or (kind not in (FLOAT, VECTOR) and _strip_optional(tp) is tp):
                required.append(f.name)  # never left out (numbers may be NaN, Optional fields None)
            prop["description"] = describe_field(f.name)
            props[f.name] = prop
            kinds.append(kind)
        doc = inspect.cleandoc(cls.__doc__ or "")
        if doc.startswith(cls.__name__ + "("):  # dataclass' generated signature
            doc = ""
        desc = (doc + "\n\n" if doc else "") + ("A number that is not finite (NaN), or an array of them, is "
                                                 "left out of the message.")
        self.cls = cls
        self.names = tuple(f.name for f in flds)
        self.kinds = tuple(kinds)
        self.getter = attrgetter(*self.names) if len(self.names) > 1 else (
            lambda m, _n=self.names[0]: (getattr(m, _n),)
        )
        self.schema_name = f"{cls.__module__}.{cls.__qualname__}"
        schema = {
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": self.schema_name,
            "description": desc,
            "type": "object",
            "properties": props,
            "required": required,
        }
        self._schema = schema
        self.schema_json = json.dumps(schema, indent=1).encode()
        # what orjson writes for a field that as_dict leaves out: any field None (null), a number that is not
        # finite (null), an array of them ([null,...]); t_s, the first field, has no comma before it
        nulls = b"|".join(re.escape(n.encode()) for n in self.names[1:])
        arrays = b"|".join(re.escape(n.encode()) for n, k in zip(self.names[1:], self.kinds[1:]) if k == VECTOR)
        pattern = b',"(?:' + nulls + b')":null(?=[,}])' if nulls else b""
        if arrays:
            pattern += b'|,"(?:' + arrays + b')":\\[null(?:,null)*\\](?=[,}])'
        self._drop = re.compile(pattern) if pattern else None

    def schema_json_for(self, first: Any) -> bytes:
        """The schema with each array's length (``minItems`` = ``maxItems``) taken from ``first``, a message of
        the type (the project's arrays have a fixed length per field)."""
        schema = json.loads(self.schema_json)
        for name, kind, v in zip(self.names, self.kinds, self.getter(first)):
            if kind == VECTOR and v is not None:
                schema["properties"][name]["minItems"] = schema["properties"][name]["maxItems"] = len(v)
        return json.dumps(schema, indent=1).encode()

    def encode(self, msg: Any) -> bytes:
        """One message as compact UTF-8 JSON (orjson: dataclasses and numpy arrays natively); a number that is
        not finite, an array of them, or an Optional field that is None is left out (orjson writes them as
        null: only then is the message encoded again without them)."""
        data = _orjson_dumps(msg, option=_ORJSON_OPTIONS, default=_json_default)
        if b"null" not in data:
            return data
        if self._drop is not None:  # the fields left out, cut from orjson's text (no string holds an unescaped ")
            out = self._drop.sub(b"", data)
            if b'":null' not in out:  # else (t_s null): the dict below
                return out
        return _orjson_dumps(self.as_dict(msg), option=_ORJSON_OPTIONS, default=_json_default)

    def as_dict(self, msg: Any) -> dict:
        """One message as a JSON-ready dict (arrays -> lists) without the fields that are left out: a number
        that is not finite, an array whose elements all are, a None (a partly NaN array: NaN -> None)."""
        out = {}
        for name, kind, v in zip(self.names, self.kinds, self.getter(msg)):
            if v is None:
                continue
            elif kind == FLOAT:
                v = float(v)
                if v - v != 0.0:  # NaN or inf
                    continue
            elif kind == VECTOR:
                if isinstance(v, np.ndarray):
                    v = v.tolist()
                v = [x if x - x == 0.0 else None for x in v]
                if v and all(x is None for x in v):
                    continue  # NaN as a whole: left out (a partly NaN array keeps its numbers, NaN as null)
            elif kind == INT:
                v = int(v)
            elif kind == BOOL:
                v = bool(v)
            out[name] = v
        return out


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):  # (orjson: one that is not C-contiguous)
        return o.tolist()
    raise TypeError(f"Object of type {type(o).__name__} is not JSON serializable")


_ORJSON_OPTIONS = orjson.OPT_SERIALIZE_NUMPY
_orjson_dumps = orjson.dumps

_dumps: Callable[[Any], str] = json.JSONEncoder(
    separators=(",", ":"), default=_json_default, allow_nan=True
).encode


@lru_cache(maxsize=None)
def spec_for(cls: type) -> MessageSpec:
    """The cached MessageSpec of a dataclass type."""
    return MessageSpec(cls)


def json_schema(cls: type) -> dict:
    """The JSON Schema (as a dict) the writer registers for ``cls``."""
    return json.loads(spec_for(cls).schema_json)
