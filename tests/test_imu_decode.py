"""The numpy decode (imu.decode) is identical to cantools, frame by frame, and so is its scalar twin;
multiplexed, extended-ID, CAN FD, big- and little-endian, signed and float signals decode through
the whole read_log pipeline to the values cantools gives."""

from __future__ import annotations

import math

import can
import cantools
import numpy as np
import pytest
from cantools.database.can import Message, Signal
from cantools.database.conversion import BaseConversion
from hypothesis import given, settings
from hypothesis import strategies as st

from imu import CanMapping, ImuMount, read_log
from imu.dbc import resolve
from imu.decode import decode_frame, decode_source, extract_raw, physical, physical_scalar

FD_LENGTHS = (1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


@st.composite
def layouts(draw, lengths=FD_LENGTHS):
    """A message of one of ``lengths`` bytes with one signal anywhere in it: byte order,
    length, sign, float, scaling."""
    nbytes = draw(st.sampled_from(lengths))
    is_float = draw(st.booleans()) and nbytes * 8 >= 32
    if is_float:
        length = draw(st.sampled_from([32, 64] if nbytes * 8 >= 64 else [32]))
    else:
        length = draw(st.integers(1, min(64, nbytes * 8)))
    order = draw(st.sampled_from(["little_endian", "big_endian"]))
    first = draw(st.integers(0, nbytes * 8 - length))  # LSB index (little) or network MSB index (big)
    start = first if order == "little_endian" else 8 * (first // 8) + 7 - first % 8
    signed = (not is_float) and draw(st.booleans())
    scale = draw(st.sampled_from([1, 0.5, 0.005, 0.0001274, 0.03589, 0.244, 2.0, -0.1]))
    offset = draw(st.sampled_from([0, -163.84, -18.375, -125, 3.5, -67.67]))
    sig = Signal("S", start, length, order, signed,
                 conversion=BaseConversion.factory(scale=scale, offset=offset, choices=None, is_float=is_float))
    msg = Message(0x123, "M", nbytes, [sig], is_fd=nbytes > 8, strict=True)
    payloads = draw(st.lists(st.binary(min_size=nbytes, max_size=nbytes), min_size=1, max_size=16))
    return msg, sig, payloads


@pytest.mark.filterwarnings("error::RuntimeWarning")   # NaN/inf payloads decode silently, as in cantools
@settings(max_examples=400, deadline=None)
@given(layouts())
def test_numpy_and_scalar_decode_equal_cantools(case):
    """Bit for bit: the same IEEE-754 operations as cantools (raw * scale + offset)."""
    msg, sig, payloads = case
    data = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(len(payloads), msg.length)
    got = physical(data, sig)
    for i, p in enumerate(payloads):
        want = msg.decode(p, decode_choices=False)["S"]
        scalar = physical_scalar(p, sig)
        if isinstance(want, float) and math.isnan(want):
            assert math.isnan(got[i]) and math.isnan(scalar)
            continue
        if abs(want) < 2**53 or isinstance(want, float):
            assert got[i] == float(want) and scalar == float(want), (p.hex(), want, got[i], scalar)
        else:  # 54..64-bit integers: cantools keeps a Python int, we round it to the nearest double
            assert got[i] == float(want) == scalar


@settings(max_examples=200, deadline=None)
@given(layouts(lengths=[8]))
def test_fast_and_general_raw_paths_agree(case):
    """8-byte frames read one 64-bit word; the general path (CAN FD) must give the same bits."""
    msg, sig, payloads = case
    data = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(len(payloads), 8)
    wide = np.zeros((len(payloads), 16), dtype=np.uint8)
    wide[:, :8] = data
    assert np.array_equal(extract_raw(data, sig), extract_raw(wide, sig))


VARIANTS_DBC = """VERSION ""

NS_ :

BS_:

BU_: IMU ABS

BO_ 2633962036 IMU_FD: 64 IMU
 SG_ FdRateX : 100|16@1- (0.01,0) [-327.68|327.67] "deg/s" Vector__XXX
 SG_ FdRateY : 263|16@0- (0.01,0) [-327.68|327.67] "Deg/sec" Vector__XXX
 SG_ FdRateZ : 400|32@1- (1,0) [-10|10] "rad/s" Vector__XXX

BO_ 512 IMU_MUX: 8 IMU
 SG_ Page M : 0|2@1+ (1,0) [0|3] "" Vector__XXX
 SG_ AccX m0 : 8|16@1- (0.001,0) [-32.768|32.767] "m/s^2" Vector__XXX
 SG_ AccY m1 : 8|16@1- (0.001,0) [-32.768|32.767] "m/s2" Vector__XXX
 SG_ AccZ m2 : 15|16@0- (0.0001,0) [-3.2768|3.2767] "G" Vector__XXX

BO_ 513 WHEEL: 8 ABS
 SG_ Speed : 55|16@0+ (0.01,0) [0|655.35] "mph" Vector__XXX

SIG_VALTYPE_ 2633962036 FdRateZ : 1;
"""

VARIANT_SIGNALS = {"gyro_x": "IMU_FD.FdRateX", "gyro_y": "IMU_FD.FdRateY", "gyro_z": "IMU_FD.FdRateZ",
                   "accel_x": "IMU_MUX.AccX", "accel_y": "IMU_MUX.AccY", "accel_z": "IMU_MUX.AccZ",
                   "speed": "WHEEL.Speed"}


def _variant_messages(db, n=200, seed=0):
    """CAN FD rate frame (extended ID), then three multiplexed accel pages 150 us apart, and a
    big-endian wheel-speed frame every other sample."""
    rng = np.random.default_rng(seed)
    fd, mux, wheel = (db.get_message_by_name(x) for x in ("IMU_FD", "IMU_MUX", "WHEEL"))
    msgs, truth = [], []
    for k in range(n):
        t = 100.0 + 0.01 * k
        r = {"FdRateX": float(rng.uniform(-300, 300)), "FdRateY": float(rng.uniform(-300, 300)),
             "FdRateZ": float(np.float32(rng.uniform(-5, 5)))}
        a = {"AccX": float(rng.uniform(-30, 30)), "AccY": float(rng.uniform(-30, 30)),
             "AccZ": float(rng.uniform(-3, 3))}
        truth.append((t, r, a))
        msgs.append(can.Message(timestamp=t, arbitration_id=fd.frame_id, is_extended_id=True, is_fd=True,
                                bitrate_switch=True, data=fd.encode(r), channel=0))
        for page, name in enumerate(("AccX", "AccY", "AccZ")):
            msgs.append(can.Message(timestamp=t + 150e-6 * (page + 1), arbitration_id=mux.frame_id,
                                    is_extended_id=False, data=mux.encode({"Page": page, name: a[name]}), channel=0))
        if k % 2 == 0:
            msgs.append(can.Message(timestamp=t + 0.004, arbitration_id=wheel.frame_id, is_extended_id=False,
                                    data=wheel.encode({"Speed": 40.0 + 0.01 * k}), channel=0))
    return msgs, truth


def test_mapped_signals_that_share_bits_within_a_frame_are_refused(tmp_path):
    """AccX (page 0) and AccY (page 1) lie on the same bits in different pages of the
    multiplexer: never in one frame, accepted. A plain signal of the message on AccX's bits is
    in every page-0 frame: mapped with AccX, refused (the first check compared only signals of
    one page, a review); so is a mapped signal on the multiplexer's own bits."""
    from imu import ImuConfigError

    dbc = tmp_path / "v.dbc"
    dbc.write_text(VARIANTS_DBC)
    resolve(CanMapping(dbc, VARIANT_SIGNALS))
    dbc.write_text(VARIANTS_DBC.replace(" SG_ AccX m0", ' SG_ Temp : 8|16@1- (0.001,0) [-32.768|32.767] "m/s^2" '
                                        "Vector__XXX\n SG_ AccX m0"))
    with pytest.raises(ImuConfigError, match="IMU_MUX.Temp and IMU_MUX.AccX share 16 bit"):
        resolve(CanMapping(dbc, dict(VARIANT_SIGNALS, accel_x="IMU_MUX.Temp", accel_y="IMU_MUX.AccX")))
    dbc.write_text(VARIANTS_DBC.replace("SG_ AccX m0 : 8|16@1-", "SG_ AccX m0 : 0|16@1-"))
    with pytest.raises(ImuConfigError, match="IMU_MUX.AccX and multiplexer Page share 2 bit"):
        resolve(CanMapping(dbc, VARIANT_SIGNALS))


@pytest.mark.parametrize("suffix", [".blf", ".asc", ".log"])  # the writers that keep CAN FD frames
def test_fd_extended_multiplexed_both_byte_orders(tmp_path, suffix):
    dbc = tmp_path / "variants.dbc"
    dbc.write_text(VARIANTS_DBC)
    db = cantools.database.load_file(dbc)
    msgs, truth = _variant_messages(db)
    log = tmp_path / f"variants{suffix}"
    with can.Logger(log) as w:
        for m in msgs:
            w.on_message_received(m)
    mapping = CanMapping(dbc, VARIANT_SIGNALS)
    table, summary = read_log(log, mapping, ImuMount())
    assert len(table) == len(truth)
    fd, mux = db.get_message_by_name("IMU_FD"), db.get_message_by_name("IMU_MUX")
    # expected: cantools decode of what was written, times the unit factor (independent of imu.units)
    want_rate = np.array([[fd.decode(fd.encode(r))[s] for s in ("FdRateX", "FdRateY", "FdRateZ")]
                          for _, r, _ in truth]) * np.array([math.pi / 180, math.pi / 180, 1.0])
    want_acc = np.array([[mux.decode(mux.encode({"Page": p, s: a[s]}))[s] for p, s in enumerate(("AccX", "AccY", "AccZ"))]
                         for _, _, a in truth]) * np.array([1.0, 1.0, 9.80665])
    got_rate = table[["gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"]].to_numpy()
    got_acc = table[["accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]].to_numpy()
    np.testing.assert_array_equal(got_rate, want_rate)  # same double operations: exactly equal
    np.testing.assert_allclose(got_acc, want_acc, rtol=1e-15, atol=0)
    # mph -> m/s exactly 0.44704; speed is held from the latest frame before each sample
    speed = table["speed_m_s"].to_numpy()
    assert np.nanmax(np.abs(speed[1::2] - (40.0 + 0.01 * np.arange(0, 200, 2)) * 0.44704)) < 0.005 * 0.44704
    assert [s.name for s in summary.sources] == ["IMU_FD", "IMU_MUX[Page=0]", "IMU_MUX[Page=1]", "IMU_MUX[Page=2]", "WHEEL"]
    assert summary.sources[0].frame_id == "0x1CFF1234x"
    assert summary.decode_errors == 0 and all(s.unaligned == 0 for s in summary.sources)


def test_scalar_twin_equals_numpy_on_variants(tmp_path):
    """decode_frame (live path) == decode_source (log path) on random payloads, mux included."""
    dbc = tmp_path / "variants.dbc"
    dbc.write_text(VARIANTS_DBC)
    plan = resolve(CanMapping(dbc, VARIANT_SIGNALS, range_check=True))
    rng = np.random.default_rng(7)
    for src in plan.sources:
        data = rng.integers(0, 256, size=(500, src.length), dtype=np.uint8)
        vec = decode_source(data, src, True)
        for i in range(len(data)):
            present, si, valid, oor, _ = decode_frame(data[i].tobytes(), src, True)
            assert present == vec.present[i]
            if present:
                assert valid == list(vec.valid[i]) and oor == [int(x) for x in vec.out_of_range[i]]
                np.testing.assert_array_equal(np.array(si), vec.si[i])


def test_integers_beyond_2_53_are_rounded_once_as_cantools():
    """Integer scale and offset: cantools keeps an exact Python int. A raw value of 2^53 + 1
    minus 125 is 9007199254740868 exactly; rounding the raw value to a double first would give
    ...867 (found by the property test above on a fresh clone)."""
    sig = Signal("S", 0, 64, "little_endian", False,
                 conversion=BaseConversion.factory(scale=1, offset=-125, choices=None, is_float=False))
    msg = Message(0x123, "M", 8, [sig], strict=True)
    payload = (2**53 + 1).to_bytes(8, "little")
    want = msg.decode(payload, decode_choices=False)["S"]
    assert want == 2**53 + 1 - 125
    data = np.frombuffer(payload, dtype=np.uint8).reshape(1, 8)
    assert physical(data, sig)[0] == float(want) == physical_scalar(payload, sig) == 9007199254740868.0


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_float_signal_nan_and_overflow_decode_silently_as_cantools():
    """Float signals carry whatever the sender put there: a signalling NaN becomes NaN and a
    value the scale pushes past float64 becomes inf, as cantools' Python floats give them,
    without a RuntimeWarning per frame (NumPy raises the invalid/overflow flags for both)."""
    for length, payload, scale in ((32, b"\x7f\x80\x00\x01", 0.5),                       # float32 sNaN
                                   (64, b"\x7f\xf0\x00\x00\x00\x00\x00\x01", 2.0),       # float64 sNaN
                                   (64, b"\x7f\xef\xff\xff\xff\xff\xff\xff", 2.0)):      # max * 2 = inf
        sig = Signal("S", 7, length, "big_endian", False,
                     conversion=BaseConversion.factory(scale=scale, offset=0, choices=None, is_float=True))
        msg = Message(0x123, "M", 8, [sig], strict=True)
        data = np.frombuffer(payload.ljust(8, b"\0"), np.uint8)[None, :]
        ours = float(physical(data, sig)[0])
        ref = msg.decode(payload.ljust(8, b"\0"), decode_choices=False)["S"]
        assert (math.isnan(ours) and math.isnan(ref)) or ours == ref, (ours, ref)
