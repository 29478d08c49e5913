"""Shared inputs of the fusion tests: a simulated drive's IMU table (vehicle frame, as
``imu.read_log`` gives it) and vision results drawn from the truth with known noise.

Drawing the vision results from the truth (instead of rendering and running the estimator)
isolates the filter: its errors can then be compared with the noise it was given.
"""

from __future__ import annotations

import dataclasses
import math
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

from drivesim.drive import SIM_ATTITUDE_WALK_DEG_SQRT_S, build_road, truth_frame
from drivesim.imu_model import simulate_imu
from drivesim.scenario import load_scenario
from drivesim.trajectory import Trajectory
from fusion.metrics import truth_lane_plane_curvature
from imu.config import ImuMount

SCENARIOS = Path(__file__).resolve().parents[1] / "configs" / "scenarios"
#: The simulated accelerometer's white noise per sample (every scenario's), which is what the
#: filter should be told for a simulated drive (``tools/drivesim/drive.py`` writes it into a
#: drive's config).
SIM_ACCEL_NOISE_M_S2 = 0.03
#: The noise model's values for a synthetic drive, as the simulator's configs give them: the
#: accelerometer's residual after calibration as a datasheet gives it (0.05 m/s^2 every axis, the
#: scenarios' ``accel_bias_sigma_m_s2``; not the bias drawn, ``synth_drive``'s 0.03 / 0.01 / 0.03,
#: which the filter was told until 2026-11-26: every test here passed with either), and its
#: accelerometer noise, all the simulated vehicle's specific force leaves out (the default allows
#: for a real car's suspension and road, ``NoiseModel.accel_meas_m_s2``), and the attitude
#: allowance for its gyros, which see every rotation (``SIM_ATTITUDE_WALK_DEG_SQRT_S``; the
#: default allows for a real vehicle's).
SIM_NOISE = dict(init_accel_bias_m_s2=0.05, accel_meas_m_s2=(SIM_ACCEL_NOISE_M_S2,) * 3,
                 attitude_walk_rad_sqrt_s=math.radians(SIM_ATTITUDE_WALK_DEG_SQRT_S))


@dataclasses.dataclass
class SynthDrive:
    imu: pd.DataFrame
    vision: pd.DataFrame
    truth: pd.DataFrame
    imu_truth: pd.DataFrame
    lever_arm_m: tuple
    traj: Trajectory


@lru_cache(maxsize=8)
def synth_drive(scenario: str = "banked_curves_60s.toml", duration_s: float | None = None,
                vision_sigma_deg: float = 0.3, fps: float = 30.0, seed: int = 0,
                accel_bias_m_s2: tuple = (0.03, 0.01, -0.03), pitch_rate: bool = True,
                curvature_error: float = 0.0, wheelbase_m: float = 0.0, vehicle: str | None = None) -> SynthDrive:
    sc = load_scenario(SCENARIOS / scenario)
    if wheelbase_m:
        sc = dataclasses.replace(sc, motion=dataclasses.replace(sc.motion, wheelbase_m=wheelbase_m))
    if vehicle is not None:
        sc = dataclasses.replace(sc, motion=dataclasses.replace(sc.motion, vehicle=vehicle))
    assert sc.imu.accel_noise_m_s2 == SIM_ACCEL_NOISE_M_S2, "the tests tell the filter SIM_ACCEL_NOISE_M_S2"
    imu_spec = dataclasses.replace(sc.imu, accel_bias_m_s2=accel_bias_m_s2, pitch_rate=pitch_rate)
    sc = dataclasses.replace(sc, imu=imu_spec, duration_s=duration_s or sc.duration_s)
    traj = Trajectory(build_road(sc), sc.motion)
    rng = np.random.default_rng(seed)
    meas, speed, imu_truth = simulate_imu(traj, sc.imu, sc.duration_s, rng)
    R = ImuMount(sc.imu.axes, sc.imu.position_m).R_v_from_imu
    t = meas["t_s"].to_numpy()
    imu = pd.DataFrame({"t_s": t})
    g = meas[[f"gyro_{a}_rad_s" for a in "xyz"]].to_numpy() @ R.T
    f = meas[[f"accel_{a}_m_s2" for a in "xyz"]].to_numpy() @ R.T
    for i, a in enumerate("xyz"):
        imu[f"gyro_{a}_rad_s"] = g[:, i]
    for i, a in enumerate("xyz"):
        imu[f"accel_{a}_m_s2"] = f[:, i]
    if not pitch_rate:
        imu["gyro_y_rad_s"] = np.nan
    imu["speed_m_s"] = np.interp(t, speed["t_s"], speed["speed_m_s"])
    fresh = np.zeros(len(t), dtype=bool)
    fresh[np.clip(np.searchsorted(t, speed["t_s"].to_numpy()), 0, len(t) - 1)] = True
    imu["fresh_speed"] = fresh
    tf = np.arange(0.0, sc.duration_s, 1.0 / fps)
    tr = traj.truth(tf)
    noise = rng.standard_normal((len(tf), 3)) * vision_sigma_deg
    vision = pd.DataFrame({
        "t_s": tf, "frame": np.arange(len(tf)),
        "roll_deg": np.degrees(tr["roll"]) + noise[:, 0], "pitch_deg": np.degrees(tr["pitch"]) + noise[:, 1],
        "yaw_deg": np.degrees(tr["yaw"]) + noise[:, 2], "valid": True,
        "roll_sigma_deg": vision_sigma_deg, "pitch_sigma_deg": vision_sigma_deg, "yaw_sigma_deg": vision_sigma_deg,
        # the lane fit's curvature is the road plane's (fusion.ekf._lane_plane_curvature)
        "curvature_1_m": truth_lane_plane_curvature(truth_frame(traj, tf, tf)) * (1.0 + curvature_error),
        "lateral_offset_m": tr["lateral_offset_m"],
        # what a good lane fit would claim: 2e-4 1/m plus 5 % (a biased fit lies about it)
        "curvature_sigma_1_m": 2e-4 + 0.05 * np.abs(tr["curvature_1_m"]),
    })
    tt = np.arange(0.0, sc.duration_s, 0.01)
    truth = truth_frame(traj, tt, tt)
    return SynthDrive(imu, vision, truth, imu_truth, tuple(sc.imu.position_m), traj)


def rmse_deg(est: pd.DataFrame, truth: pd.DataFrame, col: str, t_min: float = 2.0, mask=None) -> float:
    t = est["t_s"].to_numpy()
    m = t >= t_min if mask is None else (t >= t_min) & mask
    ref = np.interp(t[m], truth["t_s"], truth[col])
    return float(math.sqrt(np.mean((est[col].to_numpy()[m] - ref) ** 2)))
