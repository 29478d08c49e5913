"""Fuzz: thousands of corrupted logs (mutated real files of every format, and hypothesis-made candump
text). Every input either decodes into a table that keeps the table's promises, or stops with a
one-line ImuError naming the file. No other exception, ever."""

from __future__ import annotations

import math

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivesim.canlog import DBC_PATH, write_can_log
from imu import COLUMNS, ImuError, load_dbc, read_log
from test_imu_common import COMMA, MOUNT_FRD, comma_mapping, sim_imu, sim_mapping

SIM_DB = load_dbc(DBC_PATH)
#: Physical limits of the simulator's DBC in SI (the DBC ranges): no decoded value may leave them.
GYRO_MAX_RAD_S = math.radians(163.84)
ACCEL_MAX_M_S2 = 4.1768 * 9.80665
SPEED_MAX_M_S = 655.34 / 3.6


def check(path, mapping, db, mount=MOUNT_FRD):
    """Run read_log; return "ok" or "error" and assert the promises either way."""
    try:
        table, summary = read_log(path, mapping, mount, db=db)
    except ImuError as e:
        text = str(e)
        assert "\n" not in text and (path.name in text or "align_window_s" in text), text
        return "error"
    assert tuple(table.columns) == COLUMNS
    t = table["t_s"].to_numpy()
    assert np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)
    for ch, col in (("gyro_x", "gyro_x_rad_s"), ("gyro_y", "gyro_y_rad_s"), ("gyro_z", "gyro_z_rad_s"),
                    ("accel_x", "accel_x_m_s2"), ("accel_y", "accel_y_m_s2"), ("accel_z", "accel_z_m_s2")):
        v = table[col].to_numpy()
        fresh = table[f"fresh_{ch}"].to_numpy()
        assert np.array_equal(fresh, np.isfinite(v)), "NaN exactly where not fresh"
        if mapping.range_check and db is SIM_DB:
            limit = GYRO_MAX_RAD_S if ch.startswith("gyro") else ACCEL_MAX_M_S2
            assert np.all(np.abs(v[fresh]) <= limit * (1 + 1e-9))
    sp = table["speed_m_s"].to_numpy()
    assert np.all(np.isfinite(sp[table["fresh_speed"].to_numpy()]))
    if mapping.range_check and db is SIM_DB:
        assert np.all((sp[np.isfinite(sp)] >= 0) & (sp[np.isfinite(sp)] <= SPEED_MAX_M_S * (1 + 1e-9)))
    assert summary.samples == len(table)
    summary.lines()  # the report renders
    return "ok"


def mutate_text(text: str, rng: np.random.Generator) -> str:
    lines = text.splitlines(keepends=True)
    for _ in range(int(rng.integers(1, 6))):
        if not lines:
            break
        i = int(rng.integers(0, len(lines)))
        op = int(rng.integers(0, 9))
        if op == 0:
            del lines[i]
        elif op == 1:
            lines.insert(i, lines[i])  # duplicate line
        elif op == 2 and i + 1 < len(lines):
            lines[i], lines[i + 1] = lines[i + 1], lines[i]  # out of order
        elif op == 3:
            s = list(lines[i])
            for _ in range(int(rng.integers(1, 4))):
                if s:
                    s[int(rng.integers(0, len(s)))] = chr(int(rng.choice([0, 9, 32, 35, 44, 46, 45, 120, 255, 0x263A,
                                                                          int(rng.integers(33, 127))])))
            lines[i] = "".join(s)
        elif op == 4:
            lines[i] = lines[i][: int(rng.integers(0, max(1, len(lines[i]))))]  # cut line
        elif op == 5:
            lines.insert(i, "".join(chr(int(c)) for c in rng.integers(32, 127, int(rng.integers(0, 60)))) + "\n")
        elif op == 6:  # a digit changes: timestamps jump, IDs change, data changes
            s = list(lines[i])
            digits = [k for k, c in enumerate(s) if c.isdigit()]
            if digits:
                s[digits[int(rng.integers(0, len(digits)))]] = str(int(rng.integers(0, 10)))
            lines[i] = "".join(s)
        elif op == 7:
            del lines[i:]  # truncated file
        else:
            lines[i] = lines[i].replace(" 8 ", " 9 ", 1).replace(",8,", ",12,", 1)  # wrong DLC
    return "".join(lines)


