"""The filter's gravity reference on real recordings, IMU only, against their own attitude truth.

Usage::

    .venv/bin/python tools/fusion_realdata.py [--kitti DRIVE_SYNC_FOLDER] [--comma SEGMENT] [--out DIR]

* KITTI drive 0001 (default ``../shared/data/kitti_2011_09_26_drive_0001/2011_09_26_drive_0001_sync``):
  the OXTS packets as the IMU (:func:`imu.oxts.read_oxts`), the OXTS INS attitude as truth.
* comma2k19 (default ``../shared/data/comma2k19_rav4_segment``): the phone's IMU (100 Hz, axes
  forward, right, down, turned into x forward, y left, z up) with the CAN wheel speed comma
  decoded (held to the IMU times), and comma's offline INS/GNSS pose of the same device as
  truth (``global_pose/frame_orientations``: device to ECEF, turned into roll and pitch relative
  to the local level). The CAN's own IMU signals (yaw rate, two accelerations) lack the roll
  rate the filter needs; this loader is the tool's, not the package's.

Runs :func:`fusion.pipeline.fuse` without vision and prints, after the first 2 s, the RMS and
largest error of the fused roll and pitch relative to level, next to the plain accelerometer
tilt (no speed, no yaw rate) on the same samples, and the fused 1-sigma. ``--out`` also writes
``<name>/fused.csv`` and the report (plots against the truth). Exit status 2 with a one-line
error on bad input.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
#: ``VIFUSION_SHARED_DATA`` overrides, as for the tests (``tests/conftest.py``)
DATA = Path(os.environ.get("VIFUSION_SHARED_DATA") or ROOT.parent / "shared" / "data")
KITTI = DATA / "kitti_2011_09_26_drive_0001" / "2011_09_26_drive_0001_sync"
COMMA = DATA / "comma2k19_rav4_segment"
CONVERGED_S = 2.0
_FRD_TO_FLU = np.array([1.0, -1.0, -1.0])


def read_comma(segment: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The phone IMU with the CAN speed as the IMU table, and the device's INS roll and pitch."""
    from scipy.spatial.transform import Rotation

    from imu.errors import DecodeError
    from imu.samples import COLUMNS, FRESH_COLUMNS

    def load(name):
        path = segment / name
        if not path.is_file():
            raise DecodeError(f"{path}: missing (a comma2k19 segment folder?)")
        return np.load(path)

    t, acc, gyr = load("processed_log/IMU/accelerometer/t"), load("processed_log/IMU/accelerometer/value"), \
        load("processed_log/IMU/gyro/value")
    ts, speed = load("processed_log/CAN/speed/t"), load("processed_log/CAN/speed/value")[:, 0]
    if len(gyr) != len(t) or not np.array_equal(load("processed_log/IMU/gyro/t"), t):
        raise DecodeError(f"{segment}: accelerometer and gyro samples are not at the same times")
    keep = t > ts[0]
    t, acc, gyr = t[keep], acc[keep] * _FRD_TO_FLU, gyr[keep] * _FRD_TO_FLU
    k = np.searchsorted(ts, t) - 1            # the latest speed before each IMU sample
    imu = pd.DataFrame({"t_s": t, "gyro_x_rad_s": gyr[:, 0], "gyro_y_rad_s": gyr[:, 1], "gyro_z_rad_s": gyr[:, 2],
                        "accel_x_m_s2": acc[:, 0], "accel_y_m_s2": acc[:, 1], "accel_z_m_s2": acc[:, 2],
                        "speed_m_s": speed[k]})
    for c in FRESH_COLUMNS:
        imu[c] = True
    imu["fresh_speed"] = np.r_[True, np.diff(k) > 0]
    # truth: device (forward, right, down) to ECEF, then to north-east-down at the start
    tp, q, pos = load("global_pose/frame_times"), load("global_pose/frame_orientations"), \
        load("global_pose/frame_positions")
    x, y, z = pos[0]
    lat, lon = _geodetic_latitude(x, y, z), math.atan2(y, x)
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    R_ecef_from_ned = np.array([[-sl * co, -so, -cl * co], [-sl * so, co, -cl * so], [cl, 0.0, -sl]])
    R_ned_from_dev = R_ecef_from_ned.T @ Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    yaw, pitch, roll = Rotation.from_matrix(R_ned_from_dev).as_euler("ZYX", degrees=True).T
    # forward-right-down to forward-left-up: roll keeps its sign, pitch (nose up) flips
    truth = pd.DataFrame({"t_s": tp, "roll_world_deg": roll, "pitch_world_deg": -pitch})
    return imu[list(COLUMNS)], truth


