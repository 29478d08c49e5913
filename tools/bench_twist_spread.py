"""How much the fused figures move with nothing physical changed: the twist map's discrete steps.

Usage::

    .venv/bin/python tools/bench_twist_spread.py [drive names ...] [--scales 1 1.000000001 ...]

The estimator's road-twist map (:mod:`vision.twistmap`) makes yes/no decisions per frame: a
cross-section's twist gated in or out, a frame projected onto the twisted road or onto the
plane (:attr:`vision.options.EstimatorOptions.road_twist_min_deg`). A decision that flips moves
the frames after it, so the figures of one run are one draw: the same drive with the wheel
speed's travel scaled by 1 +- 1e-9 (nothing a wheel-speed sensor could tell apart) gives other
figures. This runs each drive (as ``tools/bench_fusion.py`` caches it) through the vision with
the CAN wheel speed times each scale and the forward filter, as ``vifusion run`` does (one
worker, the configured camera offset), and prints the RMSE against truth after 2 s and the
NEES share per scale, then the spread (min / median / max) per drive. A scale of 0.99 or 1.01
is a wheel-speed scale error of 1 %.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

ANGLES = ("roll", "pitch", "yaw", "bank")


def run_once(drive: Path, scale: float) -> tuple[dict, float]:
    """Forward-filter RMSE per angle (deg) and the NEES share in its 95 % band."""
    from fusion.config import load_config
    from fusion.drive import read_frame_times
    from fusion.metrics import consistency, rmse_table
    from fusion.options import fusion_options_from_table
    from fusion.drive import frame_speeds
    from fusion.pipeline import fuse
    from imu import read_log
    from vision.options import options_from_table
    from vision.video import estimate_video

    cfg = load_config(drive / "config.toml")
    imu, _ = read_log(next(drive.glob("can.*")), cfg.can, cfg.imu)
    fusion_opts, settings = fusion_options_from_table(cfg.extra.get("fusion"))
    offset_s = settings.camera_time_offset_s
    frames = read_frame_times(drive / "frames.csv", cfg.video, None)
    frames = frames.assign(speed_m_s=scale * frame_speeds(imu, frames["t_s"].to_numpy() + offset_s))
    vision, _ = estimate_video(next(drive.glob("video.*")), frames, cfg.camera, cfg.mount, cfg.road,
                               options_from_table(cfg.extra.get("vision")), progress=False)
    run = fuse(imu, vision, lever_arm_m=cfg.imu.position_m, options=fusion_opts, camera_time_offset_s=offset_s)
    truth = pd.read_csv(drive / "truth.csv")
    t0 = float(run.fused["t_s"].iloc[0]) + 2.0
    acc = rmse_table(run.fused, truth, t0, angles=ANGLES)
    return acc, consistency(run.fused, truth, run.cov, t0).fraction_inside


def main(argv=None) -> int:
    from bench_fusion import DRIVES, cached_full_drive

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("drives", nargs="*", default=list(DRIVES))
    ap.add_argument("--scales", nargs="+", type=float, default=[1.0, 1.000000001, 0.999999999, 1.000000002])
    args = ap.parse_args(argv)
    print("Forward filter, RMSE against truth after 2 s [deg] and NEES share, wheel-speed travel x scale")
    print(f"{'drive':<26} {'scale':>12} {'roll':>7} {'pitch':>7} {'yaw':>7} {'bank':>7} {'NEES':>7}")
    spread = {}
    for name in args.drives:
        drive = cached_full_drive(name)
        rows = []
        for scale in args.scales:
            acc, nees = run_once(drive, scale)
            rows.append([acc[a] for a in ANGLES] + [100 * nees])
            print(f"{name:<26} {scale:12.9f} " + " ".join(f"{v:7.3f}" for v in rows[-1][:4]) + f" {rows[-1][4]:6.1f}%",
                  flush=True)
        spread[name] = rows
    print()
    print("Spread over the scales: min / median / max")
    print(f"{'drive':<26} " + " ".join(f"{a:>19}" for a in (*ANGLES, "NEES %")))
    for name, rows in spread.items():
        cells = []
        for k in range(5):
            col = [r[k] for r in rows]
            fmt = "{:.1f}" if k == 4 else "{:.3f}"
            cells.append("/".join(fmt.format(v) for v in (min(col), statistics.median(col), max(col))))
        print(f"{name:<26} " + " ".join(f"{c:>19}" for c in cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
