"""The ``[fusion]`` table of a config file: the filter's noise model (your IMU's datasheet
values and the allowances for what the model leaves out) and how a run is done.

Every key is optional; units are in the names. Example::

    [fusion]
    gyro_noise_deg_s = 0.05          # 1-sigma of one gyro sample
    accel_noise_m_s2 = [0.1, 0.1, 0.3]     # an example; the default [0.5, 0.3, 1.6] is a car's
                                     # unmodelled motion (NoiseModel.accel_meas_m_s2)
    accel_bias_sigma_m_s2 = 0.03     # residual after calibration (or one per axis); its lateral
                                     # part bounds the bank accuracy (0.01 m/s^2 = 0.06 deg)
    gyro_bias_sigma_deg_s = 0.5      # turn-on offset (or one per axis)
    accel_bias_m_s2 = [0, 0, 0]      # calibrated biases, vehicle frame (prior means; the
    gyro_bias_deg_s = [0, 0, 0]      # sigmas above are their uncertainty): calibration.toml of
                                     # an earlier run (fusion.calibration)
    camera_time_offset_s = 0.0       # added to frames.csv times
    estimate_time_offset = false     # estimate it from the data and use the estimate
    smooth = false                   # forward filter + RTS smoother (offline)
    defer_roll = true                # vision roll applied when the vehicle reaches the road it
                                     # was measured on (false: modelled as the bank ahead)
    max_imu_gap_s = 0.2              # IMU samples further apart: the filter starts again
    wheelbase_m = 1.45               # rear contact behind the front one (the origin), m: the
                                     # front contact moves sideways at L x heading rate (0:
                                     # the default, along the heading; measured on a motorcycle
                                     # drive in the README)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from .config import Table
from .noise import NoiseModel

__all__ = ["FusionOptions", "RunSettings", "fusion_options_from_table"]


@dataclass(frozen=True)
class FusionOptions:
    """How :class:`fusion.engine.FusionStream` runs the filter: its noise model and switches (the
    ``[fusion]`` table's keys map onto them, :func:`fusion_options_from_table`)."""

    noise: NoiseModel = field(default_factory=NoiseModel)
    use_vision: bool = True
    #: Apply the gravity reference every n-th IMU sample (1: every sample).
    gravity_every: int = 1
    #: How far back late vision results are still applied, s.
    history_s: float = 1.0
    #: Without a lane fit for this long the road is assumed to turn with the vehicle (yaw
    #: relative to the road held, the curvature state unused), s.
    lane_fit_hold_s: float = 0.25
    #: After this many vision results in a row fail the chi-square gate, the road states
    #: (yaw relative to the road, bank, grade) are re-acquired from the next one: their
    #: covariance is reset to the initial one, so that a filter that drifted while the lanes
    #: were lost cannot lock itself out.
    reacquire_after_rejections: int = 10
    #: After the gravity reference has been refused by the gate for this long (every update in
    #: a row), the world roll and pitch are taken again from the accelerometer (the bank and
    #: grade moved with them, so that the angles relative to the road stay), s: a gyro glitch
    #: (a zeroed CAN frame reads -164 deg/s) that turned the attitude 16 deg in 0.1 s had every
    #: later update refused and the bank 20 deg off with a sigma of 0.3 (a review). On the
    #: benchmark's drives the longest run of refusals is one update.
    gravity_reacquire_after_s: float = 1.0
    #: Apply the vision roll when the vehicle reaches the road it was measured on
    #: (:class:`fusion.ekf.RollAhead`) instead of modelling the bank ahead with the bank rate.
    defer_roll: bool = True
    #: The bank rate reverts to the road's bank rate that the frames' twists mapped ahead, where
    #: there is one (:meth:`fusion.engine.FusionStream._bank_rate_target`), instead of to 0.
    bank_rate_map: bool = True
    #: IMU samples further apart than this (a gap in the CAN stream) are not integrated
    #: across: the mean of two gyro readings says nothing about a motorcycle's roll over
    #: more than a fifth of a second (its roll modes are at 1-2 Hz). The filter starts again
    #: from the sample after the gap (:meth:`fusion.engine.FusionStream.restart`), s.
    max_imu_gap_s: float = 0.2
    #: The rear wheel's contact point behind the front one (the vehicle's origin), m: the
    #: origin moves sideways at the wheelbase times the heading rate (the rear wheel rolls
    #: without side slip; :class:`fusion.ekf.AttitudeEKF`). 0: along the body's heading.
    wheelbase_m: float = 0.0


@dataclass(frozen=True)
class RunSettings:
    camera_time_offset_s: float = 0.0
    estimate_time_offset: bool = False
    smooth: bool = False


# key -> (NoiseModel field, converter from the file's unit, smallest and largest value accepted).
# The upper limits are far beyond any vehicle's (they keep a typo such as 1e300 from overflowing
# the filter's covariance into NaN estimates, which a review found written as valid); a time
# constant divides, so it cannot be 0, nor can the sigma of a state (its covariance would be
# singular: the no-pitch-gyro pitch rate), nor the wheel speed's noise (with the longitudinal
# jerk at 0 as well, the speed update divided by 0: a review's traceback).
_NOISE_KEYS = {
    "gyro_noise_deg_s": ("gyro_noise_rad_s", math.radians, 0.0, 100.0),
    "gyro_bias_walk_deg_s_sqrt_s": ("gyro_bias_walk_rad_s_sqrt_s", math.radians, 0.0, 10.0),
    "accel_bias_walk_m_s2_sqrt_s": ("accel_bias_walk_m_s2_sqrt_s", float, 0.0, 10.0),
    "speed_noise_m_s": ("speed_meas_m_s", float, 1e-4, 100.0),
    "attitude_walk_deg_sqrt_s": ("attitude_walk_rad_sqrt_s", math.radians, 0.0, 100.0),
    "no_pitch_rate_sigma_deg_s": ("no_pitch_rate_sigma_rad_s", math.radians, 1e-3, 100.0),
    "no_pitch_rate_tau_s": ("no_pitch_rate_tau_s", float, 0.01, 10.0),
    "bank_rate_deg_s": ("bank_rate_rad_s", math.radians, 0.0, 100.0),
    "bank_rate_tau_s": ("bank_rate_tau_s", float, 0.01, 1000.0),
    "bank_rate_tau_mapped_s": ("bank_rate_tau_mapped_s", float, 0.01, 1000.0),
    "bank_rate_map_deadband_deg_s": ("bank_rate_map_deadband_rad_s", math.radians, 0.0, 100.0),
    "bank_rate_preview_floor_deg_s": ("bank_rate_preview_floor_rad_s", math.radians, 0.0, 100.0),
    "bank_rate_preview_gain": ("bank_rate_preview_gain", float, 0.0, 100.0),
    "grade_walk_deg_sqrt_s": ("grade_walk_rad_sqrt_s", math.radians, 0.0, 100.0),
    "grade_rate_deg_s": ("grade_rate_rad_s", math.radians, 0.0, 100.0),
    "grade_rate_tau_s": ("grade_rate_tau_s", float, 0.01, 1000.0),
    "longitudinal_jerk_m_s3": ("accel_x_walk_m_s2_sqrt_s", float, 0.0, 1000.0),
    "vision_sigma_scale": ("vision_sigma_scale", float, 0.0, 1000.0),
    "vision_road_model_error": ("vision_road_model_error", float, 0.0, 100.0),
    "gate_probability": ("gate_probability", float, 0.5, 0.999999),
    "accel_noise_rate_hz": ("accel_meas_rate_hz", float, 0.1, 10000.0),
}


def fusion_options_from_table(table: dict | None, source: str = "config") -> tuple[FusionOptions, RunSettings]:
    """Parse ``[fusion]``; errors name the file and key (:class:`fusion.errors.ConfigError`)."""
    t = Table(table or {}, "fusion", source)
    noise = NoiseModel()
    changes = {}
    for key, (name, conv, lo, hi) in _NOISE_KEYS.items():
        if t.has(key):
            changes[name] = conv(t.get(key, "float", min=lo, max=hi))
    for key, name, conv, hi in (("accel_bias_sigma_m_s2", "init_accel_bias_m_s2", float, 10.0),
                                ("gyro_bias_sigma_deg_s", "init_gyro_bias_rad_s", math.radians, 100.0),
                                ("vision_sigma_floor_deg", "vision_sigma_floor_rad", math.radians, 90.0)):
        if t.has(key):   # one value, or one per axis (angle: roll, pitch, yaw)
            if isinstance(t.data[key], list):
                changes[name] = tuple(conv(v) for v in t.get(key, "floats", length=3, min=0.0, max=hi))
            else:
                changes[name] = conv(t.get(key, "float", min=0.0, max=hi))
    for key, name, conv, hi in (("accel_bias_m_s2", "accel_bias_prior_m_s2", float, 10.0),
                                ("gyro_bias_deg_s", "gyro_bias_prior_rad_s", math.radians, 100.0)):
        if t.has(key):
            changes[name] = tuple(conv(v) for v in t.get(key, "floats", length=3, min=-hi, max=hi))
    if t.has("accel_noise_m_s2"):
        changes["accel_meas_m_s2"] = t.get("accel_noise_m_s2", "floats", length=3, min=1e-6, max=100.0)
    noise = replace(noise, **changes)
    d = FusionOptions()
    opts = FusionOptions(
        noise=noise,
        gravity_every=t.get("gravity_every", "int", d.gravity_every, min=1, max=100),
        history_s=t.get("history_s", "float", d.history_s, min=0.0, max=60.0),
        lane_fit_hold_s=t.get("lane_fit_hold_s", "float", d.lane_fit_hold_s, min=0.0, max=10.0),
        reacquire_after_rejections=t.get("reacquire_after_rejections", "int", d.reacquire_after_rejections, min=1),
        gravity_reacquire_after_s=t.get("gravity_reacquire_after_s", "float", d.gravity_reacquire_after_s,
                                        min=0.01, max=600.0),
        defer_roll=t.get("defer_roll", "bool", d.defer_roll),
        bank_rate_map=t.get("bank_rate_map", "bool", d.bank_rate_map),
        max_imu_gap_s=t.get("max_imu_gap_s", "float", d.max_imu_gap_s, min=1e-3, max=60.0),
        wheelbase_m=t.get("wheelbase_m", "float", d.wheelbase_m, min=0.0, max=10.0),
    )
    run = RunSettings(
        camera_time_offset_s=t.get("camera_time_offset_s", "float", 0.0, min=-10.0, max=10.0),
        estimate_time_offset=t.get("estimate_time_offset", "bool", False),
        smooth=t.get("smooth", "bool", False),
    )
    t.done()
    return opts, run
