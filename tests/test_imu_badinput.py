"""Bad input, one injected fault per test (named for what it injects): either the good part is
decoded and the rest counted, or the read stops with one line naming the file, line or frame ID."""

from __future__ import annotations

import dataclasses
import math

import can
import numpy as np
import pandas as pd
import pytest

from drivesim.canlog import write_can_log
from imu import CanMapping, DecodeError, ImuConfigError, read_log
from test_imu_common import MOUNT_FRD, RES_GYRO_RAD_S, sim_imu, sim_mapping, vehicle_truth

TOL_GYRO_RAD_S = RES_GYRO_RAD_S / 2 * (1 + 1e-6)  # half a raw step: the writer rounds


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """A 3-s simulated drive as messages (exact float timestamps via .csv) and its clean decode."""
    tmp = tmp_path_factory.mktemp("clean")
    imu, speed = sim_imu(duration_s=3.0, seed=2)
    path = tmp / "clean.csv"
    offset = write_can_log(path, imu, speed, seed=2)
    msgs = list(can.LogReader(path))
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    return imu, offset, msgs, table, summary


def _write(msgs, path):
    with can.Logger(path) as w:
        for m in msgs:
            w.on_message_received(m)
    return path


def _one_line(e):
    text = str(e.value)
    assert "\n" not in text and len(text) < 400
    return text


def test_WRONG_LENGTH_frames_counted_rest_decoded(tmp_path, clean):
    imu, _, msgs, ref, _ = clean
    bad = list(msgs)
    n_cut = 0
    for i, m in enumerate(bad):
        if m.arbitration_id == 0x178 and n_cut < 7 and i % 3 == 0:
            bad[i] = can.Message(timestamp=m.timestamp, arbitration_id=0x178, is_extended_id=False,
                                 data=m.data[:6], channel=m.channel)
            n_cut += 1
    table, summary = read_log(_write(bad, tmp_path / "x.blf"), sim_mapping(), MOUNT_FRD)
    acc = next(s for s in summary.sources if s.name == "IMU_ACC")
    assert acc.wrong_length == n_cut == 7
    assert (~table["fresh_accel_x"]).sum() == 7 and table["accel_x_m_s2"].isna().sum() == 7
    assert table["fresh_gyro_x"].all() and len(table) == len(ref)


