"""Dispersions of a batch spec: scenario fields drawn from distributions, reproducibly.

In a batch entry (docs/guide/batches.md)::

    seed: 2024                          # top level of the spec: the draws' seed (default 0)
    runs:
      - scenario: ../paper_mission.yaml
        samples: 100
        dispersions:
          target.speed_m_s: {uniform: [0, 10]}
          target.course_deg: {uniform_angle_deg: [0, 360]}
          world.wind_enu_m_s: {normal: [[0, 0, 0], [3, 3, 0]]}   # element by element
          camera.detector.pixel_noise_px: {choice: [1.0, 1.5, 3.0]}

Each (sample, field) pair draws from its own stream, seeded by the batch seed,
the entry's index, the sample's index and the field's path: the same spec
gives the same draws on any machine, and adding or removing a dispersed field
leaves the other fields' draws as they were.
"""
from __future__ import annotations

import math
import zlib
from typing import Any

import numpy as np

__all__ = ["DISTRIBUTIONS", "parse_dispersions", "draw"]

#: distribution name -> what its value is
DISTRIBUTIONS = {
    "uniform": "[low, high] (numbers, or lists of numbers of one length: element by element)",
    "normal": "[mean, std] (numbers, or lists of numbers of one length: element by element)",
    "choice": "a non-empty list of values, each equally likely",
    "uniform_angle_deg": "[low, high] degrees, or true for [0, 360)",
}


def _numbers(x: Any) -> bool:
    ok = isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
    return ok or (isinstance(x, list) and bool(x) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in x))


def _pair(value: Any, where: str, error: type[Exception], what: str) -> tuple[Any, Any]:
    if not (isinstance(value, list) and len(value) == 2 and all(_numbers(v) for v in value)):
        raise error(f"{where}: expected {what} (got {str(value)[:60]})")
    a, b = value
    if isinstance(a, list) != isinstance(b, list) or (isinstance(a, list) and len(a) != len(b)):
        raise error(f"{where}: both sides must be numbers or lists of one length (got {str(value)[:60]})")
    return a, b


def parse_dispersions(spec: Any, where: str, error: type[Exception]) -> dict[str, tuple[str, Any]]:
    """``{path: (distribution, parameters)}`` from a spec's ``dispersions:`` mapping; ``error`` (one line)
    on anything else."""
    if not isinstance(spec, dict) or not spec:
        raise error(f"{where}: expected a mapping of scenario field paths to distributions")
    out = {}
    for path, dist in spec.items():
        w = f"{where}.{path}"
        if not isinstance(path, str) or not path or any(not p for p in path.split(".")):
            raise error(f"{where}: {str(path)[:40]!r} is not a dotted field path")
        if not (isinstance(dist, dict) and len(dist) == 1 and next(iter(dist)) in DISTRIBUTIONS):
            raise error(f"{w}: expected one of {{{', '.join(f'{k}: ...' for k in DISTRIBUTIONS)}}} "
                        f"(got {str(dist)[:60]})")
        (kind, value), = dist.items()
        if kind == "choice":
            if not isinstance(value, list) or not value:
                raise error(f"{w}.choice: expected {DISTRIBUTIONS['choice']}")
        elif kind == "uniform_angle_deg" and value is True:
            value = [0.0, 360.0]
        else:
            a, b = _pair(value, f"{w}.{kind}", error, DISTRIBUTIONS[kind])
            lo, hi = np.atleast_1d(a), np.atleast_1d(b)
            if kind == "normal" and np.any(hi < 0):
                raise error(f"{w}.normal: the standard deviation must be >= 0 (got {b})")
            if kind != "normal" and np.any(hi < lo):
                raise error(f"{w}.{kind}: low must not exceed high (got {value})")
        out[path] = (kind, value)
    return out


def _stream(seed: int, entry: int, sample: int, path: str) -> np.random.Generator:
    return np.random.default_rng([seed, entry, sample, zlib.crc32(path.encode())])


def _value(kind: str, value: Any, rng: np.random.Generator) -> Any:
    if kind == "choice":
        return value[int(rng.integers(len(value)))]
    a, b = value
    if kind == "normal":
        x = rng.normal(np.asarray(a, float), np.asarray(b, float))
    else:  # uniform, uniform_angle_deg
        x = rng.uniform(np.asarray(a, float), np.asarray(b, float))
    return x.tolist() if isinstance(a, list) else float(x)


def draw(dispersions: dict[str, tuple[str, Any]], samples: int, seed: int, entry: int) -> list[dict[str, Any]]:
    """The overrides of each sample: ``[{path: value}, ...]`` (``samples`` of them)."""
    return [{path: _value(kind, value, _stream(seed, entry, i, path)) for path, (kind, value) in
             sorted(dispersions.items())} for i in range(samples)]
