"""``vifusion run``: vision on the video, IMU from the CAN log, fusion, report.

With no input arguments it runs the bundled sample drive (:data:`fusion.drive.SAMPLE_DRIVE`).
Everything is written into ``OUT.partial`` and renamed to ``OUT`` at the end, so that a run
that stops half-way never leaves files that look complete.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
import time
from pathlib import Path

from . import check_debug_video, mapped_as, refuse_inputs_as_outputs, workers_arg, write_tables

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "run",
        help="estimate attitude and road bank of a drive (video + CAN log), with a report",
        description="Vision on the video, IMU from the CAN log, EKF fusion and road bank angle. "
        "Without --video/--can/--config it runs the bundled sample drive.",
    )
    p.add_argument("--drive", type=Path, help="a drive folder as written by 'vifusion simulate'")
    p.add_argument("--video", type=Path, help="video file or folder of PNG/JPEG frames")
    p.add_argument("--frames", type=Path, help="frames.csv (frame,t_s on the CAN clock)")
    p.add_argument("--can", type=Path, help="CAN log (.asc .blf .log .trc .csv .mf4)")
    p.add_argument("--dbc", type=Path, help="DBC (overrides [can] dbc of the config)")
    p.add_argument("--config", type=Path, help="config TOML")
    p.add_argument("--truth", type=Path, help="truth.csv to compare with (simulated drives)")
    p.add_argument("--out", type=Path, default=Path("out/run"), help="output folder (default out/run)")
    p.add_argument("--smooth", action="store_true", help="forward filter plus RTS smoother (offline)")
    p.add_argument("--calibration", type=Path,
                   help="calibration.toml of an earlier run of this IMU: start from its bias estimates")
    p.add_argument("--estimate-time-offset", action="store_true",
                   help="estimate the camera-to-CAN clock offset from the data and apply it")
    p.add_argument("--debug-video", type=Path, help="also write the vision debug video here")
    p.add_argument("--no-report", action="store_true", help="skip the plots and report.html (report/summary.json is written)")
    p.add_argument("--workers", type=workers_arg, default=None,
                   help="processes for the vision (default: the cores available; 1 with --debug-video); "
                        "the tables do not depend on it")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show tracebacks")
    p.set_defaults(func=run)


def _inputs(args):
    from ..drive import SAMPLE_DRIVE, DriveFiles, find_drive_files
    from ..errors import InputError

    explicit = [a for a in ("video", "can", "config", "frames") if getattr(args, a) is not None]
    if args.drive is not None:
        if explicit:
            raise InputError(f"--drive cannot be combined with --{explicit[0]}")
        files = find_drive_files(args.drive)
    elif not explicit:
        files = find_drive_files(SAMPLE_DRIVE)
    else:
        missing = [a for a in ("video", "can", "config") if getattr(args, a) is None]
        if missing:
            raise InputError(f"--{missing[0]} is required with --{explicit[0]} (or give none to run the sample drive)")
        truth = args.truth
        beside = Path(args.video).parent / "truth.csv"
        if truth is None and beside.is_file():
            # the drive's truth, as with --drive (INTERFACE.md: the report against truth.csv when
            # the drive has one; given file by file, a simulated drive's was left out, a review)
            truth = beside
            print(f"truth: {beside} (the drive's, beside the video; --truth names another)")
        files = DriveFiles(video=args.video, can_log=args.can, config=args.config, frames=args.frames,
                           dbc=args.dbc, truth=truth).check()
    if args.truth is not None and files.truth != args.truth:
        files = DriveFiles(**{**files.__dict__, "truth": args.truth}).check()
    if args.dbc is not None and files.dbc != args.dbc:
        files = DriveFiles(**{**files.__dict__, "dbc": args.dbc}).check()
    return files


def run(args: argparse.Namespace) -> int:
    """``vifusion run``; a run that fails leaves no ``OUT.partial`` behind."""
    try:
        return _run(args)
    except BaseException:
        partial = getattr(args, "partial_dir", None)
        if partial is not None:
            shutil.rmtree(partial, ignore_errors=True)
        raise


def _run(args: argparse.Namespace) -> int:
    from imu import CHANNELS, VALUE_COLUMNS, read_log
    from imu.samples import never_seen
    from vision.options import options_from_table
    from vision.video import default_workers, estimate_video, start_numba

    from ..calibration import (apply_calibration, calibration_table, mount_warnings, pitch_gyro_prior_deg_s,
                               read_calibration, write_calibration)
    from ..config import load_config
    from ..drive import (check_overlap, check_truth_overlap, frame_speeds, frames_outside_warning, frames_warnings,
                         read_frame_times, read_truth, vision_warnings)
    from ..errors import ConfigError, InputError
    from ..options import fusion_options_from_table
    from ..timing import estimate_camera_offset
    # (the filter, fusion.pipeline, and the report are loaded while the vision workers estimate:
    # imu_only_run below)

    from . import STARTED_S, settle_heap

    t_start = getattr(args, "started_s", STARTED_S)   # a campaign starts each drive's clock anew
    timings: dict[str, float] = {}
    warnings: list[str] = []
    progress = not args.quiet
    files = _inputs(args)
    cfg = load_config(files.config)
    if cfg.can is None:
        raise ConfigError(f"{files.config}: [can] is missing (the CAN signals of the IMU)")
    mapping = cfg.can if files.dbc is None else type(cfg.can)(**{**cfg.can.__dict__, "dbc_path": files.dbc})
    vision_opts = options_from_table(cfg.extra.get("vision"), str(files.config))
    fusion_table, fusion_source = cfg.extra.get("fusion") or {}, str(files.config)
    if args.calibration is not None:   # (a campaign reads it before it replaces anything)
        cal = getattr(args, "calibration_table", None) or read_calibration(args.calibration)
        fusion_table = apply_calibration(fusion_table, cal, cfg.imu, args.calibration)
        warnings += mount_warnings(cal, cfg.imu, args.calibration)
        fusion_source += f" with {args.calibration}"
    fusion_opts, settings = fusion_options_from_table(fusion_table, fusion_source)
    smooth = args.smooth or settings.smooth
    offset_s = settings.camera_time_offset_s
    truth = read_truth(files.truth)
    imu_truth = read_truth(files.imu_truth, columns=("t_s",))
    out = args.out.resolve()          # '--out .' names the folder it is
    check_out(out)
    tmp = out.with_name(out.name + ".partial")
    if args.debug_video is not None:
        check_debug_video(args.debug_video)
        refuse_inputs_as_outputs([args.debug_video], [files.video, files.frames, files.can_log, files.dbc, files.config,
                                                      files.truth, files.imu_truth, args.calibration])
        if out in args.debug_video.resolve().parents:
            raise InputError(f"--debug-video {args.debug_video} is inside --out {out}, which the run replaces: "
                             "write it elsewhere")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    args.partial_dir = tmp
    settle_heap()
    # numba's compiler target, which every compiled kernel needs (0.1-0.3 s once a process, as
    # imports are): started here, before the vision workers fork from this process
    start_numba()
    timings["start-up"] = time.perf_counter() - t_start

    # CAN first: it is cheap and fails fast on a bad log or mapping.
    t0 = time.perf_counter()
    imu, summary = read_log(files.can_log, mapping, cfg.imu, progress=progress)
    timings["CAN decode"] = time.perf_counter() - t0
    unavailable = set(imu.attrs.get("unavailable", ()))
    essential = {"gyro_x_rad_s", "gyro_z_rad_s", "accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2", "speed_m_s"}
    never = never_seen(imu)
    missing = sorted((unavailable | set(never)) & essential)
    if missing:
        channel = dict(zip(VALUE_COLUMNS, CHANNELS))[missing[0]]
        raise InputError(f"{files.can_log}: IMU channel {missing[0]} never seen (needed by the filter; "
                         f"{mapped_as(mapping, channel)})" + _never_seen_why(summary, missing[0]))
    if truth is not None:
        check_truth_overlap(truth, imu["t_s"].to_numpy(), files.truth, files.can_log)
    has_pitch_rate = "gyro_y_rad_s" not in unavailable and "gyro_y_rad_s" not in never
    if not has_pitch_rate:
        warnings.append("no pitch-rate channel: pitch rate reconstructed as yaw rate * tan(roll), less a "
                        "modelled pitch rate it leaves out")
    if not imu.attrs.get("complete", True):
        why = imu.attrs.get("summary", {}).get("stop_reason") or "truncated"
        end = imu["t_s"].iloc[-1] - imu["t_s"].iloc[0]
        warnings.append(f"{files.can_log}: log incomplete, read up to {end:.1f} s ({why}): "
                        "the fused table ends there")
    warnings += _can_problems(summary, files.can_log)
    gaps = imu.attrs.get("gaps", [])
    for source, start_s, duration_s in gaps[:5]:
        warnings.append(f"CAN gap: no {source} frames for {duration_s:.3f} s from {start_s:.3f} s (never interpolated)")
    if len(gaps) > 5:
        warnings.append(f"CAN gaps: {len(gaps) - 5} more")

    frames = read_frame_times(files.frames, cfg.video, None if files.frames else _count_frames(files.video))
    frame_t, imu_t, frames_name = frames["t_s"].to_numpy() + offset_s, imu["t_s"].to_numpy(), str(files.frames or files.video)
    check_overlap(frame_t, imu_t, frames_name, str(files.can_log))
    outside = frames_outside_warning(frame_t, imu_t, frames_name, imu.attrs.get("complete", True))
    warnings += ([outside] if outside else []) + frames_warnings(files.video, frames, files.frames, cfg.video.fps)

    # the wheel speed at each frame: the estimator carries the road's twist by the distance travelled
    frames = frames.assign(speed_m_s=frame_speeds(imu, frame_t))

    imu_only_box: dict = {}

    def imu_only_run() -> None:
        # Needs no vision: done while the vision workers estimate, and so is loading the filter
        # (filterpy, which loads scipy.stats) and the report (0.7-1.1 s of imports, measured by
        # python -X importtime): the workers fork from this process without them.
        from ..pipeline import fuse
        imu_only_box["run"] = fuse(imu, None, lever_arm_m=cfg.imu.position_m, has_pitch_rate=has_pitch_rate,
                                   options=fusion_opts)
        from .. import report  # noqa: F401

    t0 = time.perf_counter()
    vision, vstats = estimate_video(files.video, frames, cfg.camera, cfg.mount, cfg.road, vision_opts,
                                    progress=progress, debug_video=args.debug_video,
                                    # the strip's CAN clock as the fusion has it (an estimated offset
                                    # comes after the video: --estimate-time-offset)
                                    debug_clock_offset_s=offset_s,
                                    workers=args.workers or default_workers(), while_waiting=imu_only_run)
    timings["vision"] = time.perf_counter() - t0
    if args.debug_video is not None and not len(vision):
        warnings.append(f"no debug video written to {args.debug_video}: no frame was processed")
    for w in vision_warnings(files.video, vision, vstats, len(frames),
                             "that frames.csv lists" if files.frames else "counted in the video"):
        warnings.append(w + (": the fused angles relative to the road rest on the IMU and the last bank estimate "
                             "elsewhere" if w.startswith("vision valid") else ""))
    t0 = time.perf_counter()
    write_tables(vision, tmp / "vision")
    timings["outputs"] = time.perf_counter() - t0   # the tables grow with the drive: not a fixed cost

    from ..pipeline import frame_gap_limit_s, frames_to_samples, fuse, plain_bank
    from ..report import ReportInputs, write_report

    time_offset = None
    if args.estimate_time_offset or settings.estimate_time_offset:
        # the correction to the configured offset, applied where the data tell it from zero
        est = estimate_camera_offset(vision.assign(t_s=vision["t_s"] + offset_s), imu)
        applied = est.ok and abs(est.offset_s) > OFFSET_SIGNIFICANCE * est.sigma_s
        time_offset = {"offset_s": est.offset_s, "sigma_s": est.sigma_s, "correlation": est.correlation,
                       "frames": est.n_frames, "reason": est.reason or None,   # null where estimated (it was "", a review)
                       "configured_s": offset_s, "applied": applied}
        if applied:
            offset_s += est.offset_s
        elif not est.ok:   # (an estimate within 2 sigma of the configured offset confirms it: no
            # warning, the printed line and summary.json say it; it was a warning, a review)
            warnings.append(f"camera time offset not estimable: {est.reason}")

    t0 = time.perf_counter()
    fused = fuse(imu, vision, lever_arm_m=cfg.imu.position_m, has_pitch_rate=has_pitch_rate, options=fusion_opts,
                 smooth=smooth, camera_time_offset_s=offset_s, progress=progress)
    imu_only = imu_only_box["run"]
    pb = plain_bank(imu_only.fused, vision, offset_s, fusion_opts.max_imu_gap_s)
    table = fused.fused.copy()
    table["roll_world_imu_only_deg"] = imu_only.fused["roll_world_deg"].to_numpy()
    table["pitch_world_imu_only_deg"] = imu_only.fused["pitch_world_deg"].to_numpy()   # the summary scores both
    table["bank_plain_deg"] = frames_to_samples(table["t_s"].to_numpy(), pb["t_s"].to_numpy(), pb["bank_plain_deg"].to_numpy(),
                                                frame_gap_limit_s(vision["t_s"].to_numpy()))
    timings["fusion"] = time.perf_counter() - t0
    warnings += fused.warnings
    t0 = time.perf_counter()
    write_tables(table, tmp / "fused")
    calibration = None
    try:
        calibration = calibration_table(fused.fused, None if has_pitch_rate else pitch_gyro_prior_deg_s(fusion_opts.noise))
        write_calibration(calibration, tmp / "calibration.toml",
                          f"{files.can_log} ({'smoothed' if smooth else 'forward filter'})", cfg.imu)
    except ValueError as e:   # a filter that ended without finite biases: nothing to carry on
        warnings.append(f"no calibration.toml written: {e}")
    timings["outputs"] += time.perf_counter() - t0

    # summary.json always (warnings, counts, the time offset, accuracy): --no-report skips the plots
    t0 = time.perf_counter()
    summary_out = write_report(ReportInputs(
        fused=fused.fused, vision=vision, imu_only=imu_only.fused, plain_bank=pb, truth=truth,
        imu_truth=imu_truth, cov=fused.cov, counts={**fused.counts, **_can_counts(summary.as_dict())},
        timings_s=timings, time_offset=time_offset, warnings=warnings, smoothed=smooth,
        title=f"vifusion run: {files.video.parent.name}/{files.video.name}", camera_time_offset_s=offset_s,
        # the files used, as absolute paths (a relative one means nothing away from where the run
        # was started), the DBC the decode used: --dbc's or the config's [can] dbc (null had said
        # none where the config gave it, a review)
        inputs={k: _absolute(v) for k, v in (("video", files.video), ("frames", files.frames),
                ("can_log", files.can_log), ("dbc", mapping.dbc_path), ("config", files.config), ("truth", files.truth))},
        imu_calibration=calibration, calibration_from=_absolute(args.calibration)), tmp / "report",
        plots=not args.no_report)
    timings["report"] = time.perf_counter() - t0

    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)
    if args.calibration is not None:   # (the summary.json says it too: calibration_from)
        print(f"IMU biases started from {args.calibration}")
    _print_summary(out, files, frames, imu, timings, warnings, summary_out, time_offset, time.perf_counter() - t_start,
                   getattr(args, "warning_prefix", ""), args.debug_video)
    return 0


def _absolute(path: Path | None) -> str | None:
    """An input's path for summary.json: absolute, links resolved."""
    return None if path is None else str(Path(path).resolve())