@pytest.mark.parametrize("suffix", [".asc", ".log", ".trc", ".csv"])
def test_CORRUPT_LINE_MIDWAY_skipped_and_counted(tmp_path, clean, suffix):
    """One garbled IMU_RATE line in the middle of a text log: that sample is lost, the reader goes on
    after it with the header state intact, and every other sample is decoded as in the clean log.
    candump and CSV lines that python-can cannot parse are counted as bad lines (naming the line),
    as are ASC lines in the form of a frame that its reader passes over (it does so without a
    word for lines it does not recognise; a review); python-can's TRC reader passes over them
    too, with only an INFO log of an "unsupported type" (the garbled type column), which is
    counted the same way (before, the loss showed there only as the orphaned IMU_ACC frame,
    counted as unaligned as it is in the others)."""
    _, _, msgs, _, _ = clean
    path = _write(msgs, tmp_path / f"x{suffix}")
    ref, _ = read_log(path, sim_mapping(), MOUNT_FRD)
    lines = path.read_text().splitlines(keepends=True)
    rate_lines = [i for i, ln in enumerate(lines) if "174" in ln]
    victim = rate_lines[len(rate_lines) // 2]
    lines[victim] = lines[victim].replace(" ", " zz ", 2).replace("#", "#ZZ").replace(",", ",q", 1)
    path.write_text("".join(lines))
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert summary.bad_lines == 1 and f"line {victim + 1}:" in summary.problems[0]
    assert next(s for s in summary.sources if s.name == "IMU_ACC").unaligned == 1
    assert len(table) == len(ref) - 1, "exactly the garbled sample is missing"
    merged = ref.merge(table, on="t_s", suffixes=("", "_got"))
    assert len(merged) == len(table)
    assert np.array_equal(merged["gyro_x_rad_s"], merged["gyro_x_rad_s_got"])
    assert np.array_equal(merged["accel_y_m_s2"], merged["accel_y_m_s2_got"])


def test_TRC_STATUS_AND_ERROR_RECORDS_are_counted(tmp_path, clean):
    """PCAN-View writes bus status (ST), error counter (EC) and error frame (ER) records between
    the frames of a TRC log (format 2.x); python-can's reader passes over any type it does not
    take with an INFO log only, which nothing counted (a review). Three such records mid-file:
    counted as skipped lines, named with their types and the first one's line, and every frame
    is read as in the clean log."""
    _, _, msgs, _, _ = clean
    path = _write(msgs, tmp_path / "x.trc")
    ref, _ = read_log(path, sim_mapping(), MOUNT_FRD)
    lines = path.read_text().splitlines(keepends=True)
    k = [i for i, ln in enumerate(lines) if " DT " in ln][len(msgs) // 2]
    lines[k + 1:k + 1] = ["   9001      1500.100 ST  1  Rx    00 00 00 08\n",
                          "   9002      1500.200 ER  1  Rx    04 00 02 00 00\n",
                          "   9003      1500.300 ST  1  Rx    00 00 00 00\n"]
    path.write_text("".join(lines))
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert summary.bad_lines == 3 and summary.complete
    said = next(p for p in summary.problems if "record type" in p)
    assert said.startswith(f"line {k + 2}:") and "'ST' 2" in said and "'ER' 1" in said, said
    pd.testing.assert_frame_equal(table, ref)


@pytest.mark.parametrize("edit, problem", [
    (lambda ln: ln.replace(".", ",", 1), "decimal comma"),                    # CANoe in a German locale
    (lambda ln: ln.replace(".", ".x", 1), "decimal comma"),                   # a stray character
    (lambda ln: " nan " + ln.split(None, 1)[1], "decimal comma"),             # a time written as nan
    (lambda ln: ln.replace("Rx", "#%", 1), "decimal comma"),                  # overwritten after its ID
    (lambda ln: ln[:-4] + ln[-3:], "not two hex digits"),                     # a lost digit: '7' for '07'
])
def test_ASC_FRAME_LINES_the_reader_passes_over_are_counted(tmp_path, clean, edit, problem):
    """python-can's ASC reader passes over a frame line its pattern does not match without a
    word, and takes a lone hex digit for a whole byte: a review found a log with such lines
    mid-file read as clean, the corrupt line's frame read with its bytes shifted. Each is now a
    counted, named, skipped line, and the rest is read as in the clean log; a log all of whose
    frame lines are so (a decimal comma throughout) is a one-line error naming it, not an empty
    read."""
    _, _, msgs, _, _ = clean
    path = _write(msgs, tmp_path / "x.asc")
    ref, _ = read_log(path, sim_mapping(), MOUNT_FRD)
    lines = path.read_text().splitlines(keepends=True)
    rate = [i for i, ln in enumerate(lines) if " 174 " in ln]
    victim = rate[len(rate) // 2]
    lines[victim] = edit(lines[victim].rstrip("\n")) + "\n"
    path.write_text("".join(lines))
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert summary.bad_lines == 1 and summary.complete
    assert f"line {victim + 1}" in summary.problems[0] and problem in summary.problems[0]
    assert len(table) == len(ref) - 1, "exactly the corrupt line's sample is missing"
    merged = ref.merge(table, on="t_s", suffixes=("", "_got"))
    assert np.array_equal(merged["gyro_z_rad_s"], merged["gyro_z_rad_s_got"])
    # the whole file in a decimal-comma locale
    lines = [edit(ln.rstrip("\n")) + "\n" if (" Rx " in ln and "," not in ln) else ln for ln in lines]
    path.write_text("".join(lines))
    with pytest.raises(DecodeError) as e:
        read_log(path, sim_mapping(), MOUNT_FRD)
    assert problem in _one_line(e)


@pytest.mark.parametrize("start, stop", [(0.6, 0.8), (0.3, 0.32)])
def test_MF4_ZEROED_STRETCH_is_counted_and_said(tmp_path, clean, start, stop):
    """An uncompressed MF4 log with a stretch of its bytes zeroed (a damaged disk or copy):
    asammdf reads the stretch as frames of ID 0 without data, all at one time, without a
    complaint; a review found such a log read as complete with no problem, its loss visible only
    as a gap and an unknown ID 0x0. The zeroed records are skipped, counted and said with where
    they start; the frames around them are decoded as in the clean log."""
    _, _, msgs, _, _ = clean
    path = tmp_path / "x.mf4"
    with can.io.MF4Writer(str(path), compression_level=0) as w:
        for m in msgs:
            w.on_message_received(m)
    ref, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert summary.bad_lines == 0 and not summary.problems
    raw = bytearray(path.read_bytes())
    lo, hi = int(start * len(raw)), int(stop * len(raw))
    raw[lo:hi] = bytes(hi - lo)
    path.write_bytes(bytes(raw))
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    # (a record the stretch's edge cuts through keeps its own time: one such may pass as ID 0)
    assert summary.bad_lines > 10 and summary.unknown_ids.get("0x0", 0) <= 2
    assert "zeroed records" in summary.problems[0] and "damaged" in summary.problems[0]
    assert 0 < len(table) < len(ref)
    merged = ref.merge(table, on="t_s", suffixes=("", "_got"))
    assert len(merged) == len(table)
    assert np.array_equal(merged["gyro_x_rad_s"], merged["gyro_x_rad_s_got"], equal_nan=True)


def test_TRUNCATED_BLF_keeps_what_came_before(tmp_path, clean):
    imu, offset, msgs, _, _ = clean
    path = _write(msgs, tmp_path / "x.blf")
    ref, _ = read_log(path, sim_mapping(), MOUNT_FRD)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * 0.6)])
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert not summary.complete and not table.attrs["complete"]
    assert any("truncated" in p for p in summary.problems)
    assert 0 < len(table) < len(ref)
    n = len(table)
    # all but possibly the last sample (its accel frame may be cut off) equal the full decode
    assert np.array_equal(table["gyro_x_rad_s"].to_numpy()[: n - 1], ref["gyro_x_rad_s"].to_numpy()[: n - 1])
    truth = vehicle_truth(imu, MOUNT_FRD)[:n]
    assert np.abs(table["gyro_x_rad_s"].to_numpy() - truth[:, 0]).max() <= TOL_GYRO_RAD_S


def test_TRUNCATED_ASC_mid_line(tmp_path, clean):
    _, _, msgs, _, _ = clean
    path = _write(msgs, tmp_path / "x.asc")
    text = path.read_text()
    path.write_text(text[: int(len(text) * 0.5) + 7])  # ends inside a frame line
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert 100 < len(table) < 200
    assert table.filter(like="fresh_gyro").iloc[:-1].all().all()


