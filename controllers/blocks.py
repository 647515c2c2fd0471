"""Swappable blocks: the Protocols a user's class implements, and how the scenario picks one.

Four parts of the flight software are chosen in the scenario's ``controllers``
section, each by a built-in name or by the import path of a user's class::

    controllers:
      estimator: ukf                    # the target estimator: ukf | ct_ukf | imm (Protocol TargetEstimator)
      after_lock: nmpc                  # Phase 2 guidance: path | orbit | nmpc (Protocol LoiterGuidance)
      terminal: bpng                    # Phase 3 guidance (Protocol TerminalGuidance)
      pointing: ibvs                    # the gimbal's tracking law (Protocol PointingLaw)

      estimator:                        # a user's class, with its own options
        use: my_package.filters:MyFilter
        options: {process_noise: 0.1}

The module is imported from the Python path, else from the scenario file's
folder or the current folder. The class is checked when the scenario is
read: a bad path, or a class that lacks a method of the Protocol, is a
one-line scenario error before anything flies. The Protocol's data members
(``initialised``, ``radius_m``, ...) may be properties, class attributes or
attributes the class sets in ``__init__``: they are checked on the built
block, at the start of the run. In flight, a user's block is guarded at its
boundary (:func:`build_block`): an exception in one of its methods, or a
return value of the wrong type, ends the run with a :class:`PluginError`
naming the slot, the method, the line of the user's file and the exception. If the class has a ``Config``
attribute (a pydantic model), the options are validated with it and the class
gets the model; otherwise it gets the options as a dict. It is built as
``cls(options, context)``, where ``context`` (:class:`BlockContext`) holds
what a block may use: the whole ``controllers`` configuration, the camera
model, the mount offset, the flight software's ship model and a recorder for
its own log topics and events. A user estimator can wrap the built-in one::

    class CountingUkf:
        def __init__(self, options, context):
            self.inner = UkfTargetEstimator(context.camera, context.config.ukf)
        ...                                # delegate, counting calls

docs/guide/plugins.md shows whole ones. What a block returns is typed
(``controllers.messages``). Built-in classes live beside their algorithms:
``controllers.estimation.ukf``, ``controllers.estimation.ct_ukf``, ``controllers.estimation.imm``,
``controllers.guidance.guidance``, ``controllers.pointing.pointing``.

This module imports nothing heavy (no solver, filter or OpenCV): the scenario
validation uses it.
"""
from __future__ import annotations

import importlib
import inspect
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np

__all__ = ["TargetEstimator", "LoiterGuidance", "TerminalGuidance", "PointingLaw", "BlockContext", "Recorder",
           "SLOTS", "Slot", "BlockError", "PluginError", "builtin_names", "resolve_class", "build_block",
           "options_for"]


# --------------------------------------------------------------------------- the Protocols


@runtime_checkable
class TargetEstimator(Protocol):
    """A target estimator (``controllers.estimator``). The flight software's estimation block
    (``controllers.estimation.estimation``) decides when it starts and restarts; the estimator predicts, fuses
    and estimates. Members (``initialised``, ``tracked_height_m``: a property, a class attribute or an
    attribute set in ``__init__``):"""

    @property
    def initialised(self) -> bool:
        """True while it has a target (after ``initialise``, until it resets itself)."""
        ...

    @property
    def tracked_height_m(self) -> float:
        """Height above the ship's waterline of the point it tracks (the perception's box-centre
        correction and the depth model use it)."""
        ...

    def initialise(self, fix, camera) -> None:
        """Start from one detection (``DetectionFix``: its box centre ``u_px, v_px``) seen by the camera
        (``CameraMotion``); raise ValueError when it cannot (e.g. the ray misses the sea)."""
        ...

    def predict(self, t_s: float, camera) -> None:
        """Bring the estimate to ``t_s`` (the camera's motion since the last call in ``camera``). It may
        reset itself here (``initialised`` false afterwards) when its state is no longer finite."""
        ...

    def update(self, fix, camera):
        """Fuse a detection (the box centre corrected for the ship's shape); return a ``FusionResult``
        (used, or why not, with the innovation and its test ratio when there is one)."""
        ...

    def estimate(self):
        """The ``TargetEstimate`` now (called only while ``initialised``); it is logged on /fsw/estimate."""
        ...

    def status(self, t_s: float):
        """Its counters (``EstimatorStatus``), logged on /fsw/estimator_status when one changes."""
        ...


@runtime_checkable
class LoiterGuidance(Protocol):
    """Phase 2 guidance (``controllers.after_lock``): circles the target on its ring until the switch."""

    @property
    def radius_m(self) -> float:
        """R, the ring's radius round the target (the phase switch and the metrics use it)."""
        ...

    @property
    def altitude_m(self) -> float:
        """H, the ring's altitude (world z)."""
        ...

    def step(self, nav, target):
        """``Measurements`` (the flight software's position), ``TargetState`` -> ``Guidance``."""
        ...


