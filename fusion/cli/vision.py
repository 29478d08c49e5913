"""``vifusion vision --video V [--frames F] --config C --out vision.csv``: the vision estimator
alone, frame by frame (INTERFACE.md), with an optional debug video."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from . import workers_arg


def add_parser(sub) -> None:
    p = sub.add_parser(
        "vision",
        help="estimate roll, pitch and yaw relative to the road from a video (vision.csv)",
        description="Run the vision estimator (Alrazouk et al. 2024, or the 2018 roll loop of Damon et al.) "
        "on a video or a folder of frames and write vision.csv: t_s, frame, roll_deg, pitch_deg, yaw_deg, "
        "valid and quality columns. Options of the estimator come from the config's [vision] table.",
    )
    p.add_argument("--video", required=True, type=Path, help="video file, or folder of PNG/JPEG frames (name order)")
    p.add_argument("--frames", type=Path, default=None,
                   help="frames.csv (frame,t_s); without it, times are [video] start_s + frame / fps")
    p.add_argument("--config", required=True, type=Path, help="config TOML ([camera], [mount], [road], [vision])")
    p.add_argument("--out", required=True, type=Path, help="output CSV (written as OUT.partial, then renamed)")
    p.add_argument("--debug-video", type=Path, default=None, help="also write the debug video here (.mp4 or .avi)")
    p.add_argument("--method", choices=("alrazouk", "damon2018"), default=None,
                   help="estimator (default: the config's [vision] method, else alrazouk)")
    p.add_argument("--preset", choices=("default", "paper", "damon2018"), default=None,
                   help="start from these options instead of the config's [vision] preset")
    p.add_argument("--workers", type=workers_arg, default=None,
                   help="processes for the vision (default: the cores available; 1 with --debug-video)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from vision.options import options_from_table
    from vision.video import count_frames, default_workers, estimate_video

    from ..config import load_config
    from ..drive import read_frame_times

    cfg = load_config(args.config)
    table = dict(cfg.extra.get("vision") or {})
    if args.preset is not None:
        table["preset"] = args.preset
    options = options_from_table(table, str(args.config))
    if args.method is not None and args.method != options.method:
        options = replace(options, method=args.method) if args.method == "alrazouk" else \
            options_from_table({**table, "preset": "damon2018"}, str(args.config))
    frames = read_frame_times(args.frames, cfg.video, None if args.frames else count_frames(args.video))
    vision, stats = estimate_video(args.video, frames, cfg.camera, cfg.mount, cfg.road, options,
                                   progress=not args.quiet, debug_video=args.debug_video,
                                    workers=args.workers or default_workers())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_name(args.out.name + ".partial")
    vision.to_csv(tmp, index=False, float_format="%.6f")
    os.replace(tmp, args.out)
    n = len(vision)
    missing = f"; {stats['frames_missing']} listed frames not in the video" if stats["frames_missing"] else ""
    print(f"wrote {args.out}: {n} frames, {stats['valid']} valid ({100 * stats['valid'] / max(n, 1):.0f} %), "
          f"median {stats['median_ms']:.1f} ms/frame ({options.method}, {stats['workers']} worker(s)){missing}"
          + (f"; debug video {args.debug_video}" if args.debug_video else ""))
    return 0
