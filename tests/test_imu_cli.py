"""``vifusion can LOG --config C --out imu.parquet|csv``: the table, the printed summary, and one-line
errors with exit status 2 that leave no output file behind."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from drivesim.canlog import DBC_PATH, signal_map, write_can_log
from fusion.cli import main
from test_imu_common import RES_GYRO_RAD_S, sim_imu


def _config(tmp_path, dbc=None, extra=""):
    signals = "\n".join(f'{k} = "{v}"' for k, v in signal_map().items())
    path = tmp_path / "config.toml"
    path.write_text(f"""
[camera]
width = 1280
height = 720
fx = 700.0

[mount]
height_m = 1.2
tilt_deg = 12.0

[imu]
axes = ["x", "-y", "-z"]
position_m = [0.0, 0.0, 0.5]

[can]
dbc = "{dbc or DBC_PATH}"
{extra}
[can.signals]
{signals}
""")
    return path


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cli")
    imu, speed = sim_imu(duration_s=1.0, seed=6)
    log = tmp / "drive.blf"
    offset = write_can_log(log, imu, speed)
    return imu, offset, log


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_writes_table_and_summary(tmp_path, drive, capsys, suffix):
    imu, offset, log = drive
    out = tmp_path / f"imu{suffix}"
    rc = main(["can", str(log), "--config", str(_config(tmp_path)), "--out", str(out), "--quiet"])
    assert rc == 0
    printed = capsys.readouterr().out
    for needle in ("frames read", "samples: 100", "IMU_RATE.RateX", "deg/s", "gaps: none",
                   "unknown IDs (not in the DBC): 1: 0x51A", "decode errors: 0", "Hz"):
        assert needle in printed, needle
    table = pd.read_parquet(out) if suffix == ".parquet" else pd.read_csv(out)
    assert len(table) == len(imu)
    # FRD IMU: vehicle gyro_z = -IMU gyro_z, within half a raw step of the written sample
    assert np.abs(table["gyro_z_rad_s"] + imu["gyro_z_rad_s"]).max() <= RES_GYRO_RAD_S / 2 * (1 + 1e-6)
    assert np.abs(table["t_s"] - offset - imu["t_s"]).max() < 1.5e-6
    assert not list(tmp_path.glob(".*partial*")), "no temporary file left behind"


def _run_error(args, capsys):
    rc = main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


def test_bad_inputs_one_line_exit_2(tmp_path, drive, capsys):
    _, _, log = drive
    cfg = _config(tmp_path)
    out = tmp_path / "imu.parquet"
    msg = _run_error(["can", str(tmp_path / "missing.blf"), "--config", str(cfg), "--out", str(out), "--quiet"], capsys)
    assert "missing.blf: no such log file" in msg
    msg = _run_error(["can", str(log), "--config", str(cfg), "--out", str(tmp_path / "imu.xlsx"), "--quiet"], capsys)
    assert "output must end in .parquet or .csv" in msg
    broken = tmp_path / "broken.dbc"
    broken.write_text(DBC_PATH.read_text().replace('BO_ 376 IMU_ACC: 8 IMU', 'BO_ 376 IMU_ACC 8 IMU', 1))
    msg = _run_error(["can", str(log), "--config", str(cfg), "--out", str(out), "--dbc", str(broken), "--quiet"], capsys)
    assert "broken.dbc:" in msg and "DBC syntax error" in msg
    broken.write_text("hello\nthis is not a dbc\n")     # the text near the error, without cantools' quote
    msg = _run_error(["can", str(log), "--config", str(cfg), "--out", str(out), "--dbc", str(broken), "--quiet"], capsys)
    assert msg.endswith("broken.dbc:1: DBC syntax error at column 1 near 'hello'"), msg
    # outputs under a file: said before the log is read (a review: after the whole log)
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    msg = _run_error(["can", str(log), "--config", str(cfg), "--out", str(a_file / "imu.csv"), "--quiet"], capsys)
    assert "is a file, not a folder" in msg
    bad_cfg = _config(tmp_path, extra="gap_limt_s = 0.2\n")
    msg = _run_error(["can", str(log), "--config", str(bad_cfg), "--out", str(out), "--quiet"], capsys)
    assert "[can] gap_limt_s is not a known key" in msg
    assert not out.exists()


def test_truncated_log_needs_partial(tmp_path, drive, capsys):
    _, _, log = drive
    cut = tmp_path / "cut.blf"
    cut.write_bytes(log.read_bytes()[: log.stat().st_size * 2 // 3])
    cfg = _config(tmp_path)
    out = tmp_path / "imu.csv"
    msg = _run_error(["can", str(cut), "--config", str(cfg), "--out", str(out), "--quiet"], capsys)
    assert "truncated" in msg and "nothing written" in msg and "--partial" in msg
    assert not out.exists(), "never a partial output file that looks complete"
    msg = _run_error(["can", str(cut), "--config", str(cfg), "--out", str(out), "--partial", "--quiet"], capsys)
    assert "--partial needs a .parquet output" in msg and not out.exists()   # a CSV has no complete=false
    out_pq = tmp_path / "imu.parquet"
    assert main(["can", str(cut), "--config", str(cfg), "--out", str(out_pq), "--partial", "--quiet"]) == 0
    assert "reading stopped early" in capsys.readouterr().err
    table = pd.read_parquet(out_pq)
    assert table.attrs["complete"] is False and 0 < len(table) < 100


def test_config_with_only_imu_and_can(tmp_path, drive, capsys):
    """A CAN-only user needs no [camera]; a config without [can] is a one-line error."""
    _, _, log = drive
    signals = "\n".join(f'{k} = "{v}"' for k, v in signal_map(False).items())
    cfg = tmp_path / "can_only.toml"
    cfg.write_text(f'[imu]\naxes = ["x", "-y", "-z"]\n[can]\ndbc = "{DBC_PATH}"\n[can.signals]\n{signals}\n')
    out = tmp_path / "imu.csv"
    assert main(["can", str(log), "--config", str(cfg), "--out", str(out), "--quiet"]) == 0
    assert "gyro_y_rad_s: UNAVAILABLE" in capsys.readouterr().out
    assert pd.read_csv(out)["gyro_y_rad_s"].isna().all()
    no_can = tmp_path / "no_can.toml"
    no_can.write_text('[imu]\naxes = ["x", "y", "z"]\n')
    msg = _run_error(["can", str(log), "--config", str(no_can), "--out", str(out), "--quiet"], capsys)
    assert "[can] is missing" in msg


def test_a_channel_never_sent_is_a_warning(tmp_path, drive, capsys):
    """A mapped signal whose message never comes: the column is all NaN and the command says so
    (a review found it silent)."""
    _, _, log = drive
    dbc = tmp_path / "aux.dbc"
    text = DBC_PATH.read_text()
    first_bo = text.index("BO_ ")
    dbc.write_text(text[:first_bo] + 'BO_ 1793 AUX: 8 IMU\n SG_ AccY : 0|16@1- (0.001,0) [-32|32] "m/s2" ECU\n\n'
                   + text[first_bo:])
    cfg = _config(tmp_path, dbc=dbc)
    cfg.write_text("\n".join('accel_y = "AUX.AccY"' if line.startswith("accel_y =") else line
                             for line in cfg.read_text().splitlines()))
    out = tmp_path / "imu.csv"
    assert main(["can", str(log), "--config", str(cfg), "--out", str(out), "--quiet"]) == 0
    assert "accel_y_m_s2 never seen" in capsys.readouterr().err
    assert pd.read_csv(out)["accel_y_m_s2"].isna().all()


def test_a_binary_dbc_is_one_printable_line(tmp_path, drive, capsys):
    """A DBC that is binary garbage: the one-line error quotes the bytes near the syntax error
    as escapes, not as raw NUL and control bytes on the user's terminal (a review)."""
    _, _, log = drive
    garbage = tmp_path / "garbage.dbc"
    garbage.write_bytes(bytes(range(256)) * 4)
    msg = _run_error(["can", str(log), "--config", str(_config(tmp_path)), "--out", str(tmp_path / "imu.csv"),
                      "--dbc", str(garbage), "--quiet"], capsys)
    assert "garbage.dbc:1: DBC syntax error at column 1 near '\\x00\\x01\\x02" in msg, msg
    assert msg.isprintable(), repr(msg)


