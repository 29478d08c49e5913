"""``vifusion simulate SCENARIO.toml --out DIR``: render a drive with exact ground truth."""

from __future__ import annotations

import argparse
import time


def add_parser(sub) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate a drive (video, CAN log, config, truth) from a scenario file",
        description="Simulate a drive from a scenario TOML (see configs/scenarios/) into a folder "
        "in the contract's format, with exact ground truth.",
    )
    p.add_argument("scenario", help="scenario TOML file")
    p.add_argument("--out", required=True, help="output folder (written as OUT.partial, then renamed)")
    p.add_argument("--frames", type=int, default=None, help="render at most this many frames")
    p.add_argument("--no-video", action="store_true", help="write truth, CAN log and config only")
    p.add_argument("--force", action="store_true", help="replace OUT if it exists")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from drivesim.drive import simulate
    from drivesim.scenario import load_scenario

    from ..errors import InputError
    from . import settle_heap

    settle_heap()
    if args.frames is not None and args.frames < 1:    # 0 wrote a drive of no frames, exit 0
        raise InputError(f"--frames must be >= 1 (a drive needs frames), got {args.frames}")
    scenario = load_scenario(args.scenario)
    t0 = time.perf_counter()
    try:
        files = simulate(scenario, args.out, progress=not args.quiet, max_frames=args.frames,
                         render_video=not args.no_video, overwrite=args.force)
    except MemoryError:
        # numpy's 'Unable to allocate' was a traceback (a review); simulate() removed its folder
        raise InputError(f"{args.scenario}: out of memory simulating {scenario.camera.width}x{scenario.camera.height}"
                         f" frames over {scenario.duration_s:g} s: smaller [camera] width and height, or a shorter "
                         "drive") from None
    n = scenario.n_frames if args.frames is None else min(args.frames, scenario.n_frames)
    video = ("no video" if args.no_video else
             f"{n} frames {scenario.camera.width}x{scenario.camera.height} @ {scenario.video.fps:g} fps")
    print(f"wrote {files.root} ({scenario.name}: {scenario.duration_s:g} s of truth and CAN, {video}) "
          f"in {time.perf_counter() - t0:.1f} s")
    return 0
