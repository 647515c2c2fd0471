"""Scenario files: YAML -> validated, typed configuration.

A scenario is data (like JSBSim's scripts): aircraft, initial state, rates,
duration, seed and what the flight software should do. Unknown keys are
rejected; every problem is reported as one line naming the field path:

    scenarios/x.yaml: initial.airspeed_m_s: Input should be greater than 0 (got -5)

User-facing angles are degrees in aviation convention (docs/design/architecture.md, "Frames and conventions"):
heading clockwise from North, flight-path angle positive climbing.
"""
from __future__ import annotations

import copy
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationError, field_validator, model_validator

from controllers.config import Controllers
from fwsim.sensors.camera import CameraConfig
from fwsim.interface.configbase import StrictModel
from fwsim.world.events import Event
from fwsim.sensors.onboard import SensorsConfig
from fwsim.world.target import TargetConfig
from fwsim.scenario.yamlfile import load_yaml_text, read_text, short

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


#: how far from the world origin a run may start (see Scenario._within_the_flat_earth_mapping)
MAX_RANGE_FROM_ORIGIN_M = 20_000.0


class Rates(StrictModel):
    sim_hz: float = Field(120.0, gt=0, le=2000, description="JSBSim and autopilot rate")
    flight_software_hz: float = Field(30.0, gt=0, le=1000, description="rate of the flight software step")
    log_hz: float = Field(30.0, gt=0, le=2000, description="rate of the state and command topics in the log")

    @model_validator(mode="after")
    def _divides(self):
        for name in ("flight_software_hz", "log_hz"):
            ratio = self.sim_hz / getattr(self, name)
            if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
                raise ValueError(f"{name} must divide sim_hz evenly (sim_hz / {name} = {ratio:g})")
        return self


class Aircraft(StrictModel):
    name: str = Field("fwuav", description="folder under aircraft/")
    autopilot_gains: dict[str, float] = Field(default_factory=dict,
                                              description="overrides of aircraft/<name>/autopilot.yaml values")

    @model_validator(mode="after")
    def _known(self):
        """The aircraft exists (aircraft/<name>/ with its JSBSim file) and every gain named is one of its
        autopilot's, within that gain's range."""
        from fwsim import AIRCRAFT_DIR
        known = sorted(p.name for p in AIRCRAFT_DIR.iterdir() if (p / f"{p.name}.xml").is_file())
        if self.name not in known:
            raise ValueError(f"name: no aircraft '{short(self.name, 40)}' under aircraft/ (known: {', '.join(known)})")
        from fwsim.autopilot import load_autopilot_params
        try:
            load_autopilot_params(self.name, overrides=self.autopilot_gains)
        except (ValueError, FileNotFoundError) as exc:
            raise ValueError(f"autopilot_gains: {short(exc, 160)}") from None
        return self


#: severity -> (JSBSim's probability-of-exceedance curve, MIL-F-8785C Fig. 7; wind at 20 ft, m/s): the
#: handbook's light / moderate / severe reference values (15 / 30 / 45 kn at 20 ft)
TURBULENCE_SEVERITY = {"light": (3, 7.716), "moderate": (4, 15.433), "severe": (6, 23.150)}


class Turbulence(StrictModel):
    """Continuous turbulence from JSBSim's own MIL-F-8785C model (Dryden spectra; FGWinds), seeded from the
    scenario's seed. Above 2000 ft its intensity follows the severity's probability-of-exceedance curve,
    below 1000 ft the wind at 20 ft (sigma_w = 0.1 W20), blended between."""

    model: Literal["dryden", "tustin"] = Field(
        "dryden", description="JSBSim's Milspec (dryden) or Tustin discretisation of the Dryden filters")
    severity: Literal["light", "moderate", "severe"] | None = Field(
        None, description="the handbook's intensity (with its reference wind at 20 ft unless that is given)")
    wind_at_20ft_m_s: float | None = Field(
        None, ge=0.0, le=60.0, description="wind speed 20 ft above the sea (sets the low-altitude intensity; "
                                           "without a severity it also picks the curve: light up to 15 kn, "
                                           "moderate up to 30 kn, else severe)")

    @model_validator(mode="after")
    def _something(self):
        if self.severity is None and self.wind_at_20ft_m_s is None:
            raise ValueError("give a severity (light, moderate, severe) or wind_at_20ft_m_s")
        return self

    def jsbsim_settings(self) -> tuple[int, int, float]:
        """(turb-type, severity index, wind at 20 ft in m/s) for JSBSim's FGWinds."""
        kind = 3 if self.model == "dryden" else 4
        if self.severity is not None:
            index, w20 = TURBULENCE_SEVERITY[self.severity]
            return kind, index, self.wind_at_20ft_m_s if self.wind_at_20ft_m_s is not None else w20
        w20 = float(self.wind_at_20ft_m_s)
        index = next((i for i, ref in TURBULENCE_SEVERITY.values() if w20 <= ref + 1e-9), 6)
        return kind, index, w20