def test_TIME_JUMPS_BACK_once_frame_dropped(tmp_path, clean):
    _, _, msgs, ref, _ = clean
    bad = list(msgs)
    i = next(k for k in range(len(bad) // 2, len(bad)) if bad[k].arbitration_id == 0x174)
    m = bad[i]
    bad[i] = can.Message(timestamp=m.timestamp - 0.5, arbitration_id=m.arbitration_id, is_extended_id=False,
                         data=m.data, channel=m.channel)
    table, summary = read_log(_write(bad, tmp_path / "x.csv"), sim_mapping(), MOUNT_FRD)
    rate = next(s for s in summary.sources if s.name == "IMU_RATE")
    assert rate.backwards == 1
    assert len(table) == len(ref) - 1
    acc = next(s for s in summary.sources if s.name == "IMU_ACC")
    assert acc.unaligned == 1, "its accel frame has no sample to join and is counted"


def test_CLOCK_RESET_stops_with_one_line(tmp_path, clean):
    _, _, msgs, _, _ = clean
    half = len(msgs) // 2
    bad = msgs[:half] + [can.Message(timestamp=m.timestamp - 100.0, arbitration_id=m.arbitration_id,
                                     is_extended_id=m.is_extended_id, data=m.data, channel=m.channel)
                         for m in msgs[half:]]
    path = _write(bad, tmp_path / "x.csv")
    with pytest.raises(DecodeError) as e:
        read_log(path, sim_mapping(), MOUNT_FRD)
    text = _one_line(e)
    assert str(path) in text and "backwards" in text and "frame 0x" in text


def test_DUPLICATE_FRAMES_counted_not_doubled(tmp_path, clean):
    _, _, msgs, ref, _ = clean
    bad = []
    dup = 0
    for m in msgs:
        bad.append(m)
        if m.arbitration_id in (0x174, 0x178) and dup < 20:
            bad.append(m)
            dup += 1
    table, summary = read_log(_write(bad, tmp_path / "x.blf"), sim_mapping(), MOUNT_FRD)
    assert sum(s.duplicates for s in summary.sources) == 20
    assert len(table) == len(ref)
    assert np.array_equal(table["accel_z_m_s2"], ref["accel_z_m_s2"])


def test_ECHOED_FRAMES_counted_not_taken_for_samples(tmp_path, clean):
    """Every IMU and wheel-speed frame echoed 0.1 ms later (a second interface on the bus, a
    gateway forwarding twice): the same samples as the clean log, live and from the log, the
    copies counted. Live, each echoed rate frame had opened a sample no acceleration joined and
    the wheel speed went to it: no speed and no bank for the whole drive, no warning; the log
    path refused the log, calling the copies a 0.1 ms message period (a review found both)."""
    from imu import StreamDecoder, samples_frame

    _, _, msgs, ref, _ = clean
    bad = []
    for m in msgs:
        bad.append(m)
        if m.arbitration_id in (0x174, 0x178, 0x122):
            bad.append(can.Message(timestamp=m.timestamp + 1e-4, arbitration_id=m.arbitration_id,
                                   is_extended_id=m.is_extended_id, data=m.data, channel=m.channel))
    path = _write(bad, tmp_path / "x.csv")    # .csv keeps the float timestamps exactly
    n_echo = len(bad) - len(msgs)
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    dec = StreamDecoder(sim_mapping(), MOUNT_FRD)
    live = [s for m in can.LogReader(path) for s in dec.push(m)] + dec.flush()
    for got, counts in ((table, summary), (samples_frame(live), dec.summary())):
        assert len(got) == len(ref) and sum(s.duplicates for s in counts.sources) == n_echo
        for c in ("t_s", "gyro_z_rad_s", "accel_y_m_s2", "speed_m_s"):
            assert np.array_equal(got[c].to_numpy(), ref[c].to_numpy(), equal_nan=True), c
        assert got["fresh_speed"].sum() == ref["fresh_speed"].sum() > 0


def test_LATE_SPEED_said_in_the_summary(tmp_path, clean):
    """The wheel speed's frames missing for the first 1.5 s and the last 0.5 s of a 3 s log:
    not a gap between two frames, which the gap finder sees ('gaps: none' was all it said, a
    review); the summary says the source starts 1.5 s after the clock message, live and from
    the log (its first and last frames' times are in both), and not the 0.5 s at the end
    (under 1 s)."""
    from imu import StreamDecoder

    _, _, msgs, _, _ = clean
    t0, t1 = msgs[0].timestamp, msgs[-1].timestamp
    bad = [m for m in msgs if not (m.arbitration_id == 0x122 and not t0 + 1.5 <= m.timestamp <= t1 - 0.5)]
    path = _write(bad, tmp_path / "x.csv")
    _, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    dec = StreamDecoder(sim_mapping(), MOUNT_FRD)
    for m in can.LogReader(path):
        dec.push(m)
    dec.flush()
    for got in (summary, dec.summary()):
        said = [line for line in got.lines() if "starts" in line or "stops" in line]
        assert len(said) == 1 and said[0].startswith("source ") and "starts 1.5 s after" in said[0], said
    assert [(s.first_s, s.last_s) for s in summary.sources] == [(s.first_s, s.last_s) for s in dec.summary().sources]
    _, plain = read_log(_write(msgs, tmp_path / "y.csv"), sim_mapping(), MOUNT_FRD)
    assert plain.span_lines() == []


def test_GAP_reported_not_interpolated(tmp_path, clean):
    imu, offset, msgs, ref, _ = clean
    t0 = msgs[0].timestamp
    lo, hi = offset + 1.0, offset + 1.5
    bad = [m for m in msgs if not (lo <= m.timestamp < hi)]
    table, summary = read_log(_write(bad, tmp_path / "x.blf"), sim_mapping(), MOUNT_FRD)
    T = table["t_s"].to_numpy()
    assert not ((T > lo) & (T < hi)).any(), "no samples invented inside the gap"
    gaps = {g.source: g for g in summary.gaps}
    assert set(gaps) == {"IMU_RATE", "IMU_ACC", "ABS_SPEED"}
    assert gaps["IMU_RATE"].duration_s == pytest.approx(0.51, abs=0.011)  # 0.5 s removed + one 10-ms period
    assert table.attrs["gaps"] and t0 > 0
    # the first sample after the gap has no speed younger than gap_limit_s unless an ABS frame came first
    after = np.flatnonzero(T >= hi)[0]
    assert np.isnan(table["speed_m_s"].iloc[after]) or table["fresh_speed"].iloc[after]


def test_OUT_OF_RANGE_and_SNA_values_are_invalid(tmp_path, clean):
    _, _, msgs, ref, _ = clean
    bad = list(msgs)
    hits = 0
    for i, m in enumerate(bad):
        if m.arbitration_id == 0x174 and i % 5 == 0:
            d = bytearray(m.data)
            d[0:2] = b"\xff\xff"  # RateX raw 0xFFFF: 163.835 deg/s, outside [-163.84|163.83], the SNA value
            bad[i] = can.Message(timestamp=m.timestamp, arbitration_id=0x174, is_extended_id=False, data=d)
            hits += 1
    table, summary = read_log(_write(bad, tmp_path / "x.blf"), sim_mapping(), MOUNT_FRD)
    gx = next(c for c in summary.channels if c.channel == "gyro_x")
    assert gx.out_of_range == hits and gx.invalid == hits
    assert table["gyro_x_rad_s"].isna().sum() == hits == (~table["fresh_gyro_x"]).sum()
    assert table["gyro_z_rad_s"].notna().all(), "the frame's other rates are fine"
    # without the range check (opendbc's DBCs give raw ranges) the value is still no measurement:
    # the DBC's value table names 0xFFFF "SNA" (it passed as 163.8 deg/s before)
    kept, s2 = read_log(tmp_path / "x.blf", sim_mapping(range_check=False), MOUNT_FRD)
    assert kept["gyro_x_rad_s"].isna().sum() == hits and s2.channels[0].out_of_range == hits
    assert s2.channels[0].invalid == hits


@pytest.mark.parametrize("name, invalid", [
    ("SNA", True), ("Signal not available", True), ("unavailable", True), ("FAULT_TIMEOUT", True),
    ("Init", True), ("invalid", True), ("N/A", True), ("Error", True),
    # names that say the opposite (comma2k19's Toyota DBC has "NO_FAULT"; it matched 'fault')
    ("NO_FAULT", False), ("No error", False), ("Initialized", False), ("ok", False),
    ("valid", False), ("Snap", False), ("Nasa", False), ("NO_ERROR_DETECTED", False), ("NO_FAULT_PRESENT", False),
    # negations of those (a review found 'Not initialized' called valid)
    ("Not initialized", True), ("NOT_INITIALIZED", True), ("Sensor not initialised", True),
    ("Error - not OK", True), ("Signal not OK / error", True), ("not valid", True),
])
def test_VALUE_TABLE_NAMES_invalid_or_not(name, invalid):
    from imu.dbc import invalid_choice

    assert invalid_choice(name) is invalid


def test_REMOTE_ERROR_and_EXTENDED_twins_are_skipped(tmp_path, clean):
    _, _, msgs, ref, _ = clean
    t = msgs[10].timestamp
    extra = [can.Message(timestamp=t, arbitration_id=0x174, is_extended_id=False, is_remote_frame=True, dlc=8),
             can.Message(timestamp=t, is_error_frame=True),
             # an error frame whose class bits equal a DBC message's ID (ENGINE_2, unmapped):
             # an error frame, not unmapped traffic, in the log and live alike
             can.Message(timestamp=t, arbitration_id=0x500, is_error_frame=True),
             can.Message(timestamp=t, arbitration_id=0x174, is_extended_id=True, data=bytes(8))]
    bad = msgs[:11] + extra + msgs[11:]
    table, summary = read_log(_write(bad, tmp_path / "x.blf"), sim_mapping(), MOUNT_FRD)
    assert summary.sources[0].remote == 1 and summary.error_frames == 2
    n_unmapped = read_log(_write(msgs, tmp_path / "clean.blf"), sim_mapping(), MOUNT_FRD)[1].unmapped_frames
    assert summary.unmapped_frames == n_unmapped
    from imu import StreamDecoder

    live = StreamDecoder(sim_mapping(), MOUNT_FRD)
    for m in bad:
        live.push(m)
    live.flush()
    assert (live.error_frames, live.unmapped_frames) == (2, n_unmapped)
    assert summary.unknown_ids.get("0x174x") == 1
    assert len(table) == len(ref)


@pytest.mark.parametrize("signals, pattern", [
    ({"gyro_z": "IMU_RATES.RateZ"}, r'no message "IMU_RATES" in the DBC \(did you mean IMU_RATE'),
    ({"gyro_z": "IMU_RATE.RateQ"}, r'message IMU_RATE has no signal "RateQ"'),
    ({"gyro_z": "IMU_RATE.RateZ", "speed": "IMU_RATE.RateX"}, r'unit "deg/s" is an angular rate, but speed needs a speed'),
])
def test_MAPPING_MISMATCH_names_the_signal(tmp_path, clean, signals, pattern):
    _, _, msgs, _, _ = clean
    path = _write(msgs[:50], tmp_path / "x.log")
    mapping = dataclasses.replace(sim_mapping(), signals=signals)
    with pytest.raises(ImuConfigError, match=pattern) as e:
        read_log(path, mapping, MOUNT_FRD)
    _one_line(e)


def test_a_signal_mapped_with_a_minus_is_decoded_negated(tmp_path, clean):
    """``"-MESSAGE.SIGNAL"``: a signal that counts the other way than its IMU axis (the RAV4's
    right-positive lateral acceleration) comes out negated, bit for bit, and named so in the
    table's attrs; its range check is the DBC's, on the value before the sign. A stray sign or a
    signal mapped twice, with and without it, is a config error."""
    _, _, msgs, ref, _ = clean
    path = _write(msgs, tmp_path / "x.blf")
    signals = dict(sim_mapping().signals)
    flipped = dict(signals, accel_y="-" + signals["accel_y"], gyro_z="-" + signals["gyro_z"])
    table, _ = read_log(path, dataclasses.replace(sim_mapping(), signals=flipped), MOUNT_FRD)
    for c in table.columns:
        want = -ref[c] if c in ("accel_y_m_s2", "gyro_z_rad_s") else ref[c]
        assert np.array_equal(table[c].to_numpy(), want.to_numpy(), equal_nan=True), c
    # MOUNT_FRD flips y and z already: the two signs cancel in the name
    assert table.attrs["channels"]["accel_y_m_s2"].split(" ")[0] == signals["accel_y"]
    for bad in ("--IMU_RATE.RateZ", "-.RateZ", "-IMU_RATE.", "-"):
        with pytest.raises(ImuConfigError, match=r'must be "MESSAGE.SIGNAL" \(or "-MESSAGE.SIGNAL"'):
            dataclasses.replace(sim_mapping(), signals=dict(signals, gyro_z=bad))
    with pytest.raises(ImuConfigError, match="a speed has no axis"):
        dataclasses.replace(sim_mapping(), signals=dict(signals, speed="-" + signals["speed"]))
    twice = dataclasses.replace(sim_mapping(), signals=dict(signals, gyro_y="-" + signals["gyro_z"]))
    with pytest.raises(ImuConfigError, match="both map IMU_RATE.RateZ"):
        read_log(path, twice, MOUNT_FRD)


def test_UNKNOWN_UNIT_override():
    """An unknown unit in [can.units] is refused where the mapping is made (the config: its
    error then names the file), not when the log is decoded."""
    m = sim_mapping()
    with pytest.raises(ImuConfigError, match=r'\[can.units\] gyro_x: unknown unit "furlong/fortnight"') as e:
        CanMapping(m.dbc_path, m.signals, units={"gyro_x": "furlong/fortnight"})
    assert "to override" not in str(e.value)    # it is the override (a review: told to set the key that is wrong)
    with pytest.raises(ImuConfigError, match=r'\[can.units\] gyro_x: unit "m/s" is a speed, but gyro_x needs'):
        CanMapping(m.dbc_path, m.signals, units={"gyro_x": "m/s"})


@pytest.mark.parametrize("name, content, pattern", [
    ("garbage.blf", bytes(range(256)) * 40, r"not a readable BLF log"),
    ("garbage.mf4", b"MDF     4.10    " + bytes(3000), r"not a readable MF4 log"),
    ("empty.log", b"", r"the file is empty \(0 bytes\)"),
    ("text.asc", b"hello\nworld\n" * 100, r"no CAN frames in the log"),
    ("noise.log", b"(1.0) can0 zzz#\n" * 200, r"not a readable \.log log"),
    ("x.xyz", b"1", r"unknown log format '\.xyz'"),
])
def test_UNREADABLE_FILES_one_line(tmp_path, name, content, pattern):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(DecodeError, match=pattern) as e:
        read_log(path, sim_mapping(), MOUNT_FRD)
    assert name in _one_line(e)


def test_a_corrupt_mf4_is_said_without_a_traceback(tmp_path, clean):
    """An MF4 log with 50 bytes of its compressed data zeroed: asammdf logs a message with
    a whole Python traceback inside, which reached the one-line error (a review: 359
    characters of it). Now the cause alone: what precedes the traceback and its last line."""
    _, _, msgs, _, _ = clean
    path = _write(msgs, tmp_path / "x.mf4")
    data = bytearray(path.read_bytes())
    k = int(0.3 * len(data))              # inside the compressed frames: 'Invalid deflate block'
    data[k:k + 50] = bytes(50)
    path.write_bytes(bytes(data))
    try:
        _, summary = read_log(path, sim_mapping(), MOUNT_FRD)
        said = " ".join(summary.problems)
    except DecodeError as e:
        said = str(e)
    assert said and "Traceback" not in said and 'File "' not in said, said


def test_MISSING_FILES_one_line(tmp_path):
    with pytest.raises(DecodeError, match="no such log file"):
        read_log(tmp_path / "nope.blf", sim_mapping(), MOUNT_FRD)
    m = dataclasses.replace(sim_mapping(), dbc_path=tmp_path / "nope.dbc")
    (tmp_path / "x.log").write_text("(1.0) can0 174#0000000000000000\n")
    with pytest.raises(DecodeError, match="nope.dbc: no such DBC file"):
        read_log(tmp_path / "x.log", m, MOUNT_FRD)


def test_NO_CLOCK_FRAMES_names_the_message(tmp_path, clean):
    _, _, msgs, _, _ = clean
    path = _write([m for m in msgs if m.arbitration_id != 0x174], tmp_path / "x.blf")
    with pytest.raises(DecodeError, match=r"no usable frame of IMU_RATE \(0x174\), the IMU clock message") as e:
        read_log(path, sim_mapping(), MOUNT_FRD)
    _one_line(e)


def test_ALIGN_WINDOW_TOO_LONG(tmp_path, clean):
    _, _, msgs, _, _ = clean
    path = _write(msgs, tmp_path / "x.blf")
    with pytest.raises(ImuConfigError, match=r"align_window_s = 0.006 s is not less than half the IMU_RATE period"):
        read_log(path, sim_mapping(align_window_s=0.006), MOUNT_FRD)


def test_TRUNCATED_ASC_is_marked_incomplete(tmp_path, clean):
    """A text log cut in the middle parses to the end of what is left; python-can's writer (and
    CANoe) close the trigger block, so a block left open says the file broke off (a review found
    a half ASC log read as complete: a run covered 6 of its 12 s without a warning)."""
    imu, offset, msgs, _, _ = clean
    path = _write(msgs, tmp_path / "x.asc")
    ref, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert summary.complete and path.read_text().rstrip().endswith("End TriggerBlock")
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[: len(lines) // 2]))
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert not summary.complete and not table.attrs["complete"]
    assert any("End TriggerBlock" in p and "truncated" in p for p in summary.problems)
    assert 0 < len(table) < len(ref)


def test_ONE_FAR_FUTURE_STAMP_is_a_bad_timestamp(tmp_path, clean):
    """One rate frame stamped 1e6 s ahead (a clock glitch) between good neighbours: counted as a
    bad timestamp and dropped, the rest decoded (it made every later frame 'backwards' and the
    log was refused, naming a good frame)."""
    _, _, msgs, ref, _ = clean
    bad = list(msgs)
    i = next(k for k in range(len(bad) // 2, len(bad)) if bad[k].arbitration_id == 0x174)
    m = bad[i]
    bad[i] = can.Message(timestamp=m.timestamp + 1e6, arbitration_id=m.arbitration_id, is_extended_id=False,
                         data=m.data, channel=m.channel)
    table, summary = read_log(_write(bad, tmp_path / "x.csv"), sim_mapping(), MOUNT_FRD)
    rate = next(s for s in summary.sources if s.name == "IMU_RATE")
    assert rate.bad_timestamp == 1 and rate.backwards == 0
    assert len(table) == len(ref) - 1


def test_AN_ID_NO_INTEGER_TYPE_HOLDS_is_an_unknown_id(tmp_path, clean):
    """A text log line with a 20-digit hex ID (garbage a reader still parses): counted among
    the unknown IDs (it was an OverflowError traceback)."""
    _, _, msgs, ref, _ = clean
    path = _write(msgs, tmp_path / "x.csv")
    lines = path.read_text().splitlines()
    fields = lines[-1].split(",")
    fields[1] = "0x" + "F" * 20
    path.write_text("\n".join(lines + [",".join(fields)]) + "\n")
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert summary.unknown_ids.get("0x" + "F" * 20) == 1 and len(table) == len(ref)


def test_DBC_STALE_VALUE_TABLES_are_dropped(tmp_path, clean):
    """A value table (``VAL_``) of a signal no message has: cantools refuses the whole DBC even
    with strict=False, and with the mapped signal renamed that refusal hid the real problem (a
    review). Such tables are dropped: the log decodes as with the clean DBC, and a renamed
    mapped signal is said by name."""
    from test_imu_common import DBC_PATH

    _, _, msgs, ref, _ = clean
    log = _write(msgs, tmp_path / "x.csv")
    text = DBC_PATH.read_text()
    stale = tmp_path / "stale.dbc"
    stale.write_text(text + 'VAL_ 372 NoSuchSignal 1 "on" 0 "off" ;\n')
    table, _ = read_log(log, dataclasses.replace(sim_mapping(), dbc_path=stale), MOUNT_FRD)
    pd.testing.assert_frame_equal(table, ref)
    renamed = tmp_path / "renamed.dbc"
    assert " SG_ RateX " in text
    renamed.write_text(text.replace(" SG_ RateX ", " SG_ RateXX "))       # its VAL_ table now stale
    with pytest.raises(ImuConfigError, match='no signal "RateX"'):
        read_log(log, dataclasses.replace(sim_mapping(), dbc_path=renamed), MOUNT_FRD)


@pytest.mark.parametrize("edit, pattern", [
    (("BO_ 376 IMU_ACC", "BO_ 372 IMU_ACC"), "IMU_RATE and IMU_ACC both have ID 0x174"),
    (("(0.005,-163.84)", "(0,-163.84)"), "scale 0, offset -163.84"),
    # RateY moved onto RateX's high byte: both were decoded from the shared bits (a review)
    ((" SG_ RateY : 16|16@1+", " SG_ RateY : 8|16@1+"),
     "message IMU_RATE: IMU_RATE.RateX and IMU_RATE.RateY share 8 bit(s) (byte 1)"),
    # a Motorola RateZ whose start bit (its most significant, 23: byte 2's bit 7) lays it on RateY
    ((" SG_ RateZ : 32|16@1+", " SG_ RateZ : 23|16@0+"), "RateY and IMU_RATE.RateZ share 16 bit(s) (byte 2)"),
])
def test_DBC_TWO_MESSAGES_ONE_ID_or_A_ZERO_SCALE(tmp_path, clean, edit, pattern):
    """Two mapped messages with one frame ID would decode one's bytes as the other's signals;
    a scale of 0 makes every frame the offset: both were decoded as valid (bank 80 deg off in a
    run). Now one line naming them."""
    from test_imu_common import DBC_PATH

    text = DBC_PATH.read_text()
    assert text.count(edit[0]) >= 1
    dbc = tmp_path / "edited.dbc"
    # (the value tables of the renumbered message are dropped: cantools refuses them orphaned)
    lines = [line for line in text.replace(edit[0], edit[1], 1).splitlines()
             if not (edit[0].startswith("BO_ 376") and line.startswith("VAL_ 376"))]
    dbc.write_text("\n".join(lines) + "\n")
    _, _, msgs, _, _ = clean
    with pytest.raises(ImuConfigError) as e:
        read_log(_write(msgs, tmp_path / "x.csv"), dataclasses.replace(sim_mapping(), dbc_path=dbc), MOUNT_FRD)
    assert pattern in _one_line(e)


def test_API_CONSTRUCTORS_check_values_and_word_them_plainly():
    """ImuMount and CanMapping built from code (not a TOML file): a NaN position, an infinite gap
    limit and a string for a flag are errors; numpy values are shown as numbers, not reprs; a
    numpy integer channel is an integer."""
    from imu import ImuMount

    for make, pattern in ((lambda: ImuMount(("x", "y", "z"), np.zeros(2)), r"got \[0\.0, 0\.0\]"),
                          (lambda: ImuMount(np.array(["x", "y"])), r"got \['x', 'y'\]"),
                          (lambda: ImuMount(position_m=[math.nan, 0.0, 0.0]), "finite"),
                          (lambda: sim_mapping(gap_limit_s=math.inf), "gap_limit_s"),
                          (lambda: sim_mapping(pad_short_frames="false"), "pad_short_frames must be true or false")):
        with pytest.raises(ImuConfigError, match=pattern) as e:
            make()
        assert "np." not in str(e.value)
    assert sim_mapping(channel=np.int64(0)).channel == 0


@pytest.mark.parametrize("suffix", [".asc", ".csv", ".trc", ".log"])
def test_LAST_LINE_WITHOUT_LINE_END_whole_is_read_cut_is_marked(tmp_path, clean, suffix):
    """A writer that leaves out the final line end wrote a complete log: read in full (it was
    called truncated, and an ASC lost its 'End TriggerBlock'). A last line cut inside its data
    bytes is a writer cut off: that frame is not decoded and the log is marked incomplete."""
    _, _, msgs, _, _ = clean
    path = _write(msgs, tmp_path / f"x{suffix}")
    ref, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert summary.complete
    text = path.read_text()
    path.write_text(text.rstrip("\n"))
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert summary.complete, summary.problems
    assert len(table) == len(ref)
    # cut the last frame line inside its last data byte (for ASC the line before the closing
    # 'End TriggerBlock', dropped with it; a candump line also loses its direction flag)
    lines = text.rstrip("\n").split("\n")
    k = max(i for i, line in enumerate(lines) if line.strip() and not line.lower().startswith("end "))
    data_line = lines[k].rstrip()
    if suffix == ".log":
        data_line = data_line.rsplit(" ", 1)[0]
    if suffix != ".csv":
        path.write_text("\n".join(lines[:k] + [data_line[:-1]]))
    else:  # base64 data: cut inside it
        path.write_text("\n".join(lines[:k] + [data_line[:-3]]))
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert not summary.complete
    assert any("no line end" in p and "truncated" in p for p in summary.problems), summary.problems
    assert len(ref) - 1 <= len(table) <= len(ref)


@pytest.mark.parametrize("suffix", [".asc", ".csv", ".trc", ".log"])
def test_LAST_LINE_cut_before_its_data_is_marked(tmp_path, clean, suffix):
    """A writer cut off before the last line's data bytes: python-can's TRC reader logs
    "Failed to parse message" and skips the line instead of raising, and the log was read as
    complete (a review: half a TRC log taken for a whole one). Every text format: incomplete."""
    _, _, msgs, _, _ = clean
    path = _write(msgs, tmp_path / f"x{suffix}")
    ref, _ = read_log(path, sim_mapping(), MOUNT_FRD)
    lines = path.read_text().rstrip("\n").split("\n")
    k = max(i for i, line in enumerate(lines) if line.strip() and not line.lower().startswith("end "))
    cut = lines[k][:len(lines[k]) // 2].rstrip()          # half the line: its data are gone
    path.write_text("\n".join(lines[:k] + [cut]))
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert not summary.complete, (cut, summary.problems)
    assert len(ref) - 1 <= len(table) <= len(ref)


@pytest.mark.parametrize("last_data", [bytes(range(1, 13)), bytes([1, 2, 3, 0x88])], ids=["fd", "classic"])
def test_ASC_LAST_LINE_a_lone_digit_after_the_data_is_a_field_not_a_cut(tmp_path, last_data):
    """An ASC log without trigger block (CANoe exports) whose last frame line has no line end: a
    CAN FD line goes on after its data (duration, flags, CRC, bit timings: python-can writes '0'
    last), and CANoe's classic lines with 'ID = 5'. That lone digit is a whole field: the log is
    complete and every frame read (it was called cut off). Cut inside the data, it still is."""
    from imu.log_source import ReadState, iter_messages

    path = tmp_path / "x.asc"
    with can.ASCWriter(str(path)) as w:
        for k in range(3):
            w.on_message_received(can.Message(timestamp=1.0 + k, arbitration_id=0x5, data=last_data,
                                              is_fd=len(last_data) > 8, is_extended_id=False))
    lines = [ln for ln in path.read_text().splitlines() if "triggerblock" not in ln.lower()]
    if len(last_data) <= 8:   # CANoe's classic line: fields after the data, the last a lone digit
        lines[-1] += "  Length = 0 BitCount = 0 ID = 5"
    assert lines[-1].split()[-1] in ("0", "5")
    path.write_text("\n".join(lines))
    state = ReadState(path, ".asc")
    msgs = list(iter_messages(path, state))
    assert state.complete, state.problems
    assert [bytes(m.data) for m in msgs] == [last_data] * 3
    cut = lines[-1][:lines[-1].index(last_data[-1:].hex().upper()) + 1]   # half of the last data byte
    path.write_text("\n".join(lines[:-1] + [cut]))
    state = ReadState(path, ".asc")
    msgs = list(iter_messages(path, state))
    assert not state.complete and "no line end" in state.stop_reason
    assert [bytes(m.data) for m in msgs] == [last_data] * 2


def test_STOP_REASON_is_the_cause_not_the_first_problem(tmp_path, clean):
    """Unreadable lines early in a log and a cut at its end: the summary's stop reason (what
    `vifusion can` and the run report name) is the cut, not the first problem listed (it named
    an unreadable line as the reason the log was incomplete)."""
    _, _, msgs, ref, _ = clean
    path = _write(msgs, tmp_path / "x.csv")
    lines = path.read_text().split("\n")
    lines[5:5] = ["garbage,line"] * 3
    path.write_text("\n".join(lines).rstrip("\n")[:-3])
    table, summary = read_log(path, sim_mapping(), MOUNT_FRD)
    assert not summary.complete and summary.bad_lines == 3
    assert "unreadable" in summary.problems[0]
    assert "no line end" in summary.stop_reason and summary.stop_reason in summary.problems


def test_OUT_OF_RANGE_values_are_said_per_channel_with_the_key(tmp_path, clean):
    """Values outside the DBC range that range_check drops are named per channel, with their
    count, the range and the key that keeps them (the run and ``vifusion can`` print these lines;
    a review found the range never mentioned); with range_check off nothing was dropped, nothing
    said."""
    _, _, msgs, _, _ = clean
    bad, hits = list(msgs), 0
    for i, m in enumerate(bad):
        if m.arbitration_id == 0x174 and i % 7 == 0:
            d = bytearray(m.data)
            d[0:2] = b"\xff\xff"  # RateX raw 0xFFFF: 163.835 deg/s, outside [-163.84|163.83]
            bad[i] = can.Message(timestamp=m.timestamp, arbitration_id=0x174, is_extended_id=False, data=d)
            hits += 1
    _, summary = read_log(_write(bad, tmp_path / "x.blf"), sim_mapping(), MOUNT_FRD)
    lines = summary.range_lines()
    assert len(lines) == 1 and lines[0].startswith("gyro_x_rad_s (IMU_RATE.RateX): ")
    gx = summary.channels[0]
    assert gx.out_of_range == hits and f"{hits} of {gx.decoded + gx.invalid} values outside" in lines[0]
    assert "[-163.84|163.83] deg/s" in lines[0] and "[can] range_check = false keeps them" in lines[0]
    assert lines[0] in summary.lines()
    _, s2 = read_log(tmp_path / "x.blf", sim_mapping(range_check=False), MOUNT_FRD)
    assert s2.range_lines() == []


@pytest.mark.parametrize("encoding", ["utf-8", "utf-8-sig", "cp1252"])
def test_DBC_ENCODING_a_degree_sign_in_utf8_or_cp1252(tmp_path, clean, encoding):
    """The gyro unit written "°/s" and a comment with an umlaut, the file saved as UTF-8 (with or
    without a BOM) or as cp1252 (Vector's tools): each decodes as the "deg/s" original. cantools
    reads a DBC as cp1252, and the UTF-8 file's unit came out "Â°/s", an unknown unit, exit 2
    (a review)."""
    from drivesim.canlog import DBC_PATH, signal_map

    _, _, msgs, ref, _ = clean
    text = DBC_PATH.read_text().replace('"deg/s"', '"°/s"')
    text = text.replace("CM_ ", 'CM_ "Drehraten über CAN, in °/s";\nCM_ ', 1)
    dbc = tmp_path / "imu.dbc"
    dbc.write_bytes(text.encode(encoding))
    table, summary = read_log(_write(msgs, tmp_path / "x.blf"), CanMapping(dbc, signal_map(True)), MOUNT_FRD)
    assert {c.unit for c in summary.channels if c.channel.startswith("gyro")} == {"°/s"}
    for col in ("gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"):
        np.testing.assert_array_equal(table[col].to_numpy(), ref[col].to_numpy())


def _on_channel(m: can.Message, channel, dt_s: float = 0.0) -> can.Message:
    return can.Message(timestamp=m.timestamp + dt_s, arbitration_id=m.arbitration_id,
                       is_extended_id=m.is_extended_id, data=m.data, channel=channel)


@pytest.mark.parametrize("stray_id, source", [(0x174, "IMU_RATE"), (0x122, "ABS_SPEED")])
def test_STRAY_FRAME_ON_A_SECOND_CHANNEL_does_not_take_its_ID_for_good(clean, stray_id, source):
    """No ``[can] channel``; the bus on socketcan's "can0", and one copy of the first rate (or
    wheel-speed) frame 1 ms before it on "can1" (a gateway's echo, a second interface): the ID
    was taken from "can1" for the whole stream, every later frame of it counted ``other_channel``:
    one incomplete sample after another, or no wheel speed, with no word (a review). Now, once
    "can0" has carried the ID for more than ``gap_limit_s`` with none on "can1", the ID is taken
    from "can0": counted once, said in one line, and every sample from there on is the clean
    log's."""
    from imu import StreamDecoder, samples_frame

    _, _, msgs, ref, _ = clean
    bus = [_on_channel(m, "can0") for m in msgs]
    first = next(m for m in bus if m.arbitration_id == stray_id)
    dec = StreamDecoder(sim_mapping(), MOUNT_FRD)
    live = samples_frame([s for m in [_on_channel(first, "can1", -1e-3), *bus] for s in dec.push(m)] + dec.flush())
    # from 0.2 s on (the move, after gap_limit_s = 0.1 s, and the glitch gate's wait for the
    # ID's next frame), the clean log's samples
    t_from = ref["t_s"].iloc[0] + 0.2
    got, want = live[live["t_s"] >= t_from], ref[ref["t_s"] >= t_from]
    assert len(got) == len(want) > 250
    for c in ("t_s", "gyro_z_rad_s", "accel_y_m_s2", "speed_m_s", "fresh_speed"):
        assert np.array_equal(got[c].to_numpy(), want[c].to_numpy(), equal_nan=True), c
    said = [w for w in dec.warnings if source in w]
    assert len(said) == 1 and "taken from bus channel 'can0'" in said[0] and "'can1'" in said[0], dec.warnings
    src = next(s for s in dec.summary().sources if s.name == source)
    assert src.channel_relocked == 1
    # the frames of the ID on "can0" until the move: gap_limit_s of them at its rate, 3 at least
    rate_hz = {"IMU_RATE": 100.0, "ABS_SPEED": 50.0}[source]
    assert 3 <= src.other_channel <= math.ceil(sim_mapping().gap_limit_s * rate_hz) + 2, src.other_channel


def test_TWO_CHANNELS_CARRYING_ONE_ID_keep_the_first_and_say_so(clean):
    """Every rate frame on "can0" and, 0.2 ms later, on "can1" too (a gateway bridging two buses):
    the lock holds ("can0" never falls silent), the samples are the clean log's, and one line
    says that the ID comes on two channels, which one is used and that ``[can] channel`` picks
    one (only the summary's ``other_channel`` count said it)."""
    from imu import StreamDecoder, samples_frame

    _, _, msgs, ref, _ = clean
    bus = []
    for m in msgs:
        bus.append(_on_channel(m, "can0"))
        if m.arbitration_id == 0x174:
            bus.append(_on_channel(m, "can1", 2e-4))
    dec = StreamDecoder(sim_mapping(), MOUNT_FRD)
    live = samples_frame([s for m in bus for s in dec.push(m)] + dec.flush())
    assert len(live) == len(ref)
    for c in ("t_s", "gyro_z_rad_s", "speed_m_s"):
        assert np.array_equal(live[c].to_numpy(), ref[c].to_numpy(), equal_nan=True), c
    said = [w for w in dec.warnings if "more than one bus channel" in w]
    assert len(said) == 1 and "'can0', which is used" in said[0] and "[can] channel" in said[0], dec.warnings
    rate = next(s for s in dec.summary().sources if s.name == "IMU_RATE")
    assert rate.channel_relocked == 0 and rate.other_channel == 300


def test_MANY_UNKNOWN_IDS_are_counted_in_bounded_memory(clean):
    """200,000 frames of random extended IDs the DBC does not have (a J1939 network of many
    source addresses, a noisy bus) among the drive's frames: ``unknown_ids`` kept one entry per
    distinct ID (500,000 frames: 46 MB, a review). Now it keeps the first ``MAX_UNKNOWN_IDS``
    and counts the frames of the rest in one number, which the summary prints; every frame is
    counted once, and the samples are the clean log's. A normal bus's summary is unchanged."""
    import random
    import tracemalloc

    from imu import StreamDecoder, samples_frame
    from imu.can_source import MAX_UNKNOWN_IDS

    _, _, msgs, ref, _ = clean
    rnd = random.Random(0)
    dec = StreamDecoder(sim_mapping(), MOUNT_FRD)
    tracemalloc.start()
    out = []
    for i, m in enumerate(msgs):
        out += dec.push(m)
        for _ in range(200_000 // len(msgs) + 1):
            dec.push(can.Message(timestamp=m.timestamp, arbitration_id=rnd.getrandbits(29),
                                 is_extended_id=True, data=bytes(8)))
    out += dec.flush()
    grown = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    summary = dec.summary()
    assert len(summary.unknown_ids) == MAX_UNKNOWN_IDS
    n_random = len(msgs) * (200_000 // len(msgs) + 1)
    plain = StreamDecoder(sim_mapping(), MOUNT_FRD)
    for m in msgs:
        plain.push(m)
    plain.flush()
    normal = plain.summary()
    assert sum(summary.unknown_ids.values()) + summary.unknown_more_frames \
        == sum(normal.unknown_ids.values()) + n_random
    # the first thousand IDs' entries and the decoder's own state: 0.1-0.2 MB here; one entry
    # per ID had grown by 19 MB (a tenth of that would still be caught)
    assert grown < 2_000_000, grown
    said = next(line for line in summary.lines() if line.startswith("unknown IDs"))
    assert f"and {summary.unknown_more_frames} frames of further IDs" in said, said
    assert normal.unknown_more_frames == 0 and "further IDs" not in "\n".join(normal.lines())
    got = samples_frame(out)
    assert len(got) == len(ref) and np.array_equal(got["gyro_z_rad_s"].to_numpy(), ref["gyro_z_rad_s"].to_numpy())