@runtime_checkable
class TerminalGuidance(Protocol):
    """Phase 3 guidance (``controllers.terminal``): to the ship at the mission's impact angles
    (``controllers.bpng.impact_flight_path_deg`` / ``impact_heading_deg``, whichever law flies)."""

    def step(self, nav, target):
        """``Measurements``, ``TargetState`` -> ``Guidance`` (an ``AccelCommand`` or a ``RateCommand``)."""
        ...


@runtime_checkable
class PointingLaw(Protocol):
    """The gimbal's tracking law (``controllers.pointing.pointing``), while the target is being detected."""

    def step(self, nav, camera, target):
        """``Measurements``, ``CameraMotion``, ``TargetState`` -> ``GimbalCommand`` (joint rates)."""
        ...


# --------------------------------------------------------------------------- what a block gets


class Recorder:
    """Where the blocks put what goes to the log in one tick: messages by topic, and event lines.

    A message is a dataclass whose first field is ``t_s`` (its JSON Schema is made from the class)."""

    def __init__(self):
        self._logs: list[tuple[str, Any]] = []
        self._events: list[str] = []

    def log(self, topic: str, msg: Any) -> None:
        self._logs.append((topic, msg))

    def event(self, text: str) -> None:
        self._events.append(text)

    def drain(self) -> tuple[tuple[tuple[str, Any], ...], tuple[str, ...]]:
        """This tick's (logs, events), emptied."""
        out = tuple(self._logs), tuple(self._events)
        self._logs.clear()
        self._events.clear()
        return out


@dataclass
class BlockContext:
    """What a block may use: the flight software's configuration and its a-priori models."""

    config: Any  # controllers.config.Controllers: every block's settings
    camera: Any  # controllers.navigation.camera_model.PinholeCamera: the camera's intrinsics
    mount_offset_frd_m: np.ndarray  # the gimbal's rotation centre relative to the CG, body FRD
    ship: Any  # controllers.perception.target_model.ShipModel: the ship class's outline and its learnt heading
    recorder: Recorder = field(default_factory=Recorder)
    initial: Any = None  # the scenario's initial state (the initial path starts there)


# --------------------------------------------------------------------------- the slots


@dataclass(frozen=True)
class Slot:
    """One swappable part: its Protocol, the members a class must have, and the built-in blocks."""

    name: str
    protocol: type
    members: tuple[str, ...]
    builtins: dict[str, Callable[[BlockContext], Any]]

    @property
    def methods(self) -> tuple[str, ...]:
        """The members that must be methods of the class."""
        return tuple(m for m in self.members if callable(getattr(self.protocol, m, None)))

    @property
    def data(self) -> tuple[str, ...]:
        """The data members: properties, class attributes or attributes set in ``__init__`` (see the module text)."""
        return tuple(m for m in self.members if m not in self.methods)


def _ukf(ctx: BlockContext):
    from controllers.estimation.ukf import UkfTargetEstimator
    return UkfTargetEstimator(ctx.camera, ctx.config.ukf)


def _ct_ukf(ctx: BlockContext):
    from controllers.estimation.ct_ukf import CtUkfTargetEstimator
    return CtUkfTargetEstimator(ctx.camera, ctx.config.ukf, ctx.config.ct_ukf)


def _imm(ctx: BlockContext):
    from controllers.estimation.imm import ImmTargetEstimator
    return ImmTargetEstimator(ctx.camera, ctx.config.ukf, ctx.config.ct_ukf, ctx.config.imm)


def _orbit(ctx: BlockContext):
    from controllers.guidance.guidance import OrbitLoiter
    return OrbitLoiter(ctx.config.orbit, ctx.config.initial_path.max_bank_deg)


def _nmpc(ctx: BlockContext):
    from controllers.guidance.guidance import NmpcLoiter
    return NmpcLoiter(ctx.config.nmpc, ctx.recorder)


def _bpng(ctx: BlockContext):
    from controllers.guidance.guidance import BpngTerminal
    return BpngTerminal(ctx.config.bpng, ctx.ship, ctx.recorder)


def _ibvs(ctx: BlockContext):
    from controllers.pointing.pointing import IbvsPointing
    return IbvsPointing(ctx.config.ibvs, ctx.camera, ctx.mount_offset_frd_m, ctx.recorder)


