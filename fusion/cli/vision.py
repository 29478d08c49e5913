"""``vifusion vision --video V [--frames F] --config C --out vision.csv``: the vision estimator
alone, frame by frame (INTERFACE.md), with an optional debug video.

With ``--can LOG`` the wheel speed is read from the drive's CAN log (the config's ``[can]``), and
the estimator is given the distance travelled per frame, as in ``vifusion run``: the road-twist
map (``[vision] road_twist``) then works, and the table is the one ``vifusion run`` writes for
the same drive and workers. Without it the map is off and the summary line says so."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import check_debug_video, check_output_file, mapped_as, refuse_inputs_as_outputs, workers_arg, write_table


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
    p.add_argument("--out", required=True, type=Path, help="output table, .csv or .parquet (written under a temporary name, then renamed)")
    p.add_argument("--can", type=Path, default=None,
                   help="CAN log of the drive: the wheel speed gives the estimator the distance travelled per "
                   "frame (the road-twist map), as in vifusion run")
    p.add_argument("--dbc", type=Path, default=None, help="DBC for --can (default: the config's [can] dbc)")
    p.add_argument("--debug-video", type=Path, default=None, help="also write the debug video here (.mp4 or .avi)")
    p.add_argument("--method", choices=("alrazouk", "damon2018"), default=None,
                   help="estimator (default: the config's [vision] method, else alrazouk)")
    p.add_argument("--preset", choices=("default", "paper", "damon2018"), default=None,
                   help="start from these options instead of the config's [vision] preset")
    p.add_argument("--workers", type=workers_arg, default=None,
                   help="processes for the vision (default: the cores available; 1 with --debug-video); "
                        "the tables do not depend on it")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from vision.options import options_from_table
    from vision.video import count_frames, default_workers, estimate_video

    from ..config import load_config
    from ..drive import frames_warnings, read_frame_times, vision_warnings
    from ..errors import InputError
    from ..options import fusion_options_from_table
    from . import settle_heap

    settle_heap()
    if args.out.suffix.lower() not in (".csv", ".parquet"):
        raise InputError(f"{args.out}: the vision table is written as .csv or .parquet")
    check_output_file(args.out)   # said now, not after every frame
    if args.debug_video is not None:
        check_debug_video(args.debug_video)
    refuse_inputs_as_outputs([args.out, args.debug_video], [args.video, args.frames, args.config, args.can, args.dbc])

    cfg = load_config(args.config)
    _, settings = fusion_options_from_table(cfg.extra.get("fusion"), str(args.config))
    table = dict(cfg.extra.get("vision") or {})
    if args.preset is not None:
        table["preset"] = args.preset
    options = options_from_table(table, str(args.config))
    if args.method is not None and args.method != options.method:
        options = replace(options, method=args.method) if args.method == "alrazouk" else \
            options_from_table({**table, "preset": "damon2018"}, str(args.config))
    frames = read_frame_times(args.frames, cfg.video, None if args.frames else count_frames(args.video))
    warnings = frames_warnings(args.video, frames, args.frames, cfg.video.fps)
    if args.can is not None:
        frames = frames.assign(speed_m_s=_wheel_speeds(args, cfg, frames["t_s"].to_numpy(), settings.camera_time_offset_s))
    elif args.dbc is not None:
        raise InputError("--dbc needs --can (the CAN log it decodes)")
    vision, stats = estimate_video(args.video, frames, cfg.camera, cfg.mount, cfg.road, options,
                                   progress=not args.quiet, debug_video=args.debug_video,
                                   debug_clock_offset_s=settings.camera_time_offset_s,
                                    workers=args.workers or default_workers())
    listed_by = "that frames.csv lists" if args.frames else "counted in the video"
    if not len(vision):
        raise InputError(f"{args.video}: none of the {len(frames)} frames {listed_by} could be read: nothing written")
    warnings += vision_warnings(args.video, vision, stats, len(frames), listed_by)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_table(vision, args.out)
    n = len(vision)
    missing = f"; {stats['frames_missing']} listed frames not in the video" if stats["frames_missing"] else ""
    if stats["frames_unreadable"]:
        missing += f"; {stats['frames_unreadable']} unreadable picture(s) skipped"
    print(f"wrote {args.out}: {n} frames, {stats['valid']} valid ({100 * stats['valid'] / max(n, 1):.0f} %), "
          f"median {stats['median_ms']:.1f} ms/frame ({options.method}, {stats['workers']} worker(s)){missing}"
          + ((f"; debug video {args.debug_video}" if n else "; no debug video written (no frame was processed)")
             if args.debug_video else "")
          + ("; road-twist map off (no wheel speed: --can LOG)" if options.road_twist and args.can is None else ""))
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0


def _wheel_speeds(args: argparse.Namespace, cfg, t_s, offset_s: float):
    """The wheel speed at each frame time (frames.csv's clock plus ``offset_s``, the config's
    ``camera_time_offset_s``), decoded from ``--can`` as ``vifusion run`` does
    (:func:`fusion.drive.frame_speeds`)."""
    import numpy as np

    from imu import read_log

    from ..drive import SPEED_SPAN_WARN_S, check_overlap, frame_speeds, frames_outside_warning
    from ..errors import ConfigError, InputError

    for path in (args.can, args.dbc):
        if path is not None and not path.is_file():
            raise InputError(f"{path}: no such file")
    if cfg.can is None:
        raise ConfigError(f"{args.config}: [can] is missing (the CAN signals of the wheel speed)")
    mapping = cfg.can if args.dbc is None else type(cfg.can)(**{**cfg.can.__dict__, "dbc_path": args.dbc})
    imu, _ = read_log(args.can, mapping, cfg.imu, progress=not args.quiet)
    t = np.asarray(t_s, dtype=float) + offset_s
    check_overlap(t, imu["t_s"].to_numpy(), str(args.frames or args.video), str(args.can))
    # as vifusion run says them (a truncated log had gone without a word here, a review)
    if not imu.attrs.get("complete", True):
        print(f"warning: {args.can}: log incomplete, read up to {imu['t_s'].iloc[-1]:.1f} s: the frames after it "
              "get no wheel speed", file=sys.stderr)
    outside = frames_outside_warning(t, imu["t_s"].to_numpy(), str(args.frames or args.video),
                                     imu.attrs.get("complete", True))
    if outside:
        print(f"warning: {outside}", file=sys.stderr)
    speeds = frame_speeds(imu, t)
    if not np.isfinite(speeds).any():
        raise InputError(f"{args.can}: no wheel speed at any frame ({mapped_as(mapping, 'speed')})")
    missing = ~np.isfinite(speeds)
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    if missing.sum() * period > SPEED_SPAN_WARN_S:
        # said, as `run` says a wheel speed that starts late (it said nothing, a review); a frame
        # or two before the first speed sample is every drive's start, not worth a line
        print(f"warning: {args.can}: no wheel speed at {int(missing.sum())} of {len(t)} frames (the first "
              f"{t[missing][0] - t[0]:.2f} s after the first frame): the road-twist map does not move between them",
              file=sys.stderr)
    return speeds
