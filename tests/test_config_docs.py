"""Every setting a scenario can hold says what it is, in one short line (the rationale lives in
docs/design/settings.md)."""
from __future__ import annotations

import typing

from pydantic import BaseModel

from fwsim.scenario.model import Scenario

MAX_CHARS = 200


def _models(annotation) -> list[type[BaseModel]]:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for arg in typing.get_args(annotation) for m in _models(arg)]


def _fields():
    seen, todo, out = set(), [Scenario], []
    while todo:
        model = todo.pop()
        if model in seen:
            continue
        seen.add(model)
        for name, field in model.model_fields.items():
            out.append((f"{model.__name__}.{name}", field.description or ""))
            todo += _models(field.annotation)
    return seen, out


def test_every_field_reachable_from_the_scenario_has_a_short_description():
    models, fields = _fields()
    assert len(models) > 40 and len(fields) > 300  # the walk reaches the controllers' and the events' models
    missing = [name for name, d in fields if not d.strip()]
    long = [(name, len(d)) for name, d in fields if len(d) > MAX_CHARS]
    assert not missing, missing
    assert not long, long


def test_the_defaults_are_the_mission_users_fly():
    """Controllers() by itself loiters with the NMPC after the lock and dives (the envelope's mission)."""
    from controllers.config import Controllers
    c = Controllers()
    assert c.kind == "mission" and c.after_lock.use == "nmpc" and c.switch.enabled
    assert c.switch.min_loiter_s == 30.0 and c.switch.entry_depression_margin_deg == 5.0
