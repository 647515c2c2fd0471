"""The estimation block's slow-ship coast (``detection_gate.slow_coast_velocity``), through a scripted filter."""
from __future__ import annotations

import dataclasses
import types

import numpy as np
import pytest
from test_course_turn import _Recorder

from controllers.estimation import Estimation
from controllers.messages import DetectionFix, EstimatorStatus, FusionReason, FusionResult, TargetEstimate
from fwsim import SCENARIO_DIR
from fwsim.scenario import load_scenario


class _Scripted:
    """A filter whose estimate is what the test says: position p0 + vel * (t - t0), the velocity set per step."""

    tracked_height_m = 3.75

    def __init__(self):
        self.initialised = False
        self.t, self.pos, self.vel = 0.0, np.array([100.0, 50.0, 3.75]), np.zeros(3)

    def initialise(self, fix, camera):
        self.initialised = True

    def predict(self, t_s, camera):
        self.pos = self.pos + self.vel * (t_s - self.t)
        self.t = t_s

    def update(self, fix, camera):
        return FusionResult(True, FusionReason.USED)

    def estimate(self):
        return TargetEstimate(self.t, self.pos.copy(), self.vel.copy(), np.ones(3), np.ones(3), 0.0, 0.0,
                              np.full(2, np.nan))

    def status(self, t_s):
        return EstimatorStatus(t_s, 0, 0, 0, 0, 0, 0)


class _Nav:
    def __init__(self, t_s):
        self.t_s, self.pos_enu_m = t_s, np.array([0.0, 0.0, 300.0])


_FIX = DetectionFix(0.0, True, 0.0, 320.0, 240.0, np.zeros(4), 320.0, 240.0, np.full(4, np.nan), True, "", "",
                    True, False, 0.0, 0.0)


def _fly(speed_limit, dive_vel, dive_box_vel, coast_from_s=10.0, end_s=12.0, dt=0.1):
    """The loiter to t = 5 s at ``dive_vel``, the dive's boxes to ``coast_from_s`` with the filter's velocity
    ``dive_box_vel``, then the gate's too_close to ``end_s``: (the last fused estimate (t, pos), the states of
    the coast)."""
    f = _Scripted()
    est = Estimation(f, 120.0, 5, _Recorder(), None, speed_limit)
    f.vel = np.asarray(dive_vel, float)
    coast, fused = [], None
    for k in range(int(round(end_s / dt)) + 1):
        t = k * dt
        nav, cam = _Nav(t), object()
        est.in_dive = t > 5.0
        if t > 5.25:  # (the block takes the dive's starting velocity at its first tick, 5.1 s)
            f.vel = np.asarray(dive_box_vel, float)
        est.predict(nav, cam)
        close = t >= coast_from_s
        fix = dataclasses.replace(_FIX, t_s=t, lock_now=k == 0, use=not close,
                                  reason=FusionReason.TOO_CLOSE if close else "")
        state = est.update(nav, cam, fix)
        if not close:
            fused = (t, f.pos.copy())
        else:
            coast.append((t, state, f.estimate()))
    return fused, coast


def test_a_slow_ships_coast_flies_the_dives_starting_velocity_from_the_last_fused_box():
    v0, v1 = [0.3, -0.2, 0.0], [1.1, 0.6, 0.0]  # the dive's boxes pulled the filter's velocity
    (t0, p0), coast = _fly(2.0, v0, v1)
    for t, state, filt in coast:
        assert np.allclose(state.vel_enu_m_s, v0)
        assert np.allclose(state.pos_enu_m, p0 + np.asarray(v0) * (t - t0))
        assert np.allclose(filt.vel_enu_m_s, v1)  # the filter (and /fsw/estimate) keep their own
    assert np.linalg.norm(coast[-1][1].pos_enu_m - coast[-1][2].pos_enu_m) > 1.0


@pytest.mark.parametrize("limit, v0, v1", [(None, [0.3, -0.2, 0.0], [1.1, 0.6, 0.0]),  # off
                                           (2.0, [2.5, 0.0, 0.0], [1.1, 0.6, 0.0]),  # fast at the dive's start
                                           (2.0, [0.3, -0.2, 0.0], [1.5, 1.5, 0.0])])  # fast at the last box
