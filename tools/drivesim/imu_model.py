"""Simulated IMU and wheel-speed sensor: exact kinematics plus bias, bias walk and noise.

Angular rate and specific force come from :class:`drivesim.trajectory.Trajectory` (the
derivative of the rotation, the second derivative of the IMU's position); they are rotated
into the IMU's own axes (``[imu] axes``), then get a constant bias, an optional random-walk
bias and white noise, all in the IMU's axes. Samples are instantaneous (no anti-alias filter
delay). Wheel speed is the contact point's ground speed times a scale error plus noise.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from imu.config import ImuMount

from .scenario import ImuSpec
from .trajectory import Trajectory

__all__ = ["simulate_imu"]

AX = ("x", "y", "z")


def simulate_imu(traj: Trajectory, spec: ImuSpec, duration_s: float, rng: np.random.Generator):
    """Sample the IMU and the wheel-speed sensor over ``[spec.start_s, duration_s]``.

    Returns
    -------
    measured : DataFrame
        ``t_s``, ``gyro_{x,y,z}_rad_s``, ``accel_{x,y,z}_m_s2`` in the IMU's own axes, with
        bias and noise: what goes onto the CAN bus.
    speed : DataFrame
        ``t_s``, ``speed_m_s``: the wheel-speed sensor.
    truth : DataFrame
        ``t_s``, true ``gyro_*_rad_s`` and ``accel_*_m_s2`` in the vehicle frame at the IMU,
        and the biases in the vehicle frame, ``gyro_bias_*_rad_s``, ``accel_bias_*_m_s2``.
    """
    t = spec.start_s + np.arange(int(math.floor((duration_s - spec.start_s) * spec.rate_hz + 1e-9)) + 1) / spec.rate_hz
    dt = 1.0 / spec.rate_hz
    mount = ImuMount(spec.axes, spec.position_m)
    R_imu_from_v = mount.R_v_from_imu.T

    w_v = traj.body_rate_rad_s(t)
    f_v = traj.specific_force_m_s2(t, spec.position_m)

    def bias(constant, walk_per_sqrt_s):
        b = np.broadcast_to(np.asarray(constant, dtype=float), (len(t), 3)).copy()
        if walk_per_sqrt_s > 0:
            b += np.cumsum(rng.standard_normal((len(t), 3)) * walk_per_sqrt_s * math.sqrt(dt), axis=0)
        return b

    gyro_bias_imu = bias(np.radians(spec.gyro_bias_deg_s), math.radians(spec.gyro_bias_walk_deg_s_sqrt_s))
    accel_bias_imu = bias(spec.accel_bias_m_s2, spec.accel_bias_walk_m_s2_sqrt_s)
    gyro_imu = (w_v @ R_imu_from_v.T) + gyro_bias_imu + rng.standard_normal((len(t), 3)) * math.radians(spec.gyro_noise_deg_s)
    accel_imu = (f_v @ R_imu_from_v.T) + accel_bias_imu + rng.standard_normal((len(t), 3)) * spec.accel_noise_m_s2

    measured = pd.DataFrame({"t_s": t})
    truth = pd.DataFrame({"t_s": t})
    gyro_bias_v = gyro_bias_imu @ R_imu_from_v
    accel_bias_v = accel_bias_imu @ R_imu_from_v
    for i, a in enumerate(AX):
        measured[f"gyro_{a}_rad_s"] = gyro_imu[:, i]
    for i, a in enumerate(AX):
        measured[f"accel_{a}_m_s2"] = accel_imu[:, i]
    for i, a in enumerate(AX):
        truth[f"gyro_{a}_rad_s"] = w_v[:, i]
        truth[f"accel_{a}_m_s2"] = f_v[:, i]
        truth[f"gyro_bias_{a}_rad_s"] = gyro_bias_v[:, i]
        truth[f"accel_bias_{a}_m_s2"] = accel_bias_v[:, i]

    ts = spec.start_s + np.arange(int(math.floor((duration_s - spec.start_s) * spec.speed_rate_hz + 1e-9)) + 1) / spec.speed_rate_hz
    v = traj.pose(ts)["speed_m_s"] * spec.speed_scale + rng.standard_normal(len(ts)) * spec.speed_noise_m_s
    speed = pd.DataFrame({"t_s": ts, "speed_m_s": np.maximum(v, 0.0)})
    return measured, speed, truth
