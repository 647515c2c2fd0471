"""The scenario's field reference: its JSON Schema (for an editor) and a Markdown page of every field.

    fwsim scenario schema > fwsim.schema.json             # scenario_schema()
    fwsim scenario reference --out docs/guide/reference.md  # reference_markdown()

Both are made from the pydantic models of :class:`fwsim.scenario.model.Scenario` (the harness's sections and the flight
software's ``controllers``, ``controllers/config.py``): a field's type, default, bounds and description are the
model's own. The page gives each field's unit from its name's suffix (``_m``, ``_m_s``, ``_deg``, ``_s``, ``_hz``,
``_px`` ...). A test regenerates the page and fails when the committed one is stale.
"""
from __future__ import annotations

import json
import types
import typing
from dataclasses import dataclass
from typing import Any

import annotated_types as at
from pydantic import BaseModel
from pydantic_core import PydanticUndefined

__all__ = ["FieldRow", "Section", "sections", "scenario_schema", "reference_markdown", "unit_of", "REGENERATE"]

#: the command that writes the page (the stale-page test names it)
REGENERATE = "fwsim scenario reference --out docs/guide/reference.md"

#: a field name's suffix -> its unit (the longest suffix that matches wins)
UNITS = {
    "_m_s2": "m/s²", "_m_s": "m/s", "_deg_s": "deg/s", "_rad_s": "rad/s", "_1_s": "1/s", "_px2": "px²",
    "_px": "px", "_m": "m", "_deg": "deg", "_rad": "rad", "_ms": "ms", "_s": "s", "_hz": "Hz", "_kg": "kg",
    "_frac": "fraction", "_norm": "normalised",
}


def unit_of(name: str) -> str:
    """The unit a field's name says (``airspeed_m_s`` -> m/s, ``box_px_std`` -> px); '' when it says none."""
    base = name.removesuffix("_std")
    for suffix in sorted(UNITS, key=len, reverse=True):
        if base.endswith(suffix):
            return UNITS[suffix]
    return ""


def scenario_schema() -> dict[str, Any]:
    """The JSON Schema of a scenario file (pydantic's, with a block choice's short form allowed: ``estimator:
    ukf`` as well as ``estimator: {use: ukf}``)."""
    from fwsim.scenario.model import Scenario
    schema = Scenario.model_json_schema()
    defs = schema.get("$defs", {})
    choice = defs.get("BlockChoice")
    if choice is not None:
        use = choice.get("properties", {}).get("use", {})
        defs["BlockChoice"] = {"anyOf": [{"type": "string", "description": use.get("description", "")}, choice],
                               "title": choice.get("title", "BlockChoice")}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema, "title": "fwsim scenario"}


# --------------------------------------------------------------------------- the page


@dataclass(frozen=True)
class FieldRow:
    path: str  # dotted path, as --set and fwsim.fly take it (``[]``: each item of a list)
    type: str
    unit: str
    default: str  # "required" when the field has none
    bounds: str
    description: str


@dataclass(frozen=True)
class Section:
    """The fields of one model, at ``path`` (``when``: the variant of a union it is, e.g. ``kind: wind_gust``)."""

    path: str
    title: str
    when: str
    doc: str
    rows: tuple[FieldRow, ...]


def _models(annotation: Any) -> list[type[BaseModel]]:
    """The model classes inside an annotation (Optional, list, union, Annotated)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    out: list[type[BaseModel]] = []
    for arg in typing.get_args(annotation):
        out += [m for m in _models(arg) if m not in out]
    return out


def _is_list(annotation: Any) -> bool:
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _is_list(typing.get_args(annotation)[0])
    if origin is typing.Union or isinstance(annotation, types.UnionType):
        return any(_is_list(a) for a in typing.get_args(annotation))
    return origin in (list, tuple)


def type_name(annotation: Any) -> str:
    """A readable type: ``float``, ``list of 3 float``, ``one of dryden, tustin``, ``float or null`` ..."""
    if annotation is type(None):
        return "null"
    if annotation is Any:
        return "any"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "section (below)"
    if isinstance(annotation, type):
        return annotation.__name__
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Literal:
        return ("one of " if len(args) > 1 else "") + ", ".join(f"`{a}`" for a in args)
    if origin is typing.Annotated:
        inner = type_name(args[0])
        lengths = [m for m in args[1:] if hasattr(m, "metadata")]
        sizes = {type(x).__name__: x for f in lengths for x in f.metadata}
        if "MinLen" in sizes and "MaxLen" in sizes and sizes["MinLen"].min_length == sizes["MaxLen"].max_length:
            return inner.replace("list of ", f"list of {sizes['MinLen'].min_length} ", 1)
        return inner
    if origin is typing.Union or isinstance(annotation, types.UnionType):
        models = [a for a in args if isinstance(a, type) and issubclass(a, BaseModel)]
        if len(models) > 1:
            return "section (one of the variants below)"
        return " or ".join(dict.fromkeys(type_name(a) for a in args))
    if origin in (list, tuple):
        return "list of " + (type_name(args[0]) if args else "any")
    if origin is dict:
        return f"map of {type_name(args[0])} to {type_name(args[1])}" if args else "map"
    return str(annotation).replace("typing.", "")


def _value(v: Any) -> str:
    if isinstance(v, BaseModel):
        return ""
    if isinstance(v, str):
        return v
    if isinstance(v, tuple):
        v = list(v)
    try:
        return json.dumps(v, ensure_ascii=False)
    except (TypeError, ValueError):
        return str(v)


def _default(field) -> str:
    if field.default is not PydanticUndefined:
        return _value(field.default)
    if field.default_factory is not None:
        try:
            return _value(field.default_factory())
        except TypeError:  # a factory that takes the data validated so far
            return ""
    return "required"


_BOUNDS = ((at.Ge, "ge", "≥"), (at.Gt, "gt", ">"), (at.Le, "le", "≤"), (at.Lt, "lt", "<"))


def _bounds(field) -> str:
    out = []
    lengths = [None, None]
    for meta in field.metadata:
        for kind, attr, sign in _BOUNDS:
            if isinstance(meta, kind):
                out.append(f"{sign} {_value(getattr(meta, attr))}")
        if isinstance(meta, at.MinLen) and meta.min_length:
            lengths[0] = meta.min_length
        if isinstance(meta, at.MaxLen):
            lengths[1] = meta.max_length
    if lengths[0] is not None and lengths[0] == lengths[1]:
        out.append(f"{lengths[0]} items")
    else:
        out += [f"at least {lengths[0]} items"] * (lengths[0] is not None)
        out += [f"at most {lengths[1]} items"] * (lengths[1] is not None)
    return ", ".join(out)


def _one_line(text: str | None) -> str:
    return " ".join((text or "").split())


def _doc(model: type[BaseModel]) -> str:
    """The first paragraph of a model's docstring, as one line."""
    doc = model.__doc__ or ""
    if model.__doc__ == BaseModel.__doc__:
        return ""
    return _one_line(doc.strip().split("\n\n")[0])


