"""Every setting of the flight software, in one place (the scenario's ``controllers:`` section).

Each block's settings are a pydantic model with a default, a range and a
description per field (PX4's ``module.yaml`` habit); unknown keys are errors.
They live apart from the algorithms so that reading a scenario loads no
solver, filter, OpenCV or ray-casting module: ``fwsim --help``, scenario
validation and ``fwsim metrics`` stay fast. The algorithms import their
settings from here (``controllers.estimation.ukf.UkfConfig`` is this module's).

Which block flies each part of the mission is chosen here too
(:class:`BlockChoice`: a built-in name, or ``module.sub:ClassName`` of a
user's class implementing the block's Protocol, ``controllers.blocks``).

Nothing here imports the truth side of the harness (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, Field, ValidationError, ValidationInfo, field_validator, model_validator

from fwsim.interface.configbase import StrictModel

_PI = math.pi
_HALF_PI = 0.5 * math.pi
_PanAngle = Annotated[float, Field(ge=-2.0 * _PI, le=2.0 * _PI)]
_TiltAngle = Annotated[float, Field(ge=-_HALF_PI, le=_HALF_PI)]
Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


# --------------------------------------------------------------------------- navigation and acquisition


class NavigationConfig(StrictModel):
    """How the flight software turns GNSS fixes into its position."""

    propagate: bool = Field(True, description="propagate the position with the fix velocity between fixes "
                                              "(false: use the held fix as it is)")
    fix_gain: float = Field(0.1, gt=0, le=1,
                            description="K: weight of a new fix against the propagated position "
                                        "(1: take each fix as it is; smaller smooths its noise)")
    turn_velocity: bool = Field(
        True, description="turn the fix velocity with the gyros between fixes (dV/dt = omega x V: the flight "
                          "path turns with the airframe); false: hold it")
    wind_gain: float = Field(
        0.02, ge=0, le=1,
        description="weight of each near-level fix's wind (fix velocity minus airspeed along the nose) in the "
                    "running wind estimate; the velocity then turns with the gyros relative to the air; 0: no wind "
                    "estimate")
    max_gap_s: float = Field(1.0, gt=0, le=60,
                             description="a fix older than this when the next arrives: restart from the fix")


class InsConfig(StrictModel):
    """Tuning of the onboard INS/GNSS error-state EKF (``controllers.navigation.ins``); noises are 1 sigma.

    Defaults are for a PX4-class small UAV (MEMS IMU at ~120 Hz, GNSS at 5 Hz with ~0.12 s latency); the gates
    and the reset timeout are PX4 EKF2's."""

    # process noise
    gyro_noise_rad_s_rt_hz: float = Field(3.4e-4, gt=0, le=1, description="gyro white-noise density (angle random "
                                          "walk), rad/s/sqrt(Hz)")
    accel_noise_m_s2_rt_hz: float = Field(4.0e-3, gt=0, le=10, description="accelerometer white-noise density "
                                          "(velocity random walk), m/s^2/sqrt(Hz)")
    gyro_bias_rw_rad_s2_rt_hz: float = Field(3.9e-5, gt=0, le=1,
                                             description="gyro bias random walk, rad/s^2/sqrt(Hz)")
    accel_bias_rw_m_s3_rt_hz: float = Field(6.0e-3, gt=0, le=10,
                                            description="accelerometer bias random walk, m/s^3/sqrt(Hz)")
    wind_rw_m_s2_rt_hz: float = Field(0.05, gt=0, le=10, description="horizontal wind random walk, m/s^2/sqrt(Hz)")
    baro_bias_rw_m_s_rt_hz: float = Field(0.05, gt=0, le=10,
                                          description="barometer height bias random walk (drift), m/s/sqrt(Hz)")
    mag_bias_rw_gauss_s_rt_hz: float = Field(1.0e-4, gt=0, le=1, description="magnetometer body-frame bias random "
                                             "walk, gauss/s/sqrt(Hz)")
    # measurement noise (floors on what the sensor reports) and gates
    gnss_pos_noise_min_m: float = Field(0.5, gt=0, le=100, description="floor on the fix's h_acc / v_acc, m")
    gnss_vel_noise_min_m_s: float = Field(0.3, gt=0, le=100, description="floor on the fix's speed accuracy, m/s")
    baro_noise_m: float = Field(1.0, gt=0, le=100, description="barometric height noise, m")
    mag_fusion: Literal["field", "heading"] = Field(
        "field", description="field: the 3 axes against the configured earth field, with body-frame (hard-iron) "
                             "bias states; heading: the tilt-compensated heading as the yaw alone (EKF2's heading "
                             "fusion)")
    mag_noise_gauss: float = Field(0.01, gt=0, le=1, description="magnetometer noise per axis (field fusion), gauss")
    mag_heading_noise_rad: float = Field(0.3, gt=0, le=3, description="magnetic heading noise (heading fusion), rad "
                                         "(EKF2_HEAD_NOISE: a compass's error is mostly a bias, which fusing does not "
                                         "average away)")
    airspeed_noise_m_s: float = Field(1.4, gt=0, le=50, description="true-airspeed noise, m/s")
    sideslip_noise_rad: float = Field(0.3, gt=0, le=3, description="synthetic zero-sideslip noise, rad")
    gnss_pos_gate_sd: float = Field(5.0, gt=0, le=100, description="GNSS position innovation gate, SD")
    gnss_vel_gate_sd: float = Field(5.0, gt=0, le=100, description="GNSS velocity innovation gate, SD")
    baro_gate_sd: float = Field(5.0, gt=0, le=100, description="barometric height innovation gate, SD")
    mag_gate_sd: float = Field(2.6, gt=0, le=100, description="magnetic heading innovation gate, SD")
    mag_field_gate_sd: float = Field(3.0, gt=0, le=100, description="magnetic field innovation gate, per axis, SD")
    airspeed_gate_sd: float = Field(3.0, gt=0, le=100, description="airspeed innovation gate, SD")
    sideslip_gate_sd: float = Field(5.0, gt=0, le=100, description="synthetic sideslip innovation gate, SD")
    fuse_sideslip: bool = Field(True, description="fuse zero sideslip with each airspeed sample (fixed wing: wind "
                                                  "observable in straight flight)")
    airspeed_min_m_s: float = Field(5.0, ge=0, le=100, description="airspeed below this is not fused, m/s")
    # the earth's magnetic field at the mission site (a priori)
    mag_declination_deg: float = Field(0.0, ge=-180, le=180, description="magnetic declination, east positive, deg")
    mag_inclination_deg: float = Field(60.0, ge=-90, le=90, description="magnetic inclination, down positive, deg")
    mag_strength_gauss: float = Field(0.5, gt=0, le=2, description="earth field strength, gauss")
    mag_strength_tol_gauss: float = Field(0.15, gt=0, le=2, description="a sample whose strength is further than this "
                                          "from mag_strength_gauss is rejected, gauss")
    mag_inclination_tol_deg: float = Field(20.0, gt=0, le=180, description="a sample whose inclination (on the "
                                           "estimated tilt) is further than this from mag_inclination_deg is rejected")
    # fusion timing and faults
    fusion_horizon_s: float = Field(0.25, ge=0, le=2, description="the EKF runs this far behind the newest IMU "
                                    "sample; a measurement up to this old is fused at its own time of validity, s")
    gnss_delay_s: float = Field(0.12, ge=0, le=2, description="receiver latency assumed for a fix without a time "
                                "of fix (NaN), s")
    sample_average_s: float = Field(0.1, ge=0, le=2, description="baro, magnetometer and airspeed samples are "
                                    "averaged over this long and fused once per window (0: each sample), s")
    dead_reckoning_after_s: float = Field(1.0, gt=0, le=60, description="no GNSS position or velocity fused for "
                                          "this long: mode dead_reckoning, s")
    gnss_reset_after_s: float = Field(7.0, gt=0, le=600, description="GNSS position (or velocity) rejected this "
                                      "long in a row: reset it to the fix, s")
    output_tau_s: float = Field(0.25, gt=0, le=10, description="time constant of the output predictor's velocity "
                                "and position tracking of the delayed EKF, s")
    # initialisation
    init_alignment_s: float = Field(1.0, gt=0, le=30, description="in-motion alignment: IMU and GNSS over this "
                                    "long give the first attitude, s")
    init_tilt_std_deg: float = Field(3.0, gt=0, le=90, description="initial roll and pitch std, deg")
    init_yaw_std_deg: float = Field(10.0, gt=0, le=180, description="initial yaw std with a magnetometer, deg")
    init_yaw_std_course_deg: float = Field(30.0, gt=0, le=180, description="initial yaw std from the GNSS course "
                                           "(no usable magnetometer), deg")
    init_gyro_bias_std_rad_s: float = Field(0.02, gt=0, le=1, description="initial gyro bias std, rad/s")
    init_accel_bias_std_m_s2: float = Field(0.2, gt=0, le=10, description="initial accelerometer bias std, m/s^2")
    init_mag_bias_std_gauss: float = Field(0.05, gt=0, le=2, description="initial magnetometer bias std (an "
                                           "uncalibrated hard iron), per axis, gauss")
    init_wind_std_m_s: float = Field(5.0, gt=0, le=50, description="initial wind std when no airspeed sample is there "
                                     "to initialise it from, m/s")


