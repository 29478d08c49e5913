"""Offline fusion of a whole drive: IMU table + vision table -> fused table.

The tables are the ones the other packages produce: :func:`imu.read_log` (``t_s``,
``gyro_{x,y,z}_rad_s``, ``accel_{x,y,z}_m_s2``, ``speed_m_s``, ``fresh_*``; vehicle frame) and
the vision estimator's ``vision.csv`` (``t_s``, ``roll_deg``, ``pitch_deg``, ``yaw_deg``,
``valid``, ``*_sigma_deg``, ``curvature_1_m`` with ``curvature_sigma_1_m``, ``roll_lookahead_m``,
``pitch_per_twist_m`` and ``yaw_per_twist_m`` when the estimator gives them, ``lateral_offset_m``). Both on the CAN log's
clock. The same :class:`fusion.engine.FusionStream` that the prototype embeds does the work,
fed in time order; a second one without vision gives the IMU-only attitude, from which the
plain bank of Damon et al. 2018 (IMU roll minus vision roll) is formed for comparison.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from tqdm import tqdm

from vision.video import SAG_COLUMNS, TWIST_RESPONSE_COLUMNS, current_names

from .drive import SPEED_SPAN_WARN_S
from .ekf import GRAVITY_M_S2, S, relative_outputs
from .engine import LEVELLING_FORCE_G, MAX_ROAD_TWIST_RAD_M, SPEED_DRIFT_M_S2, SPEED_REACQUIRE_M_S, FusionStream
from .errors import InputError
from .options import FusionOptions
from .smoother import rts_smooth

__all__ = ["FusedRun", "fuse", "outputs_table", "output_covariance", "plain_bank", "vision_inputs"]

GYRO_COLS = ("gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s")
ACCEL_COLS = ("accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2")


@dataclass
class FusedRun:
    """Result of :func:`fuse`."""

    fused: pd.DataFrame
    counts: dict
    smoothed: bool
    #: (N, 4, 4) joint covariance of (roll, pitch, yaw, bank) in rad^2, per sample
    cov: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)


def output_covariance(X: np.ndarray, P: np.ndarray) -> np.ndarray:
    """(N, 4, 4) covariance of (roll, pitch, yaw, bank), rad^2 (:func:`fusion.ekf.relative_outputs`)."""
    return relative_outputs(np.ascontiguousarray(X), np.ascontiguousarray(P))[1]


def outputs_table(t_s: np.ndarray, X: np.ndarray, P: np.ndarray, rel_cov=None) -> pd.DataFrame:
    """The fused table (degrees, with 1-sigma) of states ``X`` (N, n) with covariances ``P``;
    ``rel_cov``: :func:`fusion.ekf.relative_outputs` of them, when already computed."""
    rel, cov = rel_cov if rel_cov is not None else relative_outputs(np.ascontiguousarray(X), np.ascontiguousarray(P))
    sig_rel = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2)[:, :3], 0.0))
    d = np.sqrt(np.maximum(np.diagonal(P, axis1=1, axis2=2), 0.0))
    deg = np.degrees
    out = {
        "t_s": t_s,
        "roll_deg": deg(rel[:, 0]), "pitch_deg": deg(rel[:, 1]), "yaw_deg": deg(rel[:, 2]),
        "bank_deg": deg(X[:, S.BANK]), "roll_world_deg": deg(X[:, S.ROLL_W]),
        "pitch_world_deg": deg(X[:, S.PITCH_W]), "grade_deg": deg(X[:, S.GRADE]),
        "roll_sigma_deg": deg(sig_rel[:, 0]), "pitch_sigma_deg": deg(sig_rel[:, 1]),
        "yaw_sigma_deg": deg(sig_rel[:, 2]), "bank_sigma_deg": deg(d[:, S.BANK]),
        "roll_world_sigma_deg": deg(d[:, S.ROLL_W]), "pitch_world_sigma_deg": deg(d[:, S.PITCH_W]),
        "grade_sigma_deg": deg(d[:, S.GRADE]),
        "bank_rate_deg_s": deg(X[:, S.BANK_RATE]), "grade_rate_deg_s": deg(X[:, S.GRADE_RATE]),
        "bank_rate_sigma_deg_s": deg(d[:, S.BANK_RATE]), "grade_rate_sigma_deg_s": deg(d[:, S.GRADE_RATE]),
        "gyro_bias_x_deg_s": deg(X[:, S.GYRO_BIAS_X]), "gyro_bias_y_deg_s": deg(X[:, S.GYRO_BIAS_Y]),
        "gyro_bias_z_deg_s": deg(X[:, S.GYRO_BIAS_Z]),
        "accel_bias_x_m_s2": X[:, S.ACCEL_BIAS][:, 0], "accel_bias_y_m_s2": X[:, S.ACCEL_BIAS][:, 1],
        "accel_bias_z_m_s2": X[:, S.ACCEL_BIAS][:, 2],
        "gyro_bias_x_sigma_deg_s": deg(d[:, S.GYRO_BIAS_X]), "gyro_bias_y_sigma_deg_s": deg(d[:, S.GYRO_BIAS_Y]),
        "gyro_bias_z_sigma_deg_s": deg(d[:, S.GYRO_BIAS_Z]),
        "accel_bias_x_sigma_m_s2": d[:, S.ACCEL_BIAS][:, 0], "accel_bias_y_sigma_m_s2": d[:, S.ACCEL_BIAS][:, 1],
        "accel_bias_z_sigma_m_s2": d[:, S.ACCEL_BIAS][:, 2],
        "speed_m_s": X[:, S.SPEED],
        "curvature_1_m": X[:, S.CURVATURE], "curvature_sigma_1_m": d[:, S.CURVATURE],
    }
    return pd.DataFrame(out)


def implausible_vision_warning(n: int) -> str:
    """The line for ``n`` vision results refused for their numbers (``vision_implausible``)."""
    return (f"{n} vision result(s) refused: an angle beyond +-90 deg relative to the road or a sigma of 0 or below "
            "(degrees handed in as radians?)")


#: Share of the vision results the filter decided on (used or refused by its chi-square gate,
#: :attr:`fusion.noise.NoiseModel.gate_probability` 0.999) over which a run warns. Measured
#: (README, "Fusion": a camera clock off the bus): up to 0.3 % of them refused on the HD
#: benchmark drives and 3.5 % on the 640x360 sample drive; with the frames' times 0.2 s late
#: 30-31 % on four HD drives (the hold-out drive 1 %, the sample 20 %), 0.5 s off either way
#: 34-40 % (the sample 29-30 %). Live, over 10 s of the sample drive, a right clock gave up to
#: 5.7 %, and 10.1 % with the frames handed in 0.2 s before the bus reached them (a review; the
#: first threshold, 10 %, warned there), a clock 0.2-0.5 s off 22-30 %. An offset of 0.1 s or
#: less is not seen by the gate (HD up to 0.7 %, the sample 8 %), though it costs the 60 s
#: drive's bank 0.09 -> 0.42 deg: only the offset's estimate from the data finds it
#: (:mod:`fusion.timing`).
VISION_REFUSED_WARN = 0.15
#: Least number of decided results before the share is judged (two seconds at 30 fps).
VISION_REFUSED_MIN = 60


def vision_refused_warning(refused: int, decided: int, span: str = "") -> str | None:
    """The line for a run whose filter refused more than :data:`VISION_REFUSED_WARN` of the
    vision results it decided on (``span``: over what, e.g. " in 10 s"), or None."""
    if decided < VISION_REFUSED_MIN or not refused > VISION_REFUSED_WARN * decided:
        return None
    return (f"the filter's gate refused {refused} of {decided} vision results{span} ({100.0 * refused / decided:.0f} %): "
            "is camera_time_offset_s right? (frames 0.2 s or more off the CAN clock do this; vifusion run "
            "--estimate-time-offset estimates the offset) Or does the vision misread the lanes? (the debug video)")


#: The fused table's columns that rest on the gravity reference, NaN before the first wheel speed.
GRAVITY_COLUMNS = ("bank_deg", "bank_sigma_deg", "roll_world_deg", "roll_world_sigma_deg", "pitch_world_deg",
                   "pitch_world_sigma_deg", "grade_deg", "grade_sigma_deg")


def vision_inputs(vision: pd.DataFrame) -> pd.DataFrame:
    """Check the vision table and return it sorted by time with the columns the filter reads."""
    need = ("t_s", "roll_deg", "pitch_deg", "yaw_deg", "valid")
    missing = [c for c in need if c not in vision.columns]
    if missing:
        raise InputError(f"vision table lacks column(s) {', '.join(missing)}")
    v = current_names(vision).sort_values("t_s", kind="stable").reset_index(drop=True)
    for c in ("roll_sigma_deg", "pitch_sigma_deg", "yaw_sigma_deg"):
        if c not in v.columns:
            v[c] = 0.3  # the paper's order of magnitude when the estimator gives none
    for c in ("curvature_1_m", "lateral_offset_m", "curvature_sigma_1_m", "roll_lookahead_m"):
        if c not in v.columns:
            v[c] = np.nan
    for c in ("pitch_per_twist_m", "yaw_per_twist_m"):
        if c not in v.columns:
            v[c] = 0.0
    for c in ("road_twist_deg_per_m", "road_twist_sigma_deg_per_m", "yaw_per_curvature_m") + TWIST_RESPONSE_COLUMNS + SAG_COLUMNS:
        if c not in v.columns:
            v[c] = np.nan
    return v


def fuse(imu: pd.DataFrame, vision: pd.DataFrame | None, *, lever_arm_m=(0.0, 0.0, 0.0),
         has_pitch_rate: bool = True, options: FusionOptions = FusionOptions(), smooth: bool = False,
         camera_time_offset_s: float = 0.0, progress: bool = False) -> FusedRun:
    """Fuse a drive; see the module docstring.

    Parameters
    ----------
    imu : DataFrame
        IMU samples in the vehicle frame (``imu.read_log``'s table), strictly increasing ``t_s``.
    vision : DataFrame or None
        Vision results; None runs the IMU alone.
    camera_time_offset_s : float
        Added to the vision times (camera-to-CAN clock offset).
    smooth : bool
        Forward filter plus RTS smoother (offline only).
    """
    t = imu["t_s"].to_numpy(dtype=float)
    if len(t) < 2:
        raise InputError("the IMU table has fewer than two samples")
    if not np.all(np.isfinite(t)):
        # (np.diff's comparison is False at a NaN: the row was written out with t_s NaN)
        raise InputError(f"{int(np.sum(~np.isfinite(t)))} IMU sample times are not finite")
    if np.any(np.diff(t) <= 0):
        raise InputError("IMU sample times are not strictly increasing")
    gyro = imu[list(GYRO_COLS)].to_numpy(dtype=float).copy()
    accel = imu[list(ACCEL_COLS)].to_numpy(dtype=float)
    speed = imu["speed_m_s"].to_numpy(dtype=float) if "speed_m_s" in imu else np.full(len(t), np.nan)
    fresh = imu["fresh_speed"].to_numpy(dtype=bool) if "fresh_speed" in imu else np.isfinite(speed)
    warnings: list[str] = []
    if not has_pitch_rate:
        gyro[:, 1] = 0.0  # not used: q = r tan(roll) inside the filter
    bad = ~np.all(np.isfinite(gyro), axis=1) | ~np.all(np.isfinite(accel), axis=1)
    if bad.any():
        warnings.append(f"{int(bad.sum())} IMU samples without a valid gyro or accelerometer value were skipped")
        warnings += imu_span_warnings(t, np.column_stack([gyro, accel]), GYRO_COLS + ACCEL_COLS, ~bad)
    keep = ~bad
    t, gyro, accel, speed, fresh = t[keep], gyro[keep], accel[keep], speed[keep], fresh[keep]
    if len(t) < 2:
        raise InputError("no IMU sample has all gyro and accelerometer channels")

    stream = FusionStream(lever_arm_m, has_pitch_rate, options, record=smooth)
    if vision is not None:
        v = vision_inputs(vision)
        vt = v["t_s"].to_numpy(dtype=float) + camera_time_offset_s
        vang = np.radians(v[["roll_deg", "pitch_deg", "yaw_deg"]].to_numpy(dtype=float))
        vsig = np.radians(v[["roll_sigma_deg", "pitch_sigma_deg", "yaw_sigma_deg"]].to_numpy(dtype=float))
        vvalid = v["valid"].to_numpy(dtype=bool)
        vk = v["curvature_1_m"].to_numpy(dtype=float)
        vks = v["curvature_sigma_1_m"].to_numpy(dtype=float)
        vla = v["roll_lookahead_m"].to_numpy(dtype=float)
        vtw = v[["pitch_per_twist_m", "yaw_per_twist_m"]].to_numpy(dtype=float)
        vrt = np.radians(v[["road_twist_deg_per_m", "road_twist_sigma_deg_per_m"]].to_numpy(dtype=float))
        vresp = v[list(TWIST_RESPONSE_COLUMNS)].to_numpy(dtype=float)
        vsag = v[list(SAG_COLUMNS)].to_numpy(dtype=float)
        vyk = v["yaw_per_curvature_m"].to_numpy(dtype=float)
        vd = v["lateral_offset_m"].to_numpy(dtype=float)
    else:
        vt, vvalid = np.zeros(0), np.zeros(0, dtype=bool)
    speed_known = np.zeros(len(t), dtype=bool)
    X = np.empty((len(t), stream.ekf.dim_x))
    Pm = np.empty((len(t), stream.ekf.dim_x, stream.ekf.dim_x))
    j = 0
    t_list, speed_list, fresh_list = t.tolist(), speed.tolist(), fresh.tolist()   # Python scalars: cheaper per sample
    vt_list = vt.tolist()
    for k in tqdm(range(len(t)), desc="fuse", unit="sample", disable=not progress, mininterval=0.5):
        while j < len(vt_list) and vt_list[j] <= t_list[k]:
            stream.add_vision(vt_list[j], vang[j], vsig[j], bool(vvalid[j]), vk[j], vd[j], vks[j], vla[j], vtw[j], vrt[j], vresp[j], vsag[j], vyk[j])
            j += 1
        stream.add_imu(t_list[k], gyro[k], accel[k], speed_list[k], fresh_list[k])
        X[k], Pm[k] = stream.ekf.x, stream.ekf.P
        speed_known[k] = stream.speed_known
    if smooth:
        at_sample = np.concatenate([[True], [s.imu_index >= 0 for s in stream.steps]])
        del X, Pm      # the forward rows: the smoothed ones take their place
        X, Pm = rts_smooth(stream.steps, *stream.start, keep=at_sample)
        stream.steps.clear()
    rel_cov = relative_outputs(X, Pm)
    table = outputs_table(t, X, Pm, rel_cov)
    if not has_pitch_rate:
        # no pitch gyro, no bias of it: that state is the pitch rate q = r tan(roll) leaves out
        table["gyro_bias_y_deg_s"] = table["gyro_bias_y_sigma_deg_s"] = np.nan
    # before the first wheel speed the speed state is a placeholder and the gravity reference
    # waits for it (its centripetal term): the angles relative to gravity and the road's are not
    # known yet, as FusionStream.estimate() says with NaN (they had numbers here, a review)
    table.loc[~speed_known, ["speed_m_s", *GRAVITY_COLUMNS]] = np.nan
    counts = dict(stream.counts)
    counts["imu_invalid"] += int(bad.sum())     # skipped here, before the stream (no output row)
    counts["vision_after_last_imu"] = int(len(vt) - j)
    if counts["vision_implausible"]:
        warnings.append(implausible_vision_warning(counts["vision_implausible"]))
    refused = vision_refused_warning(counts["vision_rejected"], counts["vision_rejected"] + counts["vision_used"])
    if refused:
        warnings.append(refused)
    warnings += glitch_warnings(counts, options.gravity_reacquire_after_s)
    if counts["imu_gaps"]:
        # the results inside them had no IMU to be placed on (counted as ahead of or older than
        # the filter, with no word of the gap: a review found 271 frames of a 10 s gap so)
        # (valid ones; those within min(max_imu_gap_s, history_s) of the sample after the gap
        # are applied at it: FusionStream.add_imu)
        gap = np.flatnonzero(np.diff(t) > options.max_imu_gap_s)
        reach = min(options.max_imu_gap_s, options.history_s)
        inside = sum(int(np.sum(vvalid[(vt > a) & (vt < b - reach)])) for a, b in zip(t[gap], t[gap + 1]))
        warnings.append(f"the IMU samples have {counts['imu_gaps']} gap(s) longer than {options.max_imu_gap_s:g} s: "
                        "the filter started again after each, keeping the IMU biases"
                        + (f"; {inside} vision result(s) inside them were not used" if inside else ""))
    warnings += imu_setup_warnings(accel, speed_known, counts["gravity_rejected"], options.gravity_every)
    warnings += start_warnings(t, gyro, options)
    warnings += speed_span_warnings(t, speed_known, np.asarray(fresh, dtype=bool) & np.isfinite(speed))
    return FusedRun(table, counts, smooth, rel_cov[1], warnings)


#: Share of the gravity updates refused as outliers over which a run warns: about 10 % on the
#: simulated drives (the differenced gyro's noise through the lever arm, which the update's
#: noise leaves out: docs/fusion-notes.md, 2026-11-26 third session), 36-38 % on the 2 s test
#: drive; all of them with an accelerometer read in the wrong unit.
GRAVITY_REFUSED_WARN = 0.75


def imu_setup_warnings(accel_m_s2: np.ndarray, speed_known: np.ndarray, gravity_refused: int,
                       gravity_every: int = 1) -> list[str]:
    """Warnings for an IMU whose setup cannot be right, which the filter alone does not refuse:
    a specific force whose median magnitude is not about 1 g (a unit: g read as m/s^2), a
    vehicle z axis that does not point up (``[imu] axes``), no wheel speed (the gravity
    reference, which needs it for the centripetal term, was never used), and most gravity
    updates refused as outliers (axes, lever arm, units)."""
    out = []
    g = GRAVITY_M_S2
    mag = float(np.median(np.linalg.norm(accel_m_s2, axis=1))) if len(accel_m_s2) else math.nan
    # a coordinated lean reads g / cos(lean): 1.74 g at 55 deg; a unit error is a factor of 9.81
    if not LEVELLING_FORCE_G[0] * g < mag < LEVELLING_FORCE_G[1] * g:
        out.append(f"the accelerometer reads a median of {mag:.3g} m/s^2, not about {g:.2f}: check the unit of its "
                   "signals in the DBC or [can.units]; the gravity reference is wrong")
    elif float(np.median(accel_m_s2[:, 2])) < 0.5 * g:
        out.append(f"the vehicle's z axis does not point up (median specific force on z {np.median(accel_m_s2[:, 2]):+.2f} "
                   "m/s^2, about +9.81 expected): check [imu] axes")
    attempted = int(np.sum(speed_known)) // max(1, gravity_every)
    if not np.any(speed_known):
        out.append("no wheel speed: the gravity reference (it needs the speed for the centripetal term) was never "
                   "used; the world roll, pitch and the bank rest on the gyros and the vision")
    elif attempted and gravity_refused > GRAVITY_REFUSED_WARN * attempted:
        out.append(f"{gravity_refused} of {attempted} gravity updates refused as outliers: the accelerometer "
                   "disagrees with the model (check [imu] axes and position_m, the accelerometer's units)")
    return out


#: A drive whose first :data:`START_SPAN_S` turn at more than this mean yaw rate, deg/s, starts in
#: a curve (1.5 deg/s: a 900 m radius at 80 km/h; the bench drives start on a straight at 0.2-0.3,
#: their yaw-rate gyro's bias); with the gyro biases uncalibrated (a prior sigma over
#: :data:`CALIBRATED_BIAS_DEG_S`) it is warned (:func:`start_warnings`).
START_TURN_DEG_S = 1.5
START_SPAN_S = 2.0
CALIBRATED_BIAS_DEG_S = 0.1


def start_warnings(t_s: np.ndarray, gyro_rad_s: np.ndarray, options: FusionOptions) -> list[str]:
    """A drive that starts in a curve without calibrated gyro biases. On a straight the world
    roll is the accelerometer's lateral force alone and the gyro biases settle in seconds; in a
    turn the yaw-rate bias and the world roll trade in the centripetal term (``v r``: 1 deg/s of
    bias at 20 m/s is 2 deg of roll) and only the vision's heading against the lane curvature
    tells them apart, slowly. Measured (forward filter, the bench's 60 s drive cut to start at
    its first curve's roll-in, 5 s): bank 0.39 and 0.42 deg RMS over 2-6 s and 6-15 s after the
    start against 0.02 and 0.04 deg from the same start with the drive's own end-of-drive
    calibration; started just before the second curve (25 s) 0.79 and 0.30 against 0.12 and
    0.03. A campaign's calibration (``--calibration``) is the remedy."""
    if not len(t_s):
        return []
    first = t_s - t_s[0] < START_SPAN_S
    turn = math.degrees(float(np.mean(np.abs(gyro_rad_s[first, 2]))))
    prior = math.degrees(float(options.noise.init_gyro_bias_sigma_rad_s[2]))
    if turn <= START_TURN_DEG_S or prior <= CALIBRATED_BIAS_DEG_S:       # (the yaw-rate gyro's prior)
        return []
    return [f"the drive starts in a turn ({turn:.1f} deg/s of yaw rate over its first {START_SPAN_S:g} s) with "
            f"uncalibrated gyro biases (prior {prior:.2g} deg/s): in a turn the yaw-rate bias and the world roll trade, "
            "and the world roll and bank can be tenths of a degree off for 15 s or more; start it from a calibration "
            "(--calibration: a campaign's, or a drive with a straight) or on a straight"]


#: The counts :func:`glitch_warnings` speaks of (``LiveFusion`` says each once as it comes).
GLITCH_COUNTS = ("gravity_reacquired", "level_skipped", "speed_implausible", "twist_implausible")


def glitch_warnings(counts: dict, reacquire_after_s: float) -> list[str]:
    """Warnings for inputs the filter could not use as they came: a gravity reference refused
    for ``reacquire_after_s`` in a row and taken again from the accelerometer
    (``counts["gravity_reacquired"]``, :meth:`fusion.engine.FusionStream._reacquire_gravity`),
    samples whose specific force could not level the filter (``counts["level_skipped"]``,
    :data:`fusion.engine.LEVELLING_FORCE_G`), wheel speeds refused as a sensor's fault
    (``counts["speed_implausible"]``, :data:`fusion.engine.SPEED_REACQUIRE_M_S`), and road twists beyond any road's
    (``counts["twist_implausible"]``, :data:`fusion.engine.MAX_ROAD_TWIST_RAD_M`). The offline
    run's warnings and :class:`fusion.realtime.LiveFusion`'s."""
    out = []
    if counts.get("gravity_reacquired"):
        out.append(f"the gravity reference was refused for {reacquire_after_s:g} s in a row {counts['gravity_reacquired']} "
                   "time(s) and the world roll and pitch were taken again from the accelerometer: a glitch in the "
                   "IMU's rates or forces (a zeroed CAN frame?); the estimates around it are off")
    if counts.get("level_skipped"):
        lo, hi = LEVELLING_FORCE_G
        out.append(f"{counts['level_skipped']} IMU samples with a specific force outside {lo:g}-{hi:g} g could not "
                   "level the filter (start, first wheel speed, re-acquired gravity reference): a zeroed or "
                   "saturated accelerometer frame?")
    if counts.get("speed_implausible"):
        out.append(f"{counts['speed_implausible']} wheel speed(s) were refused as a sensor fault: more than "
                   f"{SPEED_REACQUIRE_M_S:g} m/s, plus {SPEED_DRIFT_M_S2:g} m/s for each second since the last one taken, "
                   "from the speed the accelerometer carried on, which no acceleration explains (a locked, lifted or "
                   "spinning wheel, a sensor stuck at one value?); the filter carried its speed on instead")
    if counts.get("twist_implausible"):
        out.append(f"{counts['twist_implausible']} vision result(s) with a road twist beyond "
                   f"{math.degrees(MAX_ROAD_TWIST_RAD_M):.2f} deg/m or a twist sigma of 0 or below: their twists were "
                   "not used (their angles were)")
    return out


def speed_span_warnings(t_s: np.ndarray, speed_known: np.ndarray, fresh: np.ndarray) -> list[str]:
    """A wheel speed that starts late or stops early (a CAN log's gap finder sees only gaps
    between frames): before it the world roll, pitch and bank rest on the gyros and the vision;
    after it the speed is held and the gravity reference's centripetal term with it."""
    out = []
    if not len(t_s) or not np.any(speed_known):
        return out                      # no wheel speed at all: imu_setup_warnings says so
    first = t_s[np.argmax(speed_known)]
    if first - t_s[0] > SPEED_SPAN_WARN_S:
        out.append(f"no wheel speed for the first {first - t_s[0]:.1f} s of the IMU samples: until it the gravity "
                   "reference waited and the world roll, pitch and bank rest on the gyros and the vision")
    last = t_s[np.flatnonzero(fresh)[-1]] if np.any(fresh) else first
    if t_s[-1] - last > SPEED_SPAN_WARN_S:
        out.append(f"no wheel speed in the last {t_s[-1] - last:.1f} s of the IMU samples: the filter carried the "
                   "last speed on (its acceleration state), and the gravity reference with it")
    return out


def imu_span_warnings(t_s: np.ndarray, values: np.ndarray, names: tuple[str, ...], keep: np.ndarray) -> list[str]:
    """Gyro or accelerometer channels whose values start more than :data:`SPEED_SPAN_WARN_S`
    after the IMU samples or stop that long before them (a log whose accelerometer message ends
    at 3 s of 12): the samples without them are skipped, so the fused table starts or ends
    there; it ended at 3 s with only a count of skipped samples said (a review). Channels that
    start or stop together are named in one warning."""
    out: list[str] = []
    if not len(t_s) or not np.any(keep):
        return out
    fused_first, fused_last = t_s[np.argmax(keep)], t_s[len(keep) - 1 - np.argmax(keep[::-1])]
    late: dict[str, list[str]] = {}
    early: dict[str, list[str]] = {}
    for j, name in enumerate(names):
        ok = np.isfinite(values[:, j])
        if not ok.any():
            continue                    # never seen: the caller's error
        first, last = t_s[np.argmax(ok)], t_s[len(ok) - 1 - np.argmax(ok[::-1])]
        if first - t_s[0] > SPEED_SPAN_WARN_S:
            late.setdefault(f"{first - t_s[0]:.1f}", []).append(name)
        if t_s[-1] - last > SPEED_SPAN_WARN_S:
            early.setdefault(f"{t_s[-1] - last:.1f}", []).append(name)
    for span, cols in late.items():
        out.append(f"no {', '.join(cols)} value for the first {span} s of the IMU samples (the channel"
                   f"{'s' if len(cols) > 1 else ''} started late): those samples were skipped and the fused table "
                   f"starts {fused_first - t_s[0]:.1f} s after the IMU samples do")
    for span, cols in early.items():
        out.append(f"no {', '.join(cols)} value in the last {span} s of the IMU samples (the channel"
                   f"{'s' if len(cols) > 1 else ''} stopped early): those samples were skipped and the fused table "
                   f"ends {t_s[-1] - fused_last:.1f} s before the IMU samples do")
    return out


#: Frames further apart than this (lanes lost) leave the per-sample plain bank NaN between them, s.
PLAIN_BANK_MAX_FRAME_GAP_S = 0.1
#: A gap within this of the limit counts as at it (s): frame times are written to the
#: microsecond, and epoch seconds in float64 resolve 2.4e-7 s, so three frames of a 30 fps camera
#: came out 0.10000014 or 0.09999990 s apart and were split or bridged by the rounding (a review).
_GAP_TOLERANCE_S = 1e-6


def frames_to_samples(t_s: np.ndarray, frame_t_s: np.ndarray, values: np.ndarray,
                      max_gap_s: float = PLAIN_BANK_MAX_FRAME_GAP_S) -> np.ndarray:
    """Per-frame ``values`` at the IMU sample times ``t_s``: interpolated between frames at most
    ``max_gap_s`` apart, NaN before the first frame, after the last and across longer gaps (no
    value where there was no vision)."""
    t_s = np.asarray(t_s, dtype=float)
    out = np.full(t_s.size, math.nan)
    if len(frame_t_s) == 0:
        return out
    out[:] = np.interp(t_s, frame_t_s, values, left=math.nan, right=math.nan)
    k = np.clip(np.searchsorted(frame_t_s, t_s, side="right"), 1, len(frame_t_s) - 1)
    gap = frame_t_s[k] - frame_t_s[k - 1] if len(frame_t_s) > 1 else np.zeros(t_s.size)
    exact = np.isin(t_s, frame_t_s)
    out[(gap > max_gap_s + _GAP_TOLERANCE_S) & ~exact] = math.nan
    return out


def frame_gap_limit_s(all_frame_t_s: np.ndarray) -> float:
    """The gap between valid frames beyond which the vision counts as lost: 0.1 s
    (:data:`PLAIN_BANK_MAX_FRAME_GAP_S`), or 1.5 frame periods of a slower camera (the median
    interval of all its frames, valid or not): a 10 fps camera's 0.1 s comes out a rounding
    step over 0.1 for 40 % of its intervals, which were all lost."""
    t = np.asarray(all_frame_t_s, dtype=float)
    period = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    return max(PLAIN_BANK_MAX_FRAME_GAP_S, 1.5 * period)


def plain_bank(fused_imu_only: pd.DataFrame, vision: pd.DataFrame, camera_time_offset_s: float = 0.0,
               max_imu_gap_s: float = FusionOptions().max_imu_gap_s) -> pd.DataFrame:
    """Damon et al. 2018, section IV: bank = IMU roll (gravity-referenced) - vision roll.

    Evaluated at the vision frames' times with the IMU-only filter's world roll; NaN at frames
    inside a gap in the IMU samples longer than ``max_imu_gap_s`` (the filter restarted there:
    no IMU roll to take; interpolated across, a 1.8 s gap in a weave gave 7.7 deg of error).
    """
    v = vision_inputs(vision)
    v = v[v["valid"].astype(bool)]
    tv = v["t_s"].to_numpy(dtype=float) + camera_time_offset_s
    roll_imu = frames_to_samples(tv, fused_imu_only["t_s"].to_numpy(dtype=float),
                                 fused_imu_only["roll_world_deg"].to_numpy(dtype=float), max_gap_s=max_imu_gap_s)
    return pd.DataFrame({"t_s": tv, "bank_plain_deg": roll_imu - v["roll_deg"].to_numpy(dtype=float),
                         "roll_world_imu_only_deg": roll_imu})
