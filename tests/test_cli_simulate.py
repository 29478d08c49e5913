"""``vifusion simulate`` end to end: a complete drive in the contract's format, whose parts agree
with each other and with the truth; bad scenario files give one line naming the key."""

import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from fusion.config import load_config
from imu import read_log

TEST_SCENARIOS = Path(__file__).resolve().parents[1] / "configs" / "scenarios" / "test"


def vifusion(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "fusion", *map(str, args)], capture_output=True, text=True, cwd=cwd)


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    out = {}
    for name in ("tiny_banked_curve", "tiny_dlc_car_distorted"):
        d = tmp_path_factory.mktemp(name) / "drive"
        r = vifusion("simulate", TEST_SCENARIOS / f"{name}.toml", "--out", d, "--quiet")
        assert r.returncode == 0, r.stderr
        out[name] = d
    return out


def test_drive_files_are_complete_and_consistent(drives):
    d = drives["tiny_banked_curve"]
    for f in ("video.mp4", "frames.csv", "can.asc", "vifusion_imu.dbc", "config.toml", "truth.csv",
              "truth_frames.csv", "imu_truth.csv", "scenario.toml"):
        assert (d / f).is_file(), f
    assert not d.with_name("drive.partial").exists()
    frames = pd.read_csv(d / "frames.csv")
    assert list(frames.columns) == ["frame", "t_s"]
    assert len(frames) == 30  # 2 s at 15 fps
    cap = cv2.VideoCapture(str(d / "video.mp4"))
    n = 0
    while True:
        ok, img = cap.read()
        if not ok:
            break
        assert img.shape == (180, 320, 3)
        n += 1
    assert n == len(frames)
    truth = pd.read_csv(d / "truth.csv")
    for c in ("t_s", "roll_deg", "pitch_deg", "yaw_deg", "bank_deg", "roll_world_deg", "pitch_world_deg"):
        assert c in truth.columns
    assert np.allclose(np.diff(truth["t_s"]), 0.01)  # 100 Hz
    # the curve is banked 5 deg (positive: right-hand curve, left edge up) and reached
    assert truth["bank_deg"].iloc[-1] == pytest.approx(5.0, abs=1e-6)


def test_can_log_carries_the_true_imu_on_the_same_clock(drives):
    """Decoded with the drive's own config and DBC, the CAN log gives the true rates plus the
    configured bias and noise, at the times truth gives them: the clocks agree."""
    d = drives["tiny_banked_curve"]
    cfg = load_config(d / "config.toml")
    imu, _ = read_log(d / "can.asc", cfg.can, cfg.imu)
    true = pd.read_csv(d / "imu_truth.csv")
    assert len(imu) == len(true)
    np.testing.assert_allclose(imu["t_s"], true["t_s"], atol=1e-6)
    for a in "xyz":
        err = imu[f"gyro_{a}_rad_s"] - true[f"gyro_{a}_rad_s"] - true[f"gyro_bias_{a}_rad_s"]
        # white noise 0.05 deg/s per sample plus half a DBC step (0.0025 deg/s)
        assert math.degrees(err.std()) == pytest.approx(0.05, rel=0.4)
        assert abs(math.degrees(err.mean())) < 0.05
    frames = pd.read_csv(d / "frames.csv")
    tf = pd.read_csv(d / "truth_frames.csv")
    np.testing.assert_allclose(frames["t_s"], tf["t_s"], atol=1e-6)  # both written to the microsecond
    assert imu["t_s"].iloc[0] <= frames["t_s"].iloc[0] and frames["t_s"].iloc[-1] <= imu["t_s"].iloc[-1] + 0.01


