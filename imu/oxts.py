"""KITTI OXTS packets as the IMU table, and the OXTS attitude as truth.

The KITTI raw recordings carry an OXTS RT3003 GPS/IMU: one text file per packet under
``oxts/data/`` (30 numbers: ``lat lon alt roll pitch yaw vn ve vf vl vu ax ay az af al au wx wy
wz wf wl wu pos_accuracy vel_accuracy navstat numsats posmode velmode orimode``, see the
recording's ``dataformat.txt``) and ``oxts/timestamps.txt`` (local time, one line a packet).
Its body axes are x forward, y left, z up: the vehicle frame of INTERFACE.md, so the rates
``wx wy wz`` (rad/s) and the specific force ``ax ay az`` (m/s^2, gravity included) go into the
IMU table unrotated; the speed is ``vf``, the forward velocity parallel to the ground (GPS-aided,
not a wheel speed). Its roll (positive: left side up) and pitch (positive: front down) relative
to level are the INS solution (GPS and the same IMU), the ZYX angles of INTERFACE.md.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .errors import DecodeError
from .samples import COLUMNS, FRESH_COLUMNS, VALUE_COLUMNS

__all__ = ["read_oxts"]

_FIELDS = ("lat lon alt roll pitch yaw vn ve vf vl vu ax ay az af al au wx wy wz wf wl wu "
           "pos_accuracy vel_accuracy navstat numsats posmode velmode orimode").split()


def _oxts_dir(path: Path) -> Path:
    for cand in (path, path / "oxts"):
        if (cand / "data").is_dir() and (cand / "timestamps.txt").is_file():
            return cand
    raise DecodeError(f"{path}: no OXTS recording here (need oxts/data/*.txt and oxts/timestamps.txt)")


def read_oxts(path: str | Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Read a KITTI OXTS recording (the drive's ``*_sync`` or ``*_extract`` folder, or its ``oxts``).

    Returns
    -------
    imu : DataFrame
        The IMU table of :func:`imu.read_log` (``t_s`` in seconds since the epoch, the
        timestamps read as UTC; vehicle frame, at the OXTS unit; every channel fresh).
    truth : DataFrame
        ``t_s``, ``roll_world_deg``, ``pitch_world_deg``, ``yaw_world_deg`` (the OXTS attitude
        relative to level, named as in the fused table; yaw 0 = east, counter-clockwise),
        ``speed_m_s``.

    Raises
    ------
    DecodeError
        Missing files, a packet that is not 30 numbers, timestamps that do not parse or do not
        increase, or a packet count that differs from the timestamps'.
    """
    root = _oxts_dir(Path(path))
    files = sorted((root / "data").glob("*.txt"))
    if not files:
        raise DecodeError(f"{root / 'data'}: no OXTS packets (*.txt)")
    stamps = [s for s in (root / "timestamps.txt").read_text().splitlines() if s.strip()]
    if len(stamps) != len(files):
        raise DecodeError(f"{root}: {len(files)} OXTS packets but {len(stamps)} timestamps")
    try:
        t = pd.to_datetime(stamps, format="%Y-%m-%d %H:%M:%S.%f").to_numpy(dtype="datetime64[ns]")
    except ValueError as exc:
        raise DecodeError(f"{root / 'timestamps.txt'}: {exc}") from None
    t_s = t.astype(np.int64) / 1e9
    if np.any(np.diff(t_s) <= 0):
        raise DecodeError(f"{root / 'timestamps.txt'}: timestamps do not increase")
    rows = []
    for f in files:
        try:
            values = [float(v) for v in f.read_text().split()]
        except ValueError:
            raise DecodeError(f"{f}: not a list of numbers") from None
        if len(values) != len(_FIELDS):
            raise DecodeError(f"{f}: {len(values)} values, an OXTS packet has {len(_FIELDS)}")
        rows.append(values)
    o = dict(zip(_FIELDS, np.array(rows).T))
    imu = pd.DataFrame({"t_s": t_s,
                        "gyro_x_rad_s": o["wx"], "gyro_y_rad_s": o["wy"], "gyro_z_rad_s": o["wz"],
                        "accel_x_m_s2": o["ax"], "accel_y_m_s2": o["ay"], "accel_z_m_s2": o["az"],
                        "speed_m_s": o["vf"]})
    for c, v in zip(FRESH_COLUMNS, VALUE_COLUMNS):   # a packet's nan or inf is no value
        fine = np.isfinite(imu[v].to_numpy())
        imu.loc[~fine, v] = np.nan
        imu[c] = fine
    imu = imu[list(COLUMNS)]
    truth = pd.DataFrame({"t_s": t_s, "roll_world_deg": np.degrees(o["roll"]),
                          "pitch_world_deg": np.degrees(o["pitch"]), "yaw_world_deg": np.degrees(o["yaw"]),
                          "speed_m_s": o["vf"]})
    return imu, truth
