"""Real data: 60 s of a 2017 Toyota RAV4 on highway 280 (comma2k19), its raw CAN and real opendbc DBCs.

What the segment shows, asserted with physical tolerances:

* CAN yaw rate (KINEMATICS 0x24, deg/s) and lateral acceleration come at about 83 Hz, wheel speeds
  (WHEEL_SPEEDS 0xAA, km/h) too; the car drives 8 to 20 m/s.
* The yaw rate correlates with the phone gyro's vertical axis with r = -0.78: the phone's z axis
  points down, the CAN yaw rate is positive to the left (z up, like the vehicle frame), and it
  carries a -0.44 deg/s bias (the DBC comment says "verify").
* comma's own processed wheel speeds (m/s, an independent decoder) equal ours.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from imu import CanMapping, DecodeError, ImuConfigError, ImuMount, read_log
from test_imu_common import COMMA, comma_mapping

pytestmark = pytest.mark.skipif(not COMMA.is_dir(), reason="../shared/data/comma2k19_rav4_segment not present")

LOG = COMMA / "derived" / "raw_can_candump.log"


@pytest.fixture(scope="module")
def decoded():
    return read_log(LOG, comma_mapping(), ImuMount())


def _phone(name):
    base = COMMA / "processed_log" / "IMU" / name
    return np.load(base / "t"), np.load(base / "value")


def test_rates_and_ranges_are_plausible(decoded):
    table, summary = decoded
    assert summary.frames_read == 135468  # every frame of the derived candump log
    kin = next(s for s in summary.sources if s.name == "KINEMATICS")
    # 4974 frames in 60 s: 83 Hz (comma's logs show ~83 Hz for 0x24), no gap > 0.1 s
    assert kin.frames == 4974 and kin.rate_hz == pytest.approx(82.9, abs=0.5) and kin.gaps == ()
    assert summary.duration_s == pytest.approx(60.0, abs=0.1)
    yaw_deg_s = np.degrees(table["gyro_z_rad_s"])
    # highway driving: a few deg/s at most, 0.244 deg/s resolution
    assert yaw_deg_s.abs().max() < 5.0 and yaw_deg_s.std() > 0.2
    assert table["accel_y_m_s2"].abs().max() < 3.0  # lateral: well under 0.3 g on a highway
    v = table["speed_m_s"].dropna()
    assert 5.0 < v.min() and v.max() < 25.0  # 18 to 90 km/h
    assert summary.unavailable == ("gyro_x_rad_s", "gyro_y_rad_s", "accel_x_m_s2", "accel_z_m_s2")
    assert summary.unknown_ids, "the RAV4 bus carries IDs the 2017 DBC does not describe"


def test_lateral_acceleration_is_the_turn_s_in_the_vehicle_frame(decoded):
    """On a highway the lateral specific force is the centripetal ``v r`` (a road's bank and the
    body's roll add a few tenths of m/s^2 at most): on 1 s means, correlated with it at r > 0.7
    and a slope of 0.8-1.4 (measured 0.86 and 1.07). The RAV4's ``KINEMATICS.ACCEL_Y`` counts to
    the right, so the mapping is ``-KINEMATICS.ACCEL_Y``; before, it went into the vehicle's
    left-positive y unflipped, r = -0.86, and the tests checked only its size (a review)."""
    table, _ = decoded
    t = table["t_s"].to_numpy()
    fy = table["accel_y_m_s2"].to_numpy()
    vr = table["speed_m_s"].ffill().to_numpy() * table["gyro_z_rad_s"].to_numpy()
    ok = np.isfinite(fy) & np.isfinite(vr)
    bins = np.floor((t[ok] - t[0]) / 1.0).astype(int)
    count = np.bincount(bins)
    use = count > 40                         # whole seconds (KINEMATICS at 83 Hz)
    fy1 = np.bincount(bins, fy[ok])[use] / count[use]
    vr1 = np.bincount(bins, vr[ok])[use] / count[use]
    r = np.corrcoef(fy1, vr1)[0, 1]
    slope = np.polyfit(vr1, fy1, 1)[0]
    assert r > 0.7 and 0.8 < slope < 1.4, (r, slope)


def test_yaw_rate_correlates_with_phone_gyro(decoded):
    """After time alignment (best lag within +-0.3 s), |r| > 0.7; the sign is negative because the
    phone's z axis points down while the CAN yaw rate (and the vehicle frame) is z up."""
    table, _ = decoded
    t = table["t_s"].to_numpy()
    yaw = table["gyro_z_rad_s"].to_numpy()
    pt, pg = _phone("gyro")  # same clock (device boot time) as the CAN timestamps
    lags = np.arange(-0.3, 0.301, 0.01)
    r = np.array([np.corrcoef(yaw, np.interp(t + lag, pt, pg[:, 2]))[0, 1] for lag in lags])
    best = int(np.argmax(np.abs(r)))
    print(f"comma2k19: r(CAN yaw rate, phone gyro z down) = {r[best]:+.3f} at lag {lags[best]:+.2f} s")
    assert abs(r[best]) > 0.7
    assert r[best] < 0, "CAN yaw rate is z up, the phone's gyro z is down: opposite signs"
    assert abs(lags[best]) <= 0.05  # both logged on the same device clock
    # bias: CAN yaw rate minus the (z-up) phone rate, deg/s
    bias_deg_s = np.degrees(np.mean(yaw + np.interp(t, pt, pg[:, 2])))
    assert bias_deg_s == pytest.approx(-0.42, abs=0.1)


def test_wheel_speed_equals_commas_own_decoder(decoded):
    """comma's processed_log/CAN/wheel_speed (m/s, front-left first) is an independent decode of
    the same frames: equal to float precision; our table holds it at the IMU samples."""
    table, _ = decoded
    base = COMMA / "processed_log" / "CAN" / "wheel_speed"
    t_ws, v_ws = np.load(base / "t"), np.load(base / "value")[:, 0]
    t_ws = np.array([float(f"{x:.6f}") for x in t_ws])  # as written into the candump log
    T = table["t_s"].to_numpy()
    idx = np.searchsorted(t_ws, T, side="left") - 1  # latest wheel frame strictly before each sample
    ok = (idx >= 0) & ~np.isnan(table["speed_m_s"].to_numpy())
    assert ok.sum() == len(T) - 1  # only the first sample precedes every wheel frame
    assert np.abs(T[ok] - t_ws[idx[ok]]).max() < 0.03  # both at ~83 Hz, held at most one period
    assert np.abs(table["speed_m_s"].to_numpy()[ok] - v_ws[idx[ok]]).max() < 1e-9  # 0.01 km/h = 2.8e-3 m/s


def test_broken_dbc_names_file_and_line():
    """toyota_new_mc_pt_generated.dbc: line 569 lacks its ';', cantools trips on line 570."""
    mapping = CanMapping(COMMA / "toyota_new_mc_pt_generated.dbc", {"gyro_z": "KINEMATICS.YAW_RATE"})
    with pytest.raises(DecodeError) as e:
        read_log(LOG, mapping, ImuMount())
    msg = str(e.value)
    assert "\n" not in msg
    assert "toyota_new_mc_pt_generated.dbc:570" in msg and "line 569" in msg


def test_range_check_on_an_opendbc_dbc_flags_negative_yaw(decoded):
    """opendbc gives YAW_RATE the raw range [0|65535]; with range_check the DBC's word is taken, so
    every negative yaw rate is invalid (NaN, counted), which the summary makes plain."""
    table_on, summary = read_log(LOG, comma_mapping(range_check=True), ImuMount())
    table_off, _ = decoded
    neg = table_off["gyro_z_rad_s"].to_numpy() < 0
    assert np.isnan(table_on["gyro_z_rad_s"].to_numpy()[neg]).all()
    assert not table_on["fresh_gyro_z"].to_numpy()[neg].any()
    ch = next(c for c in summary.channels if c.channel == "gyro_z")
    assert ch.invalid == neg.sum() and ch.out_of_range == ch.invalid


def test_raw_arrays_drop_trailing_zero_bytes(tmp_path, decoded):
    """Frames rebuilt from comma's |S8 arrays lose trailing 0x00 bytes: they are counted as wrong
    length, or zero-padded and decoded to the same table with pad_short_frames."""
    base = COMMA / "processed_log" / "CAN" / "raw_can"
    t, addr, data, src = (np.load(base / n) for n in ("t", "address", "data", "src"))
    log = tmp_path / "raw.log"
    with open(log, "w") as f:
        for ti, a, d, s in zip(t, addr, data, src):
            f.write(f"({ti:.6f}) can{s} {a:03X}#{bytes(d).hex().upper()}\n")
    table, summary = read_log(log, comma_mapping(), ImuMount())
    short = {s.name: s.wrong_length for s in summary.sources}
    assert short["KINEMATICS"] > 0 and summary.decode_errors >= short["KINEMATICS"]
    assert len(table) == 4974 - short["KINEMATICS"]
    padded, summary_p = read_log(log, comma_mapping(pad_short_frames=True), ImuMount())
    reference, _ = decoded
    assert summary_p.sources[0].padded == short["KINEMATICS"]
    np.testing.assert_array_equal(padded["gyro_z_rad_s"], reference["gyro_z_rad_s"])
    assert np.abs(padded["t_s"] - reference["t_s"]).max() < 1e-6


def test_same_id_on_two_buses_needs_a_channel():
    """0x228 (ACCELEROMETER in this DBC) is on bus 0 and bus 1: without [can] channel the reader
    stops with a one-line error naming the frame ID rather than interleaving two buses."""
    mapping = CanMapping(COMMA / "toyota_rav4_2017_pt_generated.dbc",
                         {"accel_x": "ACCELEROMETER.ACCEL_X"}, range_check=False)
    with pytest.raises(DecodeError, match=r"frame 0x228 \(ACCELEROMETER\) appears on bus channels"):
        read_log(LOG, mapping, ImuMount())


def test_signal_without_unit_needs_an_override():
    """STEERING_TORQUE (bits 17|10 of 0x24) has no unit in the 2017 DBC."""
    mapping = CanMapping(COMMA / "toyota_rav4_2017_pt_generated.dbc", {"accel_x": "KINEMATICS.STEERING_TORQUE"})
    with pytest.raises(ImuConfigError, match=r"KINEMATICS.STEERING_TORQUE has no unit; set \[can.units\] accel_x"):
        read_log(LOG, mapping, ImuMount())
    ok = CanMapping(mapping.dbc_path, mapping.signals, units={"accel_x": "m/s^2"}, range_check=False, channel="can0")
    table, _ = read_log(LOG, ok, ImuMount())
    assert math.isfinite(table["accel_x_m_s2"].abs().max())
