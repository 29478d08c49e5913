"""Pinhole camera with OpenCV distortion, its mount on the vehicle, and the road markings.

These are the frozen descriptions the estimator works with; ``fusion.config`` builds them
from the ``[camera]``, ``[mount]`` and ``[road]`` tables of a config file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import VisionError
from .frames import R_v_from_cp, R_v_from_cs

__all__ = ["Camera", "Mount", "RoadMarkings"]


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics in pixels and OpenCV distortion ``(k1, k2, p1, p2, k3)``.

    Pixel ``(u, v)``: u to the right, v down, the centre of the top-left pixel at (0, 0).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise VisionError(f"camera size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise VisionError(f"camera focal lengths must be > 0, got fx={self.fx}, fy={self.fy}")
        d = tuple(float(x) for x in self.distortion)
        if len(d) not in (4, 5, 8):
            raise VisionError(f"camera distortion needs 4, 5 or 8 coefficients, got {len(d)}")
        object.__setattr__(self, "distortion", d + (0.0,) * (5 - len(d)) if len(d) < 5 else d)

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float, **kw) -> "Camera":
        """Square pixels, principal point at the image centre, horizontal field of view."""
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, **kw)

    @property
    def K(self) -> np.ndarray:
        """3x3 calibration matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(abs(k) > 0.0 for k in self.distortion)

    @property
    def dist_coeffs(self) -> np.ndarray:
        return np.asarray(self.distortion, dtype=float)

    def distort_normalized(self, xn, yn):
        """OpenCV's radial-tangential model on normalized coordinates ``x/z, y/z``."""
        k = self.distortion
        k1, k2, p1, p2, k3 = k[:5]
        r2 = xn * xn + yn * yn
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        if len(k) == 8:
            k4, k5, k6 = k[5:8]
            radial = radial / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
        yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
        return xd, yd

    def project(self, points_cp) -> np.ndarray:
        """Pixels ``(..., 2)`` of points ``(..., 3)`` in the pinhole frame ``cp`` (z > 0)."""
        p = np.asarray(points_cp, dtype=float)
        xn, yn = p[..., 0] / p[..., 2], p[..., 1] / p[..., 2]
        if self.has_distortion:
            xn, yn = self.distort_normalized(xn, yn)
        return np.stack([self.fx * xn + self.cx, self.fy * yn + self.cy], axis=-1)

    def normalized(self, uv) -> np.ndarray:
        """Undistorted normalized coordinates ``(..., 2)`` (``x/z, y/z`` in ``cp``) of pixels."""
        uv = np.asarray(uv, dtype=float)
        xd = (uv[..., 0] - self.cx) / self.fx
        yd = (uv[..., 1] - self.cy) / self.fy
        if not self.has_distortion:
            return np.stack([xd, yd], axis=-1)
        # Fixed-point start, then Newton on the forward model (converges to 1e-12 in a few steps
        # inside the calibrated field; cv2.undistortPoints stops at 1e-6 relative).
        xn, yn = xd.copy(), yd.copy()
        for _ in range(30):
            fx_, fy_ = self.distort_normalized(xn, yn)
            e = 1e-7
            ax, ay = self.distort_normalized(xn + e, yn)
            bx, by = self.distort_normalized(xn, yn + e)
            j11, j21 = (ax - fx_) / e, (ay - fy_) / e
            j12, j22 = (bx - fx_) / e, (by - fy_) / e
            rx, ry = xd - fx_, yd - fy_
            det = j11 * j22 - j12 * j21
            dx = (j22 * rx - j12 * ry) / det
            dy = (-j21 * rx + j11 * ry) / det
            xn, yn = xn + dx, yn + dy
            if np.nanmax(np.abs(dx) + np.abs(dy), initial=0.0) < 1e-13:
                break
        return np.stack([xn, yn], axis=-1)

    def rays(self, uv) -> np.ndarray:
        """Unit ray directions ``(..., 3)`` in ``cp`` through pixels ``uv``."""
        n = self.normalized(uv)
        r = np.concatenate([n, np.ones(n.shape[:-1] + (1,))], axis=-1)
        return r / np.linalg.norm(r, axis=-1, keepdims=True)


@dataclass(frozen=True)
class Mount:
    """Camera mount: optical centre ``height_m`` above the road at zero roll, straight above
    the vehicle origin (``x_m`` ahead of it), tilted down by ``tilt_rad`` about vehicle y."""

    height_m: float
    tilt_rad: float
    x_m: float = 0.0

    def __post_init__(self) -> None:
        if not self.height_m > 0:
            raise VisionError(f"mount height must be > 0 m, got {self.height_m}")
        if not -math.pi / 2 < self.tilt_rad < math.pi / 2:
            raise VisionError(f"mount tilt must be within +-90 deg, got {math.degrees(self.tilt_rad)}")

    @property
    def R_v_from_cs(self) -> np.ndarray:
        return R_v_from_cs(self.tilt_rad)

    @property
    def R_v_from_cp(self) -> np.ndarray:
        return R_v_from_cp(self.tilt_rad)

    @property
    def position_v(self) -> np.ndarray:
        """Optical centre in the vehicle frame, m."""
        return np.array([self.x_m, 0.0, self.height_m])


@dataclass(frozen=True)
class RoadMarkings:
    """Lane geometry the estimator relies on.

    ``lane_width_m`` is the distance between marking centre lines. ``marker_widths_m`` are the
    widths of the left, centre and right markings (equal by default).
    """

    lane_width_m: float = 3.5
    marker_width_m: float = 0.15
    center_line: bool = True
    marker_widths_m: tuple[float, float, float] = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if not self.lane_width_m > 0:
            raise VisionError(f"lane width must be > 0 m, got {self.lane_width_m}")
        if not self.marker_width_m > 0:
            raise VisionError(f"marker width must be > 0 m, got {self.marker_width_m}")
        if self.marker_widths_m is None:
            object.__setattr__(self, "marker_widths_m", (self.marker_width_m,) * 3)
        else:
            w = tuple(float(x) for x in self.marker_widths_m)
            if len(w) != 3 or min(w) <= 0:
                raise VisionError(f"marker_widths_m needs three widths > 0 (left, centre, right), got {w}")
            object.__setattr__(self, "marker_widths_m", w)

    @property
    def equal_widths(self) -> bool:
        w = self.marker_widths_m
        return abs(w[0] - w[2]) < 1e-9
