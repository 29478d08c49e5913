"""Camera-to-CAN clock offset, estimated from the data.

The vision roll (relative to the road) changes mostly with the vehicle's own roll, which the
gyro's x axis measures; the road's bank changes far more slowly. So the vision roll rate and
the gyro roll rate are the same signal, shifted by the clock offset. The offset is the lag that
maximises their correlation, refined to sub-sample precision by a parabola through the peak.

Its 1-sigma is a block jackknife: the estimate again without each tenth of the drive in turn.
The roll moves in a few manoeuvres, and where one of them decides the lag, the jackknife says so.
Measured on the benchmark drives with the frame times shifted by 0, +50 and -100 ms (errors of
the estimate against the shift, and its sigma): 60 s drive 0.6-0.7 ms (sigma 1.5-9.0), left-hand
drive 5.5-6.5 ms (38-44), bundled 640x360 sample drive 14-17 ms (46-47); on the three others it
declines (peak correlation under 0.6, or the roll barely moves). ``vifusion run`` applies an
estimate only where it is more than twice its sigma away from the configured offset (it estimates
the correction to that offset): a -14 +- 46 ms on a correct clock is no reason to move it.

The road's own bank rate is part of the vision roll rate (the roll is relative to the road),
which biases the lag where runoffs dominate the roll. A high-pass of both rates (their moving
average over 1 or 2 s removed) to suppress it lowered the peak correlation below the threshold
on four of the six drives and moved the 60 s drive's estimate from -0.6 to +4.4 ms: not kept.

The returned ``offset_s`` is what to add to the frame times (``frames.csv``) to put them on
the CAN clock, i.e. the ``[fusion] camera_time_offset_s`` of the config.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

__all__ = ["TimeOffset", "estimate_camera_offset"]

_JACKKNIFE_BLOCKS = 10


@dataclass(frozen=True)
class TimeOffset:
    offset_s: float          # add to frame times; NaN when not estimable
    correlation: float       # peak normalised correlation
    n_frames: int            # vision frames used
    roll_rate_std_deg_s: float
    reason: str = ""         # why it is not estimable, if it is not
    sigma_s: float = math.nan  # 1-sigma of offset_s (block jackknife over the drive)

    @property
    def ok(self) -> bool:
        return math.isfinite(self.offset_s)


def estimate_camera_offset(vision: pd.DataFrame, imu: pd.DataFrame, max_offset_s: float = 0.5,
                           step_s: float = 0.002, min_correlation: float = 0.6,
                           min_roll_rate_std_deg_s: float = 1.0) -> TimeOffset:
    """Cross-correlate the vision roll rate with the gyro roll rate (see module docstring).

    Parameters
    ----------
    vision : DataFrame with ``t_s``, ``roll_deg``, ``valid``
    imu : DataFrame with ``t_s``, ``gyro_x_rad_s`` (vehicle frame)
    """
    from scipy.signal import savgol_filter

    v = vision[vision["valid"].astype(bool)].sort_values("t_s")
    tv = v["t_s"].to_numpy(dtype=float)
    roll = np.radians(v["roll_deg"].to_numpy(dtype=float))
    if len(tv) < 20:
        return TimeOffset(math.nan, math.nan, len(tv), math.nan, "fewer than 20 valid vision frames")
    ti = imu["t_s"].to_numpy(dtype=float)
    p = imu["gyro_x_rad_s"].to_numpy(dtype=float)
    good = np.isfinite(p)
    ti, p = ti[good], p[good]
    if len(ti) < 2:
        return TimeOffset(math.nan, math.nan, 0, math.nan, "no gyro roll rate")
    # Uniform grid at the frame rate over the overlap; grid points more than two frames from a
    # valid frame are left out (lane loss).
    frame_dt = float(np.median(np.diff(tv)))
    lo, hi = max(tv[0], ti[0] + max_offset_s), min(tv[-1], ti[-1] - max_offset_s)
    if hi - lo < 20 * frame_dt:
        return TimeOffset(math.nan, math.nan, 0, math.nan, "too little overlap between vision and IMU")
    grid = np.arange(lo, hi, frame_dt)
    near = np.abs(tv[np.clip(np.searchsorted(tv, grid), 0, len(tv) - 1)] - grid) <= 2 * frame_dt
    roll_g = np.interp(grid, tv, roll)
    # Savitzky-Golay over ~0.3 s: the derivative of the vision roll, and the same smoothing of
    # the gyro rate, so that both have the same bandwidth.
    win = max(5, int(round(0.3 / frame_dt)) | 1)
    rate = savgol_filter(roll_g, win, 2, deriv=1, delta=frame_dt)
    n_box = max(1, int(round(frame_dt / float(np.median(np.diff(ti))))))
    p_box = np.convolve(p, np.ones(n_box) / n_box, mode="same")
    keep = near.copy()
    keep[: win // 2], keep[-(win // 2):] = False, False
    std = math.degrees(float(np.std(rate[keep]))) if keep.any() else math.nan
    n_used = int(keep.sum())
    if n_used < 20:
        return TimeOffset(math.nan, math.nan, n_used, std, "too few frames with lanes in the overlap")
    if not std >= min_roll_rate_std_deg_s:
        return TimeOffset(math.nan, math.nan, n_used, std,
                          f"roll barely moves (rate std {std:.2f} deg/s < {min_roll_rate_std_deg_s})")
    lags = np.arange(-max_offset_s, max_offset_s + step_s / 2, step_s)
    r = rate[keep]
    # The correlation at every lag from per-block sums (ten blocks, for the jackknife): memory
    # O(lags x blocks), not a (lags x frames) matrix (1.4 GB for an hour's drive).
    block = np.empty(len(r), dtype=np.int64)
    for b, ix in enumerate(np.array_split(np.arange(len(r)), _JACKKNIFE_BLOCKS)):
        block[ix] = b
    nb = _JACKKNIFE_BLOCKS
    n_b = np.bincount(block, minlength=nb).astype(float)
    sr_b, srr_b = np.bincount(block, r, nb), np.bincount(block, r * r, nb)
    sums = np.empty((len(lags), 3, nb))          # per lag and block: sum g, sum g^2, sum r g
    for i, lag in enumerate(lags):
        g = savgol_filter(np.interp(grid + lag, ti, p_box), win, 2)[keep]   # smoothed like the vision's
        sums[i] = np.bincount(block, g, nb), np.bincount(block, g * g, nb), np.bincount(block, r * g, nb)

    def estimate(use: np.ndarray) -> tuple[float, float]:
        """Lag and peak correlation from the blocks ``use``."""
        n_, sr, srr = n_b[use].sum(), sr_b[use].sum(), srr_b[use].sum()
        sg, sgg, srg = (sums[:, j][:, use].sum(axis=1) for j in range(3))
        corr = (srg - sr * sg / n_) / np.sqrt(np.maximum((srr - sr * sr / n_) * (sgg - sg * sg / n_), 1e-300))
        return _peak_lag(corr, lags, step_s)

    lag, peak = estimate(np.ones(nb, dtype=bool))
    if not peak >= min_correlation:
        return TimeOffset(math.nan, peak, n_used, std, f"peak correlation {peak:.2f} < {min_correlation}")
    # block jackknife: the estimate without each tenth of the drive in turn
    jk = np.array([estimate(np.arange(nb) != b)[0] for b in range(nb)])
    sigma = math.sqrt((nb - 1) / nb * float(np.sum((jk - jk.mean()) ** 2)))
    # vision at frame time t matches the gyro at t + lag: add lag to the frame times
    return TimeOffset(float(lag), float(peak), n_used, std, sigma_s=sigma)


def _peak_lag(corr: np.ndarray, lags: np.ndarray, step_s: float) -> tuple[float, float]:
    """Lag of the peak of the normalised correlation ``corr`` over ``lags`` (a parabola through
    the peak) and the peak."""
    k = int(np.argmax(corr))
    lag = float(lags[k])
    if 0 < k < len(lags) - 1:
        a, b, c = corr[k - 1], corr[k], corr[k + 1]
        den = a - 2 * b + c
        if den < 0:
            lag += 0.5 * (a - c) / den * step_s
    return lag, float(corr[k])
