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
import threading
from dataclasses import dataclass

import cv2
import numba as nb
import numpy as np

from .camera import Camera
from .errors import VisionError

__all__ = ["BevGrid", "Bev", "RoadTwist", "ground_from_rays", "rays_from_pixels", "pixels_from_rays"]


#: The largest bird's-eye grid, cells: 28 times the default HD grid's (about 360,000), some
#: 40 MB per image plane.
MAX_BEV_CELLS = 10_000_000


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
                              f"y [{self.y_min_m}, {self.y_max_m}] m (the config's [vision] x_min_m, x_max_m "
                              "and the camera's view)")
        if not (self.dx_m > 0 and self.dy_m > 0):
            raise VisionError(f"BEV pixel size must be > 0, got dx={self.dx_m} m, dy={self.dy_m} m")
        if self.height * self.width > MAX_BEV_CELLS:
            # a review's [vision] options, each within its range, made a grid of 1.2e9 cells:
            # 7.3 GB and 36 s a frame, or a MemoryError traceback under a memory limit
            raise VisionError(f"BEV grid of {self.height} x {self.width} cells (x [{self.x_min_m:g}, {self.x_max_m:g}] m "
                              f"by {self.dx_m:g}, y [{self.y_min_m:g}, {self.y_max_m:g}] m by {self.dy_m:g}) is over "
                              f"{MAX_BEV_CELLS:.0e}: coarsen [vision] dx_m / dy_m or narrow x_min_m, x_max_m, "
                              "half_width_m")

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
                     x0_m: float = 0.0, twist: "RoadTwist | None" = None):
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
    twist : RoadTwist, optional
        The road turning about its centre line ahead (a superelevation runoff): the surface
        then rises by :meth:`RoadTwist.height` more (Newton from the untwisted root).

    Returns
    -------
    x_m, y_m : arrays
        Forward and left coordinates, m; NaN for rays that miss the road (at or above the
        horizon of a plane, over a crest).
    """
    rays = np.asarray(rays_cp, dtype=float)
    shape = rays.shape[:-1]
    flat = np.ascontiguousarray(rays.reshape(-1, 3))
    R = np.ascontiguousarray(R_o_from_cp, dtype=float)
    if twist is None or not twist.active:
        x, y = _ground_from_rays(flat, R, float(height_m), float(vertical_curvature_1_m), float(x0_m))
    else:
        x, y = _ground_from_rays_twisted(flat, R, float(height_m), float(vertical_curvature_1_m), float(x0_m),
                                         np.ascontiguousarray(twist.u_m, np.float64),
                                         np.ascontiguousarray(twist.bank_change_rad, np.float64),
                                         np.ascontiguousarray(twist.axis, np.float64))
    return x.reshape(shape), y.reshape(shape)


@dataclass(frozen=True)
class RoadTwist:
    """The road turning about its centre line ahead of the vehicle (a superelevation runoff).

    The bank changes by ``b(u)`` at ``u = x - x0`` ahead of the contact point ``x0`` (rad,
    ``b(0) = 0``; linear between the tabulated ``u_m``, constant twist beyond the last), about
    the centre line ``y_c(x)``, so that, above the tangent plane at the contact point, the road
    lies

    .. math:: h(x, y) = (y - y_c(x)) \tan b(u) + y_c(x_0) b'(0) u

    higher (plus the vertical curvature's ``zeta u^2 / 2``). The last term keeps the plane
    tangent at the vehicle: the vehicle rides ``-y_c(x0)`` off the axis, where the twist
    ``b'(0)`` makes a grade ``-y_c(x0) b'(0)``; near the vehicle ``h ~ b'(0) u y``, a twist about
    the vehicle's own line, whatever the axis. Checked against the simulator's exact road
    (``tools/vision_surface_oracle.py``: with the true bank change and centre-line height, the
    vision's yaw in runoffs is 0.04-0.06 deg, against 0.6-0.9 deg on the untwisted surface).

    ``axis``: the centre line as the lane model writes a line, ``(a, b, s, c2, c3)`` for
    ``y_c = a + b x + s (c2 t^2 + c3 t^3)``, ``t = x / 10`` (:class:`vision.lanemodel.LaneModel`).
    """

    u_m: np.ndarray
    bank_change_rad: np.ndarray
    axis: np.ndarray

    @property
    def active(self) -> bool:
        return bool(np.any(self.bank_change_rad != 0.0))

    def bank_change(self, u):
        """``b(u)``, rad, at ``u`` m ahead of the contact point."""
        u = np.atleast_1d(np.asarray(u, float))
        return _profile_many(np.ascontiguousarray(self.u_m, np.float64), np.ascontiguousarray(self.bank_change_rad, np.float64),
                             np.ascontiguousarray(u.ravel())).reshape(u.shape)

    def height(self, x, y, x0_m: float):
        """``h(x, y)`` above the tangent plane (without the vertical curvature), m."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        out = np.empty(x.size)
        _twist_height_many(np.ascontiguousarray(x.ravel()), np.ascontiguousarray(y.ravel()), float(x0_m),
                           self.u_m, self.bank_change_rad, self.axis, out)
        return out.reshape(x.shape)


@nb.njit(cache=True)
def _profile(u_m, b, u):  # pragma: no cover (numba)
    """``b(u)`` and ``b'(u)`` of the table (linear; the end segments' twist beyond the ends)."""
    n = u_m.size
    if u <= u_m[0]:
        i = 0
    elif u >= u_m[n - 1]:
        i = n - 2
    else:
        i = np.searchsorted(u_m, u) - 1
    db = (b[i + 1] - b[i]) / (u_m[i + 1] - u_m[i])
    return b[i] + db * (u - u_m[i]), db


@nb.njit(cache=True)
def _profile_many(u_m, b, u):  # pragma: no cover (numba)
    """``b(u)`` of :func:`_profile` at each of ``u`` (one call instead of one per point)."""
    out = np.empty(u.size)
    for i in range(u.size):
        out[i] = _profile(u_m, b, u[i])[0]
    return out


@nb.njit(cache=True, inline="always")
def _axis_y(axis, x):  # pragma: no cover (numba)
    """Centre line ``y_c(x)`` and its slope (:class:`RoadTwist`)."""
    t = x / 10.0
    shape = axis[3] * t * t + axis[4] * t * t * t
    dshape = (2.0 * axis[3] * t + 3.0 * axis[4] * t * t) / 10.0
    return axis[0] + axis[1] * x + axis[2] * shape, axis[1] + axis[2] * dshape


@nb.njit(cache=True)
def _twist_h(x, y, x0, u_m, b_tab, axis, tau0):  # pragma: no cover (numba)
    """``h``, ``dh/dx``, ``dh/dy`` of :class:`RoadTwist` at ``(x, y)``; ``tau0 = b'(0)``."""
    u = x - x0
    b, db = _profile(u_m, b_tab, u)
    yc, dyc = _axis_y(axis, x)
    yc0, _ = _axis_y(axis, x0)
    tb = math.tan(b)
    h = (y - yc) * tb + yc0 * tau0 * u
    hx = -dyc * tb + (y - yc) * (1.0 + tb * tb) * db + yc0 * tau0
    return h, hx, tb


@nb.njit(cache=True)
def _twist_height_many(x, y, x0, u_m, b_tab, axis, out):  # pragma: no cover (numba)
    tau0 = _profile(u_m, b_tab, 0.0)[1]
    for i in range(x.size):
        out[i] = _twist_h(x[i], y[i], x0, u_m, b_tab, axis, tau0)[0]


@nb.njit(cache=True)
def _segment(u_m, u, i):  # pragma: no cover (numba)
    """The table's segment :func:`_profile` takes for ``u`` (the last ``u_m[i] < u``, clamped to
    the end segments), searched from segment ``i``: the Newton steps of one ray, and neighbouring
    rays, stay in or next to the same segment, where a bisection of the table took 7 steps."""
    n = u_m.size
    if u <= u_m[0]:
        return 0
    if u >= u_m[n - 1]:
        return n - 2
    if not u == u:
        return 0                 # NaN (the result is NaN whatever the segment)
    i = min(max(i, 0), n - 2)
    while i > 0 and u_m[i] >= u:
        i -= 1
    while i < n - 2 and u_m[i + 1] < u:
        i += 1
    return i


@nb.njit(cache=True)
def _ground_from_rays_twisted(rays, R, H, zeta, x0, u_m, b_tab, axis):  # pragma: no cover (numba)
    """:func:`ground_from_rays` onto the twisted surface ``z = -H + zeta u^2 / 2 + h(x, y)``:
    Newton on ``f(t) = t r_z + H - zeta u^2 / 2 - h(t r_x, t r_y)`` from the untwisted root.

    :func:`_twist_h` written out, with what does not change from step to step taken out of the
    loop (the table's slopes, the axis at ``x0``; the same operations on the same numbers, so the
    same results): half the time."""
    x, y = _ground_from_rays(rays, R, H, zeta, x0)
    tau0 = _profile(u_m, b_tab, 0.0)[1]
    yc0 = _axis_y(axis, x0)[0]
    slopes = np.empty(u_m.size - 1)
    for k in range(u_m.size - 1):
        slopes[k] = (b_tab[k + 1] - b_tab[k]) / (u_m[k + 1] - u_m[k])     # as _profile computes them
    seg = 0
    for i in range(rays.shape[0]):
        if not math.isfinite(x[i]):
            continue
        a, b, c = rays[i, 0], rays[i, 1], rays[i, 2]
        r0 = a * R[0, 0] + b * R[0, 1] + c * R[0, 2]
        r1 = a * R[1, 0] + b * R[1, 1] + c * R[1, 2]
        r2 = a * R[2, 0] + b * R[2, 1] + c * R[2, 2]
        t = x[i] / r0 if abs(r0) > 1e-12 else -H / r2
        ok = False
        for _ in range(20):
            px, py = t * r0, t * r1
            u = px - x0
            # _twist_h(px, py, x0, u_m, b_tab, axis, tau0)
            seg = _segment(u_m, u, seg)
            db = slopes[seg]
            tb = math.tan(b_tab[seg] + db * (u - u_m[seg]))
            yc, dyc = _axis_y(axis, px)
            h = (py - yc) * tb + yc0 * tau0 * u
            hx = -dyc * tb + (py - yc) * (1.0 + tb * tb) * db + yc0 * tau0
            f = t * r2 + H - 0.5 * zeta * u * u - h
            df = r2 - (zeta * u + hx) * r0 - tb * r1
            if df >= -1e-12:
                break            # grazing the surface: no stable hit
            step = f / df
            t -= step
            if abs(step * r0) < 1e-7 and abs(step * r1) < 1e-7:
                ok = t > 0.0
                break
        if ok:
            x[i] = t * r0
            y[i] = t * r1
        else:
            x[i] = np.nan
            y[i] = np.nan
    return x, y


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
    surface : tuple, optional
        ``(zeta, x0, twist)``: the view of the road as :func:`ground_from_rays` with that vertical
        curvature, contact point and :class:`RoadTwist` has it, instead of the plane (the warp
        is then a per-pixel remap; ``image_from_bev`` stays the plane's homography, for what
        only needs it roughly: the image's footprint, drawing).
    """

    def __init__(self, grid: BevGrid, camera: Camera, R_o_from_cp, height_m: float, surface=None) -> None:
        self.grid, self.camera = grid, camera
        self.surface = surface
        self.R_o_from_cp = np.asarray(R_o_from_cp, dtype=float)
        self.height_m = float(height_m)
        # image (undistorted pixel) from BEV pixel: K R_cp_from_o M  (Damon et al. 2018, eq. (5)).
        self.image_from_bev = camera.K @ self.R_o_from_cp.T @ grid.M_h(self.height_m)
        self.f_vx, self.f_vy = grid.f_v(self.height_m)
        self.u0 = grid.y_max_m / grid.dy_m
        self.v0 = grid.x_max_m / grid.dx_m

    @property
    def bev_from_image(self) -> np.ndarray:
        """BEV pixel from image (undistorted) pixel, the inverse of ``image_from_bev``: computed
        when asked (the estimator never does; it was a 3x3 inverse every warp)."""
        return np.linalg.inv(self.image_from_bev)

    # ---- coordinates ----

    def rays_of_bev(self, u, v) -> np.ndarray:
        """Rays in ``cp`` ``(..., 3)`` through BEV pixels."""
        u, v = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float))
        if self.surface is not None:
            return self._surface_points(u, v) @ self.R_o_from_cp
        p = np.stack([u, v, np.ones_like(u)], axis=-1) @ (self.R_o_from_cp.T @ self.grid.M_h(self.height_m)).T
        return p / p[..., 2:3]

    def _surface_points(self, u, v) -> np.ndarray:
        """The road points ``(X, Y, Z)`` (road frame at the nadir) of BEV pixels on the surface."""
        zeta, x0, twist = self.surface
        g = self.grid
        X = g.x_of_row(v)
        Y = g.y_of_col(u)
        Z = -self.height_m + 0.5 * zeta * (X - x0) ** 2 + twist.height(X, Y, x0)
        return np.stack([X, Y, Z], axis=-1)

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
        if self.surface is not None:
            zeta, x0, twist = self.surface
            pad = 0 if undistort_maps is None else undistort_maps[2]
            xu, yu = _surface_maps(g.height, g.width, g.x_max_m, g.y_max_m, g.dx_m, g.dy_m, self.height_m,
                                   float(zeta), float(x0), np.ascontiguousarray(twist.u_m, np.float64),
                                   np.ascontiguousarray(twist.bank_change_rad, np.float64),
                                   np.ascontiguousarray(twist.axis, np.float64),
                                   np.ascontiguousarray(self.R_o_from_cp), np.ascontiguousarray(self.camera.K, np.float64),
                                   float(pad), *_map_buffers(g.height, g.width))
            if undistort_maps is None:
                return cv2.remap(image, xu, yu, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            lut_x, lut_y, _ = undistort_maps
            xd = cv2.remap(lut_x, xu, yu, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1e6)
            yd = cv2.remap(lut_y, xu, yu, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1e6)
            return cv2.remap(image, xd, yd, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
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


#: Per thread, the storage of :meth:`Bev.warp`'s surface maps, kept from warp to warp.
_MAP_STORE = threading.local()


def _map_buffers(n_rows: int, n_cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Two float32 ``(n_rows, n_cols)`` arrays for the surface maps, views of storage kept from
    call to call (per thread; they only live until the remap). Fresh ones (2 x 0.9 MB for the
    HD drives' BEV) came from the system each time: 350 page faults, 0.45 ms of a 0.6 ms
    warp."""
    n = n_rows * n_cols
    store = getattr(_MAP_STORE, "arrays", None)
    if store is None or store[0].size < n:
        store = (np.empty(n, np.float32), np.empty(n, np.float32))
        _MAP_STORE.arrays = store
    return store[0][:n].reshape(n_rows, n_cols), store[1][:n].reshape(n_rows, n_cols)


@nb.njit(cache=True)
def _surface_maps(n_rows, n_cols, x_max, y_max, dx, dy, H, zeta, x0, u_m, b_tab, axis, R, K, pad, mx, my):  # pragma: no cover (numba)
    """Undistorted image pixel (plus ``pad``) of every BEV pixel on the surface of
    :class:`Bev` ``surface``: float32 maps for ``cv2.remap`` (-1e6 behind the camera), into
    ``mx``, ``my`` ``(n_rows, n_cols)``."""
    tau0 = _profile(u_m, b_tab, 0.0)[1]
    yc0 = _axis_y(axis, x0)[0]
    fx, sk, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2] + pad, K[1, 1], K[1, 2] + pad
    # along a row X and the bank are fixed and Z is linear in Y: cp = R^T (X, Y, Z) steps by a
    # constant vector from column to column
    for v in range(n_rows):
        X = x_max - v * dx
        u = X - x0
        b = _profile(u_m, b_tab, u)[0]
        tb = math.tan(b)
        yc = _axis_y(axis, X)[0]
        z0 = -H + 0.5 * zeta * u * u + yc0 * tau0 * u - yc * tb
        Z = z0 + y_max * tb
        q0 = R[0, 0] * X + R[1, 0] * y_max + R[2, 0] * Z
        q1 = R[0, 1] * X + R[1, 1] * y_max + R[2, 1] * Z
        q2 = R[0, 2] * X + R[1, 2] * y_max + R[2, 2] * Z
        d0 = -dy * (R[1, 0] + R[2, 0] * tb)
        d1 = -dy * (R[1, 1] + R[2, 1] * tb)
        d2 = -dy * (R[1, 2] + R[2, 2] * tb)
        for c in range(n_cols):
            p2 = q2 + c * d2
            if p2 > 1e-9:
                inv = 1.0 / p2
                p0 = (q0 + c * d0) * inv
                p1 = (q1 + c * d1) * inv
                mx[v, c] = fx * p0 + sk * p1 + cx
                my[v, c] = fy * p1 + cy
            else:
                mx[v, c] = -1e6
                my[v, c] = -1e6
    return mx, my


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
        # within [-1, u_max + 1] (an empty row keeps lo > hi): a pose past the horizon gives
        # bounds of 1e19 and more, which the marker search casts to integers (undefined in
        # numba: a segmentation fault with a seed pitched 84 deg)
        if not lo[v] <= u_max:
            lo[v] = u_max + 1.0
        if not hi[v] >= 0.0:
            hi[v] = -1.0
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
