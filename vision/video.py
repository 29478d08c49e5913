"""Frames from a video file or a folder of pictures, and the vision table of a whole video.

A source is anything OpenCV's ``VideoCapture`` reads (mp4, avi, ...), or a folder of PNG or
JPEG frames taken in name order (INTERFACE.md). Unreadable input is a :class:`VisionError`
that names the file.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from .camera import Camera, Mount, RoadMarkings
from .errors import VisionError
from .estimator import Estimator, VisionEstimate
from .options import EstimatorOptions

__all__ = ["FrameSource", "count_frames", "estimate_video", "vision_row", "VISION_COLUMNS"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")

#: Columns of ``vision.csv`` (INTERFACE.md: the first six, then quality columns).
VISION_COLUMNS = (
    "t_s", "frame", "roll_deg", "pitch_deg", "yaw_deg", "valid",
    "roll_sigma_deg", "pitch_sigma_deg", "yaw_sigma_deg",
    "curvature_1_m", "curvature_sigma_1_m", "lateral_offset_m", "line_spacing_m",
    "n_lines", "roll_equation", "vp_x_px", "vp_y_px", "edge_rms_px", "iterations", "warps", "ms", "reason",
)


class FrameSource:
    """Frames of a video file or of a folder of pictures, in order.

    Parameters
    ----------
    path : str or Path
        Video file, or folder of ``.png`` / ``.jpg`` / ``.jpeg`` files (name order).

    Raises
    ------
    VisionError
        Missing path, a folder without pictures, a file OpenCV cannot open.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise VisionError(f"{self.path}: no such video file or folder")
        self.files: list[Path] | None = None
        if self.path.is_dir():
            self.files = sorted(p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not self.files:
                raise VisionError(f"{self.path}: folder has no .png or .jpg frames")
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
        if self.files is not None:
            for f in self.files:
                img = cv2.imread(str(f), cv2.IMREAD_COLOR)
                if img is None:
                    raise VisionError(f"{f}: not a readable picture")
                yield img
            return
        cap = cv2.VideoCapture(str(self.path))
        try:
            while True:
                ok, img = cap.read()
                if not ok:
                    break
                yield img
        finally:
            cap.release()


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


def vision_row(t_s: float, frame: int, est: VisionEstimate, ms: float = math.nan) -> dict:
    """One row of ``vision.csv`` (:data:`VISION_COLUMNS`): angles in degrees, units in the names."""
    deg = math.degrees
    return {
        "t_s": float(t_s), "frame": int(frame),
        "roll_deg": deg(est.roll_rad), "pitch_deg": deg(est.pitch_rad), "yaw_deg": deg(est.yaw_rad),
        "valid": int(bool(est.valid)),
        "roll_sigma_deg": deg(est.roll_sigma_rad), "pitch_sigma_deg": deg(est.pitch_sigma_rad),
        "yaw_sigma_deg": deg(est.yaw_sigma_rad),
        "curvature_1_m": est.curvature_1_m, "curvature_sigma_1_m": est.curvature_sigma_1_m,
        "lateral_offset_m": est.lateral_offset_m, "line_spacing_m": est.line_spacing_m,
        "n_lines": est.n_lines, "roll_equation": est.roll_equation,
        "vp_x_px": est.vp_px[0], "vp_y_px": est.vp_px[1], "edge_rms_px": est.edge_rms_px,
        "iterations": est.iterations, "warps": est.warps, "ms": ms, "reason": est.reason,
    }


def estimate_video(video: str | os.PathLike, frames, camera: Camera, mount: Mount, road: RoadMarkings,
                   options: EstimatorOptions = EstimatorOptions(), *, progress: bool = True,
                   debug_video: str | os.PathLike | None = None, debug_fps: float | None = None):
    """Run the estimator over a video.

    Parameters
    ----------
    video : path
        Video file or folder of frames.
    frames : DataFrame
        ``frame, t_s``: the frames to process and their capture times (``frames.csv``, or built
        from ``[video] fps, start_s``). Frames of the video not listed are skipped.
    camera, mount, road, options :
        As for :class:`vision.estimator.Estimator`.
    progress : bool
        tqdm progress bar.
    debug_video : path, optional
        Also write the debug video (:mod:`vision.debug`) there.

    Returns
    -------
    table : DataFrame
        One row per processed frame, :data:`VISION_COLUMNS`.
    stats : dict
        ``frames_read`` (decoded), ``frames_missing`` (listed in ``frames`` but not in the video),
        ``valid`` (count), ``median_ms``.
    """
    import time

    import pandas as pd
    from tqdm import tqdm

    from .debug import DebugWriter

    src = FrameSource(video)
    want = {int(f): float(t) for f, t in zip(frames["frame"], frames["t_s"])}
    last = max(want) if want else -1
    est = Estimator(camera, mount, road, options)
    rows = []
    writer = None
    if debug_video is not None:
        fps = debug_fps or _fps_of(frames)
        writer = DebugWriter(debug_video, fps, camera)
    n_read = 0
    bar = tqdm(total=len(want), desc="vision", unit="frame", disable=not progress)
    try:
        for i, img in enumerate(src):
            n_read = i + 1
            if i > last:
                break
            if i not in want:
                continue
            t0 = time.perf_counter()
            e = est.estimate(img, keep_debug=writer is not None)
            ms = (time.perf_counter() - t0) * 1e3
            rows.append(vision_row(want[i], i, e, ms))
            if writer is not None:
                writer.write(img, e, want[i])
            bar.update(1)
    finally:
        bar.close()
        if writer is not None:
            writer.close()
    table = pd.DataFrame(rows, columns=list(VISION_COLUMNS))
    done = set(table["frame"]) if len(table) else set()
    stats = {
        "frames_read": n_read,
        "frames_missing": sum(1 for f in want if f not in done),
        "valid": int(table["valid"].sum()) if len(table) else 0,
        "median_ms": float(table["ms"].median()) if len(table) else math.nan,
    }
    return table, stats


def _fps_of(frames) -> float:
    t = np.asarray(frames["t_s"], dtype=float)
    if t.size > 1:
        dt = np.median(np.diff(t))
        if dt > 0:
            return float(1.0 / dt)
    return 30.0