def test_config_tells_the_filter_the_datasheet_not_the_drawn_bias(drives):
    """The drive's config gives the filter the accelerometer's residual as the scenario's datasheet
    states it (``accel_bias_sigma_m_s2``, 0.05 m/s^2 here), whatever bias the drive drew: until
    2026-11-26 it gave the drawn biases' own magnitudes, which no user knows and which set the
    bank's sigma on a single curve."""
    from drivesim.scenario import load_scenario

    from fusion.options import fusion_options_from_table

    d = drives["tiny_banked_curve"]
    scenario = load_scenario(d / "scenario.toml")
    opts, _ = fusion_options_from_table(load_config(d / "config.toml").extra["fusion"])
    np.testing.assert_allclose(np.broadcast_to(opts.noise.init_accel_bias_m_s2, (3,)),
                               scenario.imu.accel_bias_sigma_m_s2, rtol=1e-12)
    # and with a bias drawn: the config the simulator writes for this scenario with one
    import dataclasses
    import tomllib

    from drivesim.drive import _config_toml

    biased = dataclasses.replace(scenario, imu=dataclasses.replace(scenario.imu, accel_bias_m_s2=(0.02, -0.03, 0.01)))
    fusion = tomllib.loads(_config_toml(biased, "imu.dbc", {}, 15.0, 0.0))["fusion"]
    assert fusion["accel_bias_sigma_m_s2"] == scenario.imu.accel_bias_sigma_m_s2 == 0.05, fusion


def test_car_drive_with_distortion_png_frames_and_no_pitch_rate(drives):
    d = drives["tiny_dlc_car_distorted"]
    pngs = sorted((d / "video").glob("*.png"))
    assert len(pngs) == 30
    cfg = load_config(d / "config.toml")
    assert cfg.camera.has_distortion and cfg.road.marker_widths_m == (0.25, 0.15, 0.15)
    assert "gyro_y" not in cfg.can.signals  # the IMU has no pitch-rate channel
    imu, _ = read_log(d / "can.blf", cfg.can, cfg.imu)
    assert "gyro_y_rad_s" in imu.attrs["unavailable"]
    assert np.all(np.isnan(imu["gyro_y_rad_s"]))
    truth = pd.read_csv(d / "truth.csv")
    # BLF: the clock is absolute epoch seconds; the truth keeps its 100 Hz steps there too
    assert truth["t_s"].iloc[0] > 1e9
    np.testing.assert_allclose(np.diff(truth["t_s"]), 0.01, atol=2e-6)
    np.testing.assert_allclose(pd.read_csv(d / "frames.csv")["t_s"], pd.read_csv(d / "truth_frames.csv")["t_s"], atol=2e-6)
    # car: the body follows the road plus 0.5 deg of body roll per m/s^2 of lateral acceleration
    # (2.6 m/s^2 peak in this lane change): well under 2 deg, and outward (right in a left move)
    assert 0.5 < truth["roll_deg"].abs().max() < 2.0
    # 3 % grade uphill: the road pitches nose-up (negative, INTERFACE: positive is nose down)
    assert truth["road_pitch_deg"].iloc[-1] == pytest.approx(-math.degrees(math.atan(0.03)), abs=1e-3)


