r"""Attitude and road EKF: CAN IMU rates propagate, vision angles and gravity correct.

State (named slices in :class:`S`, units in the names)::

    roll_w, pitch_w   rad   vehicle attitude relative to the level frame (ZYX roll, pitch)
    yaw_rel           rad   vehicle heading minus road heading, in the level frame
    bank, grade       rad   road frame relative to level at the vehicle: R_g'_from_o = Ry(grade) Rx(bank)
    gyro_bias         rad/s gyro bias, vehicle axes (3)
    speed             m/s   ground speed of the vehicle origin
    accel_x           m/s^2 dv/dt
    bank_rate         rad/s d(bank)/dt
    accel_bias        m/s^2 accelerometer bias, vehicle axes (3)
    curvature         1/m   road curvature at the vehicle (positive turning left)
    grade_rate        rad/s d(grade)/dt

with ``g'`` the level frame turned to the road's heading, so that
``R_g'_from_v = Rz(yaw_rel) Ry(pitch_w) Rx(roll_w)`` and the attitude relative to the road is

.. math:: R_{o\leftarrow v} = (R_y(\text{grade}) R_x(\text{bank}))^T R_z(\psi_{rel}) R_y(\theta_w) R_x(\phi_w),

whose ZYX angles are what vision measures (INTERFACE.md). With zero yaw and pitch this gives
``roll = roll_w - bank``: the road bank is the IMU's gravity-referenced roll minus the vision
roll (Damon et al. 2018, section IV), here estimated jointly with its covariance.

Process (one IMU interval ``dt``, rates ``w = gyro - bias`` averaged over the interval)::

    R_g'_from_v <- Rz(-dpsi_road) R_g'_from_v exp([w dt]x)     (exact for the interval)
    dpsi_road = kappa v cos(yaw_rel) / (1 - kappa d) dt          road heading change, from the
                                                                 curvature state and the
                                                                 lateral offset d of vision
    bank += bank_rate dt;  grade += grade_rate dt;  speed += accel_x dt
    bank_rate' = -(bank_rate - r_map) / tau_bank + noise   (first-order Gauss-Markov)
    grade_rate' = -grade_rate / tau_grade + noise  (likewise)
    grade, gyro_bias, accel_bias, accel_x, curvature: random walks

The grade has a rate state for the same reason: a vertical curve is a ramp of the grade (``v /
R``: 0.4 deg/s at 80 km/h over a 3000 m crest or sag, 1.3 deg/s over 1000 m), which a random
walk could only follow with a lag; the grade's own walk is then only what the rate leaves out.
Unlike the bank rate it keeps its correlation time while the vision is away: the accelerometer
measures it (``v dgrade/dt`` is vertical acceleration), where no sensor sees the bank's. Decaying
in 0.3 s as the bank rate does, the grade held through the hill drive's sag during a 5 s lane
loss and the pitch ended 1.2 deg off, which gated the returning vision out for ten frames;
keeping it, 0.12 deg; on the flat drives the rate, pulled by the vertical accelerometer bias
(0.06 deg/s on steady road), takes the pitch 0.12-0.28 deg off over the same loss (0.03-0.05
with the fast decay), within its sigma. Measured on
``hill_banked_curve_5deg`` (+5 % to -3 % over 150 m, a runoff in the sag; rendered, the same
vision for both): with the grade a random walk of 0.2 deg/sqrt(s) the fused pitch RMSE was 0.064
deg, with the rate (and the rate in the gravity model, below) 0.057; on a vision whose sag was
noisier (a worker's cold start there) 0.140 against 0.093, the random walk lagging the vision's
pitch by up to 0.8 deg. With the vision drawn from the truth (0.3 deg noise): 0.150 against
0.095 (``tests/test_fusion_filter.py::test_vertical_curves``).

The bank has a rate state: superelevation runoffs are ramps of a few deg/s that a plain random
walk could only follow by letting vision noise through; with a rate state the ramp is tracked
and the bank stays smooth where it is constant. The rate is mean-reverting (time constant
``tau_bank``, a second) rather than a random walk, and while the vision is away (lane loss)
it decays faster (0.3 s), so that the bank holds instead of extrapolating the last runoff.
With the vision roll deferred, the rate's sigma is scheduled by the runoffs the camera sees
ahead (:attr:`NoiseModel.bank_rate_preview_gain`): on steady road none is in view and the bank
holds between the vision's rolls, which come in bursts, one road patch per dash.

Between the bursts the rate reverts to ``r_map``, the road's bank rate under the wheels as the
frames' twists (below) measured it ahead of the vehicle, kept by when the vehicle gets there and
linear between the road patches measured (:meth:`fusion.engine.FusionStream._bank_rate_target`,
:attr:`ImuStep.bank_rate_target_rad_s`), with the correlation time ``tau_bank`` of
:attr:`NoiseModel.bank_rate_tau_mapped_s` (0.1 s); a mapped rate within
:attr:`NoiseModel.bank_rate_map_deadband_rad_s` (0.25 deg/s) of 0 is 0 (steady road, where the
map's own bias would be integrated into the bank); where no patch ahead is mapped, ``r_map = 0``
with the times above. It is a known input of the prediction, not a measurement: each twist is
measured once, when its roll lands (``update_road_twist``); the map only carries what the
frames said of the road between the landings. Before it, at the end of the left-hand drive's
runoff the rate held -1.3 to -1.0 deg/s through a 0.3 s hole between two bursts where the
truth's fell to 0, the frames captured meanwhile having measured about 0 there: the bank ran
0.45 deg off, roll and yaw with it. Measured on the bench's five HD drives (forward, the same
vision), roll / yaw / bank and NEES share in band, without and with the map: 60 s 0.108 / 0.074
/ 0.120, 45 % -> 0.072 / 0.069 / 0.092, 48 %; right-hand 0.078 / 0.093 / 0.110, 23 % -> 0.075 /
0.090 / 0.114, 23 %; left-hand 0.049 / 0.101 / 0.224 -> 0.040 / 0.095 / 0.216; hold-out 0.028 /
0.057 / 0.219, 69 % -> 0.025 / 0.057 / 0.219, 74 %; hill 0.028 / 0.034 / 0.200 -> 0.025 / 0.035 /
0.188 (the map's patches each their frames' median, :meth:`fusion.engine.FusionStream._patch_rate`).

Vision (roll, pitch, yaw relative to the road, :meth:`AttitudeEKF.update_vision`). The
estimator's roll is relative to the road ``L = roll_lookahead_m`` ahead, where its lane
cross-sections are. In a superelevation runoff that road is banked differently from the road
under the wheels, so the roll is applied when the vehicle gets there, ``L / v`` later
(:class:`RollAhead`), as a measurement of ``roll_w - bank`` then, corrected by the roll the gyros
turned through meanwhile::

    z = roll_vision(t) + (roll_w(t + L/v) - roll_w(t))_propagated

Modelling it instead as the bank ahead, ``bank + bank_rate L / v``, assumes that the bank rate
seen ahead is the one under the wheels: it starts and ends every runoff ``L / v`` (about half a
second) early. Measured on the three HD benchmark drives (cached vision, forward filter),
applying the roll at the lookahead cut the fused roll RMSE from 0.224 / 0.205 / 0.119 to
0.136 / 0.103 / 0.138 deg and the bank from 0.336 / 0.422 / 0.512 to 0.276 / 0.228 / 0.508
deg; on the bundled 640x360 sample drive it is worse for roll (0.29 against 0.17 deg; bank 0.47
against 0.45), which ``defer_roll = false`` in ``[fusion]`` gives back. Pitch and yaw are
applied at capture with the twist correction of :meth:`AttitudeEKF.update_vision`.

On a curve the road ahead has also turned, by ``phi = asin(kappa L)``, and in the vehicle's frame
it is banked less than ``bank``, and its grade, turned with it, slopes across the vehicle's axis
(:func:`road_ahead_as_seen`): the roll is modelled as ``roll_w - bank + r`` with ``r`` about
``bank (1 - cos phi) + grade sin phi`` (0.016 deg on the benchmark's 7 deg curve of 200 m radius,
where it was the vision roll's mean error on steady road; 0.5 deg on a 10 deg curve of 33 m radius
at 15 m; -0.09 deg on the hill drive's 250 m curve at -3 %), deferred or not. The grade's part
is only as good as the grade: at constant speed the longitudinal accelerometer bias and the
vehicle's pitch relative to level cannot be told apart (0.04 m/s^2 is 0.23 deg of grade).

With three lines the estimator also measures the road's twist at its cross-sections, ``tau =
d bank / ds`` (rad/m, :func:`vision.estimator._road_twist`). It travels with the deferred roll
(:class:`RollAhead`) and, when the vehicle reaches that road, measures the bank rate
(:meth:`AttitudeEKF.update_road_twist`)::

    z = v tau,    sigma = v max(sigma_tau, floor + rel |tau|)

after the twist a steadily banked curve shows ahead, about ``bank kappa^2 L``, is taken out
(:func:`road_ahead_as_seen`; -2.2e-3 deg/m on the 7 deg curve, where the measured twist read
-3.0e-3 on steady road), so that the bank rate is no longer only what the bursts of deferred
rolls imply. The twist
also moves the vision's yaw and lane curvature; where it changes across the view (a runoff
coming into view) the uniform-twist model misses most of it, and the estimator's own response
to the twist here and ahead (``VisionMeasurement.twist_response``) corrects yaw and curvature
with ``tau_here = bank_rate / v`` and ``tau_ahead`` the measured twist (``tau_here`` where the
frame measured none; pitch keeps the uniform model, which did better for it). Measured on
the three HD drives (``tools/bench_fusion.py``), the twist as the bank rate alone: NEES share in
band 61 / 73 / 92 -> 78 / 83 / 93 %, roll 0.133 / 0.093 / 0.125 -> 0.132 / 0.069 / 0.123 deg,
bank 0.260 / 0.198 / 0.557 -> 0.275 / 0.177 / 0.587 deg; with the response as well, yaw 0.185 /
0.221 / 0.063 -> 0.162 / 0.144 / 0.098 deg, bank -> 0.204 / 0.171 / 0.276 deg (all three now
better than the plain IMU-minus-vision difference), NEES -> 82 / 82 / 93 %.

A vertical curve coming into view (a sag or crest ahead, not yet under the wheels) changes the
road's vertical curvature across the view, and the estimator's single quadratic surface reads the
change as pitch (the hill drive's vision pitch error, up to 0.08 deg, is -6 m times it). The
estimator reports its fitted curvature ``zeta`` and its pitch's response to it
(``pitch_per_vertical_curvature_m``, the lane model's linear response to a curvature growing
ahead, -5 to -6.6 m); the pitch is modelled with ``L (zeta - zeta_here)``, ``zeta_here =
-grade_rate / v - kappa sin(bank)`` the vertical curvature at the vehicle from the state, the
grade rate in the Jacobian. Faded out towards a bank rate of 1 deg/s here or ahead (runoffs: there
the change is the banked curve's, which the twist model carries). Measured on the bench's five HD
drives (forward, their configs): hill pitch 0.040 -> 0.023 deg (within 2 sigma 86 -> 100 %),
banks 0.117 / 0.170 / 0.259 / 0.257 / 0.203 -> 0.115 / 0.159 / 0.245 / 0.263 / 0.213 deg.

The lane fit couples the yaw to the lane curvature: a line fitted more bent also points more
to the inside at the vehicle. The estimator reports ``yaw_per_curvature_m`` (``L_k``, the
yaw's error per 1/m of the curvature's, ``cov(yaw, kappa) / var(kappa)`` of the fit's
covariance, 4-7 m), and the yaw is modelled as ``yaw_rel + L_k (kappa_vision - kappa)``, the
curvature state in the Jacobian (``-L_k``), with the same runoff fade as the vertical curve's
term. This is the conditional form of a joint (yaw, curvature) measurement: the yaw's residual
is then the part of its error that the curvature's does not explain, independent of the
curvature's own update, which follows unchanged. The curvature state is known better than a
frame's fit: the yaw relative to the road turns at ``r - kappa v``, which the gyros see.
Measured on the vision of the bench's drives (``fuse`` forward, the drives' configs; median
over 20 draws of the accelerometer bias from its datasheet sigma), roll / pitch / yaw / bank:
the 60 s drive 0.082 / 0.022 / 0.079 / 0.112 -> 0.082 / 0.022 / 0.078 / 0.109 deg, the hill
drive 0.026 / 0.023 / 0.046 / 0.201 -> 0.026 / 0.024 / 0.039 / 0.186, the bundled 640x360
sample drive 0.220 / 0.100 / 0.280 / 0.349 -> 0.180 / 0.122 / 0.214 / 0.201 (its pitch worse:
its pitch and yaw errors are anti-correlated, -0.85, and the frames whose yaw the term now
explains pass the gate with their pitch: 32 -> 13 refused). Not faded in runoffs the yaw
gained more on three drives (60 s 0.074, left-hand 0.041, sample 0.184) but lost on the
hold-out drive (0.043 -> 0.055) and took the left-hand bank from 0.180 to 0.217 (through the
yaw-rate bias, learnt 0.03 deg/s further off in its first seconds).

Without a fresh lane curvature (lane loss) the road is assumed to turn with the vehicle
(``kappa`` = NaN in :class:`ImuStep`): yaw relative to the road is held and its uncertainty grows.

An IMU without a pitch-rate channel (Bosch MM5.10) uses the kinematic reconstruction
``q = r tan(roll_w)``, which holds when the pitch relative to level does not change (steady
lean: Omega (-sin theta, cos theta sin phi, cos theta cos phi) in the body), minus a pitch rate
``u`` that it leaves out (suspension pitch, the rider), a first-order Gauss-Markov state in
the missing gyro's bias slot: ``q = r tan(roll_w) - u``, ``u' = -u / tau_q + noise``
(:attr:`NoiseModel.no_pitch_rate_sigma_rad_s`, 2 deg/s, 0.2 s). The accelerometer sees ``u``:
it turns the body against its velocity, ``v u`` on the specific force, laterally ``v
sin(roll_rel) u`` in a lean. Without the state the filter read that as lateral accelerometer
bias and world roll, and the bank drifted through steady turns: the simulator's rider pitching
0.3 deg at 1.3 Hz (1.7 deg/s RMS), a 20 s left-hand turn with 0.05 deg vision, bank 0.299 ->
0.048 deg RMS (0.044 with the pitch gyro); with the rider not pitching 0.053 either way.

Gravity reference (specific force at the IMU, vehicle axes). The vehicle origin moves along
its heading: in the level frame turned to the vehicle's heading its acceleration is
``a_h = (v', v psi_w', 0)`` with the heading rate ``psi_w' = (q sin(phi) + r cos(phi)) /
cos(theta)`` (ZYX kinematics). Then::

    f = Rx(-phi) Ry(-theta) (v', v psi_w', g) + w' x rho + w x (w x rho)

with lever arm rho and angular acceleration w'. Writing ``a_b = (v', v r, -v q)`` instead (the
textbook body-frame form, velocity along body x) is wrong here: a body that pitches on its
suspension relative to its path would turn ``-v q`` into a spurious vertical acceleration
(0.9 m/s^2 for a 0.3 deg, 1.3 Hz pitch oscillation at 80 km/h, measured on the simulator).
On a leaning motorcycle the lateral specific force is ~0, so ``f_y`` pins
``tan(roll_w) = -v psi_w' / g`` (positive roll leans right, psi_w' > 0 turns left; for zero
pitch ``sin(roll_w) = -v r / g``): the centripetal compensation. A yaw-rate bias of 0.3 deg/s
at 25 m/s would be 0.75 deg of roll through this term, which is why the biases are states. The
same equation holds for a car, whose body follows the road (``f_y`` then carries body roll).
(The compiled model, :meth:`AttitudeEKF.specific_force_model`, writes the velocity along the
road, whose frame turns with the heading, bank and grade rates: in a vertical curve the path's
vertical acceleration ``v d(grade)/dt`` is then in it, 0.57 m/s^2 on the hill drive's sag,
which with the grade's rate left out was read as attitude.) The rates and the angular
acceleration ``w'`` (differenced from consecutive gyro samples) are inputs, so the gyro's
white noise is in the prediction: its covariance (:func:`rate_noise_cov`) joins the
accelerometer's, all of it in the gate, the part that accumulates over samples (the rates'
own; the differenced part telescopes) in the update.

The wheelbase (``wheelbase_m``, ``L``; :class:`fusion.options.FusionOptions`, ``[fusion]``). The
origin is the front wheel's contact point (INTERFACE.md), but the wheel that rolls without side
slip is the rear one, which is not steered: the origin moves sideways at ``L w_n``, with ``w_n =
w . e_n`` the heading rate about the road's normal, along ``e_lat`` (the body's y in the road
plane). Its acceleration adds ``L (w_n' e_lat + w_n (de_lat/dt + w x e_lat))`` to ``f``, with
``w_n' = w' . e_n + w . de_n/dt``: in a steady turn ``-L w_n^2`` along the path (0.02 m/s^2 for
1.45 m in a 200 m curve at 80 km/h), entering a curve ``L w_n'`` across it (0.05 m/s^2 in the
right-hand drive's clothoid, 1/200 m^-1 in about 66 m at 80 km/h). Small, but along the weakly
observed directions: on the simulator's right-hand drive with a 1.45 m wheelbase
(``tools/drivesim``, ``[motion] wheelbase_m``) a filter without it took the longitudinal
accelerometer bias to -0.2 m/s^2 through the curve's entry and held it there, the grade 0.77 deg
RMS off and the bank 0.26 (0.15 and 0.11 on the same drive without a wheelbase); with it, 0.15
and 0.08. In the steady turn the body's yaw relative to the road is ``-asin(L kappa)`` (0.42
deg in size there), which the vision sees and ``yaw_rel`` carries. Its Jacobian keeps the rates'
first-order terms (the relative Euler rates' share left out); ``L (w' . e_n) e_lat``'s gyro
noise, differenced as ``w'`` is, joins :func:`rate_noise_cov`.

Noise is given as 1-sigma values in natural units (:class:`fusion.noise.NoiseModel`, with the
state indices :class:`S`); the filter squares them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numba as nb
import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.stats import chi2

from vision.frames import R_from_rpy_scalar, rpy_from_R_scalar, so3_exp_scalar, wrap_angle

# the state's indices and the noise model (fusion.noise), names of this module as well
from .noise import (_FLOOR_AT, DIM_X, GRAVITY_M_S2, NoiseModel, S, _curvature_sigma, _float_if_scalar, _twist_sigma,
                    _vectorize, _vision_sigma)

__all__ = ["S", "DIM_X", "NoiseModel", "ImuStep", "RollAhead", "AttitudeEKF", "GRAVITY_M_S2",
           "rate_noise_cov", "relative_attitude", "relative_outputs", "road_ahead_as_seen", "twist_response_effect",
           "vision_hx",
           "vision_jacobian"]


def road_ahead_as_seen(bank_rad, curvature_1_m, distance_m, grade_rad=0.0):
    """The bank and the twist of a steadily banked, steadily graded curve ``distance_m`` ahead
    as the vehicle sees them in its own frame, which is how the vision's cross-sections
    measure them.

    A cross-section at forward distance ``x`` meets a curve of curvature ``kappa`` where the
    road has turned by ``phi = asin(kappa x)`` about the vertical. With the road's frame under
    the vehicle ``R0 = Ry(grade) Rx(bank)`` (the state's), the road there is ``Rz(phi) R0``
    (a helix: the same bank about its own tangent, the same grade along it), and its normal in
    the frame under the vehicle is ``n = R0^T Rz(phi) R0 e_z``. The markings' heights along
    the cross-section rise with ``S = -n_y / n_z`` per metre across, so that the vision's roll
    there is ``roll_w - bank + r`` with ``r = -atan S``: about ``bank (1 - cos phi) + grade sin
    phi``. The grade's part is the larger one on a graded curve: the grade turned with the
    road is a slope across the vehicle's axis (-0.094 deg at 15 m on the hill drive's 250 m
    curve at -3 %, against +0.009 deg from its 5 deg bank; 1.4 deg on a 50 m curve at 6 %).
    Its twist (``d/dx`` of the bank it sees) is ``tau cos phi - dr/dx``, ``dr/dx = dr/dphi kappa
    / cos phi`` (analytic), about ``-(bank kappa^2 x + grade kappa)`` with the bank and grade
    constant. Returns ``(bank - r, -dr/dx, phi)``, rad, rad/m and rad (scalars or arrays).

    Against the exact surface of the simulator's road (three markings' heights at a forward
    distance) it holds to 0.03 % on the benchmark's curves and to 2 % up to ``kappa x = 0.45``
    (a 10 deg curve of 33 m radius at 15 m), where the markings' own radii begin to differ
    (``tests/test_fusion_filter.py::test_road_ahead_as_seen_matches_the_simulated_road``).
    Up to ``2733e2a`` it took the bank alone: on the hill drive's graded curve the vision roll
    then read 0.075 deg low on steady road, which the filter took for bank (the fused bank
    ended 0.38 deg off).

    On the simulator's 7 deg curve of 200 m radius (the benchmark's right-hand drive) the vision
    roll on steady road was off by +0.017 deg on average and its twist by -3.0e-3 deg/m (about
    0.07 deg/s of bank rate at 80 km/h), against +0.016 and -2.2e-3 from this; on the left-hand
    curves (4e-3 1/m, -5 and -6 deg) -0.008 / -0.011 deg against -0.009 / -0.010. Taking it
    out, the steady-road roll error RMS fell from 0.010 / 0.020 / 0.013 / 0.021 to 0.003 /
    0.006 / 0.004 / 0.012 deg on the four banked curves of the three drives.
    """
    floats = (isinstance(bank_rad, float) and isinstance(curvature_1_m, float) and isinstance(distance_m, float)
              and isinstance(grade_rad, float))      # (np.ndim costs 2 us each, once a frame)
    if not floats and (np.ndim(bank_rad) or np.ndim(curvature_1_m) or np.ndim(distance_m) or np.ndim(grade_rad)):
        return _road_turn_v(bank_rad, curvature_1_m, distance_m, grade_rad)
    return _road_turn(float(bank_rad), float(curvature_1_m), float(distance_m), float(grade_rad))


@nb.njit(cache=True)
def _road_turn(b, k, d, g=0.0):
    """:func:`road_ahead_as_seen` for scalars (compiled: the filter calls it twice a frame).
    ``phi`` is clipped short of a quarter turn: no cross-section meets the curve beyond its
    radius."""
    phi = math.asin(max(-0.999, min(0.999, k * d)))
    cphi, sphi = math.cos(phi), math.sin(phi)
    sb, cb, sg, cg = math.sin(b), math.cos(b), math.sin(g), math.cos(g)
    # w = Rz(phi) R0 e_z and its derivative in phi; n = R0^T w = Rx(-b) Ry(-g) w
    w1, w2, w3 = cphi * sg * cb + sphi * sb, sphi * sg * cb - cphi * sb, cg * cb
    dw1, dw2 = -sphi * sg * cb + cphi * sb, cphi * sg * cb + sphi * sb
    a, da = sg * w1 + cg * w3, sg * dw1
    ny, nz = cb * w2 + sb * a, -sb * w2 + cb * a
    dny, dnz = cb * dw2 + sb * da, -sb * dw2 + cb * da
    S = -ny / nz
    dS = -(dny * nz - ny * dnz) / (nz * nz)
    drdx = -dS / (1.0 + S * S) * k / cphi
    return b + math.atan(S), -drdx, phi


_road_turn_v = _vectorize(_road_turn, 3)


def twist_response_effect(response, tau_here_rad_m, tau_ahead_rad_m):
    """The yaw (rad) and lane-curvature (1/m) errors that the estimator's twist response
    predicts (:attr:`VisionMeasurement.twist_response`, six gains: curvature, pitch, yaw per
    rad/m of twist here and at the cross-sections), for the twist ``tau_here_rad_m`` at the
    vehicle and the vision's own measured twist ahead (NaN where it measured none: the twist
    here, a uniform twist). Scalars, or arrays with the gains along the first axis."""
    yaw, curvature = _twist_effect_v(response[0], response[1], response[4], response[5], tau_here_rad_m, tau_ahead_rad_m)
    return _float_if_scalar(yaw), _float_if_scalar(curvature)


@nb.njit(cache=True)
def _twist_effect(k_here, k_ahead, yaw_here, yaw_ahead, tau_here, tau_ahead):
    """:func:`twist_response_effect` of one frame: ``(yaw, curvature)``."""
    ahead = tau_ahead if math.isfinite(tau_ahead) else tau_here
    return yaw_here * tau_here + yaw_ahead * ahead, k_here * tau_here + k_ahead * ahead


_twist_effect_v = _vectorize(_twist_effect, 2)


@dataclass(frozen=True)
class VisionMeasurement:
    """One vision result, as the filter uses it (vision.csv's columns; vehicle relative to road).

    ``roll_lookahead_m``: how far ahead of the vehicle the roll was measured (the bank there
    is modelled, :meth:`AttitudeEKF.update_vision`); ``twist_m``: the pitch and yaw errors per
    rad/m of road twist, ``(y_l + y_r, y_l y_r / H)`` in metres (:class:`vision.VisionEstimate`
    ``pitch_per_twist_m``, ``yaw_per_twist_m``); ``road_twist_rad_m``: how fast the bank changes
    along the road at the roll's cross-sections, with its 1-sigma (NaN: not measured).
    """

    t_s: float
    angles_rad: np.ndarray
    sigmas_rad: np.ndarray
    curvature_1_m: float = math.nan
    curvature_sigma_1_m: float = math.nan
    lateral_offset_m: float = math.nan
    roll_lookahead_m: float = 0.0
    twist_m: tuple[float, float] = (0.0, 0.0)
    road_twist_rad_m: float = math.nan
    road_twist_sigma_rad_m: float = math.nan
    #: The estimator's response to a twist changing across the view (``vision.VisionEstimate``
    #: ``twist_response``): curvature, pitch, yaw per rad/m of twist at the vehicle and at the
    #: roll's cross-sections, in that order per output; NaN: the uniform-twist model instead.
    twist_response: tuple = (math.nan,) * 6
    #: The road's vertical curvature in view (1/m) and the pitch error per 1/m of it beyond the
    #: vertical curvature at the vehicle (m) (``vision.VisionEstimate`` ``vertical_curvature_1_m``,
    #: ``pitch_per_vertical_curvature_m``); NaN: none.
    vertical_curvature: tuple = (math.nan, math.nan)
    #: The yaw's error per 1/m of the lane curvature's, as the lane fit couples them (m;
    #: ``vision.VisionEstimate.yaw_per_curvature_m``); NaN: none.
    yaw_per_curvature_m: float = math.nan


@dataclass(frozen=True)
class RollAhead:
    """A vision roll waiting for the vehicle to reach the road it was measured on.

    The estimator's roll is relative to the road ``roll_lookahead_m`` ahead of the vehicle
    (where its lane cross-sections are); it is applied at ``t_s = capture + lookahead / v``,
    corrected by the roll the vehicle turned through meanwhile (``roll_prop_at_capture_rad``:
    the stream's running sum of propagated roll at capture time). The road's twist measured
    there (rad/m, NaN: none) comes with it: at arrival it is the bank rate under the wheels
    divided by the speed (:meth:`AttitudeEKF.update_road_twist`).
    """

    t_s: float
    roll_rad: float
    sigma_rad: float
    dt_ahead_s: float
    roll_prop_at_capture_rad: float
    twist_rad_m: float = math.nan
    twist_sigma_rad_m: float = math.nan
    #: Distance from the vehicle to the roll's cross-sections at capture, m (the road's turn
    #: over it, :func:`road_ahead_as_seen`).
    lookahead_m: float = 0.0


class ImuStep(NamedTuple):
    """Inputs of one propagation interval (vehicle frame). (A named tuple, not a frozen
    dataclass: one is made per propagation, and a frozen dataclass took 9 us of the filter's
    250 us per IMU sample on this machine.)"""

    dt_s: float
    gyro_rad_s: np.ndarray           # mean measured rate over the interval (bias included)
    follow_road: bool = False        # no lane fit: the road turns with the vehicle
    lateral_offset_m: float = 0.0    # vehicle's offset from the lane line the curvature is of
    vision_gap: bool = False         # no vision for a while: the bank and grade rates decay fast (held)
    #: The road's bank rate at the vehicle as the frames' twists mapped it ahead (NaN: not
    #: mapped), what the bank rate reverts to (module docstring, "Process"), rad/s.
    bank_rate_target_rad_s: float = math.nan


# ---- small dense products, written as loops: for these sizes (3x3, 16x16, 16x3) they are
# cheaper to call than BLAS and far cheaper to compile (numba's ``@`` brings BLAS bindings and
# their shape-error formatting: about 10 s of the fusion's 26 s first-run compile, measured).
# Zeros of the left factor (F, H are sparse) are skipped. Arguments must be C-contiguous
# (pass no transposes: each layout is compiled anew).


@nb.njit(cache=True)
def _mm(A, B):
    """``A @ B``."""
    n, k = A.shape
    m = B.shape[1]
    C = np.zeros((n, m))
    for i in range(n):
        for l in range(k):
            a = A[i, l]
            if a != 0.0:
                for j in range(m):
                    C[i, j] += a * B[l, j]
    return C


@nb.njit(cache=True)
def _tmm(A, B):
    """``A.T @ B``."""
    k, n = A.shape
    m = B.shape[1]
    C = np.zeros((n, m))
    for l in range(k):
        for i in range(n):
            a = A[l, i]
            if a != 0.0:
                for j in range(m):
                    C[i, j] += a * B[l, j]
    return C


@nb.njit(cache=True)
def _mmt(A, B):
    """``A @ B.T``; zeros of ``B`` are skipped."""
    n, k = A.shape
    m = B.shape[0]
    C = np.zeros((n, m))
    for j in range(m):
        for l in range(k):
            b = B[j, l]
            if b != 0.0:
                for i in range(n):
                    C[i, j] += A[i, l] * b
    return C


@nb.njit(cache=True)
def _mv(A, v):
    """``A @ v``."""
    n, k = A.shape
    out = np.zeros(n)
    for i in range(n):
        acc = 0.0
        for l in range(k):
            acc += A[i, l] * v[l]
        out[i] = acc
    return out


_VISION_STATES = (S.ROLL_W, S.PITCH_W, S.YAW_REL, S.BANK, S.GRADE)


@nb.njit(cache=True)
def relative_attitude(x) -> np.ndarray:
    """``R_o_from_v`` of state ``x``: ``(Ry(grade) Rx(bank))^T Rz(yaw_rel) Ry(pitch_w) Rx(roll_w)``
    (state indices 0-4 of :class:`S`)."""
    R_gp_from_v = R_from_rpy_scalar(x[0], x[1], x[2])
    R_gp_from_o = R_from_rpy_scalar(x[3], x[4], 0.0)
    return _tmm(R_gp_from_o, R_gp_from_v)


@nb.njit(cache=True)
def vision_hx(x) -> np.ndarray:
    """Predicted vision measurement: (roll, pitch, yaw) relative to the road, rad."""
    h = np.empty(3)
    h[0], h[1], h[2] = rpy_from_R_scalar(relative_attitude(x))
    return h


@nb.njit(cache=True)
def _skew(a, b, c):
    K = np.zeros((3, 3))
    K[0, 1], K[0, 2], K[1, 2] = -c, b, -a
    K[1, 0], K[2, 0], K[2, 1] = c, -b, a
    return K


@nb.njit(cache=True)
def vision_jacobian(x) -> np.ndarray:
    """3 x DIM_X Jacobian of :func:`vision_hx`, analytic.

    With ``A = Ry(grade) Rx(bank)``, ``B = Rz(yaw_rel) Ry(pitch_w) Rx(roll_w)`` and
    ``R = A^T B``: ``dB/droll = B [x]``, ``dB/dyaw = [z] B``, ``dB/dpitch = [Rz(yaw) y] B``,
    ``dA/dbank = A [x]``, ``dA/dgrade = [y] A``; then the derivatives of
    ``(atan2(R21, R22), -asin(R20), atan2(R10, R00))``. (Compiled: state indices as numbers,
    0-4 = roll_w, pitch_w, yaw_rel, bank, grade as in :class:`S`.)
    """
    A = R_from_rpy_scalar(x[3], x[4], 0.0)
    B = R_from_rpy_scalar(x[0], x[1], x[2])
    R = _tmm(A, B)
    cy, sy = math.cos(x[2]), math.sin(x[2])
    ex, ey, ez = _skew(1.0, 0.0, 0.0), _skew(0.0, 1.0, 0.0), _skew(0.0, 0.0, 1.0)
    dR = np.empty((5, 3, 3))              # in the order of _VISION_STATES
    dR[0] = _tmm(A, _mm(B, ex))           # roll_w
    dR[1] = _tmm(A, _mm(_skew(-sy, cy, 0.0), B))   # pitch_w
    dR[2] = _tmm(A, _mm(ez, B))           # yaw_rel
    dR[3] = -_mm(ex, R)                   # bank:  (A [x])^T B = -[x] A^T B
    dR[4] = -_tmm(A, _mm(ey, B))          # grade: ([y] A)^T B = -A^T [y] B
    r21, r22, r20, r10, r00 = R[2, 1], R[2, 2], R[2, 0], R[1, 0], R[0, 0]
    n_roll, n_pitch, n_yaw = r21 * r21 + r22 * r22, math.sqrt(max(1e-300, 1.0 - r20 * r20)), r10 * r10 + r00 * r00
    H = np.zeros((3, DIM_X))
    for k in range(5):
        i, d = _VISION_STATES[k], dR[k]
        H[0, i] = (r22 * d[2, 1] - r21 * d[2, 2]) / n_roll
        H[1, i] = -d[2, 0] / n_pitch
        H[2, i] = (r00 * d[1, 0] - r10 * d[0, 0]) / n_yaw
    return H


@nb.njit(cache=True)
def relative_outputs(X, P):
    """Per state ``X[k]`` (N, DIM_X) with covariance ``P[k]``: the relative (roll, pitch, yaw)
    of :func:`vision_hx`, (N, 3) rad, and the joint covariance of (roll, pitch, yaw, bank),
    (N, 4, 4) rad^2, through :func:`vision_jacobian` (the fused table's outputs)."""
    n = X.shape[0]
    rel = np.empty((n, 3))
    cov = np.empty((n, 4, 4))
    J = np.zeros((4, DIM_X))
    J[3, 3] = 1.0                                   # bank
    for k in range(n):
        x = np.ascontiguousarray(X[k])
        rel[k] = vision_hx(x)
        J[:3] = vision_jacobian(x)
        cov[k] = _mmt(_mm(J, np.ascontiguousarray(P[k])), J)
    return rel, cov


def vision_jacobian_numeric(x, eps: float = 1e-6) -> np.ndarray:
    """Central-difference twin of :func:`vision_jacobian`, for tests."""
    H = np.zeros((3, DIM_X))
    for i in _VISION_STATES:
        xp, xm = x.copy(), x.copy()
        xp[i] += eps
        xm[i] -= eps
        H[:, i] = wrap_angle(vision_hx(xp) - vision_hx(xm)) / (2 * eps)
    return H


@nb.njit(cache=True)
def _angle_residual(a, b):
    """Residual of angles (float arrays), wrapped to [-pi, pi) like :func:`vision.frames.wrap_angle`
    (compiled: it runs for every vision update)."""
    y = np.empty(a.size)
    for i in range(a.size):
        y[i] = (a[i] - b[i] + math.pi) % (2.0 * math.pi) - math.pi
    return y


def accel_r_scale(noise: NoiseModel, update_period_s: float) -> float:
    """Factor on the accelerometer's noise variance for gravity updates every
    ``update_period_s``: ``f / f_ref`` (:attr:`NoiseModel.accel_meas_rate_hz`), which keeps the
    allowance's 1 s average at any rate. 1 for a period that is not finite and positive."""
    if not (math.isfinite(update_period_s) and update_period_s > 0):
        return 1.0
    return 1.0 / (noise.accel_meas_rate_hz * update_period_s)


class AttitudeEKF(ExtendedKalmanFilter):
    """filterpy EKF with the nonlinear process model of the module docstring.

    Parameters
    ----------
    noise : NoiseModel
    lever_arm_m : (3,) array
        IMU position in the vehicle frame, m.
    has_pitch_rate : bool
        False for IMUs without a pitch-rate channel: ``q = r tan(roll_w)``.
    wheelbase_m : float
        The rear wheel's contact point behind the front one (the origin), m: the rear wheel
        rolls without side slip (module docstring, "The wheelbase"); 0: the origin's velocity
        along the body's heading.
    """

    def __init__(self, noise: NoiseModel = NoiseModel(), lever_arm_m=(0.0, 0.0, 0.0),
                 has_pitch_rate: bool = True, wheelbase_m: float = 0.0) -> None:
        super().__init__(dim_x=DIM_X, dim_z=3)
        self.noise = noise
        self.lever_arm_m = np.asarray(lever_arm_m, dtype=float)
        self.wheelbase_m = float(wheelbase_m)
        # what the compiled kernels take: the lever arm, then the wheelbase
        self._rho = np.append(self.lever_arm_m, self.wheelbase_m)
        self.has_pitch_rate = has_pitch_rate
        n = noise
        sig0 = np.zeros(DIM_X)
        sig0[[S.ROLL_W, S.PITCH_W, S.YAW_REL]] = n.init_angle_rad
        sig0[S.BANK], sig0[S.GRADE] = n.init_bank_rad, n.init_grade_rad
        sig0[S.GYRO_BIAS] = n.init_gyro_bias_rad_s
        sig0[S.SPEED], sig0[S.ACCEL_X] = n.init_speed_m_s, n.init_accel_m_s2
        sig0[S.BANK_RATE] = n.init_bank_rate_rad_s
        sig0[S.GRADE_RATE] = n.init_grade_rate_rad_s
        sig0[S.ACCEL_BIAS] = n.init_accel_bias_m_s2
        sig0[S.CURVATURE] = n.init_curvature_1_m
        self.x = np.zeros(DIM_X)
        self.x[S.GYRO_BIAS] = n.gyro_bias_prior_rad_s
        self.x[S.ACCEL_BIAS] = n.accel_bias_prior_m_s2
        if not has_pitch_rate:
            # no pitch gyro: its bias slot holds the pitch rate q = r tan(roll) leaves out (minus)
            self.x[S.GYRO_BIAS_Y] = 0.0
            sig0[S.GYRO_BIAS_Y] = n.no_pitch_rate_sigma_rad_s
        self.P = np.diag(sig0**2)
        self._I = np.eye(DIM_X)
        self.F = np.eye(DIM_X)
        self.Q = np.zeros((DIM_X, DIM_X))
        self.x_prior, self.P_prior = self.x.copy(), self.P.copy()
        self.x_post, self.P_post = self.x.copy(), self.P.copy()
        # constant parts of Q per second
        q = np.zeros(DIM_X)
        q[S.BANK_RATE] = 2.0 * n.bank_rate_rad_s**2 / n.bank_rate_tau_s   # stationary variance sigma^2
        q[S.GRADE] = n.grade_walk_rad_sqrt_s**2
        q[S.GRADE_RATE] = 2.0 * n.grade_rate_rad_s**2 / n.grade_rate_tau_s
        q[S.GYRO_BIAS] = n.gyro_bias_walk_rad_s_sqrt_s**2
        q[S.ACCEL_X] = n.accel_x_walk_m_s2_sqrt_s**2
        q[S.ACCEL_BIAS] = n.accel_bias_walk_m_s2_sqrt_s**2
        q[S.CURVATURE] = n.curvature_walk_1_m_sqrt_s**2
        q[S.ROLL_W] = q[S.YAW_REL] = n.attitude_walk_rad_sqrt_s**2
        q[S.PITCH_W] = (n.attitude_walk_rad_sqrt_s if has_pitch_rate else n.no_pitch_rate_walk_rad_sqrt_s) ** 2
        if not has_pitch_rate:   # the pitch rate in the gyro's bias slot: Gauss-Markov, not a walk
            q[S.GYRO_BIAS_Y] = 2.0 * n.no_pitch_rate_sigma_rad_s**2 / n.no_pitch_rate_tau_s
        self._q_const = q
        self._q_scheduled = q.copy()   # with the bank-rate sigma of set_bank_rate_sigma
        self._bank_rate_scheduled = False
        self.last_d2 = math.nan
        self._gate = {k: float(chi2.ppf(noise.gate_probability, k)) for k in (1, 2, 3, 4)}
        self._R_accel = np.diag(np.asarray(noise.accel_meas_m_s2, dtype=float) ** 2)
        self._R_accel_scaled = (1.0, self._R_accel)   # (r_scale, R_accel * r_scale) last used
        self._sigma_params = noise._vision_sigma_params()
        self.curvature_rejected = 0
        # the kernels' other noise arguments, worked out once as the gates are (per call they
        # were a tenth of the Python time around the propagation's kernel)
        self._gyro_var = n.gyro_noise_rad_s**2
        self._yaw_walk_var = n.yaw_rel_walk_no_lanes_rad_sqrt_s**2
        self._speed_var = n.speed_meas_m_s**2
        taus = (n.grade_rate_tau_s, n.no_pitch_rate_tau_s)
        self._taus_mapped = (n.bank_rate_tau_mapped_s, *taus)
        self._taus_no_vision = (min(n.bank_rate_tau_s, n.bank_rate_tau_no_vision_s), *taus)
        self._taus = (n.bank_rate_tau_s, *taus)

    # ---- process ----

    def predict_x(self, u: ImuStep = None) -> None:
        """Propagate the state over one IMU interval (module docstring, "Process")."""
        gyro, dt, follow, offset, has_q, taus, _, _, _, target = self._interval_args(u)
        self.x = _predict_x(self.x, gyro, dt, follow, offset, has_q, taus, target)

    def set_bank_rate_sigma(self, sigma_rad_s: float | None) -> None:
        """Stationary 1-sigma of the bank rate from now on (None: ``noise.bank_rate_rad_s``);
        while the vision is away the constant applies (:attr:`ImuStep.vision_gap`)."""
        self._bank_rate_scheduled = sigma_rad_s is not None
        if sigma_rad_s is not None:
            self._q_scheduled[S.BANK_RATE] = 2.0 * sigma_rad_s**2 / self.noise.bank_rate_tau_s

    def _interval_args(self, u: ImuStep) -> tuple:
        """The compiled process model's arguments for interval ``u`` (:func:`_transition`'s after
        the state, then the bank rate's mean), worked out in one call per propagation:
        ``(gyro, dt, follow_road, lateral_offset, has_pitch_rate, taus, q_per_s, gyro_var,
        yaw_walk_var, bank_rate_target)``.

        ``taus``: the correlation times of the bank rate, the grade rate and (without a pitch
        gyro) the pitch rate over this interval: where the road ahead is mapped (a finite
        :attr:`ImuStep.bank_rate_target_rad_s`), ``bank_rate_tau_mapped_s`` for the bank rate;
        else while the vision is away, ``bank_rate_tau_no_vision_s`` (the bank holds); the grade
        rate keeps its own, the accelerometer measures it (module docstring). ``q_per_s``: the
        diagonal process noise per second (the scheduled bank rate's while the vision is there).
        ``bank_rate_target``: the bank rate's mean over the interval (rad/s), the mapped road's,
        else 0."""
        target, gap = u.bank_rate_target_rad_s, u.vision_gap
        if math.isnan(target):
            taus, target = (self._taus_no_vision if gap else self._taus), 0.0
        else:
            taus = self._taus_mapped
        q_per_s = self._q_scheduled if self._bank_rate_scheduled and not gap else self._q_const
        return (u.gyro_rad_s, u.dt_s, u.follow_road, u.lateral_offset_m, self.has_pitch_rate, taus, q_per_s,
                self._gyro_var, self._yaw_walk_var, target)

    def road_turn_rate(self, u: ImuStep) -> float:
        """Heading rate of the road at the vehicle, rad/s: ``kappa v cos(yaw_rel) / (1 - kappa d)``,
        or the vehicle's own heading rate when there is no lane fit (``follow_road``)."""
        return _road_turn_rate(self.x, u.gyro_rad_s, u.follow_road, u.lateral_offset_m, self.has_pitch_rate)

    def transition(self, u: ImuStep):
        """Jacobian ``F = I + A dt`` and process noise ``Q`` of one interval (:func:`_transition`)."""
        return _transition(self.x, *self._interval_args(u)[:9])

    def predict(self, u: ImuStep = None) -> None:
        """filterpy's ``predict`` (``predict_x``, then ``P = F P F^T + Q``, then the priors),
        with the covariance product compiled."""
        self.predict_x(u)
        self.P = _propagate_cov(self.P, self.F, self.Q)
        self.x_prior, self.P_prior = self.x.copy(), self.P.copy()

    def propagate(self, u: ImuStep) -> float:
        """filterpy predict with this interval's F and Q (:meth:`transition`, then
        :meth:`predict`), in one compiled call: it runs once or twice per IMU sample. Returns
        the road's heading rate after the step (:meth:`road_turn_rate`). The prior, ``F`` and
        ``Q`` are written into the filter's own arrays, as :meth:`propagate_and_update` does."""
        self.x, self.P, road_rate = _propagate_into(self.x, self.P, *self._interval_args(u), self.x_prior,
                                                    self.P_prior, self.F, self.Q)
        return road_rate

    # ---- measurements ----

    def gated_update(self, z, H, hx, R, residual=np.subtract) -> bool:
        """Chi-square (Mahalanobis) gate, then the EKF update.

        The gate ``y^T S^-1 y < chi2(p_gate, dof)`` is computed before the update from the same
        ``S = H P H^T + R``; a rejected measurement leaves the state untouched and returns
        False. The update is filterpy's with the same attributes (``y, S, SI, K, z, x_post,
        P_post``), written out so that ``S`` is inverted once, and with the covariance in the
        optimal-gain form ``P - K S K^T`` (equal to filterpy's Joseph form for the optimal
        gain, and half the matrix products), symmetrised.
        """
        y = residual(z, hx)
        ok, d2, x, P, K, Sm, SI = _gated_update(self.x, self.P, y, H, R, self._gate[len(y)])
        return self._accept(ok, d2, x, P, y, K, Sm, SI, z)

    def _accept(self, ok, d2, x, P, y, K, Sm, SI, z) -> bool:
        """Take a gated update's result: the state, and filterpy's attributes, when accepted."""
        self.last_d2 = d2
        if not ok:
            return False
        self.x, self.P = x, P
        self.y, self.S, self.SI, self.K, self.z = y, Sm, SI, K, z
        self._log_likelihood = self._likelihood = self._mahalanobis = None
        self.x_post, self.P_post = self.x, self.P
        return True

    def gated_update_state(self, i: int, z: float, r2: float) -> bool:
        """:meth:`gated_update` for a measurement of state ``i`` itself (speed, curvature), with
        variance ``r2``: the same equations, without the matrix products of a general H."""
        P = self.P
        y = z - self.x[i]
        Sm = P[i, i] + r2
        d2 = y * y / Sm
        self.last_d2 = d2
        if d2 > self._gate[1]:
            return False
        self.x, self.P, K = _update_state(self.x, P, i, y, Sm)
        self.y, self.S, self.SI, self.K, self.z = np.array([y]), np.array([[Sm]]), np.array([[1.0 / Sm]]), K[:, None], z
        self._log_likelihood = self._likelihood = self._mahalanobis = None
        self.x_post, self.P_post = self.x, self.P
        return True

    def update_vision(self, m: VisionMeasurement, defer_roll: bool = False, bank_rate_ahead: float = 0.0) -> bool:
        """Vision (roll, pitch, yaw) relative to the road, with the estimator's own 1-sigma, then
        the lane-fit curvature when there is one, gated on its own: a curvature outlier must not
        throw away good angles, nor good angles carry a bad curvature in. Returns whether the
        angles were used.

        The road in view is not the road under the wheels. The roll comes from lane
        cross-sections ``m.roll_lookahead_m`` ahead, where in a superelevation runoff the road
        is banked differently (7 deg over 70 m at 10 m ahead: 1 deg). With ``defer_roll`` the
        roll is left out here and applied when the vehicle gets there
        (:meth:`update_roll_ahead`, :class:`RollAhead`); without, it is modelled as the bank
        ahead, ``bank + bank_rate * lookahead / v``, which assumes the bank rate seen ahead is
        the one under the wheels and so starts and ends every runoff ``lookahead / v`` early.
        The runoff also twists the road (``tau = bank_rate / v``, rad/m), which the estimator
        reads as pitch and yaw errors ``tau * m.twist_m`` (sample drive: 0.7 and 1.6 deg in the
        runoff); the measurement is modelled with it, which turns the runoff from a vision
        error into information on the bank rate.
        """
        angles = np.asarray(m.angles_rad, dtype=float)
        (ok, d2, y, K, Sm, SI, k_tried, k_ok, k_d2, k_z, k_y, k_S, k_K, x, P) = _vision_update(
            self.x, self.P, angles, np.asarray(m.sigmas_rad, dtype=float), float(m.twist_m[0]), float(m.twist_m[1]),
            float(m.roll_lookahead_m), defer_roll, float(bank_rate_ahead), np.asarray(m.twist_response, dtype=float),
            float(m.road_twist_rad_m), float(m.curvature_1_m), float(m.curvature_sigma_1_m),
            float(m.vertical_curvature[0]), float(m.vertical_curvature[1]), float(m.yaw_per_curvature_m), self._sigma_params,
            self._gate[1], self._gate[2] if defer_roll else self._gate[3])
        self._accept(ok, d2, x, P, y, K, Sm, SI, angles[1:] if defer_roll else angles)
        if k_tried:
            if k_ok:
                self._accept(True, k_d2, x, P, np.array([k_y]), k_K[:, None], np.array([[k_S]]),
                             np.array([[1.0 / k_S]]), k_z)
            else:
                self.last_d2 = k_d2
                self.curvature_rejected += 1
        return ok

    def update_roll_ahead(self, r: "RollAhead", roll_turned_rad: float) -> bool:
        """The vision roll of :class:`RollAhead` ``r``, applied now that the vehicle is where the
        roll was measured: ``r.roll_rad + roll_turned_rad`` is the roll relative to the road
        under the wheels, with ``roll_turned_rad`` the vehicle's roll (relative to level) since
        the frame, as the gyros propagated it. Gated like every update."""
        z = float(r.roll_rad + roll_turned_rad)
        ok, d2, x, P, y, K, Sm, SI = _roll_ahead_update(self.x, self.P, z, float(r.sigma_rad), float(r.dt_ahead_s),
                                                         float(r.lookahead_m), self._sigma_params, self._gate[1])
        return self._accept(ok, d2, x, P, y, K, Sm, SI, np.array([z]))

    def update_road_twist(self, twist_rad_m: float, sigma_rad_m: float, lookahead_m: float = 0.0) -> bool:
        """The vision's road twist at the road under the wheels (:class:`RollAhead`) as the
        bank rate: ``d bank / dt = v d bank / ds``. The twist a steadily banked, graded curve
        shows ``lookahead_m`` ahead (:func:`road_ahead_as_seen`, with the bank, grade and
        curvature of the state: the road the twist was measured on) is part of the model::

            z = twist,   h(x) = bank_rate cos(phi) / v + turned(bank, grade, kappa)

        with 1-sigma :meth:`NoiseModel.twist_sigma_rad_m`. The Jacobian has the bank rate and
        the grade: the grade's part, about ``-grade kappa`` (0.15 deg/s of bank rate at 80 km/h
        on the hill drive's 250 m curve at -3 %), is only as good as the grade, which the
        longitudinal accelerometer bias blurs (0.04 m/s^2 is 0.23 deg); taken as known, that
        error became a bank-rate bias (synthetic 60 s drive with the twist: bank 0.145 -> 0.173
        deg; with the grade in the Jacobian 0.145). The bank's and curvature's parts are second
        order (``bank kappa^2 L``) and taken as known: with them in the Jacobian the runoffs'
        twist errors reached the curvature (left-hand drive's bank 0.267 -> 0.308 deg, same
        vision). Gated like every update."""
        if not (self.x[S.SPEED] > 1.0 and math.isfinite(twist_rad_m)):
            return False
        ok, d2, x, P, y, K, Sm, SI = _road_twist_update(self.x, self.P, float(twist_rad_m), float(sigma_rad_m),
                                                         float(lookahead_m), self._sigma_params, self._gate[1])
        return self._accept(ok, d2, x, P, y, K, Sm, SI, np.array([twist_rad_m]))

    def specific_force_model(self, gyro_rad_s, gyro_dot_rad_s2, road_turn_rate_rad_s: float = 0.0):
        """Predicted specific force at the IMU (vehicle axes, m/s^2) and its Jacobian.

        Module docstring, "Gravity reference": the velocity's direction in the body follows
        the relative roll and pitch, and its rate the relative Euler rates (body rates minus
        the road frame's own rotation: heading rate about level z, grade rate about the road's
        level y, bank rate about road x). The Jacobian keeps the grade rate (the accelerometer
        sees a vertical curve's ``v d(grade)/dt``: synthetic hill drive pitch 0.095 -> 0.081 deg
        with it) and takes the bank rate as known. The attitude's columns turn the vehicle's
        acceleration and gravity together with the body: at a steady lean ``d f_y / d roll = g /
        cos(roll)``, not gravity's ``g cos(roll)`` alone; the road's angles, which reach the
        model only through the velocity's small attitude relative to the road, are left out.
        Compiled
        (:func:`_specific_force`): it runs for every IMU sample.
        """
        return _specific_force(self.x, np.asarray(gyro_rad_s, dtype=float), np.asarray(gyro_dot_rad_s2, dtype=float),
                               self._rho, float(road_turn_rate_rad_s), self.has_pitch_rate)

    def update_gravity(self, accel_m_s2, gyro_rad_s, gyro_dot_rad_s2, road_turn_rate_rad_s: float = 0.0,
                       r_scale: float = 1.0, gyro_dot_dt_s: float = math.inf) -> bool:
        """Accelerometer as gravity reference, centripetal and lever-arm terms compensated:
        :meth:`specific_force_model`, then :meth:`gated_update`, in one compiled call. The
        accelerometer noise (:attr:`NoiseModel.accel_meas_m_s2`) is multiplied by ``r_scale``:
        ``f / f_ref`` for gravity updates at ``f`` (:func:`accel_r_scale`). The gyro's noise
        that the model's inputs carry in is added to it (:func:`rate_noise_cov`: all of it in
        the gate, the part that accumulates over samples in the update); ``gyro_dot_dt_s`` is
        the interval over which ``gyro_dot_rad_s2`` was differenced from this sample's rates and
        the previous one's (``inf``: not differenced)."""
        z = np.asarray(accel_m_s2, dtype=float)
        ok, d2, x, P, y, K, Sm, SI = _gravity_update(
            self.x, self.P, z, np.asarray(gyro_rad_s, dtype=float), np.asarray(gyro_dot_rad_s2, dtype=float),
            self._rho, float(road_turn_rate_rad_s), self.has_pitch_rate, self._accel_r(r_scale),
            self._gate[3], self._gyro_var, float(gyro_dot_dt_s))
        return self._accept(ok, d2, x, P, y, K, Sm, SI, z)

    def _accel_r(self, r_scale: float) -> np.ndarray:
        """The accelerometer's noise covariance times ``r_scale`` (one value for a whole drive:
        kept, not multiplied out for every sample)."""
        if r_scale != self._R_accel_scaled[0]:
            self._R_accel_scaled = (r_scale, self._R_accel * r_scale)
        return self._R_accel_scaled[1]

    def update_speed(self, speed_m_s: float) -> bool:
        return self.gated_update_state(S.SPEED, speed_m_s, self._speed_var)

    def propagate_and_update(self, u: ImuStep, speed_m_s: float, accel_m_s2, gyro_rad_s, gyro_dot_rad_s2,
                             gravity: bool, r_scale: float = 1.0,
                             gyro_dot_dt_s: float = math.inf) -> tuple[float, bool, bool]:
        """One IMU sample's whole step in one compiled call: :meth:`propagate` over ``u``, then
        :meth:`update_speed` when ``speed_m_s`` is finite, then :meth:`update_gravity` (with the
        road's heading rate after the propagation) when ``gravity``. The same equations as the
        three calls, in the same order; the per-update attributes of filterpy (``y``, ``S``,
        ``K``) are not set. Returns ``(road turn rate, speed used, gravity used)``; an update
        not attempted counts as used. The prior and the step's ``F`` and ``Q`` are written into
        the filter's own ``x_prior``, ``P_prior``, ``F``, ``Q`` arrays (copy them to keep them):
        arrays returned from the compiled call cost about 1 us each to hand back."""
        road_rate, ok_v, ok_g, d2, self.x, self.P = _imu_step(
            self.x, self.P, *self._interval_args(u), float(speed_m_s), self._speed_var, self._gate[1],
            np.asarray(accel_m_s2, dtype=float), np.asarray(gyro_rad_s, dtype=float),
            np.asarray(gyro_dot_rad_s2, dtype=float), self._rho, gravity, self._accel_r(r_scale), self._gate[3],
            float(gyro_dot_dt_s), self.x_prior, self.P_prior, self.F, self.Q)
        self.x_post, self.P_post = self.x, self.P
        self.last_d2 = d2
        return road_rate, ok_v, ok_g


@nb.njit(cache=True)
def _road_attitude(x):
    """``(R_g'_from_o, R_o_from_v, roll, pitch)``: the road frame against level, the vehicle
    against the road and its ZYX roll and pitch relative to the road."""
    A = R_from_rpy_scalar(x[3], x[4], 0.0)
    R = _tmm(A, R_from_rpy_scalar(x[0], x[1], x[2]))
    return A, R, math.atan2(R[2, 1], R[2, 2]), -math.asin(max(-1.0, min(1.0, R[2, 0])))


@nb.njit(cache=True)
def _specific_force(x, gyro, gyro_dot, rho, road_rate, has_q):
    """Specific-force model and Jacobian; see :meth:`AttitudeEKF.specific_force_model`."""
    g = GRAVITY_M_S2
    phi, theta, v, a = x[0], x[1], x[8], x[9]
    sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta)
    p, q, r = _body_rates(x, gyro, has_q)
    # attitude relative to the road and the road frame's rotation, in o
    A, R, phi_o, theta_o = _road_attitude(x)
    # the road frame's rotation in o: A^T (road turn rate z + grade rate y) + bank rate x
    wo0 = road_rate * A[2, 0] + x[15] * A[1, 0] + x[10]
    wo1 = road_rate * A[2, 1] + x[15] * A[1, 1]
    wo2 = road_rate * A[2, 2] + x[15] * A[1, 2]
    pr = p - (wo0 * R[0, 0] + wo1 * R[1, 0] + wo2 * R[2, 0])
    qr = q - (wo0 * R[0, 1] + wo1 * R[1, 1] + wo2 * R[2, 1])
    rr = r - (wo0 * R[0, 2] + wo1 * R[1, 2] + wo2 * R[2, 2])
    so, co, sto, cto = math.sin(phi_o), math.cos(phi_o), math.sin(theta_o), math.cos(theta_o)
    theta_o_dot = qr * co - rr * so
    phi_o_dot = pr + sto / cto * (qr * so + rr * co)
    # velocity direction in the body and its derivative as seen in the body
    ex, ey, ez = cto, sto * so, sto * co
    dex = -sto * theta_o_dot
    dey = cto * theta_o_dot * so + sto * co * phi_o_dot
    dez = cto * theta_o_dot * co - sto * so * phi_o_dot
    # a_b = a e + v (de + w x e);  gravity g (-sin th, cos th sin ph, cos th cos ph)
    fx = a * ex + v * (dex + q * ez - r * ey) - g * st
    fy = a * ey + v * (dey + r * ex - p * ez) + g * ct * sf
    fz = a * ez + v * (dez + p * ey - q * ex) + g * ct * cf
    # lever arm: w' x rho + w x (w x rho)
    rx, ry, rz = rho[0], rho[1], rho[2]
    wdx, wdy, wdz = gyro_dot[0], gyro_dot[1], gyro_dot[2]
    cx, cy, cz = q * rz - r * ry, r * rx - p * rz, p * ry - q * rx
    f = np.empty(3)
    f[0] = fx + wdy * rz - wdz * ry + q * cz - r * cy + x[11]
    f[1] = fy + wdz * rx - wdx * rz + r * cx - p * cz + x[12]
    f[2] = fz + wdx * ry - wdy * rx + p * cy - q * cx + x[13]
    # the wheelbase (rho[3], 0 without one): the rear wheel rolls without side slip, so the origin
    # (the front contact) moves sideways in the road plane at L w_n, w_n = w . e_n the heading
    # rate about the road's normal e_n, along e_lat (the body's y in the road plane); its
    # acceleration in the body: L (w_n' e_lat + w_n (de_lat + w x e_lat)), w_n' = w' . e_n +
    # w . de_n. In a steady turn that is -L w_n^2 along the path, entering a curve L w_n' across
    # it (module docstring, "The wheelbase")
    wb = rho[3] if rho.shape[0] > 3 else 0.0
    if wb != 0.0:
        nx, ny, nz = -sto, so * cto, co * cto                    # e_n in the body
        lx, ly, lz = 0.0, co, -so                                # e_lat in the body
        dnx = -cto * theta_o_dot
        dny = co * cto * phi_o_dot - so * sto * theta_o_dot
        dnz = -so * cto * phi_o_dot - co * sto * theta_o_dot
        dly, dlz = -so * phi_o_dot, -co * phi_o_dot
        w_n = p * nx + q * ny + r * nz
        w_n_dot = wdx * nx + wdy * ny + wdz * nz + p * dnx + q * dny + r * dnz
        # w x e_lat
        kx, ky, kz = q * lz - r * ly, r * lx - p * lz, p * ly - q * lx
        f[0] += wb * (w_n_dot * lx + w_n * kx)
        f[1] += wb * (w_n_dot * ly + w_n * (dly + ky))
        f[2] += wb * (w_n_dot * lz + w_n * (dlz + kz))
    # Jacobian. Rates enter through w x e and through de (the relative Euler rates):
    # df/dw = v (-[e]x + de/dtheta_o (0, cos, -sin) + de/dphi_o (1, tan sin, tan cos)); the
    # two cancel for a body pitching relative to its path, so a pitch-rate bias does not
    # show in f_z. The angles' columns are below.
    tto = sto / cto
    t0, t1, t2 = -sto, cto * so, cto * co       # de/dtheta_o
    h0, h1, h2 = 0.0, sto * co, -sto * so      # de/dphi_o
    J = np.empty((3, 3))                        # columns p, q, r; d(w x e)/dw = -[e]x
    J[0, 0], J[0, 1], J[0, 2] = h0, ez + t0 * co + h0 * tto * so, -ey - t0 * so + h0 * tto * co
    J[1, 0], J[1, 1], J[1, 2] = -ez + h1, t1 * co + h1 * tto * so, ex - t1 * so + h1 * tto * co
    J[2, 0], J[2, 1], J[2, 2] = ey + h2, -ex + t2 * co + h2 * tto * so, -t2 * so + h2 * tto * co
    H = np.zeros((3, DIM_X))
    for i in range(3):
        H[i, 11 + i] = 1.0
    H[0, 9], H[1, 9], H[2, 9] = ex, ey, ez
    if v > 0.1:
        H[0, 8], H[1, 8], H[2, 8] = (fx + g * st - a * ex) / v, (fy - g * ct * sf - a * ey) / v, (fz - g * ct * cf - a * ez) / v
    # the grade rate turns the road frame, hence the path: d f / d grade_rate through de
    ga, gb, gc = A[1, 0], A[1, 1], A[1, 2]
    g_p = -(ga * R[0, 0] + gb * R[1, 0] + gc * R[2, 0])
    g_q = -(ga * R[0, 1] + gb * R[1, 1] + gc * R[2, 1])
    g_r = -(ga * R[0, 2] + gb * R[1, 2] + gc * R[2, 2])
    d_th = g_q * co - g_r * so
    d_ph = g_p + tto * (g_q * so + g_r * co)
    H[0, 15] = v * (-sto * d_th)
    H[1, 15] = v * (cto * d_th * so + sto * co * d_ph)
    H[2, 15] = v * (cto * d_th * co - sto * so * d_ph)
    # the rates: v times J, and the lever arm's w x (w x rho) = w (w . rho) - rho |w|^2, whose
    # derivative is (w . rho) I + w rho^T - 2 rho w^T (left out before: at 0.5 rad/s and 0.5 m
    # up to 0.5 m/s^2 per rad/s, a review)
    w3 = (p, q, r)
    wr = p * rho[0] + q * rho[1] + r * rho[2]
    M = np.empty((3, 3))
    for i in range(3):
        for k in range(3):
            M[i, k] = v * J[i, k] + w3[i] * rho[k] - 2.0 * rho[i] * w3[k] + (wr if i == k else 0.0)
    if wb != 0.0:
        # the wheelbase's terms by the rates, the relative Euler rates' share left out (second
        # order): L (e_lat de_n^T + (de_lat + w x e_lat) e_n^T - w_n [e_lat]x)
        el, en, den = (lx, ly, lz), (nx, ny, nz), (dnx, dny, dnz)
        acr = (kx, dly + ky, dlz + kz)
        skew = ((0.0, -lz, ly), (lz, 0.0, -lx), (-ly, lx, 0.0))   # [e_lat]x
        for i in range(3):
            for k in range(3):
                M[i, k] += wb * (el[i] * den[k] + acr[i] * en[k] - w_n * skew[i][k])
    for i in range(3):
        if has_q:
            H[i, 5], H[i, 6], H[i, 7] = -M[i, 0], -M[i, 1], -M[i, 2]
        else:  # q = r tan(phi) - x[6]: r carries q
            H[i, 5], H[i, 6] = -M[i, 0], -M[i, 1]
            H[i, 7] = -(M[i, 2] + M[i, 1] * math.tan(x[0]))
    # The attitude's columns: the vehicle's acceleration and gravity, (fx, fy, fz), are fixed in
    # the level frame, and an attitude error turns all of it in the body: d f / d roll = f x
    # e_x, d f / d pitch = f x (0, cos(roll), -sin(roll)) (the pitch turns about the level y
    # axis, seen in the body). At a steady lean f = (0, 0, g / cos(roll)): d f_y / d roll = g /
    # cos(roll), where gravity's part alone, g cos(roll) and -g sin(roll) in f_z, was the
    # Jacobian before (at 45 deg of lean half the roll information of every update, a review's
    # central differences, 2026-11-27). The lever arm's terms and the biases are the body's own
    # and do not turn. The heading rate is not differentiated: from the body rates it would take
    # the suspension's pitching at a lean for a turn of the path (the docstring's level-frame
    # form, tried: it made the lateral accelerometer bias observable on a straight from the
    # pitch oscillation, and the right-hand drive's bank went 0.18 -> 0.77 deg). The road's
    # angles (yaw_rel, bank, grade) reach the model only through the velocity's small attitude
    # relative to the road and are left out with it (their exact columns made the bank
    # observable from the accelerometer without vision, where no sensor sees it). With a
    # pitch gyro the measured rates are the path's turn plus the body's own motion on it, so
    # the path's turn does not move with an attitude error; without one, below.
    H[0, 0], H[1, 0], H[2, 0] = 0.0, fz, -fy
    H[0, 1], H[1, 1], H[2, 1] = -fy * sf - fz * cf, fx * sf, fx * cf
    if not has_q:
        # Without a pitch gyro the rate the model takes for q is r tan(roll) - x[6], and the
        # columns stay as they were: the roll's gravity's plus the one through q by the rates'
        # Jacobian, the pitch's gravity's alone. This is not the model's whole derivative (at a
        # steady 11 deg turn (9.22, -1.86) m/s^2 per rad in f_y, f_z against (9.61, 0.08),
        # whose f_z part, g sin(roll) tan(roll)^2, comes from the heading rate r / cos(roll)
        # turning with the roll), but with the whole one, or the turning above, the left-hand
        # drive's bank went from 0.10 to 0.29-0.38 deg (test_pitching_without_a_pitch_gyro_
        # does_not_bias_the_bank): the lateral accelerometer bias and the world roll, which the
        # accelerometer cannot tell apart, then drift apart. Left as a finding (notes).
        for i in range(3):
            H[i, 0] = M[i, 1] * r / (cf * cf)
        H[1, 0] += g * ct * cf
        H[2, 0] -= g * ct * sf
        H[0, 1], H[1, 1], H[2, 1] = -g * ct, -g * st * sf, -g * st * cf
    return f, H


# ---- compiled kernels: they run for every IMU sample ----
# State indices as in S: 0 roll_w, 1 pitch_w, 2 yaw_rel, 3 bank, 4 grade, 5-7 gyro bias,
# 8 speed, 9 accel_x, 10 bank_rate, 11-13 accel bias, 14 curvature, 15 grade_rate.


@nb.njit(cache=True)
def _body_rates(x, gyro, has_q):
    """Bias-corrected (p, q, r); ``q = r tan(roll_w) - x[6]`` without a pitch-rate gyro (``x[6]``:
    the pitch rate the kinematic relation leaves out, :attr:`NoiseModel.no_pitch_rate_sigma_rad_s`)."""
    p, q, r = gyro[0] - x[5], gyro[1] - x[6], gyro[2] - x[7]
    if not has_q:
        q = r * math.tan(x[0]) - x[6]
    return p, q, r


@nb.njit(cache=True)
def _road_turn_rate(x, gyro, follow, offset, has_q):
    """:meth:`AttitudeEKF.road_turn_rate`."""
    if follow:
        p, q, r = _body_rates(x, gyro, has_q)
        return (q * math.sin(x[0]) + r * math.cos(x[0])) / math.cos(x[1])
    k = x[14]
    return k * x[8] * math.cos(x[2]) / max(1.0 - k * offset, 0.2)


@nb.njit(cache=True)
def _predict_x(x0, gyro, dt, follow, offset, has_q, taus, rate_target=0.0):
    """Process model of the module docstring over one interval ``dt``; ``taus``: the bank rate's
    and the grade rate's correlation times; ``rate_target``: the bank rate's mean (rad/s)."""
    x = x0.copy()
    p, q, r = _body_rates(x, gyro, has_q)
    R = _mm(R_from_rpy_scalar(x[0], x[1], x[2]), so3_exp_scalar(p * dt, q * dt, r * dt))
    roll, pitch, yaw = rpy_from_R_scalar(R)
    x[0], x[1] = roll, pitch
    if not follow:
        x[2] = yaw - _road_turn_rate(x, gyro, False, offset, has_q) * dt
    x[3] += x[10] * dt
    x[10] = rate_target + (x[10] - rate_target) * math.exp(-dt / taus[0])
    x[4] += x[15] * dt
    x[15] *= math.exp(-dt / taus[1])
    if not has_q:
        x[6] *= math.exp(-dt / taus[2])
    x[8] += x[9] * dt
    return x


@nb.njit(cache=True)
def _transition(x, gyro, dt, follow, offset, has_q, taus, q_per_s, gyro_var, yaw_walk_var):
    """Jacobian ``F = I + A dt`` and process noise ``Q`` of one interval.

    ``A`` is the derivative of the ZYX Euler-rate equations ``roll' = p + tan(th) (q sin(ph)
    + r cos(ph))``, ``pitch' = q cos(ph) - r sin(ph)``, ``yaw' = (q sin(ph) + r cos(ph)) /
    cos(th) - road_turn_rate`` with ``(p, q, r) = gyro - bias``; ``Q``: the gyro noise through
    the same equations (``E``), the random walks per second times ``dt``, and the integrated
    walks' own share (speed from acceleration, bank and grade from their rates).
    """
    phi, theta, psi = x[0], x[1], x[2]
    sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta)
    tt = st / ct
    p, q, r = _body_rates(x, gyro, has_q)
    F = np.eye(16)
    E = np.zeros((3, 3))
    if has_q:
        qs_rc = q * sf + r * cf
        F[0, 0], F[0, 1], F[0, 5], F[0, 6], F[0, 7] = 1.0 + tt * (q * cf - r * sf) * dt, qs_rc / ct**2 * dt, -dt, -tt * sf * dt, -tt * cf * dt
        F[1, 0], F[1, 6], F[1, 7] = (-q * sf - r * cf) * dt, -cf * dt, sf * dt
        F[2, 0], F[2, 1], F[2, 6], F[2, 7] = (q * cf - r * sf) / ct * dt, qs_rc * st / ct**2 * dt, -sf / ct * dt, -cf / ct * dt
        E[0, 0], E[0, 1], E[0, 2] = 1.0, sf * tt, cf * tt
        E[1, 1], E[1, 2] = cf, -sf
        E[2, 1], E[2, 2] = sf / ct, cf / ct
    else:  # q = r tan(phi) - x[6]: the pitch rate is the Gauss-Markov state's
        u6 = x[6]
        d_phi = r * sf / cf**2 - u6 * cf             # d(q sin(phi) + r cos(phi)) / d(phi)
        qs_rc = r / cf - u6 * sf                     # q sin(phi) + r cos(phi)
        F[0, 0], F[0, 1], F[0, 5], F[0, 7] = 1.0 + tt * d_phi * dt, qs_rc / ct**2 * dt, -dt, -tt / cf * dt
        F[1, 0] = u6 * sf * dt
        F[2, 0], F[2, 1], F[2, 7] = d_phi / ct * dt, qs_rc * st / ct**2 * dt, -dt / (cf * ct)
        F[0, 6], F[1, 6], F[2, 6] = -tt * sf * dt, -cf * dt, -sf / ct * dt
        F[6, 6] = math.exp(-dt / taus[2])
        E[0, 0], E[0, 2] = 1.0, tt / cf
        E[2, 2] = 1.0 / (cf * ct)
    if follow:  # road turns with the vehicle: yaw relative to the road is held
        F[2, 0] = F[2, 1] = F[2, 6] = F[2, 7] = 0.0
        E[2, 0] = E[2, 1] = E[2, 2] = 0.0
    else:
        k = x[14]
        scale = 1.0 / max(1.0 - k * offset, 0.2)
        F[2, 2] = 1.0 + k * x[8] * math.sin(psi) * scale * dt
        F[2, 8] = -k * math.cos(psi) * scale * dt
        F[2, 14] = -x[8] * math.cos(psi) * scale**2 * dt   # d(k / (1 - k d))/dk = scale^2
    F[8, 9] = dt
    F[3, 10] = dt
    F[10, 10] = math.exp(-dt / taus[0])
    F[4, 15] = dt
    F[15, 15] = math.exp(-dt / taus[1])
    Q = np.zeros((16, 16))
    for i in range(16):
        Q[i, i] = q_per_s[i] * dt
    # the Gauss-Markov rates exactly: dx = -x / tau dt + dW (density q) adds q tau / 2 (1 -
    # exp(-2 dt / tau)) over dt, so that with q = 2 sigma^2 / tau the stationary variance is
    # sigma^2 at any dt (q dt, Euler, gave sigma^2 / (1 - dt / 2 tau): 0.5-2.5 % over at 100 Hz)
    Q[10, 10] = q_per_s[10] * taus[0] * 0.5 * -math.expm1(-2.0 * dt / taus[0])
    Q[15, 15] = q_per_s[15] * taus[1] * 0.5 * -math.expm1(-2.0 * dt / taus[1])
    if not has_q:
        Q[6, 6] = q_per_s[6] * taus[2] * 0.5 * -math.expm1(-2.0 * dt / taus[2])
    g2 = gyro_var * dt * dt
    for i in range(3):
        for j in range(3):
            Q[i, j] += (E[i, 0] * E[j, 0] + E[i, 1] * E[j, 1] + E[i, 2] * E[j, 2]) * g2
    if follow:
        Q[2, 2] += yaw_walk_var * dt
    Q[8, 8] += q_per_s[9] * dt**3 / 3.0
    Q[8, 9] = Q[9, 8] = q_per_s[9] * dt**2 / 2.0
    Q[3, 3] += q_per_s[10] * dt**3 / 3.0
    Q[3, 10] = Q[10, 3] = q_per_s[10] * dt**2 / 2.0
    Q[4, 4] += q_per_s[15] * dt**3 / 3.0
    Q[4, 15] = Q[15, 4] = q_per_s[15] * dt**2 / 2.0
    return F, Q


@nb.njit(cache=True)
def _propagate_cov(P, F, Q):
    """``F P F^T + Q``, symmetrised."""
    P1 = _mmt(_mm(F, P), F) + Q
    return (P1 + P1.T) * 0.5


@nb.njit(cache=True)
def _inv_gauss_jordan(M):
    """Inverse of a small square matrix, Gauss-Jordan with partial pivoting."""
    n = M.shape[0]
    A = M.copy()
    out = np.eye(n)
    for c in range(n):
        piv = c
        for r in range(c + 1, n):
            if abs(A[r, c]) > abs(A[piv, c]):
                piv = r
        if piv != c:
            for j in range(n):
                A[c, j], A[piv, j] = A[piv, j], A[c, j]
                out[c, j], out[piv, j] = out[piv, j], out[c, j]
        d = A[c, c]
        for j in range(n):
            A[c, j] /= d
            out[c, j] /= d
        for r in range(n):
            if r != c:
                f = A[r, c]
                if f != 0.0:
                    for j in range(n):
                        A[r, j] -= f * A[c, j]
                        out[r, j] -= f * out[c, j]
    return out


@nb.njit(cache=True)
def _inv_small(M):
    """Inverse of a symmetric 1x1, 2x2 or 3x3 matrix by cofactors, else by Gauss-Jordan
    elimination with partial pivoting (no LAPACK: see :func:`_mm`)."""
    n = M.shape[0]
    if n == 1:
        out = np.empty((1, 1))
        out[0, 0] = 1.0 / M[0, 0]
        return out
    if n == 2:
        a, b, d = M[0, 0], M[0, 1], M[1, 1]
        det = a * d - b * b
        out = np.empty((2, 2))
        out[0, 0], out[0, 1], out[1, 0], out[1, 1] = d / det, -b / det, -b / det, a / det
        return out
    if n != 3:
        return _inv_gauss_jordan(M)
    a, b, c, d, e, f = M[0, 0], M[0, 1], M[0, 2], M[1, 1], M[1, 2], M[2, 2]
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * A + b * B + c * C
    D, E, F = a * f - c * c, b * c - a * e, a * d - b * b
    out = np.empty((3, 3))
    out[0, 0], out[0, 1], out[0, 2] = A / det, B / det, C / det
    out[1, 0], out[1, 1], out[1, 2] = B / det, D / det, E / det
    out[2, 0], out[2, 1], out[2, 2] = C / det, E / det, F / det
    return out


@nb.njit(cache=True)
def _gated_update(x, P, y, H, R, gate):
    """Chi-square gate and EKF update (:meth:`AttitudeEKF.gated_update`): returns
    ``(accepted, d2, x, P, K, S, S^-1)``; ``x`` and ``P`` unchanged when rejected."""
    PHT = _mmt(P, H)
    Sm = _mm(H, PHT) + R
    SI = _inv_small(Sm)
    d2 = _mahalanobis2(y, SI)
    if not d2 <= gate:   # NaN rejects too
        return False, d2, x, P, PHT, Sm, SI
    K, x1, P1 = _kalman_step(x, P, y, PHT, SI)
    return True, d2, x1, P1, K, Sm, SI


@nb.njit(cache=True)
def _mahalanobis2(y, SI):
    """``y^T S^-1 y``."""
    SIy = _mv(SI, y)
    d2 = 0.0
    for i in range(y.size):
        d2 += y[i] * SIy[i]
    return d2


@nb.njit(cache=True)
def _kalman_step(x, P, y, PHT, SI):
    """The update by residual ``y`` given ``P H^T`` and ``S^-1``: ``(K, x, P)``, ``P``
    symmetrised."""
    K = _mm(PHT, SI)
    x1 = x + _mv(K, y)
    P1 = P - _mmt(K, PHT)
    return K, x1, (P1 + P1.T) * 0.5


@nb.njit(cache=True)
def _propagate(x, P, gyro, dt, follow, offset, has_q, taus, q_per_s, gyro_var, yaw_walk_var, rate_target=0.0):
    """:meth:`AttitudeEKF.propagate`: ``F, Q`` at the prior state, the state through the process
    model, ``P = F P F^T + Q``, and the road's heading rate at the new state."""
    F, Q = _transition(x, gyro, dt, follow, offset, has_q, taus, q_per_s, gyro_var, yaw_walk_var)
    x1 = _predict_x(x, gyro, dt, follow, offset, has_q, taus, rate_target)
    return x1, _propagate_cov(P, F, Q), F, Q, _road_turn_rate(x1, gyro, follow, offset, has_q)


@nb.njit(cache=True)
def _propagate_into(x, P, gyro, dt, follow, offset, has_q, taus, q_per_s, gyro_var, yaw_walk_var, rate_target,
                    x_prior, P_prior, F_out, Q_out):
    """:func:`_propagate`, the prior, ``F`` and ``Q`` written into the last four arrays (two
    arrays returned instead of four, and no copies of the prior in Python): ``(x, P,
    road_rate)``."""
    x1, P1, F, Q, road_rate = _propagate(x, P, gyro, dt, follow, offset, has_q, taus, q_per_s, gyro_var, yaw_walk_var,
                                         rate_target)
    _store_step(x1, P1, F, Q, x_prior, P_prior, F_out, Q_out)
    return x1, P1, road_rate


@nb.njit(cache=True)
def _store_step(x1, P1, F, Q, x_prior, P_prior, F_out, Q_out):
    """A propagation's prior, ``F`` and ``Q`` copied into the filter's own arrays (what
    :func:`_propagate_into` and :func:`_imu_step` hand back instead of returning them)."""
    x_prior[:] = x1
    P_prior[:, :] = P1
    F_out[:, :] = F
    Q_out[:, :] = Q


@nb.njit(cache=True)
def rate_noise_cov(x, H, rho, has_q, gyro_var, dot_dt):  # pragma: no cover (numba)
    """What the gyro's white noise (``gyro_var``, rad^2/s^2 per sample and axis) carries into
    the specific-force model through its inputs, as covariances (m/s^2)^2 ``(white, sample)``.
    The inputs are the rates, in the path's turn ``v (w x e)`` and the lever arm's ``w x (w x
    rho)``, and the angular acceleration differenced from this sample's rates and the previous
    one's over ``dot_dt`` s, in the lever arm's ``w' x rho``. With ``n_k, n_k-1`` the two
    samples' noise the model's error is ``(J_w + J_a / dt) n_k - (J_a / dt) n_k-1``:

    * ``sample``, its covariance, ``gyro_var ((J_w + J_a / dt)(J_w + J_a / dt)^T + (J_a / dt)
      (J_a / dt)^T)``, is what one sample's innovation carries: the gate's;
    * ``white``, ``gyro_var J_w J_w^T``, is what accumulates over samples: the differenced part
      telescopes (its sum over samples ``k..m`` is ``J_a (n_m - n_k-1) / dt``), so it adds
      almost nothing to an average over many samples whose weights change slowly from one to
      the next, which is what the filter takes of them: the update's.

    ``H`` is :func:`_specific_force`'s Jacobian, whose gyro-bias columns are minus the model's
    whole ``d f / d w`` (the path's turn, the lever arm's and the wheelbase's terms). Without a
    pitch gyro its channel carries no noise (``q = r tan(roll)``).
    ``dot_dt`` not finite: not differenced.

    The sample's part is not small: a 0.05 deg/s gyro differenced at 100 Hz is 0.12 rad/s^2 of
    angular acceleration noise, 0.06 m/s^2 at an IMU 0.5 m above the roll axis (0.05 deg/s times
    22 m/s is another 0.02 m/s^2, white), against a simulated accelerometer's 0.03: left out of
    the gate, 10 % of the benchmark drives' gravity updates failed its 0.999 (0.1 % expected).
    In the update as well, the banks were as good but the sigmas wider still (the 60 s drive's
    NEES share 60 -> 54 %, over ten accelerometer-bias draws of the right-hand drive 56 -> 45 %)."""
    # d f / d w is minus H's gyro-bias columns: the path's turn, the lever arm's centripetal
    # term and the wheelbase's (the lever arm's was added here as well until the twenty-fifth
    # session, counted twice since H's columns took it in the thirteenth)
    Jw = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            Jw[i, j] = -H[i, 5 + j]
    inv = 1.0 / dot_dt if math.isfinite(dot_dt) and dot_dt > 0.0 else 0.0
    # d (w' x rho) / d w' = -[rho]x
    Ja = np.array([[0.0, rho[2], -rho[1]], [-rho[2], 0.0, rho[0]], [rho[1], -rho[0], 0.0]]) * inv
    wb = rho[3] if rho.shape[0] > 3 else 0.0
    if wb != 0.0:
        # the wheelbase's L (w' . e_n) e_lat (_specific_force), e_n and e_lat from the attitude
        # relative to the road
        _, _, phi_o, theta_o = _road_attitude(x)
        so, co, sto, cto = math.sin(phi_o), math.cos(phi_o), math.sin(theta_o), math.cos(theta_o)
        en, el = (-sto, so * cto, co * cto), (0.0, co, -so)
        for i in range(3):
            for j in range(3):
                Ja[i, j] += wb * el[i] * en[j] * inv
    if not has_q:
        # no pitch channel, no noise on it: q = r tan(roll) moves with r, which H's column 7
        # carries (its column 6 is the modelled pitch rate's state, not a measured rate)
        for i in range(3):
            Jw[i, 1] = 0.0
            Ja[i, 1] = 0.0
    A = Jw + Ja
    return gyro_var * (Jw @ Jw.T), gyro_var * (A @ A.T + Ja @ Ja.T)


@nb.njit(cache=True)
def _gravity_update(x, P, z, gyro, gyro_dot, rho, road_rate, has_q, R, gate, gyro_var, dot_dt):
    """:meth:`AttitudeEKF.update_gravity`: ``(accepted, d2, x, P, y, K, S, S^-1)``, gated with the
    gyro noise one sample carries and updated with the part that accumulates
    (:func:`rate_noise_cov`); a rejection returns the gate's ``S``."""
    f, H = _specific_force(x, gyro, gyro_dot, rho, road_rate, has_q)
    y = z - f
    white, full = rate_noise_cov(x, H, rho, has_q, gyro_var, dot_dt)
    PHT = _mmt(P, H)
    S0 = _mm(H, PHT)
    S_gate = S0 + R + full
    SI = _inv_small(S_gate)
    d2 = _mahalanobis2(y, SI)
    if not d2 <= gate:   # NaN rejects too
        return False, d2, x, P, y, PHT, S_gate, SI
    Sm = S0 + R + white
    SI = _inv_small(Sm)
    K, x1, P1 = _kalman_step(x, P, y, PHT, SI)
    return True, d2, x1, P1, y, K, Sm, SI


@nb.njit(cache=True)
def _update_state(x, P, i, y, Sm):
    """Update by a measurement of state ``i`` with residual ``y`` and innovation variance ``Sm``."""
    K = P[:, i] / Sm
    Pi = P[i, :].copy()
    P1 = P.copy()
    for a in range(P.shape[0]):
        ka = K[a]
        if ka != 0.0:
            for b in range(P.shape[1]):
                P1[a, b] -= ka * Pi[b]
    return x + K * y, P1, K


@nb.njit(cache=True)
def _lane_plane_curvature(x, moving):
    """The lane curvature the vision measures, as the state has it: ``(kappa_plane,
    d kappa_plane / d kappa)``.

    The estimator fits the lines in the road's tangent plane at the vehicle (the surface's
    vertical curvature taken out, :mod:`vision.lanemodel`), so it measures the lines' geodesic
    curvature: the part of their curvature vector along the road's lateral axis. The state's
    ``kappa`` is the horizontal curvature, whose heading rate the level frame integrates (and the
    truth's ``curvature_1_m``). With the lateral axis ``cos(bank) h + sin(bank) up`` and a line's
    curvature vector ``kappa h + kv up`` (``kv = -grade_rate / v``, the vertical curve, a sag
    positive; its normal part ``kv cos(bank) - kappa sin(bank)`` is the vision's
    ``vertical_curvature``, which the pitch's model takes to first order, ``kv - kappa
    sin(bank)``)::

        kappa_plane = kappa cos(bank) + kv sin(bank)

    exact for the circles of a steadily banked curve (a cone: a circle of horizontal radius
    ``R`` has geodesic curvature ``cos(bank) / R``). On the simulator's exact marker edges the
    lane fit on the 250 m curve banked 5 deg is ``cos(5 deg)`` times the unbanked fit to 7e-9 1/m
    (``tests/test_vision_geometry.py``); read as the horizontal curvature it was 0.38 % low at 5
    deg, 0.55 % at 6, 0.75 % at 7, which the yaw-rate bias took up through ``r - kappa v`` (0.022
    deg/s at 25 m/s on 250 m). Forward filter on the bench's banked drives (their configs, the
    cached vision), yaw-rate bias error at the end, car left / motorcycle left / motorcycle right /
    car right / car hold-out / motorcycle hold-out: +0.070 / +0.019 / -0.031 / -0.166 / +0.020 /
    +0.021 -> +0.062 / +0.011 / -0.015 / -0.150 / +0.017 / +0.019 deg/s; bank RMSE 0.302 / 0.216 /
    0.114 / 0.157 / 0.296 / 0.219 -> 0.298 / 0.214 / 0.116 / 0.152 / 0.299 / 0.222 deg; roll
    and pitch within 0.001 deg, yaw 0.052 / 0.095 / 0.090 / 0.086 / 0.060 / 0.057 -> 0.053 /
    0.096 / 0.091 / 0.092 / 0.059 / 0.056 deg. Most of the vision's curvature error on those
    drives is not this term: the lane polynomial's missing quartic of an arc (-0.35 % at 28 m,
    banked or not), the edges (-0.8 to +0.4 % from drive to drive, bank or not), and the
    estimator's surface, whose vertical curvature does not grow towards the inside of the curve
    as the cone's does (``zeta (1 + kappa y)``), +0.14 % on the 5 deg frames."""
    b = x[3]
    kv = -x[15] / x[8] if moving else 0.0
    c = math.cos(b)
    return x[14] * c + kv * math.sin(b), c


@nb.njit(cache=True)
def _curvature_from_plane(x, kappa_plane, moving):
    """The horizontal curvature (the state's) that a lane fit's ``kappa_plane`` (1/m) says at
    the bank, grade rate and speed of ``x``: :func:`_lane_plane_curvature` inverted,
    ``(kappa_plane - kv sin(bank)) / cos(bank)``. Returns it and ``d kappa_plane / d kappa``."""
    k_plane, per_kappa = _lane_plane_curvature(x, moving)
    return (kappa_plane - (k_plane - per_kappa * x[14])) / per_kappa, per_kappa


def curvature_from_lane_fit(x: np.ndarray, kappa_plane_1_m: float) -> float:
    """The curvature state (horizontal, 1/m) that sets a lane fit's ``kappa_plane_1_m`` at the
    rest of state ``x``: what the first frame and a re-acquisition take (before the twenty-eighth
    session they took the fit's curvature itself, 0.38 % low at 5 deg of bank)."""
    return float(_curvature_from_plane(x, float(kappa_plane_1_m), x[S.SPEED] > 1.0)[0])


@nb.njit(cache=True)
def _bank_turned_ahead(H_roll, x, lookahead_m):
    """The vision roll's part from the road turning over ``lookahead_m`` (roll ahead ``roll_w
    - bank + r``, :func:`road_ahead_as_seen`): returns ``r`` to add to the predicted roll,
    and adds its derivatives to the roll's Jacobian row ``H_roll`` (in place)."""
    if not lookahead_m > 0.0:
        return 0.0
    bank, kappa, grade = x[3], x[14], x[4]
    seen, _, phi = _road_turn(bank, kappa, lookahead_m, grade)
    # derivatives of r ~ bank (1 - cos phi) + grade sin phi, phi = asin(kappa L): to first
    # order in the bank and grade
    H_roll[3] += 1.0 - math.cos(phi)
    H_roll[4] += math.sin(phi)
    H_roll[14] += (bank * math.tan(phi) + grade) * lookahead_m
    return bank - seen


@nb.njit(cache=True)
def _vision_update(x, P, z, own_sig, twist_pitch_m, twist_yaw_m, roll_lookahead_m, defer_roll, bank_rate_ahead,
                   response, road_twist, curvature, curvature_sigma, zeta, pitch_per_zeta, yaw_per_kappa, sig_prm, gate1,
                   gate_angles):
    """:meth:`AttitudeEKF.update_vision` (its docstring has the model): the angles, then the
    curvature. ``sig_prm``: :meth:`NoiseModel._vision_sigma_params`. Returns the angles' ``(ok,
    d2, y, K, S, S^-1)``, the curvature's ``(tried, ok, d2, z, y, S, K)`` (``z``: the lane fit's
    curvature less the twist's modelled effect on it) and the final ``(x, P)``."""
    v = x[8]
    lookahead = roll_lookahead_m if math.isfinite(roll_lookahead_m) and roll_lookahead_m > 0 else 0.0
    moving = v > 1.0
    per_twist = np.zeros(3)            # rad per rad/s of bank rate
    if moving:
        per_twist[1], per_twist[2] = twist_pitch_m / v, twist_yaw_m / v
    effect = np.zeros(3)               # the road-in-view effect modelled, rad (per angle)
    curvature_effect = 0.0             # and on the lane curvature, 1/m
    if moving and not defer_roll:
        dt_ahead = lookahead / v
        x_seen = x.copy()
        x_seen[3] += x[10] * dt_ahead
        H = vision_jacobian(x_seen)
        hx = vision_hx(x_seen) + per_twist * x[10]
        hx[0] += _bank_turned_ahead(H[0], x_seen, lookahead)
        for i in range(3):
            H[i, 10] = H[i, 3] * dt_ahead
            H[i, 10] += per_twist[i]
        effect[0], effect[1], effect[2] = x[10] * dt_ahead, x[10] * per_twist[1], x[10] * per_twist[2]
    else:
        H, hx = vision_jacobian(x), vision_hx(x)
        if moving:
            # Deferred roll. The twist in view is that of the road between the vehicle and
            # the lookahead: its bank rate is taken as the mean of the rate here (state) and
            # the mean rate over the stretch (``bank_rate_ahead``, from the vision roll ahead
            # against the bank here). A known correction, not information on the bank rate:
            # at a runoff's start the errors do not follow the uniform-twist model
            # (measured: of either sign), and read as information they pulled the bank the
            # wrong way by degrees.
            rate = 0.5 * (x[10] + bank_rate_ahead)
            for i in range(3):
                effect[i] = per_twist[i] * rate
            finite = True
            for g in response:
                finite = finite and math.isfinite(g)
            if finite:
                # Yaw and lane curvature: the estimator's own response to the twist here
                # (bank rate) and at its cross-sections (its measured twist; where it measured
                # none, the twist here, a uniform twist), a twist changing across the view
                # included. Where the frame measured no twist, the rate the deferred rolls
                # imply ahead did better on the HD drives (left-hand bank 0.230 against 0.276
                # deg) but ruined the bundled 640x360 drive, whose rolls are noisier (bank
                # 0.453 -> 0.657, world roll 0.346 -> 0.737 deg, worse than the IMU alone;
                # with the twist here 0.517 and 0.583, the IMU alone's 0.588).
                # Pitch keeps the uniform model: with the response it was worse on all
                # three benchmark drives (0.051 / 0.031 / 0.021 -> 0.065 / 0.045 / 0.045 deg).
                effect[2], curvature_effect = _twist_effect(response[0], response[1], response[4], response[5],
                                                            x[10] / v, road_twist)
            hx = hx + effect
    # Faded out as a runoff comes into view (the bank rate here or ahead towards ``sig_prm[10]``):
    # the in-view terms below are the lane fit's, and a runoff's errors are the twist's.
    fade = 1.0
    if moving:
        rate = abs(x[10])
        if math.isfinite(road_twist):
            rate = max(rate, abs(road_twist) * v)
        fade = max(0.0, 1.0 - rate / sig_prm[10])
    if math.isfinite(curvature) and math.isfinite(yaw_per_kappa):
        # The lane fit couples yaw and curvature (a line bent more reads as pointing more to
        # the inside, correlation 0.98 in its covariance): the yaw is modelled with
        # ``yaw_per_kappa`` times the fit's curvature error, the curvature state in the
        # Jacobian. The yaw's noise is then what the curvature does not explain, independent
        # of the curvature's own update below.
        # (the fit's curvature is the road plane's, :func:`_lane_plane_curvature`)
        w = fade * yaw_per_kappa
        k_plane, per_kappa = _lane_plane_curvature(x, moving)
        d_yaw = w * (curvature - curvature_effect - k_plane)
        hx[2] += d_yaw
        effect[2] += d_yaw
        H[2, 14] -= w * per_kappa
    if moving and math.isfinite(zeta) and math.isfinite(pitch_per_zeta):
        # The road's vertical curvature changing across the view (a sag or crest coming into
        # view): the estimator reads the change as pitch, ``pitch_per_zeta`` per 1/m of the
        # curvature it fitted beyond the one at the vehicle, ``-grade_rate / v - kappa
        # sin(bank)`` (the axis's, and the banked curve's). Faded out as a runoff comes into
        # view: there the fitted curvature's change is the bank times the lane curvature
        # changing, whose pitch the twist model carries. With the grade rate in the Jacobian:
        # the vision measures the vertical curve.
        w = fade * pitch_per_zeta
        dzeta = zeta + x[15] / v + x[14] * math.sin(x[3])
        hx[1] += w * dzeta
        effect[1] += w * dzeta
        H[1, 15] += w / v
    first = 1 if defer_roll else 0     # a deferred roll is applied later (RollAhead)
    m = 3 - first
    R = np.zeros((m, m))
    for i in range(m):
        s = _vision_sigma(own_sig[first + i], effect[first + i], sig_prm[0], sig_prm[_FLOOR_AT[first + i]], sig_prm[2])
        R[i, i] = s * s
    if first == 0 and not moving and lookahead > 0.0 and math.isfinite(road_twist):
        # No speed yet (a wheel speed that starts late): the roll is of the road the lookahead
        # ahead, the bank there neither deferred nor modelled (both need the speed). The road's
        # twist in view times the lookahead is the bank change it can hold: in the roll's sigma
        # (a review: in a runoff 1.8-2.2 deg off at a sigma of 0.09-0.12 before).
        R[0, 0] += (road_twist * lookahead) ** 2
    y = _angle_residual(z[first:].copy(), hx[first:].copy())
    ok, d2, x1, P1, K, Sm, SI = _gated_update(x, P, y, H[first:].copy(), R, gate_angles)
    # the lane-fit curvature, gated on its own
    k_tried, k_ok, k_d2, k_z, k_y, k_S, k_K = False, False, math.nan, math.nan, math.nan, math.nan, np.zeros(x.size)
    if math.isfinite(curvature):
        s_k = _curvature_sigma(curvature, curvature_sigma, sig_prm[3], sig_prm[4], sig_prm[5])
        s_k = math.hypot(s_k, sig_prm[2] * curvature_effect)
        k_tried = True
        # the lane fit measures the curvature in the road's plane; as one of the horizontal
        # curvature state: ``(kappa_plane - kv sin(bank)) / cos(bank)`` (:func:`_lane_plane_curvature`)
        k_z, per_kappa = _curvature_from_plane(x1, curvature - curvature_effect, moving)
        s_k = s_k / per_kappa
        k_y = k_z - x1[14]
        k_S = P1[14, 14] + s_k * s_k
        k_d2 = k_y * k_y / k_S
        k_ok = not k_d2 > gate1
        if k_ok:
            x1, P1, k_K = _update_state(x1, P1, 14, k_y, k_S)
    return ok, d2, y, K, Sm, SI, k_tried, k_ok, k_d2, k_z, k_y, k_S, k_K, x1, P1


@nb.njit(cache=True)
def _roll_ahead_update(x, P, z, sigma, dt_ahead, lookahead_m, sig_prm, gate1):
    """:meth:`AttitudeEKF.update_roll_ahead`: ``(ok, d2, x, P, y, K, S, S^-1)``. The lookahead's
    own error (a fraction of it) is a timing error of the bank."""
    s = _vision_sigma(sigma, x[10] * dt_ahead, sig_prm[0], sig_prm[1], sig_prm[2])
    H = vision_jacobian(x)[:1].copy()
    hx = vision_hx(x)[:1].copy()
    hx[0] += _bank_turned_ahead(H[0], x, lookahead_m)
    zz = np.empty(1)
    zz[0] = z
    R = np.empty((1, 1))
    R[0, 0] = s * s
    y = _angle_residual(zz, hx)
    ok, d2, x1, P1, K, Sm, SI = _gated_update(x, P, y, H, R, gate1)
    return ok, d2, x1, P1, y, K, Sm, SI


@nb.njit(cache=True)
def _road_twist_update(x, P, twist, sigma, lookahead_m, sig_prm, gate1):
    """:meth:`AttitudeEKF.update_road_twist` (the speed above 1 m/s, the twist finite):
    ``(ok, d2, x, P, y, K, S, S^-1)``."""
    v = x[8]
    b, k, g = x[3], x[14], x[4]
    _, turned, phi = _road_turn(b, k, lookahead_m, g)
    H = np.zeros((1, x.size))
    H[0, 10] = math.cos(phi) / v
    h = 1e-3   # rad; central difference (``turned`` is linear in the grade to 1e-6)
    H[0, 4] = (_road_turn(b, k, lookahead_m, g + h)[1] - _road_turn(b, k, lookahead_m, g - h)[1]) / (2 * h)
    y = np.empty(1)
    y[0] = twist - (x[10] * math.cos(phi) / v + turned)
    s = _twist_sigma(twist, sigma, sig_prm[6], sig_prm[7])
    R = np.empty((1, 1))
    R[0, 0] = s * s
    ok, d2, x1, P1, K, Sm, SI = _gated_update(x, P, y, H, R, gate1)
    return ok, d2, x1, P1, y, K, Sm, SI


@nb.njit(cache=True)
def _imu_step(x, P, gyro_mean, dt, follow, offset, has_q, taus, q_per_s, gyro_var, yaw_walk_var, rate_target,
              speed, speed_var, gate1, accel, gyro, gyro_dot, rho, gravity, R_accel, gate3, dot_dt,
              x_prior, P_prior, F_out, Q_out):
    """:meth:`AttitudeEKF.propagate_and_update`: ``(road_rate, speed_ok, gravity_ok, last d2, x,
    P)``; the prior, ``F`` and ``Q`` are written into ``x_prior, P_prior, F_out, Q_out`` (every
    array returned is boxed, about 1 us each: four fewer per IMU sample)."""
    x1, P1, F, Q, road_rate = _propagate(x, P, gyro_mean, dt, follow, offset, has_q, taus, q_per_s, gyro_var,
                                         yaw_walk_var, rate_target)
    x2, P2 = x1, P1
    ok_v, ok_g, d2 = True, True, math.nan
    if not math.isnan(speed):
        y = speed - x2[8]
        Sm = P2[8, 8] + speed_var
        d2 = y * y / Sm
        ok_v = d2 <= gate1
        if ok_v:
            x2, P2, _ = _update_state(x2, P2, 8, y, Sm)
    if gravity:
        ok_g, d2, xg, Pg, _, _, _, _ = _gravity_update(x2, P2, accel, gyro, gyro_dot, rho, road_rate, has_q,
                                                       R_accel, gate3, gyro_var, dot_dt)
        x2, P2 = xg, Pg
    _store_step(x1, P1, F, Q, x_prior, P_prior, F_out, Q_out)
    return road_rate, ok_v, ok_g, d2, x2, P2