def _geodetic_latitude(x: float, y: float, z: float) -> float:
    """WGS84 geodetic latitude (rad) of an ECEF point (m): that of the ellipsoid's normal, the
    local level's (gravity's direction to arcseconds). The geocentric ``atan2(z, hypot(x, y))``
    used before is 0.186 deg off it at comma2k19's 37.7 deg north, which went whole into the
    reference pitch of a car heading north (a review, fifteenth session). Bowring's iteration:
    converged to 1e-15 rad in four steps at any height of a road."""
    a, f = 6378137.0, 1.0 / 298.257223563
    e2 = f * (2.0 - f)
    p = math.hypot(x, y)
    lat = math.atan2(z, p * (1.0 - e2))
    for _ in range(6):
        n = a / math.sqrt(1.0 - e2 * math.sin(lat) ** 2)
        h = p / math.cos(lat) - n
        lat = math.atan2(z, p * (1.0 - e2 * n / (n + h)))
    return lat


def table(name: str, imu: pd.DataFrame, truth: pd.DataFrame, out: Path | None, accel_bias_m_s2: float | None = None,
          has_pitch_rate: bool = True) -> None:
    """Print the table of one recording (``accel_bias_m_s2``: the accelerometer-bias prior,
    1-sigma; None keeps the filter's default for a calibrated IMU; ``has_pitch_rate=False``:
    the pitch gyro left out, as on a Bosch MM5.10)."""
    import dataclasses

    from fusion.engine import FusionOptions
    from fusion.metrics import interp_truth
    from fusion.pipeline import fuse
    from fusion.report import ReportInputs, write_report

    options = FusionOptions()
    if accel_bias_m_s2 is not None:
        options = dataclasses.replace(options, noise=dataclasses.replace(options.noise, init_accel_bias_m_s2=accel_bias_m_s2))
    if not has_pitch_rate:
        imu = imu.assign(gyro_y_rad_s=np.nan)
    run = fuse(imu, None, options=options, has_pitch_rate=has_pitch_rate)
    f = run.fused
    tr = interp_truth(truth, f["t_s"].to_numpy())
    m = ((f["t_s"] >= f["t_s"].iloc[0] + CONVERGED_S) & tr["roll_world_deg"].notna()).to_numpy()
    tilt = {"roll": np.degrees(np.arctan2(imu["accel_y_m_s2"], imu["accel_z_m_s2"])),
            "pitch": np.degrees(np.arcsin(np.clip(-imu["accel_x_m_s2"] / 9.80665, -1.0, 1.0)))}
    duration = f["t_s"].iloc[-1] - f["t_s"].iloc[0]
    bias = options.noise.init_accel_bias_m_s2
    print(f"\n{name}: {len(imu)} IMU samples, {duration:.1f} s, accelerometer-bias prior {bias} m/s^2"
          f"{'' if has_pitch_rate else ', no pitch gyro'}; "
          f"errors against its attitude truth after {CONVERGED_S:.0f} s, deg")
    for w in run.warnings:
        print(f"warning: {w}")
    print("| angle | fused RMSE | fused mean | fused max | accelerometer tilt RMSE | fused 1-sigma (min-max) | error inside 2 sigma |")
    print("|---|---|---|---|---|---|---|")
    for ang in ("roll", "pitch"):
        e = (f[f"{ang}_world_deg"] - tr[f"{ang}_world_deg"])[m].to_numpy()
        et = (tilt[ang] - tr[f"{ang}_world_deg"])[m].to_numpy()
        s = f[f"{ang}_world_sigma_deg"][m]
        print(f"| {ang} (relative to level) | {np.sqrt(np.mean(e**2)):.3f} | {np.mean(e):+.3f} | {np.abs(e).max():.3f} | "
              f"{np.sqrt(np.mean(et**2)):.3f} | {s.min():.2f}-{s.max():.2f} | {100 * np.mean(np.abs(e) < 2 * s):.0f} % |")
    if out is not None:
        d = out / name
        d.mkdir(parents=True, exist_ok=True)
        f.to_csv(d / "fused.csv", index=False, float_format="%.6f")
        write_report(ReportInputs(fused=f, truth=truth, cov=run.cov, counts=run.counts, warnings=run.warnings,
                                  title=f"{name}: IMU only"), d / "report")
        print(f"wrote {d}/fused.csv and {d}/report/report.html")