def test_quiet_and_debug_before_or_after_the_command(tmp_path, drive, capsys):
    """``--quiet`` is taken before the command's name as ``--debug`` is (``vifusion --quiet can
    ...`` had been "unrecognized arguments", exit 2, a review), by every command, and either
    flag given on one side is not undone by the other side's default."""
    from fusion.cli import SUBCOMMANDS, build_parser

    _, _, log = drive
    out = tmp_path / "imu.csv"
    assert main(["--quiet", "can", str(log), "--config", str(_config(tmp_path)), "--out", str(out)]) == 0
    assert out.is_file() and "error" not in capsys.readouterr().err
    rest = {"run": [], "campaign": ["d", "--out", "o"], "vision": ["--video", "v", "--config", "c", "--out", "o"],
            "can": ["log", "--config", "c", "--out", "o"], "simulate": ["s", "--out", "o"]}
    assert set(rest) == set(SUBCOMMANDS)
    for command, args in rest.items():
        for before, after, quiet, debug in (([], [], False, False), (["--quiet"], [], True, False),
                                            ([], ["--quiet"], True, False), (["--debug"], ["--quiet"], True, True),
                                            (["--quiet", "--debug"], [], True, True)):
            got = build_parser().parse_args([*before, command, *args, *after])
            assert (got.quiet, got.debug) == (quiet, debug), (before, command, after)