@pytest.mark.parametrize("edit, key", [
    ("heigth_m = 1.1", "heigth_m"),
    ('width = "wide"', "width"),
    ("duration_s = -3", "duration_s"),
    ("[[motion.manoeuvre]]\nkind = \"wheelie\"\nstart_m = 1\nlength_m = 10", "kind"),
    ("hfov_dg", "hfov_dg"),    # a typo of hfov_deg: named, with the key meant (it said 'fx is missing')
])
def test_bad_scenario_is_one_line_naming_the_key(tmp_path, edit, key):
    src = (TEST_SCENARIOS / "tiny_banked_curve.toml").read_text()
    table = {"heigth_m = 1.1": "[mount]", 'width = "wide"': "[camera]", "duration_s = -3": "[scenario]"}.get(edit)
    if edit == "hfov_dg":
        bad = src.replace("hfov_deg", "hfov_dg", 1)
        assert bad != src
    elif table:
        bad = src.replace(table + "\n", table + "\n" + edit + "\n", 1)
        if key in ("width", "duration_s"):
            bad = bad.replace(f"{key} = 320\n", "", 1).replace(f"{key} = 2.0\n", "", 1)
    else:
        bad = src + "\n" + edit + "\n"
    p = tmp_path / "bad.toml"
    p.write_text(bad)
    r = vifusion("simulate", p, "--out", tmp_path / "out")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and key in lines[0], r.stderr
    assert edit != "hfov_dg" or "did you mean hfov_deg?" in lines[0], r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("table, edit, key", [
    # values a review found taken, then failing inside the simulator with a traceback, or giving
    # a physically absurd drive with exit 0 (fifteenth session)
    ("motion", "speed_profile = [[0, 72], [1, nan]]", "speed_profile"),
    ("motion", "speed_profile = [[0, 72], [inf, 80]]", "speed_profile"),
    ("motion", "speed_profile = [[0, 72], [1, -50]]", "speed_profile"),      # drove backwards
    ("motion", "speed_profile = [[0, 72], [1, 5000]]", "speed_profile"),     # 1389 m/s
    ("motion", "speed_profile = [[0, 72], [1, 80]]", "speed_kmh"),           # both: one was ignored
    ("motion", "start_station_m = 1e12", "start_station_m"),                 # 29 TiB of road table
    ("imu", "start_s = 5.0", "start_s"),                                     # no IMU sample at all
    ("can", "start_epoch_s = 1.7e12", "start_epoch_s"),                      # milliseconds
    ("render", "max_distance_m = 1e12", "max_distance_m"),
    ("segment", "radius_m = 0.5", "radius_m"),                               # 2 1/m: lean 90 deg
    ("manoeuvre", "shift_m = 1e6", "shift_m"),
    ("manoeuvre", "repeat = 100000\nperiod_m = 10", "repeat"),              # did not finish
    ("manoeuvre", "shift_m = 10.5\nrepeat = 12\nperiod_m = 21", "manoeuvre"), # 92.7 m, adding up
    ("scenario", "seed = 18446744073709551615", "seed"),                    # 2^64 - 1: the renderer's traceback
    # a review's cosmetic findings (session 29): each was exit 0 or named the wrong key
    ("segment", "curvature_1_m = -0.005\nradius_m = -200", "radius_m and curvature_1_m both given"),
    ("video", "fps = 0.1", "fps = 0.1 gives no frame in the 2 s"),           # 2 s at 0.1 fps: no frame, exit 0
    ("scenario", 'name = "two\\nlines"', "name must not hold control characters"),   # broke the summary line
])
def test_out_of_range_scenario_values_are_named(tmp_path, table, edit, key):
    """Checked when the scenario is read, each a one-line error naming its key."""
    from drivesim.scenario import load_scenario

    from fusion.errors import ConfigError

    src = (TEST_SCENARIOS / "tiny_banked_curve.toml").read_text()
    if table == "segment":
        bad = src.replace("curvature_1_m = -0.005", edit, 1)
    elif table == "video" and edit.startswith("fps"):
        bad = src.replace("fps = 15.0", edit, 1)
    elif table == "scenario" and edit.startswith("name"):
        bad = src.replace('name = "tiny_banked_curve"', edit, 1)
    elif table == "scenario":
        bad = src.replace("seed = 5\n", edit + "\n", 1)
    elif table == "manoeuvre":
        bad = src + '\n[[motion.manoeuvre]]\nkind = "lane_change"\nstart_m = 10\nlength_m = 20\n' + edit + "\n"
    elif f"[{table}]\n" in src:
        bad = src.replace(f"[{table}]\n", f"[{table}]\n{edit}\n", 1)
    else:
        bad = src + f"\n[{table}]\n{edit}\n"
    assert bad != src
    p = tmp_path / "bad.toml"
    p.write_text(bad)
    with pytest.raises(ConfigError, match=key) as e:
        load_scenario(p)
    assert "\n" not in str(e.value)


def test_a_key_before_any_table_is_named_as_such(tmp_path):
    """A scenario without its ``[scenario]`` header: its keys are at the top level, and the error
    said "[name] is not a known table" (a review)."""
    src = (TEST_SCENARIOS / "tiny_banked_curve.toml").read_text()
    p = tmp_path / "headless.toml"
    p.write_text(src.replace("[scenario]\n", "", 1))
    r = vifusion("simulate", p, "--out", tmp_path / "out")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "name is given before any [table] header" in r.stderr and "not a known table" not in r.stderr, r.stderr


def test_missing_scenario_file(tmp_path):
    r = vifusion("simulate", tmp_path / "nope.toml", "--out", tmp_path / "out")
    assert r.returncode == 2 and r.stderr.startswith("error: ") and "nope.toml" in r.stderr