def residuals(name: str, imu: pd.DataFrame, truth: pd.DataFrame, window_s: float = 1.0) -> None:
    """What the specific-force model leaves out of a real vehicle's motion: the accelerometer
    against the model evaluated on the truth's attitude (x forward, y left, z up; roll right
    side down, pitch nose down, as the filter has them): ``f_x = dv/dt - g sin(pitch)``,
    ``f_y = v r + g sin(roll) cos(pitch)``, ``f_z = g cos(roll) cos(pitch)`` (``dv/dt`` from
    the wheel speed, ``r`` the yaw gyro; no lever arm, no road turn rates). Prints per axis the
    residual's mean, its RMS per sample about that mean, and averaged over ``window_s``, and the
    white noise per sample whose average over ``window_s`` has that RMS: the equivalent of
    ``[fusion] accel_noise_m_s2`` at the time scale of the gravity reference
    (:attr:`fusion.noise.NoiseModel.accel_meas_m_s2` takes its default from comma2k19's)."""
    t = imu["t_s"].to_numpy()
    ok = imu["speed_m_s"].notna().to_numpy()
    v = np.interp(t, t[ok], imu["speed_m_s"].to_numpy()[ok])
    roll = np.radians(np.interp(t, truth["t_s"], truth["roll_world_deg"]))
    pitch = np.radians(np.interp(t, truth["t_s"], truth["pitch_world_deg"]))
    g = 9.80665
    model = {"x": np.gradient(v, t) - g * np.sin(pitch),
             "y": v * imu["gyro_z_rad_s"].to_numpy() + g * np.sin(roll) * np.cos(pitch),
             "z": g * np.cos(roll) * np.cos(pitch)}
    m = t >= t[0] + CONVERGED_S
    rate = 1.0 / float(np.median(np.diff(t)))
    n = max(int(round(window_s * rate)), 1)
    print(f"\n{name}: specific force against the model on the truth's attitude, {rate:.0f} Hz, m/s^2")
    print(f"| axis | mean | RMS per sample | RMS of {window_s:g} s means | white sigma per sample with that {window_s:g} s RMS |")
    print("|---|---|---|---|---|")
    for axis in "xyz":
        r = (imu[f"accel_{axis}_m_s2"].to_numpy() - model[axis])[m]
        r0 = r - r.mean()
        avg = np.sqrt(np.mean(np.convolve(r0, np.ones(n) / n, mode="valid") ** 2))
        print(f"| {axis} | {r.mean():+.3f} | {np.sqrt(np.mean(r0**2)):.3f} | {avg:.3f} | {avg * math.sqrt(n):.2f} |")


def gyro_drift(name: str, imu: pd.DataFrame, truth: pd.DataFrame) -> None:
    """What the gyros leave out of the truth's roll and pitch: the rates integrated over windows
    of 1 and 4 s from the truth (:func:`fusion.metrics.gyro_attitude_drift`, the windows' mean
    error taken out: the rates' bias is not known), against the filter's default allowance for
    it, ``sqrt(gyro_noise^2 dt + attitude_walk^2)`` per sqrt(s) (``[fusion]
    attitude_walk_deg_sqrt_s``; the simulator's drives give 0.02, what their gyros leave out)."""
    from fusion.noise import NoiseModel
    from fusion.metrics import gyro_attitude_drift

    ok = imu[["gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"]].notna().all(axis=1).to_numpy()
    t = imu["t_s"].to_numpy()[ok]
    w = imu[["gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"]].to_numpy()[ok]
    n = NoiseModel()
    allowed = math.degrees(math.hypot(n.gyro_noise_rad_s * math.sqrt(float(np.median(np.diff(t)))),
                                      n.attitude_walk_rad_sqrt_s))
    print(f"\n{name}: the gyros integrated from the truth's attitude, error per sqrt(window) less its mean,"
          f" deg/sqrt(s); the filter's default allowance {allowed:.3f}")
    print("| window | windows | roll | pitch |")
    print("|---|---|---|---|")
    for window_s in (1.0, 4.0):
        try:
            d, count = gyro_attitude_drift(t, w, truth, window_s, remove_mean=True, return_windows=True)
        except ValueError:  # a recording too short for three windows
            print(f"| {window_s:g} s | < 3 | - | - |")
            continue
        print(f"| {window_s:g} s | {count} | {d[0]:.3f} | {d[1]:.3f} |")


def main(argv=None) -> int:
    from fusion.errors import FusionError
    from imu.errors import ImuError
    from imu import read_oxts

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--kitti", type=Path, default=KITTI, help="KITTI *_sync folder (or its oxts)")
    p.add_argument("--comma", type=Path, default=COMMA, help="comma2k19 segment folder")
    p.add_argument("--out", type=Path, help="write <name>/fused.csv and the reports here")
    args = p.parse_args(argv)
    try:
        if args.out is not None:   # said before the work, as the commands do (a review: a traceback after it)
            from fusion.cli import check_output_file

            check_output_file(args.out / "x")
        kitti = read_oxts(args.kitti)
        table("kitti_oxts", *kitti, args.out)
        residuals("kitti_oxts", *kitti)
        gyro_drift("kitti_oxts", *kitti)
        table("kitti_oxts_no_pitch_gyro", *kitti, args.out, has_pitch_rate=False)
        comma = read_comma(args.comma)
        table("comma2k19_phone_imu", *comma, args.out)
        residuals("comma2k19_phone_imu", *comma)
        gyro_drift("comma2k19_phone_imu", *comma)
        # a phone's MEMS accelerometer: a zero-g offset of tens of mg, not a calibrated unit's 3 mg
        table("comma2k19_phone_imu_phone_prior", *comma, args.out, accel_bias_m_s2=0.2)
    except (ImuError, FusionError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
