"""The filter's gravity reference on a real recording: KITTI OXTS packets as the IMU, the OXTS
INS attitude as truth.

Usage::

    .venv/bin/python tools/fusion_oxts.py [DRIVE_SYNC_FOLDER] [--out DIR]

Default folder: ``../shared/data/kitti_2011_09_26_drive_0001/2011_09_26_drive_0001_sync``.
Runs :func:`fusion.pipeline.fuse` without vision on the packets (:func:`imu.oxts.read_oxts`)
and prints, after the first 2 s, the RMS and largest error of the fused roll and pitch relative
to level against the OXTS attitude, next to the plain accelerometer tilt (no speed, no yaw
rate) on the same packets, and the fused 1-sigma. ``--out`` also writes ``fused.csv`` and the
report (plots against the OXTS truth). Exit status 2 with a one-line error on bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT.parent / "shared" / "data" / "kitti_2011_09_26_drive_0001" / "2011_09_26_drive_0001_sync"
CONVERGED_S = 2.0


def main(argv=None) -> int:
    from fusion.metrics import interp_truth
    from fusion.pipeline import fuse
    from fusion.report import ReportInputs, write_report
    from imu.errors import ImuError
    from imu.oxts import read_oxts

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("drive", nargs="?", type=Path, default=DEFAULT, help="KITTI *_sync folder (or its oxts)")
    p.add_argument("--out", type=Path, help="write fused.csv and the report here")
    args = p.parse_args(argv)
    try:
        imu, truth = read_oxts(args.drive)
    except ImuError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    run = fuse(imu, None)
    f = run.fused
    tr = interp_truth(truth, f["t_s"].to_numpy())
    m = (f["t_s"] >= f["t_s"].iloc[0] + CONVERGED_S).to_numpy()
    tilt = {"roll": np.degrees(np.arctan2(imu["accel_y_m_s2"], imu["accel_z_m_s2"])),
            "pitch": np.degrees(np.arcsin(np.clip(-imu["accel_x_m_s2"] / 9.80665, -1.0, 1.0)))}
    duration = f["t_s"].iloc[-1] - f["t_s"].iloc[0]
    print(f"{args.drive.name}: {len(imu)} OXTS packets, {duration:.1f} s; errors against the OXTS attitude "
          f"after {CONVERGED_S:.0f} s, deg")
    print("| angle | fused RMSE | fused max | accelerometer tilt RMSE | fused 1-sigma (min-max) |")
    print("|---|---|---|---|---|")
    for ang in ("roll", "pitch"):
        e = (f[f"{ang}_world_deg"] - tr[f"{ang}_world_deg"])[m].to_numpy()
        et = (tilt[ang] - truth[f"{ang}_world_deg"])[m].to_numpy()
        s = f[f"{ang}_world_sigma_deg"][m]
        print(f"| {ang} (relative to level) | {np.sqrt(np.mean(e**2)):.3f} | {np.abs(e).max():.3f} | "
              f"{np.sqrt(np.mean(et**2)):.3f} | {s.min():.2f}-{s.max():.2f} |")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        f.to_csv(args.out / "fused.csv", index=False, float_format="%.6f")
        write_report(ReportInputs(fused=f, truth=truth, cov=run.cov, counts=run.counts, warnings=run.warnings,
                                  title=f"KITTI OXTS {args.drive.name}: IMU only"), args.out / "report")
        print(f"wrote {args.out}/fused.csv and {args.out}/report/report.html")
    return 0


if __name__ == "__main__":
    sys.exit(main())
