"""Reading the project's YAML (scenarios, ``--set`` values, batch specs, baselines, tolerances) with one-line
errors, whatever the input.

:func:`load_yaml_text` is YAML 1.1's safe subset with four changes a scenario
file needs: a key given twice is an error (not "the last one wins"); dates
stay text (``name: 2024-02-30`` is a name, not an impossible date); aliases
may not expand to more than :data:`MAX_VALUES` values (a few lines of nested
aliases otherwise become gigabytes); and every failure of the parser or of a
value's constructor (nesting too deep, an integer of thousands of digits, a
bad ``!!float`` tag, text that is not UTF-8) is one short line naming where.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from yaml.constructor import ConstructorError
from yaml.nodes import MappingNode, ScalarNode

__all__ = ["load_yaml_text", "load_yaml_file", "read_text", "MAX_VALUES", "MAX_FILE_BYTES", "short", "FAST_SAFE_LOADER",
           "FAST_SAFE_DUMPER"]

#: yaml.safe_load's and yaml.safe_dump's loader and dumper with libyaml's parser and emitter where PyYAML has them
#: (the same values and text, a quarter of the time): for the project's own files, read or written per run
FAST_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
FAST_SAFE_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)

#: the most values (mappings, lists and scalars, aliases expanded) one file may hold
MAX_VALUES = 200_000
#: the largest scenario or batch file read (the project's are a few KiB)
MAX_FILE_BYTES = 4 * 1024 * 1024
_TIMESTAMP = "tag:yaml.org,2002:timestamp"
_MERGE = "tag:yaml.org,2002:merge"


def short(text: Any, n: int = 80) -> str:
    """``text`` as one line of at most ``n`` characters (an error message never echoes a whole input)."""
    s = " ".join(str(text).split())
    return s if len(s) <= n else s[:n - 3] + "..."


class _Loader(yaml.SafeLoader):
    """SafeLoader without timestamps and with duplicate keys rejected."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, MappingNode):
            seen: set[tuple[str, str]] = set()
            for key_node, _ in node.value:
                if not isinstance(key_node, ScalarNode) or key_node.tag == _MERGE:
                    continue
                key = (key_node.tag, key_node.value)
                if key in seen:
                    raise ConstructorError("while reading a mapping", node.start_mark,
                                           f"the key '{short(key_node.value, 40)}' appears twice", key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


_Loader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag != _TIMESTAMP]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_Loader.add_constructor(
    "tag:yaml.org,2002:map", lambda loader, node: loader.construct_mapping(node))  # plain dicts, checked


def _count_values(data: Any, limit: int) -> int:
    """Values in ``data`` with shared (aliased) parts counted every time they appear; stops past ``limit``."""
    memo: dict[int, int] = {}

    def size(obj: Any) -> int:
        if isinstance(obj, dict):
            children = [*obj.keys(), *obj.values()]
        elif isinstance(obj, list):
            children = obj
        else:
            return 1
        key = id(obj)
        if key not in memo:
            total = 1
            for child in children:
                total += size(child)
                if total > limit:
                    break
            memo[key] = total
        return memo[key]

    return size(data)


def load_yaml_text(text: str, source: str, error: type[Exception]) -> Any:
    """The data of YAML ``text``; ``error("<source>[:line:col]: ...")`` on any problem (see the module text)."""
    if len(text) > MAX_FILE_BYTES:
        raise error(f"{source}: too large ({len(text):,} characters; at most {MAX_FILE_BYTES:,})")
    try:
        data = yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass
        too_large = _count_values(data, MAX_VALUES) > MAX_VALUES
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f":{mark.line + 1}:{mark.column + 1}" if mark else ""
        problem = exc.problem or exc.context or "syntax error"
        kind = "YAML error" if isinstance(exc, ConstructorError) else "YAML syntax error"
        raise error(f"{source}{where}: {kind}: {short(problem)}") from None
    except yaml.YAMLError as exc:
        raise error(f"{source}: YAML error: {short(str(exc).splitlines()[0] if str(exc) else exc)}") from None
    except RecursionError:
        raise error(f"{source}: YAML error: nested too deeply") from None
    except Exception as exc:  # noqa: BLE001 - a value's constructor: huge ints, bad !!float/!!bool ...
        raise error(f"{source}: YAML error: bad value: {short(exc)}") from None
    if too_large:
        raise error(f"{source}: too large: more than {MAX_VALUES:,} values (aliases expanded)")
    return data


def read_text(path: str | Path, what: str, error: type[Exception]) -> str:
    """The text of ``path``; ``error`` when it is missing, unreadable or not UTF-8."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: no such {what}")
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise error(f"{path}: too large for a {what} ({size:,} bytes; at most {MAX_FILE_BYTES:,})")
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise error(f"{path}: cannot read it: {short(exc.strerror or exc)}") from None


def load_yaml_file(path: str | Path, what: str, error: type[Exception]) -> Any:
    """The parsed YAML of ``path``; ``error`` with ``"<path>: ..."`` when it is missing or not YAML."""
    return load_yaml_text(read_text(path, what, error), str(path), error)