def mutate_bytes(data: bytes, rng: np.random.Generator) -> bytes:
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 5))):
        if not b:
            break
        op = int(rng.integers(0, 4))
        i = int(rng.integers(0, len(b)))
        if op == 0:
            b[i] ^= 1 << int(rng.integers(0, 8))
        elif op == 1:
            del b[i:]
        elif op == 2:
            b[i:i + int(rng.integers(1, 64))] = bytes(int(rng.integers(1, 64)))
        else:
            b[i:i] = b[max(0, i - 100):i]
    return bytes(b)


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    """Small real logs: the simulator's drive in every format, and the start of the comma log."""
    tmp = tmp_path_factory.mktemp("seeds")
    imu, speed = sim_imu(duration_s=0.3, seed=3)
    out = {}
    for suffix in (".asc", ".log", ".trc", ".csv", ".blf", ".mf4"):
        path = tmp / f"seed{suffix}"
        write_can_log(path, imu, speed, seed=3)
        out[suffix] = path.read_bytes()
    if COMMA.is_dir():
        with open(COMMA / "derived" / "raw_can_candump.log", "rb") as f:
            out["comma"] = b"".join(f.readline() for _ in range(500))
    return out


#: Inputs per seed file; asammdf opens an MF4 in ~30 ms, so it gets fewer.
N_MUTANTS = {".asc": 300, ".log": 300, ".trc": 300, ".csv": 300, ".blf": 400, ".mf4": 20, "comma": 160}


@pytest.mark.parametrize("kind", list(N_MUTANTS))
def test_mutated_real_logs(tmp_path, seeds, kind):
    if kind not in seeds:
        pytest.skip("comma2k19 data not present")
    rng = np.random.default_rng(sum(map(ord, kind)))  # reproducible mutants
    seed = seeds[kind]
    suffix = ".log" if kind == "comma" else kind
    mapping, db = (comma_mapping(), load_dbc(comma_mapping().dbc_path)) if kind == "comma" else (sim_mapping(), SIM_DB)
    outcomes = {"ok": 0, "error": 0}
    for k in range(N_MUTANTS[kind]):
        path = tmp_path / f"m{k}{suffix}"
        if suffix in (".blf", ".mf4"):
            path.write_bytes(mutate_bytes(seed, rng))
        else:
            path.write_bytes(mutate_text(seed.decode("latin-1"), rng).encode("utf-8", "surrogateescape"))
        outcomes[check(path, mapping, db)] += 1
        path.unlink()
    print(f"fuzz {kind}: {outcomes}")
    assert outcomes["ok"] > 0, "mutants that keep most of the file must still decode"


VALID = "(1700000000.{:06d}) can0 {}#{}\n"


@st.composite
def candump_text(draw):
    lines = []
    t = 0
    for _ in range(draw(st.integers(1, 40))):
        t += draw(st.integers(-3000, 20000))
        kind = draw(st.integers(0, 3))
        if kind == 0:
            lines.append(draw(st.text(max_size=60)) + "\n")
        else:
            fid = draw(st.sampled_from(["174", "178", "122", "100", "18FEF100", "7FF", "0174"]))
            data = draw(st.binary(min_size=0, max_size=draw(st.sampled_from([8, 8, 12, 64])))).hex().upper()
            lines.append(VALID.format(max(t, 0) % 1_000_000, fid, data))
    return "".join(lines)


@settings(max_examples=160, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=candump_text())
def test_hypothesis_candump(tmp_path, text):
    path = tmp_path / "h.log"
    path.write_text(text, encoding="utf-8", errors="surrogateescape")
    check(path, sim_mapping(), SIM_DB)


def test_error_frames_and_remote_frames_only(tmp_path):
    """A bus with nothing but error and remote frames: one line, not a crash."""
    path = tmp_path / "errors.blf"
    with can.Logger(path) as w:
        for k in range(50):
            w.on_message_received(can.Message(timestamp=1.7e9 + k, is_error_frame=True))
            w.on_message_received(can.Message(timestamp=1.7e9 + k, arbitration_id=0x174, is_extended_id=False,
                                              is_remote_frame=True, dlc=8))
    assert check(path, sim_mapping(), SIM_DB) == "error"
