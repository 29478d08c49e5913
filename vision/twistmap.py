"""The road's twist ahead of the vehicle, carried from frame to frame with the distance travelled.

In a superelevation runoff the road turns about its centre line ahead of the vehicle, and a
planar (or vertically curved) road surface reads the twisted lanes as degrees of roll, pitch and
yaw error (``tools/vision_surface_oracle.py``). One frame measures the twist only where its
three lines overlap, the cross-sections (:func:`vision.estimator._road_twist`: 7 to 22 m ahead,
one dash of the centre line at a time); the road between the vehicle and there was measured by
the frames before, when it was farther ahead. This map keeps those measurements along the road,
moved by the distance travelled between frames (from the wheel speed: the estimator cannot see
it), and gives the estimator the bank change ahead, ``b(u)``, the twist integrated from the
contact point, for its projection (:class:`vision.ipm.RoadTwist`).

Model: the twist along the road is a uniform cubic B-spline with knots every :data:`KNOT_M`
fixed to the road, its coefficients a random walk from knot to knot (1-sigma
``step_sigma`` per knot: a runoff seen ahead goes on ramping, within what runoffs do), kept
with their joint covariance over the road from behind the vehicle to :data:`AHEAD_M` ahead. A
frame's cross-sections measure the mean twist over their span, a scalar Kalman update, gated
at ``gate_sigma`` against what the map expects there (a dash leaving the cross-sections can
throw the twist of a short span off by 0.1 deg/m). With the true twist in the map the
estimator's yaw in the simulator's runoffs is within 0.07 deg RMS (0.9 deg on an untwisted
road).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .ipm import RoadTwist

__all__ = ["TwistMap", "KNOT_M", "AHEAD_M", "MAX_FRAME_GAP_S", "travel_between"]

#: Knot spacing of the twist along the road, m (runoffs change their twist over 10-30 m).
KNOT_M = 4.0
#: How far ahead the map reaches (the projection holds the twist there beyond), m.
AHEAD_M = 60.0
#: Grid of the profile handed to the projection, m.
_PROFILE_STEP_M = 0.5
_PROFILE_U = np.arange(0.0, AHEAD_M + 0.5 * _PROFILE_STEP_M, _PROFILE_STEP_M)
#: Frames farther apart than this (s) give no travel: the map starts again.
MAX_FRAME_GAP_S = 1.0


def travel_between(speed0_m_s: float, speed1_m_s: float, dt_s: float) -> float | None:
    """The distance travelled between two frames ``dt_s`` apart with these speeds at them
    (trapezoid), m; None where it is not known (a speed NaN, ``dt_s`` not in
    ``(0, MAX_FRAME_GAP_S]``)."""
    if not (math.isfinite(speed0_m_s) and math.isfinite(speed1_m_s) and 0.0 < dt_s <= MAX_FRAME_GAP_S):
        return None
    return 0.5 * (speed0_m_s + speed1_m_s) * dt_s


@nb.njit(cache=True, inline="always")
def _bspline3(a):  # pragma: no cover (numba)
    """The uniform cubic B-spline centred at 0 at ``|t| = a`` (support ``[-2, 2]``, sums to 1
    over shifts)."""
    if a < 1.0:
        return (4.0 - 6.0 * a * a + 3.0 * a * a * a) / 6.0
    if a < 2.0:
        return (2.0 - a) ** 3 / 6.0
    return 0.0


@nb.njit(cache=True)
def _bank_change_table(s0, u, k0, c, knot_m):  # pragma: no cover (numba)
    """The twist ``sum_i c_i B((s0 + u) / knot_m - k0 - i)`` at the stations ``s0 + u`` and its
    trapezoid integral from ``u[0]``: the bank change table of :meth:`TwistMap.profile`."""
    n, n_knots = u.size, c.size
    tau = np.zeros(n)
    for j in range(n):
        t = (s0 + u[j]) / knot_m - k0
        first = max(0, int(math.floor(t)) - 2)
        for i in range(first, min(n_knots, first + 5)):
            tau[j] += c[i] * _bspline3(abs(t - i))
    b = np.zeros(n)
    for j in range(1, n):
        b[j] = b[j - 1] + 0.5 * (tau[j] + tau[j - 1]) * (u[j] - u[j - 1])
    return b


@nb.njit(cache=True)
def _mean_row(s_lo, s_hi, n, k0, n_knots, knot_m):  # pragma: no cover (numba)
    """Mean over ``n`` evenly spaced stations from ``s_lo`` to ``s_hi`` of each knot's B-spline
    (knot ``k0 + i`` at ``(k0 + i) knot_m``)."""
    h = np.zeros(n_knots)
    for j in range(n):
        s = s_lo + (s_hi - s_lo) * j / (n - 1)
        t = s / knot_m - k0
        first = max(0, int(math.floor(t)) - 2)
        for i in range(first, min(n_knots, first + 5)):
            h[i] += _bspline3(abs(t - i))
    return h / n


class TwistMap:
    """The twist of the road (rad/m) around the vehicle, along the road.

    Parameters
    ----------
    prior_sigma_rad_m : float
        1-sigma of the first knots' twist (runoffs reach 0.2-0.3 deg/m).
    step_sigma_rad_m : float
        1-sigma of the twist's change from one knot to the next, for the knots entering ahead.
    walk_rad_m_sqrt_m : float
        Growth of every coefficient's 1-sigma per sqrt(metre travelled): the travel's own error.
    gate_sigma : float
        Measurements farther than this many sigma from the map's expectation are left out.
    """

    def __init__(self, prior_sigma_rad_m: float = math.radians(0.3), step_sigma_rad_m: float = math.radians(0.05),
                 walk_rad_m_sqrt_m: float = math.radians(0.002), gate_sigma: float = 4.0) -> None:
        self.prior_var = prior_sigma_rad_m**2
        self.step_var = step_sigma_rad_m**2
        self.walk_var = walk_rad_m_sqrt_m**2
        self.gate2 = gate_sigma**2
        self.reset()

    def reset(self) -> None:
        #: Station of the contact point along the road since the map started, m.
        self.s_m = 0.0
        self.k0 = -3                               # index of the first knot held (knot k at k * KNOT_M)
        n = int(math.ceil(AHEAD_M / KNOT_M)) + 6
        self.c = np.zeros(n)
        self.P = np.eye(n) * self.prior_var
        self.n_updates = 0
        self.n_rejected = 0
        self._table = None

    # ---- the window of knots ----

    def advance(self, travel_m: float) -> None:
        """The vehicle moved ``travel_m`` along the road: knots that fell behind are dropped,
        knots now within reach ahead enter, each the last one plus a step."""
        if not math.isfinite(travel_m) or travel_m == 0.0:
            return
        self._table = None
        self.s_m += float(travel_m)
        self.P[np.diag_indices(self.c.size)] += self.walk_var * abs(travel_m)
        # drop knots whose support (2 spacings each way) lies entirely behind the vehicle - 5 m
        while (self.k0 + 2) * KNOT_M < self.s_m - 5.0 and self.c.size > 4:
            self.c, self.P = self.c[1:], self.P[1:, 1:]
            self.k0 += 1
        while (self.k0 + self.c.size - 3) * KNOT_M < self.s_m + AHEAD_M:
            n = self.c.size
            c = np.append(self.c, self.c[-1])
            P = np.zeros((n + 1, n + 1))
            P[:n, :n] = self.P
            P[n, :n] = P[:n, n] = self.P[-1]
            P[n, n] = self.P[-1, -1] + self.step_var
            self.c, self.P = c, P

    # ---- measurements ----

    def _row(self, u_lo: float, u_hi: float) -> np.ndarray:
        """``h``: the mean twist over ``[u_lo, u_hi]`` ahead of the contact point is ``h . c``."""
        n = max(2, int(math.ceil((u_hi - u_lo) / 0.25)) + 1)
        return _mean_row(self.s_m + u_lo, self.s_m + u_hi, n, self.k0, self.c.size, KNOT_M)

    def update(self, u_lo: float, u_hi: float, twist_rad_m: float, sigma_rad_m: float) -> bool:
        """A measurement of the mean twist over ``[u_lo, u_hi]`` ahead of the contact point;
        False when it was gated out."""
        if not (math.isfinite(twist_rad_m) and math.isfinite(sigma_rad_m) and sigma_rad_m > 0 and u_hi > u_lo):
            return False
        h = self._row(u_lo, u_hi)
        Ph = self.P @ h
        s = float(h @ Ph) + sigma_rad_m**2
        nu = twist_rad_m - float(h @ self.c)
        if self.n_updates > 0 and nu * nu > self.gate2 * s:
            self.n_rejected += 1
            return False
        gain = Ph / s
        self._table = None
        self.c = self.c + gain * nu
        self.P = self.P - np.outer(gain, Ph)
        self.P = 0.5 * (self.P + self.P.T)
        self.n_updates += 1
        return True

    def mean_twist(self, u_lo: float, u_hi: float) -> tuple[float, float]:
        """Mean twist over ``[u_lo, u_hi]`` and its 1-sigma, rad/m."""
        h = self._row(u_lo, max(u_hi, u_lo + 1e-3))
        return float(h @ self.c), math.sqrt(max(float(h @ self.P @ h), 0.0))

    def profile(self, axis: np.ndarray) -> RoadTwist | None:
        """The bank change ahead as a :class:`vision.ipm.RoadTwist` about ``axis``, or None before
        the first measurement."""
        if self.n_updates == 0:
            return None
        if self._table is None:
            self._table = _PROFILE_U, _bank_change_table(self.s_m, _PROFILE_U, self.k0, self.c, KNOT_M)
        return RoadTwist(self._table[0], self._table[1], np.asarray(axis, float))

    def bank_change(self, u_m: float) -> float:
        """``b(u)`` of :meth:`profile` (0 before any measurement), rad."""
        tw = self.profile(np.zeros(5))
        return 0.0 if tw is None else float(tw.bank_change(u_m)[0])
