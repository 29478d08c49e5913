"""``vifusion run`` end to end on small simulated drives, and its answers to bad input: one
line, exit status 2, no output folder that looks complete; or a warning when it can go on."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fusion.drive import SAMPLE_DRIVE

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "configs" / "scenarios" / "test" / "tiny_banked_curve.toml"


def vifusion(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "fusion", *map(str, args)], capture_output=True, text=True, cwd=cwd)


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    d = tmp_path_factory.mktemp("run") / "drive"
    r = vifusion("simulate", TINY, "--out", d, "--quiet")
    assert r.returncode == 0, r.stderr
    return d


@pytest.fixture
def copy(drive, tmp_path):
    d = tmp_path / "drive"
    shutil.copytree(drive, d)
    return d


def one_line_error(r, *words):
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert "Traceback" not in r.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])


def test_run_writes_the_contract_outputs(drive, tmp_path):
    out = tmp_path / "out"
    r = vifusion("run", "--drive", drive, "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    vision = pd.read_csv(out / "vision.csv")
    assert list(vision.columns[:6]) == ["t_s", "frame", "roll_deg", "pitch_deg", "yaw_deg", "valid"]
    assert len(vision) == 30
    fused = pd.read_csv(out / "fused.csv")
    for c in ("t_s", "roll_deg", "pitch_deg", "yaw_deg", "bank_deg", "roll_world_deg", "roll_sigma_deg",
              "bank_sigma_deg", "bank_plain_deg", "roll_world_imu_only_deg", "pitch_world_imu_only_deg",
              "bank_rate_sigma_deg_s"):
        assert c in fused.columns, c
    # one row per IMU sample (100 Hz over 2 s), no NaN in the estimates: none in the angles
    # relative to the road, none in those relative to gravity from the first wheel speed on and
    # all of them before it (the gravity reference waits for the speed, as the live estimate says)
    assert 195 <= len(fused) <= 201
    assert np.isfinite(fused[["roll_deg", "pitch_deg", "yaw_deg", "roll_sigma_deg"]].to_numpy()).all()
    known = np.isfinite(fused["speed_m_s"].to_numpy())
    assert known.mean() > 0.95 and not known[0] and np.all(np.diff(known.astype(int)) >= 0)
    gravity = fused[["bank_deg", "bank_sigma_deg", "roll_world_deg", "pitch_world_deg", "grade_deg"]].to_numpy()
    assert np.isfinite(gravity[known]).all() and np.isnan(gravity[~known]).all()
    summary = json.loads((out / "report" / "summary.json").read_text())
    # a 2 s drive leaves nothing to score after the 2 s of convergence: no RMSE, and it says so
    assert summary["rmse_deg"] is None and any("no RMSE against truth" in w for w in summary["warnings"])
    assert set(summary["imu_calibration"]) == {"gyro_bias_deg_s", "gyro_bias_sigma_deg_s", "accel_bias_m_s2",
                                               "accel_bias_sigma_m_s2"}
    # the CAN log's totals in the run table: every IMU sample is a row of fused.csv
    counts = summary["counts"]
    assert counts["imu_samples_decoded"] == len(fused) and counts["imu_rate_hz"] == 100.0
    assert counts["can_frames_read"] >= counts["can_frames_decoded"] >= 2 * len(fused)
    # each frame read in one row (the simulated log has extra traffic of both kinds)
    assert counts["can_frames_other_messages"] > 0 and counts["can_frames_unknown_ids"] > 0
    assert counts["can_frames_read"] == sum(counts[k] for k in (
        "can_frames_decoded", "can_frames_other_messages", "can_frames_unknown_ids", "can_error_frames")), counts
    # every key of the counts is a snake_case name (they mixed in phrases, a review)
    assert all(k.isidentifier() and k == k.lower() for k in counts), list(counts)
    # the input files named, and the smoothed or forward estimate said
    assert summary["inputs"]["video"] == str(drive / "video.mp4") and summary["smoothed"] is False
    # the DBC the decode used, the config's [can] dbc (it was null without --dbc, a review)
    assert summary["inputs"]["dbc"] == str(drive / "vifusion_imu.dbc")
    assert (out / "calibration.toml").is_file()
    html = (out / "report" / "report.html").read_text()
    assert "data:image/png;base64" in html
    for png in ("attitude.png", "world.png", "errors.png", "road.png", "biases.png"):
        assert (out / "report" / png).stat().st_size > 10_000
    assert not out.with_name("out.partial").exists()
    # the Parquet twins hold the same table; the CSV keeps 9 significant digits (a fixed 6
    # decimals kept 2 of a curvature sigma of 9e-5 1/m) and the times to the microsecond
    for name, csv in (("vision", vision), ("fused", fused)):
        pq = pd.read_parquet(out / f"{name}.parquet")
        assert list(pq.columns) == list(csv.columns)
        assert np.max(np.abs(pq["t_s"] - csv["t_s"])) <= 1e-6
        num = [c for c in pq.columns if pd.api.types.is_numeric_dtype(pq[c]) and c != "t_s"]
        np.testing.assert_allclose(csv[num].to_numpy(dtype=float), pq[num].to_numpy(dtype=float), rtol=1e-8, atol=0,
                                   equal_nan=True, err_msg=name)
    # a frame without a valid estimate has no numbers of one (its twist columns were 0.0)
    from vision.video import ESTIMATE_COLUMNS

    bad = vision[vision["valid"] == 0]
    assert len(bad) and bad[list(ESTIMATE_COLUMNS)].isna().all().all()


def test_numeric_tables_are_written_as_pandas_writes_them(tmp_path):
    """fused.csv is written by one format per row (fusion.cli.numeric_csv, a third of pandas'
    time): the same bytes as pandas' to_csv with the run's formats, for the values that format
    differently (NaN empty, infinities, -0, the smallest and largest, ints beyond 9 digits,
    booleans) and for no rows; a table with a string column (vision.csv's reason) is left to
    pandas, which quotes."""
    from fusion.cli import numeric_csv, write_table

    x = np.array([0.1, np.nan, np.inf, -np.inf, -0.0, 1e-300, 1.7976931348623157e308, 123456789.123, -2.5e-5])
    df = pd.DataFrame({"t_s": np.linspace(1000.0, 1000.08, len(x)), "roll_deg": x, "bank_deg": x[::-1],
                       "frame": np.arange(len(x)) * 2**40 - 7, "valid": np.arange(len(x)) % 2 == 0,
                       "n": np.arange(len(x), dtype=np.uint16)})

    def by_pandas(d):
        if "t_s" in d:
            d = d.assign(t_s=np.char.mod("%.6f", d["t_s"].to_numpy(dtype=float)))
        return d.to_csv(index=False, float_format="%.9g", lineterminator="\n")

    for d in (df, df.head(0), df[["roll_deg", "valid"]]):
        assert numeric_csv(d) == by_pandas(d)
    assert numeric_csv(df[["roll_deg"]]) is None       # pandas writes its NaN as "": left to it
    write_table(df, tmp_path / "t.csv")
    assert (tmp_path / "t.csv").read_bytes() == by_pandas(df).encode()
    assert pd.read_csv(tmp_path / "t.csv")["roll_deg"].isna().sum() == 1
    assert numeric_csv(df.assign(reason="no lanes, dashed")) is None
    # a missing time is an empty field on both paths (pandas' own would write "nan")
    nan_time = df.assign(t_s=df["t_s"].where(df.index != 3))
    write_table(nan_time.assign(reason="x"), tmp_path / "s.csv")
    for text in (numeric_csv(nan_time), (tmp_path / "s.csv").read_text()):
        assert text.splitlines()[4].split(",")[0] == "", text


def test_run_without_inputs_processes_the_bundled_sample(tmp_path):
    """The bundled 12 s drive (640x360, a right-hand runoff to 6 deg) against its truth.csv.
    Measured: fused roll 0.214, yaw 0.274, bank 0.195 deg RMS after 2 s; the vision alone 0.557
    roll, 0.433 yaw; the plain IMU-minus-vision bank 0.835. Bars: the issue's 0.3 deg for the
    bank, 0.3 for roll and yaw (a quarter of the HD drives' resolution: coarser than the
    bench's), and better than the vision and the plain difference."""
    out = tmp_path / "sample"
    r = vifusion("run", "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    fused = pd.read_csv(out / "fused.csv")
    assert fused["t_s"].iloc[-1] - fused["t_s"].iloc[0] > 11.0
    summary = json.loads((out / "report" / "summary.json").read_text())
    rmse = summary["rmse_deg"]
    assert rmse["fused"]["bank"] < 0.3 and rmse["fused"]["roll"] < 0.3 and rmse["fused"]["yaw"] < 0.3, rmse
    assert rmse["fused"]["roll"] < rmse["vision"]["roll"] and rmse["fused"]["yaw"] < rmse["vision"]["yaw"], rmse
    assert rmse["fused"]["bank"] < rmse["imu_minus_vision"]["bank"], rmse
    # the road's grade is scored against the simulator's road pitch (truth.csv's road_pitch_deg,
    # the same convention as fused.csv's grade_deg): the summary's figure is that RMSE
    truth = pd.read_csv(SAMPLE_DRIVE / "truth.csv")
    late = fused["t_s"] >= fused["t_s"].iloc[0] + 2.0
    e = fused["grade_deg"][late] - np.interp(fused["t_s"][late], truth["t_s"], truth["road_pitch_deg"])
    assert rmse["fused"]["grade"] == pytest.approx(float(np.sqrt(np.mean(e**2))), rel=1e-6), rmse
    # its 640x360 vision is overconfident in the banked curve (docs/fusion-notes.md): the report
    # says so when the NEES misses the 90 % (66 % measured), and says nothing otherwise
    c = summary["consistency"]
    said = [w for w in summary["warnings"] if w.startswith("fused sigma against the truth")]
    assert len(said) == (c["fraction_inside"] < 0.9), (c, summary["warnings"])
    if said:
        assert ("overconfident" in said[0]) == (c["fraction_above"] >= c["fraction_below"]), said


def test_shipped_sample_drive_is_what_the_simulator_makes(tmp_path):
    """The bundled sample drive must not drift from its scenario: re-simulated (without video)
    its truth and IMU truth are identical."""
    fresh = tmp_path / "sample"
    r = vifusion("simulate", SAMPLE_DRIVE / "scenario.toml", "--out", fresh, "--no-video", "--quiet")
    assert r.returncode == 0, r.stderr
    a, b = (SAMPLE_DRIVE / "config.toml").read_text(), (fresh / "config.toml").read_text()
    assert a.replace(str(SAMPLE_DRIVE), "") == b.replace(str(fresh), "")
    # Tables: same columns and rows, values equal to 1e-6 in their units (deg, m, rad/s, m/s^2):
    # far below anything physical (the simulated gyro noise is 9e-4 rad/s), while rounding
    # differs between machines and library builds: a fresh install gave -2.54162814e-13 for
    # -2.54162815e-13 in truth.csv and up to 7e-9 in imu_truth.csv's numerically
    # differentiated rates and forces.
    for f in ("truth.csv", "imu_truth.csv", "frames.csv"):
        a, b = pd.read_csv(SAMPLE_DRIVE / f), pd.read_csv(fresh / f)
        assert list(a.columns) == list(b.columns) and len(a) == len(b), f
        num = a.select_dtypes("number").columns
        np.testing.assert_allclose(a[num].to_numpy(), b[num].to_numpy(), rtol=0.0, atol=1e-6, err_msg=f)
        assert a.drop(columns=num).equals(b.drop(columns=num)), f


def test_calibration_written_and_read_back(drive, tmp_path):
    """Every run writes its end-of-drive IMU biases (calibration.toml); ``--calibration`` starts
    the next run from them: its first sample's biases are the file's, within a tenth of their
    sigma (one IMU sample's update moves them that little)."""
    r = vifusion("run", "--drive", drive, "--out", tmp_path / "a", "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    # --no-report skips the plots, not the summary (its warnings, counts and time offset)
    assert sorted(p.name for p in (tmp_path / "a" / "report").iterdir()) == ["summary.json"]
    cal = tmp_path / "a" / "calibration.toml"
    from fusion.calibration import read_calibration

    values = read_calibration(cal)
    r = vifusion("run", "--drive", drive, "--out", tmp_path / "b", "--quiet", "--no-report", "--calibration", cal)
    assert r.returncode == 0, r.stderr
    assert f"IMU biases started from {cal}" in r.stdout.splitlines()    # (said nowhere but summary.json, a review)
    first = pd.read_csv(tmp_path / "b" / "fused.csv").iloc[0]
    for i, a in enumerate("xyz"):
        assert abs(first[f"gyro_bias_{a}_deg_s"] - values["gyro_bias_deg_s"][i]) < 0.1 * values["gyro_bias_sigma_deg_s"][i]
        assert abs(first[f"accel_bias_{a}_m_s2"] - values["accel_bias_m_s2"][i]) < 0.1 * values["accel_bias_sigma_m_s2"][i]
    bad = tmp_path / "bad.toml"
    bad.write_text("[fusion]\naccel_bias_m_s2 = 0.1\n")
    one_line_error(vifusion("run", "--drive", drive, "--out", tmp_path / "c", "--calibration", bad),
                   "bad.toml", "accel_bias_m_s2")
    assert not (tmp_path / "c").exists() and not (tmp_path / "c.partial").exists()
    # the file says whose biases they are, and the run what it started from (a review: a
    # calibration of an FRD-mounted IMU was applied to an FLU one, 9 sigma off, without a word)
    import json

    from fusion.config import load_config

    mount = load_config(drive / "config.toml").imu
    assert values["imu_axes"] == list(mount.axes) == ["x", "-y", "-z"]
    summary = json.loads((tmp_path / "b" / "report" / "summary.json").read_text())
    assert summary["calibration_from"] == str(cal)
    assert json.loads((tmp_path / "a" / "report" / "summary.json").read_text())["calibration_from"] is None
    flu = tmp_path / "flu"
    shutil.copytree(drive, flu)
    text = (flu / "config.toml").read_text()
    (flu / "config.toml").write_text(text.replace('axes = ["x", "-y", "-z"]', 'axes = ["x", "y", "z"]'))
    one_line_error(vifusion("run", "--drive", flu, "--out", tmp_path / "d", "--calibration", cal),
                   "calibration.toml", "axes = ['x', '-y', '-z']", "['x', 'y', 'z']")
    assert not (tmp_path / "d").exists()


def test_missing_file(drive, tmp_path):
    r = vifusion("run", "--video", drive / "video.mp4", "--can", tmp_path / "nope.blf", "--config",
                 drive / "config.toml", "--out", tmp_path / "out")
    one_line_error(r, "nope.blf")
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.partial").exists()


def test_config_key_of_the_wrong_type(copy, tmp_path):
    cfg = copy / "config.toml"
    text = cfg.read_text()
    cfg.write_text(text.replace("height_m = 1.1", 'height_m = "tall"'))
    one_line_error(vifusion("run", "--drive", copy, "--out", tmp_path / "out"), "height_m")
    # millimetres for metres: refused (it ran and found lanes on no frame, a review)
    cfg.write_text(text.replace("height_m = 1.1", "height_m = 1100"))
    one_line_error(vifusion("run", "--drive", copy, "--out", tmp_path / "out"), "height_m must be within")


def test_no_overlap_between_video_and_can(copy, tmp_path):
    frames = pd.read_csv(copy / "frames.csv")
    frames["t_s"] += 1000.0
    frames.to_csv(copy / "frames.csv", index=False)
    one_line_error(vifusion("run", "--drive", copy, "--out", tmp_path / "out"), "no overlap")
    assert not (tmp_path / "out").exists()


def test_imu_channel_never_seen(copy, tmp_path):
    # A speed message that the DBC describes but no node ever sends.
    dbc = copy / "vifusion_imu.dbc"
    dbc.write_text(dbc.read_text().replace(
        "BO_ 290 ABS_SPEED:",
        'BO_ 1792 ABS_SPEED_AUX: 8 ABS\n SG_ Speed : 0|16@1+ (0.01,0) [0|655.34] "km/h" ECU\n\nBO_ 290 ABS_SPEED:', 1))
    cfg = copy / "config.toml"
    cfg.write_text(cfg.read_text().replace('speed = "ABS_SPEED.WheelSpeedFront"', 'speed = "ABS_SPEED_AUX.Speed"'))
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out")
    one_line_error(r, "speed_m_s", "ABS_SPEED_AUX.Speed")
    assert not (tmp_path / "out").exists()
    # the vision command with that log for the travel per frame: likewise
    r = vifusion("vision", "--video", next(copy.glob("video.*")), "--frames", copy / "frames.csv", "--config", cfg,
                 "--can", next(copy.glob("can.*")), "--out", tmp_path / "v.csv", "--quiet")
    one_line_error(r, "speed")
    assert not (tmp_path / "v.csv").exists()


def test_truth_of_another_clock_is_an_error(copy, tmp_path):
    """A truth.csv whose times miss the drive's: one line, not NaN figures in the summary."""
    truth = pd.read_csv(copy / "truth.csv")
    truth["t_s"] -= 1.7e9
    truth.to_csv(tmp_path / "truth.csv", index=False)
    r = vifusion("run", "--video", copy / "video.mp4", "--frames", copy / "frames.csv", "--can", next(copy.glob("can.*")),
                 "--config", copy / "config.toml", "--truth", tmp_path / "truth.csv", "--out", tmp_path / "out")
    one_line_error(r, "no overlap", "truth.csv")
    assert not (tmp_path / "out").exists()


def test_truth_of_world_angles_only_is_scored(tmp_path):
    """A reference with only the attitude relative to level (an INS, as KITTI's OXTS): its
    angles are scored, the road angles and NEES are not (it was refused for lacking roll_deg).
    The same figures as from the full truth: the columns are the same numbers. (The bundled
    12 s drive: the tiny one is too short to be scored.)"""
    from fusion.drive import SAMPLE_DRIVE

    copy = tmp_path / "drive"
    shutil.copytree(SAMPLE_DRIVE, copy)
    full = tmp_path / "full"
    assert vifusion("run", "--drive", copy, "--out", full, "--quiet").returncode == 0
    truth = pd.read_csv(copy / "truth.csv")[["t_s", "roll_world_deg", "pitch_world_deg"]]
    truth.to_csv(tmp_path / "ins.csv", index=False, float_format="%.12g")
    out = tmp_path / "out"
    # (the files named relative to the folder the run starts in: summary.json gives them absolute)
    r = vifusion("run", "--video", "drive/video.mp4", "--frames", "drive/frames.csv", "--can",
                 next(copy.glob("can.*")).relative_to(tmp_path), "--config", "drive/config.toml",
                 "--truth", "ins.csv", "--out", "out", "--quiet", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "report" / "summary.json").read_text())
    ref = json.loads((full / "report" / "summary.json").read_text())
    fused = summary["rmse_deg"]["fused"]
    # every angle's key, null where the truth has none (they were left out, a review)
    assert {a for a, v in fused.items() if v is not None} == {"roll_world", "pitch_world"}
    assert set(fused) == set(ref["rmse_deg"]["fused"]) and fused["bank"] is None and summary["consistency"] is None
    for a in ("roll_world", "pitch_world"):
        assert fused[a] == pytest.approx(ref["rmse_deg"]["fused"][a], abs=1e-6)
    assert summary["inputs"] == {"video": str(copy / "video.mp4"), "frames": str(copy / "frames.csv"),
                                 "can_log": str(next(copy.glob("can.*"))), "dbc": str(copy / "vifusion_imu.dbc"),
                                 "config": str(copy / "config.toml"), "truth": str(tmp_path / "ins.csv")}


def test_video_shorter_than_frames_csv_is_a_warning(copy, tmp_path):
    frames = pd.read_csv(copy / "frames.csv")
    extra = pd.DataFrame({"frame": np.arange(30, 40), "t_s": frames["t_s"].iloc[-1] + np.arange(1, 11) / 15.0})
    pd.concat([frames, extra]).to_csv(copy / "frames.csv", index=False, float_format="%.6f")
    out = tmp_path / "out"
    r = vifusion("run", "--drive", copy, "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    assert "warning:" in r.stderr and "frames" in r.stderr
    summary = json.loads((out / "report" / "summary.json").read_text())
    assert any("10 of the" in w for w in summary["warnings"])


def test_video_longer_than_frames_csv_is_a_warning(copy, tmp_path):
    """A frames.csv cut short (the last 20 of 30 frames, 1.3 s, not listed): the run goes on
    with the frames listed and says how many of the video's it leaves out (it said nothing,
    and the fused table simply ended early); a listing of every 4th frame is timed by its own
    spacing per frame number. The run of the whole list says nothing of it."""
    frames = pd.read_csv(copy / "frames.csv")
    frames.head(10).to_csv(copy / "frames.csv", index=False, float_format="%.6f")
    out = tmp_path / "out"
    r = vifusion("run", "--drive", copy, "--out", out, "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "report" / "summary.json").read_text())
    assert any("holds 30 frames" in w and "up to frame 9: the last 20 (1.3 s) are not processed" in w
               for w in summary["warnings"]), summary["warnings"]
    # every 4th frame listed, up to frame 28 of 30: the one after it is 0.07 s, not 4 times more
    frames.iloc[::4].to_csv(copy / "frames.csv", index=False, float_format="%.6f")
    r = vifusion("run", "--drive", copy, "--out", out, "--quiet", "--no-report")
    summary = json.loads((out / "report" / "summary.json").read_text())
    assert r.returncode == 0 and not any("not processed" in w for w in summary["warnings"]), summary["warnings"]
    frames.iloc[::4].head(3).to_csv(copy / "frames.csv", index=False, float_format="%.6f")   # up to frame 8
    r = vifusion("run", "--drive", copy, "--out", out, "--quiet", "--no-report")
    summary = json.loads((out / "report" / "summary.json").read_text())
    assert any("the last 21 (1.4 s) are not processed" in w for w in summary["warnings"]), summary["warnings"]
    frames.to_csv(copy / "frames.csv", index=False, float_format="%.6f")
    r = vifusion("run", "--drive", copy, "--out", out, "--quiet", "--no-report")
    summary = json.loads((out / "report" / "summary.json").read_text())
    assert r.returncode == 0 and not any("not processed" in w for w in summary["warnings"]), summary["warnings"]


@pytest.mark.parametrize("column, words, value", [("t_s", "t_s does not increase", None),
                                                   ("frame", "frame numbers must increase", None),
                                                   ("frame", "row 7: frame number 99999999999999991611392 is beyond", 1e23)])
def test_frames_csv_not_increasing(copy, tmp_path, column, words, value):
    """A time going back, or a frame listed twice; a frame number beyond any video's (it wrapped
    to a negative integer and the run went on with nonsense warnings, a review)."""
    frames = pd.read_csv(copy / "frames.csv").astype({"frame": float})
    frames.loc[5, column] = frames.loc[4, column] if value is None else value
    frames.to_csv(copy / "frames.csv", index=False, float_format="%.6f")
    one_line_error(vifusion("run", "--drive", copy, "--out", tmp_path / "out"), "frames.csv", words)


def test_corrupt_can_log(copy, tmp_path):
    (copy / "can.asc").write_bytes(b"\x00\xff garbage\n" * 50)
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out")
    assert r.returncode == 2 and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_campaign_carries_the_calibration_and_skips_a_bad_drive(tmp_path):
    """``vifusion campaign``: drives in order, each started from the previous good one's
    calibration.toml; a missing drive is a counted, reported skip (its reason in the table and
    one line on stderr), not the end of the campaign; all drives bad: exit status 2. (The
    bundled sample drive: the tiny drive's vision is too poor for its biases to be carried,
    test_campaign_does_not_carry_a_drive_with_poor_vision.)"""
    drive, second = tmp_path / "drive", tmp_path / "second"
    shutil.copytree(SAMPLE_DRIVE, drive)
    shutil.copytree(SAMPLE_DRIVE, second)
    out = tmp_path / "camp"
    r = vifusion("campaign", drive, tmp_path / "missing", second, "--out", out, "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    assert [line for line in r.stderr.splitlines() if "skipped" in line] == \
        [f"warning: {tmp_path / 'missing'} skipped: {tmp_path / 'missing'}: no such drive folder"], r.stderr
    table = pd.read_csv(out / "campaign.csv")
    assert list(table["status"]) == ["ok", f"skipped: {tmp_path / 'missing'}: no such drive folder", "ok"]
    # 'ok' means it ran; the run's own warnings are in the table (the sample drive's NEES share)
    assert all("NEES" in w for w in table["warnings"].iloc[[0, 2]]), table["warnings"]
    assert table["calibration_from"].fillna("").tolist() == ["", str(out / "drive" / "calibration.toml"),
                                                             str(out / "drive" / "calibration.toml")]
    assert table["calibration_carried"].iloc[0] and table["calibration_carried"].iloc[2], table
    assert pd.read_parquet(out / "campaign.parquet").shape == table.shape
    # the second drive started where the first ended (one sample's update moves the biases little)
    first_end = pd.read_csv(out / "drive" / "fused.csv").iloc[-1]
    second_start = pd.read_csv(out / "second" / "fused.csv").iloc[0]
    for c in ("gyro_bias_z_deg_s", "accel_bias_y_m_s2"):
        sig = first_end[c.replace("_bias_z_", "_bias_z_sigma_").replace("_bias_y_", "_bias_y_sigma_")]
        assert abs(second_start[c] - first_end[c]) < 0.1 * sig, c
    r = vifusion("campaign", tmp_path / "missing", "--out", tmp_path / "none", "--quiet")
    assert r.returncode == 2 and r.stderr.strip().splitlines()[-1] == "error: no drive of the campaign could be run"
    assert "Traceback" not in r.stderr
    # run again into the same folder with the second drive now broken: its outputs of the first
    # campaign do not outlive the row that now says 'skipped' (a review found them left there,
    # complete-looking, beside a table that said the drive was skipped)
    (second / "can.blf").unlink()
    r = vifusion("campaign", drive, second, "--out", out, "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    table = pd.read_csv(out / "campaign.csv")
    assert table["status"].iloc[0] == "ok" and table["status"].iloc[1].startswith("skipped: "), table["status"]
    assert not (out / "second").exists() and (out / "drive" / "fused.csv").is_file()
    # started from a calibration an earlier campaign's drive wrote, into the same folder: that
    # drive's folder is kept for it (the cleanup had deleted the file before the first drive read
    # it, a review)
    third = tmp_path / "third"
    shutil.copytree(drive, third)
    cal = out / "drive" / "calibration.toml"
    saved = cal.read_text()
    r = vifusion("campaign", third, drive, "--out", out, "--quiet", "--no-report", "--calibration", cal)
    assert r.returncode == 0, r.stderr
    table = pd.read_csv(out / "campaign.csv")
    assert list(table["status"]) == ["ok", "ok"] and table["calibration_from"].iloc[0] == str(cal), table
    assert cal.read_text() != saved     # the drive ran again, from the third's calibration, and replaced it
    # a drive's output folder holding files a run did not write: refused before any drive runs
    (out / "drive" / "notes.txt").write_text("mine")
    one_line_error(vifusion("campaign", second, drive, "--out", out, "--quiet"), "holds files a run did not write")
    assert (out / "drive" / "notes.txt").is_file() and (out / "campaign.csv").is_file()


def test_campaign_does_not_carry_a_drive_with_poor_vision(drive, tmp_path):
    """The tiny drive's lanes are found on 11 of 30 frames: its run ends with a yaw-rate bias of
    1.56 +- 0.30 deg/s against a truth of -0.30 (a review), and carried, it doubled the next
    drive's bank RMSE. Such a drive runs, its biases are not handed on (said on stderr,
    ``calibration_carried`` false), and the next drive starts from what the drive started from:
    the config, or ``--calibration``."""
    from fusion.calibration import write_calibration

    out = tmp_path / "camp"
    cal = tmp_path / "cal.toml"
    write_calibration({"gyro_bias_deg_s": [0.2, 0.15, -0.3], "gyro_bias_sigma_deg_s": [0.05, 0.05, 0.05],
                       "accel_bias_m_s2": [0.0, 0.0, 0.0], "accel_bias_sigma_m_s2": [0.05, 0.05, 0.05]}, cal)
    second = tmp_path / "second"
    shutil.copytree(drive, second)
    for given, start in ((None, ""), (cal, str(cal))):
        r = vifusion("campaign", drive, second, "--out", out, "--quiet", "--no-report",
                     *(("--calibration", given) if given else ()))
        assert r.returncode == 0, r.stderr
        said = [line for line in r.stderr.splitlines() if "calibration is not carried" in line]
        assert len(said) == 2 and "vision valid on 11 of 30 frames" in said[0], r.stderr
        assert said[0].endswith(f"starts from {given or 'the config'}"), said[0]
        table = pd.read_csv(out / "campaign.csv")
        assert ["" if pd.isna(c) else c for c in table["calibration_from"]] == [start, start], table
        assert not table["calibration_carried"].any(), table


def test_vision_command_with_the_can_log_is_the_runs_vision(tmp_path):
    """``vifusion vision --can`` gives the estimator the wheel-speed travel per frame, as
    ``vifusion run`` does: with the same workers the two vision tables are identical, the
    road-twist map included (the bundled sample drive's first 120 frames run into a banked
    curve: 65 of them projected onto the twisted road, measured). Without ``--can`` the map is
    off, and the summary line says so."""
    d = tmp_path / "sample"
    d.mkdir()
    for f in SAMPLE_DRIVE.iterdir():
        if f.name != "frames.csv":
            (d / f.name).symlink_to(f)
    pd.read_csv(SAMPLE_DRIVE / "frames.csv").iloc[:120].to_csv(d / "frames.csv", index=False)
    run_out = tmp_path / "run"
    r = vifusion("run", "--drive", d, "--out", run_out, "--workers", 1, "--no-report", "--quiet")
    assert r.returncode == 0, r.stderr
    common = ("vision", "--video", d / "video.mp4", "--frames", d / "frames.csv", "--config", d / "config.toml",
              "--workers", 1, "--quiet")
    r = vifusion(*common, "--can", d / "can.blf", "--out", tmp_path / "with_can.csv")
    assert r.returncode == 0, r.stderr
    assert "map off" not in r.stdout
    ran = pd.read_csv(run_out / "vision.csv")
    alone = pd.read_csv(tmp_path / "with_can.csv")
    pd.testing.assert_frame_equal(alone.drop(columns="estimator_ms"), ran.drop(columns="estimator_ms"))   # all but the timing
    assert (ran["road_twist_bank_change_deg"] != 0).sum() >= 40
    r = vifusion(*common, "--out", tmp_path / "without.csv")
    assert r.returncode == 0, r.stderr
    assert "road-twist map off (no wheel speed: --can LOG)" in r.stdout
    assert (pd.read_csv(tmp_path / "without.csv")["road_twist_bank_change_deg"] != 0).sum() == 0


def test_vision_command_can_log_without_the_wheel_speed(copy, tmp_path):
    """A ``--can`` log whose wheel-speed signal never appears: one line naming the log."""
    cfg = copy / "config.toml"
    text = cfg.read_text()
    speed = next(line for line in text.splitlines() if line.startswith("speed ="))
    cfg.write_text(text.replace(speed, speed.replace(speed.split('"')[1], speed.split('"')[1].split(".")[0] + ".NoSuch")))
    r = vifusion("vision", "--video", next(copy.glob("video.*")), "--frames", copy / "frames.csv", "--config", cfg,
                 "--can", next(copy.glob("can.*")), "--out", tmp_path / "v.csv", "--quiet")
    one_line_error(r)
    assert not (tmp_path / "v.csv").exists()
    # not mapped at all: said so (it read "mapped as ?")
    cfg.write_text(text.replace(speed + "\n", ""))
    r = vifusion("vision", "--video", next(copy.glob("video.*")), "--frames", copy / "frames.csv", "--config", cfg,
                 "--can", next(copy.glob("can.*")), "--out", tmp_path / "v.csv", "--quiet")
    one_line_error(r, "not mapped in [can] signals")
    # a log cut in half: the frames after its end get no wheel speed, and the command says so
    # as vifusion run does (it said nothing, a review); not as frames outside the log's clock
    # (which a later review found them blamed on)
    cfg.write_text(text)
    log = next(copy.glob("can.*"))
    data = log.read_bytes()
    log.write_bytes(data[:len(data) // 2])
    r = vifusion("vision", "--video", next(copy.glob("video.*")), "--frames", copy / "frames.csv", "--config", cfg,
                 "--can", log, "--out", tmp_path / "v.csv", "--quiet")
    assert r.returncode == 0, r.stderr
    assert "log incomplete" in r.stderr and "fall outside the CAN log" not in r.stderr, r.stderr


def test_out_folder_with_other_files_is_left_alone(tmp_path):
    """--out naming a folder that holds someone's files: a one-line error, nothing deleted; a
    file as --out likewise (a review found both: the folder was emptied, the file a traceback)."""
    out = tmp_path / "thesis"
    out.mkdir()
    (out / "chapter1.tex").write_text("x")
    r = vifusion("run", "--out", out, "--quiet")
    assert r.returncode == 2 and r.stderr.startswith("error: ") and "chapter1.tex" in r.stderr, r.stderr
    assert (out / "chapter1.tex").read_text() == "x" and not (tmp_path / "thesis.partial").exists()
    f = tmp_path / "f"
    f.write_text("x")
    r = vifusion("run", "--out", f, "--quiet")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "is a file" in r.stderr, r.stderr
    # the operating system's refusals in words ("Not a directory", "File exists" before)
    one_line_error(vifusion("campaign", SAMPLE_DRIVE, "--out", f, "--quiet"), f"{f}: exists already")
    one_line_error(vifusion("simulate", ROOT / "configs" / "scenarios" / "test" / "tiny_banked_curve.toml",
                            "--out", f / "drive", "--quiet"), "a file is in the way where a folder is needed")


def test_a_users_files_in_the_report_folder_or_the_partial_folder_are_left_alone(tmp_path):
    """--out's check looked at its top level only: a file of the user's in ``OUT/report/`` went
    with the replaced folder, and so did an ``OUT.partial`` folder of theirs, which the run takes
    for its own temporary folder (a review). Both are refused now, nothing deleted; a folder an
    earlier run wrote (an interrupted write's ``NAME.partial`` included) is still replaced."""
    out = tmp_path / "res"
    (out / "report").mkdir(parents=True)
    (out / "report" / "thesis.docx").write_text("x")
    one_line_error(vifusion("run", "--out", out, "--quiet", "--no-report"), "report/thesis.docx")
    assert (out / "report" / "thesis.docx").read_text() == "x"
    (out / "report" / "thesis.docx").unlink()
    (out / "report" / "summary.json.partial").write_text("{")       # a run cut short
    partial = tmp_path / "res.partial"
    partial.mkdir()
    (partial / "notes.txt").write_text("keep")
    one_line_error(vifusion("run", "--out", out, "--quiet", "--no-report"), "notes.txt")
    assert (partial / "notes.txt").read_text() == "keep"
    (partial / "notes.txt").unlink()
    r = vifusion("run", "--out", out, "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (out / "report").iterdir()) == ["summary.json"] and not partial.exists()


def test_a_drive_of_one_frame_runs(copy, tmp_path):
    """frames.csv listing one frame inside the CAN log's span: the run said "no overlap between
    the video's frame times (5.000 .. 5.000 s ...)" (a review); a single time inside the other's
    span overlaps it. The run goes through, its time line without a share of a duration."""
    frames = pd.read_csv(copy / "frames.csv")
    frames.iloc[[len(frames) // 2]].to_csv(copy / "frames.csv", index=False, float_format="%.9f")
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out", "--no-report", "--workers", "1", "--quiet")
    assert r.returncode == 0, r.stderr
    assert len(pd.read_csv(tmp_path / "out" / "vision.csv")) == 1 and "one frame" in r.stdout


def test_frame_times_that_disagree_with_their_numbers_are_said(copy, tmp_path):
    """frames.csv with half a second between two consecutive 30 fps frames (a logger's clock
    jump), or every frame 1 ns apart: both were fused at those times without a word (a
    review). A warning now names the interval, or the median period against the video's rate;
    the drive's own frames.csv says nothing (checked by every run test's clean stderr)."""
    frames = pd.read_csv(copy / "frames.csv")
    k = len(frames) // 2
    jumped = frames.assign(t_s=frames["t_s"] + np.where(np.arange(len(frames)) >= k, 0.5, 0.0))
    jumped.to_csv(copy / "frames.csv", index=False, float_format="%.9f")
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "a", "--no-report", "--workers", "1", "--quiet")
    assert r.returncode == 0, r.stderr
    assert f"1 of {len(frames) - 1} frame intervals are off the median period" in r.stderr, r.stderr
    assert f"frames {int(frames['frame'][k - 1])} to {int(frames['frame'][k])}" in r.stderr, r.stderr
    tiny = frames.assign(t_s=frames["t_s"].iloc[k] + 1e-9 * np.arange(len(frames)))
    tiny.to_csv(copy / "frames.csv", index=False, float_format="%.12f")
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "b", "--no-report", "--workers", "1", "--quiet")
    assert r.returncode == 0 and "is not the video's" in r.stderr, r.stderr


def test_a_wheel_speed_without_noise_is_a_config_error():
    """``speed_noise_m_s = 0`` with ``longitudinal_jerk_m_s3 = 0`` divided by zero in the speed
    update (a review's traceback): a measurement's noise may not be 0."""
    from fusion.errors import ConfigError
    from fusion.options import fusion_options_from_table

    with pytest.raises(ConfigError, match="speed_noise_m_s"):
        fusion_options_from_table({"speed_noise_m_s": 0.0, "longitudinal_jerk_m_s3": 0.0})
    opts, _ = fusion_options_from_table({"speed_noise_m_s": 1e-3, "longitudinal_jerk_m_s3": 0.0})
    assert opts.noise.speed_meas_m_s == 1e-3


@pytest.mark.parametrize("change, words", [
    (("[video]", "[foo]\nbar = 1\n[video]"), "[foo] is not a known table"),
    (("[fusion]", "[fusoin]\n[fusion]"), "[fusoin] is not a known table (did you mean fusion?"),
    (("fx =", "fxx ="), "[camera] fxx is not a known key (did you mean fx?"),
    (("center_line", "centre_line"), "[road] centre_line is not a known key (did you mean center_line?"),
    (("start_s", "start"), "[video] start is not a known key (did you mean start_s?"),
    (("gyro_noise_deg_s", "gyro_noise_degs"), "[fusion] gyro_noise_degs is not a known key (did you mean gyro_noise_deg_s?"),
    (("[fusion]", "[vision]\nroad_twst = true\n[fusion]"), "[vision] road_twst is not a known key (did you mean road_twist?"),
    (("height_m = 1.1", 'height_m = "1.1"'), "[mount] height_m must be a number, got '1.1'"),
])
def test_every_command_checks_the_whole_config(tmp_path, capsys, change, words):
    """A key or table vifusion does not know, or a value of the wrong kind, is the same one-line
    error (exit 2, with run's did-you-mean) from every command that reads the config: `can` read
    only [imu] and [can], `vision` not [fusion], and both took these without a word (a review)."""
    from fusion.cli import main

    shutil.copy(SAMPLE_DRIVE / "vifusion_imu.dbc", tmp_path)
    cfg = tmp_path / "config.toml"
    cfg.write_text((SAMPLE_DRIVE / "config.toml").read_text().replace(*change, 1))
    video, frames, log = SAMPLE_DRIVE / "video.mp4", SAMPLE_DRIVE / "frames.csv", SAMPLE_DRIVE / "can.blf"
    said = []
    for args in (["run", "--video", video, "--frames", frames, "--can", log, "--config", cfg, "--out", tmp_path / "r"],
                 ["vision", "--video", video, "--frames", frames, "--config", cfg, "--out", tmp_path / "v.csv"],
                 ["can", log, "--config", cfg, "--out", tmp_path / "imu.csv"]):
        assert main([*map(str, args), "--quiet"]) == 2, args
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and words in err[0], (args[0], err)
        said.append(err[0])
    assert len(set(said)) == 1, said
    assert not list(tmp_path.glob("r*")) and not (tmp_path / "v.csv").exists() and not (tmp_path / "imu.csv").exists()


def test_a_table_given_as_a_value_is_a_config_error(tmp_path):
    from fusion.config import load_config
    from fusion.errors import ConfigError

    p = tmp_path / "config.toml"
    p.write_text('fusion = 3\n[camera]\nwidth = 640\n[mount]\nheight_m = 1.1\n')
    with pytest.raises(ConfigError, match="fusion must be a table"):
        load_config(p)


def test_a_camera_config_that_does_not_fit_the_video_is_one_line(copy, tmp_path):
    """A config for another camera size: no frame of the video can give lanes. It was a
    warning ("vision valid on 0 of 30 frames") after the whole video, with outputs that looked
    complete (a review); a video has one size, known from its first frame, so it is now an error
    before any frame is estimated, naming both sizes and the keys to set, from `vifusion vision`
    alike, and nothing is written."""
    cfg = copy / "config.toml"
    text = cfg.read_text()
    w = next(line for line in text.splitlines() if line.startswith("width ="))
    cfg.write_text(text.replace(w, "width = 1280", 1))
    h = next(line for line in text.splitlines() if line.startswith("height =")).split("=")[1].strip()
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out", "--quiet", "--no-report")
    words = ("video.mp4: the video's frames are 320x180", f"[camera] width x height is 1280x{h}",
             "set [camera] width = 320, height = 180")
    one_line_error(r, *words)
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.partial").exists()
    r = vifusion("vision", "--video", copy / "video.mp4", "--frames", copy / "frames.csv", "--config", cfg,
                 "--out", tmp_path / "v.csv", "--quiet")
    one_line_error(r, *words)
    assert not (tmp_path / "v.csv").exists()


def test_bad_arguments_and_an_unreadable_video_are_one_line(copy, tmp_path):
    """argparse's usage block and FFmpeg's own line ("moov atom not found") used to come before
    the error."""
    one_line_error(vifusion("run", "--workers", "0"), "--workers", "vifusion run --help")
    one_line_error(vifusion("can"), "required")
    one_line_error(vifusion("run", "--drive", copy, "--out", tmp_path / "o", "--debug-video", tmp_path / "d.txt"),
                   "d.txt", ".mp4")
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.partial").exists()
    video = copy / "video.mp4"
    video.write_bytes(video.read_bytes()[:5000])
    one_line_error(vifusion("run", "--drive", copy, "--out", tmp_path / "out"), "video.mp4")
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.partial").exists()   # failed after starting


def test_smooth_and_time_offset_estimate_through_the_command(drive, tmp_path):
    """--smooth and --estimate-time-offset end to end: the summary says the run was smoothed and
    reports the offset estimate (or why none: the tiny drive has lanes on 11 of 30 frames), and
    the smoothed table differs from the forward one."""
    fwd, sm = tmp_path / "fwd", tmp_path / "sm"
    assert vifusion("run", "--drive", drive, "--out", fwd, "--quiet").returncode == 0
    r = vifusion("run", "--drive", drive, "--out", sm, "--quiet", "--smooth", "--estimate-time-offset")
    assert r.returncode == 0, r.stderr
    summary = json.loads((sm / "report" / "summary.json").read_text())
    assert summary["smoothed"] is True
    offset = summary["time_offset"]
    # strict JSON: an offset that could not be estimated is null, with the reason
    assert offset is not None and ("offset_s" in offset and (offset["offset_s"] is not None or offset["reason"]))
    a, b = pd.read_csv(fwd / "fused.csv"), pd.read_csv(sm / "fused.csv")
    assert len(a) == len(b) and not np.allclose(a["roll_deg"], b["roll_deg"])
    html = (sm / "report" / "report.html").read_text()
    assert "RTS smoother" in html


def test_a_gap_in_the_can_log_is_a_warning(copy, tmp_path):
    """0.3 s of the log gone (the logger dropped frames): the run goes on, says where and how
    long in its warnings, in words."""
    lines = (copy / "can.asc").read_text().splitlines(keepends=True)

    def t_of(line):
        try:
            return float(line.split()[0])
        except (ValueError, IndexError):
            return None
    kept = [ln for ln in lines if not (t_of(ln) is not None and 1.0 <= t_of(ln) < 1.3)]
    (copy / "can.asc").write_text("".join(kept))
    out = tmp_path / "out"
    r = vifusion("run", "--drive", copy, "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    gaps = [w for w in json.loads((out / "report" / "summary.json").read_text())["warnings"] if "CAN gap" in w]
    assert gaps and all(" for 0.3" in w and "from " in w and "[" not in w for w in gaps), gaps


def test_a_debug_video_inside_out_is_refused(drive, tmp_path):
    """The run replaces --out at its end: a debug video written into it would vanish (a review
    found it deleted without a word on a second run)."""
    out = tmp_path / "out"
    assert vifusion("run", "--drive", drive, "--out", out, "--quiet", "--no-report").returncode == 0
    one_line_error(vifusion("run", "--drive", drive, "--out", out, "--debug-video", out / "dbg.mp4"), "inside --out")
    assert (out / "fused.csv").is_file()
    # beside it: the line of what was written names it (it did not, as `vifusion vision`'s does, a review)
    r = vifusion("run", "--drive", drive, "--out", out, "--debug-video", tmp_path / "dbg.mp4", "--quiet", "--no-report")
    assert r.returncode == 0 and f"debug video {tmp_path / 'dbg.mp4'}" in r.stdout.splitlines()[0], r.stdout


def test_campaign_refuses_before_it_replaces_anything(drive, tmp_path):
    """What a review found a campaign deleting or mislabelling (each refused with one line, exit
    2, before anything in --out is touched): a --calibration that is not one (the earlier
    campaign's drive folders were deleted first, and every drive then 'skipped' for it); a
    campaign.csv or campaign.parquet in --out that no campaign wrote (deleted, a folder of that
    name with it); a drive named X.partial beside one named X (X's run writes into X.partial
    first: the first drive's output was lost); the root as --out. A run's warnings on stderr
    name their drive."""
    out = tmp_path / "camp"
    r = vifusion("campaign", drive, "--out", out, "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    assert "warning: drive: vision valid on 11 of 30 frames" in r.stderr, r.stderr
    before = sorted(str(p.relative_to(out)) for p in out.rglob("*"))
    bogus = tmp_path / "bogus.toml"
    bogus.write_text("x\n")
    one_line_error(vifusion("campaign", drive, "--out", out, "--calibration", bogus), "bogus.toml")
    one_line_error(vifusion("campaign", drive, "--out", out, "--calibration", tmp_path / "none.toml"), "none.toml")
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == before
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "campaign.csv").write_text("my notes\n")
    one_line_error(vifusion("campaign", drive, "--out", mine), "campaign.csv", "not a campaign's table")
    (mine / "campaign.csv").unlink()
    (mine / "campaign.parquet").mkdir()
    (mine / "campaign.parquet" / "keep.txt").write_text("keep")
    one_line_error(vifusion("campaign", drive, "--out", mine), "campaign.parquet", "not a campaign's table")
    assert (mine / "campaign.parquet" / "keep.txt").is_file() and not (mine / "drive").exists()
    twin = tmp_path / "e.partial"
    shutil.copytree(drive, twin)
    (tmp_path / "e").symlink_to(drive, target_is_directory=True)
    one_line_error(vifusion("campaign", twin, tmp_path / "e", "--out", tmp_path / "c2"), "e.partial")
    one_line_error(vifusion("campaign", drive, "--out", "/"), "root")
    assert not (tmp_path / "c2").exists() and not Path("/drive").exists()


def test_campaign_interrupted_after_a_drive_finished_says_it_ran(drive, tmp_path, monkeypatch, capsys):
    """Ctrl-C after a drive's folder is in place but before its figures are read: the row says
    the drive ran (it said 'not run: interrupted' beside a complete folder, a review). A drive
    interrupted while it ran has the calibration it started from in its row (it was empty)."""
    from fusion import cli
    from fusion.calibration import write_calibration
    from fusion.cli import campaign

    second = tmp_path / "second"
    shutil.copytree(drive, second)
    real, calls = campaign._drive_row, []

    def interrupted_on_the_second(fused, summary):
        calls.append(summary)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(fused, summary)

    monkeypatch.setattr(campaign, "_drive_row", interrupted_on_the_second)
    out = tmp_path / "camp"
    # started from a calibration: the tiny drive's own is not carried (its vision is poor), so
    # each drive starts from this one
    cal = tmp_path / "cal.toml"
    write_calibration({"gyro_bias_deg_s": [0.2, 0.15, -0.3], "gyro_bias_sigma_deg_s": [0.05, 0.05, 0.05],
                       "accel_bias_m_s2": [0.0, 0.0, 0.0], "accel_bias_sigma_m_s2": [0.05, 0.05, 0.05]}, cal)
    assert cli.main(["campaign", str(drive), str(second), str(drive.parent / "third"), "--out", str(out), "--quiet",
                     "--no-report", "--calibration", str(cal)]) == 130
    table = pd.read_csv(out / "campaign.csv")
    assert list(table["status"]) == ["ok", "ok (interrupted before its figures were read)", "not run: interrupted"]
    assert (out / "second" / "fused.csv").is_file()
    assert table["calibration_from"].fillna("").tolist()[1:] == [str(cal), ""]
    # interrupted while the second drive ran: its row has the calibration it started from
    calls.clear()
    monkeypatch.setattr(campaign, "_drive_row", real)
    from fusion.cli import run as run_cmd
    started = run_cmd.run

    def interrupted_in_the_second(args):
        if args.drive == second:
            raise KeyboardInterrupt
        return started(args)

    monkeypatch.setattr(run_cmd, "run", interrupted_in_the_second)
    assert cli.main(["campaign", str(drive), str(second), "--out", str(out), "--quiet", "--no-report",
                     "--calibration", str(cal)]) == 130
    table = pd.read_csv(out / "campaign.csv")
    assert list(table["status"]) == ["ok", "not run: interrupted"]
    assert table["calibration_from"].iloc[1] == str(cal)


def test_frames_after_a_log_that_broke_off_are_not_blamed_on_the_clock():
    """Frames after the end of a CAN log that broke off are that log's warning's ("log
    incomplete"), not a question of frames.csv's clock, which a review found them blamed on;
    frames before a log's start still are."""
    from fusion.drive import frames_outside_warning

    frame_t, imu_t = np.arange(30) / 30.0, np.arange(0.0, 0.5, 0.01)
    assert "are frames.csv's times in seconds" in frames_outside_warning(frame_t, imu_t, "frames.csv")
    assert frames_outside_warning(frame_t, imu_t, "frames.csv", log_complete=False) is None
    assert "15 before" in frames_outside_warning(frame_t - 0.5, imu_t + 0.0, "frames.csv", log_complete=False)


def test_the_contracts_command_line_with_a_drives_files(drive, tmp_path):
    """INTERFACE.md's command line, file by file: a config without `[can] dbc` runs with `--dbc`
    (it was refused for the missing key, a review), and a config without it and no `--dbc` is
    one line naming both; the report is against the drive's truth.csv beside the video, as with
    --drive (it was left out, a review), and the run says which file it took."""
    cfg = tmp_path / "config.toml"
    cfg.write_text("".join(line for line in (drive / "config.toml").read_text().splitlines(keepends=True)
                           if not line.startswith("dbc")))
    common = ["run", "--video", drive / "video.mp4", "--frames", drive / "frames.csv", "--can",
              next(drive.glob("can.*")), "--config", cfg, "--quiet", "--no-report"]
    r = vifusion(*common, "--dbc", drive / "vifusion_imu.dbc", "--out", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert f"truth: {drive / 'truth.csv'} (the drive's, beside the video" in r.stdout, r.stdout
    summary = json.loads((tmp_path / "out" / "report" / "summary.json").read_text())
    # (the 2 s drive is too short to score: said only when there is a truth)
    assert any("no RMSE against truth: the drive has under 1 s" in w for w in summary["warnings"]), summary
    one_line_error(vifusion(*common, "--out", tmp_path / "none"), "[can] dbc is missing", "--dbc")
    assert not (tmp_path / "none").exists() and not (tmp_path / "none.partial").exists()


def test_campaign_drives_of_one_name_in_two_folders_are_two_drives(drive, tmp_path):
    """A campaign's usual layout, ``day1/drive`` and ``day2/drive`` (links here, which keep
    their own names): two drives, written to ``OUT/day1/drive`` and ``OUT/day2/drive`` (they
    were refused as two drives of one name, a review); the same folder given twice is refused
    before anything is written."""
    for day in ("day1", "day2"):
        (tmp_path / day).mkdir()
        (tmp_path / day / "drive").symlink_to(drive, target_is_directory=True)
    out = tmp_path / "camp"
    r = vifusion("campaign", tmp_path / "day1" / "drive", tmp_path / "day2" / "drive", "--out", out, "--quiet",
                 "--no-report")
    assert r.returncode == 0, r.stderr
    assert (out / "day1" / "drive" / "fused.csv").is_file() and (out / "day2" / "drive" / "fused.csv").is_file()
    table = pd.read_csv(out / "campaign.csv")
    assert list(table["status"]) == ["ok", "ok"]
    one_line_error(vifusion("campaign", tmp_path / "day1" / "drive", tmp_path / "day1" / ".." / "day1" / "drive",
                            "--out", tmp_path / "twice", "--quiet", "--no-report"), "given twice")
    assert not (tmp_path / "twice").exists()


def test_outputs_a_review_found_wanting(drive, tmp_path):
    """A truth file without the contract's angle columns is an error (it was accepted and the
    RMSE table came out empty); summary.json is strict JSON (NaN was written bare); `vifusion
    vision --out x.parquet` writes Parquet (it wrote CSV text into it); `--debug` before the
    command shows the traceback as after it."""
    out = tmp_path / "o"
    one_line_error(vifusion("run", "--video", drive / "video.mp4", "--frames", drive / "frames.csv",
                            "--can", next(drive.glob("can.*")), "--config", drive / "config.toml",
                            "--truth", drive / "imu_truth.csv", "--out", out), "not a truth table", "roll_deg")
    r = vifusion("run", "--drive", drive, "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    json.loads((out / "report" / "summary.json").read_text(), parse_constant=lambda c: pytest.fail(f"bare {c}"))
    pq = tmp_path / "v.parquet"
    r = vifusion("vision", "--video", drive / "video.mp4", "--frames", drive / "frames.csv", "--config", drive / "config.toml",
                 "--out", pq, "--quiet")
    assert r.returncode == 0, r.stderr
    assert len(pd.read_parquet(pq)) == len(pd.read_csv(out / "vision.csv"))
    r = vifusion("--debug", "run", "--drive", tmp_path / "missing", "--out", tmp_path / "x")
    assert r.returncode != 0 and "Traceback" in r.stderr


def test_the_plain_bank_column_has_no_value_without_vision(drive, tmp_path):
    """fused.csv's bank_plain_deg is the per-frame IMU-minus-vision bank at the IMU samples: NaN
    where the vision has no valid frame within 0.1 s either side (it was interpolated across
    lane losses and held before the first frame), equal to the frame's value at a frame."""
    out = tmp_path / "o"
    assert vifusion("run", "--drive", drive, "--out", out, "--quiet", "--no-report").returncode == 0
    fused, vision = pd.read_csv(out / "fused.csv"), pd.read_csv(out / "vision.csv")
    tv = vision.loc[vision["valid"].astype(bool), "t_s"].to_numpy()
    t = fused["t_s"].to_numpy()
    k = np.clip(np.searchsorted(tv, t), 1, len(tv) - 1)
    lost = (t < tv[0]) | (t > tv[-1]) | ((tv[k] - tv[k - 1] > 0.1) & ~np.isin(t, tv))
    assert lost.any() and (~lost).any()          # the tiny drive has lanes on some frames only
    assert fused.loc[lost, "bank_plain_deg"].isna().all()
    assert fused.loc[~lost, "bank_plain_deg"].notna().all()


def test_time_offset_estimate_corrects_the_configured_offset(tmp_path):
    """The bundled sample drive with its frame times 200 ms late on the CAN clock. The estimate
    is of the correction to the configured offset: configured 0, it finds about -200 ms and
    applies it (its error on this drive: 14-17 ms, sigma about 46 ms, fusion.timing); configured
    -200 ms, the correction is not significant and the configured offset stays (the estimate was
    added to the configured offset as if it were a correction while it was the whole offset: a
    correct configuration went to -400 ms)."""
    from fusion.drive import SAMPLE_DRIVE

    d = tmp_path / "drive"
    shutil.copytree(SAMPLE_DRIVE, d)
    frames = pd.read_csv(d / "frames.csv", dtype={"t_s": str})
    frames["t_s"] = [f"{float(t) + 0.2:.9f}" for t in frames["t_s"]]
    frames.to_csv(d / "frames.csv", index=False)
    base = (d / "config.toml").read_text()
    results = {}
    for configured in (0.0, -0.2):
        (d / "config.toml").write_text(base.replace("[fusion]\n", f"[fusion]\ncamera_time_offset_s = {configured}\n"))
        out = tmp_path / f"out{configured}"
        r = vifusion("run", "--drive", d, "--out", out, "--quiet", "--estimate-time-offset")
        assert r.returncode == 0, r.stderr
        results[configured] = json.loads((out / "report" / "summary.json").read_text())
        results[configured]["stdout"] = r.stdout
    first, second = results[0.0], results[-0.2]
    assert first["time_offset"]["applied"] is True
    assert first["camera_time_offset_s"] == pytest.approx(-0.2, abs=0.05)
    assert second["time_offset"]["applied"] is False and second["camera_time_offset_s"] == pytest.approx(-0.2, abs=1e-9)
    assert abs(second["time_offset"]["offset_s"]) < 2 * second["time_offset"]["sigma_s"]
    assert first["time_offset"]["reason"] is None       # estimated: no reason (it was "")
    # a correct configuration confirmed is no warning (it was one, a review), the line says it
    assert not any("time offset" in w for w in second["warnings"]) and "not applied (within 2 sigma)" in second["stdout"]


@pytest.mark.parametrize("fault, words", [
    ("axes", "z axis does not point up"),
    ("unit", "median of 1.0"),
])
def test_an_imu_setup_that_cannot_be_right_is_a_warning(copy, tmp_path, fault, words):
    """The IMU mounted upside down in the config (axes x, y, z for an FRD unit: the vehicle's z
    reads -1 g) or its accelerometer's DBC unit m/s^2 for values in g (1 m/s^2 for gravity): the
    run goes on, but says why its world roll and bank are wrong. A review found both silent
    (exit 0; with the axes flipped the bank came out -171 deg with a sigma of 0.8; with the
    unit, every gravity update refused)."""
    if fault == "axes":
        cfg = copy / "config.toml"
        text = cfg.read_text()
        axes = next(line for line in text.splitlines() if line.startswith("axes ="))
        cfg.write_text(text.replace(axes, 'axes = ["x", "y", "z"]', 1))
    else:
        dbc = next(copy.glob("*.dbc"))
        text = dbc.read_text()
        dbc.write_text("\n".join(line.replace('"g"', '"m/s^2"') if " SG_ Acc" in line else line
                                 for line in text.splitlines()))
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out", "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "out" / "report" / "summary.json").read_text())
    assert any(words in w for w in summary["warnings"]), summary["warnings"]
    assert words in r.stderr


def test_an_output_path_the_system_refuses_is_one_line(drive, tmp_path):
    """A file name longer than the file system takes (255 bytes): one line naming it, exit
    status 2. A review found it, a full disk and a read-only file system giving tracebacks:
    only some kinds of operating-system error were taken as the user's."""
    r = vifusion("run", "--drive", drive, "--out", tmp_path / ("a" * 300), "--quiet", "--no-report")
    one_line_error(r, "file name too long")


def test_an_output_that_is_an_input_is_refused(copy, tmp_path):
    """An output path naming one of the command's inputs is refused before any work, the
    input untouched (a review: ``vifusion can X.csv --out X.csv`` replaced the recording with
    its decode; ``vision --out frames.csv`` the frame list; ``--debug-video`` equal to
    ``--video`` left the video a 60-frame debug video); ``run --out /`` is one line (it was a
    traceback)."""
    import can as pycan

    log = tmp_path / "log.csv"          # python-can's CSV log format
    with pycan.Logger(log) as w:
        for m in list(pycan.LogReader(copy / "can.asc"))[:50]:
            w.on_message_received(m)
    before = {p: p.read_bytes() for p in (log, copy / "frames.csv", copy / "video.mp4")}
    one_line_error(vifusion("can", log, "--config", copy / "config.toml", "--out", log), "is an input")
    common = ("--video", copy / "video.mp4", "--config", copy / "config.toml")
    one_line_error(vifusion("vision", *common, "--frames", copy / "frames.csv", "--out", copy / "frames.csv"),
                   "is an input")
    one_line_error(vifusion("vision", *common, "--out", tmp_path / "v.csv", "--debug-video", copy / "video.mp4"),
                   "is an input")
    one_line_error(vifusion("run", "--drive", copy, "--out", tmp_path / "o", "--debug-video", copy / "video.mp4"),
                   "is an input")
    assert all(p.read_bytes() == b for p, b in before.items())
    one_line_error(vifusion("run", "--drive", copy, "--out", "/"), "the root is not an output folder")


def test_a_wheel_speed_that_starts_late(tmp_path):
    """The bundled drive with its wheel speed missing for the first 6 s (of 12). Before it the
    filter took the speed as 0: the road stood still while the gyros turned the vehicle, and
    the vision's yaw pulled the world roll 18 deg off with a sigma of 2.3 deg; from the first
    speed on every gravity update was refused and the bank ended 18 deg off, with only a
    warning blaming the IMU's axes (a review). Now the road turns with the vehicle until the
    speed comes, the first speed levels the world roll again from the accelerometer, and the
    run says the speed started late. Bar: the bank's RMS error over the last 3 s under 1 deg
    (measured 0.72, still converging from the accelerometer's level 3 s after the speed came;
    the run with the speed all along 0.09; before the fix 18)."""
    import can as pycan

    d = tmp_path / "late"
    shutil.copytree(SAMPLE_DRIVE, d)
    log = next(d.glob("can.*"))
    msgs = list(pycan.LogReader(log))
    t0 = msgs[0].timestamp
    log.unlink()
    with pycan.Logger(d / "can.blf") as w:
        for m in msgs:
            if not (m.arbitration_id == 0x122 and m.timestamp < t0 + 6.0):
                w.on_message_received(m)
    r = vifusion("run", "--drive", d, "--out", tmp_path / "out", "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    assert "no wheel speed for the first 6.0 s" in r.stderr and "gravity updates refused" not in r.stderr, r.stderr
    f = pd.read_csv(tmp_path / "out" / "fused.csv")
    truth = pd.read_csv(d / "truth.csv")
    end = f[f["t_s"] > f["t_s"].iloc[-1] - 3.0]
    err = end["bank_deg"] - np.interp(end["t_s"], truth["t_s"], truth["bank_deg"])
    assert np.sqrt(np.mean(err**2)) < 1.0, np.sqrt(np.mean(err**2))


def test_a_truth_that_does_not_cover_the_scored_drive_is_said(tmp_path):
    """A truth cut to its first 0.33 s, or without a bank after 1 s: one warning saying so and
    no RMSE or NEES computed from nothing. Before, numpy's 'Mean of empty slice' warnings went
    to stderr, summary.json held nulls without a word and the page said 'nan % of samples'
    (a review)."""
    truth = pd.read_csv(SAMPLE_DRIVE / "truth.csv")
    truth.iloc[:33].to_csv(tmp_path / "short.csv", index=False)
    nobank = truth.copy()
    nobank.loc[nobank["t_s"] > nobank["t_s"].iloc[0] + 1.0, "bank_deg"] = np.nan
    nobank.to_csv(tmp_path / "nobank.csv", index=False)
    for name, said in (("short.csv", ["no RMSE against truth: it has values for 0.0 s"]),
                       ("nobank.csv", ["no NEES against the truth", "no RMSE of bank against truth"])):
        out = tmp_path / name.replace(".csv", "")
        r = vifusion("run", "--truth", tmp_path / name, "--out", out, "--quiet", "--no-report")
        assert r.returncode == 0 and "RuntimeWarning" not in r.stderr, r.stderr
        summary = json.loads((out / "report" / "summary.json").read_text())
        for words in said:
            assert any(words in w for w in summary["warnings"]), summary["warnings"]
        assert summary["consistency"] is None


def _video_as_pictures(copy: Path) -> Path:
    """The drive's video as a folder of PNGs (its ``video.mp4`` removed)."""
    import cv2

    from vision.video import FrameSource

    folder = copy / "video"
    folder.mkdir()
    for k, img in enumerate(FrameSource(copy / "video.mp4")):
        cv2.imwrite(str(folder / f"{k:06d}.png"), img)
    (copy / "video.mp4").unlink()
    return folder


@pytest.mark.parametrize("bad", ["not a picture", "cut", "dangling"])
def test_an_unreadable_picture_is_skipped_and_said(copy, tmp_path, bad):
    """The drive's video as a folder of pictures, the tenth unreadable: text, a PNG cut in half
    (libpng printed its own "Read Error" line, a review) or a link to nothing (OpenCV's
    "findDecoder" warning). Its frame is skipped: an invalid row with the reason, a warning
    naming the picture, nothing raw on stderr, the debug video written whole. It had ended the
    run with one line and nothing written (a review: after 12 s of a 4000-picture folder)."""
    folder = _video_as_pictures(copy)
    tenth = folder / "000009.png"
    if bad == "not a picture":
        tenth.write_bytes(b"not a picture")
    elif bad == "cut":
        tenth.write_bytes(tenth.read_bytes()[: tenth.stat().st_size // 2])
    else:
        tenth.unlink()
        tenth.symlink_to(folder / "nowhere.png")
    dbg = tmp_path / "debug.mp4"
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out", "--debug-video", dbg, "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    assert all(line.startswith("warning: ") for line in r.stderr.splitlines()), r.stderr
    summary = json.loads((tmp_path / "out" / "report" / "summary.json").read_text())
    assert any("000009.png" in w and "could not be read" in w for w in summary["warnings"]), summary["warnings"]
    v = pd.read_csv(tmp_path / "out" / "vision.csv").set_index("frame")
    assert v.loc[9, "valid"] == 0 and v.loc[9, "reason"].startswith("unreadable picture")
    assert dbg.exists()


def test_no_debug_video_is_left_when_no_picture_can_be_read(copy, tmp_path):
    """Every picture unreadable: one line, before any frame, and no debug video under its name."""
    folder = _video_as_pictures(copy)
    for f in folder.iterdir():
        f.write_bytes(b"not a picture")
    dbg = tmp_path / "debug.mp4"
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out", "--debug-video", dbg, "--quiet", "--no-report")
    one_line_error(r, "none of the", "000000.png")
    assert not dbg.exists() and not list(tmp_path.glob("debug*")), list(tmp_path.iterdir())


def test_can_frames_the_decoder_did_not_use_are_warnings(copy, tmp_path):
    """Five IMU_RATE frames cut to 4 bytes: the run says how many frames of which message it
    did not use (a review found them only in ``vifusion can``'s report)."""
    log = copy / "can.asc"
    lines, cut = log.read_text().splitlines(), 0
    for k, line in enumerate(lines):
        f = line.split()
        if cut < 5 and len(f) == 14 and f[2] == "174" and f[5] == "8":
            lines[k] = " ".join(f[:5] + ["4"] + f[6:10])
            cut += 1
    log.write_text("\n".join(lines) + "\n")
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out", "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "out" / "report" / "summary.json").read_text())
    assert any("IMU_RATE" in w and "5 frames not used (wrong length 5" in w for w in summary["warnings"]), summary["warnings"]


def test_frames_mostly_outside_the_can_log_are_a_warning(copy, tmp_path):
    """frames.csv shifted 1.5 s later than the 2 s CAN log: the frames past the log's end are
    not used, and the run says how many and asks about the clock (a review found only 'vision
    valid on 11 of 30' said)."""
    frames = pd.read_csv(copy / "frames.csv")
    frames["t_s"] += 1.5
    frames.to_csv(copy / "frames.csv", index=False)
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out", "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "out" / "report" / "summary.json").read_text())
    assert any("fall outside the CAN log's IMU samples (0 before" in w for w in summary["warnings"]), summary["warnings"]


def test_a_truth_column_without_values_is_not_scored_and_inf_is_an_error(copy, tmp_path):
    """A truth column all NaN (a reference without that angle) is not scored, as a missing
    column is not: no 'bank nan' and no numpy warnings (a review found both). One holding inf
    is a one-line error naming it, and so is a file of the header alone."""
    truth = pd.read_csv(copy / "truth.csv")
    truth["bank_deg"] = float("nan")
    truth.to_csv(copy / "truth.csv", index=False)
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out", "--quiet", "--no-report")
    assert r.returncode == 0 and "Warning" not in r.stderr and "bank nan" not in r.stdout, (r.stdout, r.stderr)
    truth["bank_deg"] = float("inf")
    truth.to_csv(copy / "truth.csv", index=False)
    one_line_error(vifusion("run", "--drive", copy, "--out", tmp_path / "out2"), "truth.csv", "bank_deg holds infinite")
    truth.head(0).to_csv(copy / "truth.csv", index=False)   # the header alone (it said 'not numeric')
    one_line_error(vifusion("run", "--drive", copy, "--out", tmp_path / "out3"), "truth.csv: 0 data rows")


def test_outputs_that_cannot_be_written_are_refused_before_the_work(drive, tmp_path):
    """`vifusion vision --out X.csv` where X.csv is a folder, a campaign drive named
    campaign.csv, and a campaign's --out inside one of its drives: refused at once. A review found both found out after every frame or drive,
    leaving X.csv.partial behind."""
    (tmp_path / "x.csv").mkdir()
    r = vifusion("vision", "--video", drive / "video.mp4", "--config", drive / "config.toml", "--out", tmp_path / "x.csv")
    one_line_error(r, "is a directory")
    assert not list(tmp_path.glob("*.partial"))
    named = tmp_path / "campaign.csv"
    shutil.copytree(drive, named)
    one_line_error(vifusion("campaign", named, "--out", tmp_path / "c"), "campaign's table")
    # the campaign's folder inside a drive's (its outputs would mix with the drive's files)
    one_line_error(vifusion("campaign", drive, "--out", drive / "campaign"), "inside the drive")
    assert not (drive / "campaign").exists()
    # ... or a drive's output folder the drive itself (`campaign runs/d1 --out runs`): it was
    # found out on the drive's turn, after the drives before it had run
    one_line_error(vifusion("campaign", drive, "--out", drive.parent), "would replace the drive")
    assert not (drive.parent / "campaign.csv").exists()


def test_a_reader_that_goes_away_is_no_traceback(drive, tmp_path):
    """`vifusion can LOG ... | head -1`: the reader closes the pipe (here before the first line);
    the command ends without a word on stderr (a review found BrokenPipeError's traceback; as
    an operating-system error it then said 'error: Broken pipe')."""
    p = subprocess.Popen([sys.executable, "-m", "fusion", "can", next(drive.glob("can.*")), "--config",
                          drive / "config.toml", "--out", tmp_path / "imu.parquet"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    p.stdout.close()
    err = p.stderr.read()
    p.wait(timeout=60)
    assert err.strip() == "", err


@pytest.mark.parametrize("case", ["bom", "gz", "empty"])
def test_inputs_a_review_found_worded_badly(copy, tmp_path, case):
    """A config saved with a byte-order mark runs (it said 'Invalid statement at line 1'); a
    drive whose log is gzipped (can.asc.gz) is found, as the log reader reads it (it said 'no
    can.<...> log'); an empty log says so (an empty BLF said 'unpack requires a buffer of 72
    bytes')."""
    import gzip

    log = copy / "can.asc"
    if case == "bom":
        cfg = copy / "config.toml"
        cfg.write_bytes(b"\xef\xbb\xbf" + cfg.read_bytes())
    elif case == "gz":
        (copy / "can.asc.gz").write_bytes(gzip.compress(log.read_bytes()))
        log.unlink()
    else:
        log.unlink()
        (copy / "can.blf").write_bytes(b"")
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out", "--quiet", "--no-report")
    if case == "empty":
        one_line_error(r, "can.blf", "empty")
    else:
        assert r.returncode == 0, r.stderr


def test_unreadable_log_lines_are_said_with_the_first_one(copy, tmp_path):
    """A CAN log with a corrupt frame line mid-file (an ASC line with a decimal comma, which
    python-can's reader passes over without a word): the run goes on, and its warning says how
    many lines were skipped and which was the first, and why."""
    asc = copy / "can.asc"
    lines = asc.read_text().splitlines(keepends=True)
    frames = [i for i, ln in enumerate(lines) if " Rx " in ln]
    victim = frames[len(frames) // 2]
    lines[victim] = lines[victim].replace(".", ",", 1)
    asc.write_text("".join(lines))
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out", "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "out" / "report" / "summary.json").read_text())
    said = [w for w in summary["warnings"] if "unreadable lines skipped" in w]
    assert len(said) == 1 and f"line {victim + 1}: .asc frame line" in said[0] and "decimal comma" in said[0], said


def test_a_lever_arm_in_millimetres_and_a_spaced_header(copy, tmp_path):
    """`[imu] position_m = [0, 0, 500]` (millimetres): a one-line error naming the key (a review
    found 1e300 accepted, every gravity update then refused); `frame, t_s` as a hand-written
    frames.csv header reads (it said 'missing t_s')."""
    frames = copy / "frames.csv"
    frames.write_text(frames.read_text().replace("frame,t_s", "frame, t_s", 1))
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "ok", "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    cfg = copy / "config.toml"
    text = cfg.read_text()
    pos = next(line for line in text.splitlines() if line.startswith("position_m ="))
    cfg.write_text(text.replace(pos, "position_m = [0.0, 0.0, 500.0]", 1))
    one_line_error(vifusion("run", "--drive", copy, "--out", tmp_path / "out"), "position_m", "metres")


@pytest.mark.parametrize("after", ["argparse", "numpy", "fusion.config", "vision.frames", "filterpy"])
def test_ctrl_c_while_the_command_loads_is_one_line(tmp_path, after):
    """Ctrl-C while `vifusion run` loads its modules: `error: interrupted`, exit 130, no
    traceback (a review: an interrupt in the first quarter second printed the imports'; numpy
    and numba loaded before the command could say it). The signal is sent the moment the child
    reports ``after`` imported (``-X importtime``), so each phase of the start-up is hit, not a
    time that a busy machine shifts: the command line's first imports, numpy (the error types'
    modules), the subcommands (the parser), numba (the run), the filter (loaded while the vision
    workers estimate). Left to Python: its own start-up
    and ``runpy`` before the program (about 25 ms here). SIGINT is put back to its default in
    the child: a test run started with it ignored (``nohup ... &``) passes the ignoring on."""
    import signal

    p = subprocess.Popen([sys.executable, "-X", "importtime", "-m", "fusion", "run", "--out", str(tmp_path / "out"),
                          "--quiet"], stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    said = []
    for line in p.stderr:
        if not line.startswith("import time:"):
            said.append(line)
        elif line.rsplit("|", 1)[-1].strip() == after:
            p.send_signal(signal.SIGINT)
            break
    else:
        p.wait()
        pytest.fail(f"{after} was not imported by the run: {''.join(said)[-500:]}")
    said += [line for line in p.stderr if not line.startswith("import time:")]
    assert p.wait(timeout=120) == 130 and "".join(said) == "error: interrupted\n"


def test_the_vision_workers_start_before_the_filter_loads(tmp_path):
    """`vifusion run` forks its vision workers before it loads the filter: filterpy and the
    scipy.stats it imports (0.7-1.1 s of imports by ``-X importtime``, a third of the start-up)
    load while the workers estimate, when the run's process has nothing else to do, not while
    a core stands idle before them (docs/fusion-notes.md, twenty-fifth session). The first
    worker's fork is ``multiprocessing.popen_fork``'s import."""
    p = subprocess.run([sys.executable, "-X", "importtime", "-m", "fusion", "run", "--out", str(tmp_path / "out"),
                        "--quiet", "--no-report", "--workers", "2"], capture_output=True, text=True, cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-2000:]
    order = [line.rsplit("|", 1)[-1].strip() for line in p.stderr.splitlines() if line.startswith("import time:")]
    fork = order.index("multiprocessing.popen_fork")
    for heavy in ("filterpy", "scipy.stats", "fusion.ekf"):
        assert order.index(heavy) > fork, heavy


@pytest.mark.parametrize("where", ["the watch", "after the watch"])
def test_an_interrupt_between_the_parsing_and_the_command_is_one_line(monkeypatch, capsys, tmp_path, where):
    """The interrupt that the start-up test above caught once in a full test run (exit -2, the
    child killed by its own SIGINT after a KeyboardInterrupt escaped `main`): between the
    parsing of the command line and the command, where neither `main`'s handlers were in
    place. Raised here as Python's handler would raise it, while the interrupt watch is made
    and just after it."""
    import fusion.cli as cli

    if where == "the watch":
        def made(quiet=True):
            raise KeyboardInterrupt
        monkeypatch.setattr(cli, "_InterruptWatch", made)
    else:
        def disable():
            raise KeyboardInterrupt
        monkeypatch.setattr(cli.gc, "disable", disable)
    assert cli.main(["run", "--out", str(tmp_path / "out"), "--quiet"]) == 130
    assert capsys.readouterr().err == "error: interrupted\n"
    assert cli._WATCH is None


@pytest.mark.parametrize("installing", ["SIGINT", "SIGTERM"])
def test_an_interrupt_while_the_watch_installs_its_handlers_leaves_none(monkeypatch, capsys, tmp_path, installing):
    """The interrupt arriving just as the watch's handler for SIGINT (or then SIGTERM) went
    in: the command ends with its one line, and the process's handlers are the ones it had
    (a review: the watch made and installed in one step left its handler in the process,
    where a later `main` in the same process took it for the caller's)."""
    import signal

    import fusion.cli as cli

    real = signal.signal
    inherited = real(signal.SIGINT, signal.default_int_handler), real(signal.SIGTERM, signal.SIG_DFL)

    def install(sig, handler):
        before = real(sig, handler)
        if sig == getattr(signal, installing) and isinstance(getattr(handler, "__self__", None), cli._InterruptWatch):
            raise KeyboardInterrupt      # as Python's handler would, the signal right then
        return before

    try:
        monkeypatch.setattr(signal, "signal", install)
        assert cli.main(["run", "--out", str(tmp_path / "out"), "--quiet"]) == 130
        assert capsys.readouterr().err == "error: interrupted\n"
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
        assert cli._WATCH is None
    finally:
        monkeypatch.undo()
        real(signal.SIGINT, inherited[0])
        real(signal.SIGTERM, inherited[1])


def test_an_interrupt_that_surfaces_as_another_error_is_an_interrupt(monkeypatch, capsys, tmp_path):
    """Ctrl-C inside numba's compiler comes out as RuntimeError ("no compiled object yet"), in a
    vision worker as SystemError: a review got those tracebacks on 2 of 21 interrupts. Any
    error after this process got SIGINT is the interrupt (exit 130, one line); the same error
    without an interrupt is still a bug's traceback. An interrupt raised in a finalizer, which
    Python prints and drops ("Exception ignored"), is raised again in the main thread (a review
    found it first silenced, the run going on). A real SIGINT, sent to this process's main
    thread, with Python's own handler in place for the test: a test run started with SIGINT
    ignored (a background job of a non-interactive shell, ``nohup``) inherits the ignoring, which
    Python keeps and the program rightly leaves alone, and the signal never came ("no SIGINT
    arrived" in two such CI runs, 2026-11-27)."""
    import signal
    import threading

    def _sigint_to_the_main_thread():
        signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)

    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _interrupts_in_the_command(monkeypatch, capsys, tmp_path, _sigint_to_the_main_thread)
    finally:
        signal.signal(signal.SIGINT, inherited)


def _interrupts_in_the_command(monkeypatch, capsys, tmp_path, _sigint_to_the_main_thread):
    """The body of :func:`test_an_interrupt_that_surfaces_as_another_error_is_an_interrupt`."""
    import signal
    import time

    import fusion.cli.run as run_cmd
    from fusion.cli import main

    def compiler_interrupted(args):
        try:
            _sigint_to_the_main_thread()
            time.sleep(5.0)          # the handler raises here
        except KeyboardInterrupt:
            raise RuntimeError("no compiled object yet for <Library '_propagate_cov'>") from None
        pytest.fail("no SIGINT arrived")

    monkeypatch.setattr(run_cmd, "run", compiler_interrupted)
    hook = sys.unraisablehook
    assert main(["run"]) == 130
    assert capsys.readouterr().err == "error: interrupted\n"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler and sys.unraisablehook is hook  # put back

    class Finalizer:   # the interrupt arrives in a finalizer, where Python can only print it
        def __del__(self):
            _sigint_to_the_main_thread()
            time.sleep(1.0)

    def interrupted_in_a_finalizer(args):
        Finalizer()
        time.sleep(5.0)          # raised again here, in the main thread
        pytest.fail("the interrupt went missing")

    monkeypatch.setattr(run_cmd, "run", interrupted_in_a_finalizer)
    assert main(["run"]) == 130
    assert capsys.readouterr().err == "error: interrupted\n"     # no "Exception ignored" traceback

    # in a campaign, an interrupt that surfaces as a user error (an OSError) ends the campaign:
    # it was a skipped drive, and the next drive ran
    ran = []

    def os_error_interrupted(args):
        ran.append(args.drive)
        try:
            _sigint_to_the_main_thread()
            time.sleep(5.0)
        except KeyboardInterrupt:
            raise OSError(4, "Interrupted system call") from None

    monkeypatch.setattr(run_cmd, "run", os_error_interrupted)
    assert main(["campaign", "d1", "d2", "--out", str(tmp_path / "camp"), "--quiet"]) == 130
    assert [str(d) for d in ran] == ["d1"] and capsys.readouterr().err.endswith("error: interrupted\n")
    # the table says so (it had been written only after the last drive, and an earlier
    # campaign's table was left in its place)
    table = pd.read_csv(tmp_path / "camp" / "campaign.csv")
    assert list(table["status"]) == ["not run: interrupted"] * 2

    def a_bug(args):
        raise RuntimeError("a bug")

    monkeypatch.setattr(run_cmd, "run", a_bug)
    with pytest.raises(RuntimeError, match="a bug"):
        main(["run"])


def test_sigterm_ends_the_run_and_its_vision_workers_at_once(tmp_path):
    """SIGTERM to the run's process alone (``kill PID``; SIGINT ignored, as for a command put
    in the background of a script), while its two vision workers estimate: exit 143 with one
    line within 2 s, the workers gone, no ``OUT`` and no ``OUT.partial``. A review found the
    command killed outright when SIGINT was ignored (the workers orphaned, ``OUT.partial``
    left), and otherwise waiting 18 s for the rest of the video's pieces."""
    import signal
    import subprocess
    import time

    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "fusion", "run", "--out", str(out), "--workers", "2", "--quiet"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: (signal.signal(signal.SIGINT, signal.SIG_IGN),
                                             signal.signal(signal.SIGTERM, signal.SIG_DFL)))

    def children():
        try:
            return [int(x) for x in Path(f"/proc/{p.pid}/task/{p.pid}/children").read_text().split()]
        except OSError:
            return []

    deadline = time.monotonic() + 120
    while len(children()) < 2 and p.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    workers = children()
    time.sleep(0.5)                         # into the pieces
    sent = time.monotonic()
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=60)
    took = time.monotonic() - sent
    assert p.returncode == 143 and err.strip().splitlines()[-1] == "error: terminated (SIGTERM)", (p.returncode, err)
    assert "Traceback" not in err and took < 2.0, took
    time.sleep(0.5)

    def running(pid):
        try:
            return "\nState:\tZ" not in Path(f"/proc/{pid}/status").read_text()
        except OSError:
            return False

    assert len(workers) >= 2 and not any(running(w) for w in workers), workers
    assert not out.exists() and not out.with_name("out.partial").exists()


@pytest.mark.parametrize("where", ["video", "out", "debug-video"])
def test_a_file_name_that_is_not_utf8_is_one_line(drive, tmp_path, where):
    """A file name with a byte that is not UTF-8 (0xfc, Latin-1's u-umlaut, as an old archive
    may have it): OpenCV's reader and writer crashed the process with a segmentation fault
    (exit 139, no message) and pyarrow raised UnicodeEncodeError (a review). Said before any
    work, in one line with the name as it can be shown; nothing written."""
    import os

    odd = os.fsdecode(b"x_\xfc")
    video = drive / "video.mp4"
    if where == "video":
        video = tmp_path / f"{odd}.mp4"
        shutil.copy(drive / "video.mp4", video)
    out = tmp_path / (odd if where == "out" else "out")
    extra = ["--debug-video", tmp_path / f"{odd}.mp4"] if where == "debug-video" else []
    r = vifusion("run", "--video", video, "--frames", drive / "frames.csv", "--can", next(drive.glob("can.*")),
                 "--config", drive / "config.toml", "--out", out, "--quiet", *extra)
    one_line_error(r, "x_\\xfc", "not UTF-8")
    assert not out.exists() and not out.with_name(out.name + ".partial").exists()


def test_a_drive_folder_that_does_not_say_which_log_is_one_line(copy, tmp_path):
    """A drive folder holding two CAN logs (can.asc beside a can.blf of another day): the run
    took can.asc without a word (a review); now it says which it found and how to choose. A
    file given as --drive is said to be a file (it was "no such drive folder")."""
    import can as pycan

    with pycan.Logger(copy / "can.blf") as w:
        for m in list(pycan.LogReader(copy / "can.asc"))[:20]:
            w.on_message_received(m)
    one_line_error(vifusion("run", "--drive", copy, "--out", tmp_path / "out"), "2 CAN logs", "can.asc, can.blf",
                   "--can")
    one_line_error(vifusion("run", "--drive", copy / "can.asc", "--out", tmp_path / "out"), "is a file, not a drive folder")
    assert not (tmp_path / "out").exists()


def test_a_truth_angle_beyond_a_turn_is_one_line(tmp_path):
    """A truth roll of 1e308 deg (a corrupt cell) was scored: an RMSE of 109 deg (a review). An
    angle column beyond +-360 deg is not an angle in degrees: said with its row."""
    from fusion.drive import read_truth
    from fusion.errors import InputError

    truth = pd.read_csv(SAMPLE_DRIVE / "truth.csv")
    truth.loc[40, "roll_deg"] = 1e308
    truth.to_csv(tmp_path / "truth.csv", index=False)
    with pytest.raises(InputError, match=r"truth column roll_deg holds 1e\+308 at row 42: not an angle in degrees"):
        read_truth(tmp_path / "truth.csv")
    assert read_truth(SAMPLE_DRIVE / "truth.csv") is not None


def test_vision_command_says_frames_without_a_wheel_speed(tmp_path):
    """``vifusion vision --can`` with the wheel speed missing for the log's first 3 s: the frames
    of that stretch get no travel for the road-twist map, and the command now says so, as
    ``vifusion run`` says a late wheel speed (it said nothing, a review). The sample drive as it
    is (its first frame comes just before the first speed) says nothing."""
    import can as pycan

    d = tmp_path / "late"
    d.mkdir()
    for f in SAMPLE_DRIVE.iterdir():
        if f.name not in ("frames.csv", "can.blf"):
            (d / f.name).symlink_to(f)
    pd.read_csv(SAMPLE_DRIVE / "frames.csv").iloc[:150].to_csv(d / "frames.csv", index=False)
    msgs = list(pycan.LogReader(SAMPLE_DRIVE / "can.blf"))
    t0 = msgs[0].timestamp
    with pycan.Logger(d / "can.blf") as w:
        for m in msgs:
            if not (m.arbitration_id == 0x122 and m.timestamp < t0 + 3.0):
                w.on_message_received(m)
    common = ("vision", "--video", d / "video.mp4", "--frames", d / "frames.csv", "--config", d / "config.toml",
              "--workers", 1, "--quiet", "--out", tmp_path / "v.csv")
    r = vifusion(*common, "--can", d / "can.blf")
    assert r.returncode == 0, r.stderr
    said = [line for line in r.stderr.splitlines() if "no wheel speed at" in line]
    assert len(said) == 1 and "the road-twist map does not move" in said[0], r.stderr
    n = int(said[0].split("no wheel speed at ")[1].split(" of")[0])
    assert 85 <= n <= 95, said                  # 3 s at 30 fps, give or take the speed's last age
    r = vifusion(*common, "--can", SAMPLE_DRIVE / "can.blf")
    assert r.returncode == 0 and "no wheel speed" not in r.stderr, r.stderr


def test_values_outside_the_dbcs_range_are_said_with_the_key_that_keeps_them(copy, tmp_path):
    """A DBC whose yaw-rate range is [0|5] deg/s (a typo'd range): the values outside it are
    dropped, and the run says which channel lost how many to the range and the key that keeps
    them; before, it said only "N IMU samples without a valid gyro ... skipped" (a review). The
    count is the frames whose RateZ cantools decodes outside [0, 5]. A float declaration on the
    16-bit RateX (SIG_VALTYPE_) puts every value outside the range: the "never seen" error now
    says they came and were all out of range (it read as if no frame had arrived)."""
    import can as pycan
    import cantools

    dbc = copy / "vifusion_imu.dbc"
    text = dbc.read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith(" SG_ RateZ "))
    dbc.write_text(text.replace(line, line[:line.index("[")] + "[0|5]" + line[line.index("]") + 1:], 1))
    msg = cantools.database.load_file(dbc).get_message_by_frame_id(0x174)
    outside = sum(not 0 <= msg.decode(bytes(m.data), decode_choices=False)["RateZ"] <= 5
                  for m in pycan.LogReader(next(copy.glob("can.*"))) if m.arbitration_id == 0x174)
    assert outside > 0
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out", "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    said = [w for w in r.stderr.splitlines() if "IMU_RATE.RateZ" in w]
    assert len(said) == 1 and f"{outside} of " in said[0] and "outside the DBC's range [0|5] deg/s" in said[0] \
        and "[can] range_check = false" in said[0], r.stderr
    summary = json.loads((tmp_path / "out" / "report" / "summary.json").read_text())
    assert any("IMU_RATE.RateZ" in w for w in summary["warnings"]), summary["warnings"]

    dbc.write_text(text.replace("BO_ 290 ABS_SPEED:", "SIG_VALTYPE_ 372 RateX : 1;\nBO_ 290 ABS_SPEED:", 1))
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out2", "--quiet", "--no-report")
    one_line_error(r, "never seen", "IMU_RATE.RateX", "of its values were outside the DBC's range",
                   "[can] range_check = false")


@pytest.mark.parametrize("cut, words", [
    ("after", "value in the last 1.2 s of the IMU samples (the channels stopped early)"),
    ("before", "value for the first 1.2 s of the IMU samples (the channels started late)"),
])
def test_an_accelerometer_message_that_stops_early_or_starts_late_is_said(copy, tmp_path, cut, words):
    """The 2-s drive's accelerometer message (IMU_ACC) cut off after 0.8 s, or missing for its
    first 1.2 s: the samples without it cannot be fused, so fused.csv ends (starts) there. The
    run said only "N IMU samples ... skipped" and its fused.csv looked like the drive's (a review
    on a 12-s log cut at 3 s); now it names the channels, how long they were missing and where
    the fused table ends. The fused table's span is the accelerometer's, to one 10-ms sample."""
    import can as pycan

    log = next(copy.glob("can.*"))
    msgs = list(pycan.LogReader(log))
    t0, t1 = msgs[0].timestamp, msgs[-1].timestamp
    log.unlink()
    acc = []
    with pycan.Logger(copy / "can.blf") as w:
        for m in msgs:
            if m.arbitration_id == 0x178 and ((m.timestamp > t0 + 0.8) if cut == "after" else (m.timestamp < t0 + 1.2)):
                continue
            acc += [m.timestamp] if m.arbitration_id == 0x178 else []
            w.on_message_received(m)
    r = vifusion("run", "--drive", copy, "--out", tmp_path / "out", "--quiet", "--no-report")
    assert r.returncode == 0, r.stderr
    said = [w for w in r.stderr.splitlines() if words in w]
    assert len(said) == 1 and "accel_x_m_s2, accel_y_m_s2, accel_z_m_s2" in said[0], r.stderr
    f = pd.read_csv(tmp_path / "out" / "fused.csv")
    if cut == "after":
        assert "the fused table ends 1.2 s before" in said[0] and t1 - acc[-1] > 1.15
        assert abs(f["t_s"].iloc[-1] - acc[-1]) < 0.011
    else:
        assert "the fused table starts 1.2 s after" in said[0] and acc[0] - t0 > 1.15
        assert abs(f["t_s"].iloc[0] - acc[0]) < 0.011


def test_campaign_goes_on_after_a_drive_fails_with_a_bug(drive, tmp_path, monkeypatch, capsys):
    """A drive whose run fails with an internal error (a bug, not bad input: the division by
    zero a zeroed accelerometer frame caused, a review) ended the campaign with a traceback, the
    drives after it never run and their rows 'not run' with no reason. Now the row says
    'failed: internal error ...', the traceback is on stderr, the next drive runs from the last
    good calibration, and the exit status is 1; with --debug the campaign stops at it."""
    from fusion import cli
    from fusion.cli import run as run_cmd

    second, third = tmp_path / "second", tmp_path / "third"
    shutil.copytree(drive, second)
    shutil.copytree(drive, third)
    started = run_cmd.run

    def a_bug_in_the_second(args):
        if args.drive == second:
            raise ZeroDivisionError("division by zero")
        return started(args)

    monkeypatch.setattr(run_cmd, "run", a_bug_in_the_second)
    out = tmp_path / "camp"
    assert cli.main(["campaign", str(drive), str(second), str(third), "--out", str(out), "--quiet",
                     "--no-report"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "ZeroDivisionError: division by zero" in err
    assert err.strip().splitlines()[-1].startswith("error: a drive of the campaign failed with an internal error")
    table = pd.read_csv(out / "campaign.csv")
    assert table["status"].iloc[0] == "ok" and table["status"].iloc[2] == "ok", table["status"]
    assert table["status"].iloc[1] == ("failed: internal error (a bug, the traceback on stderr): ZeroDivisionError: "
                                       "division by zero")
    assert not (out / "second").exists() and not (out / "second.partial").exists()
    with pytest.raises(ZeroDivisionError):
        cli.main(["campaign", str(drive), str(second), "--out", str(out), "--quiet", "--no-report", "--debug"])
