"""Embedding: raw CAN messages and frames pushed as they arrive give the same estimate as the
offline run over the same drive, even when every frame's result comes in 80 ms late; the
estimator's road-twist map moved by the same wheel-speed travel in both."""

import subprocess
import sys
from pathlib import Path

import can
import numpy as np
import pandas as pd
import pytest

from fusion.config import load_config
from fusion.options import fusion_options_from_table
from fusion.pipeline import frame_speeds, fuse
from fusion.realtime import LiveFusion
from imu import read_log
from vision.options import options_from_table
from vision.video import FrameSource, estimate_video

SCENARIO = Path(__file__).resolve().parents[1] / "configs" / "scenarios" / "test" / "tiny_banked_curve.toml"


@pytest.fixture(scope="module", params=["tiny", "sample"])
def drive(request, tmp_path_factory):
    """The tiny drive (320x180, .asc: lanes found on half the frames, two lines) and the bundled
    sample drive (640x360, .blf, three lines through a runoff: the twist map in use)."""
    if request.param == "sample":
        from fusion.drive import SAMPLE_DRIVE

        return SAMPLE_DRIVE, "can.blf", 60      # 104 of 360 frames twisted (measured)
    d = tmp_path_factory.mktemp("rt") / "drive"
    r = subprocess.run([sys.executable, "-m", "fusion", "simulate", str(SCENARIO), "--out", str(d), "--quiet"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return d, "can.asc", 0


def test_live_fusion_equals_the_offline_run(drive):
    drive, can_file, min_twisted = drive
    cfg = load_config(drive / "config.toml")
    frames = pd.read_csv(drive / "frames.csv")
    # offline
    imu, _ = read_log(drive / can_file, cfg.can, cfg.imu)
    frames = frames.assign(speed_m_s=frame_speeds(imu, frames["t_s"].to_numpy()))   # as vifusion run does
    vision, _ = estimate_video(drive / "video.mp4", frames, cfg.camera, cfg.mount, cfg.road,
                               options_from_table(cfg.extra.get("vision")), progress=False)
    opts, _ = fusion_options_from_table(cfg.extra.get("fusion"))
    offline = fuse(imu, vision, lever_arm_m=cfg.imu.position_m, options=opts).fused
    # live: every frame's result is handed in once the bus has moved 80 ms past its capture
    live = LiveFusion(cfg)
    # the pictures the offline run's estimator saw
    images = list(FrameSource(drive / "video.mp4").grey_frames())
    queue = list(zip(frames["t_s"], images))
    for msg in can.LogReader(drive / can_file):
        live.push_can(msg)
        while queue and queue[0][0] + 0.08 <= msg.timestamp:
            t, img = queue.pop(0)
            live.push_frame(t, img)
    for t, img in queue:            # the frames captured in the last 80 ms, after the bus went quiet
        live.push_frame(t, img)
    est = live.estimate()
    assert live.stream.counts["vision_late"] >= 10
    if min_twisted:      # the tiny drive's two lines never use the twist map
        assert (vision["road_twist_bank_change_deg"] != 0).sum() >= min_twisted
    last = offline.iloc[-1]
    assert est.t_s == pytest.approx(last["t_s"], abs=1e-9)
    for name in ("roll", "pitch", "yaw", "bank", "roll_world"):
        assert np.degrees(getattr(est, f"{name}_rad")) == pytest.approx(last[f"{name}_deg"], abs=1e-6), name
    assert np.degrees(est.roll_sigma_rad) == pytest.approx(last["roll_sigma_deg"], abs=1e-6)
    # what the embedded filter would save at the end of the drive is the offline run's calibration
    from fusion.calibration import calibration_table

    saved, offline_cal = live.calibration(), calibration_table(offline)
    for key, values in offline_cal.items():
        np.testing.assert_allclose(saved[key], values, atol=1e-9, err_msg=key)