def _can_problems(summary, log) -> list[str]:
    """Warnings for the mapped frames the decoder did not use and the lines it could not read
    (``vifusion can`` lists them per message): the samples they belonged to are missing or
    incomplete."""
    from imu.samples import SKIP_KINDS

    kinds = [k for k in SKIP_KINDS if k != "other_channel"]   # the channel the config picked: expected
    out = []
    for s in summary.sources:
        counts = {k: getattr(s, k) for k in kinds if getattr(s, k)}
        if counts:
            listed = ", ".join(f"{k.replace('_', ' ')} {n}" for k, n in counts.items())
            out.append(f"{log}: {s.name} ({s.frame_id}): {sum(counts.values())} frames not used ({listed}; "
                       "vifusion can lists them)")
    out += [f"{log}: {line}" for line in summary.range_lines()]
    if summary.bad_lines:   # with the reader's first word on them (which line, what was wrong)
        first = next((p for p in summary.problems if "skipped" in p), "")
        out.append(f"{log}: {summary.bad_lines} unreadable {'records' if log.suffix.lower() == '.mf4' else 'lines'} "
                   f"skipped" + (f" ({first})" if first else ""))
    return out


def _never_seen_why(summary, column: str) -> str:
    """Why a mapped channel has no value: its frames came, but every value was outside the DBC's
    range (``range_check``); said, as the frames were read (a review: "never seen" for 1201
    frames that arrived)."""
    for c in summary.channels:
        if c.column == column and summary.range_check and c.out_of_range and not c.decoded:
            return (f": all {c.out_of_range} of its values were outside the DBC's range{c.dbc_range} "
                    "([can] range_check = false keeps them)")
    return ""


