"""Debug video: the camera frame with the detected lines, the vanishing point and the horizon,
beside the BEV with the fitted edges and the cross-sections.

Left panel (the camera frame): the edges of the markers used (green left edges, red right
edges; blue for markers found but not used), the image lines of the paper's vanishing point
when it used them (yellow), the vanishing point (magenta cross) and the horizon of the road
plane at the estimated pose (cyan). Right panel (the BEV the markers were found in, at the
road's proportions, a metre ahead as long as a metre across, fitted into the panel): the edge
fits, the cross-sections (yellow rows) and the camera's centre line at the BEV's near edge
(magenta dot). Text: the angles, their 1-sigma, the validity (or why not), the time.
"""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path

import cv2
import numpy as np

from .camera import Camera
from .errors import VisionError
from .estimator import VisionEstimate

__all__ = ["DebugWriter", "render_debug", "strip_text"]

GREEN, RED, BLUE, YELLOW, MAGENTA, CYAN, WHITE = ((0, 200, 0), (0, 0, 230), (230, 120, 0), (0, 220, 220),
                                                  (220, 0, 220), (230, 230, 0), (255, 255, 255))


def _pts(uv: np.ndarray) -> np.ndarray:
    return np.round(uv).astype(np.int32).reshape(-1, 1, 2)


def strip_text(est: VisionEstimate, t_s: float | None = None, t0_s: float | None = None,
               clock_offset_s: float = 0.0) -> list[str]:
    """The lines of a frame's strip: its angles and 1-sigma (or why it is invalid), then its time
    since ``t0_s`` (the video's first frame) with the CAN clock's after it, ``t_s +
    clock_offset_s`` (the clock alone, a Unix time of ten digits, was hard to read against the
    plots, a review); with an offset, the camera's own ``t_s`` under it (the strip had said the
    camera's time as the CAN clock's: 4.000 where the fusion put the frame at 4.200, a review)."""
    lines = []
    if est.valid:
        lines.append("roll %+6.2f  pitch %+5.2f  yaw %+5.2f deg" % tuple(math.degrees(x) for x in est.rpy_rad))
        lines.append("1-sigma %.2f %.2f %.2f deg  %s  %d lines" % (
            math.degrees(est.roll_sigma_rad), math.degrees(est.pitch_sigma_rad), math.degrees(est.yaw_sigma_rad),
            est.roll_equation, est.n_lines))
    else:
        lines.append("invalid: " + (est.reason or "?")[:70])
    if t_s is not None:
        can_s = t_s + clock_offset_s
        lines.append(f"t {t_s - t0_s:.3f} s (CAN clock {can_s:.3f})" if t0_s is not None else f"t {can_s:.3f} s")
        if clock_offset_s:
            lines.append(f"camera clock {t_s:.3f} ({-clock_offset_s:+.3f} s from the CAN clock)")
    return lines