def test_otherwise_the_coast_is_the_filters_own(limit, v0, v1):
    _, coast = _fly(limit, v0, v1)
    for _, state, filt in coast:
        assert np.array_equal(state.pos_enu_m, filt.pos_enu_m) and np.array_equal(state.vel_enu_m_s,
                                                                                 filt.vel_enu_m_s)


def test_a_dive_given_up_forgets_its_starting_velocity():
    f = _Scripted()
    est = Estimation(f, 120.0, 5, _Recorder(), None, 2.0)
    nav, cam = _Nav(0.0), object()
    est.predict(nav, cam)
    est.update(nav, cam, dataclasses.replace(_FIX, lock_now=True))
    f.vel = np.array([0.5, 0.0, 0.0])
    est.in_dive = True
    est.update(_Nav(1.0), cam, _FIX)
    assert np.allclose(est._dive_vel, [0.5, 0.0, 0.0])
    est.in_dive = False  # a go-around
    est.update(_Nav(2.0), cam, _FIX)
    f.vel = np.array([1.2, 0.3, 0.0])
    est.in_dive = True
    est.update(_Nav(3.0), cam, _FIX)
    assert np.allclose(est._dive_vel, [1.2, 0.3, 0.0])


def test_the_scenario_sets_it():
    from controllers.mission import FlightSoftware
    default, _ = load_scenario(SCENARIO_DIR / "paper_mission.yaml")
    on, _ = load_scenario(SCENARIO_DIR / "paper_mission.yaml",
                          {"controllers.detection_gate.slow_coast_velocity": "dive_start"})
    assert FlightSoftware(on.controllers, on.initial, on.camera).estimation.slow_coast_speed_m_s == 2.0
    default_fsw = FlightSoftware(default.controllers, default.initial, default.camera)
    assert default_fsw.estimation.slow_coast_speed_m_s is None


class _Turning:
    """A course-turn finder stand-in: a turn handed on from ``from_s``."""

    def __init__(self, from_s):
        self.from_s = from_s

    fitted = False

    def state(self, t_s):
        return (np.zeros(3), np.zeros(3), 0.01) if t_s >= self.from_s else None

    def observe(self, *args):
        pass


def test_the_velocity_along_the_line_of_sight_is_held_only_in_the_dive_with_no_turn_handed_on():
    """``ukf.dive_los_velocity_hold_m``: the block tells the filter when the hold may act."""
    f = _Scripted()
    f.los_velocity_hold = False  # (a filter with the option on)
    est = Estimation(f, 120.0, 5, _Recorder(), None)
    cam = types.SimpleNamespace(pos_enu_m=np.array([0.0, 0.0, 300.0]), vel_enu_m_s=np.array([20.0, 0.0, 0.0]))
    est.predict(_Nav(0.0), cam)
    est.update(_Nav(0.0), cam, dataclasses.replace(_FIX, lock_now=True))
    seen = []
    for t, dive, turn_from in ((1.0, False, None), (2.0, True, None), (3.0, True, 5.0), (5.0, True, 5.0),
                               (6.0, False, 5.0)):
        est.turn = _Turning(turn_from) if turn_from is not None else None
        est.in_dive = dive
        est.predict(_Nav(t), cam)
        est.update(_Nav(t), cam, dataclasses.replace(_FIX, t_s=t))
        seen.append(f.los_velocity_hold)
    assert seen == [False, True, True, False, False]


def test_a_filter_with_the_hold_off_is_left_alone():
    f = _Scripted()
    f.los_velocity_hold = None  # (the UKF with dive_los_velocity_hold_m 0)
    est = Estimation(f, 120.0, 5, _Recorder(), None)
    cam = types.SimpleNamespace(pos_enu_m=np.array([0.0, 0.0, 300.0]), vel_enu_m_s=np.array([20.0, 0.0, 0.0]))
    est.predict(_Nav(0.0), cam)
    est.update(_Nav(0.0), cam, dataclasses.replace(_FIX, lock_now=True))
    est.in_dive = True
    est.predict(_Nav(1.0), cam)
    est.update(_Nav(1.0), cam, dataclasses.replace(_FIX, t_s=1.0))
    assert f.los_velocity_hold is None