@pytest.mark.parametrize("n", [-1, 0])
def test_a_frame_count_under_one_is_one_line(tmp_path, n):
    """``--frames 0`` wrote a drive of no frames and no video, exit 0 (a review)."""
    r = vifusion("simulate", TEST_SCENARIOS / "tiny_banked_curve.toml", "--out", tmp_path / "out", "--frames", n)
    assert r.returncode == 2 and r.stderr.strip() == f"error: --frames must be >= 1 (a drive needs frames), got {n}", \
        r.stderr
    assert not (tmp_path / "out").exists()


def test_force_replaces_a_drive_not_a_folder_of_anything(tmp_path, monkeypatch):
    """``--force`` replaced any folder: with ``--out ..`` it emptied the parent folder, and a
    thesis beside a drive went with it (a review). It now replaces a folder holding only what
    a simulation writes and refuses anything else in one line, touching nothing; the root is no
    output folder; a negative seed is a scenario error; a simulation that fails leaves no
    ``OUT.partial`` behind."""
    scen = TEST_SCENARIOS / "tiny_banked_curve.toml"
    out = tmp_path / "work" / "drive"
    r = vifusion("simulate", scen, "--out", out, "--no-video", "--quiet")
    assert r.returncode == 0, r.stderr
    r = vifusion("simulate", scen, "--out", out, "--no-video", "--quiet", "--force")   # a drive: replaced
    assert r.returncode == 0, r.stderr
    (out / "thesis.tex").write_text("mine")
    for target, cwd in ((out, None), ("..", out)):
        r = vifusion("simulate", scen, "--out", target, "--no-video", "--quiet", "--force", cwd=cwd)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "holds files a simulation did not write" in r.stderr, r.stderr
    assert (out / "thesis.tex").read_text() == "mine" and (out / "truth.csv").is_file()
    r = vifusion("simulate", scen, "--out", "/", "--no-video", "--force")
    assert r.returncode == 2 and r.stderr.strip() == "error: /: the root is not an output folder", r.stderr
    bad = tmp_path / "seed.toml"
    bad.write_text(scen.read_text().replace("seed = 5\n", "seed = -3\n", 1))
    r = vifusion("simulate", bad, "--out", tmp_path / "s")
    assert r.returncode == 2 and "seed" in r.stderr and "within [0," in r.stderr and "Traceback" not in r.stderr, r.stderr

    from drivesim import drive as drive_mod
    from drivesim.scenario import load_scenario

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(drive_mod, "simulate_imu", broken)
    with pytest.raises(OSError):
        drive_mod.simulate(load_scenario(scen), tmp_path / "half", progress=False, render_video=False)
    assert not (tmp_path / "half.partial").exists() and not (tmp_path / "half").exists()


def test_force_does_not_replace_a_recorded_drive(tmp_path):
    """A recorded drive has the simulator's layout (video.mp4, frames.csv, can.*, a DBC,
    config.toml): ``--force`` replaced it (a review). Only a folder with the truth only a
    simulation writes (imu_truth.csv, truth_frames.csv) is a simulated drive."""
    import shutil

    sample = Path(__file__).resolve().parents[1] / "fusion" / "data" / "sample_drive"
    rec = tmp_path / "recorded"
    rec.mkdir()
    for name in ("video.mp4", "frames.csv", "can.blf", "vifusion_imu.dbc", "config.toml"):
        shutil.copyfile(sample / name, rec / name)
    before = sorted(p.name for p in rec.iterdir())
    r = vifusion("simulate", TEST_SCENARIOS / "tiny_banked_curve.toml", "--out", rec, "--no-video", "--quiet",
                 "--force")
    assert r.returncode == 2 and "is not a simulated drive" in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr
    assert sorted(p.name for p in rec.iterdir()) == before


