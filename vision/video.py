"""Frames from a video file or a folder of pictures, and the vision table of a whole video.

A source is anything OpenCV's ``VideoCapture`` reads (mp4, avi, ...), or a folder of PNG or
JPEG frames taken in name order (INTERFACE.md). Unreadable input is a :class:`VisionError`
that names the file.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import os
import tempfile
from pathlib import Path
from typing import Callable, Iterable, Iterator, NamedTuple

import cv2
import numba as nb
import numpy as np

from .camera import Camera, Mount, RoadMarkings
from .errors import VisionError
from .estimator import Estimator, VisionEstimate
from .options import EstimatorOptions
from .twistmap import travel_between

__all__ = ["FrameSource", "count_frames", "default_workers", "estimate_video", "start_numba", "vision_row",
           "VISION_COLUMNS"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")

#: ``vision.csv``'s columns of :attr:`vision.estimator.VisionEstimate.twist_response`, in its order.
TWIST_RESPONSE_COLUMNS = ("curvature_per_twist_here_1_rad", "curvature_per_twist_ahead_1_rad", "pitch_per_twist_here_m",
                          "pitch_per_twist_ahead_m", "yaw_per_twist_here_m", "yaw_per_twist_ahead_m")

#: ``vision.csv``'s columns of the road's vertical curvature in view and the pitch error per 1/m
#: of it beyond the vehicle's (:class:`vision.estimator.VisionEstimate`), as the filter takes them.
SAG_COLUMNS = ("vertical_curvature_1_m", "pitch_per_vertical_curvature_m")

#: Columns of ``vision.csv`` (INTERFACE.md: the first six, then quality columns).
VISION_COLUMNS = (
    "t_s", "frame", "roll_deg", "pitch_deg", "yaw_deg", "valid",
    "roll_sigma_deg", "pitch_sigma_deg", "yaw_sigma_deg",
    "curvature_1_m", "curvature_sigma_1_m", "roll_lookahead_m",
    "pitch_per_twist_m", "yaw_per_twist_m", "road_twist_deg_per_m", "road_twist_sigma_deg_per_m",
    *TWIST_RESPONSE_COLUMNS, "road_twist_bank_change_deg",
    "vertical_curvature_1_m", "vertical_curvature_sigma_1_m", "pitch_per_vertical_curvature_m",
    "yaw_per_curvature_m", "lateral_offset_m", "line_spacing_m", "n_lines", "roll_equation", "vp_x_px", "vp_y_px", "edge_rms_px", "iterations", "warps", "estimator_ms", "reason",
)

#: Columns of ``vision.csv`` renamed on 2026-11-26 (a unit in every name): old name -> new one.
#: :func:`current_names` reads a table written before with the new names.
RENAMED_COLUMNS = {"curvature_per_twist_here": "curvature_per_twist_here_1_rad",
                   "curvature_per_twist_ahead": "curvature_per_twist_ahead_1_rad", "ms": "estimator_ms"}


def current_names(table):
    """``table`` (a vision table) with the columns of :data:`RENAMED_COLUMNS` under their
    current names: a ``vision.csv`` written before the renaming keeps its twist response."""
    old = {a: b for a, b in RENAMED_COLUMNS.items() if a in table.columns and b not in table.columns}
    return table.rename(columns=old) if old else table


class FrameSource:
    """Frames of a video file or of a folder of pictures, in order.

    Parameters
    ----------
    path : str or Path
        Video file, or folder of ``.png`` / ``.jpg`` / ``.jpeg`` files (name order; numbered
        names at their number less the first's, so that a missing picture is a missing frame).
    listed : iterable of int, optional
        The frame numbers ``frames.csv`` lists, which tell numbered names from names in order
        (:func:`_by_number`).

    Raises
    ------
    VisionError
        Missing path, a folder without pictures, a file OpenCV cannot open.
    """

    def __init__(self, path: str | os.PathLike, listed: Iterable[int] | None = None) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise VisionError(f"{self.path}: no such video file or folder")
        #: A folder's pictures by frame index (None where a numbered picture is missing).
        self.files: list[Path | None] | None = None
        #: Why a folder's numbered names are not its frame numbers, when they are not and the
        #: frame numbers listed did not decide it (:func:`_by_number`); None otherwise.
        self.name_order: str | None = None
        if self.path.is_dir():
            files = sorted(p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not files:
                raise VisionError(f"{self.path}: folder has no .png or .jpg frames")
            numbers = None if listed is None else sorted(set(int(f) for f in listed))
            self.files, self.name_order = _by_number(files, numbers)
        else:
            cap = cv2.VideoCapture(str(self.path))
            ok = cap.isOpened()
            cap.release()
            if not ok:
                raise VisionError(f"{self.path}: OpenCV cannot open it as a video")

    def __len__(self) -> int:
        """Frame count (for a video, as the container reports it; may be approximate)."""
        if self.files is not None:
            return len(self.files)
        cap = cv2.VideoCapture(str(self.path))
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        cap.release()
        return max(n, 0)

    def __iter__(self) -> Iterator[np.ndarray]:
        for _, img in _frames_from(self, 0):
            yield img

    def grey_frames(self) -> Iterator[np.ndarray]:
        """The frames as :func:`estimate_video` hands them to the estimator: a video's from its
        luma plane (:func:`_luma_frames`), pictures converted to grey."""
        for _, img in _frames_from(self, 0, luma=True):
            yield img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


#: Numbered pictures spanning more numbers than this many per picture are not taken as frame
#: numbers (a list of that many entries is built): names that are times in ns stay in name order.
_MAX_NUMBERS_PER_PICTURE = 100


def _by_number(files: list[Path], listed: list[int] | None = None) -> tuple[list[Path | None], str | None]:
    """Pictures in name order, or, when every name is a frame number (``000123.png``), at their
    number less the first's: a picture missing from a numbered sequence is then a missing frame,
    not a shift of every later frame onto the time of the one before it. Names that are times
    (nanoseconds, as some datasets write them) stay in name order.

    Which one the names are is decided by ``listed``, the frame numbers ``frames.csv`` lists,
    when it is given and tells: numbers it all names (and not all positions) are frame numbers
    (a folder of every third frame named by its original number, listed 0, 3, 6, ...: in name
    order picture k had taken frame k's time, a review found); positions it all names (and not
    all numbers) are name order. Otherwise numbers that skip at most as many values as there are
    pictures are frame numbers. Numbered names mixed with others are an error: in name order
    every frame after a stray ``000040 - Copy.png`` took the picture before its own (a review).

    Also returns, when numbered names are taken in name order by that rule (not by the listing),
    a line that says so: on KITTI's pictures 0-5, 25, 45, 65, 85 picture 25 had silently become
    frame 6, at 0.6 s for 2.5 s (a review); None otherwise."""
    digits = [p.stem.isdigit() for p in files]
    if any(digits) and not all(digits):
        odd = [p.name for p, d in zip(files, digits) if not d]
        raise VisionError(f"{files[0].parent}: {sum(digits)} numbered pictures and {len(odd)} other names "
                          f"({', '.join(odd[:3])}{', ...' if len(odd) > 3 else ''}): the frames' order is not "
                          "clear; remove or rename those")
    if not all(digits):
        return files, None
    numbers = [int(p.stem) for p in files]
    first, span = min(numbers), max(numbers) - min(numbers) + 1
    in_name_order = (f": they are not taken as frame numbers, the pictures are frames 0 to {len(files) - 1} in "
                     "name order")
    if len(set(numbers)) < len(files):
        return files, f"{files[0].parent}: two or more of its pictures have one number" + in_name_order
    by_number, decided = span <= 2 * len(files), False
    if listed:
        numbered = {n - first for n in numbers}
        as_numbers, as_positions = set(listed) <= numbered, listed[-1] < len(files) and listed[0] >= 0
        if as_numbers != as_positions:
            by_number, decided = as_numbers, True
    if by_number and span > _MAX_NUMBERS_PER_PICTURE * len(files):
        by_number, decided = False, False       # as many slots as numbers: names that are times
    if not by_number:
        return files, None if decided else (f"{files[0].parent}: the numbers its {len(files)} pictures are named by "
                                            f"({first} to {first + span - 1}) skip more values than there are "
                                            "pictures" + in_name_order)
    out: list[Path | None] = [None] * span
    for p, n in zip(files, numbers):
        out[n - first] = p
    return out, None


def count_frames(path: str | os.PathLike) -> int:
    """Number of frames: the folder's pictures, or a video's frames counted by decoding
    (containers' own counts are unreliable)."""
    src = FrameSource(path)
    if src.files is not None:
        return len(src.files)
    cap = cv2.VideoCapture(str(src.path))
    n = 0
    try:
        while cap.grab():
            n += 1
    finally:
        cap.release()
    return n


def check_frame_size(src: FrameSource, camera: Camera) -> None:
    """:class:`VisionError` when no frame of ``src`` can have the camera's size: a video whose
    first frame is another size (a video has one), a folder none of whose pictures is. Every
    frame had been estimated and refused ("image is 1280x720, the camera is 640x360") and the
    run ended with exit 0 and outputs that looked complete (a review). A folder with some
    pictures of the camera's size goes on: the others are refused frame by frame, each with
    that reason in its row."""
    size = (camera.width, camera.height)
    if src.files is not None:
        sizes = []
        for found in _picture_sizes(f for f in src.files if f is not None):
            if found == size:
                return               # one of the camera's size: the folder goes on
            sizes.append(found)
        if not sizes:
            return                   # (unreadable pictures are said where they are read)
        w, h = sizes[0]
        what = (f"the pictures are {w}x{h}" if len(set(sizes)) == 1 else
                f"no picture is {size[0]}x{size[1]} (the first is {w}x{h}, {len(set(sizes))} sizes)")
    else:
        first = next(_frames_from(src, 0, luma=True), None)
        if first is None:
            return                   # nothing decodes: said where the frames are read
        h, w = first[1].shape[:2]
        if (w, h) == size:
            return
        what = f"the video's frames are {w}x{h}"
    raise VisionError(f"{src.path}: {what}, but [camera] width x height is {size[0]}x{size[1]}: set [camera] "
                      f"width = {w}, height = {h} and the intrinsics (fx, fy, cx, cy) in pixels of that size, "
                      "or give this camera's config")


def _picture_sizes(files: Iterable[Path]) -> Iterator[tuple[int, int]]:
    """The ``(width, height)`` of each readable picture of a folder, in order, from their
    headers (Pillow: a header, not the picture decoded), as they are asked for: a folder whose
    first picture has the camera's size is not read through."""
    from PIL import Image

    for f in files:
        try:
            with Image.open(f) as im:
                size = im.size
        except Exception:     # noqa: BLE001 - an unreadable picture is said when it is read
            continue
        yield size


#: The columns of ``vision.csv`` that are the estimate: empty (NaN) on a frame without a valid one.
ESTIMATE_COLUMNS = (
    "roll_deg", "pitch_deg", "yaw_deg", "roll_sigma_deg", "pitch_sigma_deg", "yaw_sigma_deg",
    "curvature_1_m", "curvature_sigma_1_m", "roll_lookahead_m", "pitch_per_twist_m", "yaw_per_twist_m",
    "road_twist_deg_per_m", "road_twist_sigma_deg_per_m", *TWIST_RESPONSE_COLUMNS, "road_twist_bank_change_deg",
    "vertical_curvature_1_m", "vertical_curvature_sigma_1_m", "pitch_per_vertical_curvature_m",
    "yaw_per_curvature_m", "lateral_offset_m", "line_spacing_m",
)


def vision_row(t_s: float, frame: int, est: VisionEstimate, ms: float = math.nan) -> dict:
    """One row of ``vision.csv`` (:data:`VISION_COLUMNS`): angles in degrees, units in the names.
    On a frame without a valid estimate the estimate's columns (:data:`ESTIMATE_COLUMNS`) are
    empty: a rejected fit's angles, and a curvature of 0 +- 0, had been written there for a
    reader who does not look at ``valid`` (a review); what the frame showed (lines, vanishing
    point, edge residual) and ``reason`` stay."""
    deg = math.degrees
    row = {
        "t_s": float(t_s), "frame": int(frame),
        "roll_deg": deg(est.roll_rad), "pitch_deg": deg(est.pitch_rad), "yaw_deg": deg(est.yaw_rad),
        "valid": int(bool(est.valid)),
        "roll_sigma_deg": deg(est.roll_sigma_rad), "pitch_sigma_deg": deg(est.pitch_sigma_rad),
        "yaw_sigma_deg": deg(est.yaw_sigma_rad),
        "curvature_1_m": est.curvature_1_m, "curvature_sigma_1_m": est.curvature_sigma_1_m,
        "roll_lookahead_m": est.roll_lookahead_m,
        "pitch_per_twist_m": est.pitch_per_twist_m, "yaw_per_twist_m": est.yaw_per_twist_m,
        "road_twist_deg_per_m": deg(est.road_twist_rad_m), "road_twist_sigma_deg_per_m": deg(est.road_twist_sigma_rad_m),
        **dict(zip(TWIST_RESPONSE_COLUMNS, est.twist_response)),
        "road_twist_bank_change_deg": deg(est.road_twist_used),
        "vertical_curvature_1_m": est.vertical_curvature_1_m,
        "vertical_curvature_sigma_1_m": est.vertical_curvature_sigma_1_m,
        "pitch_per_vertical_curvature_m": est.pitch_per_vertical_curvature_m,
        "yaw_per_curvature_m": est.yaw_per_curvature_m,
        "lateral_offset_m": est.lateral_offset_m, "line_spacing_m": est.line_spacing_m,
        "n_lines": est.n_lines, "roll_equation": est.roll_equation,
        "vp_x_px": est.vp_px[0], "vp_y_px": est.vp_px[1], "edge_rms_px": est.edge_rms_px,
        "iterations": est.iterations, "warps": est.warps, "estimator_ms": ms, "reason": est.reason,
    }
    if not est.valid:
        row.update(dict.fromkeys(ESTIMATE_COLUMNS, math.nan))
    return row


def default_workers() -> int:
    """Worker processes for :func:`estimate_video` by default: the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:          # not on Linux
        return max(1, os.cpu_count() or 1)


def estimate_video(video: str | os.PathLike, frames, camera: Camera, mount: Mount, road: RoadMarkings,
                   options: EstimatorOptions = EstimatorOptions(), *, progress: bool = True,
                   debug_video: str | os.PathLike | None = None, debug_fps: float | None = None,
                   debug_clock_offset_s: float = 0.0, workers: int = 1, while_waiting: Callable[[], object] | None = None, pieces: int | None = None):
    """Run the estimator over a video.

    Parameters
    ----------
    video : path
        Video file or folder of frames.
    frames : DataFrame
        ``frame, t_s``: the frames to process and their capture times (``frames.csv``, or built
        from ``[video] fps, start_s``). Frames of the video not listed are skipped. With a column
        ``speed_m_s`` (the vehicle's speed at each frame, from the wheel speed; NaN where
        unknown) the estimator carries the road's twist from frame to frame by the distance
        travelled (:attr:`vision.options.EstimatorOptions.road_twist`).
    camera, mount, road, options :
        As for :class:`vision.estimator.Estimator`.
    progress : bool
        tqdm progress bar.
    debug_video : path, optional
        Also write the debug video (:mod:`vision.debug`) there. It is written in frame order by
        one process: with a debug video the run uses one worker (``stats["workers"]`` says so).
    debug_clock_offset_s : float
        Added to a frame's time for the CAN clock's in the debug video's strip (the config's
        ``[fusion] camera_time_offset_s``: where the fusion places the frame).
    workers : int
        Processes that share the pieces of the video (:func:`piece_count`: cut by the video's
        length alone, so that the table does not depend on how many processes there are).
        Each piece is decoded from its own seek point and started :data:`WARM_UP_S` early.
        1 runs the pieces one after the other in this process.
    pieces : int, optional
        Where to cut the video instead: that many pieces (1: one run through it, as a live
        stream of frames gets, :class:`fusion.realtime.LiveFusion`).
    while_waiting : callable, optional
        Work of the caller's that does not need the vision (``vifusion run``: the IMU-only
        filter), called once in this process while the workers estimate (before the frames
        when there is one worker).

    Returns
    -------
    table : DataFrame
        One row per processed frame, :data:`VISION_COLUMNS`.
    stats : dict
        ``frames_read`` (decoded), ``frames_missing`` (listed in ``frames`` but not in the video),
        ``frames_unreadable`` (a folder's pictures that could not be read: their rows are invalid,
        ``reason`` :data:`UNREADABLE_PICTURE` and why), ``unreadable`` (the first three of them:
        ``(name, why)``), ``valid`` (count), ``median_ms``, ``workers`` (processes used), ``pieces``.

    Raises
    ------
    VisionError
        A source that cannot be read (:class:`FrameSource`), frames none of which has the
        camera's size (:func:`check_frame_size`), a folder none of whose pictures to estimate
        can be read (:func:`check_readable`).
    """
    import pandas as pd
    from tqdm import tqdm

    if int(workers) < 1:
        raise VisionError(f"workers must be at least 1, got {workers}")
    want = {int(f): float(t) for f, t in zip(frames["frame"], frames["t_s"])}
    src = FrameSource(video, want)
    check_frame_size(src, camera)
    check_readable(src, sorted(want))
    speeds = ({int(f): float(v) for f, v in zip(frames["frame"], frames["speed_m_s"])}
              if "speed_m_s" in frames else None)
    wanted = sorted(want)
    fps = _fps_of(frames)
    warm_up = warm_up_frames(fps)
    if pieces is not None and int(pieces) < 1:
        raise VisionError(f"pieces must be at least 1, got {pieces}")
    jobs = _piece_jobs(src, wanted, want, (camera, mount, road, options), speeds,
                       piece_count(len(wanted), fps, warm_up) if pieces is None else int(pieces), warm_up)
    workers = 1 if debug_video is not None else max(1, min(int(workers), len(jobs)))
    bar = tqdm(total=len(wanted), desc="vision", unit="frame", disable=not progress)
    try:
        if workers == 1:
            if while_waiting is not None:
                while_waiting()
            rows, n_read = _estimate_pieces_here(jobs, bar.update, debug_video, debug_fps or fps, debug_clock_offset_s)
        else:
            rows, n_read = _estimate_parallel(jobs, len(wanted), workers, bar.update, while_waiting)
    finally:
        bar.close()
    table = pd.DataFrame(rows, columns=list(VISION_COLUMNS))
    done = set(table["frame"]) if len(table) else set()
    unreadable = table.loc[table["reason"].str.startswith(UNREADABLE_PICTURE, na=False), ["frame", "reason"]]
    stats = {
        "frames_read": n_read,
        "frames_missing": sum(1 for f in want if f not in done),
        "frames_unreadable": len(unreadable),
        # the first few, for the warning: the picture's name and why it was not read
        "unreadable": [(src.files[int(f)].name, r[len(UNREADABLE_PICTURE) + 2:])
                       for f, r in unreadable.head(3).itertuples(index=False)],
        "valid": int(table["valid"].sum()) if len(table) else 0,
        "median_ms": float(table["estimator_ms"].median()) if len(table) else math.nan,
        "workers": workers,
        "pieces": len(jobs),
    }
    return table, stats


#: Smallest piece of a video (frames) besides its warm-up: each piece costs a seek and a warm-up.
_MIN_PIECE = 60
#: Pieces per started minute of video (:func:`piece_count`): two keep both cores of a two-core
#: machine busy on any video of a minute or more, at one warm-up (3 s) per 30 s of video.
PIECES_PER_MINUTE = 2
#: Seconds of video a worker's piece starts early (their rows dropped), for the estimator's
#: frame-to-frame state (vertical-curvature prior, seed, the road's twist map) to forget the
#: cold start. The map holds the twist of the road the vehicle will reach, measured 7-22 m ahead
#: and kept up to 60 m (:data:`vision.twistmap.AHEAD_M`): 3 s at 20 m/s. With 1 s (30 frames) the
#: hill drive's second piece began in a runoff with an empty map: vision yaw 0.219 deg RMS
#: against 0.085 for one worker, the fused yaw 0.124 against 0.035; with 3 s 0.091 and 0.038
#: (5 s: 0.088, 0.037). The rows after a cut still differ from those of a run through it: the
#: state carried in differs by little, but on some runoff frames the lines found and the twist
#: map's decisions turn that into other angles (the 60 s HD drive cut at 31.5 s: 47 frames of its
#: next runoff, 39.5-41.7 s, up to 1.9 deg of yaw apart; the fused roll 0.082 deg RMS with the
#: cut, 0.101 without).
#: So where the video is cut depends on the video alone (:func:`piece_count`), never on the
#: number of processes.
WARM_UP_S = 3.0


def piece_count(n_frames: int, fps: float, warm_up: int) -> int:
    """Pieces a video of ``n_frames`` wanted frames at ``fps`` is cut into: a function of the
    video alone, so that its table is the same whichever number of processes share the pieces
    (the estimator's rows after a cut differ from those of a run through it: :data:`WARM_UP_S`).
    :data:`PIECES_PER_MINUTE` per started minute, fewer where a piece would be shorter than
    its warm-up and :data:`_MIN_PIECE`."""
    by_length = PIECES_PER_MINUTE * max(1, math.ceil(n_frames / max(fps, 1e-9) / 60.0 - 1e-9))
    return max(1, min(by_length, n_frames // (warm_up + _MIN_PIECE)))


#: ``reason`` of a frame whose picture could not be read (:func:`_decode_picture`): its row in
#: ``vision.csv`` is invalid, the run goes on and counts it (``stats["frames_unreadable"]``).
UNREADABLE_PICTURE = "unreadable picture"


class UnreadablePicture(NamedTuple):
    """A picture of a frames folder that could not be read, in its frame's place
    (:func:`_frames_from` with ``unreadable=True``), and why (:func:`_decode_picture`)."""

    path: Path
    why: str


#: Lines libjpeg prints for a JPEG whose data is damaged and that OpenCV still returns, the rest
#: of the picture grey or garbled: the review's JPEGs with their second half overwritten gave
#: "Corrupt JPEG data: premature end of data segment" and 8 of 11 stayed valid, roll up to 0.24
#: deg off; junk in the middle of a random picture gives "... 1619 extraneous bytes before
#: marker 0xd9". Such a picture is unreadable. Data that decodes in step despite damage says
#: nothing and cannot be told from a picture.
_DAMAGED_JPEG = ("Corrupt JPEG data", "Premature end of JPEG file")
#: Extraneous bytes before a marker up to this many are an encoder's padding, not damage (the
#: picture decodes whole): the line is passed on, with the file's name.
_PADDING_BYTES = 16


def _damage(line: str) -> bool:
    """Whether a line libjpeg printed while decoding says the picture's data is damaged
    (:data:`_DAMAGED_JPEG`; a few extraneous bytes, :data:`_PADDING_BYTES`, are not)."""
    if not line.startswith(_DAMAGED_JPEG):
        return False
    words = line.split()
    if "extraneous" in words:
        n = words[words.index("extraneous") - 1]
        return not (n.isdigit() and int(n) <= _PADDING_BYTES)
    return True


def _decode_picture(path: Path) -> tuple[np.ndarray | None, str]:
    """One picture of a frames folder, or None and why not. What the decoders print goes with
    the picture: for one that cannot be read, or whose JPEG data libjpeg says is damaged
    (:func:`_damage`: then it is not read either, its line in the ``why``), it is dropped (a
    review: libpng's "Read Error", OpenCV's "findDecoder" and libjpeg's "Corrupt JPEG data"
    lines came raw, naming no file); the rest is passed on, each line after the file's name."""
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as e:
        return None, f"not a readable picture ({e.strerror or e})"
    if not data.size:
        return None, "not a readable picture (an empty file)"
    saved = os.dup(2)
    with tempfile.TemporaryFile() as said:
        os.dup2(said.fileno(), 2)          # the C libraries' own lines on stderr, for now
        try:
            img = cv2.imdecode(data, cv2.IMREAD_COLOR)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        if img is None:
            return None, "not a readable picture"
        said.seek(0)
        lines = said.read().decode(errors="replace").splitlines()
    damaged = [line for line in lines if _damage(line)]
    if damaged:
        return None, f"damaged JPEG data (libjpeg: {damaged[0].strip()})"
    if lines:
        os.write(2, "".join(f"{path}: {line}\n" for line in lines).encode())
    return img, ""


def check_readable(src: FrameSource, wanted: Iterable[int]) -> None:
    """:class:`VisionError` when none of the pictures of the frames ``wanted`` can be read (a
    folder's; a video is not checked): said before the first frame is estimated, and before a
    debug video is begun. Pictures are read until one is: one picture on any folder that has a
    readable one first. An unreadable picture among readable ones is a frame skipped, counted
    and said (:func:`estimate_video`); it had ended the run with nothing written, a review: the
    4000-picture folder with picture 3900 cut to 500 bytes, after 12 s of estimation."""
    if src.files is None:
        return
    tried, first = 0, ""
    for i in wanted:
        f = src.files[i] if 0 <= i < len(src.files) else None
        if f is None:
            continue
        img, why = _decode_picture(f)
        if img is not None:
            return
        tried, first = tried + 1, first or f"{f.name}: {why}"
    if tried:
        raise VisionError(f"{src.path}: none of the {tried} pictures to estimate can be read (the first, {first})")


def _frames_from(src: FrameSource, start: int, luma: bool = False,
                 unreadable: bool = False) -> Iterator[tuple[int, np.ndarray | UnreadablePicture]]:
    """``(index, image)`` from frame ``start`` on. A video is positioned with a seek, checked:
    when the container cannot seek to the frame exactly, the frames before it are decoded and
    dropped instead. ``luma``: a video's frames may come as grey pictures (:func:`_luma_frames`).
    A folder's picture that cannot be read is a :class:`VisionError`, or with ``unreadable`` an
    :class:`UnreadablePicture` in its place."""
    if src.files is not None:
        for i in range(start, len(src.files)):
            f = src.files[i]
            if f is None:
                continue          # a numbered picture missing: that frame is missing
            img, why = _decode_picture(f)
            if img is None and not unreadable:
                raise VisionError(f"{f}: {why}")
            yield i, (UnreadablePicture(f, why) if img is None else img)
        return
    if luma:
        frames = _luma_frames(src.path, start)
        if frames is not None:
            yield from frames
            return
    cap = cv2.VideoCapture(str(src.path))
    try:
        i = 0
        if start > 0 and cap.set(cv2.CAP_PROP_POS_FRAMES, start) and int(cap.get(cv2.CAP_PROP_POS_FRAMES)) == start:
            i = start
        elif start > 0:
            cap.release()
            cap = cv2.VideoCapture(str(src.path))
        while True:
            if i < start:
                if not cap.grab():
                    return
                i += 1
                continue
            ok, img = cap.read()
            if not ok:
                return
            yield i, img
            i += 1
    finally:
        cap.release()


#: Planar YUV formats whose first plane is the luma, and those of them stored in full range.
_YUV_PLANAR = {"yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p", "gray"}
_FULL_RANGE = {"yuvj420p", "yuvj422p", "yuvj444p", "gray"}
#: Video-range luma (16-235) expanded to full-range grey (0-255), BT.601.
_LUMA_TO_GREY = np.clip(np.round((np.arange(256) - 16.0) * 255.0 / 219.0), 0, 255).astype(np.uint8)


@nb.njit(cache=True)
def _video_range_to_grey(luma: np.ndarray) -> np.ndarray:  # pragma: no cover (numba)
    """:data:`_LUMA_TO_GREY` of every pixel of ``luma`` (uint8, rows may be strided), as a new
    contiguous picture: the table's values computed, ``(y - 16) * 255 / 219`` rounded by adding
    0.5 and truncating (in float32, then clipped to 0-255), which the compiler vectorises; a
    table lookup cannot be (the 60 s HD drive's decoded frames, per frame: ``cv2.LUT`` 0.41-0.69
    ms, this 0.14-0.20 ms; 1.1 against 0.45-0.57 ms on the machine loaded). Equal to the table
    for every value: the exact values lie at least 1/146 from a rounding boundary, float32's
    error here is under 2e-5 (tests/test_vision_kernels.py checks all 256)."""
    h, w = luma.shape
    out = np.empty((h, w), np.uint8)
    scale = np.float32(255.0 / 219.0)
    offset = np.float32(0.5 - 16.0 * 255.0 / 219.0)
    for r in range(h):
        src, dst = luma[r], out[r]
        for c in range(w):
            t = np.int32(np.float32(src[c]) * scale + offset)     # truncated: rounded where >= 0
            dst[c] = np.uint8(min(max(t, 0), 255))
    return out


def _decode_until_error(container, stream):
    """The stream's decoded frames up to the first undecodable packet (where OpenCV's reader
    stops too: the frames after it count as missing)."""
    import av

    frames = container.decode(stream)
    while True:
        try:
            frame = next(frames)
        except (StopIteration, av.FFmpegError):
            return
        yield frame


def _luma_frames(path: Path, start: int):
    """The grey pictures of a video straight from its decoded luma plane (PyAV), or None when
    PyAV cannot open it or the stream is not planar YUV (OpenCV reads it then).

    The estimator works on grey: OpenCV decodes to BGR (a colour conversion of the whole
    frame) that the estimator converts back to grey; the luma plane is that grey already
    (BT.601 luma, expanded from video range: :func:`_video_range_to_grey`). On the 60 s HD
    drive this cost 1.1 ms of CPU a frame against 1.6-1.8 ms (with ``cv2.LUT`` expanding), and
    it is the more faithful grey: flat grey frames 20, 60, 100, 140, 180, 220, 250 written by
    OpenCV (mp4v) come back as 20, 59, 99, 140, 179, 219, 249 from the luma and 18, 58, 97, 138,
    178, 217, 248 through BGR. Frames are numbered from their timestamps after a keyframe
    seek, or counted from the start when the stream has no regular timestamps."""
    import av

    try:
        container = av.open(str(path))
        stream = container.streams.video[0]
    except (av.FFmpegError, IndexError, OSError):
        return None
    fmt = stream.codec_context.format
    if fmt is None or fmt.name not in _YUV_PLANAR:
        container.close()
        return None
    rate, tb, t0 = stream.average_rate, stream.time_base, stream.start_time or 0

    def decoded(seek: bool):
        """``(index, frame)``; with ``seek``, from the keyframe before ``start``, numbered from
        its timestamp (None first when that is not possible: then decode from the start)."""
        if seek:
            container.seek(int(t0 + start / (rate * tb)), stream=stream, backward=True, any_frame=False)
        i = -1
        for frame in _decode_until_error(container, stream):
            if seek and i < 0:
                if frame.pts is None:
                    yield None
                    return
                i = round(float((frame.pts - t0) * tb * rate))
                if not 0 <= i <= start:
                    yield None
                    return
            else:
                i += 1
            yield i, frame

    def frames():
        try:
            seek = start > 0 and rate is not None and tb is not None and rate > 0
            items = decoded(seek)
            first = next(items, None)
            if first is None and seek:
                container.seek(0, stream=stream, backward=True, any_frame=False)
                items = decoded(False)
                first = next(items, None)
            if first is None:
                return
            for i, frame in itertools.chain([first], items):
                if i < start:
                    continue
                plane = frame.planes[0]
                y = np.frombuffer(plane, np.uint8).reshape(-1, plane.line_size)[:frame.height, :frame.width]
                full = frame.format.name in _FULL_RANGE or frame.color_range == 2
                yield i, (np.ascontiguousarray(y) if full else _video_range_to_grey(y))
        finally:
            container.close()

    return frames()


def _estimate_piece(src: FrameSource, wanted: list[int], times: dict, setup, writer=None, tick=None,
                    speeds: dict | None = None, warm: int = 0) -> tuple[list[dict], int]:
    """Rows of the frames ``wanted`` (sorted, contiguous in the video) but the first ``warm``
    (the warm-up: estimated for the state they leave, not written to the debug ``writer`` nor
    counted by ``tick``), and how many frames of the video were read (index of the last one +
    1). A fresh estimator. ``speeds``: m/s per frame, for the distance travelled between frames
    (:func:`_travel_m`)."""
    import time

    est = Estimator(*setup)
    rows, n_read, last_done = [], 0, None
    wanted_set, last = set(wanted), (wanted[-1] if wanted else -1)
    # the estimator's grey with a debug video too (it drew on OpenCV's colour frames, and the
    # estimator got their grey, a few levels off the luma: another run, 7 of 10 KITTI frames
    # valid against 2, a review); the debug video shows the grey the vision saw
    for i, img in _frames_from(src, wanted[0] if wanted else 0, luma=True, unreadable=True):
        n_read = i + 1
        if i > last:
            break
        if i not in wanted_set:
            continue
        if isinstance(img, UnreadablePicture):
            # skipped: an invalid row that says why; the estimator's state and the distance
            # travelled carry over to the next frame, as over a missing picture
            rows.append(vision_row(times[i], i, VisionEstimate.invalid(f"{UNREADABLE_PICTURE}: {img.why}",
                                                                        est.options.method)))
            if len(rows) > warm and tick is not None:
                tick(1)
            continue
        travel = _travel_m(speeds, times, last_done, i)
        last_done = i
        t0 = time.perf_counter()
        e = est.estimate(img, travel_m=travel, keep_debug=writer is not None)
        ms = (time.perf_counter() - t0) * 1e3
        rows.append(vision_row(times[i], i, e, ms))
        if len(rows) <= warm:
            continue
        if writer is not None:
            writer.write(img, e, times[i])
        if tick is not None:
            tick(1)
    return rows[warm:], n_read


def _travel_m(speeds: dict | None, times: dict, before: int | None, frame: int) -> float | None:
    """The distance travelled from frame ``before`` to ``frame``, or None where it is not known
    (no speeds, no frame before, :func:`vision.twistmap.travel_between`)."""
    if speeds is None or before is None:
        return None
    return travel_between(speeds.get(before, math.nan), speeds.get(frame, math.nan), times[frame] - times[before])


class _PieceJob(NamedTuple):
    """One piece of a video for :func:`_run_job`: the source, the piece's frames, the warm-up
    frames before it, their times, the estimator's setup (camera, mount, road, options) and
    their speeds (None: no map of the road's twist)."""

    src: FrameSource
    piece: list
    warm: list
    times: dict
    setup: tuple
    speeds: dict | None


def _piece_jobs(src: FrameSource, wanted: list[int], times: dict, setup, speeds: dict | None, pieces: int,
                warm_up: int) -> list[_PieceJob]:
    """One job per piece (:func:`_piece_starts`), each with the ``warm_up`` frames before it."""
    starts = _piece_starts(len(wanted), pieces, warm_up)
    jobs = []
    for k, end in zip(starts, starts[1:] + [len(wanted)]):
        piece, warm = wanted[k:end], wanted[max(0, k - warm_up):k]
        jobs.append(_PieceJob(src, piece, warm, {i: times[i] for i in warm + piece}, setup,
                              None if speeds is None else {i: speeds.get(i, math.nan) for i in warm + piece}))
    return jobs


def _run_job(job: _PieceJob, writer=None, tick=None) -> tuple[list[dict], int]:
    return _estimate_piece(job.src, job.warm + job.piece, job.times, job.setup, writer=writer, tick=tick,
                           speeds=job.speeds, warm=len(job.warm))


def _estimate_pieces_here(jobs: list[_PieceJob], tick, debug_video=None,
                          debug_fps: float = 30.0, debug_clock_offset_s: float = 0.0) -> tuple[list[dict], int]:
    """The pieces one after the other in this process (each from its own warm-up, as a worker
    would: the same rows), the debug video written across them in frame order."""
    from .debug import DebugWriter

    writer = (DebugWriter(debug_video, debug_fps, jobs[0].setup[0], debug_clock_offset_s)
              if debug_video is not None and jobs else None)
    rows, n_read = [], 0
    try:
        for job in jobs:
            piece_rows, n = _run_job(job, writer, tick)
            rows += piece_rows
            n_read = max(n_read, n)
    except BaseException:
        if writer is not None:
            writer.close(complete=False)
        raise
    if writer is not None:
        writer.close()
    return rows, n_read


def _piece_job(job):
    return _run_job(job, tick=_tick_shared)


_COUNTER = None  # shared frame counter of the pool's processes (set by _init_worker)


def _init_worker(counter) -> None:
    """A pool process: the shared frame counter. (Not ``cv2.setNumThreads(1)`` here: in a child
    forked after the parent used OpenCV's thread pool it deadlocks, seen in the tests.)"""
    global _COUNTER
    _COUNTER = counter
    import signal

    # a forked worker keeps the command's SIGTERM handler (fusion.cli): the pool's own
    # termination of its workers must end them as before, not raise in them
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _tick_shared(n: int) -> None:
    with _COUNTER.get_lock():
        _COUNTER.value += n


def _piece_starts(n_frames: int, pieces: int, warm: int) -> list[int]:
    """First frame (index into the wanted frames) of each piece. Every piece but the first
    also estimates ``warm`` frames before it, so those pieces are shorter by as much: each
    piece then costs the same number of frames and no worker finishes last by its warm-up
    (equal pieces when they would be too short for that)."""
    if (n_frames + (pieces - 1) * warm) // pieces - warm < _MIN_PIECE // 2:
        warm = 0
    work, extra = divmod(n_frames + (pieces - 1) * warm, pieces)
    starts = [0]
    for k in range(pieces - 1):
        starts.append(starts[-1] + work + (k < extra) - (warm if k > 0 else 0))
    return [s for s in starts if s < n_frames]


@nb.njit(cache=True)
def start_numba() -> int:  # pragma: no cover (numba)
    """Start numba's compiler target in this process (0.1-0.3 s at the first compiled call of a
    process, whichever kernel it is): done before forking, the workers inherit it."""
    return 1


def warm_up_frames(fps: float) -> int:
    """Frames of :data:`WARM_UP_S` at ``fps``."""
    return int(math.ceil(WARM_UP_S * fps))


def _estimate_parallel(jobs: list[_PieceJob], n_wanted: int, workers: int, tick, while_waiting=None):
    """:func:`_run_job` over the pieces in a pool of ``workers`` processes: the rows of
    :func:`_estimate_pieces_here`, each piece from its own warm-up (:data:`WARM_UP_S`)."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    ctx = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
    if ctx.get_start_method() == "fork":
        # numba's first call in a process sets up its compiler target (0.3-0.4 s here, importing
        # its implementations): done once here, the forked workers inherit it instead of each
        # paying it, and so does this process's fusion after the vision.
        start_numba()
    counter = ctx.Value("q", 0)
    shown = 0
    pool = ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=ctx, initializer=_init_worker,
                               initargs=(counter,))
    try:
        futures = [pool.submit(_piece_job, j) for j in jobs]
        if while_waiting is not None:   # the workers are forked by now: this process is free
            while_waiting()
        pending = set(futures)
        while pending:
            _, pending = wait(pending, timeout=0.25, return_when=FIRST_COMPLETED)
            done_frames = min(counter.value, n_wanted)
            tick(done_frames - shown)
            shown = done_frames
        results = [f.result() for f in futures]
    except BaseException:
        # an interrupt or an error: the workers are ended and the pieces not begun dropped, not
        # waited for (a SIGTERM to this process alone waited 18 s for the rest of the video,
        # and a kill after it left the workers running, a review); Ctrl-C reaches them anyway
        for proc in list((getattr(pool, "_processes", None) or {}).values()):
            with contextlib.suppress(Exception):
                proc.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()
    tick(n_wanted - shown)
    rows = [r for piece_rows, _ in results for r in piece_rows]
    # a piece past the end of the video reads nothing; the last frame read is the video's
    return rows, max(n for _, n in results)


def _fps_of(frames) -> float:
    t = np.asarray(frames["t_s"], dtype=float)
    if t.size > 1:
        dt = np.median(np.diff(t))
        if dt > 0:
            return float(1.0 / dt)
    return 30.0