def _variant(model: type[BaseModel]) -> str:
    """``kind: wind_gust``: the discriminator a union's variant is chosen by (its one Literal field)."""
    for name, f in model.model_fields.items():
        if typing.get_origin(f.annotation) is typing.Literal and len(typing.get_args(f.annotation)) == 1:
            return f"{name}: {typing.get_args(f.annotation)[0]}"
    return model.__name__


def sections(model: type[BaseModel] | None = None, path: str = "", when: str = "") -> list[Section]:
    """Every model of the scenario, depth first, each with its fields' rows."""
    if model is None:
        from fwsim.scenario.model import Scenario
        model = Scenario
    rows, below = [], []
    for name, f in model.model_fields.items():
        p = f"{path}.{name}" if path else name
        subs = _models(f.annotation)
        rows.append(FieldRow(p, type_name(f.annotation), unit_of(name), _default(f), _bounds(f),
                             _one_line(f.description)))
        inner = p + "[]" if _is_list(f.annotation) else p
        for sub in subs:
            below += sections(sub, inner, _variant(sub) if len(subs) > 1 else "")
    title = path or "the scenario's top level"
    return [Section(path, title, when, _doc(model), tuple(rows)), *below]


def _cell(text: str, code: bool = False) -> str:
    """Text in a table's cell: a pipe escaped; outside code, ``<``, ``>`` and ``*`` too (not markup)."""
    text = text.replace("|", "\\|")
    if code:
        return f"`{text}`" if text else text
    return text.replace("<", "&lt;").replace(">", "&gt;").replace("*", "\\*")


def _table(section: Section) -> list[str]:
    lines = ["| field | type | unit | default | bounds | description |", "|---|---|---|---|---|---|"]
    for r in section.rows:
        default = r.default if r.default in ("required", "") else _cell(r.default, code=True)
        lines.append(f"| {_cell(r.path, code=True)} | {_cell(r.type)} | {_cell(r.unit)} | {default} | "
                     f"{_cell(r.bounds)} | {_cell(r.description)} |")
    return lines


INTRO = """# Scenario field reference

Every field of a scenario file, generated from the models (`fwsim/scenario/model.py` and the flight software's
`controllers/config.py`); do not edit this page by hand: `{regenerate}` writes it again. A field's dotted path
is what `--set` and `fwsim.fly` take (`--set controllers.ukf.pixel_noise_px=3`); `[]` stands for each item of a
list. The unit comes from the field's name (`_m`, `_m_s`, `_deg`, `_s`, `_hz`, `_px` ...). A field without a
default is required.

`fwsim scenario show SCENARIO [--set PATH=VALUE ...]` prints a scenario with every default filled in, as the
run sees it.

## Validation and completion in your editor

`fwsim scenario schema` prints the scenario's JSON Schema. Save it beside your scenarios and name it on the
first line of a scenario file:

```console
$ fwsim scenario schema > fwsim.schema.json
```

```yaml
# yaml-language-server: $schema=fwsim.schema.json
name: my_run
duration_s: 120
initial: {{pos_enu_m: [-1000, 0, 300], airspeed_m_s: 22, heading_deg: 90}}
```

An editor with the YAML language server (VS Code's YAML extension, Neovim's yamlls, JetBrains IDEs) then
completes the field names, shows each description on hover and underlines a value out of its bounds or a key
that does not exist. The path after `$schema=` is relative to the scenario file. What the schema cannot check
(a plug-in class that does not import, limits that depend on two fields) `fwsim run` and `fwsim scenario show`
still report, one line naming the field.
"""


def reference_markdown() -> str:
    """The reference page (docs/guide/reference.md)."""
    out = [INTRO.format(regenerate=REGENERATE)]
    for s in sections():
        heading = f"`{s.path}`" if s.path else s.title[0].upper() + s.title[1:]
        out.append(f"## {heading}" + (f" ({s.when})" if s.when else "") + "\n")
        if s.doc:
            out.append(s.doc + "\n")
        out.append("\n".join(_table(s)) + "\n")
    return "\n".join(out)
