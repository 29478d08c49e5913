"""How a drive that starts inside a curve converges: the filter alone on a cached drive, cut.

Usage::

    .venv/bin/python tools/fusion_start_in_turn.py [--drive NAME] [START_S ...]

Reads the drive as ``tools/bench_fusion.py`` caches it (``.cache/drives/full-<name>-<key>/`` and
its ``-run/vision.csv``: run the bench once first), runs :func:`fusion.pipeline.fuse` (forward
filter) on the whole drive and on the drive cut to start at each ``START_S`` (default 5, 25 and
30 s of ``banked_curves_60s``: inside the first curve's roll-in, just before the second curve, in
its steady part), then on the cut drives again started from the whole drive's end-of-drive
calibration (``fusion.calibration.calibration_table``, as ``--calibration`` gives), and prints the
world roll's and the bank's RMSE over 0-2, 2-6 and 6-15 s after each start. Seconds: the vision
is not re-run. The README's "A drive that starts in a turn" is its output.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fusion import cached_drive_folder, filter_inputs  # noqa: E402

from fusion.calibration import calibration_table  # noqa: E402
from fusion.options import fusion_options_from_table  # noqa: E402
from fusion.pipeline import fuse  # noqa: E402

WINDOWS_S = ((0.0, 2.0), (2.0, 6.0), (6.0, 15.0))


def rmse(fused, truth, col: str, t0: float, a: float, b: float) -> float:
    m = (fused["t_s"] - t0 >= a) & (fused["t_s"] - t0 < b)
    e = fused[col][m] - np.interp(fused["t_s"][m], truth["t_s"], truth[col])
    return float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drive", default="banked_curves_60s")
    ap.add_argument("starts", nargs="*", type=float, default=[5.0, 25.0, 30.0])
    args = ap.parse_args(argv)
    drive = cached_drive_folder(args.drive)
    run = drive.parent / (drive.name + "-run")
    if not (run / "vision.csv").exists():
        print(f"error: {run / 'vision.csv'} not found: run tools/bench_fusion.py first", file=sys.stderr)
        return 2
    cfg, opts, imu, vision, truth = filter_inputs(drive, run)
    t0, arm = float(imu["t_s"].iloc[0]), cfg.imu.position_m
    whole = fuse(imu, vision, lever_arm_m=arm, options=opts)
    calibrated, _ = fusion_options_from_table({**(cfg.extra.get("fusion") or {}), **calibration_table(whole.fused)})
    print(f"{args.drive}: forward filter, RMSE over the windows after each start, deg "
          f"({' / '.join(f'{a:g}-{b:g} s' for a, b in WINDOWS_S)})")
    print("| start | angle | cut | cut, calibrated | whole drive |")
    print("|---|---|---|---|---|")
    for s in args.starts:
        keep, keep_v = imu["t_s"] - t0 >= s, vision["t_s"] - t0 >= s
        runs = [fuse(imu[keep], vision[keep_v], lever_arm_m=arm, options=o).fused for o in (opts, calibrated)]
        for col in ("roll_world_deg", "bank_deg"):
            cells = [" / ".join(f"{rmse(f, truth, col, t0 + s, a, b):.2f}" for a, b in WINDOWS_S)
                     for f in (*runs, whole.fused)]
            print(f"| {s:g} s | {col.removesuffix('_deg')} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
