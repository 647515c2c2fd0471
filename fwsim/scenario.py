"""Scenario files: YAML -> validated, typed configuration.

A scenario is data (like JSBSim's scripts): aircraft, initial state, rates,
duration, seed and what the flight software should do. Unknown keys are
rejected; every problem is reported as one line naming the field path:

    scenarios/x.yaml: initial.airspeed_m_s: Input should be greater than 0 (got -5)

User-facing angles are degrees in aviation convention (DESIGN.md section 4):
heading clockwise from North, flight-path angle positive climbing.
"""
from __future__ import annotations

import copy
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from controllers.bpng import BpngConfig
from controllers.ibvs import IbvsConfig
from controllers.mission import DetectionGateConfig, ReacquireConfig, SwitchConfig
from controllers.nav import NavigationConfig
from controllers.nmpc import NmpcConfig
from controllers.search import AcquisitionConfig
from controllers.target_model import ShipModelConfig
from controllers.ukf import UkfConfig
from fwsim.camera import CameraConfig
from fwsim.sensors import SensorsConfig
from fwsim.target import TargetConfig

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Rates(_Strict):
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


class Aircraft(_Strict):
    name: str = Field("fwuav", description="folder under aircraft/")
    autopilot_gains: dict[str, float] = Field(default_factory=dict,
                                              description="overrides of aircraft/<name>/autopilot.yaml values")


class World(_Strict):
    origin_lat_deg: float = Field(0.0, ge=-85, le=85, description="geodetic latitude of the world origin")
    origin_lon_deg: float = Field(0.0, ge=-180, le=180, description="longitude of the world origin")
    wind_enu_m_s: Vec3 = Field(default_factory=lambda: [0.0, 0.0, 0.0], description="constant wind")


class Initial(_Strict):
    pos_enu_m: Vec3 = Field(description="UAV position in the world ENU frame")
    airspeed_m_s: float = Field(gt=0, le=60)
    heading_deg: float = Field(ge=-360, le=360, description="clockwise from North")
    flight_path_deg: float = Field(0.0, ge=-60, le=30, description="positive climbing")
    trim: bool = Field(True, description="trim with JSBSim's trim before the run")

    @model_validator(mode="after")
    def _above_sea(self):
        if self.pos_enu_m[2] <= 0:
            raise ValueError(f"pos_enu_m: the UAV must start above the sea (z = {self.pos_enu_m[2]:g} m)")
        return self


class RatesStep(_Strict):
    airspeed_m_s: float = Field(gt=0, le=60)
    roll_rate_deg_s: float = Field(0.0, ge=-200, le=200)
    pitch_rate_deg_s: float = Field(0.0, ge=-200, le=200)


class AccelStep(_Strict):
    airspeed_m_s: float = Field(gt=0, le=60)
    right_m_s2: float = Field(0.0, ge=-60, le=60, description="perpendicular to the velocity, to the right")
    up_m_s2: float = Field(0.0, ge=-60, le=60, description="perpendicular to the velocity, upward")


class ScriptStep(_Strict):
    t_s: float = Field(ge=0, description="time from which this command holds")
    rates: RatesStep | None = None
    accel: AccelStep | None = None
    gimbal_deg: Annotated[list[float], Field(min_length=2, max_length=2)] | None = Field(
        None, description="pan, tilt the gimbal is driven to from this step on (none: keep the last)")

    @model_validator(mode="after")
    def _one_mode(self):
        if (self.rates is None) == (self.accel is None):
            raise ValueError("give exactly one of 'rates' or 'accel'")
        return self


class InitialPath(_Strict):
    airspeed_m_s: float = Field(22.0, gt=0, le=60)
    waypoints_enu_m: list[Vec3] = Field(default_factory=list,
                                        description="empty: hold the initial heading and altitude")
    max_bank_deg: float = Field(35.0, gt=0, le=60)


class Orbit(_Strict):
    """Circle around the estimated target after lock (a stand-in until the NMPC loiter)."""

    airspeed_m_s: float = Field(22.0, gt=0, le=60)
    radius_m: float = Field(500.0, gt=20, le=5000, description="the paper's R")
    altitude_m: float = Field(500.0, gt=20, le=5000, description="the paper's H")
    clockwise: bool = Field(False, description="seen from above")