SLOTS: dict[str, Slot] = {
    "estimator": Slot("estimator", TargetEstimator,
                      ("initialised", "tracked_height_m", "initialise", "predict", "update", "estimate", "status"),
                      {"ukf": _ukf, "ct_ukf": _ct_ukf, "imm": _imm}),
    "after_lock": Slot("after_lock", LoiterGuidance, ("radius_m", "altitude_m", "step"),
                       {"orbit": _orbit, "nmpc": _nmpc}),
    "terminal": Slot("terminal", TerminalGuidance, ("step",), {"bpng": _bpng}),
    "pointing": Slot("pointing", PointingLaw, ("step",), {"ibvs": _ibvs}),
}
#: after_lock's name for "no Phase 2": keep the initial path
NO_LOITER = "path"


class BlockError(ValueError):
    """A block choice that cannot be used (one line)."""


class PluginError(RuntimeError):
    """A user's block failed in flight: ``str()`` is one line naming the slot (``controllers.estimator``), the
    class and method, the line of the user's file where it happened and the exception, or the type it returned
    and the type expected. The user's exception is its ``__cause__`` (``fwsim run --debug`` prints it whole)."""


def resolve_class(path: str, slot: str, search_dirs=()) -> type:
    """The class at ``module.sub:ClassName``, checked against the slot's Protocol; BlockError if it is not.

    The module is imported from the Python path, else from ``search_dirs`` (tried in order)."""
    s = SLOTS[slot]
    module_name, sep, qualname = path.partition(":")
    if not sep or not module_name or not qualname:
        raise BlockError(f"expected a built-in name ({', '.join(builtin_names(slot))}) or an import path "
                         f"'module.sub:ClassName', got {path!r}")
    module = _import(module_name, search_dirs)
    obj = module
    for part in qualname.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            raise BlockError(f"{module_name!r} has no {qualname!r}")
    if not inspect.isclass(obj):
        raise BlockError(f"{path!r} is not a class")
    missing = [m for m in s.methods if not hasattr(obj, m)]
    if missing:
        raise BlockError(f"{path} does not implement {s.protocol.__name__}: no {', '.join(missing)} "
                         "(a method of the Protocol; see docs/guide/plugins.md)")
    not_methods = [m for m in s.methods if not callable(getattr(obj, m))]
    if not_methods:
        raise BlockError(f"{path} does not implement {s.protocol.__name__}: {', '.join(not_methods)} "
                         "must be a method")
    methods = [m for m in s.data if callable(inspect.getattr_static(obj, m, None))]
    if methods:
        raise BlockError(f"{path} does not implement {s.protocol.__name__}: {', '.join(methods)} must be a "
                         "property or an attribute, not a method")
    return obj


def _import(module_name: str, search_dirs):
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is None or not module_name.startswith(exc.name.split(".")[0]):
            raise BlockError(f"importing {module_name!r} failed: {exc}") from None
        first_error = exc
    except Exception as exc:  # noqa: BLE001 - a user's module may raise anything while importing
        raise BlockError(f"importing {module_name!r} failed: {type(exc).__name__}: {exc}") from None
    for d in search_dirs:
        d = str(Path(d).resolve())
        if d in sys.path:
            continue
        sys.path.append(d)  # kept: the run (and a batch worker, which re-reads the scenario) imports it again
        try:
            return importlib.import_module(module_name)
        except ModuleNotFoundError:
            sys.path.remove(d)
        except Exception as exc:  # noqa: BLE001
            raise BlockError(f"importing {module_name!r} failed: {type(exc).__name__}: {exc}") from None
    raise BlockError(f"cannot import {module_name!r} ({first_error}); it must be on the Python path, or in "
                     "the scenario file's folder or the current folder")


def builtin_names(slot: str) -> list[str]:
    """The slot's built-in names (``after_lock`` also takes ``path``: no Phase 2)."""
    names = list(SLOTS[slot].builtins)
    return [NO_LOITER] + names if slot == "after_lock" else names


def options_for(cls: type, options: dict) -> Any:
    """The options as the class takes them: validated by its ``Config`` model if it has one, else the dict."""
    model = getattr(cls, "Config", None)
    if inspect.isclass(model) and hasattr(model, "model_validate"):
        return model.model_validate(options)
    return dict(options)


def build_block(slot: str, choice, ctx: BlockContext, search_dirs=()):
    """The block for a choice (``BlockChoice``): a built-in made from its config section, or a user's class
    made as ``cls(options, ctx)``, guarded at its boundary (:func:`guarded`) and checked for the Protocol's
    data members once built."""
    builtin = SLOTS[slot].builtins.get(choice.use)
    if builtin is not None:
        return builtin(ctx)
    cls = resolve_class(choice.use, slot, search_dirs)
    options = options_for(cls, choice.options)
    block = guarded(slot, cls)(options, ctx)
    missing = [m for m in SLOTS[slot].data if not hasattr(block, m)]
    if missing:
        raise PluginError(f"controllers.{slot}: {cls.__name__} has no {', '.join(missing)} once built (set it in "
                          "__init__, or make it a property or a class attribute)")
    return block


