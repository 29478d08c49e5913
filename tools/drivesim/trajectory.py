"""Vehicle motion on the road, its exact attitude, and the kinematics an IMU would sense.

The contact point follows the road at station ``s(t)`` (from the speed profile) and lateral
offset ``d(s)`` (base offset plus manoeuvres, septic smoothsteps so that the lateral
jerk, hence the roll rate, is continuous). The attitude relative to the local road frame
``o`` at the contact point is ``R_o_from_v = Rz(yaw) Ry(pitch) Rx(roll)`` with

* yaw: the heading of the contact point's velocity in the road plane (no side slip), less,
  with a wheelbase ``L`` (``Motion.wheelbase_m``), ``asin(L k_p)`` with ``k_p`` the curvature
  of the contact point's path in the road plane: the body points along the chord from the rear
  contact to the front one (the contact point followed is the front wheel's, the contract's
  origin of ``v``), and the rear wheel, which is not steered, rolls without side slip. In a
  steady turn this is exact (the rear contact on the circle of radius ``sqrt(R^2 - L^2)``, the
  chord at ``asin(L / R)`` behind the tangent: nose right in a left turn, negative yaw); where
  the curvature changes it is the quasi-static chord, the rear wheel slipping by about
  ``L^2 dk_p/ds`` (measured for 1.45 m: 0.012 deg at most in the test road's clothoids, 0.07 deg
  in a double lane change; ``tests/test_simulator.py``). ``L = 0`` is the body along the
  velocity, as every drive had it before the wheelbase was modelled;
* pitch: a suspension oscillation plus a nose-down term proportional to deceleration;
* roll, motorcycle: the lean that keeps the specific force ``f = a + g z_w`` of the contact
  point's path in the vehicle's plane of symmetry, ``y_v . f = 0``. With
  ``M = R_w_from_o Rz(yaw) Ry(pitch)``, ``y_v = cos(roll) M e_y + sin(roll) M e_z``, so
  ``roll = atan2(-(M e_y) . f, (M e_z) . f)``: in a steady level turn ``tan(roll_world) =
  v^2 k / g``;
* roll, car: the body follows the road plane, plus a roll gradient times the lateral
  acceleration (outward, i.e. positive roll in a left turn).

The IMU's angular rate is the derivative of the rotation, ``w = log(R(t-h)^T R(t+h)) / 2h``,
and its specific force is ``R^T (d2/dt2 (p + R r) + g z_w)`` at the lever arm ``r``: both
differentiated from the same trajectory, never reusing the attitude angles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vision.frames import R_from_rpy, Rz, Ry, rpy_from_R, so3_log

from .road import Road, smooth7

__all__ = ["GRAVITY_M_S2", "MAX_CAR_SIDE_GRIP", "MAX_LEAN_DEG", "Manoeuvre", "Motion", "Trajectory"]

GRAVITY_M_S2 = 9.80665
#: The largest lean of the simulated motorcycle relative to the road, deg. Its lean balances the
#: side force its tyres take: a lean of 60 deg is tan(60 deg) = 1.73 times their load, about what
#: racing slicks hold on dry asphalt (road tyres 1.0-1.3), and a road motorcycle grounds its
#: footpegs before that. A scenario leaning further is no motorcycle's drive (a review's 200 km/h
#: on a 50 m radius leaned 81 deg, 400 km/h on 5 m 85-101 deg).
MAX_LEAN_DEG = 60.0
#: The largest side force a car's tyres take, as a fraction of their load (:meth:`Trajectory.side_grip`):
#: road tyres on dry asphalt hold about 1 g of lateral acceleration on a level road.
MAX_CAR_SIDE_GRIP = 1.0


@dataclass(frozen=True)
class Manoeuvre:
    """A lateral manoeuvre, placed by station.

    kind : "lane_change" | "double_lane_change" | "weave"
    start_m : station where it begins, m
    length_m : length of one lateral transition (or the weave's wavelength), m
    shift_m : lateral shift, m, positive to the left (lane changes), or amplitude (weave)
    hold_m : distance held in the other lane (double lane change), m
    repeat : how many times (double lane change and lane change), every ``period_m``
    """

    kind: str
    start_m: float
    length_m: float
    shift_m: float = 3.5
    hold_m: float = 30.0
    repeat: int = 1
    period_m: float = 0.0

    def offset(self, s):
        s = np.asarray(s, dtype=float)
        out = np.zeros_like(s)
        for n in range(self.repeat):
            x = s - self.start_m - n * self.period_m
            if self.kind == "lane_change":
                out += self.shift_m * smooth7(x / self.length_m)
            elif self.kind == "double_lane_change":
                out += self.shift_m * (smooth7(x / self.length_m)
                                       - smooth7((x - self.length_m - self.hold_m) / self.length_m))
            elif self.kind == "weave":
                # One sine period per wavelength, with a one-wavelength smooth fade in and out.
                span = self.hold_m
                env = smooth7(x / self.length_m) * smooth7((span - x) / self.length_m)
                out += self.shift_m * env * np.sin(2 * np.pi * x / self.length_m)
            else:
                raise ValueError(f"unknown manoeuvre kind {self.kind!r}")
        return out


@dataclass(frozen=True)
class Motion:
    """How the vehicle moves; see the module docstring.

    ``speed_kmh`` is a constant speed or, with ``speed_profile``, knots ``[(t_s, kmh), ...]``
    joined by septic smoothsteps (C3: the pitch that follows the deceleration turns smoothly).
    """

    vehicle: str = "motorcycle"
    speed_kmh: float = 100.0
    speed_profile: tuple[tuple[float, float], ...] = ()
    start_station_m: float = 20.0
    lateral_offset_m: float = -1.75
    manoeuvres: tuple[Manoeuvre, ...] = ()
    pitch_amplitude_deg: float = 0.3
    pitch_frequency_hz: float = 1.3
    pitch_phase_deg: float = 0.0
    pitch_per_decel_deg: float = 0.3   # deg of nose-down per m/s^2 of deceleration
    car_roll_gain_deg: float = 0.5     # deg of body roll per m/s^2 of lateral specific force across the road (car)
    wheelbase_m: float = 0.0           # rear to front contact point, m; 0: the body along the velocity
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.vehicle not in ("motorcycle", "car"):
            raise ValueError(f'vehicle must be "motorcycle" or "car", got {self.vehicle!r}')


class Trajectory:
    """Exact pose of the vehicle at any time; vectorised over arrays of ``t_s``."""

    def __init__(self, road: Road, motion: Motion) -> None:
        self.road, self.motion = road, motion
        knots = motion.speed_profile or ((0.0, motion.speed_kmh),)
        self._t = np.array([k[0] for k in knots], dtype=float)
        self._v = np.array([k[1] for k in knots], dtype=float) / 3.6
        if np.any(np.diff(self._t) <= 0):
            raise ValueError("speed_profile times must increase")
        # Station at each knot, for the closed-form integral of the smoothstep segments.
        self._s = np.concatenate([[motion.start_station_m],
                                  motion.start_station_m + np.cumsum(np.diff(self._t) * (self._v[:-1] + self._v[1:]) / 2)])

    # ---- path ----

    def speed_m_s(self, t):
        t = np.asarray(t, dtype=float)
        v = np.full(t.shape, self._v[0])
        for i in range(len(self._t) - 1):
            t0, t1, v0, v1 = self._t[i], self._t[i + 1], self._v[i], self._v[i + 1]
            x = np.clip((t - t0) / (t1 - t0), 0, 1)
            # the septic smoothstep: with the cubic one the jerk stepped at each knot, the pitch
            # (which follows the deceleration) turned its rate in one step, and through the IMU's
            # lever arm that was a one-sample spike of the specific force (6.7 m/s^2 at a 0.5 m
            # arm braking from 72 to 36 km/h in 2 s; a review): now C3, the pitch rate smooth
            v = np.where(t >= t0, v0 + (v1 - v0) * smooth7(x), v)
        return v

    def station_m(self, t):
        """``s(t) = start + integral of the speed profile`` (closed form)."""
        t = np.asarray(t, dtype=float)
        s = self._s[0] + self._v[0] * (t - self._t[0])  # before the first knot (and single knot)
        for i in range(len(self._t) - 1):
            t0, t1, v0, v1 = self._t[i], self._t[i + 1], self._v[i], self._v[i + 1]
            T = t1 - t0
            x = np.clip((t - t0) / T, 0, 1)
            # integral of v0 + (v1-v0)(35x^4 - 84x^5 + 70x^6 - 20x^7) dt
            #   = T (v0 x + (v1-v0)(7x^5 - 14x^6 + 10x^7 - 2.5x^8))
            inside = self._s[i] + T * (v0 * x + (v1 - v0) * x**5 * (7.0 - 14.0 * x + 10.0 * x**2 - 2.5 * x**3))
            after = self._s[i + 1] + v1 * (t - t1)
            s = np.where(t >= t0, np.where(t <= t1, inside, after), s)
        return s

    def offset_m(self, s):
        s = np.asarray(s, dtype=float)
        d = np.full(s.shape, self.motion.lateral_offset_m)
        for m in self.motion.manoeuvres:
            d = d + m.offset(s)
        return d

    def contact(self, t):
        """Contact point in the world frame ``(..., 3)``."""
        s = self.station_m(t)
        return self.road.surface(s, self.offset_m(s))

    @staticmethod
    def _d1(f, t, h):
        return (f(t - 2 * h) - 8 * f(t - h) + 8 * f(t + h) - f(t + 2 * h)) / (12 * h)

    @staticmethod
    def _d2(f, t, h):
        return (-f(t - 2 * h) + 16 * f(t - h) - 30 * f(t) + 16 * f(t + h) - f(t + 2 * h)) / (12 * h * h)

    # ---- attitude ----

    def pitch_rad(self, t, accel_long_m_s2):
        m = self.motion
        osc = math.radians(m.pitch_amplitude_deg) * np.sin(
            2 * np.pi * m.pitch_frequency_hz * np.asarray(t) + math.radians(m.pitch_phase_deg))
        return osc - math.radians(m.pitch_per_decel_deg) * accel_long_m_s2

    def pose(self, t):
        """Everything about the vehicle at times ``t``.

        Returns a dict of arrays: ``P_w`` contact point (m), ``V_w``, ``A_w`` its velocity and
        acceleration, ``R_w_from_o`` local road frame, ``R_w_from_v``, ``roll/pitch/yaw``
        relative to the road (rad), ``s``, ``d``.
        """
        t = np.asarray(t, dtype=float)
        s = self.station_m(t)
        d = self.offset_m(s)
        P = self.road.surface(s, d)
        V = self._d1(self.contact, t, 1e-3)
        A = self._d2(self.contact, t, 5e-3)
        R_w_from_o = self.road.frame(s, d)
        x_o, y_o = R_w_from_o[..., 0], R_w_from_o[..., 1]
        yaw = np.arctan2(np.sum(V * y_o, -1), np.sum(V * x_o, -1))
        speed = np.linalg.norm(V, axis=-1)
        if self.motion.wheelbase_m > 0.0:
            # the path's curvature in the road plane, (V x A) . z_o / |V|^3, positive to the left
            k_p = np.sum(np.cross(V, A) * R_w_from_o[..., 2], -1) / np.maximum(speed, 1e-6) ** 3
            yaw = yaw - np.arcsin(np.clip(self.motion.wheelbase_m * k_p, -1.0, 1.0))
        a_long = np.sum(A * V, -1) / np.maximum(speed, 1e-6)
        pitch = self.pitch_rad(t, a_long)
        M = R_w_from_o @ Rz(yaw) @ Ry(pitch)
        f = A + np.array([0.0, 0.0, GRAVITY_M_S2])     # the specific force at the contact point
        if self.motion.vehicle == "motorcycle":
            roll = np.arctan2(-np.sum(M[..., 1] * f, -1), np.sum(M[..., 2] * f, -1))
        else:
            # the body rolls on its springs with the lateral force the tyres take, across the
            # road: the turn's acceleration and gravity's part down a banked road (with the
            # acceleration alone a car standing on a 5 deg bank did not roll, and on a banked
            # curve its roll was 0.43 deg off; a review)
            roll = math.radians(self.motion.car_roll_gain_deg) * np.sum(f * y_o, -1)
        R_w_from_v = M @ R_from_rpy(roll, 0.0, 0.0)
        return dict(t=t, s=s, d=d, P_w=P, V_w=V, A_w=A, speed_m_s=speed, R_w_from_o=R_w_from_o,
                    R_w_from_v=R_w_from_v, roll=roll, pitch=pitch, yaw=yaw)

    def R_w_from_v(self, t):
        return self.pose(t)["R_w_from_v"]

    def side_grip(self, t):
        """The side force the tyres take as a fraction of their load: ``(f . y_o) / (f . z_o)``,
        the specific force ``f = a + g z_w`` of the contact point's path across the road over
        that along the road's normal (positive to the left; ``inf`` where the road does not
        carry the vehicle, ``f . z_o <= 0``). ``v^2 k / g`` in a steady turn on a level road; a
        bank towards the turn's centre lowers it."""
        pose = self.pose(t)
        f = pose["A_w"] + np.array([0.0, 0.0, GRAVITY_M_S2])
        across, normal = np.sum(f * pose["R_w_from_o"][..., 1], -1), np.sum(f * pose["R_w_from_o"][..., 2], -1)
        return np.where(normal > 0, across / np.where(normal > 0, normal, 1.0), np.inf)

    def body_rate_rad_s(self, t, h=1e-3):
        """Angular rate of ``v`` relative to the world, in ``v``: ``log(R(t-h)^T R(t+h)) / 2h``."""
        Ra, Rb = self.R_w_from_v(np.asarray(t) - h), self.R_w_from_v(np.asarray(t) + h)
        return so3_log(np.swapaxes(Ra, -1, -2) @ Rb) / (2 * h)

    def specific_force_m_s2(self, t, lever_arm_v_m, h=5e-3):
        """Specific force at the lever arm, in ``v``: ``R^T (d2/dt2 (P + R r) + g z)``."""
        r = np.asarray(lever_arm_v_m, dtype=float)

        def p_imu(tt):
            pose = self.pose(tt)
            return pose["P_w"] + pose["R_w_from_v"] @ r

        a = self._d2(p_imu, np.asarray(t, dtype=float), h)
        R = self.R_w_from_v(t)
        return np.einsum("...ji,...j->...i", R, a + np.array([0.0, 0.0, GRAVITY_M_S2]))

    def truth(self, t):
        """Truth table columns (rad, m, m/s) at times ``t``: the contract's angles plus extras."""
        pose = self.pose(t)
        R_w_from_o = pose["R_w_from_o"]
        bank, road_pitch, road_heading = rpy_from_R(R_w_from_o)
        roll_w, pitch_w, yaw_w = rpy_from_R(pose["R_w_from_v"])
        return dict(
            roll=pose["roll"], pitch=pose["pitch"], yaw=pose["yaw"], bank=bank,
            roll_world=roll_w, pitch_world=pitch_w, yaw_world=yaw_w, road_pitch=road_pitch,
            road_heading=road_heading, station_m=pose["s"], lateral_offset_m=pose["d"],
            speed_m_s=pose["speed_m_s"], curvature_1_m=self.road.curvature_1_m(pose["s"]),
        )
