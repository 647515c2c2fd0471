"""The base of every configuration model (scenario, flight software, aircraft gains).

:class:`StrictModel`: unknown keys are errors, values are frozen, numbers are
finite (NaN and infinities fail validation, not the run), and ``true``/``false``
are not numbers (pydantic would otherwise read ``true`` as 1 in a float field).
Pure validation: both sides of the harness import it.
"""
from __future__ import annotations

import types
import typing
from typing import Any

from pydantic import BaseModel, ConfigDict, model_validator

__all__ = ["StrictModel"]


def _numeric(annotation: Any) -> bool:
    """True when the annotation takes numbers (int or float, at any depth) and never a bool."""
    seen: set[type] = set()

    def walk(a: Any) -> None:
        if a in (bool, int, float):
            seen.add(a)
            return
        origin = typing.get_origin(a)
        if origin is typing.Literal:
            return
        if origin is typing.Annotated:
            walk(typing.get_args(a)[0])
            return
        if origin is not None or isinstance(a, types.UnionType):
            for arg in typing.get_args(a):
                walk(arg)

    walk(annotation)
    return bool(seen & {int, float}) and bool not in seen


def _has_bool(value: Any) -> bool:
    if isinstance(value, bool):
        return True
    if isinstance(value, (list, tuple)):
        return any(_has_bool(v) for v in value)
    return False


class StrictModel(BaseModel):
    """Unknown keys rejected, frozen, finite numbers only, no true/false where a number goes."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _no_bool_numbers(cls, data: Any) -> Any:
        if isinstance(data, dict):
            for name, value in data.items():
                field = cls.model_fields.get(name) if isinstance(name, str) else None
                if field is not None and _has_bool(value) and _numeric(field.annotation):
                    raise ValueError(f"{name}: a number is expected here, not true/false (got {value!r:.60})")
        return data
