"""The files of one drive (INTERFACE.md, "Drive on disk"), checked before any work starts.

Every problem is one line naming the file: a missing file, a ``frames.csv`` that is not
``frame,t_s`` with increasing finite times, a drive whose video and CAN log do not overlap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from imu.log_source import log_suffix

from .config import VideoTiming
from .errors import InputError

__all__ = ["DriveFiles", "SAMPLE_DRIVE", "SIMULATION_MARKER", "SPEED_MAX_AGE_S", "SPEED_SPAN_WARN_S", "find_drive_files", "frame_speeds",
           "last_speed", "read_frame_times", "read_truth"]

#: The bundled sample drive (a simulated 12 s banked right-hand curve, 640x360 at 30 fps),
#: rendered from ``configs/scenarios/sample_banked_curve.toml``.
SAMPLE_DRIVE = Path(__file__).resolve().parent / "data" / "sample_drive"

#: The file ``vifusion simulate`` writes first into its ``OUT.partial`` folder and removes just
#: before renaming it: a ``.partial`` folder holding it is an unfinished simulation however early
#: it was killed (a review's SIGKILL while the CAN log was written left ``can.asc`` alone, which
#: the simulator then refused as not its own).
SIMULATION_MARKER = ".vifusion-simulating"


@dataclass(frozen=True)
class DriveFiles:
    """Input files of a run; the truth files exist only for simulated drives."""

    video: Path
    can_log: Path
    config: Path
    frames: Path | None = None
    dbc: Path | None = None
    truth: Path | None = None
    truth_frames: Path | None = None
    imu_truth: Path | None = None

    def check(self) -> "DriveFiles":
        for name in ("video", "can_log", "config", "frames", "dbc"):
            p = getattr(self, name)
            if p is not None and not Path(p).exists():
                raise InputError(f"{p}: no such file ({name.replace('_', ' ')})")
        if Path(self.can_log).is_dir():
            raise InputError(f"{self.can_log}: is a directory, expected a CAN log")
        return self


def find_drive_files(root: str | Path) -> DriveFiles:
    """The files of a drive folder written by ``vifusion simulate`` (or laid out like one)."""
    root = Path(root)
    if root.exists() and not root.is_dir():
        raise InputError(f"{root}: is a file, not a drive folder (--drive takes the folder 'vifusion simulate' "
                         "writes; a single file goes with --video, --can, ...)")
    if not root.is_dir():
        raise InputError(f"{root}: no such drive folder")
    if root.name.endswith(".partial") and any((root / n).is_file() for n in (SIMULATION_MARKER, "imu_truth.csv")):
        # a simulation killed before it renamed its folder: its frames stop where it was (a
        # review ran one with 47 of 90 frames, a warning the only sign)
        raise InputError(f"{root}: an unfinished simulation (still named .partial): simulate the drive again")
    videos = [p for p in (root / "video.mp4", root / "video.avi", root / "video") if p.exists()]
    kinds = (".asc", ".blf", ".log", ".trc", ".csv", ".mf4")
    logs = sorted(p for p in root.glob("can.*") if log_suffix(p)[0] in kinds)
    if not videos:
        raise InputError(f"{root}: no video.mp4, video.avi or video/ folder")
    if not logs:
        raise InputError(f"{root}: no can.<asc|blf|log|trc|csv|mf4>[.gz] log")
    # more than one of either: which is the drive's is not for the program to guess (a review:
    # can.asc was taken beside can.blf without a word)
    for found, what, option in ((videos, "videos", "--video"), (logs, "CAN logs", "--can")):
        if len(found) > 1:
            raise InputError(f"{root}: {len(found)} {what} ({', '.join(p.name for p in found)}): give the one to use "
                             f"with {option} and the other files with --frames, --config ...")

    def opt(name):
        p = root / name
        return p if p.exists() else None

    return DriveFiles(video=videos[0], can_log=logs[0], config=root / "config.toml", frames=opt("frames.csv"),
                      truth=opt("truth.csv"), truth_frames=opt("truth_frames.csv"),
                      imu_truth=opt("imu_truth.csv")).check()


#: The largest frame number frames.csv may give: a year of video at 1000 frames/s, far under
#: the 2^63 at which the conversion to integers wraps.
MAX_FRAME = 1e12


def read_frame_times(frames_csv: Path | None, timing: VideoTiming, n_frames: int | None = None) -> pd.DataFrame:
    """``frame,t_s`` of every frame, on the CAN log's clock.

    From ``frames.csv`` when given (checked: the two columns, integer frames and finite times,
    both strictly increasing), else ``t = start_s + frame / fps`` for ``n_frames`` frames.
    """
    if frames_csv is None:
        if n_frames is None:
            raise InputError("no frames.csv and no frame count to derive frame times from")
        f = np.arange(n_frames)
        return pd.DataFrame({"frame": f, "t_s": timing.start_s + f / timing.fps})
    try:
        df = pd.read_csv(frames_csv)
        df.columns = [str(c).strip() for c in df.columns]     # 'frame, t_s' as written by hand
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise InputError(f"{frames_csv}: not a CSV file ({' '.join(str(e).split())})") from None
    missing = [c for c in ("frame", "t_s") if c not in df.columns]
    if missing:
        raise InputError(f"{frames_csv}: needs columns frame,t_s (missing {', '.join(missing)})")
    if df.empty:
        raise InputError(f"{frames_csv}: has no rows")
    frame = pd.to_numeric(df["frame"], errors="coerce").to_numpy()
    t = pd.to_numeric(df["t_s"], errors="coerce").to_numpy(dtype=float)
    bad = ~np.isfinite(t) | ~np.isfinite(frame)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{frames_csv}: row {i + 2} has a non-numeric frame or t_s")
    if np.any(frame != np.round(frame)) or np.any(frame < 0):
        raise InputError(f"{frames_csv}: frame numbers must be integers >= 0")
    if np.any(frame > MAX_FRAME):   # as a 64-bit integer it wrapped to a negative one (a review)
        i = int(np.flatnonzero(frame > MAX_FRAME)[0])
        raise InputError(f"{frames_csv}: row {i + 2}: frame number {frame[i]:.0f} is beyond any video's "
                         f"(at most {MAX_FRAME:.0e})")
    if np.any(np.diff(t) <= 0):
        i = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise InputError(f"{frames_csv}: t_s does not increase at row {i + 3} ({float(t[i])!r} then {float(t[i + 1])!r})")
    if np.any(np.diff(frame) <= 0):
        i = int(np.flatnonzero(np.diff(frame) <= 0)[0])
        raise InputError(f"{frames_csv}: frame numbers must increase (row {i + 3}: {int(frame[i])} then "
                         f"{int(frame[i + 1])}), one row per video frame")
    return pd.DataFrame({"frame": frame.astype(int), "t_s": t})


#: The columns of a drive's ``truth.csv`` that are scored (INTERFACE.md, "Drive on disk"), and the
#: road's grade: ``grade_deg`` as ``fused.csv`` has it (the pitch convention: positive downhill),
#: or the simulator's ``road_pitch_deg``, scored as it (:func:`fusion.metrics.interp_truth`).
TRUTH_COLUMNS = ("t_s", "roll_deg", "pitch_deg", "yaw_deg", "bank_deg", "roll_world_deg", "pitch_world_deg",
                 "grade_deg", "road_pitch_deg")


def read_truth(path: Path | None, columns: tuple[str, ...] = TRUTH_COLUMNS) -> pd.DataFrame | None:
    """A truth table: ``t_s`` (two or more increasing times) and at least one other of ``columns``,
    each numeric. The simulator writes them all (the grade as ``road_pitch_deg``); a real
    recording's reference may have only some (an INS gives ``roll_world_deg`` and
    ``pitch_world_deg``, no road angles): what it has is scored, the rest is not (NEES needs all
    four road angles)."""
    if path is None:
        return None
    try:
        df = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: not a CSV file ({' '.join(str(e).split())})") from None
    if len(df) < 2:   # a header alone reads as text columns: say what is missing
        raise InputError(f"{path}: {len(df)} data row{'' if len(df) == 1 else 's'}; a truth table needs two or more")
    have = [c for c in columns[1:] if c in df.columns]
    if "t_s" not in df.columns or (len(columns) > 1 and not have):
        need = "no t_s column" if "t_s" not in df.columns else f"none of the columns {', '.join(columns[1:])}"
        raise InputError(f"{path}: not a truth table: {need} (INTERFACE.md, drive on disk)")
    text = [c for c in have if not pd.api.types.is_numeric_dtype(df[c])]
    if text:
        raise InputError(f"{path}: truth column {text[0]} is not numeric")
    t = pd.to_numeric(df["t_s"], errors="coerce").to_numpy(dtype=float)
    if len(t) < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise InputError(f"{path}: t_s must hold two or more finite, increasing times")
    for c in have:
        v = df[c].to_numpy(dtype=float)
        if np.any(np.isinf(v)):
            raise InputError(f"{path}: truth column {c} holds infinite values")
        if c.endswith("_deg") and np.any(np.abs(v) > 360.0):   # 1e308 was scored: an RMSE of 109 deg (a review)
            i = int(np.flatnonzero(np.abs(v) > 360.0)[0])
            raise InputError(f"{path}: truth column {c} holds {v[i]:g} at row {i + 2}: not an angle in degrees")
    empty = [c for c in have if not df[c].notna().any()]   # a reference without that angle: not scored
    if have and len(empty) == len(have):
        raise InputError(f"{path}: no truth column has a value ({', '.join(have)} are empty)")
    return df.drop(columns=empty)


def _common_span(a_t: np.ndarray, b_t: np.ndarray) -> tuple[float, float] | None:
    """The common span of two increasing time series, or None where they do not overlap (a
    single time inside the other's span overlaps it: a one-frame drive was said to have no
    overlap, a review)."""
    lo, hi = max(a_t[0], b_t[0]), min(a_t[-1], b_t[-1])
    return (float(lo), float(hi)) if hi >= lo else None


def check_truth_overlap(truth: pd.DataFrame, imu_t: np.ndarray, truth_name, log_name) -> None:
    """An error when the truth's times miss the IMU samples' (a truth file of another drive, or
    on another clock): its RMSE would be NaN."""
    t = truth["t_s"].to_numpy(dtype=float)
    if _common_span(t, imu_t) is None:
        raise InputError(f"no overlap between the truth's times ({t[0]:.3f} .. {t[-1]:.3f} s, {truth_name}) "
                         f"and the CAN log's IMU samples ({imu_t[0]:.3f} .. {imu_t[-1]:.3f} s, {log_name})")


def check_overlap(frame_t: np.ndarray, imu_t: np.ndarray, frames_name: str, log_name: str) -> tuple[float, float]:
    """The common time span of the frames and the IMU samples; an error if there is none."""
    if len(frame_t) == 0 or len(imu_t) == 0:
        raise InputError(f"{frames_name if len(frame_t) == 0 else log_name}: no samples")
    span = _common_span(frame_t, imu_t)
    if span is None:
        raise InputError(
            f"no overlap between the video's frame times ({frame_t[0]:.3f} .. {frame_t[-1]:.3f} s, {frames_name}) "
            f"and the CAN log's IMU samples ({imu_t[0]:.3f} .. {imu_t[-1]:.3f} s, {log_name}): "
            "are both on the CAN log's clock?")
    return span


#: Share of the frames outside the IMU samples' span over which a run warns (a drive's camera
#: may start a little before the bus or stop a little after it).
FRAMES_OUTSIDE_WARN = 0.1


def frames_outside_warning(frame_t: np.ndarray, imu_t: np.ndarray, frames_name: str,
                           log_complete: bool = True) -> str | None:
    """A warning when many frames fall outside the IMU samples' span (not used: a frames.csv in
    milliseconds, or shifted), or None. The frames after the end of a log that broke off
    (``log_complete`` False) are that log's warning's, not a question of the clock (a review
    found them blamed on frames.csv's times)."""
    before, after = int(np.sum(frame_t < imu_t[0])), int(np.sum(frame_t > imu_t[-1]))
    if not log_complete:
        after = 0
    if before + after <= FRAMES_OUTSIDE_WARN * len(frame_t):
        return None
    return (f"{before + after} of {len(frame_t)} frames fall outside the CAN log's IMU samples ({before} before, "
            f"{after} after) and are not used: are {frames_name}'s times in seconds on the CAN log's clock?")


def video_container(video: Path) -> tuple[int, float | None] | None:
    """A video file's frame count and frame rate as its container gives them (read without
    decoding; the count 0 and the rate None where it has none), or None for a folder of pictures
    or a file PyAV cannot open (the vision's own reading says what is wrong)."""
    import av

    if Path(video).is_dir():
        return None
    try:
        with av.open(str(video)) as container:
            stream = container.streams.video[0]
            return int(stream.frames), (float(stream.average_rate) if stream.average_rate else None)
    except (av.FFmpegError, OSError, IndexError):
        return None


def video_cut_warning(video: Path, n_read: int, container) -> str | None:
    """A warning when a video's container (:func:`video_container`) announces more frames than
    could be decoded (a file cut short: without frames.csv, which would list the frames, it had
    read as whole, a review), or None."""
    if container is None or container[0] <= n_read:
        return None
    return (f"{video}: its container announces {container[0]} frames, {n_read} could be read "
            "(a file cut short?): the rest are not processed")


#: A frame interval of frames.csv off the median frame period (per frame number) by more than
#: this fraction is said: times and frame numbers disagree there.
FRAME_PERIOD_TOLERANCE = 0.5

#: Median frame periods (s per frame number) a camera's may have: 10 kHz to a frame in 10 s.
#: frames.csv's outside them are said: times in ms (33 "s" a frame) or in ns (1.7e18 "s" since
#: 1970, 3.3e7 a frame) read as seconds; only a video's container rate had caught them (a review).
CAMERA_PERIOD_S = (1e-4, 10.0)


def video_rate_warning(video: Path, n_frames: int, fps: float, container) -> str | None:
    """A warning when ``[video] fps``, which times the frames without frames.csv, is not the
    rate of the video's ``container`` (:func:`video_container`): by the last of its ``n_frames``
    frames their times have drifted more than one of its frames from the container's. A 15 fps
    video with ``fps = 30`` had every time halved without a word, and the same mismatch through
    a frames.csv was said (a review). NTSC's 29.97 fps given as 30 is said beyond 1000 frames."""
    video_fps = container[1] if container is not None else None
    if not video_fps or not fps > 0 or n_frames < 2:
        return None
    drift_s = (n_frames - 1) * abs(1.0 / fps - 1.0 / video_fps)
    if drift_s * video_fps <= 1.0:
        return None
    return (f"{video}: [video] fps = {fps:g} is not its container's {video_fps:g} fps: the frames are timed at "
            f"{fps:g} fps ([video] fps), {drift_s:.3g} s off the container's rate by the last frame; set [video] "
            f"fps = {video_fps:g}, or give the frames' times in a frames.csv")


#: Share of valid vision frames under which a command warns (lanes lost, a camera config that
#: does not fit the video).
VISION_VALID_WARN = 0.5


def too_few_valid(n_valid: int, n_frames: int) -> bool:
    """Whether a vision valid on ``n_valid`` of ``n_frames`` frames is said (under
    :data:`VISION_VALID_WARN` of them, none among none included): the run's warning, and a
    campaign's reason not to carry the drive's calibration."""
    return n_valid < VISION_VALID_WARN * n_frames or not n_frames


def vision_warnings(video, vision: pd.DataFrame, stats: dict, n_listed: int, listed_by: str) -> list[str]:
    """What a command says of the vision's result: listed frames the video did not give
    (``stats``: :func:`vision.video.estimate_video`'s; ``listed_by`` says who listed them:
    frames.csv, or the count of the video's frames), pictures that could not be read (their
    frames skipped, rows invalid), and a vision valid on under
    :data:`VISION_VALID_WARN` of its frames (none among none included), with the commonest
    reason."""
    out = []
    if stats.get("frames_missing"):
        out.append(f"{video}: {stats['frames_read']} frames could be read; {stats['frames_missing']} of the "
                   f"{n_listed} frames {listed_by} are not among them (not processed)")
    n_bad = stats.get("frames_unreadable", 0)
    if n_bad:
        names: dict[str, list[str]] = {}
        for name, why in stats["unreadable"]:
            names.setdefault(why, []).append(name)
        said = "; ".join(f"{', '.join(n)}{', ...' if n_bad > len(stats['unreadable']) else ''}: {why}"
                         for why, n in names.items())
        out.append(f"{video}: {n_bad} of the {n_listed} frames {listed_by} are pictures that could not be read "
                   f"({said}): skipped, their rows invalid")
    n_valid = int(vision["valid"].sum()) if len(vision) else 0
    if too_few_valid(n_valid, len(vision)):
        reasons = vision.loc[~vision["valid"].astype(bool), "reason"].value_counts() if len(vision) else ()
        why = f" (mostly: {reasons.index[0]})" if len(reasons) else ""
        out.append(f"vision valid on {n_valid} of {len(vision)} frames{why}")
    return out


def frames_spacing_warning(frames: pd.DataFrame, frames_name: str, container=None) -> str | None:
    """A warning when frames.csv's times disagree with its frame numbers: intervals whose time
    per frame number is off the median by more than :data:`FRAME_PERIOD_TOLERANCE` (a jump of
    half a second between two consecutive 30 fps frames), a median period off the rate of
    the video's ``container`` (:func:`video_container`) by more than that (360 frames 1 ns
    apart), or outside :data:`CAMERA_PERIOD_S` (a video's or a folder's); None when they agree.
    A review found them fused at those times without a word."""
    video_fps = container[1] if container is not None else None
    t = frames["t_s"].to_numpy(dtype=float)
    f = frames["frame"].to_numpy(dtype=float)
    if len(t) < 2:
        return None
    period = np.diff(t) / np.diff(f)
    med = float(np.median(period))
    off = np.abs(period / med - 1.0) > FRAME_PERIOD_TOLERANCE
    said = []
    if off.any():
        k = int(np.argmax(np.abs(period / med - 1.0)))
        said.append(f"{int(off.sum())} of {len(period)} frame intervals are off the median period "
                    f"({1e3 * med:.3g} ms a frame) by more than {100 * FRAME_PERIOD_TOLERANCE:.0f} % (the worst "
                    f"{1e3 * period[k]:.3g} ms a frame, frames {int(f[k])} to {int(f[k + 1])})")
    if video_fps and video_fps > 0 and abs(med * video_fps - 1.0) > FRAME_PERIOD_TOLERANCE:
        said.append(f"its median period {1e3 * med:.3g} ms is not the video's {1e3 / video_fps:.3g} ms "
                    f"({video_fps:g} fps)")
    if not CAMERA_PERIOD_S[0] <= med <= CAMERA_PERIOD_S[1]:
        said.append(f"its median period {med:.3g} s a frame is no camera's ({CAMERA_PERIOD_S[0]:g} to "
                    f"{CAMERA_PERIOD_S[1]:g} s; times in ms or ns given as seconds?)")
    if not said:
        return None
    return (f"{frames_name}: {'; '.join(said)}: are its times and frame numbers the video's? The frames are "
            "fused at the times it gives")


def frames_skipped_warning(frames: pd.DataFrame, frames_name: str) -> str | None:
    """A warning when frames.csv's frame numbers step over video frames more than its usual
    step does (a listing of every n-th frame is regular; one with a frame left out here and
    there leaves those frames unprocessed without a word, a review found), or None."""
    f = frames["frame"].to_numpy(dtype=np.int64)
    if len(f) < 3:
        return None
    step = np.diff(f)
    usual = int(np.median(step))
    over = step > usual
    if not over.any():
        return None
    skipped = int(np.sum(step[over] - usual) // max(usual, 1))
    k = int(np.flatnonzero(over)[0])
    return (f"{frames_name}: its frame numbers skip {skipped} of the video's frames beyond its usual step of {usual} "
            f"(first after frame {int(f[k])}, next listed {int(f[k + 1])}): those are not processed")


def frames_warnings(video: Path, frames: pd.DataFrame, frames_csv: Path | None, fps: float) -> list[str]:
    """What a command says of the frames it is to process, before the vision runs: with
    ``frames_csv``, its unlisted tail, its times against its frame numbers and frames it steps
    over; without, a video that decodes to fewer frames than its container announces and a
    ``fps`` (``[video] fps``) that is not its container's; either way, a folder whose numbered
    names are not taken as frame numbers. The container and the folder are read once for them
    all."""
    from vision.errors import VisionError
    from vision.video import FrameSource

    container = video_container(video)
    src = None
    if Path(video).is_dir():      # (a video's FrameSource would open the container again for nothing)
        try:
            src = FrameSource(video, None if frames_csv is None else frames["frame"])
        except VisionError:   # the vision's own reading says what is wrong
            pass
    if frames_csv is None:
        said = (video_cut_warning(video, len(frames), container),
                video_rate_warning(video, len(frames), fps, container))
    else:
        name = str(frames_csv)
        said = (frames_unlisted_warning(video, frames, name, fps, container, src),
                frames_spacing_warning(frames, name, container), frames_skipped_warning(frames, name))
    said += (name_order_warning(src, frames_csv),)
    return [w for w in said if w]


def name_order_warning(src, frames_csv: Path | None) -> str | None:
    """A warning when a folder's pictures are named by numbers that are not taken as frame
    numbers (:attr:`vision.video.FrameSource.name_order`), with how to give their times; None
    otherwise. On KITTI's pictures 0-5, 25, 45, 65, 85 picture 25 had become frame 6, at 0.6 s
    for 2.5 s, without a word (a review)."""
    if src is None or src.name_order is None:
        return None
    timed = "at [video] start_s + frame / fps" if frames_csv is None else f"at the times {frames_csv} gives them"
    return (f"{src.name_order}, {timed}: if the names are frame numbers, give each picture's time in a frames.csv "
            "that lists them by number (frame = the name's number less the first's, t_s)")


def frames_unlisted_warning(video: Path, frames: pd.DataFrame, frames_name: str, fps: float,
                            container=None, src=None) -> str | None:
    """A warning when the video holds more than a second of frames after the last one that
    ``frames`` lists (a frames.csv cut short: the frames after it are not processed), or None.
    The video's length is its ``container``'s frame count (:func:`video_container`, read
    without decoding), or a folder's pictures (``src``: its :class:`vision.video.FrameSource`
    with the frames listed); a video without one is not checked. The time a video frame takes
    is the listed frames' (their time span over their number span: a listing of every n-th
    frame is as good), or ``1 / fps`` when one frame is listed (``[video] fps``, the
    container's rate)."""
    if not len(frames):
        return None
    if src is not None and src.files is not None:
        n_video = len(src.files)
    elif container is None:
        return None
    else:
        n_video, fps = container[0], container[1] or fps
    t = frames["t_s"].to_numpy(dtype=float)
    f = frames["frame"].to_numpy(dtype=float)
    dt = (t[-1] - t[0]) / (f[-1] - f[0]) if len(f) > 1 and f[-1] > f[0] else 1.0 / fps if fps > 0 else 0.0
    last = int(f[-1])
    extra = n_video - 1 - last
    if not dt > 0.0 or extra * dt <= 1.0:
        return None
    return (f"{video} holds {n_video} frames; {frames_name} lists up to frame {last}: the last {extra} "
            f"({extra * dt:.1f} s) are not processed")


#: A wheel speed that starts this long after the IMU samples, or ends this long before them,
#: is said (s).
SPEED_SPAN_WARN_S = 1.0


#: A wheel speed older than this at a frame (s) gives the frame no speed.
SPEED_MAX_AGE_S = 0.5


def frame_speeds(imu: pd.DataFrame, t_s: np.ndarray, max_age_s: float = SPEED_MAX_AGE_S) -> np.ndarray:
    """The wheel speed (m/s) at times ``t_s`` on the CAN clock, for the distance the vision
    estimator travels between frames (:func:`vision.video.estimate_video`): the fresh speed
    samples of the IMU table through :func:`last_speed`."""
    t_s = np.asarray(t_s, dtype=float)
    if "speed_m_s" not in imu:
        return np.full(t_s.size, math.nan)
    fresh = imu["fresh_speed"].to_numpy(dtype=bool) if "fresh_speed" in imu else np.ones(len(imu), bool)
    return last_speed(imu["t_s"].to_numpy(dtype=float)[fresh], imu["speed_m_s"].to_numpy(dtype=float)[fresh], t_s,
                      max_age_s)


def last_speed(speed_t_s: np.ndarray, speed_m_s: np.ndarray, t_s, max_age_s: float = SPEED_MAX_AGE_S) -> np.ndarray:
    """The last finite speed sample (times ``speed_t_s``, increasing) at or before each of
    ``t_s``, NaN where there is none within ``max_age_s``. The last sample, not an
    interpolation, so that :class:`fusion.realtime.LiveFusion`, which has no later sample when a
    frame arrives, computes the same travel as the offline run (at 100 Hz and 1 m/s^2 the two
    differ by 0.01 m/s, 0.04 % of the travel at 25 m/s)."""
    t_s = np.atleast_1d(np.asarray(t_s, dtype=float))
    ts, v = np.asarray(speed_t_s, dtype=float), np.asarray(speed_m_s, dtype=float)
    ok = np.isfinite(v)
    ts, v = ts[ok], v[ok]
    out = np.full(t_s.size, math.nan)
    if ts.size == 0:
        return out
    k = np.searchsorted(ts, t_s, side="right") - 1
    have = k >= 0
    out[have] = v[k[have]]
    out[have & (t_s - ts[np.maximum(k, 0)] > max_age_s)] = math.nan
    return out
