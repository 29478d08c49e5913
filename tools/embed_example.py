"""Embedding vifusion: a CAN bus thread and a camera thread feeding one LiveFusion.

The bundled sample drive stands in for a vehicle: a sender thread plays its CAN log onto
python-can's ``virtual`` bus (the recorded stamps kept, as a logger's hardware stamps would be),
a camera thread hands each frame of its video to the filter once the bus clock has passed the
frame's capture time (as a camera with its own grab loop would), and the main thread reads the
bus, prints the estimate once a second of bus time, and saves the IMU calibration at the end.
On a vehicle, replace the sender by the real bus (``can.Bus(interface="socketcan", ...)``) and
the camera thread by the camera's grab loop; the rest stays.

Usage::

    .venv/bin/python tools/embed_example.py [--realtime] [--out DIR] [--drive DIR]

Without ``--realtime`` the drive runs as fast as the machine allows: the bus reader then waits
for the camera when it is more than 0.15 s ahead of it (on a vehicle the two keep pace by
themselves), so that frames are not older than the filter's history when they arrive.
"""

from __future__ import annotations

import argparse
import math
import resource
import sys
import threading
import time
from pathlib import Path

import can
import pandas as pd

from fusion.calibration import write_calibration
from fusion.drive import SAMPLE_DRIVE
from fusion.realtime import LiveFusion
from vision.video import FrameSource

CHANNEL = "vifusion-embed-example"
#: The camera may lag the bus by this much before the bus reader waits (fast replay only), s.
MAX_CAMERA_LAG_S = 0.15


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realtime", action="store_true", help="send the CAN frames at their recorded pace")
    ap.add_argument("--out", type=Path, default=Path("out/embed_example"), help="where calibration.toml goes")
    ap.add_argument("--drive", type=Path, default=SAMPLE_DRIVE,
                    help="a drive folder as 'vifusion simulate' writes it (default: the bundled sample)")
    args = ap.parse_args(argv)

    drive = args.drive
    if not (drive / "config.toml").is_file() or not (drive / "frames.csv").is_file():
        ap.error(f"{drive}: not a drive folder as 'vifusion simulate' writes it (config.toml, frames.csv, ...)")
    live = LiveFusion(drive / "config.toml")           # a config file's path, or a DriveConfig
    live.warm_up()        # the compiled kernels loaded now, not in the first frames' calls
    frames = pd.read_csv(drive / "frames.csv")         # capture times on the bus clock
    bus_t = [-math.inf]                                # the newest IMU sample's time (the bus clock)
    due_t = [frames["t_s"].iloc[0]]                    # the capture time of the camera's next frame
    stop = threading.Event()

    def vehicle(bus: can.BusABC) -> None:              # the vehicle's ECUs
        msgs = can.LogReader(next(drive.glob("can.*")))
        for msg in can.MessageSync(msgs) if args.realtime else msgs:
            bus.send(msg)

    def camera() -> None:                              # the camera's grab loop
        grey = FrameSource(drive / "video.mp4").grey_frames()   # the decoded luma, as offline
        for t_s, image in zip(frames["t_s"], grey):
            due_t[0] = t_s
            while bus_t[0] < t_s and not stop.is_set():          # not captured yet
                time.sleep(0.001)
            if stop.is_set():
                return
            live.push_frame(t_s, image)                # the estimator runs here, outside the filter's lock
        due_t[0] = math.inf

    with can.Bus(interface="virtual", channel=CHANNEL, preserve_timestamps=True) as tx, \
            can.Bus(interface="virtual", channel=CHANNEL, preserve_timestamps=True) as rx:
        ecus = threading.Thread(target=vehicle, args=(tx,), daemon=True)
        ecus.start()
        cam = threading.Thread(target=camera, daemon=True)
        cam.start()
        t0, shown = None, 0
        print(f"{'t':>6}  {'roll':>14}  {'pitch':>14}  {'bank':>14}  "
              "(deg, 1-sigma; roll and pitch relative to the road, bank of the road to level)")
        try:
            while True:
                msg = rx.recv(timeout=1.0)
                if msg is None:
                    if ecus.is_alive():                # a quiet bus: wait for it (on a vehicle: for ever)
                        continue
                    break                              # the recorded drive is over
                # a frame is due, captured, and not handed in yet: let the camera catch up (not
                # across a gap in the bus, nor for a stamp far ahead: the camera waits for the
                # IMU's clock, which a glitch does not move)
                while (not args.realtime and msg.timestamp - due_t[0] > MAX_CAMERA_LAG_S
                       and bus_t[0] >= due_t[0] and cam.is_alive()):
                    time.sleep(0.001)
                live.push_can(msg)
                if live.samples:
                    bus_t[0] = live.stream.t_s
                t0 = msg.timestamp if t0 is None else t0
                if msg.timestamp - t0 >= shown + 1.0 and live.samples:
                    shown = math.floor(msg.timestamp - t0)
                    e = live.estimate()
                    cells = [f"{math.degrees(a):+6.2f} +- {math.degrees(s):4.2f}" for a, s in
                             ((e.roll_rad, e.roll_sigma_rad), (e.pitch_rad, e.pitch_sigma_rad), (e.bank_rad, e.bank_sigma_rad))]
                    print(f"{e.t_s - t0:5.1f}s  " + "  ".join(cells), flush=True)
        finally:
            stop.set()
            cam.join(timeout=5)
    args.out.mkdir(parents=True, exist_ok=True)
    write_calibration(live.calibration(), args.out / "calibration.toml", "tools/embed_example.py (LiveFusion)",
                      mount=live.mount)
    # what the process took at most: the embedding's footprint (Linux reports kB)
    print(f"peak resident memory of this process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    print(f"{live.samples} IMU samples, vision used {live.stream.counts['vision_used']} times "
          f"({live.stream.counts['vision_late']} late), warnings: {live.warnings or 'none'}; "
          f"wrote {args.out / 'calibration.toml'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