class AcquisitionConfig(StrictModel):
    pan_deg: list[float] = Field(default_factory=lambda: [-90.0, 90.0], min_length=2, max_length=2,
                                 description="pan sector swept during the search")
    tilt_deg: list[float] = Field(default_factory=lambda: [-15.0, -35.0, -55.0, -75.0], min_length=1,
                                  description="tilt rows of the raster, visited in order")
    rate_deg_s: float = Field(40.0, gt=0, le=360, description="sweep rate of the joints")
    lock_detections: int = Field(5, ge=1, le=300, description="consecutive detections that make a lock")


class ReacquireConfig(StrictModel):
    """What the gimbal does when the target is lost after the lock (predictive pointing)."""

    after_s: float = Field(0.7, ge=0, le=60, description="no detection this long: point at the estimate instead")
    search_after_s: float = Field(20.0, gt=0, le=3600,
                                  description="no detection this long: restart the raster search")
    gain_1_s: float = Field(4.0, gt=0, le=50, description="joint rate per rad of pointing error")


# --------------------------------------------------------------------------- perception and estimation


class DetectionGateConfig(StrictModel):
    """Which detections the UKF does not use: those a known cause has cut short (the box then lies)."""

    box_size_tolerance: float = Field(
        0.1, ge=0, le=10,
        description="a box whose width or height differs from every plausible heading's predicted one by more than "
                    "this fraction plus box_size_tolerance_px is off in size; a large value: never")
    box_size_tolerance_px: float = Field(6.0, ge=0, le=1000, description="see box_size_tolerance, px")
    size_mismatch_action: Literal["skip", "deweight", "own_headings"] = Field(
        "own_headings", description="a box off in size: own_headings (correct it over the headings all round that "
                                    "explain it, when it cannot be cut short; else maybe_cut_action), skip, or "
                                    "deweight (its centre's doubt added)")
    maybe_cut_action: Literal["skip", "deweight"] = Field(
        "deweight", description="own_headings: a box off in size that may be cut short (or that no heading "
                                "explains): deweight (use it, its centre's doubt as pixel variance) or skip it "
                                "(until max_skipped_in_a_row)")
    airframe_clearance_deg: float = Field(
        3.0, ge=0, le=90,
        description="own_headings: a smaller box is corrected over its own headings when the estimated ship lies "
                    "this far below the wing plane (the airframe cannot cut it there), deg; 90: never")
    skip_overflowing_box: bool = Field(
        True, description="skip a detection whose box spans the whole image width or height (the ship is "
                          "larger than the frame: the box centre says little)")
    edge_px: float = Field(6.0, ge=0, le=100, description="a box edge this close to the image border touches it")
    min_range_m: float = Field(
        120.0, ge=0, le=10000,
        description="skip detections while the estimated range to the target is below this (close in the box centre "
                    "no longer follows the ship model; the estimate coasts), m; 0: never")
    moving_min_range_m: float = Field(
        80.0, ge=0, le=10000,
        description="min_range_m for a ship estimated to move at moving_speed_m_s or more (a shorter coast on its "
                    "velocity), m; equal to min_range_m: one range for every ship")
    moving_speed_m_s: float = Field(
        2.0, ge=0, le=50, description="see moving_min_range_m: the estimated horizontal speed, m/s")
    max_skipped_in_a_row: int = Field(
        30, ge=1, le=100000, description="after this many skipped detections in a row the next one is used anyway "
                                         "(the estimate the checks rely on may be what is wrong)")
    propagate_feature: bool = Field(
        True, description="bring a late detection's box centre from its exposure to now (its ray from the exposure's "
                          "camera pose meets the target plane, moves on by the estimated velocity, projected anew)")
    max_propagation_s: float = Field(
        0.5, gt=0, le=10, description="a detection older than this is used as it is (propagate_feature)")
    class_check_window: int = Field(
        150, ge=10, le=100000,
        description="the ship-class check: of the last this many boxes whose size the ship model predicted, ...")
    class_mismatch_enter: float = Field(
        0.5, gt=0, le=1,
        description="... when this share or more are off in size, the boxes disagree with the class: the size gate "
                    "then compares with the class's boxes scaled by the boxes' median size ratio")
    class_mismatch_exit: float = Field(
        0.2, ge=0, le=1,
        description="... and goes back to the class correction when the share falls to this or below")
    class_check_clear_only: bool = Field(
        True,
        description="the class check counts only boxes whose estimated ship lies airframe_clearance_deg or more "
                    "below the wing plane (a box the airframe may have cut is no size evidence); false: all")

    @model_validator(mode="after")
    def _class_check_hysteresis(self):
        if self.class_mismatch_exit >= self.class_mismatch_enter:
            raise ValueError(f"class_mismatch_exit ({self.class_mismatch_exit:g}) must be below "
                             f"class_mismatch_enter ({self.class_mismatch_enter:g})")
        return self


