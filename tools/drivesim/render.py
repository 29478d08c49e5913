"""Ray-casting renderer of the road as seen by the vehicle's camera.

Every sample's ray is intersected exactly with the road surface of :mod:`drivesim.road`
(Newton on ``o + lam r = S(s, d)``), and shaded from the road coordinates ``(s, d)``:
markings (two solid edge lines and a dashed centre line, widths per line), asphalt and verge
textures fixed to the road. Pixels are area anti-aliased by an ``n x n`` grid of sub-pixel
rays (n >= 4) wherever a marking edge, a dash end or the verge could cross the pixel; the
others are uniform in the markings and take one ray, with the texture band-limited to the
pixel footprint. A pixel is decided conservatively from its neighbours' road coordinates, so
the marker coverage that the roll estimate depends on is always the 16-ray (or finer) one.

Then optics and sensor: Gaussian blur, shot and read noise, 8-bit quantisation; the video
writer adds the codec's loss.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from vision.camera import Camera

from .road import intersect_ray

__all__ = ["Look", "Markings", "Renderer"]


@dataclass(frozen=True)
class Markings:
    """Painted lines at lateral offsets ``+lane_width`` (left edge), 0 (centre, dashed) and
    ``-lane_width`` (right edge) from the reference line; widths per line, m."""

    lane_width_m: float = 3.5
    widths_m: tuple[float, float, float] = (0.15, 0.15, 0.15)
    center_line: bool = True
    dash_m: float = 6.0
    gap_m: float = 12.0
    dash_phase_m: float = 0.0
    shoulder_m: float = 0.5


@dataclass(frozen=True)
class Look:
    """Appearance: linear intensities in [0, 1] (BGR) and sensor parameters."""

    asphalt: tuple[float, float, float] = (0.30, 0.30, 0.31)
    paint: tuple[float, float, float] = (0.86, 0.88, 0.88)
    verge: tuple[float, float, float] = (0.16, 0.33, 0.24)
    sky: tuple[float, float, float] = (0.92, 0.80, 0.62)
    texture_fine: float = 0.05      # relative amplitude of the 8 cm asphalt grain
    texture_coarse: float = 0.08    # relative amplitude of the 2 m patches
    blur_sigma_px: float = 0.6
    read_noise_dn: float = 1.5
    shot_noise_gain: float = 0.08   # variance in DN^2 per DN of signal
    max_distance_m: float = 400.0


@nb.njit(cache=True, inline="always")
def _hash(ix, iy, seed):
    h = (ix * 374761393 + iy * 668265263 + seed * 2147483647) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    h = h ^ (h >> 16)
    return (h & 0xFFFFFF) / 16777216.0


@nb.njit(cache=True, inline="always")
def _value_noise(x, y, seed):
    """Smooth value noise in [-1, 1] on the unit lattice."""
    fx, fy = math.floor(x), math.floor(y)
    ix, iy = np.int64(fx), np.int64(fy)
    tx, ty = x - fx, y - fy
    tx = tx * tx * (3.0 - 2.0 * tx)
    ty = ty * ty * (3.0 - 2.0 * ty)
    a = _hash(ix, iy, seed)
    b = _hash(ix + 1, iy, seed)
    c = _hash(ix, iy + 1, seed)
    d = _hash(ix + 1, iy + 1, seed)
    return 2.0 * ((a + (b - a) * tx) * (1.0 - ty) + (c + (d - c) * tx) * ty) - 1.0


@nb.njit(cache=True, inline="always")
def _texture(s, d, footprint_m, amp_fine, amp_coarse, seed):
    """Multiplicative texture; octaves finer than the footprint fade out (band limit)."""
    t = 1.0
    w = 1.0 - footprint_m / 0.08
    if w > 0.0:
        t += amp_fine * w * _value_noise(s / 0.08, d / 0.08, seed)
    w = 1.0 - footprint_m / 0.5
    if w > 0.0:
        t += 0.5 * amp_fine * w * _value_noise(s / 0.5, d / 0.5, seed + 7)
    t += amp_coarse * _value_noise(s / 2.0, d / 2.0, seed + 13)
    return t


@nb.njit(cache=True, inline="always")
def _in_marking(s, d, mk):
    """1 if (s, d) is painted. ``mk``: lane_w, w_left, w_center, w_right, center, dash, gap, phase."""
    lane = mk[0]
    if abs(d - lane) <= 0.5 * mk[1] or abs(d + lane) <= 0.5 * mk[3]:
        return True
    if mk[4] > 0.5 and abs(d) <= 0.5 * mk[2]:
        period = mk[5] + mk[6]
        x = (s - mk[7]) - period * math.floor((s - mk[7]) / period)
        return x < mk[5]
    return False


@nb.njit(cache=True, inline="always")
def _needs_supersampling(s, d, rs, rd, mk, verge_d):
    """True if a marking edge, a dash end or the verge edge lies within ``s +- rs, d +- rd``."""
    lane = mk[0]
    edges = (lane - 0.5 * mk[1], lane + 0.5 * mk[1], -lane - 0.5 * mk[3], -lane + 0.5 * mk[3],
             verge_d, -verge_d)
    for e in edges:
        if abs(d - e) <= rd:
            return True
    if mk[4] > 0.5 and abs(d) - rd <= 0.5 * mk[2]:
        if abs(abs(d) - 0.5 * mk[2]) <= rd:
            return True
        period = mk[5] + mk[6]
        x = (s - mk[7]) - period * math.floor((s - mk[7]) / period)
        # distance from x to the nearest dash boundary (0, dash, period)
        if x <= rs or abs(x - mk[5]) <= rs or period - x <= rs:
            return True
    return False


@nb.njit(cache=True, inline="always")
def _shade(s, d, footprint, mk, verge_d, look, seed, out):
    """Add the colour of road point (s, d) to out[0:3]."""
    if abs(d) > verge_d:
        t = _texture(s, d, footprint, 2.0 * look[9], 1.5 * look[10], seed + 101)
        for c in range(3):
            out[c] += look[6 + c] * t
    elif _in_marking(s, d, mk):
        t = _texture(s, d, footprint, 0.5 * look[9], 0.3 * look[10], seed + 57)
        for c in range(3):
            out[c] += look[3 + c] * t
    else:
        t = _texture(s, d, footprint, look[9], look[10], seed)
        for c in range(3):
            out[c] += look[c] * t


@nb.njit(cache=True, inline="always")
def _ray(u, v, cam, nmap, use_map, i, j, du, dv):
    """Ray in cp through pixel (u, v) = (j + du, i + dv); nmap holds per-pixel undistorted
    normalized coordinates and their Jacobian (xn, yn, dxn/du, dxn/dv, dyn/du, dyn/dv)."""
    if use_map:
        xn = nmap[0, i, j] + nmap[2, i, j] * du + nmap[3, i, j] * dv
        yn = nmap[1, i, j] + nmap[4, i, j] * du + nmap[5, i, j] * dv
    else:
        xn = (u - cam[2]) / cam[0]
        yn = (v - cam[3]) / cam[1]
    return xn, yn


@nb.njit(cache=True, parallel=True)
def _render(tab, cam, nmap, use_map, R, o, seed_sd, plane, mk, verge_d, look, n_sub, tex_seed,
            S_out, D_out, L_out, OK_out, img):
    H, W = img.shape[0], img.shape[1]
    # Pass 1: one ray per pixel centre.
    for i in nb.prange(H):
        s_prev, d_prev, l_prev, have = 0.0, 0.0, 0.0, False
        for j in range(W):
            xn, yn = _ray(float(j), float(i), cam, nmap, use_map, i, j, 0.0, 0.0)
            rx = R[0, 0] * xn + R[0, 1] * yn + R[0, 2]
            ry = R[1, 0] * xn + R[1, 1] * yn + R[1, 2]
            rz = R[2, 0] * xn + R[2, 1] * yn + R[2, 2]
            ok = False
            s, d, lam = 0.0, 0.0, 0.0
            if have:
                s, d, lam, ok = intersect_ray(tab, o[0], o[1], o[2], rx, ry, rz, s_prev, d_prev, l_prev)
            if not ok:
                # Seed from the local road plane at the vehicle: plane = (P, x_o, y_o, z_o).
                den = rx * plane[9] + ry * plane[10] + rz * plane[11]
                if den < -1e-9:
                    lam0 = ((plane[0] - o[0]) * plane[9] + (plane[1] - o[1]) * plane[10]
                            + (plane[2] - o[2]) * plane[11]) / den
                    qx, qy, qz = o[0] + lam0 * rx - plane[0], o[1] + lam0 * ry - plane[1], o[2] + lam0 * rz - plane[2]
                    s0 = seed_sd[0] + qx * plane[3] + qy * plane[4] + qz * plane[5]
                    d0 = seed_sd[1] + qx * plane[6] + qy * plane[7] + qz * plane[8]
                    s, d, lam, ok = intersect_ray(tab, o[0], o[1], o[2], rx, ry, rz, s0, d0, lam0)
            if ok:
                nr = math.sqrt(rx * rx + ry * ry + rz * rz)
                ok = lam * nr < look[15] and abs(d) < 80.0
            S_out[i, j], D_out[i, j], L_out[i, j], OK_out[i, j] = s, d, lam, ok
            if ok:
                s_prev, d_prev, l_prev, have = s, d, lam, True
            else:
                have = False
    # Pass 2: shade, with n x n sub-pixel rays where an edge may cross the pixel.
    inv = 1.0 / n_sub
    for i in nb.prange(H):
        acc = np.zeros(3)
        for j in range(W):
            acc[:] = 0.0
            if not OK_out[i, j]:
                # Sky, or ground beyond max_distance: sky above the horizon, far ground below.
                xn, yn = _ray(float(j), float(i), cam, nmap, use_map, i, j, 0.0, 0.0)
                rz = R[2, 0] * xn + R[2, 1] * yn + R[2, 2]
                nr = math.sqrt(xn * xn + yn * yn + 1.0)
                if rz / nr > -0.002:
                    h = min(1.0, max(0.0, rz / nr * 3.0))
                    for c in range(3):
                        img[i, j, c] = look[12 + c] * (0.85 + 0.15 * h)
                else:
                    for c in range(3):
                        img[i, j, c] = 0.5 * (look[c] + look[6 + c])
                continue
            s, d = S_out[i, j], D_out[i, j]
            # Conservative half-extent of the pixel in road coordinates, from the neighbours.
            rs, rd = 0.0, 0.0
            complete = True
            for di, dj in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                ii, jj = i + di, j + dj
                if ii < 0 or ii >= H or jj < 0 or jj >= W:
                    continue
                if not OK_out[ii, jj]:
                    complete = False
                    continue
                rs = max(rs, abs(S_out[ii, jj] - s))
                rd = max(rd, abs(D_out[ii, jj] - d))
            rs, rd = 1.5 * rs + 1e-4, 1.5 * rd + 1e-4
            footprint = min(rs, rd * 8.0)
            if complete and not _needs_supersampling(s, d, rs, rd, mk, verge_d):
                _shade(s, d, footprint, mk, verge_d, look, tex_seed, acc)
                for c in range(3):
                    img[i, j, c] = acc[c]
                continue
            count = 0
            for a in range(n_sub):
                dv = (a + 0.5) * inv - 0.5
                for b in range(n_sub):
                    du = (b + 0.5) * inv - 0.5
                    xn, yn = _ray(j + du, i + dv, cam, nmap, use_map, i, j, du, dv)
                    rx = R[0, 0] * xn + R[0, 1] * yn + R[0, 2]
                    ry = R[1, 0] * xn + R[1, 1] * yn + R[1, 2]
                    rz = R[2, 0] * xn + R[2, 1] * yn + R[2, 2]
                    ss, dd, ll, ok = intersect_ray(tab, o[0], o[1], o[2], rx, ry, rz, s, d, L_out[i, j])
                    if ok:
                        _shade(ss, dd, footprint * inv, mk, verge_d, look, tex_seed, acc)
                    else:
                        for c in range(3):
                            acc[c] += 0.5 * (look[c] + look[6 + c])
                    count += 1
            for c in range(3):
                img[i, j, c] = acc[c] / count


class Renderer:
    """Renders frames of one camera on one road.

    Parameters
    ----------
    road : drivesim.road.Road
    camera : vision.Camera
    markings : Markings
    look : Look
    supersample : int
        Sub-pixel grid per axis where edges cross (>= 4).
    """

    def __init__(self, road, camera: Camera, markings: Markings, look: Look = Look(),
                 supersample: int = 4, texture_seed: int = 1) -> None:
        if supersample < 1:
            raise ValueError("supersample must be >= 1")
        self.road, self.camera, self.markings, self.look = road, camera, markings, look
        self.n_sub = int(supersample)
        self.texture_seed = int(texture_seed)
        H, W = camera.height, camera.width
        self._cam = np.array([camera.fx, camera.fy, camera.cx, camera.cy])
        self._use_map = camera.has_distortion
        if self._use_map:
            jj, ii = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
            e = 0.25
            c = camera.normalized(np.stack([jj, ii], -1))
            du = (camera.normalized(np.stack([jj + e, ii], -1)) - camera.normalized(np.stack([jj - e, ii], -1))) / (2 * e)
            dv = (camera.normalized(np.stack([jj, ii + e], -1)) - camera.normalized(np.stack([jj, ii - e], -1))) / (2 * e)
            self._nmap = np.ascontiguousarray(np.stack([c[..., 0], c[..., 1], du[..., 0], dv[..., 0], du[..., 1], dv[..., 1]]))
        else:
            self._nmap = np.zeros((6, 1, 1))
        m = markings
        self._mk = np.array([m.lane_width_m, m.widths_m[0], m.widths_m[1], m.widths_m[2],
                             1.0 if m.center_line else 0.0, m.dash_m, m.gap_m, m.dash_phase_m])
        self._verge_d = m.lane_width_m + 0.5 * max(m.widths_m[0], m.widths_m[2]) + m.shoulder_m
        lk = look
        # Layout read by the kernel: asphalt 0-2, paint 3-5, verge 6-8, fine 9, coarse 10,
        # sky 12-14, max distance 15.
        self._look = np.array([*lk.asphalt, *lk.paint, *lk.verge, lk.texture_fine, lk.texture_coarse,
                               0.0, *lk.sky, lk.max_distance_m])
        self._buf = None

    def radiance(self, R_w_from_cp, o_w, s_vehicle, d_vehicle, R_w_from_o_vehicle, P_vehicle):
        """Linear BGR image ``(H, W, 3)`` float in [0, ~1] of the camera at pose
        (``R_w_from_cp``, optical centre ``o_w``), seeded by the vehicle's road position."""
        H, W = self.camera.height, self.camera.width
        if self._buf is None:
            self._buf = (np.empty((H, W)), np.empty((H, W)), np.empty((H, W)),
                         np.empty((H, W), dtype=np.bool_))
        S_, D_, L_, OK_ = self._buf
        img = np.empty((H, W, 3))
        Ro = np.asarray(R_w_from_o_vehicle)
        plane = np.concatenate([np.asarray(P_vehicle, float), Ro[:, 0], Ro[:, 1], Ro[:, 2]])
        _render(self.road.table, self._cam, self._nmap, self._use_map,
                np.ascontiguousarray(R_w_from_cp, dtype=float), np.asarray(o_w, dtype=float),
                np.array([s_vehicle, d_vehicle], dtype=float), plane, self._mk, self._verge_d,
                self._look, self.n_sub, self.texture_seed, S_, D_, L_, OK_, img)
        return img

    def sensor(self, radiance, rng: np.random.Generator):
        """Blur, noise and quantisation: uint8 BGR image."""
        import cv2

        img = radiance * 255.0
        if self.look.blur_sigma_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), self.look.blur_sigma_px)
        var = self.look.read_noise_dn**2 + self.look.shot_noise_gain * np.maximum(img, 0.0)
        img = img + rng.standard_normal(img.shape) * np.sqrt(var)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)
