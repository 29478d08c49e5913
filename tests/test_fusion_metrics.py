"""``fusion.metrics.gyro_attitude_drift`` against attitudes whose body rates are known exactly.

The attitude is given in closed form (ZYX roll, pitch, yaw as functions of time) and its body
rates follow from the Euler-rate kinematics, so every figure below has an exact value: a
frame-convention slip in the integration, a window normalised by the wrong length or a
bias removed with the wrong count shows up as a physical error in deg/sqrt(s).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from fusion.metrics import gyro_attitude_drift


def _weave(t: np.ndarray, roll_deg: float = 20.0, pitch_deg: float = 3.0,
           turn_deg_s: float = 10.0) -> tuple[pd.DataFrame, np.ndarray]:
    """A weaving vehicle: roll ``roll_deg`` at 0.5 Hz, pitch ``pitch_deg`` at 1 Hz, heading
    turning ``turn_deg_s``, as a truth table and its exact body rates (p, q, r) in rad/s."""
    a, b, c = math.radians(roll_deg), math.radians(pitch_deg), math.radians(turn_deg_s)
    w1, w2 = math.pi, 2 * math.pi
    phi, th, psi = a * np.sin(w1 * t), b * np.sin(w2 * t), c * t
    dphi, dth, dpsi = a * w1 * np.cos(w1 * t), b * w2 * np.cos(w2 * t), np.full_like(t, c)
    p = dphi - dpsi * np.sin(th)
    q = dth * np.cos(phi) + dpsi * np.cos(th) * np.sin(phi)
    r = -dth * np.sin(phi) + dpsi * np.cos(th) * np.cos(phi)
    wrapped = (np.degrees(psi) + 180.0) % 360.0 - 180.0
    truth = pd.DataFrame({"t_s": t, "roll_world_deg": np.degrees(phi), "pitch_world_deg": np.degrees(th),
                          "yaw_world_deg": wrapped})
    return truth, np.stack([p, q, r], axis=1)


def test_exact_rates_leave_nothing_out_once_the_integration_is_fine():
    """At 1 kHz the midpoint integration of the weave's exact rates errs by ~(w dt)^2: under
    1e-4 deg/sqrt(s) on every axis (a swapped axis or sign would drift degrees per window). At
    100 Hz the same rates leave out a measurable amount, the integration's own (what the
    simulator's drives carry as their attitude allowance), still under the 0.02 deg/sqrt(s)
    their configs allow."""
    t = np.arange(0.0, 20.0, 0.001)
    truth, w = _weave(t)
    drift = gyro_attitude_drift(t, w, truth, 1.0)
    assert np.all(drift < 1e-4), drift
    t100 = t[::10]
    coarse = gyro_attitude_drift(t100, w[::10], truth, 1.0)
    assert np.max(coarse) > 10 * np.max(drift)
    assert np.all(coarse < 0.02), coarse


def test_a_constant_bias_drifts_as_its_rate_times_the_square_root_of_the_window():
    """On a vehicle that only rolls (its x axis fixed), a roll-rate bias b left in the rates errs
    b T at the end of every window of T seconds: b sqrt(T) per sqrt(s) (0.1 deg/s over 4 s
    windows: 0.2 deg/sqrt(s), to 0.1 %), the other axes untouched. Taking the windows' mean out
    leaves the integration's residue only. On the full weave the turning body carries some of
    the bias into pitch and yaw, and the roll's share is smaller."""
    t = np.arange(0.0, 40.0, 0.001)
    truth, w = _weave(t, pitch_deg=0.0, turn_deg_s=0.0)
    b = math.radians(0.1)
    biased = w + np.array([b, 0.0, 0.0])
    drift = gyro_attitude_drift(t, biased, truth, 4.0)
    assert drift[0] == pytest.approx(0.1 * 2.0, rel=0.001)
    assert np.all(drift[1:] < 1e-4)
    assert gyro_attitude_drift(t, biased, truth, 4.0, remove_mean=True)[0] < 1e-4
    truth, w = _weave(t)
    weave = gyro_attitude_drift(t, w + np.array([b, 0.0, 0.0]), truth, 4.0)
    assert weave[0] < 0.2 and max(weave[1:]) > 0.01