def test_a_saturated_imu_signal_is_the_range_end_not_sna():
    """The simulated IMU saturates at its DBC range as a sensor does: the top and bottom raw
    values that are measurements, not the "SNA" value the DBC names at raw 65535 (cantools
    rounds the range's maximum of AccX onto it: a review's 1e5 m/s^2 bias read as "accel_x
    never seen"). Unsaturated values are encoded as before."""
    import cantools

    from drivesim.canlog import DBC_PATH, _encode

    acc = cantools.database.load_file(DBC_PATH).get_message_by_name("IMU_ACC")
    base = {"AccStatus": 0, "AccCounter": 0, "AccCRC": 0}
    data = _encode(acc, {**base, "AccX": 1e5, "AccY": -1e5, "AccZ": 1.0})
    raw = acc.decode(data, decode_choices=False, scaling=False)
    assert raw["AccX"] == 65534 and raw["AccY"] == 0, raw
    phys = acc.decode(data, decode_choices=False)
    step = 0.0001274
    assert 4.1723 - 1.5 * step < phys["AccX"] < 4.1723 and phys["AccY"] == pytest.approx(-4.1768, abs=step / 2)
    at_max = acc.decode(_encode(acc, {**base, "AccX": 4.1723, "AccY": -4.1768, "AccZ": 1.0}),
                        decode_choices=False, scaling=False)
    assert at_max["AccX"] == 65534, "a value exactly at the range's maximum is saturated too"
    plain = {**base, "AccX": 0.5, "AccY": -0.25, "AccZ": 1.0}
    assert _encode(acc, plain) == bytes(acc.encode(plain, scaling=True, padding=False, strict=True))


