"""Inverse perspective mapping: a metric bird's-eye view (BEV) of the road from one image.

The BEV is the picture of a virtual camera at the real camera's optical centre, looking
straight down the road normal of an *assumed* road frame (Alrazouk et al. 2024, section III;
Damon et al. 2018, eqs. (1)-(5)). Its pixel ``(u, v)`` shows the road point

    X = x_max - v * dx    (forward, m)        Y = y_max - u * dy    (left, m)

at ``Z = -H`` below the optical centre, in a road-aligned frame whose origin is the camera's
nadir (the frame ``R_IPM`` of the 2024 paper: origin at the camera, orientation of ``o``).
So the virtual camera has (eq. (5)) ``f_vx = H / dy = H w_pix / W_met`` and
``f_vy = H / dx = H h_pix / H_met``, principal point at the nadir ``u0 = y_max / dy``,
``v0 = x_max / dx``. Eq. (5) puts the ROI's near edge at the camera (``x_min = 0``,
``v0 = h_pix``); here the ROI starts at ``x_min`` because the road right under the camera
is outside the picture, and ``v0`` moves accordingly.

The assumed pose is the rotation ``R_o_from_cp`` (pinhole frame to road frame) and the
camera height ``H`` above the road. The collineation of Damon et al. (eq. (5),
``G = (K M S^-1)^-1``) is built directly as ``image_from_bev = K R_cp_from_o M`` with
``M`` taking BEV pixels to road points; the warp is one ``cv2.warpPerspective`` (or, for a
camera with distortion, two ``cv2.remap`` calls that fold the undistortion in).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numba as nb
import numpy as np

from .camera import Camera
from .errors import VisionError

__all__ = ["BevGrid", "Bev", "ground_from_rays", "rays_from_pixels", "pixels_from_rays"]


@dataclass(frozen=True)
class BevGrid:
    """Metric region of interest and pixel size of the BEV.

    Parameters
    ----------
    x_min_m, x_max_m : float
        Forward extent ahead of the camera's nadir, m.
    y_min_m, y_max_m : float
        Lateral extent, m, positive to the left.
    dx_m, dy_m : float
        Pixel size forward (rows) and lateral (columns), m.
    """

    x_min_m: float
    x_max_m: float
    y_min_m: float
    y_max_m: float
    dx_m: float
    dy_m: float

    def __post_init__(self) -> None:
        if not (self.x_max_m > self.x_min_m and self.y_max_m > self.y_min_m):
            raise VisionError(f"BEV region is empty: x [{self.x_min_m}, {self.x_max_m}] m, "
                              f"y [{self.y_min_m}, {self.y_max_m}] m")
        if not (self.dx_m > 0 and self.dy_m > 0):
            raise VisionError(f"BEV pixel size must be > 0, got dx={self.dx_m} m, dy={self.dy_m} m")

    @property
    def width(self) -> int:
        """``w_pix``: columns."""
        return int(round((self.y_max_m - self.y_min_m) / self.dy_m))

    @property
    def height(self) -> int:
        """``h_pix``: rows."""
        return int(round((self.x_max_m - self.x_min_m) / self.dx_m))

    def M_h(self, height_m: float) -> np.ndarray:
        """3x3: ``(X, Y, -H) = M_h @ (u, v, 1)`` for a camera ``height_m`` above the road."""
        return np.array([[0.0, -self.dx_m, self.x_max_m],
                         [-self.dy_m, 0.0, self.y_max_m],
                         [0.0, 0.0, -height_m]])

    def f_v(self, height_m: float) -> tuple[float, float]:
        """Virtual camera focal lengths ``(f_vx, f_vy)`` in BEV pixels (eq. (5))."""
        return height_m / self.dy_m, height_m / self.dx_m

    def x_of_row(self, v) -> np.ndarray:
        return self.x_max_m - np.asarray(v, dtype=float) * self.dx_m

    def y_of_col(self, u) -> np.ndarray:
        return self.y_max_m - np.asarray(u, dtype=float) * self.dy_m

    def row_of_x(self, x) -> np.ndarray:
        return (self.x_max_m - np.asarray(x, dtype=float)) / self.dx_m

    def col_of_y(self, y) -> np.ndarray:
        return (self.y_max_m - np.asarray(y, dtype=float)) / self.dy_m


def rays_from_pixels(camera: Camera, uv) -> np.ndarray:
    """Rays ``(xn, yn, 1)`` in ``cp`` (undistorted normalized coordinates) of pixels ``(..., 2)``."""
    n = camera.normalized(uv)
    return np.concatenate([n, np.ones(n.shape[:-1] + (1,))], axis=-1)


def pixels_from_rays(camera: Camera, rays_cp) -> np.ndarray:
    """Pixels ``(..., 2)`` of rays ``(..., 3)`` in ``cp`` (z > 0), with distortion."""
    return camera.project(rays_cp)


def ground_from_rays(rays_cp, R_o_from_cp, height_m: float, vertical_curvature_1_m: float = 0.0,
                     x0_m: float = 0.0):
    """Road points hit by rays, in the road-aligned frame at the camera's nadir.

    The road is the plane ``z = -H`` or, with a vertical curvature ``zeta``, the surface
    ``z = -H + zeta (x - x0)^2 / 2`` tangent to that plane at ``x0`` (a sag for ``zeta > 0``, a
    crest for ``zeta < 0``; on a curve of curvature ``kappa`` banked by ``b`` the road seen from
    its tangent plane has ``zeta = -kappa sin(b)``, see :mod:`vision.lanemodel`). The ray
    ``t r`` meets it where ``zeta/2 r_x^2 t^2 - (r_z + zeta x0 r_x) t + zeta x0^2/2 - H = 0``;
    the root taken is the one that tends to the plane's ``t = H / -r_z`` as ``zeta -> 0``.

    Parameters
    ----------
    rays_cp : (..., 3) array
        Ray directions in ``cp``.
    R_o_from_cp : (3, 3) array
        Camera orientation relative to the road.
    height_m : float
        Optical centre above the road's tangent plane, m.
    vertical_curvature_1_m : float
        ``zeta``, 1/m (0: a plane).
    x0_m : float
        Where the surface touches the plane (the contact point), m ahead of the nadir.

    Returns
    -------
    x_m, y_m : arrays
        Forward and left coordinates, m; NaN for rays that miss the road (at or above the
        horizon of a plane, over a crest).
    """
    rays = np.asarray(rays_cp, dtype=float)
    shape = rays.shape[:-1]
    x, y = _ground_from_rays(np.ascontiguousarray(rays.reshape(-1, 3)), np.ascontiguousarray(R_o_from_cp, dtype=float),
                             float(height_m), float(vertical_curvature_1_m), float(x0_m))
    return x.reshape(shape), y.reshape(shape)


@nb.njit(cache=True)
def _ground_from_rays(rays, R, H, zeta, x0):  # pragma: no cover (numba)
    """:func:`ground_from_rays` for rays ``(n, 3)``, one pass."""
    n = rays.shape[0]
    x = np.empty(n)
    y = np.empty(n)
    C = 0.5 * zeta * x0 * x0 - H
    for i in range(n):
        a, b, c = rays[i, 0], rays[i, 1], rays[i, 2]
        r0 = a * R[0, 0] + b * R[0, 1] + c * R[0, 2]
        r1 = a * R[1, 0] + b * R[1, 1] + c * R[1, 2]
        r2 = a * R[2, 0] + b * R[2, 1] + c * R[2, 2]
        t = np.nan
        if zeta == 0.0:
            if -r2 > 1e-9:
                t = H / -r2
        else:
            A = 0.5 * zeta * r0 * r0
            B = -(r2 + zeta * x0 * r0)
            disc = B * B - 4.0 * A * C
            if disc >= 0:
                den = -B - math.sqrt(disc)        # the planar root's branch: t = 2C / den
                if den < -1e-12:
                    t = 2.0 * C / den
        x[i] = t * r0
        y[i] = t * r1
    return x, y


class Bev:
    """One BEV warp: the grid, the assumed pose and the homography for one image.

    Parameters
    ----------
    grid : BevGrid
    camera : Camera
    R_o_from_cp : (3, 3) array
        Assumed orientation of the pinhole frame relative to the road.
    height_m : float
        Assumed camera height above the road, m.
    """

    def __init__(self, grid: BevGrid, camera: Camera, R_o_from_cp, height_m: float) -> None:
        self.grid, self.camera = grid, camera
        self.R_o_from_cp = np.asarray(R_o_from_cp, dtype=float)
        self.height_m = float(height_m)
        # image (undistorted pixel) from BEV pixel: K R_cp_from_o M  (Damon et al. 2018, eq. (5)).
        self.image_from_bev = camera.K @ self.R_o_from_cp.T @ grid.M_h(self.height_m)
        self.bev_from_image = np.linalg.inv(self.image_from_bev)
        self.f_vx, self.f_vy = grid.f_v(self.height_m)
        self.u0 = grid.y_max_m / grid.dy_m
        self.v0 = grid.x_max_m / grid.dx_m

    # ---- coordinates ----

    def rays_of_bev(self, u, v) -> np.ndarray:
        """Rays in ``cp`` ``(..., 3)`` through BEV pixels."""
        u, v = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float))
        p = np.stack([u, v, np.ones_like(u)], axis=-1) @ (self.R_o_from_cp.T @ self.grid.M_h(self.height_m)).T
        return p / p[..., 2:3]

    def bev_of_rays(self, rays_cp) -> tuple[np.ndarray, np.ndarray]:
        """BEV pixel coordinates of rays in ``cp`` (NaN above the horizon)."""
        x, y = ground_from_rays(rays_cp, self.R_o_from_cp, self.height_m)
        return self.grid.col_of_y(y), self.grid.row_of_x(x)

    def valid_columns(self) -> tuple[np.ndarray, np.ndarray]:
        """Per BEV row, the column interval ``[lo, hi]`` whose pixels come from inside the image
        (undistorted image rectangle), as float arrays of length ``h_pix``; empty rows get
        ``lo > hi``."""
        g, cam = self.grid, self.camera
        return _valid_columns(np.ascontiguousarray(self.image_from_bev), g.height, float(g.width - 1),
                              float(cam.width), float(cam.height))

    # ---- warp ----

    def warp(self, image: np.ndarray, undistort_maps=None) -> np.ndarray:
        """The BEV of ``image`` (any dtype OpenCV warps), bilinear, zero outside the image.

        ``undistort_maps`` (from :func:`undistortion_lookup`) folds the camera's distortion
        into the warp; without distortion it is one ``cv2.warpPerspective``.
        """
        g = self.grid
        if undistort_maps is None:
            return cv2.warpPerspective(image, self.image_from_bev, (g.width, g.height),
                                       flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                       borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        # BEV pixel -> undistorted pixel (homography) -> distorted pixel (lookup table).
        lut_x, lut_y, pad = undistort_maps
        uu, vv = np.meshgrid(np.arange(g.width, dtype=np.float32), np.arange(g.height, dtype=np.float32))
        H = self.image_from_bev.astype(np.float64)
        w = H[2, 0] * uu + H[2, 1] * vv + H[2, 2]
        xu = ((H[0, 0] * uu + H[0, 1] * vv + H[0, 2]) / w + pad).astype(np.float32)
        yu = ((H[1, 0] * uu + H[1, 1] * vv + H[1, 2]) / w + pad).astype(np.float32)
        xu[w <= 0] = -1e6
        xd = cv2.remap(lut_x, xu, yu, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1e6)
        yd = cv2.remap(lut_y, xu, yu, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1e6)
        return cv2.remap(image, xd, yd, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


@nb.njit(cache=True)
def _valid_columns(H, n_rows, u_max, W, Hh):  # pragma: no cover (numba)
    """For each row v, the u range where the homogeneous image point ``H (u, v, 1)`` lies in
    front of the camera and inside ``[-0.5, W - 0.5] x [-0.5, Hh - 0.5]``: five linear
    constraints ``c . p(u) >= 0`` with ``p(u) = a + u b``."""
    lo = np.zeros(n_rows)
    hi = np.full(n_rows, u_max)
    C = np.array([[1.0, 0.0, 0.5], [-1.0, 0.0, W - 0.5], [0.0, 1.0, 0.5], [0.0, -1.0, Hh - 0.5],
                  [0.0, 0.0, 1.0]])
    for v in range(n_rows):
        a0 = H[0, 1] * v + H[0, 2]
        a1 = H[1, 1] * v + H[1, 2]
        a2 = H[2, 1] * v + H[2, 2]
        for k in range(5):
            ca = C[k, 0] * a0 + C[k, 1] * a1 + C[k, 2] * a2
            cb = C[k, 0] * H[0, 0] + C[k, 1] * H[1, 0] + C[k, 2] * H[2, 0]
            if cb > 0:
                lo[v] = max(lo[v], -ca / cb)
            elif cb < 0:
                hi[v] = min(hi[v], -ca / cb)
            elif ca < 0:
                lo[v] = np.inf
    return lo, hi


def undistortion_lookup(camera: Camera, pad_px: int = 64):
    """Lookup tables ``(lut_x, lut_y, pad)``: distorted pixel of each undistorted pixel
    ``(x - pad, y - pad)`` over the image plus a margin, float32, for :meth:`Bev.warp`."""
    W, H = camera.width + 2 * pad_px, camera.height + 2 * pad_px
    xx, yy = np.meshgrid(np.arange(W, dtype=float) - pad_px, np.arange(H, dtype=float) - pad_px)
    xn = (xx - camera.cx) / camera.fx
    yn = (yy - camera.cy) / camera.fy
    xd, yd = camera.distort_normalized(xn, yn)
    return ((camera.fx * xd + camera.cx).astype(np.float32), (camera.fy * yd + camera.cy).astype(np.float32),
            pad_px)


def default_grid(camera: Camera, marker_width_m: float = 0.15, *, half_width_m: float = 6.5,
                 min_marker_px: float = 3.0, max_range_m: float = 40.0, min_range_m: float = 1.0,
                 dy_m: float | None = None, dx_m: float = 0.1, height_m: float = 1.1,
                 tilt_rad: float = 0.0) -> BevGrid:
    """A BEV grid suited to a camera: far edge where a marker is still ``min_marker_px`` wide,
    near edge at the first road visible at the bottom of the picture (at least ``min_range_m``),
    lateral pixel the image's footprint at a third of the range (clamped to [1, 4] cm)."""
    f = camera.fx
    x_max = min(max_range_m, marker_width_m * f / min_marker_px)
    # Bottom image row's ray, at zero roll and pitch = tilt.
    down = math.atan((camera.height - 1 - camera.cy) / camera.fy) + tilt_rad
    x_bottom = height_m / math.tan(down) if down > 0.01 else min_range_m
    x_min = max(min_range_m, x_bottom + 0.3)
    if x_max <= x_min + 2.0:
        x_max = x_min + 10.0
    if dy_m is None:
        dy_m = float(np.clip((x_min + (x_max - x_min) / 3.0) / f, 0.01, 0.04))
    return BevGrid(x_min, x_max, -half_width_m, half_width_m, dx_m, dy_m)