def _can_counts(can: dict) -> dict:
    """The CAN log's totals as rows of the report's run table (the decoder's summary,
    :meth:`imu.samples.Summary.as_dict`)."""
    rate = can.get("sample_rate_hz")
    # the read frames, each in one row (a review: "of other IDs" left out the IDs not in the DBC,
    # and the rows did not add up to the frames read)
    # (snake_case keys as the filter's counts beside them: they were phrases, "IMU sample rate
    # [Hz]", a review; can_frames_read is the sum of the four rows after it)
    return {"can_frames_read": can.get("frames_read"), "can_frames_decoded": can.get("frames_mapped"),
            "can_frames_other_messages": can.get("unmapped_frames"),
            "can_frames_unknown_ids": sum((can.get("unknown_ids") or {}).values())
            + (can.get("unknown_more_frames") or 0),      # a live summary's IDs past the first 1000
            "can_error_frames": can.get("error_frames"), "imu_samples_decoded": can.get("samples"),
            "imu_rate_hz": round(rate, 1) if isinstance(rate, float) else rate}


def _count_frames(video: Path) -> int:
    from vision.video import count_frames

    return count_frames(video)


#: An estimated camera-offset correction is applied when it is more than this many of its
#: sigmas from zero (fusion.timing).
OFFSET_SIGNIFICANCE = 2.0