class Controllers(_Strict):
    kind: Literal["script", "mission"] = Field("mission", description="scripted commands or the mission")
    navigation: NavigationConfig = Field(default_factory=NavigationConfig)
    script: list[ScriptStep] = Field(default_factory=list)
    initial_path: InitialPath = Field(default_factory=InitialPath)
    acquisition: AcquisitionConfig = Field(default_factory=AcquisitionConfig)
    after_lock: Literal["path", "orbit", "nmpc"] = Field(
        "path", description="after the lock: keep the path, or loiter (Phase 2) with a circle follower or the NMPC")
    orbit: Orbit = Field(default_factory=Orbit)
    nmpc: NmpcConfig = Field(default_factory=NmpcConfig)
    switch: SwitchConfig = Field(default_factory=lambda: SwitchConfig(enabled=False))
    reacquire: ReacquireConfig = Field(default_factory=ReacquireConfig)
    bpng: BpngConfig = Field(default_factory=BpngConfig)
    ukf: UkfConfig = Field(default_factory=UkfConfig)
    target_model: ShipModelConfig = Field(default_factory=ShipModelConfig)
    detection_gate: DetectionGateConfig = Field(default_factory=DetectionGateConfig)
    ibvs: IbvsConfig = Field(default_factory=IbvsConfig)

    @model_validator(mode="after")
    def _script(self):
        if self.kind == "script":
            if not self.script:
                raise ValueError("kind 'script' needs a non-empty 'script' list")
            times = [s.t_s for s in self.script]
            if times != sorted(times):
                raise ValueError("script steps must be in increasing t_s")
        return self


class Stop(_Strict):
    min_height_m: float = Field(0.0, ge=0, description="end the run below this height above the sea")
    max_airspeed_m_s: float = Field(80.0, gt=0, description="end the run (failed) above this airspeed")


class Scenario(_Strict):
    name: str
    description: str = ""
    seed: int = Field(0, ge=0)
    duration_s: float = Field(gt=0, le=7200)
    rates: Rates = Field(default_factory=Rates)
    aircraft: Aircraft = Field(default_factory=Aircraft)
    world: World = Field(default_factory=World)
    initial: Initial
    stop: Stop = Field(default_factory=Stop)
    target: TargetConfig = Field(default_factory=TargetConfig)
    camera: CameraConfig = Field(default_factory=CameraConfig)
    sensors: SensorsConfig = Field(default_factory=SensorsConfig)
    controllers: Controllers = Field(default_factory=Controllers)

    @model_validator(mode="after")
    def _camera_rates(self):
        for name, hz in (("camera.rate_hz", self.camera.rate_hz), ("camera.render.rate_hz",
                                                                   self.camera.render.rate_hz)):
            if hz > 0:
                ratio = self.rates.sim_hz / hz
                if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
                    raise ValueError(f"{name} must divide rates.sim_hz evenly (sim_hz / rate = {ratio:g})")
        return self


class ScenarioError(ValueError):
    """A scenario file that cannot be used; ``str()`` is one line per problem."""


def _format_errors(source: str, exc: ValidationError) -> str:
    lines = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"] if not (isinstance(p, str) and p.startswith("function-")))
        msg = err["msg"].removeprefix("Value error, ")
        got = ""
        if err["type"] not in ("missing", "extra_forbidden") and "input" in err and not isinstance(err["input"], dict):
            got = f" (got {err['input']!r})"
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        lines.append(f"{source}: {loc or '<top>'}: {msg}{got}")
    return "\n".join(lines)


def parse_sets(items: list[str]) -> dict[str, Any]:
    """``["a.b=1", "c=[1, 2]"]`` (command-line ``--set`` items) -> ``{"a.b": 1, "c": [1, 2]}``, values as YAML."""
    out = {}
    for item in items:
        if "=" not in item:
            raise ScenarioError(f"--set {item}: expected PATH=VALUE (e.g. initial.airspeed_m_s=24)")
        key, value = item.split("=", 1)
        out[key.strip()] = yaml.safe_load(value)
    return out


def set_path(data: dict, path: str, value: Any) -> None:
    """Set ``a.b.c`` (list indices allowed: ``script.2.t_s``) in nested YAML data."""
    keys = path.split(".")
    node = data
    for k in keys[:-1]:
        if isinstance(node, list):
            node = node[int(k)]
        else:
            node = node.setdefault(k, {})
    last = keys[-1]
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value


def parse_scenario(text: str, source: str = "<scenario>", overrides: dict[str, Any] | None = None) -> Scenario:
    """Validate scenario YAML text; raises ScenarioError with one line per problem."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ScenarioError(f"{source}{where}: YAML syntax error: {problem}") from None
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: the file must be a mapping of keys (got {type(data).__name__})")
    if overrides:
        data = copy.deepcopy(data)
        for path, value in overrides.items():
            set_path(data, path, value)
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(_format_errors(source, exc)) from None


def load_scenario(path: str | Path, overrides: dict[str, Any] | None = None) -> tuple[Scenario, str]:
    """Read and validate a scenario file; returns the config and its text (for the log)."""
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(f"{path}: no such scenario file")
    text = path.read_text()
    return parse_scenario(text, str(path), overrides), text