class ShapeHeadingConfig(StrictModel):
    """The ship's heading from the shapes of its detected boxes, for when its course is unknown (a ship
    that lies still or moves too slowly for the estimated velocity to tell): :class:`ShapeHeading`."""


    enabled: bool = Field(True, description="false: an unknown course stays unknown (the offset is averaged "
                                            "over headings_when_unknown headings)")
    headings: int = Field(72, ge=4, le=720, description="candidate headings all round")
    rate_hz: float = Field(3.0, gt=0, le=240, description="detections used per second at most (consecutive "
                                                          "frames carry nearly the same information)")
    sigma_fraction: float = Field(0.05, ge=0, le=1, description="std. dev. of a box side against the model's, "
                                                                "as a fraction of the predicted side")
    sigma_px: float = Field(3.0, gt=0, le=100, description="std. dev. of a box side against the model's, px "
                                                           "(detector noise, model's coarseness)")
    size_bias_range: tuple[float, float] = Field(
        (-0.15, 0.05),
        description="the detected boxes' widths (and apart heights) may all be off the model's by one unknown "
                    "fraction in this range; each heading's likelihood is marginalised over it. (0, 0): none")
    size_bias_steps: int = Field(13, ge=1, le=101, description="grid points over size_bias_range")

    @field_validator("size_bias_range")
    @classmethod
    def _bias_range(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (-1.0 < v[0] <= v[1]):
            raise ValueError(f"must be (low, high) with -1 < low <= high, got {tuple(v)}")
        return v
    max_effective_updates: float = Field(
        60.0, gt=0, le=10000,
        description="the evidence of more detections counts as this many: the model's outline is coarse, so its "
                    "misfit repeats from frame to frame and must not make the heading look surer than it is")
    min_updates: int = Field(10, ge=1, le=100000, description="detections used before the heading is trusted")
    min_weight: float = Field(0.02, ge=0, lt=1, description="headings with less posterior weight than this "
                                                            "times the largest are dropped")
    tell_bow_from_stern: bool = Field(
        True, description="trust the box shapes to tell the bow from the stern; false: a heading and its opposite "
                          "count alike (the fore-aft part of the offset is then not removed)")
    fuse_with_course: bool = Field(
        True, description="with a known course, weigh the shapes' headings by it (and the course by them): "
                          "the course from a noisy velocity wanders by 10-20 deg in a dive, the shapes' by ~5")
    fuse_min_course_std_deg: float = Field(3.0, gt=0, le=90, description="the course's std when fused is at "
                                                                         "least this, deg")
    follow_course: bool = Field(
        True, description="between detections the posterior turns with the ship's estimated course (a turning ship's "
                          "boxes add up at its heading now); false: the posterior stays put")
    follow_course_settle_s: float = Field(
        10.0, ge=0, le=600,
        description="the course is followed once it has been known (min_speed_for_course_m_s, "
                    "max_vel_std_for_course_m_s) this long without a break, s")
    follow_course_max_rate_deg_s: float = Field(
        3.0, gt=0, le=90,
        description="the posterior turns at most this fast, deg/s: a ship turns slower (the estimate's jumps "
                    "are not turns)")
    held_course_spread_deg_s: float = Field(
        1.5, ge=0, le=90,
        description="once a followed course is lost, the shapes' headings are weighed by it, its std "
                    "fuse_min_course_std_deg growing by this per second, until it spans the circle, deg/s; 0: off")
    max_course_off_axis_deg: float = Field(
        25.0, gt=0, le=90,
        description="an estimated velocity more than this off the ship's axis (as the shapes tell it) gives no "
                    "course: a ship moves along its axis, so such a velocity is the estimate's error")
    turn_rates_deg_s: tuple[float, ...] = Field(
        (-2.0, -1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0), min_length=1, max_length=15,
        description="while the course is not followed, the turn rates the ship may have, deg/s (clockwise seen from "
                    "above), each a hypothesis the posterior sums over; (0,): a ship that keeps its heading")
    turn_rate_prior_zero: float = Field(
        0.5, gt=0, le=1,
        description="a priori weight of the rate 0 among turn_rates_deg_s (the rest share the remainder "
                    "equally): most slow ships keep their heading")
    memory_s: float | None = Field(
        120.0, gt=0, le=100000,
        description="while the course is not followed, the box shapes' evidence fades with this time constant, s; "
                    "none: kept for good")

    @field_validator("turn_rates_deg_s")
    @classmethod
    def _rates(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        if len(set(v)) != len(v) or not all(math.isfinite(r) and abs(r) <= 30.0 for r in v):
            raise ValueError(f"must be distinct rates within +-30 deg/s, got {tuple(v)}")
        return v


class SizeFitConfig(StrictModel):
    """The ship's own length, beam and height, learnt from its boxes (``controllers.perception.size_fit.ShipSize``)."""

    enabled: bool = Field(True, description="fit the class outline's length, beam and height to the detected "
                                            "boxes' sizes and correct the box centres with the fitted outline")
    prior_std: float = Field(0.2, gt=0, le=2,
                             description="1-sigma of each log scale a priori (0.2: about +-20 % of the class)")
    box_std: float = Field(0.1, gt=0, le=2,
                           description="1-sigma of a box's log width and log height about the fitted outline's "
                                       "(detector noise, the layout's difference from the class)")
    box_scale: float = Field(
        0.95, gt=0.5, le=1.5,
        description="a detected box's size over its silhouette's, a priori (the detector's calibration; the middle "
                    "of heading_from_shape.size_bias_range)")
    box_px_std: float = Field(3.0, ge=0, le=100,
                              description="1-sigma of a box's width and height in px on top of box_std (a small, "
                                          "far box's sizes are a few pixels' worth)")
    max_gated_in_a_row: int = Field(30, ge=1, le=100000,
                                    description="this many boxes turned away by the gate in a row restart the fit "
                                                "from the prior")
    gate: float = Field(9.2, gt=0, le=1000,
                        description="skip a box whose size residual has a normalised square (chi-square, 2 dof) "
                                    "above this (9.2: 1 %; boxes cut by the UAV's airframe, merged clutter)")
    min_updates: int = Field(30, ge=0, le=100000,
                             description="boxes taken before the fitted outline replaces the class's")
    class_after_restarts: int = Field(
        1, ge=0, le=100000,
        description="once the fit has started again this many times, the correction keeps the class's outline for "
                    "good and the fit takes no more boxes; 0: never (it learns again from the prior)")
    max_scale: float = Field(2.0, gt=1, le=10, description="each scale is kept within [1/this, this]")
    min_range_m: float = Field(150.0, ge=0, le=100000,
                               description="boxes from closer than this are not taken (perspective, the UAV's "
                                           "airframe in view)")
    rate_hz: float = Field(
        3.0, gt=0, le=240,
        description="boxes weighed per second at most (consecutive frames carry nearly the same information), Hz")


class LayoutFitConfig(StrictModel):
    """Which end of the ship its superstructure stands at, learnt from where its box centres fall
    (``controllers.perception.layout_fit.LayoutFit``): the class's layout, or the same superstructure at the other end
    (a ship with its bridge forward where the class has it aft)."""

    enabled: bool = Field(
        True, description="weigh the class's layout against the superstructure at the other end while the ship's "
                          "course is known, and correct with the one the box centres fit")
    window_s: float = Field(
        60.0, gt=5, le=600,
        description="the fit's window, s: each layout's corrected box centres on the tracked point's plane are "
                    "fitted by one track (position, velocity, acceleration) and weighed by its misfit")
    rate_hz: float = Field(3.0, gt=0, le=30, description="boxes taken a second at most (nearby frames are alike)")
    point_floor_m: float = Field(
        1.0, gt=0, le=50,
        description="1-sigma floor of a ground point's error beside the pixel noise's, m (the track's own misfit, "
                    "the fitted size's error): no close view outweighs the rest")
    max_effective: float = Field(
        30.0, gt=0, le=10000,
        description="the evidence is tempered to count at most this many boxes (consecutive boxes' errors are "
                    "not independent)")
    prior_other_end: float = Field(0.2, gt=0, lt=1, description="the other end's probability a priori")
    switch_probability: float = Field(
        0.9, gt=0.5, lt=1,
        description="the correction takes the other layout once its probability reaches this, and goes back once "
                    "the class's does")
    min_boxes: int = Field(30, ge=3, le=100000, description="boxes in the window before the fit decides")
    pixel_noise_px: float = Field(2.0, gt=0, le=100, description="a box centre's pixel noise, 1-sigma, px")
    shape_weight: float = Field(
        1.0, ge=0, le=10,
        description="weight of the box shapes' evidence for the other end (their posterior's log ratio at the "
                    "reverse of the course over the course, window mean) in the log-odds; 0: box centres alone")
    shape_clip: float = Field(
        5.0, gt=0, le=50, description="each box's shape log ratio is clipped to +- this before the window's mean "
                                      "(the shapes' posterior is sure of itself far beyond what it knows)")


class ShipModelConfig(StrictModel):
    """The flight software's outline of the ship class (ship frame: x bow, y port, z up, origin at the
    waterline centre)."""


    enabled: bool = Field(True, description="correct each detection's box centre for the ship's shape "
                                            "before the UKF update")
    length_m: float = Field(55.0, gt=0, le=500, description="length of the ship class, m (paper: 55)")
    width_m: float = Field(25.0, gt=0, le=200, description="beam of the ship class, m (paper: 25)")
    height_m: float = Field(25.0, gt=0, le=200, description="height above the waterline to the mast top, m "
                                                            "(paper: 25)")
    min_speed_for_course_m_s: float = Field(
        1.5, ge=0, le=50, description="below this estimated speed the ship's course is taken as unknown")
    max_vel_std_for_course_m_s: float = Field(
        1.0, gt=0, le=50, description="above this standard deviation of the estimated velocity the course is "
                                      "taken as unknown")
    headings_when_unknown: int = Field(8, ge=1, le=72, description="headings the offset is averaged over "
                                                                   "when the course is unknown")
    heading_from_shape: ShapeHeadingConfig = Field(default_factory=ShapeHeadingConfig,
        description="the ship's heading from its boxes' shapes")
    size_fit: SizeFitConfig = Field(default_factory=SizeFitConfig,
        description="the ship's length, beam and height learnt from its boxes")
    layout_fit: LayoutFitConfig = Field(default_factory=LayoutFitConfig,
        description="which end the superstructure stands at, learnt from the box centres")


class UkfConfig(StrictModel):
    """Tuning of the target UKF (all noise values are 1-sigma)."""


    pixel_noise_px: float = Field(2.0, gt=0, le=100, description="detector box-centre noise (u, v), px")
    cam_pos_noise_m: float = Field(0.5, gt=0, le=100, description="camera position r_c (GNSS/INS), per axis, m")
    attitude_noise_rad: float = Field(
        0.002, ge=0, le=0.2,
        description="attitude + encoder error; adds (range * this) to the r_c measurement noise, rad")
    height_noise_m: float = Field(
        0.5, ge=0, le=100,
        description="altimeter error in the flat-sea depth; adds (range / height * this) to the r_c noise, m")
    target_accel_noise_m_s2: float = Field(
        0.05, gt=0, le=50,
        description="horizontal white-noise target acceleration (process), PSD = this^2 per second, m/s^2; small, so "
                    "the dive's box-centre errors do not pass into the velocity")
    target_vertical_accel_noise_m_s2: float = Field(
        0.02, gt=0, le=50, description="vertical white-noise target acceleration (process), m/s^2")
    feature_process_noise: float = Field(
        0.01, gt=0, le=10,
        description="random walk of x1, x2 (gyro/encoder-rate errors), normalised units per sqrt(s)")
    target_plane_height_m: float = Field(
        0.0, ge=-100, le=200,
        description="height of the plane the detected point lies on (0: sea; e.g. the hull's aim height), m")
    box_centre_bias_frac: float = Field(
        0.04, ge=0, le=1,
        description="1-sigma systematic error of the corrected box centre, as a fraction of the box's width (u) and "
                    "height (v); not fused, carried into the reported position std; 0: the class is exact")
    box_centre_height_std_m: float = Field(
        2.2, ge=0, le=100,
        description="1-sigma error of the height on the ship the corrected box centre stands for, m; not fused, "
                    "carried into the reported position std through the view's geometry; 0: none")
    consider_heading_spread: bool = Field(
        True,
        description="add the shape correction's spread over the headings the ship may have to the reported position "
                    "std (an error common to the detections until the heading is known); not fused")
    pointing_bias_std_rad: float = Field(
        0.005, ge=0, le=0.1,
        description="camera mount calibration 1-sigma (boresight, encoders), per image axis, rad: with the "
                    "navigation's attitude std, the prior of the estimated pointing bias (estimator ukf); 0: none")
    pointing_bias_walk_rad_rt_s: float = Field(
        2e-4, gt=0, le=0.1,
        description="random walk of the pointing bias (the navigation's attitude error wanders), rad/sqrt(s)")
    pointing_rate_error_frac: float = Field(
        0.01, ge=0, le=1,
        description="with the pointing bias estimated: the camera's angular-rate error (gyro and encoder scale "
                    "factor, misalignment) as a fraction of its rate, added to the features' random walk")
    innovation_gate: float = Field(
        13.8, ge=0, le=1000,
        description="reject a detection whose pixel innovation has a normalised square (chi-square, 2 dof) "
                    "above this (13.8: 0.1 % of good detections); 0: never")
    innovation_gate_box_bias: bool = Field(
        True,
        description="the innovation gate also allows for the box centre's systematic error (box_centre_bias_frac); "
                    "the update is unchanged. false: the gate allows for the pixel noise alone")
    innovation_gate_max_rejects: int = Field(
        15, ge=1, le=100000, description="after this many rejections in a row the next detection is used anyway "
                                         "(the estimate, not the detections, may be wrong)")
    init_pos_std_frac: float = Field(
        0.05, gt=0, le=1, description="initial horizontal position std as a fraction of the slant range")
    init_vel_std_m_s: float = Field(10.0, gt=0, le=100, description="initial horizontal velocity std, m/s")
    max_substep_s: float = Field(0.05, gt=0, le=1, description="largest RK4 step of the process model, s")
    sigma_alpha: float = Field(1.0, gt=0, le=1, description="Merwe sigma-point spread alpha")
    sigma_beta: float = Field(2.0, ge=0, le=10, description="Merwe beta (2 is optimal for Gaussians)")
    sigma_kappa: float = Field(0.0, ge=-7, le=10, description="Merwe kappa (n + kappa must stay > 0)")


class CtUkfConfig(StrictModel):
    """Tuning of the manoeuvring-ship UKF (``controllers.estimator: ct_ukf``, ``controllers.ct_ukf``): the
    paper's UKF with the ship's turn rate and along-track acceleration as two more states, each a first-order
    Gauss-Markov process (it wanders about zero: a ship's manoeuvre lasts tens of seconds, then it steadies).

    Only the ship's motion model is set here; the measurement model and its noise, the innovation gate, the
    tracked point's height, the feature noise, the start and the sigma points are the UKF's
    (``controllers.estimation.ukf``), so a scenario tuned for the UKF flies this filter with the same camera model."""

    turn_rate_std_deg_s: float = Field(
        1.5, gt=0, le=20,
        description="turn-rate std of the Gauss-Markov model (its spread in the long run, and at the start), "
                    "deg/s; ships turn at up to ~1.5 deg/s, and a +-30 deg zigzag of period 60 s peaks at 3")
    turn_rate_time_s: float = Field(
        60.0, gt=0, le=3600,
        description="correlation time of the turn rate, s: how long a turn is expected to last (shorter follows a "
                    "zigzag's reversals, longer holds a steady turn)")
    accel_std_m_s2: float = Field(
        0.3, gt=0, le=10,
        description="along-track acceleration std of the Gauss-Markov model (long run, and at the start), m/s^2; "
                    "ships change speed at up to ~0.5 m/s^2")
    accel_time_s: float = Field(
        20.0, gt=0, le=3600, description="correlation time of the along-track acceleration, s (how long a speed "
                                         "change is expected to go on)")
    target_accel_noise_m_s2: float = Field(
        0.05, gt=0, le=50,
        description="horizontal white-noise acceleration beside the modelled turn and speed change (process, PSD = "
                    "this^2 per second), m/s^2; small, as the UKF's")
    min_speed_m_s: float = Field(
        0.5, gt=0, le=20,
        description="the along-track direction is V / max(|V|, this): below this speed an acceleration moves "
                    "the velocity less (a ship at rest has no track to speed up along), m/s")
    manoeuvre_fade_speed_m_s: float = Field(
        2.0, ge=0, le=20,
        description="below this estimated speed the turn rate and acceleration also revert to zero within about "
                    "manoeuvre_fade_time_s (fully at rest), m/s; 0: no fade")
    manoeuvre_fade_time_s: float = Field(
        2.0, gt=0, le=3600, description="the fade's time constant at rest, s")
    hold_tgo_s: float = Field(
        15.0, ge=0, le=600,
        description="while the camera closes on the estimate within this time to go (a dive), hold the manoeuvre "
                    "learnt before (turn rate kept, acceleration zero); released above twice this, s; 0: never")
    hold_turn_rate: bool = Field(
        True, description="the hold keeps the turn rate too (true), or goes on learning it (false: only the speed is "
                          "held)")


class PeriodicCourseConfig(StrictModel):
    """A zigzagging ship seen through a constant-velocity estimator (``controllers.turn_from_course.periodic``,
    ``controllers.estimation.course_turn``): the estimate's course history fitted with a line plus one sinusoid;
    when the sinusoid stands out, the ship's course is that fit one filter lag ahead, and the state handed on follows
    it (its velocity's direction, its position's lag, the turn rate the guidance predicts with)."""

    enabled: bool = Field(True, description="on: fit and use a periodic course; off: steady turns only")
    window_s: float = Field(
        150.0, gt=0, le=3600, description="the course history fitted, s (the longest period it can find)")
    min_span_s: float = Field(
        90.0, gt=0, le=3600, description="fit only once the history spans this, s; a period must fit in the span")
    min_period_s: float = Field(20.0, gt=0, le=3600, description="the shortest period searched, s")
    max_period_s: float = Field(180.0, gt=0, le=3600, description="the longest period searched, s")
    period_step_s: float = Field(2.0, gt=0, le=600, description="the period search's step (then refined), s")
    search_every_s: float = Field(
        10.0, ge=0, le=600,
        description="the whole period range is searched this often, s; between, the last period and its two "
                    "neighbours (a search costs about a millisecond; 0: search at every fit)")
    min_amplitude_deg: float = Field(
        8.0, ge=0, le=180,
        description="a sinusoid under this amplitude is no zigzag, deg (a ship turning at 1.5 deg/s, its "
                    "estimate's turn settling, showed 5-6 deg at a period as long as the history)")
    min_explained: float = Field(
        0.9, ge=0, le=1,
        description="the share of the course's weighted residual about the line that the sinusoid must take out "
                    "(1652's zigzags over 3 m/s: 0.98-1.0; the settling turn above: 0.86)")

    @model_validator(mode="after")
    def _periods(self):
        if self.max_period_s < self.min_period_s:
            raise ValueError(f"max_period_s ({self.max_period_s:g}) must be at least min_period_s "
                             f"({self.min_period_s:g})")
        return self


class TurnFromCourseConfig(StrictModel):
    """A turning ship seen through a constant-velocity estimator (the paper's UKF;
    ``controllers.estimation.course_turn``): the turn rate from the slope of the estimate's course, and the filter's
    steady lag in the turn (its velocity a few degrees and its position about a metre behind, from its own covariance)
    taken out of the state the perception, the pointing and the guidance read; the guidance then predicts the ship along
    the turn. The logged estimate (``/fsw/estimate``) stays the filter's. An estimator that estimates the turn itself
    (``ct_ukf``, ``imm``) is left alone."""

    enabled: bool = Field(True, description="on: find the turn and take the lag out; off: the estimate as it is")
    window_s: float = Field(
        15.0, gt=0, le=600,
        description="the course history fitted with a straight line (course against time), s: longer finds a steady "
                    "turn more surely, shorter follows a zigzag's reversals")
    min_span_frac: float = Field(
        0.8, gt=0, le=1, description="fit only once the history spans this share of window_s")
    sample_s: float = Field(0.5, gt=0, le=10, description="one course sample per this, s")
    min_speed_m_s: float = Field(
        3.0, ge=0, le=50,
        description="the estimated horizontal speed under which the course says nothing (the history restarts), "
                    "m/s")
    min_turn_deg_s: float = Field(
        0.3, ge=0, le=20, description="a slope under this is no turn, deg/s")
    max_turn_deg_s: float = Field(3.0, gt=0, le=20, description="the turn rate's cap, deg/s")
    significance: float = Field(
        3.0, ge=0, le=100, description="the slope must be this many of its stds (from the course's scatter about "
                                       "the line) to be a turn")
    residual_corr_s: float = Field(
        5.0, gt=0, le=600,
        description="the course residuals count as one independent residual per this (the estimate's course is "
                    "smooth, its errors correlated over seconds), s")
    steady_s: float = Field(
        30.0, ge=0, le=600,
        description="a turn is used only when every fit of the last this long found one within steady_tol of the "
                    "newest (a steady turn, not a zigzag's swing), s; 0: no such test")
    steady_tol_deg_s: float = Field(
        0.6, ge=0, le=20, description="see steady_s: the fits' spread allowed, deg/s (or steady_tol_frac)")
    steady_tol_frac: float = Field(
        0.5, ge=0, le=10, description="see steady_s: the fits' spread allowed, as a share of the newest's rate")
    hold_tgo_s: float = Field(
        15.0, ge=0, le=600,
        description="while the camera closes on the estimate within this time to go (a dive), hold the turn rate "
                    "found before; released above twice this, s; 0: never hold")
    max_lag_s: float = Field(
        10.0, gt=0, le=120,
        description="a lag correction implying a filter lag over this (velocity: lag x acceleration, position: "
                    "lag^2 x acceleration / 2) is not applied (a covariance far from steady state), s")
    periodic: PeriodicCourseConfig = Field(
        default_factory=PeriodicCourseConfig, description="a zigzag: the course fitted with a sinusoid")


class ImmConfig(StrictModel):
    """The interacting multiple model estimator (``controllers.estimator: imm``, ``controllers.imm``): the
    paper's UKF (constant velocity) and the manoeuvring-ship UKF (``ct_ukf``: turn rate and along-track
    acceleration) run side by side on the same detections, mixed each step by the probability that the ship
    is manoeuvring (Bar-Shalom's IMM). Each model keeps its own settings (``ukf``, ``ct_ukf``)."""

    switch_time_s: float = Field(
        60.0, gt=0, le=3600,
        description="mean time the ship keeps to one mode, steady or manoeuvring, s: the Markov chain's switch "
                    "probability over dt is 1 - exp(-dt / this)")
    prior_manoeuvring: float = Field(
        0.5, gt=0, lt=1, description="probability of the manoeuvring model at the start")
    hold_with_manoeuvre: bool = Field(
        True,
        description="while the CT-UKF holds its manoeuvre (ct_ukf.hold_tgo_s: the dive), hold the models' "
                    "probabilities as the loiter left them")
    min_probability: float = Field(
        1e-3, gt=0, lt=0.5,
        description="each model's probability is kept at least this: a model that has lost for minutes still "
                    "comes back within seconds when the ship starts (or stops) turning")


# --------------------------------------------------------------------------- guidance and pointing


class InitialPath(StrictModel):
    airspeed_m_s: float = Field(22.0, gt=0, le=60, description="airspeed along the initial path, m/s")
    waypoints_enu_m: list[Vec3] = Field(default_factory=list,
                                        description="empty: hold the initial heading and altitude")
    max_bank_deg: float = Field(35.0, gt=0, le=60, description="largest bank the path follower commands, deg")


class Orbit(StrictModel):
    """Circle around the estimated target after lock (a stand-in until the NMPC loiter)."""

    airspeed_m_s: float = Field(22.0, gt=0, le=60, description="airspeed on the circle, m/s")
    radius_m: float = Field(500.0, gt=20, le=5000, description="the paper's R")
    altitude_m: float = Field(500.0, gt=20, le=5000, description="the paper's H")
    clockwise: bool = Field(False, description="seen from above")


class CbfConfig(StrictModel):
    """The self-occlusion CBF of the NMPC."""


    enabled: bool = Field(True, description="impose the CBF input constraints (eqs. (23)-(24))")
    beta: float = Field(1.0, gt=0.0, le=50.0, description="CBF class-K gain beta in h_dot >= -beta h, 1/s")
    sides: Literal["both", "solve_time"] = Field(
        "both", description="both: right and left rows at every stage (smooth); solve_time: the side of "
                            "sign(R_p) at the current state for the whole horizon (the paper's switch)")
    slack_weight_linear: float = Field(100.0, ge=0.0, le=1e9,
                                       description="linear (exact) penalty on the CBF slack, per rad/s")
    slack_weight_quadratic: float = Field(100.0, gt=0.0, le=1e9,
                                          description="quadratic penalty on the CBF slack, per (rad/s)^2")


class NmpcConfig(StrictModel):
    """Tuning of the Phase 2 NMPC (paper eq. NMPC, limits) and its solver."""


    horizon_steps: int = Field(50, ge=2, le=400, description="N, prediction = control horizon (steps)")
    step_s: float = Field(0.1, gt=0.0, le=2.0, description="T_s, the NMPC step and the model's Euler step, s")
    radius_m: float = Field(500.0, gt=20.0, le=5000.0, description="R, loiter radius around the target, m")
    altitude_m: float = Field(500.0, gt=10.0, le=5000.0, description="H, loiter altitude (world z), m")
    w1_radius: float = Field(1e-4, ge=0.0, le=1e6, description="w1, per m^2 of radius error, per stage")
    w2_altitude: float = Field(1e-4, ge=0.0, le=1e6, description="w2, per m^2 of altitude error, per stage")
    w3_attitude: tuple[Annotated[float, Field(ge=0.0, le=1e6)], Annotated[float, Field(ge=0.0, le=1e6)],
                       Annotated[float, Field(ge=0.0, le=1e6)]] = Field(
        (30.0, 30.0, 1.0), description="W3 diagonal: per rad^2 of change of [phi, theta, psi] per step")
    w4_continuity: float = Field(0.1, ge=0.0, le=1e6,
                                 description="w4, per (rad/s)^2 of [u_p, u_q] change from the previous input")
    w5_approach: float = Field(1.0, ge=0.0, le=1e6,
                               description="w5 (ours), per stage: the approach-rate term (r_dot / V_ref + "
                                           "tanh((r - R) / L))^2; 0 = the paper's cost")
    approach_length_m: float = Field(150.0, gt=0.0, le=5000.0,
                                     description="L of the approach-rate term: the radius error over which the "
                                                 "wanted closing rate falls from V_ref to 0")
    air_relative: bool = Field(True, description="predict the target in the air mass (its velocity minus the "
                                                  "navigation's wind estimate), where the model's airspeed "
                                                  "kinematics hold; false: over the ground (the paper's)")
    w_airspeed: float = Field(1e-4, ge=0.0, le=1e6,
                              description="input regularisation, per (m/s)^2 of V_U - airspeed_ref, per stage")
    w_rates: float = Field(1e-4, ge=0.0, le=1e6,
                           description="input regularisation, per (rad/s)^2 of u_p and u_q, per stage")
    airspeed_ref_m_s: float = Field(22.0, gt=0.0, le=80.0, description="V_ref of the airspeed regularisation")
    roll_max_deg: float = Field(35.0, gt=0.0, lt=80.0, description="|phi| bound")
    pitch_max_deg: float = Field(15.0, gt=0.0, lt=60.0, description="|theta| bound")
    airspeed_min_m_s: float = Field(18.0, gt=0.0, le=80.0, description="V_U lower bound")
    airspeed_max_m_s: float = Field(28.0, gt=0.0, le=80.0, description="V_U upper bound")
    roll_rate_max_rad_s: float = Field(0.8, gt=0.0, le=10.0, description="|u_p| bound, rad/s")
    pitch_rate_max_rad_s: float = Field(0.3, gt=0.0, le=10.0, description="|u_q| bound, rad/s")
    cbf: CbfConfig = Field(default_factory=CbfConfig, description="the self-occlusion control barrier function")
    integrator: Literal["euler", "rk4"] = Field("euler", description="discretisation of the model")
    solver: Literal["rti_hpipm", "rti_qrqp", "fatrop", "ipopt"] = Field(
        "rti_hpipm", description="rti_*: SQP real-time iterations with that QP solver (hpipm: structured "
                                 "interior point; qrqp: comparison only); fatrop/ipopt: the full NLP to convergence")
    hessian: Literal["exact", "gauss_newton"] = Field(
        "exact", description="rti_*: the QP Hessian: exact (the Lagrangian's, eigenvalues clipped per stage block) "
                             "or gauss_newton (2 J_r^T J_r; oscillates on large radius errors, for comparison)")
    hessian_min_eig: float = Field(1e-6, gt=0.0, le=1.0,
                                   description="exact Hessian: eigenvalue floor of each stage block")
    rti_iterations: int = Field(1, ge=1, le=50, description="SQP iterations per call once warm")
    cold_start_iterations: int = Field(50, ge=1, le=500,
                                       description="SQP iterations at most on the first call or after a reset; "
                                                   "they also stop when 90 % of max_solve_ms is used")
    cold_start_tol: float = Field(1e-5, gt=0.0, le=1.0,
                                  description="cold start stops when the largest input step is below this")
    ipopt_tol: float = Field(1e-8, gt=0.0, le=1e-2, description="IPOPT convergence tolerance")
    max_solve_ms: float = Field(50.0, ge=0.0, le=1e5,
                                description="time budget of one solve (budget: wall_clock): a later result is "
                                            "not applied, and a cold start stops at 90 % of it")
    budget: Literal["iterations", "wall_clock"] = Field(
        "iterations",
        description="iterations: a solve is bounded by its iteration counts only (a run is the same on any machine); "
                    "wall_clock: also by max_solve_ms of wall time (results then depend on the machine)")
    solve_ahead_s: float = Field(
        0.067, ge=0.0, le=1.0,
        description="start each solve this long before its time, from the state predicted to it, in a process of its "
                    "own, and apply it at its time (a mission computer's compute delay), s; 0: solve at its time, in "
                    "place")
    reset_after_failures: int = Field(3, ge=1, le=1000,
                                      description="consecutive failed solves before the warm start is rebuilt")
    pitch_from: Literal["attitude", "flight_path"] = Field(
        "attitude", description="theta of the model from the AHRS pitch (paper) or the flight-path angle of "
                                "the velocity (the kinematics' z_dot = V sin(theta) then has no alpha bias)")

    @model_validator(mode="after")
    def _airspeed_bounds(self):
        if not self.airspeed_min_m_s < self.airspeed_max_m_s:
            raise ValueError(f"airspeed_min_m_s ({self.airspeed_min_m_s:g}) must be below airspeed_max_m_s "
                             f"({self.airspeed_max_m_s:g})")
        if not self.airspeed_min_m_s <= self.airspeed_ref_m_s <= self.airspeed_max_m_s:
            raise ValueError(f"airspeed_ref_m_s ({self.airspeed_ref_m_s:g}) must lie within [airspeed_min_m_s, "
                             f"airspeed_max_m_s] = [{self.airspeed_min_m_s:g}, {self.airspeed_max_m_s:g}]")
        return self


class SwitchConfig(StrictModel):
    """The Phase 2 -> 3 (loiter -> terminal) switch; the paper gives it only loosely."""

    enabled: bool = Field(True, description="false: loiter until the run ends")
    radius_tol_m: float = Field(25.0, gt=0, le=1000, description="|distance to the estimate - R| below this")
    altitude_tol_m: float = Field(15.0, gt=0, le=1000, description="|altitude - H| below this")
    dwell_s: float = Field(10.0, ge=0, le=3600, description="both tolerances held this long (counted from Phase "
                                                             "2's start on, alongside min_loiter_s)")
    min_loiter_s: float = Field(30.0, ge=0, le=3600, description="no switch before this long in Phase 2")
    approach_window_deg: float | None = Field(
        5.0, gt=0, le=180,
        description="bearing from the UAV to the target within this of the approach bearing plus the lead "
                    "(none: any bearing)")
    approach_from: Literal["impact_heading", "closing_after_go_around"] = Field(
        "closing_after_go_around",
        description="the approach bearing: the impact heading; 'closing_after_go_around': the impact heading until "
                    "a dive has gone round (go_around_m), then the bearing the UAV closes on the target in")
    go_around_m: float | None = Field(
        100.0, gt=0, le=10000,
        description="in Phase 3, back to the loiter (the switch armed again) once the range to the estimate has "
                    "grown this much above its least since the switch (a dive that is not closing), m; none: never")
    go_around_stall_s: float | None = Field(
        20.0, gt=0, le=3600,
        description="... or once this long after the switch the range has not fallen go_around_stall_fraction below "
                    "its value at the switch (a dive that holds its range), s; none: never")
    go_around_stall_fraction: float = Field(
        0.02, ge=0, lt=1, description="see go_around_stall_s")
    approach_lead_deg: float = Field(
        5.0, ge=-90, le=90,
        description="the window's centre lies this far past the approach bearing, in the direction the UAV goes "
                    "round the target (the middle of the terminal law's capture region), deg")
    entry_depression_margin_deg: float | None = Field(
        5.0, ge=0, le=60,
        description="the dive's entry ring: descend on the ring until the ship lies |impact_flight_path_deg| - this "
                    "below the horizon, then arm the switch, deg; none: dive from the ring at H (the paper's)")
    entry_min_altitude_m: float = Field(
        100.0, gt=10, le=5000, description="see entry_depression_margin_deg: the entry ring's lowest altitude, m")
    entry_descent_rate_m_s: float = Field(
        5.0, gt=0, le=30, description="see entry_depression_margin_deg: the loiter altitude's descent rate, m/s")


class BpngConfig(StrictModel):
    """Tuning of the terminal guidance (paper section Phase 3)."""


    n_sigma: float = Field(6.0, gt=0, le=20, description="PN gain N_sigma on Omega x V_p (paper: 6, optimal)")
    n_f: float = Field(2.0, ge=0, le=20, description="bias gain N_f on the impact-angle error (paper: 2, optimal)")
    impact_flight_path_deg: float = Field(
        -30.0, ge=-90, le=0,
        description="wanted flight-path angle at impact theta_f, deg, negative when diving (paper: -30)")
    impact_heading_deg: float = Field(
        30.0, ge=-360, le=360, description="wanted heading at impact psi_f, deg clockwise from North (paper: 30)")
    airspeed_m_s: float = Field(
        22.0, gt=0, le=60,
        description="airspeed commanded in the dive, m/s (the autopilot holds it with throttle only; "
                    "at idle the UAV still gains speed diving)")
    min_tgo_s: float = Field(0.5, gt=0, le=10, description="floor of t_go = |r| / |V_p|, s")
    bias_angle_cap_deg: float | None = Field(
        90.0, gt=0, le=180,
        description="the bias term uses min(theta, this), deg: far off V_f the small-angle law's bias cancels its PN "
                    "term; none: the paper's law as printed")
    capture_turn_deg_s: float | None = Field(
        3.0, gt=0, le=90,
        description="capture guard: with the look angle above capture_look_deg, turn the velocity toward the line of "
                    "sight at this rate or more (the bias scaled down), deg/s; none: the law as printed")
    capture_look_deg: float = Field(
        60.0, ge=0, le=180, description="the look angle (between the velocity and the line of sight) above which "
                                        "the capture guard acts, deg")
    max_accel_m_s2: float = Field(
        25.0, gt=0, le=200, description="cap on |u| (direction kept), m/s^2, gravity not included")
    aim_at_contact: bool = Field(
        True,
        description="steer to where the approach along the impact direction first meets the ship's outline, not to "
                    "the aim point inside it (a dive meets the deck or superstructure first)")
    contact_standoff_m: float = Field(
        6.0, ge=0, le=100,
        description="the steering point lies this much farther out than the class outline's surface, m (a ship "
                    "unlike the class may be met sooner; the law then finishes that much earlier)")
    endgame_tgo_s: float = Field(
        0.4, ge=0, le=10,
        description="below this time to go to the steering point the law's command is dropped for the endgame "
                    "(endgame_align_s): a near hit's LOS rate grows without bound there, s; 0: no endgame")
    endgame_align_s: float | None = Field(
        0.25, gt=0, le=10,
        description="in the endgame, turn the velocity onto V_f with this time constant (a = |V| theta / this, "
                    "perpendicular to V, capped), s; none: fly straight (gravity compensated)")
    aim_height_m: float = Field(
        0.0, ge=-50, le=100,
        description="height of the aim point above the given target position (the ship's waterline "
                    "point), m; 0 aims at the waterline")


class IbvsConfig(StrictModel):
    """IBVS gimbal controller settings (flight software side; angles in rad)."""


    lambda_1_s: float = Field(1.5, gt=0.0, le=20.0,
                              description="feedback gain lambda: the image error decays as exp(-lambda t), 1/s")
    feedforward: bool = Field(True, description="cancel the feature motion caused by the UAV's rotation and by "
                                                "the UAV's and the target's velocity (paper's L2 term)")
    singularity_damping: float = Field(0.1, gt=0.0, le=1.0,
                                       description="mu of the damped least-squares inverse: active when the "
                                                   "smallest singular value of J drops below mu (target line of "
                                                   "sight near the pan axis); bounds |joint rates| by |b|/mu")
    pan_limits_rad: list[_PanAngle] = Field(default_factory=lambda: [-_PI, _PI], min_length=2, max_length=2,
                                            description="[min, max] pan angle the gimbal allows, rad")
    tilt_limits_rad: list[_TiltAngle] = Field(default_factory=lambda: [-_HALF_PI, _HALF_PI], min_length=2,
                                              max_length=2, description="[min, max] tilt angle, rad (up positive)")
    max_pan_rate_rad_s: float = Field(2.0 * _PI / 3.0, gt=0.0, le=20.0, description="pan rate limit, rad/s")
    max_tilt_rate_rad_s: float = Field(2.0 * _PI / 3.0, gt=0.0, le=20.0, description="tilt rate limit, rad/s")
    hold_timeout_s: float = Field(1.0, ge=0.0, le=60.0,
                                  description="after the track is lost, keep feeding forward (coast) this long, "
                                              "then hold the joints, s")
    max_detection_age_s: float = Field(0.2, gt=0.0, le=10.0,
                                       description="a valid detection older than this (since its exposure) no "
                                                   "longer counts as tracking, s")
    keyhole_swing: bool = Field(True, description="near the pan axis, swing the pan round (full rate, tilt by least "
                                                  "squares) when the target is on the far side of the axis or its "
                                                  "azimuth is about to cross a pan limit (module docstring)")
    keyhole_fov_fraction: float = Field(1.0, gt=0.0, le=1.0,
                                        description="the keyhole: target within this fraction of the smallest half "
                                                    "field of view (principal point to the nearer image edge) of the "
                                                    "pan axis, less what the tilt limit falls short of the axis")
    propagate_feature: bool = Field(True, description="predict the feature from the detection's exposure to now "
                                                      "and between detections with the feature kinematics")
    nominal_dt_s: float = Field(1.0 / 30.0, gt=0.0, le=1.0,
                                description="controller period assumed on the first call (joint-limit "
                                            "look-ahead and feature propagation), s")

    @model_validator(mode="after")
    def _ordered(self):
        for name, lim in (("pan", self.pan_limits_rad), ("tilt", self.tilt_limits_rad)):
            if not lim[0] < lim[1]:
                raise ValueError(f"{name}_limits_rad must be ordered [min, max] with min < max (got {lim})")
        return self


# --------------------------------------------------------------------------- scripted commands


class RatesStep(StrictModel):
    airspeed_m_s: float = Field(gt=0, le=60, description="commanded airspeed, m/s")
    roll_rate_deg_s: float = Field(0.0, ge=-200, le=200, description="commanded roll rate, deg/s")
    pitch_rate_deg_s: float = Field(0.0, ge=-200, le=200, description="commanded pitch rate, deg/s")


class AccelStep(StrictModel):
    airspeed_m_s: float = Field(gt=0, le=60, description="commanded airspeed, m/s")
    right_m_s2: float = Field(0.0, ge=-60, le=60, description="perpendicular to the velocity, to the right")
    up_m_s2: float = Field(0.0, ge=-60, le=60, description="perpendicular to the velocity, upward")


class ScriptStep(StrictModel):
    t_s: float = Field(ge=0, description="time from which this command holds")
    rates: RatesStep | None = Field(None, description="roll and pitch rates and airspeed from this step on (give "
                                                      "rates or accel)")
    accel: AccelStep | None = Field(None, description="acceleration and airspeed from this step on (give rates or "
                                                      "accel)")
    gimbal_deg: Annotated[list[float], Field(min_length=2, max_length=2)] | None = Field(
        None, description="pan, tilt the gimbal is driven to from this step on (none: keep the last)")

    @model_validator(mode="after")
    def _one_mode(self):
        if (self.rates is None) == (self.accel is None):
            raise ValueError("give exactly one of 'rates' or 'accel'")
        return self


# --------------------------------------------------------------------------- swappable blocks


class BlockChoice(StrictModel):
    """Which block flies a part of the mission: a built-in name, or a user's class and its options.

    Written as a name (``estimator: ukf``) or as a mapping (``estimator: {use: pkg.mod:Class, options:
    {...}}``); ``controllers.blocks`` has the Protocols and how a class is found and built."""

    use: str = Field(description="a built-in name, or the import path 'module.sub:ClassName' of a user's class")
    options: dict[str, Any] = Field(default_factory=dict,
                                    description="the user class's options (validated by its Config model if it "
                                                "has one); a built-in takes its settings from its own section")

    @model_validator(mode="before")
    @classmethod
    def _from_name(cls, v):
        return {"use": v} if isinstance(v, str) else v


def _checked(slot: str, section: str):
    """Validation of one slot's choice: a built-in name, or a class that imports and implements the Protocol.

    The scenario's validation context may say ``check_plugins: False`` (a log's scenario read back for
    scoring: the user's module need not be importable there) and gives ``search_dirs``."""
    def check(choice: BlockChoice, info: ValidationInfo) -> BlockChoice:
        from controllers import blocks  # light: no solver or filter

        if choice.use in blocks.builtin_names(slot):
            if choice.options:
                raise ValueError(f"options are for a user's class; the built-in {choice.use!r} takes its settings "
                                 f"from controllers.{section}")
            return choice
        ctx = info.context or {}
        if not ctx.get("check_plugins", True):
            return choice
        cls = blocks.resolve_class(choice.use, slot, ctx.get("search_dirs", ()))
        try:
            blocks.options_for(cls, choice.options)
        except ValidationError as exc:
            e = exc.errors()[0]
            where = ".".join(str(p) for p in e["loc"])
            raise ValueError(f"options{'.' + where if where else ''}: {e['msg']}") from None
        return choice
    return AfterValidator(check)


EstimatorChoice = Annotated[BlockChoice, _checked("estimator", "ukf (and ct_ukf, imm)")]
LoiterChoice = Annotated[BlockChoice, _checked("after_lock", "nmpc or controllers.orbit")]
TerminalChoice = Annotated[BlockChoice, _checked("terminal", "bpng")]
PointingChoice = Annotated[BlockChoice, _checked("pointing", "ibvs")]


# --------------------------------------------------------------------------- the UAV's own airframe


def _box_sides(box: list[float]) -> list[float]:
    if not all(math.isfinite(x) for x in box):
        raise ValueError("a box's sides must be finite")
    if not (box[0] < box[1] and box[2] < box[3] and box[4] < box[5]):
        raise ValueError("a box is [x0, x1, y0, y1, z0, z1] with x0 < x1, y0 < y1 and z0 < z1")
    return box


_Box6 = Annotated[list[float], Field(min_length=6, max_length=6), AfterValidator(_box_sides)]


class AirframeConfig(StrictModel):
    """The UAV's own shape as the flight software knows it (a priori, as it knows the ship class): the parts
    that can stand between its camera and the ship (``controllers.perception.airframe``). Body FRD, metres, origin at
    the CG; the camera sits at the gimbal's mount offset. The defaults are the fwuav's (fuselage 1.0 m x
    0.12 m, high wing of 2.4 m span and 0.146 m chord, tails 0.6 m aft)."""

    enabled: bool = Field(
        True, description="predict the ship's box with the part the airframe hides removed when the detected box "
                          "touches the airframe's silhouette; false: the whole ship's box")
    fuselage_x_m: list[float] = Field(
        default_factory=lambda: [-0.65, 0.35], min_length=2, max_length=2,
        description="the fuselage cylinder's tail and nose, body x (forward), m")
    fuselage_radius_m: float = Field(0.06, ge=0, le=5, description="the fuselage cylinder's radius (0: none), m")
    boxes_frd_m: list[_Box6] = Field(
        default_factory=lambda: [[-0.0958, 0.05, -1.2, 1.2, -0.069, -0.051],  # wing
                                 [-0.6783, -0.5558, -0.2449, 0.2449, -0.004, 0.004],  # horizontal tail
                                 [-0.6925, -0.5511, -0.004, 0.004, -0.2721, -0.05]],  # vertical tail
        max_length=32, description="the other parts as boxes [x0, x1, y0, y1, z0, z1], body FRD, m")
    cut_only_if_closer: bool = Field(
        True, description="cut a heading's predicted box only when the detected box's size is nearer the cut box's "
                          "than the whole one's; false: cut whenever the detected box touches the silhouette")
    align_iterations: int = Field(
        3, ge=0, le=20,
        description="while the course is unknown, cut the ship where the detection puts it in the image (the "
                    "predicted ship moved onto the box, the move corrected this many times); 0: cut at the estimate")
    max_hidden_share: float = Field(
        0.5, ge=0, le=1,
        description="while the course is unknown, skip a detection (airframe_hidden) when the airframe hides more "
                    "than this share of the ship in the cut prediction; 1: never")
    grid_cells: int = Field(
        96, ge=8, le=1000, description="a box the airframe may cut is drawn on a grid of this many cells "
                                       "across its longer side (the cut's resolution)")

    @field_validator("fuselage_x_m")
    @classmethod
    def _fuselage(cls, v: list[float]) -> list[float]:
        if not (all(math.isfinite(x) for x in v) and v[0] < v[1]):
            raise ValueError("must be [tail, nose] with tail < nose")
        return v


# --------------------------------------------------------------------------- the whole flight software


class Controllers(StrictModel):
    kind: Literal["script", "mission"] = Field("mission", description="scripted commands or the mission")
    navigation: NavigationConfig = Field(default_factory=NavigationConfig,
        description="how GNSS fixes become the flight software's position")
    ins: InsConfig = Field(default_factory=InsConfig,
        description="the onboard INS/GNSS filter (with sensors.profile typical or degraded)")
    script: list[ScriptStep] = Field(default_factory=list,
        description="kind script: the timed commands flown in order")
    initial_path: InitialPath = Field(default_factory=InitialPath,
        description="Phase 1: the path flown until the lock")
    acquisition: AcquisitionConfig = Field(default_factory=AcquisitionConfig,
        description="the gimbal's raster search and the lock")
    estimator: EstimatorChoice = Field(
        default_factory=lambda: BlockChoice(use="ukf"),
        description="the target estimator: ukf (the paper's; settings in ukf), ct_ukf (turn rate and along-track "
                    "acceleration; ct_ukf), imm (the two mixed; imm), or a user's class 'module:Class'")
    after_lock: LoiterChoice = Field(
        default_factory=lambda: BlockChoice(use="nmpc"),
        description="after the lock: keep the initial path (path), or loiter (Phase 2) with a circle follower "
                    "(orbit) or the paper's NMPC (nmpc), or a user's class")
    terminal: TerminalChoice = Field(
        default_factory=lambda: BlockChoice(use="bpng"),
        description="Phase 3 guidance: bpng (the paper's quaternion BPNG, settings in bpng), or a user's class")
    pointing: PointingChoice = Field(
        default_factory=lambda: BlockChoice(use="ibvs"),
        description="the gimbal's tracking law: ibvs (the paper's, settings in ibvs), or a user's class")
    orbit: Orbit = Field(default_factory=Orbit, description="after_lock orbit: the circle follower's settings")
    nmpc: NmpcConfig = Field(default_factory=NmpcConfig,
        description="after_lock nmpc: the Phase 2 loiter's settings and solver")
    switch: SwitchConfig = Field(default_factory=SwitchConfig, description="the Phase 2 -> 3 switch and the go-around")
    reacquire: ReacquireConfig = Field(default_factory=ReacquireConfig,
        description="what the gimbal does when the target is lost after the lock")
    bpng: BpngConfig = Field(default_factory=BpngConfig,
        description="terminal bpng: the Phase 3 guidance law's settings")
    ukf: UkfConfig = Field(default_factory=UkfConfig,
        description="the target UKF's noise, gate and start (also read by ct_ukf and imm)")
    ct_ukf: CtUkfConfig = Field(default_factory=CtUkfConfig,
        description="estimator ct_ukf: the manoeuvring-ship model's settings")
    imm: ImmConfig = Field(default_factory=ImmConfig, description="estimator imm: the model mixing's settings")
    turn_from_course: TurnFromCourseConfig = Field(default_factory=TurnFromCourseConfig,
        description="a turn or zigzag found in a constant-velocity estimate's course")
    target_model: ShipModelConfig = Field(default_factory=ShipModelConfig,
        description="the ship class the perception corrects box centres with")
    detection_gate: DetectionGateConfig = Field(default_factory=DetectionGateConfig,
        description="which detections the estimator does not use")
    ibvs: IbvsConfig = Field(default_factory=IbvsConfig,
        description="pointing ibvs: the gimbal tracking law's settings")
    airframe: AirframeConfig = Field(default_factory=AirframeConfig,
        description="the UAV's own airframe, as the perception models it")

    @model_validator(mode="after")
    def _script(self):
        if self.kind == "script":
            if not self.script:
                raise ValueError("kind 'script' needs a non-empty 'script' list")
            times = [s.t_s for s in self.script]
            if times != sorted(times):
                raise ValueError("script steps must be in increasing t_s")
        return self

    @model_validator(mode="after")
    def _entry_ring(self, info: ValidationInfo):
        """The dive's entry ring needs a loiter that flies below its ring (``altitude_offset_m``)."""
        from controllers import blocks  # light: no solver or filter

        use = self.after_lock.use
        if self.switch.entry_depression_margin_deg is None or use in blocks.builtin_names("after_lock"):
            return self
        ctx = info.context or {}
        if ctx.get("check_plugins", True) and not hasattr(
                blocks.resolve_class(use, "after_lock", ctx.get("search_dirs", ())), "altitude_offset_m"):
            raise ValueError(f"switch.entry_depression_margin_deg: {use} has no altitude_offset_m to fly below "
                             "its ring; set it to null")
        return self
