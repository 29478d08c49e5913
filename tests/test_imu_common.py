"""Shared helpers of the imu tests (no tests here): simulated IMU samples, mappings, data paths.

The simulated samples are in the IMU's OWN axes, as ``drivesim.canlog.write_can_log`` takes them,
with an FRD-mounted IMU (``[imu] axes = ["x", "-y", "-z"]``): a motorcycle weaving through bends
(roll rate up to 0.6 rad/s, yaw rate 0.3 rad/s, lateral specific force 4 m/s^2) with gravity on
the IMU's z axis (specific force -9.81 m/s^2 in FRD at rest).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from drivesim.canlog import DBC_PATH, signal_map
from conftest import shared_data_dir
from imu import CanMapping, ImuMount

#: Real third-party data, next to the checkout (never copied into it).
SHARED_DATA = shared_data_dir()
COMMA = SHARED_DATA / "comma2k19_rav4_segment"

#: FRD-mounted IMU, 0.5 m above the front contact point.
MOUNT_FRD = ImuMount(("x", "-y", "-z"), (0.0, 0.0, 0.5))

IMU_COLUMNS = ("gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s", "accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2")

#: One raw step of the simulator's DBC in SI: 0.005 deg/s, 0.0001274 g, 0.01 km/h.
RES_GYRO_RAD_S = math.radians(0.005)
RES_ACCEL_M_S2 = 0.0001274 * 9.80665
RES_SPEED_M_S = 0.01 / 3.6


def sim_imu(duration_s: float = 3.0, rate_hz: float = 100.0, speed_rate_hz: float = 50.0,
            seed: int = 0) -> tuple[pd.DataFrame, pd.DataFrame]:
    """IMU samples (IMU axes, FRD) and wheel speed like the drive simulator's."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration_s * rate_hz)) / rate_hz
    w = 2 * np.pi * 0.4
    imu = pd.DataFrame({
        "t_s": t,
        "gyro_x_rad_s": 0.6 * np.cos(w * t) + rng.normal(0, 0.003, len(t)),
        "gyro_y_rad_s": -0.05 * np.sin(2 * w * t) + rng.normal(0, 0.003, len(t)),   # FRD: pitch
        "gyro_z_rad_s": -0.3 * np.sin(w * t) + rng.normal(0, 0.003, len(t)),        # FRD: yaw, down
        "accel_x_m_s2": 0.8 * np.sin(0.5 * w * t) + rng.normal(0, 0.05, len(t)),
        "accel_y_m_s2": -4.0 * np.sin(w * t) + rng.normal(0, 0.05, len(t)),
        "accel_z_m_s2": -9.81 - 1.5 * (1 - np.cos(2 * w * t)) + rng.normal(0, 0.05, len(t)),
    })
    ts = 0.003 + np.arange(int((duration_s - 0.003) * speed_rate_hz)) / speed_rate_hz
    speed = pd.DataFrame({"t_s": ts, "speed_m_s": 15.0 + 3.0 * np.sin(0.2 * ts) + rng.normal(0, 0.05, len(ts))})
    return imu, speed


def sim_mapping(include_pitch_rate: bool = True, **kw) -> CanMapping:
    return CanMapping(DBC_PATH, signal_map(include_pitch_rate), **kw)


def comma_mapping(**kw) -> CanMapping:
    """The comma2k19 RAV4: CAN yaw rate (z up, as the vehicle frame), lateral accel, front-left wheel.

    The opendbc DBC gives raw ranges such as [0|65535] for signed quantities, hence
    ``range_check=False``; bus 0 (``can0``) is the powertrain bus.
    """
    kw.setdefault("range_check", False)
    kw.setdefault("channel", "can0")
    return CanMapping(COMMA / "toyota_rav4_2017_pt_generated.dbc",
                      {"gyro_z": "KINEMATICS.YAW_RATE", "accel_y": "-KINEMATICS.ACCEL_Y",
                       "speed": "WHEEL_SPEEDS.WHEEL_SPEED_FL"}, **kw)


def vehicle_truth(imu: pd.DataFrame, mount: ImuMount) -> np.ndarray:
    """``(n, 6)`` gyro and accel in the vehicle frame: ``R_v_from_imu`` applied to the IMU axes."""
    R = mount.R_v_from_imu
    v = imu[list(IMU_COLUMNS)].to_numpy()
    return np.hstack([v[:, :3] @ R.T, v[:, 3:] @ R.T])