class World(StrictModel):
    origin_lat_deg: float = Field(0.0, ge=-85, le=85, description="geodetic latitude of the world origin")
    origin_lon_deg: float = Field(0.0, ge=-180, le=180, description="longitude of the world origin")
    wind_enu_m_s: Vec3 = Field(default_factory=lambda: [0.0, 0.0, 0.0], description="constant wind")
    turbulence: Turbulence | None = Field(None, description="JSBSim's continuous turbulence (none by default)")


class Initial(StrictModel):
    pos_enu_m: Vec3 = Field(description="UAV position in the world ENU frame")
    airspeed_m_s: float = Field(gt=0, le=60, description="airspeed at the start, m/s")
    heading_deg: float = Field(ge=-360, le=360, description="clockwise from North")
    flight_path_deg: float = Field(0.0, ge=-60, le=30, description="positive climbing")
    trim: bool = Field(True, description="trim with JSBSim's trim before the run")

    @model_validator(mode="after")
    def _above_sea(self):
        if self.pos_enu_m[2] <= 0:
            raise ValueError(f"pos_enu_m: the UAV must start above the sea (z = {self.pos_enu_m[2]:g} m)")
        return self


class Stop(StrictModel):
    min_height_m: float = Field(0.0, ge=0, description="end the run below this height above the sea")
    max_airspeed_m_s: float = Field(80.0, gt=0, description="end the run (failed) above this airspeed")


def start_epoch_ns(text: str) -> int:
    """ISO 8601 date-time text (``2026-05-01T09:30:00Z``; no offset = UTC) -> ns since 1970-01-01 UTC."""
    from datetime import datetime, timezone
    try:
        when = datetime.fromisoformat(str(text).strip())
    except ValueError:
        raise ValueError(f"{short(repr(text), 60)} is not an ISO 8601 date and time "
                         "(e.g. 2026-05-01T09:30:00Z)") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=timezone.utc)
    if not 1970 <= when.astimezone(timezone.utc).year <= 2200:
        raise ValueError(f"{short(repr(text), 60)} lies outside 1970-2200")
    return int(round(when.timestamp() * 1e6)) * 1000


