"""Round trip: simulated IMU samples -> CAN log (every python-can format) -> read_log -> the same
samples in the vehicle frame, within the DBC's resolution."""

from __future__ import annotations

import numpy as np
import pytest

from drivesim.canlog import LOG_FORMATS, write_can_log
from imu import COLUMNS, read_log
from test_imu_common import (
    MOUNT_FRD, RES_ACCEL_M_S2, RES_GYRO_RAD_S, RES_SPEED_M_S, sim_imu, sim_mapping, vehicle_truth,
)

#: The writer rounds to the nearest raw step, so the error is at most half a step (plus float
#: noise far below it).
TOL_GYRO_RAD_S = RES_GYRO_RAD_S / 2 * (1 + 1e-6)
TOL_ACCEL_M_S2 = RES_ACCEL_M_S2 / 2 * (1 + 1e-6)
TOL_SPEED_M_S = RES_SPEED_M_S / 2 * (1 + 1e-6)
#: Time: 1 us resolution of .asc/.log/.trc, 0.24 us float64 resolution at 1.7e9 s.
TOL_T_S = 1.5e-6


@pytest.fixture(scope="module")
def drive():
    return sim_imu(duration_s=3.0, seed=11)


@pytest.mark.parametrize("suffix", LOG_FORMATS)
def test_round_trip_every_format(tmp_path, drive, suffix):
    imu, speed = drive
    path = tmp_path / f"drive{suffix}"
    offset = write_can_log(path, imu, speed, seed=5)
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert tuple(table.columns) == COLUMNS
    assert len(table) == len(imu), "one row per IMU sample, none lost or invented"
    assert np.abs(table["t_s"].to_numpy() - offset - imu["t_s"].to_numpy()).max() < TOL_T_S
    truth = vehicle_truth(imu, MOUNT_FRD)
    gyro = table[["gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"]].to_numpy()
    accel = table[["accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]].to_numpy()
    assert np.abs(gyro - truth[:, :3]).max() <= TOL_GYRO_RAD_S
    # the accel frame comes 350 us after the rate frame and must land on the same row
    assert np.abs(accel - truth[:, 3:]).max() <= TOL_ACCEL_M_S2
    # vehicle frame is z up: at rest-like rows specific force is about +9.81 m/s^2
    assert table["accel_z_m_s2"].median() == pytest.approx(9.81 + 1.5, abs=0.5)
    assert table.filter(like="fresh_").drop(columns="fresh_speed").all().all()
    # speed: latest ABS frame strictly before the sample, held (never interpolated)
    t_imu, t_spd = imu["t_s"].to_numpy(), speed["t_s"].to_numpy()
    idx = np.searchsorted(t_spd, t_imu, side="left") - 1
    want = np.where(idx >= 0, speed["speed_m_s"].to_numpy()[np.maximum(idx, 0)], np.nan)
    got = table["speed_m_s"].to_numpy()
    assert np.array_equal(np.isnan(got), np.isnan(want))
    ok = ~np.isnan(want)
    assert np.abs(got[ok] - want[ok]).max() <= TOL_SPEED_M_S
    fresh = table["fresh_speed"].to_numpy()
    assert fresh.sum() == len(np.unique(idx[idx >= 0])), "fresh once per new ABS frame"
    assert summary.complete and summary.decode_errors == 0 and summary.unavailable == ()
    assert summary.unknown_ids == {"0x51A": summary.unknown_ids["0x51A"]}, "only the NM frame is not in the DBC"
    assert summary.sample_rate_hz == pytest.approx(100.0, rel=1e-3)


def test_imu_without_pitch_rate_is_flagged(tmp_path, drive):
    """MM5.10-like: no pitch rate. Vehicle gyro_y (= -IMU y) is NaN, never fresh, and listed."""
    imu, speed = drive
    path = tmp_path / "drive.blf"
    write_can_log(path, imu, speed, include_pitch_rate=False)
    table, summary = read_log(path, sim_mapping(include_pitch_rate=False), MOUNT_FRD)
    assert table["gyro_y_rad_s"].isna().all() and not table["fresh_gyro_y"].any()
    assert summary.unavailable == ("gyro_y_rad_s",)
    assert table.attrs["unavailable"] == ["gyro_y_rad_s"]
    assert table.attrs["channels"]["gyro_y_rad_s"] is None
    assert table.attrs["channels"]["gyro_z_rad_s"] == "-IMU_RATE.RateZ [deg/s]"
    assert any("UNAVAILABLE" in line for line in summary.lines())
    truth = vehicle_truth(imu, MOUNT_FRD)
    assert np.abs(table["gyro_x_rad_s"] - truth[:, 0]).max() <= TOL_GYRO_RAD_S


def test_sna_pitch_rate_is_invalid_when_mapped_anyway(tmp_path, drive):
    """Mapping RateY of an IMU that sends SNA (0xFFFF, outside the DBC range) gives NaN, not
    163.835 deg/s, and the summary counts it."""
    imu, speed = drive
    path = tmp_path / "drive.log"
    write_can_log(path, imu, speed, include_pitch_rate=False, extra_traffic=False)
    table, summary = read_log(path, sim_mapping(include_pitch_rate=True), MOUNT_FRD)
    assert table["gyro_y_rad_s"].isna().all() and not table["fresh_gyro_y"].any()
    gy = next(c for c in summary.channels if c.channel == "gyro_y")
    assert gy.invalid == len(imu) and gy.out_of_range == len(imu) and gy.decoded == 0


def test_attrs_survive_parquet(tmp_path, drive):
    imu, speed = drive
    path = tmp_path / "drive.trc"
    write_can_log(path, imu, speed)
    table, _ = read_log(path, sim_mapping(), MOUNT_FRD)
    table.to_parquet(tmp_path / "imu.parquet")
    import pandas as pd

    back = pd.read_parquet(tmp_path / "imu.parquet")
    assert back.attrs["imu_position_m"] == [0.0, 0.0, 0.5]
    assert back.attrs["summary"]["samples"] == len(imu)
    assert back["fresh_gyro_x"].dtype == bool