def test_sigterm_during_a_simulation_leaves_no_drive_and_a_partial_one_is_refused(tmp_path):
    """``kill`` (SIGTERM) during the render: the command cleans up as on Ctrl-C, exit 143 with
    one line, no ``OUT`` and no ``OUT.partial`` (it was killed on the spot and left a
    ``.partial`` folder with 47 of 90 frames, which ``run --drive`` took with a warning: a
    review). A ``.partial`` simulation left by a harder kill is refused by ``run``."""
    import signal
    import subprocess
    import sys
    import time

    src = (TEST_SCENARIOS / "tiny_banked_curve.toml").read_text()
    long = tmp_path / "long.toml"
    long.write_text(src.replace("duration_s = 2.0", "duration_s = 20.0", 1))
    out = tmp_path / "drive"
    p = subprocess.Popen([sys.executable, "-m", "fusion", "simulate", str(long), "--out", str(out), "--quiet"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGTERM, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while not (out.with_name("drive.partial") / "config.toml").is_file() and p.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.005)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 143 and err.strip().splitlines()[-1] == "error: terminated (SIGTERM)", (p.returncode, err)
    assert "Traceback" not in err
    assert not out.exists() and not out.with_name("drive.partial").exists()

    import shutil

    for name in ("notes.txt", "config.toml"):     # a user's file; one a simulation also writes
        mine = tmp_path / f"my{name[:5]}.partial"
        mine.mkdir()
        (mine / name).write_text("precious")
        r = vifusion("simulate", TEST_SCENARIOS / "tiny_banked_curve.toml", "--out", mine.with_suffix(""), "--no-video")
        assert r.returncode == 2 and "is not an unfinished simulation's folder" in r.stderr, r.stderr
        assert (mine / name).read_text() == "precious" and not mine.with_suffix("").exists()

    half = tmp_path / "half.partial"
    shutil.copytree(TEST_SCENARIOS.parents[2] / "fusion" / "data" / "sample_drive", half)
    r = vifusion("run", "--drive", half, "--out", tmp_path / "run")
    assert r.returncode == 2 and r.stderr.strip().startswith("error: ") and "unfinished simulation" in r.stderr


def test_the_configs_start_time_is_the_first_frames_stamp(tmp_path):
    """A drive simulated with a camera 50 ms off the bus (``[video] camera_time_offset_s``):
    ``frames.csv`` carries the error, and so does the config's ``[video] start_s``, which a run
    without ``frames.csv`` takes the frame times from (it had the true capture time, so that
    the two timings of one drive disagreed by the offset, a review)."""
    src = (TEST_SCENARIOS / "tiny_banked_curve.toml").read_text()
    scen = tmp_path / "offset.toml"
    scen.write_text(src.replace("[video]\n", "[video]\ncamera_time_offset_s = 0.05\n", 1))
    r = vifusion("simulate", scen, "--out", tmp_path / "d", "--frames", 3, "--no-video", "--quiet")
    assert r.returncode == 0, r.stderr
    frames = pd.read_csv(tmp_path / "d" / "frames.csv")
    truth = pd.read_csv(tmp_path / "d" / "truth_frames.csv")
    cfg = load_config(tmp_path / "d" / "config.toml")
    assert frames["t_s"].iloc[0] - truth["t_s"].iloc[0] == pytest.approx(0.05, abs=1e-9)
    assert cfg.video.start_s == pytest.approx(frames["t_s"].iloc[0], abs=1e-9)


@pytest.mark.parametrize("edits, named", [
    # each value within its key's range, the drive beyond what a vehicle or the IMU does (a review:
    # exit 0, and the CAN log held the DBC's 4.18 g for the truth's 6.1 g on 185 of 201 samples)
    ({"curvature_1_m = -0.005": "curvature_1_m = -0.02", "speed_kmh = 72": "speed_kmh = 200"},
     ("would lean 7", "beyond the 60 deg", "speed_kmh")),
    ({"curvature_1_m = -0.005": "curvature_1_m = 0.2", "speed_kmh = 72": "speed_kmh = 400"},
     ("would lean", "beyond the 60 deg", "curvature_1_m")),
    ({'vehicle = "motorcycle"': 'vehicle = "car"', "curvature_1_m = -0.005": "curvature_1_m = -0.02",
      "speed_kmh = 72": "speed_kmh = 100"},
     ("car's tyres would take a side force of 1.", "beyond the 1 g")),
    ({"gyro_bias_deg_s = [0.2,": "gyro_bias_deg_s = [200.0,"},
     ("gyro_x", "reaches 2", "-163.8 to 163.8 deg/s", "IMU_RATE.RateX", "[imu] gyro_bias_deg_s")),
    ({"gyro_bias_deg_s = [0.2, -0.15, 0.3]": "accel_bias_m_s2 = [50, 0, 0]"},
     ("accel_x", "reaches 50.", "-40.96 to 40.92 m/s^2", "IMU_ACC.AccX", "[imu] accel_bias_m_s2")),
])
def test_a_drive_no_vehicle_or_imu_could_give_is_refused_before_writing(tmp_path, edits, named):
    """A motorcycle leaning beyond 60 deg, a car's tyres beyond 1 g of side force, or an IMU
    channel (bias and noise included) beyond its DBC signal's range: one line naming the value,
    the limit and the key to change, exit 2, and no folder (checked before anything is written)."""
    src = (TEST_SCENARIOS / "tiny_banked_curve.toml").read_text()
    for old, new in edits.items():
        assert old in src
        src = src.replace(old, new)
    p = tmp_path / "extreme.toml"
    p.write_text(src)
    out = tmp_path / "drive"
    r = vifusion("simulate", p, "--out", out, "--no-video", "--quiet")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in r.stderr, r.stderr
    for text in named:
        assert text in lines[0], lines[0]
    assert not out.exists() and not out.with_name("drive.partial").exists()


@pytest.mark.parametrize("width, height, codec, text", [
    (321, 181, "mp4v", "the mp4v codec writes even sizes only (it would write 320x180 frames"),   # it did, exit 0
    (321, 180, "ffv1", "the ffv1 codec writes even sizes only (it would write 320x180 frames"),
    (320, 181, "mjpg", "the mjpg codec writes even sizes only (it would write 320x180 frames"),
    (1, 1, "mp4v", "renders 64 to 4096 px a side"),          # was "OpenCV cannot write mp4v video"
    (20000, 20000, "png", "renders 64 to 4096 px a side"),   # was a traceback allocating 2.98 GiB
    (4098, 2304, "mp4v", "renders 64 to 4096 px a side"),
])
def test_a_frame_size_the_codec_or_the_memory_cannot_take_is_refused(tmp_path, width, height, codec, text):
    src = (TEST_SCENARIOS / "tiny_banked_curve.toml").read_text()
    p = tmp_path / "size.toml"
    p.write_text(src.replace("width = 320\nheight = 180", f"width = {width}\nheight = {height}", 1)
                 .replace("[video]\n", f'[video]\ncodec = "{codec}"\n', 1))
    r = vifusion("simulate", p, "--out", tmp_path / "drive", "--frames", 1, "--quiet")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and text in r.stderr, r.stderr
    assert f"{width}x{height}" in r.stderr and not list(tmp_path.glob("drive*"))


def test_png_frames_keep_an_odd_size_the_config_gives(tmp_path):
    """PNG frames are written at any size: 321x181 frames, as the config says (the video
    codecs' even sizes are refused above)."""
    src = (TEST_SCENARIOS / "tiny_banked_curve.toml").read_text()
    p = tmp_path / "odd.toml"
    p.write_text(src.replace("width = 320\nheight = 180", "width = 321\nheight = 181", 1)
                 .replace("[video]\n", '[video]\ncodec = "png"\n', 1))
    r = vifusion("simulate", p, "--out", tmp_path / "drive", "--frames", 2, "--quiet")
    assert r.returncode == 0, r.stderr
    cfg = load_config(tmp_path / "drive" / "config.toml")
    frames = sorted((tmp_path / "drive" / "video").glob("*.png"))
    assert len(frames) == 2 and cv2.imread(str(frames[0])).shape[:2] == (cfg.camera.height, cfg.camera.width) == (181, 321)


def test_running_out_of_memory_is_one_line_and_leaves_no_folder(tmp_path, monkeypatch, capsys):
    """A frame too large for the machine's memory (numpy's ``_ArrayMemoryError``, a traceback
    in a review's 20000x20000 PNG drive) is one line, exit 2, and no ``OUT`` or ``OUT.partial``."""
    from drivesim import drive as drive_mod

    from fusion import cli

    def no_memory(*args, **kwargs):
        raise MemoryError("Unable to allocate 2.98 GiB for an array with shape (20000, 20000)")
        yield

    monkeypatch.setattr(drive_mod, "render_frames", no_memory)
    out = tmp_path / "drive"
    assert cli.main(["simulate", str(TEST_SCENARIOS / "tiny_banked_curve.toml"), "--out", str(out), "--frames", "1",
                     "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "out of memory simulating 320x180 frames" in err, err
    assert not out.exists() and not out.with_name("drive.partial").exists()


def test_a_simulation_killed_while_writing_its_can_log_is_simulated_again(tmp_path):
    """SIGKILL while the CAN log is written left ``OUT.partial`` holding ``can.asc`` alone, and
    the next ``simulate`` refused it as not an unfinished simulation's folder (a review): the
    folder's first file is now a marker, so the same command finishes the drive. A folder of
    that name holding a user's ``can.asc`` alone is still refused, untouched, and ``run
    --drive`` refuses the killed one as unfinished."""
    import os
    import shutil
    import signal
    import time

    src = (TEST_SCENARIOS / "tiny_banked_curve.toml").read_text()
    long = tmp_path / "long.toml"
    long.write_text(src.replace("duration_s = 2.0", "duration_s = 20.0", 1))
    out = tmp_path / "drive"
    partial = out.with_name("drive.partial")
    p = subprocess.Popen([sys.executable, "-m", "fusion", "simulate", str(long), "--out", str(out), "--quiet",
                          "--no-video"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (partial / "can.asc").is_file() and p.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.002)
    os.kill(p.pid, signal.SIGKILL)
    p.communicate(timeout=60)
    left = sorted(q.name for q in partial.iterdir())
    assert "can.asc" in left and "imu_truth.csv" not in left, left   # killed during the CAN log, as in the review
    shutil.copytree(partial, tmp_path / "copy.partial")
    r = vifusion("simulate", long, "--out", out, "--quiet", "--no-video")
    assert r.returncode == 0, r.stderr
    assert (out / "imu_truth.csv").is_file() and not partial.exists()
    assert not [q.name for q in out.iterdir() if q.name.startswith(".")]     # the marker goes before the rename
    assert len(pd.read_csv(out / "imu_truth.csv")) == 2001      # 20 s at 100 Hz, both ends
    r = vifusion("run", "--drive", tmp_path / "copy.partial", "--out", tmp_path / "run")
    assert r.returncode == 2 and "unfinished simulation" in r.stderr, r.stderr

    mine = tmp_path / "mine.partial"
    mine.mkdir()
    (mine / "can.asc").write_text("precious")
    r = vifusion("simulate", TEST_SCENARIOS / "tiny_banked_curve.toml", "--out", tmp_path / "mine", "--no-video")
    assert r.returncode == 2 and "is not an unfinished simulation's folder" in r.stderr, r.stderr
    assert (mine / "can.asc").read_text() == "precious" and sorted(mine.iterdir()) == [mine / "can.asc"]
