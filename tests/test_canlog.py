"""The simulator's CAN writer: the clock offset it returns is exact for every frame of every format,
every payload is the DBC encoding, and the traffic looks like a real motorcycle bus."""

from __future__ import annotations

import math

import can
import cantools
import numpy as np
import pytest

from drivesim.canlog import _crc8_j1850, ACC_DELAY_S, DBC_PATH, LOG_FORMATS, signal_map, write_can_log
from test_imu_common import sim_imu

#: python-can writes .asc/.log/.trc times with 1 us resolution, and float64 resolves 0.24 us at
#: 1.7e9 s; 1.5 us covers both with margin and is far below the 350 us rate-to-accel spacing.
TIME_TOL_S = 1.5e-6


@pytest.fixture(scope="module")
def drive():
    return sim_imu(duration_s=2.0)


def _expected_frames(imu, speed):
    """(drive time, ID) of the IMU and ABS frames the writer must send."""
    t = imu["t_s"].to_numpy()
    return ([(x, 0x174) for x in t] + [(x + ACC_DELAY_S, 0x178) for x in t]
            + [(x, 0x122) for x in speed["t_s"].to_numpy()])


@pytest.mark.parametrize("suffix", LOG_FORMATS)
@pytest.mark.parametrize("epoch", [1.7e9, 0.0])
def test_offset_exact_for_every_frame(tmp_path, drive, suffix, epoch):
    """LogReader(path) returns t + offset for every IMU/ABS frame, also with a 1970 epoch
    (BLF then stores no date and counts from the first frame)."""
    imu, speed = drive
    path = tmp_path / f"drive{suffix}"
    offset = write_can_log(path, imu, speed, start_epoch_s=epoch, seed=3)
    got: dict[int, list[float]] = {}
    for m in can.LogReader(path):
        got.setdefault(m.arbitration_id, []).append(m.timestamp)
    for fid, times in [(0x174, imu["t_s"]), (0x178, imu["t_s"] + ACC_DELAY_S), (0x122, speed["t_s"])]:
        read = np.asarray(got[fid]) - offset
        assert len(read) == len(times)
        err = np.abs(read - np.asarray(times))
        assert err.max() < TIME_TOL_S, (suffix, hex(fid), err.max())


def test_payloads_are_the_dbc_encoding(tmp_path, drive):
    """Decoding the written frames with cantools gives the samples to within half a raw step."""
    imu, speed = drive
    path = tmp_path / "drive.blf"
    write_can_log(path, imu, speed)
    db = cantools.database.load_file(DBC_PATH)
    rate, acc, abs_ = (db.get_message_by_name(n) for n in ("IMU_RATE", "IMU_ACC", "ABS_SPEED"))
    rates, accs, speeds = [], [], []
    for m in can.LogReader(path):
        if m.arbitration_id == rate.frame_id:
            rates.append(rate.decode(m.data, decode_choices=False))
        elif m.arbitration_id == acc.frame_id:
            accs.append(acc.decode(m.data, decode_choices=False))
        elif m.arbitration_id == abs_.frame_id:
            speeds.append(abs_.decode(m.data, decode_choices=False))
    rz = np.array([r["RateZ"] for r in rates])
    # encode rounds to the nearest 0.005 deg/s step
    assert np.abs(rz - np.degrees(imu["gyro_z_rad_s"])).max() <= 0.0025 + 1e-9
    az = np.array([a["AccZ"] for a in accs])
    assert np.abs(az - imu["accel_z_m_s2"] / 9.80665).max() <= 0.0001274 / 2 + 1e-9
    v = np.array([s["WheelSpeedFront"] for s in speeds])
    assert np.abs(v - 3.6 * speed["speed_m_s"]).max() <= 0.005 + 1e-9
    # alive counters count 0..15 and the CRC-8 (SAE J1850) byte matches bytes 0..6
    assert [r["RateCounter"] for r in rates[:20]] == [i % 16 for i in range(20)]
    assert _crc8_j1850(b"123456789") == 0x4B  # the standard check value of CRC-8/SAE-J1850
    for m in can.LogReader(path):
        if m.arbitration_id in (rate.frame_id, acc.frame_id, abs_.frame_id):
            assert m.data[7] == _crc8_j1850(bytes(m.data[:7]))