class Scenario(StrictModel):
    name: str = Field(description="the scenario's name (the log's and the batch run's)")
    description: str = Field("", description="a line saying what the scenario flies")
    seed: int = Field(0, ge=0,
        description="the seed of every random draw (sensor noise, detector misses); the same seed flies the same run")
    duration_s: float = Field(gt=0, le=7200,
        description="the run ends after this much sim time (or earlier, at impact or a stop condition), s")
    rates: Rates = Field(default_factory=Rates, description="the simulation, flight-software and log rates")
    aircraft: Aircraft = Field(default_factory=Aircraft, description="the UAV's JSBSim model")
    world: World = Field(default_factory=World, description="the world's geodetic origin, wind and turbulence")
    initial: Initial = Field(description="the UAV's start: position, airspeed, heading")
    stop: Stop = Field(default_factory=Stop, description="conditions that end the run early")
    target: TargetConfig = Field(default_factory=TargetConfig, description="the ship: size, layout, start and motion")
    camera: CameraConfig = Field(default_factory=CameraConfig,
        description="the gimbal camera, its detector and the rendered image")
    sensors: SensorsConfig = Field(default_factory=SensorsConfig,
        description="the onboard sensors: a profile of error models (IMU, GNSS, baro, mag, pitot, encoders, "
                    "camera mount) or ideal")
    controllers: Controllers = Field(default_factory=Controllers,
        description="the flight software: which blocks fly the mission and their settings")
    events: list[Event] = Field(default_factory=list, description="timed faults and disturbances (fwsim.world.events)")
    start_time: str | None = Field(None, description="the date and time (ISO 8601; UTC unless it names an offset) "
                                                     "the log's clock starts at; sim time stays in the messages; "
                                                     "none: the run's wall-clock start")

    @field_validator("start_time")
    @classmethod
    def _iso_start_time(cls, v):
        if v is not None:
            start_epoch_ns(v)  # raises ValueError with the reason
        return v

    @model_validator(mode="after")
    def _gimbal_limits_agree(self):
        """The flight software's idea of the gimbal (controllers.ibvs) must not exceed the gimbal
        (camera.gimbal): a law that plans with a wider range or faster rates than the joints have fails in
        flight. Tighter limits (soft stops) are allowed."""
        fsw, hw = self.controllers.ibvs, self.camera.gimbal
        for name in ("pan_limits_rad", "tilt_limits_rad"):
            a, b = getattr(fsw, name), getattr(hw, name)
            if a[0] < b[0] - 1e-9 or a[1] > b[1] + 1e-9:
                raise ValueError(f"controllers.ibvs.{name}: {_short(a)} reaches beyond the gimbal's "
                                 f"camera.gimbal.{name} {_short(b)}")
        for name in ("max_pan_rate_rad_s", "max_tilt_rate_rad_s"):
            a, b = getattr(fsw, name), getattr(hw, name)
            if a > b + 1e-9:
                raise ValueError(f"controllers.ibvs.{name}: {a:g} is faster than the gimbal's "
                                 f"camera.gimbal.{name} {b:g}")
        return self

    @model_validator(mode="after")
    def _within_the_flat_earth_mapping(self):
        """The start within MAX_RANGE_FROM_ORIGIN_M of the world origin, horizontally: the ENU <-> geodetic
        mapping (fwsim/interface/frames.py, GeoOrigin) scales latitude and longitude about the origin, so distances
        distort with distance from it (1.6e-4 per km of northing at mid latitudes)."""
        x, y, _ = self.initial.pos_enu_m
        r = (x * x + y * y) ** 0.5
        if r > MAX_RANGE_FROM_ORIGIN_M:
            raise ValueError(f"initial.pos_enu_m: {r / 1000:.0f} km from the world origin, beyond the flat-earth "
                             f"mapping's {MAX_RANGE_FROM_ORIGIN_M / 1000:.0f} km; move world.origin_lat_deg / "
                             "origin_lon_deg near the start instead")
        return self

    @model_validator(mode="after")
    def _nav_faults_need_error_models(self):
        """A navigation fault acts on the sensors' error models, which the ideal profile does not have."""
        from fwsim.world.events import NAV_FAULT_KINDS
        if self.sensors.profile == "ideal":
            for i, ev in enumerate(self.events):
                if ev.kind in NAV_FAULT_KINDS:
                    raise ValueError(f"events[{i}].kind: {ev.kind} acts on the sensors' error models; it needs "
                                     "sensors.profile typical or degraded")
        return self

    @model_validator(mode="after")
    def _camera_rates(self):
        for name, hz in (("camera.rate_hz", self.camera.rate_hz), ("camera.render.rate_hz",
                                                                   self.camera.render.rate_hz)):
            if hz > 0:
                ratio = self.rates.sim_hz / hz
                if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
                    raise ValueError(f"{name} must divide rates.sim_hz evenly (sim_hz / rate = {ratio:g})")
        return self


def _short(values) -> str:
    return "[" + ", ".join(f"{v:.4g}" for v in values) + "]"


class ScenarioError(ValueError):
    """A scenario file that cannot be used; ``str()`` is one line per problem."""


#: problems listed one per line at most; the rest are counted
MAX_PROBLEMS = 10


def _format_errors(source: str, exc: ValidationError) -> str:
    lines = []
    errors = exc.errors()
    for err in errors[:MAX_PROBLEMS]:
        loc = short(".".join(str(p) for p in err["loc"]
                             if not (isinstance(p, str) and p.startswith("function-"))), 100)
        msg = short(err["msg"].removeprefix("Value error, "), 200)
        got = ""
        if err["type"] not in ("missing", "extra_forbidden") and "input" in err and not isinstance(err["input"], dict):
            shown = short(repr(err['input']), 60)
            got = "" if f"got {shown}" in msg else f" (got {shown})"  # (a validator's own message may say it)
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        if loc and msg.startswith(loc + "."):  # a validator naming a deeper field itself
            loc = ""
        lines.append(f"{source}: {loc}: {msg}{got}" if loc else f"{source}: {msg}{got}")
    if len(errors) > MAX_PROBLEMS:
        lines.append(f"{source}: ... and {len(errors) - MAX_PROBLEMS} more problems")
    return "\n".join(lines)


