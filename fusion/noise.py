"""The filter's state indices and noise model: what :mod:`fusion.ekf` squares into ``Q`` and ``R``
(1-sigma values in natural units), and the measurement sigmas it derives from the vision's own.

Kept apart from the filter (filterpy, scipy.stats) so that reading a config's ``[fusion]`` table
(:mod:`fusion.options`, :mod:`fusion.calibration`) does not load them: ``vifusion run`` imports
the filter while its vision workers estimate, not before they start (a second of its start-up).

The sigma kernels below are compiled into :mod:`fusion.ekf`'s updates, and numba's cache keys a
kernel by its own file only: after editing one of them, clear ``fusion/__pycache__`` (or touch
``fusion/ekf.py``), or the updates keep the old one (a fresh install compiles anew).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

__all__ = ["S", "DIM_X", "NoiseModel", "GRAVITY_M_S2"]

GRAVITY_M_S2 = 9.80665


class S:
    """State indices (rad, rad/s, m/s, m/s^2)."""

    ROLL_W = 0
    PITCH_W = 1
    YAW_REL = 2
    BANK = 3
    GRADE = 4
    GYRO_BIAS = slice(5, 8)
    GYRO_BIAS_X, GYRO_BIAS_Y, GYRO_BIAS_Z = 5, 6, 7
    SPEED = 8
    ACCEL_X = 9
    BANK_RATE = 10
    ACCEL_BIAS = slice(11, 14)
    CURVATURE = 14
    GRADE_RATE = 15


DIM_X = 16


@dataclass(frozen=True)
class NoiseModel:
    """Process and measurement noise as 1-sigma values in natural units.

    Process noise is given as random-walk densities (per sqrt(second)); measurement noise per
    sample. The filter squares them: ``Q = sigma**2 * dt``, ``R = sigma**2``; except the bank and
    grade rates, first-order Gauss-Markov processes whose 1-sigma is the stationary one (``Q =
    sigma**2 (1 - exp(-2 dt / tau))``, exact: the driving noise's density is ``2 sigma**2 /
    tau``), and the gyro's white noise, which enters the attitude integrated
    over the interval (``sigma**2 dt**2``).
    """

    gyro_noise_rad_s: float = math.radians(0.05)           # white noise of one gyro sample
    gyro_bias_walk_rad_s_sqrt_s: float = math.radians(0.002)
    #: Stationary 1-sigma of the bank rate and its correlation time: superelevation runoffs of
    #: the benchmark drives reach 4-5 deg/s for 2-3 s. (With the vision roll applied at the
    #: lookahead, 2 deg/s and 0.3 s made the bank lag every runoff: bank RMSE 0.28 against 0.24
    #: deg on the 7 deg drive.)
    bank_rate_rad_s: float = math.radians(4.0)
    bank_rate_tau_s: float = 1.0
    #: Its correlation time while the vision is away (lane loss): the bank then holds instead
    #: of extrapolating the last runoff (3.3 deg of roll error after 5 s with 1 s, measured).
    #: The driving noise stays that of ``bank_rate_tau_s``: the rate's stationary 1-sigma is
    #: then ``sqrt(0.3 / 1)`` of ``bank_rate_rad_s``.
    bank_rate_tau_no_vision_s: float = 0.3
    #: Its correlation time about the road's bank rate ahead where the frames' twists mapped it
    #: (:attr:`fusion.ekf.ImuStep.bank_rate_target_rad_s`; :mod:`fusion.ekf`, "Process"): the rate then
    #: follows the map within a tenth of a second between the bursts of deferred rolls. The
    #: driving noise stays that of ``bank_rate_tau_s`` (as the scheduled sigma sets it): about the
    #: map the rate's stationary 1-sigma is ``sqrt(0.1 / 1)`` of the free rate's. Measured
    #: on the bench's five HD drives (forward, the same vision, the deadband below), 1 / 0.3 /
    #: 0.1 / 0.05 s: the left-hand drive's yaw 0.108 / 0.100 / 0.094 / 0.092 deg, the hill
    #: drive's bank 0.202 / 0.200 / 0.188 / 0.166, the hold-out drive's roll 0.028 / 0.026 /
    #: 0.026 / 0.029 (docs/fusion-notes.md, seventeenth session: chosen before the deadband, and
    #: kept; both sweeps before each patch's median, which moved these by up to 0.003 deg).
    bank_rate_tau_mapped_s: float = 0.1
    #: Mapped rates within this of 0 are taken as 0, steady road: three times the map's own
    #: error there (0.08 deg/s RMS against the truth; -0.02 deg/s on average on steady banked
    #: curves, which the bank integrated: the hill drive's bank 0.200 -> 0.223 deg without it).
    #: Measured, 0 / 0.05 / 0.1 / 0.25 / 0.5 / 1 deg/s: hill bank 0.223 / 0.215 / 0.199 / 0.188
    #: / 0.187 / 0.181, hold-out roll 0.030 / 0.029 / 0.027 / 0.026 / 0.025 / 0.025
    #: (docs/fusion-notes.md, seventeenth session).
    bank_rate_map_deadband_rad_s: float = math.radians(0.25)
    #: The bank-rate 1-sigma scheduled by what the camera sees ahead (with the vision roll
    #: deferred): ``max(floor, gain |rate ahead|, gain |bank_rate|)``, where the rate ahead is
    #: the mean bank rate between the vehicle and the vision's roll cross-sections. On steady
    #: road no runoff is in view and the bank holds; a runoff shows ``lookahead / v`` (about
    #: half a second) before the wheels reach it. The gain covers a runoff's peak rate against
    #: its mean over the stretch ahead (1.5 for a cubic profile). Without it the constant
    #: ``bank_rate_rad_s`` let the bank's sigma climb to 1.3 deg between the vision's rolls,
    #: which come in bursts, one road patch per dash of the centre line (0.8 s at 80 km/h).
    #: ``gain = 0`` keeps the constant.
    bank_rate_preview_floor_rad_s: float = math.radians(0.25)
    bank_rate_preview_gain: float = 2.0
    #: The grade's rate (vertical curves, and the runoffs' grade off the road's axis): stationary
    #: 1-sigma and correlation time. 0.5 deg/s is a 3000 m vertical curve at 90 km/h; a vertical
    #: curve lasts 5-15 s. The grade's own walk is what the rate leaves out. With the vertical
    #: curve's pitch in the vision model (:meth:`fusion.ekf.AttitudeEKF.update_vision`) the HD drives take
    #: half of both (notes, ninth session); the 640x360 sample drive does not.
    grade_rate_rad_s: float = math.radians(0.5)
    grade_rate_tau_s: float = 5.0
    grade_walk_rad_sqrt_s: float = math.radians(0.05)
    accel_x_walk_m_s2_sqrt_s: float = 3.0                  # longitudinal jerk
    #: Attitude motion the gyros do not see (scale factor, misalignment, vibration, timing), a
    #: random walk of roll, pitch and the heading relative to the road (``[fusion]
    #: attitude_walk_deg_sqrt_s``). A real vehicle's: comma2k19's phone gyro integrated from its
    #: INS attitude over 1 and 4 s drifts 0.025 / 0.036-0.046 deg/sqrt(s) in roll / pitch, its noise
    #: included (``tools/fusion_realdata.py``, :func:`fusion.metrics.gyro_attitude_drift`); KITTI's
    #: 10 Hz OXTS rates drift 0.090 in pitch over 1 s, over this default, but ten integration steps
    #: through the braking's pitch say more about the coarse sampling than about the gyro. The
    #: simulator's gyros leave out up to 0.009 in pitch, their noise included, and its drives'
    #: configs say 0.01 (``drivesim.drive.SIM_ATTITUDE_WALK_DEG_SQRT_S``).
    #: Without a pitch gyro the pitch walks with ``no_pitch_rate_walk_rad_sqrt_s`` instead.
    attitude_walk_rad_sqrt_s: float = math.radians(0.05)
    #: Without a lane fit the road is assumed to turn with the vehicle; how far the vehicle may
    #: steer relative to the road meanwhile (lane changes), per sqrt(second).
    yaw_rel_walk_no_lanes_rad_sqrt_s: float = math.radians(1.0)
    no_pitch_rate_walk_rad_sqrt_s: float = math.radians(3.0)  # pitch motion without a pitch gyro
    #: Without a pitch gyro, the pitch rate the kinematic ``q = r tan(roll)`` leaves out
    #: (suspension pitch, road): a first-order Gauss-Markov state in the pitch gyro's bias slot,
    #: ``q = r tan(roll) - x[GYRO_BIAS_Y]``, with this stationary 1-sigma and correlation time.
    #: The simulator's rider pitches 0.3 deg at 1.3 Hz, 1.7 deg/s RMS (:mod:`fusion.ekf`).
    no_pitch_rate_sigma_rad_s: float = math.radians(2.0)
    no_pitch_rate_tau_s: float = 0.2
    #: Accelerometer noise plus model error per axis (x, y, z), per sample: what the
    #: specific-force model (gravity, speed change, ``v r``, the road's turn and grade rates)
    #: leaves out of a real vehicle's motion: suspension heave and pitch, road roughness,
    #: vibration. Taken from the one real recording with an attitude truth and a 100 Hz IMU
    #: (comma2k19, a RAV4 on a highway; ``tools/fusion_realdata.py`` prints the residuals):
    #: against that truth the residual is 1.87 / 0.38 / 0.58 m/s^2 RMS per sample and 0.053 /
    #: 0.030 / 0.153 m/s^2 averaged over 1 s, the time scale of the gravity reference. These
    #: sigmas are the white noise with that 1 s average at 100 Hz (0.54 / 0.31 / 1.56), to
    #: 0.1 m/s^2. (Before, 0.1 / 0.1 / 1.0 allowed a third of it at 1 s in x and y: comma's roll
    #: 0.93 deg RMS with 24 % of its errors inside 2 sigma; now 0.49 deg and 97 %.) A vehicle
    #: with less unmodelled motion sets ``[fusion] accel_noise_m_s2``: the simulator's drive
    #: configs give their accelerometer's own noise (its vehicle has none of the above).
    #: The sigmas are per sample at :attr:`accel_meas_rate_hz`; at another IMU rate (or with
    #: ``gravity_every``) the filter scales them to the same 1 s average, ``R = sigma^2 f / f_ref``
    #: (:meth:`fusion.ekf.AttitudeEKF.update_gravity`'s ``r_scale``): the residual is motion, whose 1 s
    #: average does not depend on how often it is sampled. Per sample at any rate, KITTI's 10 Hz
    #: OXTS got 0.3 m/s^2 laterally against its own residual of 0.10 per sample; scaled, 0.095:
    #: roll sigma 0.48-0.85 -> 0.34-0.66 deg, roll error 0.110 -> 0.152 deg RMS (its mean -0.07
    #: -> -0.12: the filter follows the lateral accelerometer more over the 9 s scored), pitch
    #: 0.053 -> 0.049; comma (104 Hz) roll 0.494 -> 0.477 (README, "Fusion on real recordings").
    accel_meas_m_s2: tuple[float, float, float] = (0.5, 0.3, 1.6)
    accel_meas_rate_hz: float = 100.0
    speed_meas_m_s: float = 0.05
    vision_sigma_scale: float = 1.0                        # multiplies the vision's own sigmas
    #: Floor of the vision's 1-sigma, one value or one per angle (roll, pitch, yaw). On the
    #: simulator's HD drives the estimator's pitch and yaw errors on steady road are 0.005-0.03
    #: deg, and 0.04 deg for pitch and yaw with the grade allowances halved brings every HD
    #: drive's NEES share into the 90 % (the 60 s drive 68.8 -> 91.0 %), but the bundled 640x360
    #: drive's bank goes 0.23 -> 0.41 deg: its pixels are twice as coarse, and its vision's own
    #: sigmas are already too small. Kept at 0.1 for all three until the floor follows the
    #: camera's resolution (notes, ninth session).
    vision_sigma_floor_rad: float | tuple[float, float, float] = math.radians(0.1)
    #: The vertical-curve pitch term of :meth:`fusion.ekf.AttitudeEKF.update_vision` fades out linearly as
    #: the bank rate here or ahead approaches this: in a superelevation runoff the fitted vertical
    #: curvature's change is the banked curve's, whose pitch the twist model carries (with the
    #: term at full weight there the left-hand drive's pitch went 0.007 -> 0.020 deg, bank 0.259 ->
    #: 0.323). The runoffs of the benchmark drives turn the bank at 1.5-2.5 deg/s.
    vertical_curve_bank_rate_limit_rad_s: float = math.radians(1.0)
    #: Relative error of the road-in-view model of the vision (lookahead bank, twist terms),
    #: added to the vision's sigmas as this fraction of each modelled effect: the vision errors'
    #: regression on the true twist over the banked drives gives slopes 20-25 % off the model's.
    vision_road_model_error: float = 0.25
    gate_probability: float = 0.999                        # chi-square gate of every update

    init_angle_rad: float = math.radians(5.0)
    init_bank_rad: float = math.radians(5.0)
    init_bank_rate_rad_s: float = math.radians(2.0)
    init_grade_rad: float = math.radians(3.0)
    init_grade_rate_rad_s: float = math.radians(0.5)
    #: Gyro bias prior, 1-sigma: an uncalibrated MEMS gyro's turn-on offset (one value, or one
    #: per axis).
    init_gyro_bias_rad_s: float | tuple[float, float, float] = math.radians(0.5)
    init_speed_m_s: float = 2.0
    init_accel_m_s2: float = 2.0
    #: Accelerometer bias prior: what is left after calibration. The lateral part cannot be
    #: told from a bank offset (both shift f_y by g * angle), so it bounds the bank accuracy:
    #: 0.01 m/s^2 is 0.06 deg of bank.
    init_accel_bias_m_s2: float | tuple[float, float, float] = 0.03
    #: The biases' prior means (vehicle frame): a calibration of this IMU, for instance from an
    #: earlier drive (``vifusion run`` writes its end-of-drive estimates to ``calibration.toml``);
    #: ``init_gyro_bias_rad_s`` and ``init_accel_bias_m_s2`` are then their uncertainty.
    gyro_bias_prior_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_bias_prior_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_bias_walk_m_s2_sqrt_s: float = 0.0005
    init_curvature_1_m: float = 0.01
    curvature_walk_1_m_sqrt_s: float = 0.002              # clothoids: ~0.005 1/m in 2 s
    curvature_meas_1_m: float = 0.002                     # lane-fit curvature, when it gives none
    #: Floor of the lane-fit curvature's 1-sigma: absolute plus relative. Lane fits see the
    #: curvature over tens of metres, where a small pitch error scales it (a 0.2 deg pitch bias
    #: was 13 % of curvature on the simulator).
    curvature_sigma_floor_1_m: float = 3e-4
    curvature_sigma_floor_rel: float = 0.2
    #: Floor of the vision's road-twist 1-sigma (:attr:`fusion.ekf.VisionMeasurement.road_twist_rad_m`):
    #: absolute plus relative. Against the simulator's truth its error is 0.002-0.004 deg/m RMS
    #: on steady road (the estimator's own sigma: 0.001-0.002) and 15-25 % of the twist in the
    #: runoffs, where the road departs from the one-twist model over the cross-sections.
    twist_sigma_floor_rad_m: float = math.radians(0.004)
    twist_sigma_floor_rel: float = 0.25

    def vision_sigma_rad(self, sigma_rad, road_effect_rad=0.0, angle: int = 0):
        """The vision angles' 1-sigma as the filter uses it (rad; scalars or arrays): their own
        times ``vision_sigma_scale``, floored at ``vision_sigma_floor_rad`` (of ``angle``: 0
        roll, 1 pitch, 2 yaw), and in quadrature ``vision_road_model_error`` of the road-in-view
        effect the filter models for them (the lookahead's bank change, the twist's pitch and
        yaw errors, the vertical curve's pitch)."""
        p = self._vision_sigma_params()
        return _float_if_scalar(_vision_sigma_v(sigma_rad, road_effect_rad, p[0], p[_FLOOR_AT[angle]], p[2]))

    def twist_sigma_rad_m(self, twist_rad_m, sigma_rad_m):
        """The vision's road-twist 1-sigma as the filter uses it (rad/m; scalars or arrays): its
        own, floored at ``twist_sigma_floor_rad_m + twist_sigma_floor_rel |twist|``."""
        return _float_if_scalar(_twist_sigma_v(twist_rad_m, sigma_rad_m, *self._vision_sigma_params()[6:8]))

    def curvature_sigma_1_m(self, curvature_1_m, sigma_1_m):
        """The lane-fit curvature's 1-sigma as the filter uses it (1/m; scalars or arrays): the
        fit's own (``curvature_meas_1_m`` where it gives none), floored at
        ``curvature_sigma_floor_1_m + curvature_sigma_floor_rel |curvature|``."""
        return _float_if_scalar(_curvature_sigma_v(curvature_1_m, sigma_1_m, *self._vision_sigma_params()[3:6]))

    @property
    def init_gyro_bias_sigma_rad_s(self) -> np.ndarray:
        """``init_gyro_bias_rad_s`` per axis (x, y, z; one value is every axis's), rad/s."""
        return np.broadcast_to(np.asarray(self.init_gyro_bias_rad_s, dtype=float), (3,))

    def _vision_sigma_params(self) -> np.ndarray:
        """The parameters of the three sigmas above, in the order the compiled updates take them
        (:func:`_vision_sigma`, :func:`_curvature_sigma`, :func:`_twist_sigma`)."""
        floor = np.broadcast_to(np.asarray(self.vision_sigma_floor_rad, dtype=float), (3,))
        return np.array([self.vision_sigma_scale, floor[0], self.vision_road_model_error,
                         self.curvature_meas_1_m, self.curvature_sigma_floor_1_m, self.curvature_sigma_floor_rel,
                         self.twist_sigma_floor_rad_m, self.twist_sigma_floor_rel, floor[1], floor[2],
                         self.vertical_curve_bank_rate_limit_rad_s])


# ---- the measurement sigmas of NoiseModel, per value: compiled, for the updates (which run
# for every frame) and vectorised for NoiseModel's methods. np.maximum's NaN is kept.


@nb.njit(cache=True)
def _max_nan(a, b):
    """``np.maximum`` of two floats: NaN if either is."""
    if a != a or b != b:
        return math.nan
    return a if a >= b else b


@nb.njit(cache=True)
def _vision_sigma(sigma, effect, scale, floor, model_error):
    """:meth:`NoiseModel.vision_sigma_rad` of one angle."""
    return math.hypot(_max_nan(sigma * scale, floor), model_error * abs(effect))


@nb.njit(cache=True)
def _curvature_sigma(curvature, sigma, meas, floor, rel):
    """:meth:`NoiseModel.curvature_sigma_1_m` of one curvature."""
    return _max_nan(sigma if math.isfinite(sigma) else meas, floor + rel * abs(curvature))


@nb.njit(cache=True)
def _twist_sigma(twist, sigma, floor, rel):
    """:meth:`NoiseModel.twist_sigma_rad_m` of one twist."""
    return _max_nan(sigma if math.isfinite(sigma) else 0.0, floor + rel * abs(twist))


def _float_if_scalar(a):
    """A vectorised function's result: a float for scalar arguments (``np.vectorize`` gives a
    0-d array), the array otherwise."""
    return float(a) if np.ndim(a) == 0 else a


def _vectorize(f, n_out: int = 1):
    """``np.vectorize`` of compiled ``f``, quiet about NaN arguments (NaN in, NaN out, as the
    numpy expressions it replaced gave without a warning)."""
    v = np.vectorize(f, otypes=[float] * n_out)

    def call(*args):
        with np.errstate(invalid="ignore"):
            return v(*args)
    return call


_vision_sigma_v = _vectorize(_vision_sigma)
#: Where each angle's floor (roll, pitch, yaw) is in :meth:`NoiseModel._vision_sigma_params`.
_FLOOR_AT = (1, 8, 9)
_curvature_sigma_v = _vectorize(_curvature_sigma)
_twist_sigma_v = _vectorize(_twist_sigma)