def test_traffic_like_a_real_bus(tmp_path, drive):
    """Other nodes: multiplexed dashboard frames, extended IDs, and an ID not in the DBC."""
    imu, speed = drive
    path = tmp_path / "drive.log"
    write_can_log(path, imu, speed, seed=1)
    msgs = list(can.LogReader(path))
    db = cantools.database.load_file(DBC_PATH)
    ids = {m.arbitration_id for m in msgs}
    assert {0x100, 0x500, 0x3E8, 0x18FEF100, 0x18FF5021, 0x51A} <= ids
    assert all(m.is_extended_id == (m.arbitration_id > 0x7FF) for m in msgs)
    dash = db.get_message_by_name("DASH_STATUS")
    muxes = {dash.decode(m.data, decode_choices=False)["DashMux"] for m in msgs if m.arbitration_id == 0x3E8}
    assert muxes == {0, 1, 2}
    rate_hz = sum(m.arbitration_id == 0x174 for m in msgs) / 2.0
    assert rate_hz == pytest.approx(100, abs=1)  # the IMU's 100 Hz
    t = np.array([m.timestamp for m in msgs])
    assert np.all(np.diff(t) >= 0), "frames must be written in time order"


def test_without_pitch_rate_sends_sna(tmp_path, drive):
    """An MM5.10-like IMU has no pitch rate: RateY is 0xFFFF (SNA, outside the DBC range)."""
    imu, speed = drive
    path = tmp_path / "drive.csv"
    write_can_log(path, imu, speed, include_pitch_rate=False, extra_traffic=False)
    rates = [m for m in can.LogReader(path) if m.arbitration_id == 0x174]
    assert all(bytes(m.data[2:4]) == b"\xff\xff" for m in rates)
    assert "gyro_y" not in signal_map(False) and signal_map(True)["gyro_y"] == "IMU_RATE.RateY"
    assert {m.arbitration_id for m in can.LogReader(path)} == {0x174, 0x178, 0x122}


def test_bad_arguments(tmp_path, drive):
    imu, speed = drive
    with pytest.raises(ValueError, match="suffix"):
        write_can_log(tmp_path / "x.txt", imu, speed)
    with pytest.raises(ValueError, match="lacks column"):
        write_can_log(tmp_path / "x.asc", imu.drop(columns="gyro_y_rad_s"), speed)
    bad = imu.copy()
    bad.loc[3, "t_s"] = bad.loc[2, "t_s"]
    with pytest.raises(ValueError, match="increase"):
        write_can_log(tmp_path / "x.asc", bad, speed)
    with pytest.raises(ValueError, match="start_epoch_s"):
        write_can_log(tmp_path / "x.asc", imu, speed, start_epoch_s=math.nan)


@pytest.mark.parametrize("suffix", LOG_FORMATS)
def test_a_log_written_again_is_the_same_to_the_byte(tmp_path, drive, suffix):
    """The same drive written again, later and through another folder (a simulation writes into
    ``OUT.partial``), is the same file: the ASC header's ``date`` is the drive's first frame's
    time, not the time of writing, and the TRC header names the file, not the path written to
    (found, not fixed, since the fifteenth session); the MF4 frames' times are stored from the
    first frame's, not from the time of writing. Left: asammdf's file-history block of the MF4
    holds the time of saving (8 bytes of a 56-byte block), which is what it is for."""
    import time

    imu, speed = drive
    paths = [tmp_path / d / f"drive{suffix}" for d in ("one", "two.partial")]
    write_can_log(paths[0], imu, speed, seed=3)
    time.sleep(1.1)            # a second later: the time of writing would show in a date
    write_can_log(paths[1], imu, speed, seed=3)
    a, b = (p.read_bytes() for p in paths)
    if suffix == ".mf4":    # the file history block (##FH, 56 bytes) apart
        i = a.index(b"##FH")
        assert b.index(b"##FH") == i and a[i + 8:i + 16] == (56).to_bytes(8, "little")
        a, b = a[:i] + a[i + 56:], b[:i] + b[i + 56:]
    assert a == b
