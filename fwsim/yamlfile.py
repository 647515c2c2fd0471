"""Reading the project's YAML files (batch specs, baselines, tolerances) with one-line errors."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml


def load_yaml_file(path: str | Path, what: str, error: type[Exception]) -> Any:
    """The parsed YAML of ``path``; ``error`` with ``"<path>: ..."`` when it is missing or not YAML."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: no such {what}")
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise error(f"{path}: YAML syntax error: {str(exc).splitlines()[0]}") from None