#: What a run writes into its ``--out`` folder: an existing folder holding only these is replaced.
RUN_OUTPUTS = frozenset({"vision.csv", "vision.parquet", "fused.csv", "fused.parquet", "calibration.toml", "report"})
#: What a run writes into ``report/`` (:func:`fusion.report.write_report`).
REPORT_OUTPUTS = frozenset({"report.html", "summary.json", "attitude.png", "world.png", "errors.png", "road.png",
                            "biases.png"})


def _not_written_by_a_run(folder: Path) -> list[str]:
    """What ``folder`` holds that no run writes there (nor one cut short: ``NAME.partial``),
    ``report/`` included."""
    def foreign(names, allowed):
        return sorted(n for n in names if n not in allowed and not (n.endswith(".partial") and n[:-8] in allowed))

    other = foreign((p.name for p in folder.iterdir()), RUN_OUTPUTS)
    report = folder / "report"
    if report.is_dir():
        other += [f"report/{n}" for n in foreign((p.name for p in report.iterdir()), REPORT_OUTPUTS)]
    elif report.exists():
        other.append("report (a file)")
    return other


def check_out(out: Path) -> None:
    """``--out`` must be new, or a folder an earlier run wrote (replaced at the end): a folder
    with anything else in it, ``report/`` included, is left alone, not emptied. The same holds for
    ``OUT.partial``, the folder the run writes into first (a review found a user's files in both
    deleted)."""
    from ..errors import InputError

    if not out.name:
        raise InputError(f"--out {out}: the root is not an output folder")
    for folder, what in ((out, "--out"), (out.with_name(out.name + ".partial"), "the run's temporary folder")):
        if folder.exists() and not folder.is_dir():
            raise InputError(f"{what} {folder} is a file, not a folder")
        if folder.is_dir():
            other = _not_written_by_a_run(folder)
            if other:
                raise InputError(f"{what} {folder} holds files a run did not write ({', '.join(other[:3])}"
                                 f"{', ...' if len(other) > 3 else ''}): give a new or empty folder")