def render_debug(image: np.ndarray, est: VisionEstimate, camera: Camera, t_s: float | None = None,
                 t0_s: float | None = None, clock_offset_s: float = 0.0) -> np.ndarray:
    """The debug picture of one frame (uint8 BGR): the frame and the BEV panel (half its width)
    side by side, the estimate's text (:func:`strip_text`; ``t_s`` on the camera's clock,
    ``clock_offset_s`` added to it gives the CAN clock's) in a strip under them."""
    frame = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    frame = np.ascontiguousarray(frame[..., :3]).copy()
    if frame.dtype != np.uint8:
        frame = np.clip(np.nan_to_num(frame.astype(np.float32)), 0, 255).astype(np.uint8)
    H, W = frame.shape[:2]
    dbg = est.debug
    # the BEV panel has one size for every frame (half the frame's width), the BEV fitted into
    # it: its picture's width varies from frame to frame, and the writer had scaled the whole
    # picture, camera half too, to the first frame's size (1.3-1.8 times wide on KITTI, a review)
    bev_panel = np.zeros((H, max(2, W // 2), 3), np.uint8)
    if dbg is not None and getattr(dbg, "bev", None) is not None:
        bev = dbg.bev
        # Marker edges in the frame (through the BEV's homography, then the camera's distortion).
        for i, m in enumerate(dbg.markers):
            used = i in dbg.used
            k = m.inliers
            for u, col in ((m.u_left[k], GREEN if used else BLUE), (m.u_right[k], RED if used else BLUE)):
                p = np.stack([u, m.v[k], np.ones_like(u)], -1) @ bev.image_from_bev.T
                ok = p[:, 2] > 0
                uv = p[ok, :2] / p[ok, 2:3]
                if camera.has_distortion and uv.size:
                    xn = (uv[:, 0] - camera.cx) / camera.fx
                    yn = (uv[:, 1] - camera.cy) / camera.fy
                    xd, yd = camera.distort_normalized(xn, yn)
                    uv = np.stack([camera.fx * xd + camera.cx, camera.fy * yd + camera.cy], -1)
                good = np.all(np.isfinite(uv), 1) & (np.abs(uv).max(1) < 1e5)
                if good.sum() > 1:
                    cv2.polylines(frame, [_pts(uv[good])], False, col, 1, cv2.LINE_AA)
        for a, b in getattr(dbg, "image_lines", []) or []:
            cv2.line(frame, tuple(int(round(x)) for x in a), tuple(int(round(x)) for x in b), YELLOW, 1, cv2.LINE_AA)
        # BEV panel with the fits and the cross-sections, drawn at the road's proportions: the
        # grid's rows are 0.1 m and its columns 1-4 cm, and shown a pixel for a cell it had been
        # a strip a quarter of the panel's height, the lines' angles exaggerated several times
        img = dbg.bev_image
        if img is not None and img.size:
            g = bev.grid
            PH, PW = bev_panel.shape[:2]
            h, w = img.shape[:2]
            scale = min(PH / (h * g.dx_m), PW / (w * g.dy_m))     # panel pixels per metre
            bw, bh = max(1, min(PW, int(round(w * g.dy_m * scale)))), max(1, min(PH, int(round(h * g.dx_m * scale))))
            sx, sy = bw / w, bh / h

            def to_panel(u, v):
                """BEV pixel (column, row) to the resized picture's (cv2.resize's pixel centres)."""
                return (np.asarray(u) + 0.5) * sx - 0.5, (np.asarray(v) + 0.5) * sy - 0.5

            # the columns shrink and the rows grow: in two steps, as INTER_AREA averages only
            # where both shrink (one step read two source columns, a thin marker's brightness
            # anywhere from 0 to its full)
            grey = np.clip(img, 0, 255).astype(np.uint8)
            grey = cv2.resize(grey, (bw, h), interpolation=cv2.INTER_AREA)
            grey = cv2.resize(grey, (bw, bh), interpolation=cv2.INTER_AREA if bh < h else cv2.INTER_LINEAR)
            b = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
            for i, m in enumerate(dbg.markers):
                used = i in dbg.used
                vv = np.arange(int(m.v_far), int(m.v_near) + 1, dtype=float)
                if vv.size < 2:
                    continue
                ul, ur = m.u_at(vv)
                for u, col in ((ul, GREEN if used else BLUE), (ur, RED if used else BLUE)):
                    cv2.polylines(b, [_pts(np.stack(to_panel(u, vv), -1))], False, col, 1, cv2.LINE_AA)
            if dbg.cross_rows_v is not None:
                for v in np.atleast_1d(dbg.cross_rows_v):
                    if np.isfinite(v):
                        y = int(round(float(to_panel(0.0, v)[1])))
                        if 0 <= y < bh:
                            cv2.line(b, (0, y), (bw - 1, y), YELLOW, 1)
            # the camera's centre line (lateral 0) at the BEV's near edge, x_min ahead of the nadir
            cv2.circle(b, (int(round(float(to_panel(bev.u0, 0.0)[0]))), bh - 1), 4, MAGENTA, -1)
            x0, y0 = (PW - bw) // 2, (PH - bh) // 2
            bev_panel[y0:y0 + bh, x0:x0 + bw] = b
    # Vanishing point and horizon.
    if est.valid and all(math.isfinite(v) for v in est.vp_px):
        vx, vy = est.vp_px
        if abs(vx) < 1e5 and abs(vy) < 1e5:
            cv2.drawMarker(frame, (int(round(vx)), int(round(vy))), MAGENTA, cv2.MARKER_CROSS, 20, 2)
        R = getattr(dbg, "R_o_from_cp", None) if dbg is not None else None
        if R is not None:
            # The road plane's points at infinity: directions (cos a, sin a, 0) in the road frame.
            a = np.radians(np.linspace(-60, 60, 25))
            d = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], -1) @ R     # in cp
            d = d[d[:, 2] > 1e-6]
            if camera.has_distortion and d.shape[0]:
                # only where the distortion model still grows with the radius: past it the
                # polynomial folds back and the horizon crossed itself (Udacity's k1 -0.27, k3
                # -0.24: u = -9569, -1052, 937, ..., a review)
                r = np.hypot(d[:, 0] / d[:, 2], d[:, 1] / d[:, 2])
                d = d[r < _monotonic_radius(camera)]
            if d.shape[0] > 1:
                uv = camera.project(d)
                good = np.all(np.isfinite(uv), 1) & (np.abs(uv).max(1) < 1e5)
                if good.sum() > 1:
                    cv2.polylines(frame, [_pts(uv[good])], False, CYAN, 1, cv2.LINE_AA)
    lines = strip_text(est, t_s, t0_s, clock_offset_s)
    scale = max(0.5, H / 900.0)
    step = int(round(30 * scale)) + 4
    # the text in a strip under the pictures, of three lines whatever the frame says (four with a
    # clock offset: one size for the whole video): drawn over the frame, its box hid the
    # vanishing point and most of the horizon of a 320x180 frame (a review)
    pictures = np.concatenate([frame, bev_panel], axis=1)
    strip = np.zeros((step * (4 if clock_offset_s else 3) + 8, pictures.shape[1], 3), dtype=pictures.dtype)
    for i, text in enumerate(lines):
        cv2.putText(strip, text, (8, step * (i + 1)), cv2.FONT_HERSHEY_SIMPLEX, scale, WHITE, 1, cv2.LINE_AA)
    return np.concatenate([pictures, strip], axis=0)


@functools.lru_cache(maxsize=8)
def _monotonic_radius(camera: Camera) -> float:
    """The normalized radius up to which ``camera``'s distortion grows with the radius (once per
    camera, not per debug frame)."""
    r = np.linspace(0.0, 4.0, 801)
    xd, yd = camera.distort_normalized(r, np.zeros_like(r))
    falls = np.flatnonzero(np.diff(np.hypot(xd, yd)) <= 0)
    return float(r[falls[0]]) if len(falls) else math.inf


class DebugWriter:
    """Writes :func:`render_debug` pictures to a video (mp4v; ``.avi`` gets MJPG).

    The file is written under a temporary name and renamed by :meth:`close` (removed when the
    frames ended in an error).
    """

    #: The containers it writes: mp4v for ``.mp4 .mov .mkv``, MJPG for ``.avi``.
    SUFFIXES = (".mp4", ".mov", ".mkv", ".avi")

    def __init__(self, path: str | os.PathLike, fps: float, camera: Camera, clock_offset_s: float = 0.0) -> None:
        #: added to a frame's time for the CAN clock's in the strip (the config's camera_time_offset_s)
        self.clock_offset_s = float(clock_offset_s)
        self.path = self.check(path)
        self.tmp = self.path.with_name(self.path.stem + ".partial" + self.path.suffix)
        self.fps, self.camera = float(fps), camera
        self.writer = None
        self.size = None
        self.t0_s: float | None = None     # the first frame's time: the strip counts from it

    @classmethod
    def check(cls, path: str | os.PathLike) -> Path:
        """``path`` if it names a video this writer can write (a known suffix), else
        :class:`VisionError`: for a command to say so before its work (its folder is made on
        writing, as the tables' are; the commands check the place,
        :func:`fusion.cli.check_output_file`)."""
        path = Path(path)
        if path.suffix.lower() not in cls.SUFFIXES:
            raise VisionError(f"{path}: a debug video must end in {', '.join(cls.SUFFIXES)}")
        return path

    def write(self, image: np.ndarray, est: VisionEstimate, t_s: float | None = None) -> None:
        if self.t0_s is None and t_s is not None:
            self.t0_s = t_s
        pic = render_debug(image, est, self.camera, t_s, self.t0_s, self.clock_offset_s)
        if pic.shape[0] % 2 or pic.shape[1] % 2:   # the codecs take even sizes (an odd row was cut)
            pic = cv2.copyMakeBorder(pic, 0, pic.shape[0] % 2, 0, pic.shape[1] % 2, cv2.BORDER_CONSTANT)
        if self.writer is None:
            self.tmp.parent.mkdir(parents=True, exist_ok=True)
            self.size = (pic.shape[1], pic.shape[0])
            fourcc = cv2.VideoWriter_fourcc(*("MJPG" if self.path.suffix.lower() == ".avi" else "mp4v"))
            self.writer = cv2.VideoWriter(str(self.tmp), fourcc, self.fps, self.size)
            if not self.writer.isOpened():
                raise VisionError(f"{self.path}: OpenCV cannot write this video")
        if (pic.shape[1], pic.shape[0]) != self.size:     # a frame of another size: scaled to the first's
            pic = cv2.resize(pic, self.size)
        self.writer.write(pic)

    def close(self, complete: bool = True) -> None:
        """Finish the file: renamed to its name when ``complete``, else (an error or an
        interrupt ended the frames) removed, so that no partial video looks complete."""
        if self.writer is not None:
            self.writer.release()
            self.writer = None
            if complete:
                os.replace(self.tmp, self.path)
            else:
                self.tmp.unlink(missing_ok=True)