# --------------------------------------------------------------------------- a user's block, guarded

#: per slot, what a method must return (a user's block is checked at each call; None: not checked). The names
#: are ``controllers.messages`` / ``fwsim.interface.messages`` classes, looked up when a block is guarded.
RETURNS: dict[str, dict[str, str]] = {
    "estimator": {"update": "FusionResult", "estimate": "TargetEstimate", "status": "EstimatorStatus"},
    "after_lock": {"step": "Guidance"},
    "terminal": {"step": "Guidance"},
    "pointing": {"step": "GimbalCommand"},
}
#: exceptions a method may raise as part of its Protocol (they pass the guard unchanged)
PASSES: dict[tuple[str, str], tuple[type, ...]] = {("estimator", "initialise"): (ValueError,)}


def guarded(slot: str, cls: type) -> type:
    """A subclass of the user's ``cls`` (same name, same behaviour) whose Protocol methods, properties and
    ``__init__`` turn an exception into a :class:`PluginError` that says where it happened in the user's file,
    and whose methods check the type they return (:data:`RETURNS`; a Guidance's command too)."""
    from controllers import messages
    from fwsim.interface import messages as boundary
    s = SLOTS[slot]
    files = _user_files(cls)
    expected = {m: getattr(messages, n, None) or getattr(boundary, n) for m, n in RETURNS[slot].items()}
    body: dict[str, Any] = {"__module__": cls.__module__, "__qualname__": cls.__qualname__, "__doc__": cls.__doc__,
                            "__init__": _guard(slot, cls, "__init__", cls.__init__, files, None)}
    for m in s.methods:
        body[m] = _guard(slot, cls, m, getattr(cls, m), files, expected.get(m))
    for m in s.data:
        prop = inspect.getattr_static(cls, m, None)
        if isinstance(prop, property) and prop.fget is not None:
            body[m] = property(_guard(slot, cls, m, prop.fget, files, None), prop.fset, prop.fdel, prop.__doc__)
    return type(cls.__name__, (cls,), body)


def _guard(slot: str, cls: type, name: str, fn: Callable, files: frozenset[str], expected: type | None):
    passes = PASSES.get((slot, name), ())
    command = expected is not None and expected.__name__ == "Guidance"
    if command:
        from fwsim.interface.messages import AutopilotCommand

    def call(self, *args, **kwargs):
        try:
            out = fn(self, *args, **kwargs)
        except passes:
            raise
        except PluginError:
            raise
        except Exception as exc:  # noqa: BLE001 - a user's code may raise anything: the run says where
            raise PluginError(f"controllers.{slot}: {cls.__name__}.{name} failed{_where(exc, files)}: "
                              f"{type(exc).__name__}: {exc}") from exc
        if expected is not None and not isinstance(out, expected):
            raise PluginError(f"controllers.{slot}: {cls.__name__}.{name} returned {type(out).__name__}, "
                              f"expected {expected.__name__}")
        if command and not isinstance(out.command, AutopilotCommand):
            raise PluginError(f"controllers.{slot}: {cls.__name__}.{name} returned a Guidance whose command is "
                              f"{type(out.command).__name__}, expected AccelCommand or RateCommand")
        return out

    call.__name__, call.__qualname__, call.__doc__ = name, f"{cls.__qualname__}.{name}", fn.__doc__
    return call


def _user_files(cls: type) -> frozenset[str]:
    """The source files of the user's class and of its bases that are not the project's own."""
    files = set()
    for c in cls.__mro__:
        module = sys.modules.get(c.__module__)
        path = getattr(module, "__file__", None)
        if path and c.__module__.split(".")[0] not in ("controllers", "fwsim", "builtins"):
            files.add(str(Path(path).resolve()))
    return frozenset(files)


def _where(exc: BaseException, files: frozenset[str]) -> str:
    """`` at my_filters.py:42``: the innermost frame of the traceback in one of ``files`` (else the innermost
    frame of all), relative to the current folder when it is under it."""
    import traceback
    frames = traceback.extract_tb(exc.__traceback__)[1:]  # (the guard's own frame first)
    if not frames:
        return ""
    mine = [f for f in frames if str(Path(f.filename).resolve()) in files]
    frame = (mine or frames)[-1]
    name = frame.filename
    try:
        rel = os.path.relpath(name)
        name = name if rel.startswith("..") else rel
    except ValueError:  # another drive (Windows)
        pass
    return f" at {name}:{frame.lineno}"
