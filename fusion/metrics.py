"""Accuracy against ground truth: RMSE per angle and the consistency of the fused sigma.

Used by the report (when the drive has a ``truth.csv``), the benchmark and the tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.stats import chi2

from vision.frames import R_from_rpy_scalar, rpy_from_R_scalar, so3_exp_scalar, wrap_angle

__all__ = ["ANGLES", "rmse_table", "interp_truth", "wrap_deg", "consistency", "Consistency", "gyro_attitude_drift",
           "truth_lane_plane_curvature"]

#: Output angles compared with truth: ``<stem>_deg`` in the estimate and in the truth.
ANGLES = ("roll", "pitch", "yaw", "bank", "roll_world", "pitch_world", "grade")
#: The simulator's name of the road's grade in ``truth.csv`` (``tools/drivesim``): the pitch of
#: the road frame at the vehicle, ``R_w_from_o = Rz(heading) Ry(road_pitch) Rx(bank)``, which is
#: the filter's ``grade`` (``fusion.ekf``: ``R_g'_from_o = Ry(grade) Rx(bank)``), in the pitch
#: convention as ``fused.csv``'s ``grade_deg``: positive downhill.
SIMULATOR_GRADE_COLUMN = "road_pitch_deg"


def interp_truth(truth: pd.DataFrame, t_s: np.ndarray) -> pd.DataFrame:
    """Truth columns linearly interpolated at ``t_s`` (NaN outside the truth's span). Angles
    (``*_deg``) are interpolated the short way round: a heading stepping from 179.9 to -179.9
    deg between two truth samples passes through 180, not 0 (a review measured 3.8 deg of yaw
    RMSE for an estimate equal to such a truth 3 ms off its samples), and come back in
    [-180, 180). A truth without ``grade_deg`` gives the simulator's grade under that name
    (:data:`SIMULATOR_GRADE_COLUMN`)."""
    if "grade_deg" not in truth and SIMULATOR_GRADE_COLUMN in truth:
        truth = truth.assign(grade_deg=truth[SIMULATOR_GRADE_COLUMN])
    tt = truth["t_s"].to_numpy(dtype=float)
    out = {"t_s": t_s}
    for c in truth.columns:
        if c != "t_s" and np.issubdtype(truth[c].dtype, np.number):
            y = truth[c].to_numpy(dtype=float)
            angle = c.endswith("_deg")
            if angle:
                y = y.copy()
                ok = np.isfinite(y)
                y[ok] = np.unwrap(y[ok], period=360.0)
            v = np.interp(t_s, tt, y, left=np.nan, right=np.nan)
            out[c] = wrap_deg(v) if angle else v
    return pd.DataFrame(out)


def truth_lane_plane_curvature(truth: pd.DataFrame) -> np.ndarray:
    """The lane curvature that a lane fit in the road's tangent plane measures, 1/m, per row of a
    truth table (``t_s``, ``curvature_1_m``, ``bank_deg``, ``speed_m_s`` and the grade,
    ``grade_deg`` or the simulator's :data:`SIMULATOR_GRADE_COLUMN`): ``kappa cos(bank) + kv
    sin(bank)``, ``kv = -grade_rate / v`` (the grade's rate differenced over the rows; 0 below
    1 m/s), as the filter models the fit (:func:`fusion.ekf._lane_plane_curvature`). What the
    tests' synthetic vision gives and the tools score the vision's curvature against."""
    t = truth["t_s"].to_numpy(dtype=float)
    grade = np.radians(truth["grade_deg" if "grade_deg" in truth else SIMULATOR_GRADE_COLUMN].to_numpy(dtype=float))
    bank = np.radians(truth["bank_deg"].to_numpy(dtype=float))
    v = truth["speed_m_s"].to_numpy(dtype=float)
    grade_rate = np.gradient(grade, t) if len(t) > 1 else np.zeros(len(t))
    moving = v > 1.0
    kv = np.where(moving, -grade_rate / np.where(moving, v, 1.0), 0.0)
    return truth["curvature_1_m"].to_numpy(dtype=float) * np.cos(bank) + kv * np.sin(bank)


def wrap_deg(a):
    """Angles in deg into [-180, 180)."""
    return (np.asarray(a, dtype=float) + 180.0) % 360.0 - 180.0


def rmse_table(estimate: pd.DataFrame, truth: pd.DataFrame, t_min_s: float = -math.inf,
               angles=ANGLES, valid: np.ndarray | None = None) -> dict[str, float]:
    """RMSE in degrees of each ``<angle>_deg`` column present in both, for ``t_s >= t_min_s``."""
    t = estimate["t_s"].to_numpy(dtype=float)
    tr = interp_truth(truth, t)
    m = t >= t_min_s
    if valid is not None:
        m &= np.asarray(valid, dtype=bool)
    out = {}
    for a in angles:
        c = f"{a}_deg"
        if c in estimate and c in tr:
            e = wrap_deg(estimate[c].to_numpy(dtype=float)[m] - tr[c].to_numpy()[m])
            e = e[np.isfinite(e)]
            out[a] = float(np.sqrt(np.mean(e**2))) if len(e) else math.nan
    return out


@dataclass(frozen=True)
class Consistency:
    """Normalised estimation error squared of (roll, pitch, yaw, bank) against truth."""

    dof: int
    band: tuple[float, float]      # 95 % two-sided chi-square band
    fraction_inside: float         # of samples whose NEES is inside the band
    fraction_above: float          # over-confident samples
    fraction_below: float          # over-cautious samples
    mean_nees: float               # expected: dof
    per_angle_within_2sigma: dict  # fraction of |error| < 2 sigma per angle (expected 0.954)


def consistency(fused: pd.DataFrame, truth: pd.DataFrame, cov: np.ndarray | None = None,
                t_min_s: float = -math.inf, angles=("roll", "pitch", "yaw", "bank")) -> Consistency:
    """NEES per sample. ``cov`` (N, k, k) is the joint covariance of the angles in rad^2 (from
    :func:`fusion.pipeline.output_covariance`); without it the sigma columns are used as if
    the angles were independent."""
    t = fused["t_s"].to_numpy(dtype=float)
    tr = interp_truth(truth, t)
    m = (t >= t_min_s) & np.all([np.isfinite(tr[f"{a}_deg"].to_numpy()) & np.isfinite(fused[f"{a}_deg"].to_numpy())
                                 for a in angles], axis=0)      # (no bank before the first wheel speed)
    e = np.radians(np.stack([fused[f"{a}_deg"].to_numpy(dtype=float) - tr[f"{a}_deg"].to_numpy()
                             for a in angles], axis=1))[m]
    e = wrap_angle(e)
    sig = np.radians(np.stack([fused[f"{a}_sigma_deg"].to_numpy(dtype=float) for a in angles], axis=1))[m]
    if cov is None:
        nees = np.sum((e / sig) ** 2, axis=1)
    else:
        C = cov[m]
        nees = np.einsum("ni,ni->n", e, np.linalg.solve(C, e[..., None])[..., 0])
    k = len(angles)
    lo, hi = chi2.ppf(0.025, k), chi2.ppf(0.975, k)
    inside = (nees >= lo) & (nees <= hi)
    within = {a: float(np.mean(np.abs(e[:, i]) < 2 * sig[:, i])) for i, a in enumerate(angles)}
    return Consistency(k, (float(lo), float(hi)), float(inside.mean()), float((nees > hi).mean()),
                       float((nees < lo).mean()), float(nees.mean()), within)


def gyro_attitude_drift(t_s: np.ndarray, gyro_rad_s: np.ndarray, truth: pd.DataFrame,
                        window_s: float = 1.0, remove_mean: bool = False, return_windows: bool = False):
    """What a gyro leaves out of the attitude: the vehicle-frame rates ``gyro_rad_s`` (N, 3; less
    their bias) integrated as the filter propagates (the rates averaged over each interval,
    exact rotation), over back-to-back windows of ``window_s``, each started from the truth's
    attitude (``roll_world_deg``, ``pitch_world_deg``, ``yaw_world_deg`` at ``t_s``); the RMS
    over the windows of the ZYX angles' error at their ends, each divided by the square root of
    its window's length, deg/sqrt(s) (roll, pitch, yaw). Against the filter's process noise this
    is ``sqrt(gyro_noise^2 dt + attitude_walk^2)``: the gyro's white noise integrated, and what
    the gyro does not see (without a pitch gyro the filter's pitch walks with
    ``no_pitch_rate_walk_rad_sqrt_s`` instead, which this does not measure).
    ``remove_mean``: the windows' mean error taken out first (a constant gyro bias, when the
    rates' is not known), the RMS then over ``n - 1``. Windows spanning a gap in ``t_s`` (longer
    than 1.5 ``window_s``) or a non-finite sample are left out; fewer than 3 windows left raise
    ``ValueError``, as do ``t_s`` not strictly increasing and ``window_s`` not positive. A truth
    without a heading gives the roll and pitch (a rotation about the vertical does not change
    them) and NaN for the yaw. ``return_windows``: ``(drift, number of windows used)``."""
    t = np.asarray(t_s, dtype=float)
    w = np.asarray(gyro_rad_s, dtype=float)
    if t.ndim != 1 or len(t) < 2 or w.shape != (len(t), 3):
        raise ValueError(f"gyro_attitude_drift: t_s must be (N,) and gyro_rad_s (N, 3), got {t.shape} and {w.shape}")
    dt = np.diff(t)
    if not (np.all(np.isfinite(t)) and np.all(dt > 0)):
        raise ValueError("gyro_attitude_drift: t_s must be finite and strictly increasing")
    if not (math.isfinite(window_s) and window_s > 0):
        raise ValueError(f"gyro_attitude_drift: window_s must be a positive number of seconds, got {window_s}")
    tr = interp_truth(truth, t)
    has_yaw = "yaw_world_deg" in tr
    rpy = np.radians(np.stack([tr[f"{a}_world_deg"].to_numpy() if a != "yaw" or has_yaw else np.zeros(len(t))
                               for a in ("roll", "pitch", "yaw")], axis=1))
    tol = 0.5 * float(np.median(dt))  # a window ends on the sample nearest its nominal end
    errors = []
    i = 0
    while True:
        j = max(i + 1, int(np.searchsorted(t, t[i] + window_s - tol)))
        if j >= len(t):
            break
        span = t[j] - t[i]
        if span <= 1.5 * window_s and np.all(np.isfinite(rpy[[i, j]])) and np.all(np.isfinite(w[i:j + 1])):
            R = R_from_rpy_scalar(*rpy[i])
            for k in range(i, j):
                R = R @ so3_exp_scalar(*(0.5 * (w[k] + w[k + 1]) * (t[k + 1] - t[k])))
            errors.append(wrap_angle(np.array(rpy_from_R_scalar(R)) - rpy[j]) / math.sqrt(span))
        i = j
    if len(errors) < 3:
        raise ValueError(f"gyro_attitude_drift: {len(errors)} window(s) of {window_s:g} s where the truth and "
                         "the gyro are both finite; at least 3 are needed")
    e = np.asarray(errors)
    if remove_mean:
        e = e - e.mean(axis=0)
    drift = np.degrees(np.sqrt(np.sum(np.square(e), axis=0) / (len(e) - int(remove_mean))))
    if not has_yaw:
        drift[2] = math.nan
    return (drift, len(e)) if return_windows else drift