def parse_sets(items: list[str]) -> dict[str, Any]:
    """``["a.b=1", "c=[1, 2]"]`` (command-line ``--set`` items) -> ``{"a.b": 1, "c": [1, 2]}``, values as YAML."""
    out = {}
    for item in items:
        if "=" not in item:
            raise ScenarioError(f"--set {short(item)}: expected PATH=VALUE (e.g. initial.airspeed_m_s=24)")
        key, value = item.split("=", 1)
        key = key.strip()
        if not key or any(not part for part in key.split(".")):
            raise ScenarioError(f"--set {short(item)}: expected PATH=VALUE with a dotted PATH (e.g. seed=3)")
        out[key] = load_yaml_text(value, f"--set {short(key, 60)}", ScenarioError)
    return out


def set_path(data: dict, path: str, value: Any) -> None:
    """Set ``a.b.c`` (list indices allowed: ``script.2.t_s``) in nested YAML data; ScenarioError naming the
    path when it cannot lead anywhere (an index past a list's end, a key inside a number ...)."""
    keys = path.split(".")
    node: Any = data
    for depth, k in enumerate(keys):
        last = depth == len(keys) - 1
        here = ".".join(keys[:depth]) or "the file"
        if isinstance(node, list):
            try:
                i = int(k)
                if not -len(node) <= i < len(node):
                    raise IndexError
            except (ValueError, IndexError):
                raise ScenarioError(f"--set {short(path, 60)}: {here} is a list of {len(node)}; "
                                    f"'{short(k, 20)}' is not one of its indices") from None
            if last:
                node[i] = value
            else:
                node = node[i]
        elif isinstance(node, dict):
            if last:
                node[k] = value
            else:
                if node.get(k) is None:
                    node[k] = {}
                node = node[k]
        else:
            raise ScenarioError(f"--set {short(path, 60)}: {here} is a single value ({short(repr(node), 30)}), "
                                "it has no fields")


def parse_scenario(text: str, source: str = "<scenario>", overrides: dict[str, Any] | None = None,
                   check_plugins: bool = True) -> Scenario:
    """Validate scenario YAML text; raises ScenarioError with one line per problem.

    A user's block class named in ``controllers`` (``controllers.blocks``) is imported and checked, from the
    Python path, else the folder of ``source`` (when it is a file) or the current folder; ``check_plugins``
    false skips that (a log's scenario read back for scoring, where the user's module may be missing)."""
    data = load_yaml_text(text, source, ScenarioError)
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: the file must be a mapping of keys (got {type(data).__name__})")
    if overrides:
        data = copy.deepcopy(data)
        for path, value in overrides.items():
            set_path(data, path, copy.deepcopy(value))  # a later path may edit inside it
    dirs = [Path(source).resolve().parent] if Path(source).is_file() else []
    context = {"check_plugins": check_plugins, "search_dirs": dirs + [Path.cwd()]}
    try:
        return Scenario.model_validate(data, context=context)
    except ValidationError as exc:
        raise ScenarioError(_format_errors(source, exc)) from None


def dump_scenario(scenario: Scenario) -> str:
    """The scenario as YAML with every field, the defaults filled in (``fwsim scenario show``); it reads back
    (:func:`parse_scenario`) to the same scenario."""
    import yaml

    from fwsim.scenario.yamlfile import FAST_SAFE_DUMPER
    body = yaml.dump(scenario.model_dump(mode="json"), Dumper=FAST_SAFE_DUMPER, sort_keys=False, allow_unicode=True)
    return f"# {scenario.name}: every field, the defaults filled in (fwsim scenario show)\n{body}"


def load_scenario(path: str | Path, overrides: dict[str, Any] | None = None) -> tuple[Scenario, str]:
    """Read and validate a scenario file; returns the config and its text (for the log)."""
    path = Path(path)
    if path.is_dir():
        raise ScenarioError(f"{path}: is a folder, expected a scenario file (YAML)")
    text = read_text(path, "scenario file", ScenarioError)  # "no such scenario file" when missing
    return parse_scenario(text, str(path), overrides), text
