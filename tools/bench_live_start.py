"""The first calls of a live drive, with and without ``LiveFusion.warm_up()``.

Each run is a fresh process (the compiled kernels load once per process): the bundled sample
drive's first 40 frames and their CAN messages pushed as they come, the worst ``push_frame``
and ``push_can`` times over them, and what ``warm_up()`` took. Prints the median of ``--runs``
processes each way and the ratio against the cold start measured in the same run.

    .venv/bin/python tools/bench_live_start.py [--runs 3]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys

_ONE_RUN = r"""
import json, sys, time
import can
from fusion.config import load_config
from fusion.drive import SAMPLE_DRIVE, find_drive_files, read_frame_times
from fusion.realtime import LiveFusion
from vision.video import FrameSource

files = find_drive_files(SAMPLE_DRIVE)
cfg = load_config(files.config)
frames = read_frame_times(files.frames, cfg.video)
messages = list(can.LogReader(files.can_log))
images = [img for _, img in zip(range(40), FrameSource(files.video).grey_frames())]
live = LiveFusion(cfg)
warm = live.warm_up() if sys.argv[1] == "1" else 0.0
worst_frame = worst_can = 0.0
j = 0
for t, image in zip(frames["t_s"], images):
    while j < len(messages) and messages[j].timestamp <= t:
        t0 = time.perf_counter()
        live.push_can(messages[j])
        worst_can = max(worst_can, time.perf_counter() - t0)
        j += 1
    t0 = time.perf_counter()
    live.push_frame(t, image)
    worst_frame = max(worst_frame, time.perf_counter() - t0)
print(json.dumps({"warm_up_s": warm, "frame_ms": 1e3 * worst_frame, "can_ms": 1e3 * worst_can}))
"""


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=3, help="fresh processes each way (default 3)")
    args = p.parse_args(argv)
    rows = {}
    for warm in ("0", "1"):
        runs = [json.loads(subprocess.run([sys.executable, "-c", _ONE_RUN, warm], capture_output=True, text=True,
                                          check=True).stdout.strip().splitlines()[-1]) for _ in range(args.runs)]
        rows[warm] = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    cold = rows["0"]
    print(f"first 40 frames of the sample drive through LiveFusion, median of {args.runs} fresh processes each")
    print(f"{'':24}{'worst push_frame':>18}{'worst push_can':>16}{'warm_up()':>11}")
    for warm, name in (("0", "cold start"), ("1", "after warm_up()")):
        r = rows[warm]
        print(f"{name:24}{r['frame_ms']:>15.1f} ms{r['can_ms']:>13.1f} ms{r['warm_up_s']:>9.2f} s"
              + ("" if warm == "0" else f"   (x{r['frame_ms'] / cold['frame_ms']:.2f} / x{r['can_ms'] / cold['can_ms']:.2f})"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
