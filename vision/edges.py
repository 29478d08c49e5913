"""Sub-pixel marker edges measured in the camera image (beyond the paper).

The BEV finds and tracks the markers (:mod:`vision.lanes`); its resampling, though, limits the
edges to about a tenth of a BEV pixel, a floor constant in metres that near the camera is
several image pixels wide. Here every image row (or column) that crosses a tracked marker is
cut once, at full resolution and without resampling:

* the cut runs along the image axis closer to perpendicular to the marker (rows for markers
  steeper than 45 deg in the image, else columns);
* ``"area"`` (default): the marker's profile above a linear road level (from bands beyond the
  half-level crossings) has an area and a centroid: the edges are ``centroid -+ area / (2 C)``
  with ``C`` a paint contrast common to all markers of the frame. Blur keeps the area, so a
  marker narrower than the blur (far, or seen at a grazing angle) keeps its width; the
  centroid is unbiased for a symmetric blur;
* ``"subpixel"``: the half-level crossings themselves.

Along a cut, the edges of a straight marker are the exact image points where the cut meets the
marker's edges, so each point is projected to the road like any pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from .camera import Camera
from .ipm import Bev
from .lanes import Marker

__all__ = ["ImageEdges", "measure_in_image"]


@dataclass
class ImageEdges:
    """Edge points of one marker in the image: ``left`` / ``right`` are ``(n, 2)`` pixels
    ``(u, v)`` of the edges at the larger / smaller road ``Y``; ``contrast`` per cut."""

    left: np.ndarray
    right: np.ndarray
    contrast: np.ndarray
    axis: int           # 0: cuts along image rows, 1: along columns


@nb.njit(cache=True)
def _road_levels(img, v, l0, l1, r0, r1):  # pragma: no cover (numba)
    """Mean grey of row ``v`` over the bands ``[l0, l1)`` and ``(r0, r1]`` beside a marker."""
    bl = 0.0
    for j in range(l0, l1):
        bl += img[v, j]
    br = 0.0
    for j in range(r0 + 1, r1 + 1):
        br += img[v, j]
    return bl / (l1 - l0), br / (r1 - r0)


@nb.njit(cache=True)
def _cut(img, lines, centers, wpx, mode):  # pragma: no cover (numba)
    """Measure one marker on each cut ``lines[r]`` (a row of ``img``) near ``centers[r]``.

    ``wpx[r]``: expected marker width along the cut, px. ``mode`` 1: half-level crossings,
    2: area and centroid. Returns ``a, b, contrast`` (columns of the two crossings or edges).
    """
    n = lines.shape[0]
    W = img.shape[1]
    a_out = np.full(n, np.nan)
    b_out = np.full(n, np.nan)
    con = np.full(n, np.nan)
    for r in range(n):
        v = lines[r]
        w = wpx[r]
        c = centers[r]
        if not (w > 0.5) or v < 0 or v >= img.shape[0]:
            continue
        s = int(0.6 * w + 3.0)
        ci = int(round(c))
        lo = ci - s
        hi = ci + s
        if lo < 1 or hi > W - 2:
            continue
        pk = lo
        for j in range(lo, hi + 1):
            if img[v, j] > img[v, pk]:
                pk = j
        paint = float(img[v, pk])
        # road level: bands 1.2 to 2 widths from the peak on each side
        m = max(2, int(0.8 * w + 0.5))
        off = int(1.2 * w + 2.0)
        l1 = pk - off
        l0 = l1 - m
        r0 = pk + off
        r1 = r0 + m
        if l0 < 0 or r1 > W - 1:
            continue
        bl, br = _road_levels(img, v, l0, l1, r0, r1)
        ok = True
        a = 0.0
        b = 0.0
        mm = max(2, int(0.8 * w + 0.5))
        for _ in range(2):
            hl = 0.5 * (bl + paint)
            hr = 0.5 * (br + paint)
            jl = pk
            while jl > 0 and img[v, jl] >= hl:
                jl -= 1
            jr = pk
            while jr < W - 1 and img[v, jr] >= hr:
                jr += 1
            p0 = float(img[v, jl])
            p1 = float(img[v, jl + 1])
            q0 = float(img[v, jr - 1])
            q1 = float(img[v, jr])
            if not (p1 > p0 and q0 > q1 and jl > 0 and jr < W - 1):
                ok = False
                break
            a = jl + (hl - p0) / (p1 - p0)
            b = (jr - 1) + (q0 - hr) / (q0 - q1)
            # road level again, from bands beyond the crossings
            gap = max(1, int(0.5 * (b - a) + 1.0))
            l1 = int(np.floor(a)) - gap
            l0 = l1 - mm
            r0 = int(np.ceil(b)) + gap
            r1 = r0 + mm
            if l0 < 0 or r1 > W - 1:
                ok = False
                break
            bl, br = _road_levels(img, v, l0, l1, r0, r1)
        if not ok or not b > a:
            continue
        con[r] = paint - 0.5 * (bl + br)
        if mode == 1:
            a_out[r] = a
            b_out[r] = b
            continue
        # area and centroid above the line through the two road levels
        fw = b - a
        c0 = 0.5 * (a + b)
        hw = 0.5 * fw + max(fw, 1.0)
        i0 = int(np.ceil(c0 - hw))
        i1 = int(np.floor(c0 + hw))
        l0 = i0 - mm
        r1 = i1 + mm
        if l0 < 0 or r1 > W - 1 or i1 <= i0:
            continue
        sl = 0.0
        for j in range(l0, i0):
            sl += img[v, j]
        sl /= (i0 - l0)
        sr = 0.0
        for j in range(i1 + 1, r1 + 1):
            sr += img[v, j]
        sr /= (r1 - i1)
        uL = 0.5 * (l0 + i0 - 1)
        uR = 0.5 * (i1 + 1 + r1)
        beta = (sr - sl) / (uR - uL)
        alpha = sl - beta * uL
        A = 0.0
        M1 = 0.0
        for j in range(i0, i1 + 1):
            q = img[v, j] - alpha - beta * j
            A += q
            M1 += q * j
        if not A > 0:
            continue
        cen = M1 / A
        a_out[r] = cen - 0.5 * A
        b_out[r] = cen + 0.5 * A
    return a_out, b_out, con


def measure_in_image(gray: np.ndarray, markers: list[Marker], bev: Bev, camera: Camera, mode: str = "area",
                     gray_t: np.ndarray | None = None) -> list[ImageEdges | None]:
    """Edge points of each marker cut in the image (see the module docstring).

    Parameters
    ----------
    gray : (H, W) uint8 array
        The camera's grey picture (distorted, as captured).
    markers : list of Marker
        Markers tracked in ``bev``.
    bev : Bev
        The BEV they were found in (its homography maps them into the image).
    camera : Camera
    mode : {"area", "subpixel"}
    gray_t : array, optional
        ``gray.T`` as a contiguous array (made when a marker needs column cuts).

    Returns
    -------
    list
        One :class:`ImageEdges` per marker (None when fewer than 3 cuts succeeded), with the
        area widths scaled by one paint contrast common to the frame.
    """
    m_code = {"subpixel": 1, "area": 2}[mode]
    raw = []
    for mk in markers:
        k = mk.inliers
        uc = 0.5 * (mk.u_left[k] + mk.u_right[k])
        v = mk.v[k]
        # Tracked centre and edges in the image (undistorted pixels -> captured pixels).
        pts = np.stack([uc, v, np.ones_like(v)], -1) @ bev.image_from_bev.T
        pl = np.stack([mk.u_left[k], v, np.ones_like(v)], -1) @ bev.image_from_bev.T
        pr = np.stack([mk.u_right[k], v, np.ones_like(v)], -1) @ bev.image_from_bev.T
        c_img = pts[:, :2] / pts[:, 2:3]
        l_img = pl[:, :2] / pl[:, 2:3]
        r_img = pr[:, :2] / pr[:, 2:3]
        if camera.has_distortion:
            c_img, l_img, r_img = (_distort(camera, q) for q in (c_img, l_img, r_img))
        ok = np.all(np.isfinite(c_img), axis=1) & (pts[:, 2] > 0)
        c_img, l_img, r_img = c_img[ok], l_img[ok], r_img[ok]
        if c_img.shape[0] < 3:
            raw.append(None)
            continue
        du = np.ptp(c_img[:, 0])
        dv = np.ptp(c_img[:, 1])
        axis = 0 if dv >= du else 1          # rows cut steep markers, columns flat ones
        along, across = (1, 0) if axis == 0 else (0, 1)
        order = np.argsort(c_img[:, along])
        s_along = c_img[order, along]
        s_across = c_img[order, across]
        v_bev = v[ok][order]
        ol = np.argsort(l_img[:, along])
        orr = np.argsort(r_img[:, along])
        lim = gray.shape[0] if axis == 0 else gray.shape[1]
        lines = np.arange(max(0, int(np.ceil(s_along[0]))), min(lim - 1, int(np.floor(s_along[-1]))) + 1)
        if lines.size < 3:
            raw.append(None)
            continue
        # Only cuts between neighbouring tracked BEV rows (not through the gaps of a dashed line).
        g = np.clip(np.searchsorted(s_along, lines), 1, s_along.size - 1)
        inside = np.abs(v_bev[g] - v_bev[g - 1]) <= 2.5
        lines = lines[inside]
        centers = np.interp(lines, s_along, s_across)
        # Width along the cut: where the cut meets each tracked edge.
        wpx = np.abs(np.interp(lines, l_img[ol, along], l_img[ol, across])
                     - np.interp(lines, r_img[orr, along], r_img[orr, across]))
        if axis == 0:
            img = gray
        else:
            if gray_t is None:
                gray_t = np.ascontiguousarray(gray.T)
            img = gray_t
        a, b, con = _cut(img, lines.astype(np.int64), centers.astype(np.float64), wpx.astype(np.float64), m_code)
        good = np.isfinite(a) & np.isfinite(b)
        if good.sum() < 3:
            raw.append(None)
            continue
        cm = float(np.median(con[good]))
        good &= con > 0.5 * cm
        raw.append((axis, lines[good], a[good], b[good], con[good], wpx[good]))
    if mode == "area":
        cs = [float(np.median(r[4])) for r in raw if r is not None and r[4].size]
        c_all = max(cs) if cs else 1.0
    out: list[ImageEdges | None] = []
    for r in raw:
        if r is None:
            out.append(None)
            continue
        axis, lines, a, b, con, wpx = r
        if mode == "area":
            cen, half = 0.5 * (a + b), 0.5 * (b - a) / max(c_all, 1e-6)
            a, b = cen - half, cen + half
        w = b - a
        keep = (w > 0.4 * wpx) & (w < 2.5 * wpx + 2.0)
        if keep.sum() < 3:
            out.append(None)
            continue
        lines, a, b, con = lines[keep], a[keep], b[keep], con[keep]
        L = lines.astype(float)
        pa = np.stack([a, L], -1) if axis == 0 else np.stack([L, a], -1)
        pb = np.stack([b, L], -1) if axis == 0 else np.stack([L, b], -1)
        # Which of the two is the road's left edge (larger Y): the one the BEV puts left.
        ua = _bev_u(bev, camera, pa[:1])
        ub = _bev_u(bev, camera, pb[:1])
        left, right = (pa, pb) if ua[0] < ub[0] else (pb, pa)
        out.append(ImageEdges(left, right, con, axis))
    return out


def _distort(camera: Camera, uv_undistorted: np.ndarray) -> np.ndarray:
    xn = (uv_undistorted[:, 0] - camera.cx) / camera.fx
    yn = (uv_undistorted[:, 1] - camera.cy) / camera.fy
    xd, yd = camera.distort_normalized(xn, yn)
    return np.stack([camera.fx * xd + camera.cx, camera.fy * yd + camera.cy], -1)


def _bev_u(bev: Bev, camera: Camera, uv: np.ndarray) -> np.ndarray:
    rays = np.concatenate([camera.normalized(uv), np.ones((uv.shape[0], 1))], -1)
    u, _ = bev.bev_of_rays(rays)
    return u
