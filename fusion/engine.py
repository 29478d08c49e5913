"""Streaming fusion: IMU samples and vision results in, the latest estimate out.

:class:`FusionStream` is what the prototype embeds and what ``vifusion run`` feeds in time
order. Each IMU sample propagates the filter from the previous sample with the mean of the
two gyro readings, then applies the wheel speed when fresh and (every ``gravity_every``-th
sample, once a wheel speed has come) the gravity reference. A
vision result at a time between two IMU samples is applied at its own time: the filter is
propagated to it, updated, and propagated on. A result that arrives late (the vision takes
longer than an IMU interval, or frames come out of order) rolls the filter back to the stored
state just before its time and re-propagates the stored IMU samples: the same answer as if
it had come in time, as long as it is within ``history_s``: the replay applies again the
results (and deferred rolls, :class:`fusion.ekf.RollAhead`) that fell in the replayed samples.
A deferred roll falls due ``roll_lookahead_m / v`` after its frame, and is applied at that
time, in a replay too (a result later than that).

With ``record=True`` every step's prior, posterior and Jacobian are kept for the RTS smoother
(:mod:`fusion.smoother`); recording needs inputs in time order.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass, fields, replace
from operator import attrgetter, itemgetter

import numpy as np

from vision.frames import wrap_angle

from .ekf import (DIM_X, GRAVITY_M_S2, AttitudeEKF, ImuStep, RollAhead, S, VisionMeasurement, accel_r_scale,
                  curvature_from_lane_fit, relative_outputs, road_ahead_as_seen, vision_hx)
from .options import FusionOptions

__all__ = ["FusionOptions", "Estimate", "FusionStream", "StepRecord"]


#: Without a vision result for this long the bank rate decays with its lane-loss time constant
#: (:attr:`fusion.noise.NoiseModel.bank_rate_tau_no_vision_s`): three frames at 30 fps.
_VISION_GAP_S = 0.1

#: The twist map's interpolation spans no more than this between two roads measured, s.
_TWIST_SPAN_S = 1.0
#: Frames whose roads fall due within this of each other measured one road patch (the twist
#: map takes their median), s: a dash's frames land within 0.05 s on the bench's drives.
_PATCH_S = 0.05

_time_of = attrgetter("t_s")
_captured = itemgetter(2)   # of a twist map entry (due, rate, capture time)
#: IMU intervals whose median is taken as the sample period (the accelerometer noise's rate).
_PERIOD_SAMPLES = 20
#: The largest angle relative to the road a vision result may give, rad: a vehicle that follows
#: its lanes is within a quarter turn of the road in roll, pitch and yaw (a motorcycle's lean
#: less the bank stays under 65 deg); beyond it the numbers are not angles in radians.
MAX_VISION_ANGLE_RAD = math.pi / 2
#: A road twist (the bank's change per metre) beyond this is a number, not a measurement, rad/m
#: (1.15 deg/m): design guides keep a superelevation runoff's edge within 1/50-1/200 of the
#: centre line's grade, about 0.1-0.3 deg/m on a lane; the benchmark's runoffs twist 0.1-0.23
#: deg/m and the estimator's largest reading there is 0.44. One frame's twist of 0.03 rad/m took
#: the sample drive's bank 3.7 deg off (6 sigma) through the bank-rate map, 1 rad/m 131 deg, with
#: no word (a review): such a twist is dropped from its frame (the angles still count) and
#: counted (``counts["twist_implausible"]``).
MAX_ROAD_TWIST_RAD_M = 0.02

#: A vision result dated further ahead of the newest IMU sample (and of history_s) is a clock
#: mix-up, not a result the IMU has yet to reach, s.
_MAX_VISION_LEAD_S = 1.0
#: The roll's 1-sigma at a start without a wheel speed (:meth:`FusionStream._init_from_accel`):
#: a motorcycle's lean, which the accelerometer alone cannot see, up to about 45 deg.
_ROLL_SIGMA_WITHOUT_SPEED_RAD = math.radians(25.0)
#: The specific force that can level the filter (the start, the first wheel speed, a re-acquired
#: gravity reference), in g: a coordinated lean of 55 deg reads 1.74 g, while a zeroed CAN frame
#: of a +-4 g accelerometer reads 7 g and set the start's pitch to 90 deg, where the first gravity
#: update divided by zero (a review). Outside it the start is level with the roll's and pitch's
#: sigma :data:`_ROLL_SIGMA_WITHOUT_SPEED_RAD`, and the gravity updates bring them in.
LEVELLING_FORCE_G = (0.5, 2.0)
#: A wheel speed refused ``reacquire_after_rejections`` times in a row is taken again (the speed
#: state re-acquired) only if it lies within this of the speed the filter carried on with its
#: acceleration state (which the accelerometer keeps through the gravity updates), m/s, plus
#: :data:`SPEED_DRIFT_M_S2` per second since the last wheel speed taken. Without the bound a
#: wheel-speed sensor stuck at 0 (a locked or lifted wheel, a dead sensor) or at 300 km/h was
#: taken after 0.2 s: 6 s of 0 km/h at 79 km/h put the sample drive's bank 13 deg off (42 sigma,
#: a review's replay of its vision results; 17 deg at the end with its frames, the live test).
#: 2 m/s is 8 % of 25 m/s, beyond a tyre's slip and its rolling radius's change with lean.
SPEED_REACQUIRE_M_S = 2.0
#: How fast the carried speed may drift from the ground speed, m/s^2: 0.02 g, an accelerometer
#: bias or a grade 1.2 deg off for the whole while. Measured: with the wheel speed dropped for 40
#: s of the 60 s drive, the carried speed drifted 0.33 m/s at most (0.008 m/s^2).
SPEED_DRIFT_M_S2 = 0.2
#: The bound holds once the wheel has confirmed the speed state for this long since it was set, s:
#: a state set from a bad first reading (0 at power-up, for a few tenths of a second) is
#: re-acquired as before, not held against the wheel's right readings for a minute.
SPEED_CONFIRMED_S = 2.0


def _all_finite(a: np.ndarray) -> bool:
    """Whether every value of a small array is finite (per sample: a quarter of the time of
    ``np.all(np.isfinite(a))``, whose reduction machinery costs 2 us a call)."""
    return all(map(math.isfinite, a.ravel().tolist()))


@dataclass(frozen=True)
class Estimate:
    """The filter's output at ``t_s`` (s, the CAN log's clock), angles in rad with their
    1-sigma (INTERFACE.md's frames and signs): ``roll``, ``pitch``, ``yaw`` of the vehicle
    relative to the road (ZYX of ``R_o_from_v``: positive roll leans right, positive pitch is
    nose down, positive yaw nose left), ``bank`` of the road (positive raises its left edge),
    ``roll_world``, ``pitch_world`` relative to gravity, ``grade`` of the road in the pitch
    convention (positive downhill); ``gyro_bias_rad_s`` in vehicle axes (NaN for an absent
    pitch gyro); ``speed_m_s``; ``vision_age_s``, the time since the last vision update the
    filter took; ``cov_rpyb_rad2``, the joint 4x4 covariance of (roll, pitch, yaw, bank), whose
    roll-bank terms the sigmas alone do not give (they share the gravity reference). Before the
    first wheel speed the speed and the gravity-referenced angles are NaN
    (:meth:`FusionStream.estimate`)."""

    t_s: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    bank_rad: float
    roll_world_rad: float
    pitch_world_rad: float
    grade_rad: float
    roll_sigma_rad: float
    pitch_sigma_rad: float
    yaw_sigma_rad: float
    bank_sigma_rad: float
    roll_world_sigma_rad: float
    pitch_world_sigma_rad: float
    gyro_bias_rad_s: tuple[float, float, float]
    speed_m_s: float
    vision_age_s: float
    grade_sigma_rad: float = math.nan
    speed_sigma_m_s: float = math.nan
    cov_rpyb_rad2: np.ndarray | None = None


@dataclass
class StepRecord:
    """One propagation step for the smoother: from ``t0`` to ``t1``."""

    t1: float
    F: np.ndarray
    x_prior: np.ndarray
    P_prior: np.ndarray
    x_post: np.ndarray
    P_post: np.ndarray
    imu_index: int   # index of the IMU sample at t1, or -1 for a vision time


@dataclass(slots=True)
class _ImuSample:
    t: float
    gyro: np.ndarray
    accel: np.ndarray
    speed: float
    speed_fresh: bool
    index: int
    x_post: np.ndarray = None
    P_post: np.ndarray = None
    gyro_dot: np.ndarray = None
    gyro_dot_dt: float = math.inf  # the interval gyro_dot was differenced over (inf: not differenced)
    refused: tuple = (0, 0)  # this sample's speed and gravity updates refused, as counted (_tally)
    roll_prop: float = 0.0
    applied: tuple = ()   # measurements applied in the interval ending here (for replays)
    r_scale: float = 1.0  # factor on the accelerometer noise variance (NoiseModel.accel_meas_rate_hz)
    state: tuple = ()     # the stream's own state after this sample (FusionStream._snapshot)
    counted: tuple = ()   # the kinds of counts[...] this sample added to (a replay adds none again)


class FusionStream:
    """Feed :meth:`add_imu` and :meth:`add_vision`; read :meth:`estimate`.

    Parameters
    ----------
    lever_arm_m : (3,) IMU position in the vehicle frame, m
    has_pitch_rate : bool
    options : FusionOptions
    record : bool
        Keep every step for the RTS smoother (time-ordered input only).
    """

    def __init__(self, lever_arm_m=(0.0, 0.0, 0.0), has_pitch_rate: bool = True,
                 options: FusionOptions = FusionOptions(), record: bool = False) -> None:
        self.options = options
        self.ekf = AttitudeEKF(options.noise, lever_arm_m, has_pitch_rate, options.wheelbase_m)
        self.record = record
        self.steps: list[StepRecord] = []
        self.start: tuple[np.ndarray, np.ndarray] | None = None   # posterior at the first sample
        self._hist: deque[_ImuSample] = deque()
        #: The roll-deferral decisions of the vision results applied in ``_hist``, by ``id``
        #: (ahead_s, resumed, defer, twist_now): what a replay applies them with.
        self._decisions: dict[int, tuple[float, bool, bool, bool]] = {}
        self._pending: list[VisionMeasurement | RollAhead] = []   # waiting for the IMU to pass their time
        #: The road's bank rate ahead as the frames' twists measured it (:meth:`_bank_rate_target`):
        #: when the vehicle gets there (s), the rate (rad/s), the frame's capture time (s); sorted
        #: (so by the first: a probe ``(t, inf, inf)`` bisects after every entry due at ``t``).
        self._twist_map: list[tuple[float, float, float]] = []
        #: :meth:`_patch_rate`'s medians by due time: ``(since, newest capture, median)``, taken
        #: while no frame is mapped within two patches of it (:meth:`_map_twist` drops the rest)
        self._patch_memo: dict[float, tuple[float, float, float]] = {}
        #: :meth:`_bank_rate_target`'s last segment of the map, ``(after, before, since, segment)``:
        #: the same for every time strictly between ``after`` and ``before`` while the roads it
        #: rests on are unchanged (None: search again; :meth:`_map_twist` and :meth:`restart`
        #: drop it)
        self._segment_memo: tuple | None = None
        #: Frames captured at or before this time are left out of the map: a re-acquisition of
        #: the road states (the bank, the curvature) at it, their rates converted at the state
        #: that had diverged (``_map_twist``; a review)
        self._map_from = -math.inf
        self._n = 0
        #: the first IMU intervals (s): their median is the sample period that scales the
        #: accelerometer noise to the IMU's rate (fixed once known, so that replays agree; the
        #: very first sample, before any interval, takes the reference rate)
        self._intervals: list[float] = []
        self._r_scale = accel_r_scale(options.noise, 1.0 / options.noise.accel_meas_rate_hz * options.gravity_every)
        self._initialized = False
        self._vision_initialized = False
        self._lane_fit = (0.0, -math.inf)   # lateral offset m, time of the last lane fit
        self._last_vision_t = -math.inf
        self._roll_hole_until = -math.inf   # vision back after a gap: no deferred roll arrives before
        self._road_rate = 0.0
        self._rejected_in_row = 0
        self._speed_initialized = False
        self._speed_rejected_in_row = 0
        self._speed_taken_t = -math.inf   # the last wheel speed the speed state took, s
        self._speed_set_t = -math.inf     # when the speed state was last set from a wheel speed, s
        self._roll_rejected_in_row = 0
        self._gravity_refused_since = math.nan   # the first of the gravity updates refused in a row, s
        self._roll_prop = 0.0   # running sum of the roll (relative to level) the propagation turned, rad
        self._vision_times: deque[float] = deque()   # capture times of recent results (duplicates)
        self._initial_state = self._snapshot()        # what restart() returns the flags to
        self.counts = dict(imu=0, imu_invalid=0, imu_gaps=0, vision_used=0, vision_rejected=0, vision_invalid=0,
                           vision_late=0, vision_too_old=0, vision_duplicate=0, vision_future=0, vision_implausible=0, vision_reacquired=0, roll_ahead_used=0, roll_ahead_rejected=0,
                           roll_ahead_reacquired=0, twist_used=0, twist_rejected=0, gravity_rejected=0, speed_rejected=0, speed_reacquired=0,
                           speed_implausible=0, gravity_reacquired=0, level_skipped=0, twist_implausible=0)

    # ---- inputs ----

    def add_imu(self, t_s: float, gyro_rad_s, accel_m_s2, speed_m_s: float = math.nan,
                speed_fresh: bool = False) -> bool:
        """One IMU sample in the vehicle frame (rates rad/s, specific force m/s^2) at ``t_s``;
        returns whether the filter used it.

        A sample with a non-finite time, rate or force is skipped and counted
        (``counts["imu_invalid"]``); one not after the previous sample is a ValueError; one more
        than ``max_imu_gap_s`` after it restarts the filter (``counts["imu_gaps"]``)."""
        t = float(t_s)
        gyro, accel = np.asarray(gyro_rad_s, dtype=float), np.asarray(accel_m_s2, dtype=float)
        if not (math.isfinite(t) and _all_finite(gyro) and _all_finite(accel)):
            self.counts["imu_invalid"] += 1
            return False
        if self._hist and not t > self._hist[-1].t:
            raise ValueError(f"IMU sample at {t:.6f} s is not after the previous one")
        if self._hist and t - self._hist[-1].t > self.options.max_imu_gap_s:
            self.restart()
            self.counts["imu_gaps"] += 1
        if self._hist and len(self._intervals) < _PERIOD_SAMPLES:
            self._intervals.append(t - self._hist[-1].t)
            self._r_scale = accel_r_scale(self.options.noise, float(np.median(self._intervals)) * self.options.gravity_every)
        sample = _ImuSample(t, gyro, accel, float(speed_m_s), bool(speed_fresh) and math.isfinite(speed_m_s), self._n,
                            r_scale=self._r_scale)
        self._n += 1
        self.counts["imu"] += 1
        if not self._hist:
            # the first sample (or the first after a gap): there is no state before it, so a
            # result from before it is applied at it. Up to max_imu_gap_s earlier (what the filter
            # propagates across) that is fine; older ones are dropped as too old (up to history_s
            # = 1 s before, a second-old roll was applied as the current one)
            self._drop_pending(lambda p: p.t_s < t - min(self.options.max_imu_gap_s, self.options.history_s))
            # and the results too far ahead of it (a bad stamp handed in before the IMU started)
            self._drop_pending(lambda p: isinstance(p, VisionMeasurement) and self.too_far_ahead(p.t_s, t),
                               "vision_future")
        # Vision results whose time this sample passes are applied inside the interval
        # (the queue is kept in time order: the first k; most samples pass none)
        pending, ready = self._pending, ()
        if pending and pending[0].t_s <= t:
            k = bisect.bisect_right(pending, t, key=_time_of)
            ready = pending[:k]
            del pending[:k]
        self._process_sample(sample, visions=ready)
        self._hist.append(sample)
        while self._hist and sample.t - self._hist[0].t > self.options.history_s:
            for v in self._hist.popleft().applied:    # out of reach of a replay
                self._decisions.pop(id(v), None)
        return True

    def add_vision(self, t_s: float, angles_rad, sigmas_rad, valid: bool = True,
                   curvature_1_m: float = math.nan, lateral_offset_m: float = math.nan,
                   curvature_sigma_1_m: float = math.nan, lookahead_m: float = 0.0,
                   twist_m: tuple[float, float] = (0.0, 0.0),
                   road_twist_rad_m: tuple[float, float] = (math.nan, math.nan),
                   twist_response=(math.nan,) * 6, vertical_curvature=(math.nan, math.nan),
                   yaw_per_curvature_m: float = math.nan) -> None:
        """A vision result: roll, pitch, yaw relative to the road at capture time ``t_s``
        (the other arguments: :class:`fusion.ekf.VisionMeasurement`; ``road_twist_rad_m``: the
        road twist and its 1-sigma, rad/m; ``twist_response``: the estimator's six gains;
        ``vertical_curvature``: the road's in view, 1/m, and the pitch error per 1/m of it
        beyond the vehicle's, m; ``yaw_per_curvature_m``: the yaw error per 1/m of the lane
        curvature's, m)."""
        if not self.options.use_vision:
            return
        angles = np.asarray(angles_rad, dtype=float)
        sig = np.asarray(sigmas_rad, dtype=float)
        if not valid or not (_all_finite(angles) and _all_finite(sig)):
            self.counts["vision_invalid"] += 1
            return
        if max(map(abs, angles.tolist())) > MAX_VISION_ANGLE_RAD or min(sig.tolist()) <= 0.0:
            # degrees handed in as radians (8 deg of roll as 458), a sigma of 0 or below: numbers,
            # not a measurement (a review took the bank to -462 deg through 11 re-acquisitions).
            # Python's max and min: numpy's any() twice cost the filter 10 % of its samples/s
            # (17.1k -> 15.1k on the hold-out drive, alternated with the code before)
            self.counts["vision_invalid"] += 1
            self.counts["vision_implausible"] += 1
            return
        tw = tuple(float(g) if math.isfinite(g) else 0.0 for g in twist_m)
        t_s = float(t_s)
        if not math.isfinite(t_s):
            self.counts["vision_invalid"] += 1   # a NaN time would be applied at every sample
            return
        if self.too_far_ahead(t_s):
            self.counts["vision_future"] += 1
            return
        # the newest IMU sample's time; none yet (the camera started first, or the IMU is
        # silent): this result's, so that only the history's span of results waits for the IMU
        newest = self._hist[-1].t if self._hist else t_s
        if not self._hist:
            self._drop_pending(lambda p: p.t_s < t_s - self.options.history_s)
        while self._vision_times and self._vision_times[0] < newest - self.options.history_s:
            self._vision_times.popleft()
        if t_s in self._vision_times:
            self.counts["vision_duplicate"] += 1   # the same frame twice: counted once
            return
        self._vision_times.append(t_s)
        twist, twist_sigma = float(road_twist_rad_m[0]), float(road_twist_rad_m[1])
        if math.isfinite(twist) and not (abs(twist) <= MAX_ROAD_TWIST_RAD_M and twist_sigma > 0.0):
            self.counts["twist_implausible"] += 1
            twist = twist_sigma = math.nan
        item = VisionMeasurement(t_s, angles, sig, float(curvature_1_m), float(curvature_sigma_1_m),
                                 float(lateral_offset_m), float(lookahead_m) if math.isfinite(lookahead_m) else 0.0, tw,
                                 twist, twist_sigma, tuple(map(float, twist_response)), tuple(map(float, vertical_curvature)),
                                 float(yaw_per_curvature_m))
        if not self._hist or item.t_s > self._hist[-1].t:
            bisect.insort_right(self._pending, item, key=_time_of)   # the IMU has not reached it yet
        else:
            self.counts["vision_late"] += 1
            self._apply_late(item)

    def withdraw_vision(self, t_s: float) -> bool:
        """Take back the result captured at ``t_s`` if it still waits for the IMU (not applied:
        the filter is as if it had not come); False when there is none waiting (applied, or
        dropped). For a live frame whose stamp turned out to be a glitch
        (:meth:`fusion.realtime.LiveFusion.push_frame`)."""
        for i, p in enumerate(self._pending):
            if isinstance(p, VisionMeasurement) and p.t_s == t_s:
                del self._pending[i]
                if t_s in self._vision_times:
                    self._vision_times.remove(t_s)
                return True
        return False

    def too_far_ahead(self, t_s: float, newest_s: float | None = None) -> bool:
        """Whether a vision result captured at ``t_s`` is too far ahead of the newest IMU sample
        (``newest_s``, default the stream's; none yet: never) to be kept (a clock mix-up): it
        would wait in the queue for good."""
        if newest_s is None:
            if not self._hist:
                return False
            newest_s = self._hist[-1].t
        return t_s > newest_s + max(self.options.history_s, _MAX_VISION_LEAD_S)

    def restart(self, clock_reset: bool = False) -> None:
        """Start again from the next IMU sample, keeping what is known of the IMU: its biases
        and their covariance (the calibration, :mod:`fusion.calibration`). For a gap in the IMU
        samples (``max_imu_gap_s``) or a bus clock that restarted: the attitude, the road and
        the speed cannot be carried across, and results from before are dropped (deferred
        rolls included). The smoother carries nothing backwards across it either."""
        old = self.ekf
        keep = [*range(S.GYRO_BIAS.start, S.GYRO_BIAS.stop), *range(S.ACCEL_BIAS.start, S.ACCEL_BIAS.stop)]
        if not old.has_pitch_rate:
            keep.remove(S.GYRO_BIAS_Y)   # that slot is the pitch rate q = r tan(roll) leaves out
        self.ekf = AttitudeEKF(old.noise, old.lever_arm_m, old.has_pitch_rate, old.wheelbase_m)
        self.ekf.x[keep] = old.x[keep]
        self.ekf.P[np.ix_(keep, keep)] = old.P[np.ix_(keep, keep)]
        newest = self._hist[-1].t if self._hist and not clock_reset else math.inf
        self._hist.clear()
        self._decisions.clear()
        self._twist_map.clear()
        self._patch_memo.clear()
        self._segment_memo = None
        # results from before the gap (after a clock that went back: all) do not carry across
        self._drop_pending(lambda p: p.t_s <= newest or isinstance(p, RollAhead))
        if clock_reset:
            self._vision_times.clear()
        self._restore(self._initial_state)

    def _drop_pending(self, stale, count: str = "vision_too_old") -> None:
        """Take the queued items for which ``stale(item)`` holds out of the queue; the vision
        results among them are counted in ``counts[count]``."""
        self.counts[count] += sum(isinstance(p, VisionMeasurement) and stale(p) for p in self._pending)
        self._pending = [p for p in self._pending if not stale(p)]

    # ---- core ----

    def _init_from_accel(self, s: _ImuSample) -> None:
        """Roll and pitch relative to level from the first sample's specific force, the
        centripetal terms taken out: in a steady turn ``f_y = g sin(roll) + v r`` and ``f_z =
        g cos(roll) - v q`` (module docstring of :mod:`fusion.ekf`). Without a wheel speed yet
        the turn cannot be taken out (in a coordinated turn ``f_y`` is about 0: a lean of 40 deg
        reads as about 0): the roll's sigma is then :data:`_ROLL_SIGMA_WITHOUT_SPEED_RAD` until
        the gravity updates, which wait for the speed, bring it in."""
        ekf = self.ekf
        known = math.isfinite(s.speed)
        v = s.speed if known else 0.0  # the first wheel speed sets the state properly
        ekf.x[S.SPEED] = v
        if not self._levels(s):
            # a force no attitude explains (a zeroed frame, a spike): start level, the roll and
            # pitch known to _ROLL_SIGMA_WITHOUT_SPEED_RAD, for the gravity updates to bring in
            for i in (S.ROLL_W, S.PITCH_W):
                ekf.x[i] = 0.0
                ekf.P[i, i] = max(ekf.P[i, i], _ROLL_SIGMA_WITHOUT_SPEED_RAD**2)
        else:
            ekf.x[S.ROLL_W] = self._level_roll(s, v)
            ekf.x[S.PITCH_W] = self._level_pitch(s)
            if not known:
                ekf.P[S.ROLL_W, S.ROLL_W] = max(ekf.P[S.ROLL_W, S.ROLL_W], _ROLL_SIGMA_WITHOUT_SPEED_RAD**2)
        self._initialized = True

    def _levels(self, s: _ImuSample) -> bool:
        """Whether sample ``s``'s specific force can level the filter (:data:`LEVELLING_FORCE_G`);
        one that cannot is counted (``counts["level_skipped"]``)."""
        lo, hi = LEVELLING_FORCE_G
        f = math.sqrt(sum(a * a for a in s.accel.tolist())) / GRAVITY_M_S2
        if lo < f < hi:
            return True
        self.counts["level_skipped"] += 1
        return False

    def _level_pitch(self, s: _ImuSample) -> float:
        """The pitch relative to level from sample ``s``'s longitudinal specific force, ``f_x =
        a_x - g sin(pitch)``, with the acceleration state's ``a_x`` (0 at the start)."""
        ekf = self.ekf
        f = s.accel - ekf.x[S.ACCEL_BIAS]
        return math.asin(max(-1.0, min(1.0, -(f[0] - ekf.x[S.ACCEL_X]) / GRAVITY_M_S2)))

    def _level_roll(self, s: _ImuSample, v: float) -> float:
        """The roll relative to level from sample ``s``'s specific force at speed ``v``, the
        centripetal terms taken out (:meth:`_init_from_accel`); without a pitch gyro from the
        lateral force alone."""
        ekf = self.ekf
        f, r = s.accel - ekf.x[S.ACCEL_BIAS], s.gyro[2] - ekf.x[S.GYRO_BIAS_Z]
        if ekf.has_pitch_rate:
            return math.atan2(f[1] - v * r, f[2] + v * (s.gyro[1] - ekf.x[S.GYRO_BIAS_Y]))
        return math.asin(max(-1.0, min(1.0, (f[1] - v * r) / GRAVITY_M_S2)))

    def _process_sample(self, s: _ImuSample, prev: _ImuSample | None = None, visions=(), replayed=()) -> None:
        """Propagate from the previous sample to ``s``, applying the vision results that fall
        inside the interval at their own times, then the measurements of ``s``. ``replayed``:
        results applied before in this interval (a replay), merged in time order; they do not
        defer their roll again."""
        new = {id(v) for v in visions} if visions else ()
        visions = sorted((*visions, *replayed), key=_time_of) if replayed else visions
        s.applied = tuple(visions)
        prev = prev if prev is not None else (self._hist[-1] if self._hist else None)
        if prev is None:
            self._init_from_accel(s)
            s.gyro_dot, s.gyro_dot_dt = np.zeros(3), math.inf
            if self.record and self.start is not None:
                # a restart (restart()): a step whose Jacobian is zero, so that the smoother's
                # gain is zero across it and each side is smoothed on its own
                x0, P0 = self.ekf.x.copy(), self.ekf.P.copy()
                self.steps.append(StepRecord(s.t, np.zeros((DIM_X, DIM_X)), x0, P0, x0.copy(), P0.copy(), s.index))
            self._sample_updates(s)
        else:
            t0, g0 = prev.t, prev.gyro
            for v in visions:
                if v.t_s >= s.t:
                    continue  # at the sample's own time: applied after its measurements below
                tv = max(v.t_s, t0)   # a deferred roll that fell due before this interval: now
                g_v = prev.gyro + (s.gyro - prev.gyro) * (tv - prev.t) / (s.t - prev.t)
                self._propagate(t0, tv, (g0 + g_v) / 2, imu_index=-1)
                self._vision_update(v, id(v) in new)
                t0, g0 = tv, g_v
            s.gyro_dot_dt = s.t - prev.t
            s.gyro_dot = (s.gyro - prev.gyro) / s.gyro_dot_dt
            if self._speed_initialized and self._speed_rejected_in_row < self.options.reacquire_after_rejections:
                # the usual case: propagation, speed and gravity updates in one compiled call
                self._propagate(t0, s.t, (g0 + s.gyro) / 2, imu_index=s.index, sample=s)
            else:
                self._propagate(t0, s.t, (g0 + s.gyro) / 2, imu_index=s.index)
                self._sample_updates(s)
            if s.t - self._gravity_refused_since >= self.options.gravity_reacquire_after_s:   # (NaN: False)
                self._reacquire_gravity(s)
        ekf = self.ekf
        # At the sample's own time (or before the very first sample): after its IMU
        # measurements, in the same order as a late result would be applied.
        for v in visions:
            if prev is None or v.t_s >= s.t:
                self._vision_update(v, id(v) in new)
        s.x_post, s.P_post, s.roll_prop = ekf.x.copy(), ekf.P.copy(), self._roll_prop
        s.state = self._snapshot()
        if self.record:
            if prev is None and self.start is None:
                self.start = (s.x_post, s.P_post)
            else:
                self.steps[-1].x_post, self.steps[-1].P_post = s.x_post, s.P_post

    def _sample_updates(self, s: _ImuSample) -> None:
        """The measurements of sample ``s`` after the propagation to its time: wheel speed, then
        the gravity reference (which needs the speed for its centripetal term: not before the
        first one)."""
        speed_refused = self._speed_update(s.speed, s) if s.speed_fresh else False
        gravity_refused = (self._speed_initialized and s.index % self.options.gravity_every == 0
                           and not self.ekf.update_gravity(s.accel, s.gyro, s.gyro_dot, self._road_rate, s.r_scale,
                                                           s.gyro_dot_dt))
        self._tally(s, speed_refused, gravity_refused)

    def _tally(self, s: _ImuSample, speed_refused: bool, gravity_refused: bool) -> None:
        """Count sample ``s``'s refused updates once: a replay (late vision) replaces what its
        first pass counted instead of adding to it. And keep when the gravity updates attempted
        began to be refused in a row (``_gravity_refused_since``: :meth:`_reacquire_gravity`)."""
        if self._speed_initialized and s.index % self.options.gravity_every == 0:    # attempted
            if not gravity_refused:
                self._gravity_refused_since = math.nan
            elif math.isnan(self._gravity_refused_since):
                self._gravity_refused_since = s.t
        new = (int(speed_refused), int(gravity_refused))
        if new != s.refused:     # (most samples: nothing refused, then or now)
            self.counts["speed_rejected"] += new[0] - s.refused[0]
            self.counts["gravity_rejected"] += new[1] - s.refused[1]
            s.refused = new

    def _propagate(self, t0: float, t1: float, gyro, imu_index: int, sample: _ImuSample | None = None) -> None:
        """Propagate from ``t0`` to ``t1`` with the mean rate ``gyro``; with ``sample`` (the
        speed state initialised and not due for re-acquisition), also apply that sample's
        measurements (:meth:`_sample_updates`) in the same compiled call."""
        ekf = self.ekf
        if t1 <= t0:
            if sample is not None:
                self._sample_updates(sample)
            return
        offset, t_fit = self._lane_fit
        # no lane fit, or no wheel speed yet (the road's heading rate is kappa v): the road turns
        # with the vehicle. With v taken as 0 the road stood still while the gyros turned the
        # vehicle, and the vision's yaw pulled the world roll through the heading kinematics: 11
        # deg off with a sigma of 1.8 after 6 s without a wheel speed, every gravity update
        # refused from then on (a review)
        follow = t1 - t_fit > self.options.lane_fit_hold_s or not self._speed_initialized
        mapped = self._bank_rate_target(t1) if self._twist_map and self.options.bank_rate_map else math.nan
        u = ImuStep(t1 - t0, gyro, follow, offset, vision_gap=t1 - self._last_vision_t > _VISION_GAP_S,
                    bank_rate_target_rad_s=mapped)
        roll0 = ekf.x[S.ROLL_W]
        if sample is None:
            self._road_rate = ekf.propagate(u)
        else:
            gravity = sample.index % self.options.gravity_every == 0
            self._road_rate, ok_v, ok_g = ekf.propagate_and_update(
                u, sample.speed if sample.speed_fresh else math.nan, sample.accel, sample.gyro, sample.gyro_dot,
                gravity, sample.r_scale, sample.gyro_dot_dt)
            if sample.speed_fresh:
                if ok_v:
                    self._speed_rejected_in_row, self._speed_taken_t = 0, sample.t
                else:
                    self._speed_rejected_in_row += 1
            self._tally(sample, sample.speed_fresh and not ok_v, not ok_g)
        self._roll_prop += ekf.x_prior[S.ROLL_W] - roll0
        if self.record:
            self.steps.append(StepRecord(t1, ekf.F.copy(), ekf.x_prior.copy(), ekf.P_prior.copy(),
                                         ekf.x_prior.copy(), ekf.P_prior.copy(), imu_index))

    def _map_twist(self, m: VisionMeasurement, ahead_s: float) -> None:
        """Keep frame ``m``'s road twist as the bank rate of the road ``ahead_s`` ahead
        (:meth:`_bank_rate_target`): ``v (tau - turned) / cos(phi)``, the inverse of
        :meth:`fusion.ekf.AttitudeEKF.update_road_twist`'s model at the state of now."""
        x = self.ekf.x
        _, turned, phi = road_ahead_as_seen(x[S.BANK], x[S.CURVATURE], m.roll_lookahead_m, x[S.GRADE])
        rate = x[S.SPEED] * (m.road_twist_rad_m - turned) / math.cos(phi)
        due = m.t_s + ahead_s
        bisect.insort_right(self._twist_map, (due, rate, m.t_s))
        # what a replay can still reach (history_s back) needs the road from there on
        cut = m.t_s - 2.0 * self.options.history_s - _TWIST_SPAN_S
        # the medians of the patches this entry joins, or that lose entries to the cut below, are
        # taken anew (the memo's keys are entries' due times)
        memo, entries = self._patch_memo, self._twist_map
        if memo:
            lose = entries[:bisect.bisect_left(entries, (cut + 2.0 * _PATCH_S,))]
            near = entries[bisect.bisect_left(entries, (due - 2.0 * _PATCH_S,)):
                           bisect.bisect_right(entries, (due + 2.0 * _PATCH_S, math.inf, math.inf))]
            for e in (*lose, *near):
                memo.pop(e[0], None)
        old = bisect.bisect_left(entries, (cut,))
        if old:
            del entries[:old]
        # the segment _bank_rate_target keeps stands when this road is due beyond the patch of
        # its next road and the cut (roads due before it) left the patch of its last road whole:
        # the search never reaches them (kept at 1,471 of the 60 s drive's 1,571 frames)
        segment = self._segment_memo[3] if self._segment_memo is not None else None
        # (with no last road, the cut must leave the next one's patch whole: a review's case)
        if not (segment is not None and due > segment[2] + _PATCH_S
                and cut <= (segment[2] if segment[0] is None else segment[0]) - _PATCH_S):
            self._segment_memo = None

    def _bank_rate_target(self, t: float) -> float:
        """The bank rate the filter's Gauss-Markov rate reverts to at ``t``: the road's, from the
        twists the frames captured up to ``t`` measured ahead, linear between the last road
        reached and the next one, each the median of its patch (:meth:`_patch_rate`; with the two
        more than :data:`_TWIST_SPAN_S` apart, the next one's);
        0 within :attr:`fusion.noise.NoiseModel.bank_rate_map_deadband_rad_s` (steady road); NaN
        with none ahead (the rate decays as it did without the map). Frames captured at or
        before the last re-acquisition (``_map_from``) are left out."""
        memo = self._segment_memo
        if memo is not None and memo[0] < t < memo[1] and memo[2] == self._map_from:
            segment = memo[3]
        else:
            segment = self._map_segment(t)
        if segment is None:
            return math.nan
        t0, r0, t1, r1 = segment
        if t0 is None:
            r = r1
        else:
            r = r0 + (t - t0) / (t1 - t0) * (r1 - r0) if t1 > t0 else r1
        return r if abs(r) > self.options.noise.bank_rate_map_deadband_rad_s else 0.0

    def _map_segment(self, t: float) -> tuple | None:
        """The roads :meth:`_bank_rate_target` interpolates between at ``t``: ``(t0, r0, t1,
        r1)``, their due times and patch rates (``t0`` None: the next road's alone), or None with
        none ahead. Kept (``_segment_memo``) when every frame mapped was captured before ``t``:
        it is then the same for every time between the same two entries of the map (each
        capture before it, the same entries due before and after it): the search is then done
        once per segment (1,649 of the 60 s drive's 8,973 calls search)."""
        entries, since = self._twist_map, self._map_from
        n, j = len(entries), bisect.bisect_right(entries, (t, math.inf, math.inf))
        after, before = entries[j - 1][0] if j else -math.inf, entries[j][0] if j < n else math.inf
        i = j - 1
        # a frame captured at t or later is not mapped yet in a run in time: a replay's
        while j < n and not since < entries[j][2] < t:
            j += 1
        if j == n:
            segment = None
        else:
            while i >= 0 and not since < entries[i][2] < t:
                i -= 1
            t1, r1 = entries[j][0], self._patch_rate(entries[j][0], t)
            if i < 0 or t1 - entries[i][0] > _TWIST_SPAN_S:
                segment = (None, math.nan, t1, r1)
            else:
                segment = (entries[i][0], self._patch_rate(entries[i][0], t), t1, r1)
        newest = max(map(_captured, entries), default=-math.inf)
        if newest < t:
            self._segment_memo = (max(after, newest), before, since, segment)
        return segment

    def _patch_rate(self, due: float, t: float) -> float:
        """The median rate of the frames (captured before ``t``) that measured the road due within
        :data:`_PATCH_S` of ``due``: on dashed lines one road patch is measured by every frame of
        a dash, and the map's edges would otherwise take one frame's twist for the whole gap to
        the next patch (a review: one frame's twist 0.3 deg/m off moved the bank 2.5 deg)."""
        since = self._map_from
        memo = self._patch_memo.get(due)
        if memo is not None and memo[0] == since and memo[1] < t:
            return memo[2]      # the same patch, every frame of it captured before t
        lo = bisect.bisect_left(self._twist_map, (due - _PATCH_S,))
        hi = bisect.bisect_right(self._twist_map, (due + _PATCH_S, math.inf, math.inf))
        newest, r = -math.inf, []
        for _, rate, captured in self._twist_map[lo:hi]:     # (one pass: 3 generators cost 13 us)
            if since < captured:
                if captured > newest:
                    newest = captured
                if captured < t:
                    r.append(rate)
        r.sort()
        k = len(r)
        median = r[k // 2] if k % 2 else 0.5 * (r[k // 2 - 1] + r[k // 2])
        if newest < t:          # a run in time (a replay's earlier t leaves frames out)
            self._patch_memo[due] = (since, newest, median)
        return median

    def _speed_update(self, speed: float, s: _ImuSample) -> bool:
        """Sample ``s``'s wheel speed; the first one (and one after a run of rejections) sets
        the state; the first one after the start also the attitude relative to level
        (:meth:`_level_again`). Whether it was refused.

        The re-acquisition after ``reacquire_after_rejections`` refusals in a row is for a speed
        state that drifted; once the wheel has confirmed the state for :data:`SPEED_CONFIRMED_S`
        since it was set, a wheel speed further from it than :data:`SPEED_REACQUIRE_M_S`
        plus :data:`SPEED_DRIFT_M_S2` per second since the last one taken is the sensor's fault
        (no acceleration the accelerometer felt explains it): refused, before the gate, and
        counted (``counts["speed_implausible"]``), the speed carried on until the wheel agrees
        again."""
        ekf, n = self.ekf, self.options.noise
        if self._speed_initialized:
            n_due = self.options.reacquire_after_rejections
            # in a fault (refused in a row) of a state that the wheel confirmed since it was set
            # (SPEED_CONFIRMED_S): the bound before the gate, whose window the carried speed's
            # sigma widens (on a straight, where nothing else measures the speed, it took a wheel
            # stuck at 0 after 15 s, a review)
            if (self._speed_rejected_in_row >= n_due and self._speed_taken_t - self._speed_set_t >= SPEED_CONFIRMED_S
                    and abs(speed - ekf.x[S.SPEED]) > SPEED_REACQUIRE_M_S + SPEED_DRIFT_M_S2 * (s.t - self._speed_taken_t)):
                self._count_once(s, "speed_implausible")
                return True
            if ekf.update_speed(speed):
                self._speed_rejected_in_row, self._speed_taken_t = 0, s.t
                return False
            if self._speed_rejected_in_row < n_due:
                self._speed_rejected_in_row += 1
                return True
            self._count_once(s, "speed_reacquired")
        first_after_start = not self._speed_initialized and bool(self._hist)
        self._reset(((S.SPEED, speed, n.speed_meas_m_s), (S.ACCEL_X, 0.0, n.init_accel_m_s2)))
        self._speed_initialized, self._speed_rejected_in_row = True, 0
        self._speed_taken_t = self._speed_set_t = s.t
        if first_after_start:
            self._level_again(s, speed)
        return False

    def _count_once(self, s: _ImuSample, kind: str) -> None:
        """Count ``kind`` at sample ``s`` once: a replay (late vision) passes it again."""
        if kind not in s.counted:
            s.counted += (kind,)
            self.counts[kind] += 1

    def _vision_update(self, m: VisionMeasurement | RollAhead, first: bool = True) -> None:
        """Apply a vision result (``first``: not a replay of one applied before) or a deferred roll."""
        ekf = self.ekf
        if isinstance(m, RollAhead):
            turned = self._roll_prop - m.roll_prop_at_capture_rad
            ok = ekf.update_roll_ahead(m, turned)
            self.counts["roll_ahead_used" if ok else "roll_ahead_rejected"] += first
            if math.isfinite(m.twist_rad_m):
                tw_ok = ekf.update_road_twist(m.twist_rad_m, m.twist_sigma_rad_m, m.lookahead_m)
                self.counts["twist_used" if tw_ok else "twist_rejected"] += first
            self._roll_rejected_in_row = 0 if ok else self._roll_rejected_in_row + 1
            if self._roll_rejected_in_row >= self.options.reacquire_after_rejections:
                # the bank drifted away from what the vision sees: take it from the vision again
                n = self.options.noise
                seen, _, _ = road_ahead_as_seen(ekf.x[S.BANK], ekf.x[S.CURVATURE], m.lookahead_m, ekf.x[S.GRADE])
                predicted = vision_hx(ekf.x)[0] + ekf.x[S.BANK] - seen     # as update_roll_ahead has it
                bank = ekf.x[S.BANK] + wrap_angle(predicted - (m.roll_rad + turned))
                self._reset(((S.BANK, bank, n.init_bank_rad), (S.BANK_RATE, 0.0, n.init_bank_rate_rad_s)))
                self._map_from = m.t_s     # its due time: the rates mapped by now were at the old bank
                self.counts["roll_ahead_reacquired"] += first
                ekf.update_roll_ahead(m, turned)
                self._roll_rejected_in_row = 0
            if self.record and self.steps:
                self.steps[-1].x_post, self.steps[-1].P_post = ekf.x.copy(), ekf.P.copy()
            return
        t, angles, kappa, offset = m.t_s, m.angles_rad, m.curvature_1_m, m.lateral_offset_m
        v = ekf.x[S.SPEED]
        # Vision back after a gap longer than the deferral: no deferred roll is on its way, the
        # bank's sigma has grown to degrees, and for the next L / v (0.5-0.8 s) only pitch and
        # yaw would come in, moving the bank within that sigma (roll 0.39 deg off on steady road
        # after 5 s without lanes, measured). The first frame back is taken as the first frame
        # is, its roll at capture as the bank ahead, after its twist as the bank rate; until the
        # first deferred roll is due the frames' twists are applied at capture (the rate ahead
        # for the rate here), not again with their rolls.
        # (A gap longer than L / v: every roll from before it has been applied.) A replay of
        # late results (_apply_late) takes the first pass's decisions: a late result from before
        # this one can end a gap that the first pass saw, and deciding again to defer the roll
        # would lose it (its RollAhead is queued only once, by the first pass), or apply the
        # twist a second time.
        decided = None if first else self._decisions.get(id(m))
        if decided is None:
            ahead_s = m.roll_lookahead_m / v if v > 1.0 and m.roll_lookahead_m > 0.0 else 0.0
            resumed = t - self._last_vision_t > max(_VISION_GAP_S, ahead_s)
            defer = (self.options.defer_roll and m.roll_lookahead_m > 0.0 and v > 1.0 and self._vision_initialized
                     and not resumed)
            twist_now = (self.options.defer_roll and self._vision_initialized and math.isfinite(m.road_twist_rad_m)
                         and (resumed or (defer and t < self._roll_hole_until)))
            self._decisions[id(m)] = (ahead_s, resumed, defer, twist_now)
        else:
            ahead_s, resumed, defer, twist_now = decided
        if resumed:
            self._roll_hole_until = t + ahead_s
        if twist_now:
            tw_ok = ekf.update_road_twist(m.road_twist_rad_m, m.road_twist_sigma_rad_m, m.roll_lookahead_m)
            self.counts["twist_used" if tw_ok else "twist_rejected"] += first
        if first and (defer or twist_now) and ahead_s > 0.0 and math.isfinite(m.road_twist_rad_m):
            self._map_twist(m, ahead_s)
        rate_ahead = 0.0
        if defer:
            dt_ahead = ahead_s
            # the bank the vision roll says is ahead, against the bank here
            rate_ahead = (ekf.x[S.ROLL_W] - angles[0] - ekf.x[S.BANK]) / dt_ahead
            n = self.options.noise
            if n.bank_rate_preview_gain > 0.0:
                ekf.set_bank_rate_sigma(max(n.bank_rate_preview_floor_rad_s,
                                            n.bank_rate_preview_gain * abs(rate_ahead),
                                            n.bank_rate_preview_gain * abs(ekf.x[S.BANK_RATE])))
            if first:
                bisect.insort_right(self._pending, RollAhead(t + dt_ahead, float(angles[0]), float(m.sigmas_rad[0]),
                                                             dt_ahead, self._roll_prop,
                                                             math.nan if twist_now else m.road_twist_rad_m,
                                                             m.road_twist_sigma_rad_m, m.roll_lookahead_m),
                                    key=_time_of)
        self._lane_fit = (offset if math.isfinite(offset) else 0.0, t)
        if not self._vision_initialized:
            # First frame: take yaw, bank and grade from it so that the filter starts consistent:
            # bank = roll_w - roll and grade = pitch_w - pitch, correlated with roll_w and pitch_w
            # as that makes them (a start without a wheel speed: 25 deg, _init_from_accel), the
            # angles relative to the road with the bank's and grade's prior variance; the update
            # below then takes the frame once. A prior of their own said the bank was known to
            # 5 deg when the world roll was 40 deg off (tests/test_fusion_filter.py::
            # test_a_start_in_a_hard_corner).
            ekf.x[S.YAW_REL] = angles[2]
            ekf.x[S.BANK] = ekf.x[S.ROLL_W] - angles[0]
            ekf.x[S.GRADE] = ekf.x[S.PITCH_W] - angles[1]
            n = self.options.noise
            for road, level, prior in ((S.BANK, S.ROLL_W, n.init_bank_rad), (S.GRADE, S.PITCH_W, n.init_grade_rad)):
                ekf.P[road, :] = ekf.P[level, :]
                ekf.P[:, road] = ekf.P[:, level]
                ekf.P[road, road] = ekf.P[level, level] + prior**2
            if math.isfinite(kappa):   # the fit's is the road plane's, at the bank just taken
                ekf.x[S.CURVATURE] = curvature_from_lane_fit(ekf.x, kappa)
            self._vision_initialized = True
        if ekf.update_vision(m, defer_roll=defer, bank_rate_ahead=rate_ahead):
            self.counts["vision_used"] += first
            self._last_vision_t = t
            self._rejected_in_row = 0
        else:
            self.counts["vision_rejected"] += first
            self._rejected_in_row += 1
            if self._rejected_in_row >= self.options.reacquire_after_rejections:
                self._reacquire(angles, kappa, bank=not defer)
                self._map_from = t      # this frame's rate too was mapped at the diverged state
                self.counts["vision_reacquired"] += first
                if ekf.update_vision(m, defer_roll=defer, bank_rate_ahead=rate_ahead):
                    # used after all: counted once, as used (it had counted as rejected too, used
                    # + rejected + invalid one more than the frames, a review)
                    self.counts["vision_used"] += first
                    self.counts["vision_rejected"] -= first
                    self._last_vision_t = t
                self._rejected_in_row = 0
        if self.record and self.steps:
            self.steps[-1].x_post, self.steps[-1].P_post = ekf.x.copy(), ekf.P.copy()

    def _reacquire(self, angles, kappa: float = math.nan, bank: bool = True) -> None:
        """Reset the road states to agree with ``angles`` and reopen their covariance; the bank
        only with ``bank`` (with the roll deferred, the rejected updates did not measure it: it
        has its own re-acquisition from the deferred rolls)."""
        ekf, n = self.ekf, self.options.noise
        x = ekf.x
        states = [(S.YAW_REL, angles[2], n.init_angle_rad), (S.GRADE, x[S.PITCH_W] - angles[1], n.init_grade_rad),
                  (S.GRADE_RATE, 0.0, n.init_grade_rate_rad_s)]
        if bank:
            states += [(S.BANK, x[S.ROLL_W] - angles[0], n.init_bank_rad), (S.BANK_RATE, 0.0, n.init_bank_rate_rad_s)]
        self._reset(tuple(states))
        # the fit's curvature is the road plane's: the state's at the bank and grade rate just reset
        kappa_state = curvature_from_lane_fit(x, kappa) if math.isfinite(kappa) else x[S.CURVATURE]
        self._reset(((S.CURVATURE, kappa_state, n.init_curvature_1_m),))

    def _level_again(self, s: _ImuSample, v: float) -> None:
        """The first wheel speed after the start: the world roll from this sample's specific
        force with the centripetal term taken out (:meth:`_level_roll`, as the start does with a
        speed), the bank moved with it so that the roll relative to the road stays the
        vision's, and their common direction reopened to the starting sigma. Before the speed
        the gravity reference waits, and on a leaning motorcycle nothing measures the world
        roll; the vision's pitch and yaw, coupled to it through the bank, had taken it 18 deg
        off with a sigma of 2.3 deg after 6 s without a wheel speed, and every gravity update
        after it was refused as an outlier (a review found it). The pitch keeps its estimate:
        the accelerometer measured it all along (at constant speed), and one sample's
        ``-f_x / g``, with the rider's pitching in it, set the IMU-only filter off by 19 deg."""
        if not self._levels(s):
            return          # the roll keeps the start's sigma; the gravity updates bring it in
        self._level(s, v)

    def _level(self, s: _ImuSample, v: float, pitch: bool = False) -> None:
        """The world roll (and with ``pitch`` the pitch) from sample ``s``'s specific force at
        speed ``v`` (:meth:`_level_roll`, :meth:`_level_pitch`), the bank (the grade) moved with
        it, so that the angles relative to the road stay, and their common direction reopened to
        the starting sigma; a part of the last step's prediction for the smoother."""
        ekf, n = self.ekf, self.options.noise
        e = np.zeros(DIM_X)
        e[[S.ROLL_W, S.BANK]] = 1.0
        shift, grow = (self._level_roll(s, v) - ekf.x[S.ROLL_W]) * e, n.init_angle_rad**2 * np.outer(e, e)
        if pitch:
            e = np.zeros(DIM_X)
            e[[S.PITCH_W, S.GRADE]] = 1.0
            shift += (self._level_pitch(s) - ekf.x[S.PITCH_W]) * e
            grow += n.init_angle_rad**2 * np.outer(e, e)

        def level(x, P):
            x += shift
            P += grow

        level(ekf.x, ekf.P)
        if self.record and self.steps:      # part of the last step's prediction, as _reset's
            st = self.steps[-1]
            st.x_prior, st.P_prior = st.x_prior.copy(), st.P_prior.copy()
            level(st.x_prior, st.P_prior)

    def _reacquire_gravity(self, s: _ImuSample) -> None:
        """Every gravity update refused for ``options.gravity_reacquire_after_s``: the world roll
        and pitch from sample ``s``'s specific force again (:meth:`_level`; from the next sample
        that can level the filter, if this one cannot), counted once per sample
        (``counts["gravity_reacquired"]``; a replay does not count it again). The gate cannot
        tell a gyro glitch that turned the attitude (a zeroed CAN frame reads -164 deg/s on each
        axis: 16 deg in 0.1 s) from a bad accelerometer; the accelerometer that kept disagreeing
        for a second is the one to believe, as the vision's and the speed's re-acquisitions do."""
        if not self._levels(s):
            return
        self._level(s, self.ekf.x[S.SPEED], pitch=True)
        self._gravity_refused_since = math.nan
        # The glitch turned the heading too: the yaw relative to the road is reopened and the
        # next frame sets the road's states again as the first one does (yaw, bank and grade
        # from the new world attitude). Left as it was (16 deg off, its sigma 0.3), its error
        # reached the gravity model's path direction and the vision's coupling: every gravity
        # update was refused again and the frames took the world roll back 12 deg in 0.3 s.
        # The deferred rolls are carried to the road under the wheels by the roll the gyros
        # turned since their capture (RollAhead), which the glitch spoilt: dropped.
        self._reset(((S.YAW_REL, self.ekf.x[S.YAW_REL], self.options.noise.init_angle_rad),))
        self._vision_initialized = False
        self._drop_pending(lambda p: isinstance(p, RollAhead))
        self._last_vision_t = -math.inf
        self._count_once(s, "gravity_reacquired")

    def _reset(self, states) -> None:
        """Give states ``(index, value, sigma)`` new values, uncorrelated with the rest.

        For the smoother the reset is part of the last step's prediction: a new value
        independent of the past. That step's prior takes the reset values and variances and its
        Jacobian loses the rows of the reset states, so that the smoother carries no
        information backwards across the reset (otherwise the jump of the reset is read as a
        measurement and smeared over the seconds before it).
        """
        def reset(x, P):
            for i, value, sig in states:
                x[i] = value
                P[i, :] = 0.0
                P[:, i] = 0.0
                P[i, i] = sig**2

        reset(self.ekf.x, self.ekf.P)
        if self.record and self.steps:
            st = self.steps[-1]
            st.x_prior, st.P_prior, st.F = st.x_prior.copy(), st.P_prior.copy(), st.F.copy()
            reset(st.x_prior, st.P_prior)
            st.F[[i for i, _, _ in states], :] = 0.0

    def _snapshot(self) -> tuple:
        """What besides the filter's x and P the next steps depend on: the re-acquisition
        counters and flags, the last lane fit and vision time, the road's turn rate, the
        scheduled bank-rate noise. A replay starts from the base sample's (a replay that kept the
        newest, e.g. the wheel speed initialised, would gate the speed against a state of 0 m/s
        and reject it sample after sample)."""
        ekf = self.ekf
        return (self._vision_initialized, self._lane_fit, self._last_vision_t, self._roll_hole_until, self._road_rate,
                self._rejected_in_row, self._speed_initialized, self._speed_rejected_in_row, self._roll_rejected_in_row,
                ekf._bank_rate_scheduled, float(ekf._q_scheduled[S.BANK_RATE]), self._map_from,
                self._gravity_refused_since, self._speed_taken_t, self._speed_set_t)

    def _restore(self, state: tuple) -> None:
        ekf = self.ekf
        (self._vision_initialized, self._lane_fit, self._last_vision_t, self._roll_hole_until, self._road_rate,
         self._rejected_in_row,
         self._speed_initialized, self._speed_rejected_in_row, self._roll_rejected_in_row,
         ekf._bank_rate_scheduled, ekf._q_scheduled[S.BANK_RATE], self._map_from,
         self._gravity_refused_since, self._speed_taken_t, self._speed_set_t) = state

    def _apply_late(self, item: VisionMeasurement) -> None:
        """A vision result at or before the newest IMU time: roll back to the sample before it
        and re-propagate the stored samples after it."""
        hist, t = self._hist, item.t_s
        if not hist or t < hist[0].t:
            self.counts["vision_too_old"] += 1
            return
        k = len(hist) - 1
        while k > 0 and hist[k].t > t:
            k -= 1
        base, replay = hist[k], list(hist)[k + 1:]
        if replay and self.record:
            raise ValueError("late vision result with record=True: feed inputs in time order")
        self.ekf.x, self.ekf.P = base.x_post.copy(), base.P_post.copy()
        self._roll_prop = base.roll_prop
        self._restore(base.state)
        if not replay:  # exactly at the newest sample's time
            self._vision_update(item)
            base.applied = (*base.applied, item)
            base.x_post, base.P_post = self.ekf.x.copy(), self.ekf.P.copy()
            base.state = self._snapshot()
            return
        prev = base
        for i, s in enumerate(replay):
            # the deferred rolls this replay queued (the late result's own) that fall due inside
            # it, at their due time as in a run in time: they waited for the next sample and were
            # applied at its interval's start (a review: results 0.7 / 0.9 s late put the roll
            # 0.21 / 0.37 deg RMS off, 14 / 27 sigma at worst, where in time it is 0.045)
            k = bisect.bisect_right(self._pending, s.t, key=_time_of)
            due = self._pending[:k]
            if k:
                del self._pending[:k]
            self._process_sample(s, prev=prev, visions=[item, *due] if i == 0 else due, replayed=s.applied)
            prev = s

    # ---- outputs ----

    @property
    def t_s(self) -> float:
        return self._hist[-1].t if self._hist else math.nan

    @property
    def speed_known(self) -> bool:
        """Whether a wheel speed has set the speed state (before it, the state is 0 m/s)."""
        return self._speed_initialized

    def estimate(self) -> Estimate:
        """The latest estimate (after the newest IMU sample). Before the first wheel speed the
        speed and the gravity-referenced angles (world roll and pitch, grade, bank) are NaN: the
        gravity reference needs the speed for its centripetal term and waits for it, and
        without it the filter's sigma of those angles shrinks on weak couplings while they
        drift (a review fed a drive without its speed message: world roll 36 deg against 14,
        sigma 1.7). The angles relative to the road rest on the vision and stay. Before the
        first IMU sample (of the stream, or since a restart) there is no estimate: ``t_s``, the
        angles, their sigmas and the covariance are NaN, the IMU biases (what a restart keeps)
        are given (a review: roll 0 +- 7 deg was given at time NaN, the filter's prior, which a
        caller could take for an estimate)."""
        if not self._hist:
            est = estimate_from(math.nan, self.ekf.x, self.ekf.P, math.nan, self.ekf.has_pitch_rate)
            nan = math.nan
            return replace(est, **{f.name: nan for f in fields(Estimate)
                                   if f.name not in ("gyro_bias_rad_s", "cov_rpyb_rad2")},
                           cov_rpyb_rad2=np.full((4, 4), nan))
        est = estimate_from(self.t_s, self.ekf.x, self.ekf.P, self.t_s - self._last_vision_t, self.ekf.has_pitch_rate)
        if self._speed_initialized:
            return est
        nan = math.nan
        cov = est.cov_rpyb_rad2.copy()
        cov[3, :] = cov[:, 3] = nan
        return replace(est, speed_m_s=nan, bank_rad=nan, bank_sigma_rad=nan, roll_world_rad=nan,
                       roll_world_sigma_rad=nan, pitch_world_rad=nan, pitch_world_sigma_rad=nan, grade_rad=nan,
                       grade_sigma_rad=nan, speed_sigma_m_s=nan, cov_rpyb_rad2=cov)


def estimate_from(t_s: float, x: np.ndarray, P: np.ndarray, vision_age_s: float = math.nan,
                  has_pitch_rate: bool = True) -> Estimate:
    """Outputs of state ``x`` with covariance ``P`` (without a pitch gyro, no bias of it: NaN)."""
    rel, cov = (a[0] for a in relative_outputs(np.ascontiguousarray(x)[None], np.ascontiguousarray(P)[None]))
    sig = np.sqrt(np.maximum(np.diag(cov)[:3], 0.0))
    d = np.sqrt(np.maximum(np.diag(P), 0.0))
    return Estimate(
        t_s=t_s, roll_rad=rel[0], pitch_rad=rel[1], yaw_rad=rel[2], bank_rad=x[S.BANK],
        roll_world_rad=x[S.ROLL_W], pitch_world_rad=x[S.PITCH_W], grade_rad=x[S.GRADE],
        roll_sigma_rad=sig[0], pitch_sigma_rad=sig[1], yaw_sigma_rad=sig[2], bank_sigma_rad=d[S.BANK],
        roll_world_sigma_rad=d[S.ROLL_W], pitch_world_sigma_rad=d[S.PITCH_W],
        gyro_bias_rad_s=(x[S.GYRO_BIAS_X], x[S.GYRO_BIAS_Y] if has_pitch_rate else math.nan, x[S.GYRO_BIAS_Z]),
        speed_m_s=x[S.SPEED], vision_age_s=vision_age_s, grade_sigma_rad=d[S.GRADE], speed_sigma_m_s=d[S.SPEED],
        cov_rpyb_rad2=cov,
    )