def test_white_noise_integrates_to_its_density():
    """White rate noise of sigma per sample at dt integrates to sigma sqrt(dt) per sqrt(s),
    whatever the window (0.1 deg/s at 100 Hz: 0.01 deg/sqrt(s)). 400 windows of 1 s estimate it
    to 3.5 % (1-sigma) and 100 of 4 s to 7 %: bands of 15 % and 25 %, about 4 sigma (measured
    with three seeds: 0.0092-0.0105 and 0.0085-0.0113)."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 400.0, 0.01)
    _, w = _weave(t)
    t_fine = np.arange(0.0, 400.0, 0.001)  # the truth finer than the rates: no interpolation error
    truth, _ = _weave(t_fine)
    sigma = math.radians(0.1)
    noisy = w + rng.normal(0.0, sigma, w.shape)
    for window_s, rel in ((1.0, 0.15), (4.0, 0.25)):
        d = gyro_attitude_drift(t, noisy, truth, window_s, remove_mean=True)
        np.testing.assert_allclose(d, 0.1 * math.sqrt(0.01), rtol=rel, err_msg=str(window_s))


def test_windows_across_a_gap_are_left_out_and_bad_input_is_refused():
    """A 3 s hole in the log (a dropped CAN recording) with a 1 deg/s roll-rate error inside
    would count 3 deg; the window spanning it is left out instead (15 of the 20 s's 1 s windows
    are used against 19 without the hole: the one across it and the three inside it go). Unsorted times, a zero
    window or too few windows raise ValueError instead of looping or dividing by zero."""
    t = np.arange(0.0, 20.0, 0.001)
    truth, w = _weave(t)
    keep = (t < 8.0) | (t >= 11.0)
    tg, wg = t[keep], w[keep].copy()
    wg[np.searchsorted(tg, 11.0) - 1] += [math.radians(1.0) / 0.001 * 3.0, 0.0, 0.0]
    drift, windows = gyro_attitude_drift(tg, wg, truth, 1.0, return_windows=True)
    assert np.all(drift < 1e-4) and windows == 15
    assert gyro_attitude_drift(t, w, truth, 1.0, return_windows=True)[1] == 19
    with pytest.raises(ValueError, match="strictly increasing"):
        gyro_attitude_drift(t[::-1], w[::-1], truth, 1.0)
    with pytest.raises(ValueError, match="positive"):
        gyro_attitude_drift(t, w, truth, 0.0)
    with pytest.raises(ValueError, match="at least 3"):
        gyro_attitude_drift(t, w, truth, 8.0)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        gyro_attitude_drift(t, w[:, :2], truth, 1.0)


def test_the_truths_lane_plane_curvature_is_the_filters_model():
    """``truth_lane_plane_curvature`` (what the tests' synthetic vision gives and the tools score
    the lane fit against) is the filter's model of the fit, :func:`fusion.ekf._lane_plane_curvature`,
    at the truth's bank, speed and grade rate: on a banked curve (6 deg, 1/250 m) going into a sag
    (the grade, positive downhill, falling 0.5 deg/s at 20 m/s: ``kv`` +4.4e-4 1/m) to 1e-12 1/m
    (the grade is linear in time, so the difference is exact), and without ``kv`` below 1 m/s,
    where the filter leaves it out. The ``kv sin(bank)`` term is 4.6e-5 1/m here: a sign slip or
    a missing term fails by 40 million tolerances."""
    from fusion.ekf import _lane_plane_curvature
    from fusion.metrics import truth_lane_plane_curvature
    from fusion.noise import DIM_X, S

    t = np.arange(0.0, 2.0, 0.01)
    bank, kappa, rate = math.radians(6.0), 1 / 250, math.radians(-0.5)
    speed = np.where(t < 1.0, 20.0, 0.5)
    truth = pd.DataFrame({"t_s": t, "curvature_1_m": kappa, "bank_deg": math.degrees(bank),
                          "road_pitch_deg": np.degrees(rate * t), "speed_m_s": speed})
    got = truth_lane_plane_curvature(truth)
    x = np.zeros(DIM_X)
    x[S.CURVATURE], x[S.BANK], x[S.GRADE_RATE] = kappa, bank, rate
    for i in (10, 150):
        x[S.SPEED] = speed[i]
        assert got[i] == pytest.approx(_lane_plane_curvature(x, speed[i] > 1.0)[0], abs=1e-12)
    assert abs(got[10] - kappa * math.cos(bank)) > 4e-5          # the vertical curve's part is there
    assert got[150] == pytest.approx(kappa * math.cos(bank), abs=1e-15)