def _offset_line(t: dict) -> str:
    """The camera-offset estimate of ``summary.json``'s ``time_offset`` as one line."""
    if t.get("reason"):
        return f"not estimated ({t['reason']})"
    corr = 1e3 * t["offset_s"]
    return (f"correction {corr:+.1f} +- {1e3 * t['sigma_s']:.1f} ms to the configured {1e3 * t['configured_s']:g} ms "
            f"(peak correlation {t['correlation']:.2f}, {t['frames']} frames): "
            + ("applied" if t["applied"] else f"not applied (within {OFFSET_SIGNIFICANCE:g} sigma)"))


def _print_summary(out, files, frames, imu, timings, warnings, summary, time_offset, total_s, prefix="",
                   debug_video=None) -> None:
    from ..report import source_name

    drive_s = float(frames["t_s"].iloc[-1] - frames["t_s"].iloc[0]) if len(frames) > 1 else math.nan
    cal = f", {out}/calibration.toml" if (out / "calibration.toml").is_file() else ""
    report = "report.html" if (out / "report" / "report.html").is_file() else "summary.json"
    video = f", debug video {debug_video}" if debug_video is not None and Path(debug_video).is_file() else ""
    print(f"wrote {out}/vision.csv, {out}/fused.csv{cal}, {out}/report/{report}{video}")
    fixed = timings.get("start-up", 0.0) + timings.get("report", 0.0)
    per_drive = total_s - fixed
    share = (f" = {100 * per_drive / drive_s:.1f} % of the drive's duration" if drive_s > 0
             else " (one frame: no duration to compare with)")
    print(f"time: total {total_s:.1f} s for a {drive_s if drive_s > 0 else 0.0:.1f} s drive; fixed costs {fixed:.1f} s "
          f"(start-up {timings.get('start-up', 0):.1f}, report {timings.get('report', 0):.1f}); "
          f"the rest {per_drive:.1f} s{share} "
          f"(vision {timings.get('vision', 0):.1f}, CAN {timings.get('CAN decode', 0):.1f}, fusion {timings.get('fusion', 0):.1f}, "
          f"outputs {timings.get('outputs', 0):.1f})")
    if time_offset:
        print(f"camera time offset: {_offset_line(time_offset)}")
    if summary and summary.get("rmse_deg"):
        for src, vals in summary["rmse_deg"].items():
            cells = ", ".join(f"{k} {v:.3f}" for k, v in (vals or {}).items()
                              if isinstance(v, float) and math.isfinite(v) and k != "valid_fraction")
            # a source without a value is left out ('nan' had been printed as one, a review)
            if cells:
                print(f"RMSE vs truth [deg] {source_name(src, summary.get('smoothed'))}: {cells}")
    for w in (summary or {}).get("warnings", warnings):   # the report's adds its own
        print(f"warning: {prefix}{w}", file=sys.stderr)
