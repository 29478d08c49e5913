"""A camera clock off the CAN clock: what it costs the bank, and whether the gate's share says it.

Usage::

    .venv/bin/python tools/bench_clock_offset.py     # the benchmark drives (renders what is not cached)

For each drive of ``tools/bench_fusion.py`` (and the bundled 640x360 sample drive) it runs
``vifusion run`` once (its ``-run`` folder is reused when the bench left one), then the forward
filter on that run's vision with the frame times shifted by each of :data:`SHIFTS_S`, and
prints per shift the vision results the filter's gate refused of those it decided on, and the
bank's RMSE against the truth after 2 s. A run warns above
:data:`fusion.pipeline.VISION_REFUSED_WARN` of them refused (README, "Fusion").
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_fusion import CACHE, DRIVES, SAMPLE, cached_full_drive, filter_inputs, run_cli  # noqa: E402

#: Frame-time shifts (s, added to the times on the CAN clock): late and early.
SHIFTS_S = (0.0, 0.05, 0.1, -0.1, 0.2, 0.5, -0.5)


def refusals(drive: Path, run_dir: Path) -> list[tuple[int, int, float]]:
    """Per shift of :data:`SHIFTS_S`: (refused, decided, bank RMSE in deg after 2 s, as the
    report scores it: :func:`fusion.metrics.rmse_table`)."""
    from fusion.metrics import rmse_table
    from fusion.pipeline import fuse

    cfg, opts, imu, vision, truth = filter_inputs(drive, run_dir)
    out = []
    for shift in SHIFTS_S:
        r = fuse(imu, vision.assign(t_s=vision["t_s"] + shift), lever_arm_m=cfg.imu.position_m, options=opts)
        bank = rmse_table(r.fused, truth, float(r.fused["t_s"].iloc[0]) + 2.0, angles=("bank",))["bank"]
        refused = r.counts["vision_rejected"]
        out.append((refused, refused + r.counts["vision_used"], bank))
    return out


def main() -> int:
    from fusion.drive import SAMPLE_DRIVE

    rows = []
    for name in (*DRIVES, SAMPLE):
        drive = SAMPLE_DRIVE if name == SAMPLE else cached_full_drive(name)
        run_dir = CACHE / f"{SAMPLE}-run" if name == SAMPLE else drive.parent / (drive.name + "-run")
        if not (run_dir / "vision.csv").exists():
            run_cli(drive, run_dir, "--no-report")
        rows.append((name, refusals(drive, run_dir)))
        print(f"{name} done", file=sys.stderr, flush=True)
    print("| drive | " + " | ".join("0" if s == 0 else f"{s:+g} s" for s in SHIFTS_S) + " |")
    print("|---|" + "---|" * len(SHIFTS_S))
    for name, cells in rows:
        print(f"| {name} | " + " | ".join(f"{r}/{n}, {b:.3f}" for r, n, b in cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
