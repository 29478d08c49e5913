"""Lane markers in the bird's-eye view: filter, threshold, blobs, sliding windows, edges.

Steps (Damon et al. 2018, section III.B, after their ref. [13]; Alrazouk et al. 2024, IV.E):

1. marker-width filter: a dark-bright-dark response tuned to the marker width ``w``,
   ``r(u) = box_w(u) - max(box_w(u - w), box_w(u + w))`` along BEV rows (both sides must be
   darker, so a single step such as the verge gives no response);
2. threshold and small-blob removal (connected components shorter than ``min_blob_m``
   along the road);
3. line starts from the column histogram of the binary image, then sliding windows from the
   near end upwards, each recentred on its pixels and, across gaps of dashed lines,
   carried along the line's current direction;
4. both edges of each marker on every BEV row the marker covers:

   * ``"binary"`` (the paper's method): the first and last thresholded pixel of the marker's
     run, ``+-0.5`` px; the sub-pixel position comes only from the polynomial fit;
   * ``"subpixel"``: the half-level crossing of the intensity profile between the local
     road level on that side and the marker's paint level, linearly interpolated
     (unbiased for a symmetric blur narrower than the marker);
   * ``"area"``: the centroid of the marker's profile above the local road level, and its
     area divided by a paint contrast common to all markers, as the width: blur keeps the area
     even when it is wider than the marker (far away, or far to the side, where the range
     blur of the image pixel projects across the marker);

5. polynomial fits ``u = p(v)`` of each edge (degree 2 in the paper), with one pass of
   outlier rejection at 3 robust sigma.

Coordinates are BEV pixels (:mod:`vision.ipm`): ``u`` columns (left of the road to the
right), ``v`` rows (far to near). A marker's *left* edge is the one at the larger road ``Y``
(smaller ``u``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numba as nb
import numpy as np

__all__ = ["Marker", "LaneOptions", "detect_markers", "marker_response"]


@dataclass(frozen=True)
class LaneOptions:
    """Detection settings (BEV metric units, converted to pixels per grid).

    Parameters
    ----------
    edges : {"area", "subpixel", "binary"}
        How edges are located on each row (see the module docstring).
    fit_degree : int
        Degree of the edge polynomials ``u = p(v)``; 2 in Alrazouk et al. 2024, 3 in Damon et al. 2018.
    min_contrast : float
        Minimum filter response (grey levels) of a marker pixel.
    rel_threshold : float
        Threshold as a fraction of the strong responses (99.5th percentile) in the frame.
    min_blob_m : float
        Blobs shorter than this along the road are removed, m.
    window_m : float
        Half-width of a sliding window, m.
    n_windows : int
        Sliding windows from the near end to the far end.
    min_line_m : float
        A line needs marker pixels over at least this length of road, m.
    min_line_gap_m : float
        Two lines are at least this far apart laterally, m.
    """

    edges: str = "area"
    fit_degree: int = 2
    min_contrast: float = 12.0
    rel_threshold: float = 0.35
    min_blob_m: float = 0.8
    window_m: float = 0.45
    n_windows: int = 14
    min_line_m: float = 2.5
    min_line_gap_m: float = 1.2


@dataclass
class Marker:
    """One painted line found in the BEV, with both edges on the rows it covers.

    ``v`` are BEV rows; ``u_left`` / ``u_right`` the sub-pixel columns of the edges at the larger
    and smaller road ``Y``; ``fit_left`` / ``fit_right`` polynomial coefficients of ``u`` in
    ``(v - v0) / 100`` (highest power first, ``numpy.polyval``; use :meth:`u_at`),
    ``rms_left`` / ``rms_right`` their residuals, px.
    ``inliers`` marks the rows kept by the fits.
    """

    v: np.ndarray
    u_left: np.ndarray
    u_right: np.ndarray
    contrast: float
    fit_left: np.ndarray = field(default=None)  # type: ignore[assignment]
    fit_right: np.ndarray = field(default=None)  # type: ignore[assignment]
    rms_left: float = np.nan
    rms_right: float = np.nan
    inliers: np.ndarray = field(default=None)  # type: ignore[assignment]
    v0: float = 0.0    # the fits are polynomials of (v - v0) / 100

    @property
    def u_center(self) -> np.ndarray:
        return 0.5 * (self.u_left + self.u_right)

    @property
    def v_near(self) -> float:
        """Nearest row covered (largest ``v``)."""
        return float(self.v[self.inliers].max())

    @property
    def v_far(self) -> float:
        return float(self.v[self.inliers].min())

    def u_at(self, v) -> tuple[np.ndarray, np.ndarray]:
        """Fitted edge columns at rows ``v``."""
        x = (np.atleast_1d(np.asarray(v, float)) - self.v0) * 0.01
        return _polyval2(self.fit_left, self.fit_right, x)


@nb.njit(cache=True)
def _polyval2(cl, cr, x):  # pragma: no cover (numba)
    """Two polynomials (highest power first) at ``x``, Horner (numpy.polyval's overhead is
    most of the cost for a few rows)."""
    ul, ur = np.empty(x.size), np.empty(x.size)
    for i in range(x.size):
        a, b = 0.0, 0.0
        for c in cl:
            a = a * x[i] + c
        for c in cr:
            b = b * x[i] + c
        ul[i], ur[i] = a, b
    return ul, ur


def marker_response(bev: np.ndarray, width_px: int) -> np.ndarray:
    """Dark-bright-dark response ``box(u) - max(box(u - w), box(u + w))`` along rows, in grey
    levels x ``w`` (box sums, int16; 0 where the neighbours fall outside the row).

    ``box`` sums ``w`` pixels centred on ``u``: a bright stripe ``w`` wide on a darker road
    answers with ``w`` times its contrast, a single step (the verge) with nothing.
    """
    w = max(1, int(width_px))
    b = cv2.boxFilter(bev, cv2.CV_16S, (w, 1), normalize=False, borderType=cv2.BORDER_REPLICATE)
    return _stripe_response(b, w)


@nb.njit(cache=True)
def _stripe_response(b, w):  # pragma: no cover (numba)
    """``b(u) - max(b(u - w), b(u + w))`` for ``w <= u < W - w``, 0 elsewhere (int16; a loop over
    1-D row views, which numba vectorises: 4x numpy's three passes)."""
    H, W = b.shape
    r = np.zeros((H, W), np.int16)
    n = W - 2 * w
    for v in range(H):
        left, centre, right, out = b[v, 0:n], b[v, w:w + n], b[v, 2 * w:2 * w + n], r[v, w:w + n]
        for k in range(n):
            out[k] = centre[k] - max(left[k], right[k])
    return r


@nb.njit(cache=True)
def _binarize(resp, thr, lo, hi, margin):  # pragma: no cover (numba)
    """``resp > thr`` on the part of each row at least ``margin`` px inside the image's footprint
    (the black fill outside makes false edges)."""
    H, W = resp.shape
    out = np.zeros((H, W), np.uint8)
    # The response is an integer: resp > thr is resp > floor(thr), an integer compare (SIMD).
    t = np.int16(min(max(math.floor(thr), -32768), 32767))
    for v in range(H):
        a = max(0, int(np.ceil(lo[v] + margin)))
        b = min(W - 1, int(np.floor(hi[v] - margin)))
        for k in range(b + 1 - a):     # (a loop from 0 that numba vectorises)
            out[v, a + k] = resp[v, a + k] > t
    return out


def _threshold(resp: np.ndarray, width: int, lo, hi, margin: float, opts: LaneOptions) -> float:
    """Threshold (response units) from every fourth row and column inside the image's footprint:
    ``rel_threshold`` of the strong responses (99.5th percentile), at least ``min_contrast``."""
    sample = _threshold_sample(resp, lo, hi, margin)
    k = max(0, int(0.995 * sample.size) - 1)
    high = float(np.partition(sample, k)[k]) if sample.size else 0.0
    return max(opts.min_contrast * width, opts.rel_threshold * high)


@nb.njit(cache=True)
def _threshold_sample(resp, lo, hi, margin):  # pragma: no cover (numba)
    """The responses of every fourth row and column inside the image's footprint."""
    H, W = resp.shape
    out = np.empty(((H + 3) // 4) * ((W + 3) // 4), resp.dtype)
    n = 0
    for v in range(0, H, 4):
        for u in range(0, W, 4):
            if lo[v] + margin <= u <= hi[v] - margin:
                out[n] = resp[v, u]
                n += 1
    return out[:n]


def _remove_small_blobs(binary: np.ndarray, min_rows: int) -> np.ndarray:
    """Keep only pixels on vertical runs of at least ``min_rows`` rows (an opening with a
    vertical line): removes blobs shorter than that along the road, keeps lines and dashes."""
    if min_rows <= 1:
        return binary
    kernel = np.ones((int(min_rows), 1), np.uint8)
    return cv2.morphologyEx(binary, cv2.MORPH_OPEN, kernel)


def _line_starts(binary: np.ndarray, min_count: int, min_gap_px: int) -> list[int]:
    """Columns of the histogram peaks (binary pixels per column, lightly smoothed), strongest
    first, at least ``min_gap_px`` apart, returned left to right."""
    hist = _column_counts(binary)
    k = max(3, min_gap_px // 4) | 1
    hist = cv2.blur(hist.reshape(1, -1), (k, 1)).ravel()
    cand = np.flatnonzero(hist >= min_count)
    if cand.size == 0:
        return []
    return sorted(int(c) for c in _greedy_peaks(cand[np.argsort(hist[cand])[::-1]][:400], min_gap_px))


@nb.njit(cache=True)
def _column_counts(binary):  # pragma: no cover (numba)
    """Pixels set per column, float32: ``cv2.reduce(binary, 0, REDUCE_SUM, CV_32F)`` (integer
    sums, exact either way), in a third of its time."""
    H, W = binary.shape
    acc = np.zeros(W, np.int32)
    for v in range(H):
        row = binary[v]
        for k in range(W):
            acc[k] += row[k]
    return acc.astype(np.float32)


@nb.njit(cache=True)
def _greedy_peaks(ordered, min_gap):  # pragma: no cover (numba)
    """The columns of ``ordered`` (strongest first) at least ``min_gap`` from every one kept."""
    kept = np.empty(ordered.size, np.int64)
    n = 0
    for c in ordered:
        for i in range(n):
            if abs(c - kept[i]) < min_gap:
                break
        else:
            kept[n] = c
            n += 1
    return kept[:n]


@nb.njit(cache=True)
def _track_nb(binary, c, n_win, hw, min_pix):  # pragma: no cover (numba)
    Hh, W = binary.shape
    win_h = Hh / n_win
    slope = 0.0  # du per dv going up (negative v)
    vs = np.empty(n_win)
    us = np.empty(n_win)
    n = 0
    for k in range(n_win):
        v1 = int(round(Hh - k * win_h))
        v0 = int(round(Hh - (k + 1) * win_h))
        u0 = int(round(c - hw))
        u1 = int(round(c + hw)) + 1
        if u1 <= 0 or u0 >= W:
            break
        u0c = max(u0, 0)
        u1c = min(u1, W)
        tot = 0
        mom = 0
        for v in range(v0, v1):
            for k in range(u1c - u0c):      # integer sums from 0: numba vectorises them
                b = np.int64(binary[v, u0c + k] != 0)
                tot += b
                mom += b * (u0c + k)
        vm = 0.5 * (v0 + v1)
        if tot >= min_pix:
            cnew = mom / tot
            if n > 0:
                dv = vm - vs[n - 1]
                if dv != 0:
                    slope = 0.5 * slope + 0.5 * (cnew - us[n - 1]) / dv
            vs[n] = vm
            us[n] = cnew
            n += 1
            c = cnew + slope * (-win_h)
        else:
            c = c + slope * (-win_h)
    return vs[:n].copy(), us[:n].copy()


@nb.njit(cache=True)
def _centre_rows(cfit, v_lo, v_hi, c_lo, c_hi):  # pragma: no cover (numba)
    """The rows ``v_lo..v_hi`` whose centre ``numpy.polyval(cfit, v)`` (Horner, as numpy
    evaluates it) lies strictly between ``c_lo`` and ``c_hi``, and those centres (one call for
    numpy's arange, polyval and two compares: 15 us a marker)."""
    n = max(0, v_hi + 1 - v_lo)
    rows = np.empty(n, np.int64)
    centers = np.empty(n)
    m = 0
    for v in range(v_lo, v_hi + 1):
        x = float(v)
        c = 0.0
        for p in cfit:
            c = c * x + p
        if c > c_lo and c < c_hi:
            rows[m] = v
            centers[m] = c
            m += 1
    return rows[:m].copy(), centers[:m].copy()


@nb.njit(cache=True)
def _measure_rows(bev, binary, rows, centers, lo, hi, half, wpx, mode):  # pragma: no cover (numba)
    """Both edges of the marker nearest ``centers`` on each BEV row; NaN where not found.

    The marker's run is the set of thresholded pixels containing (or nearest to) the centre.
    ``mode`` 0, binary: its first and last pixel +-0.5. 1, subpixel: on each side, the crossing
    of the level halfway between the road (mean of one marker width beyond the run) and the
    run's peak. 2, area: around those crossings, a window 1.5 half-maximum widths wider on each
    side; the road level is a line through the means of bands beyond it; the marker's area above
    it and its centroid give the edges ``centroid -+ area / 2`` (grey level x px; the caller
    divides by a paint contrast). ``lo, hi`` per BEV row: columns from inside the camera image.
    Returns ``ul, ur, contrast``.
    """
    n = rows.shape[0]
    W = bev.shape[1]
    ul = np.full(n, np.nan)
    ur = np.full(n, np.nan)
    contrast = np.full(n, np.nan)
    m = max(2, int(round(wpx)))
    for r in range(n):
        v = rows[r]
        lo_v = max(0, int(np.ceil(lo[v])))
        hi_v = min(W - 1, int(np.floor(hi[v])))
        ci = int(round(centers[r]))
        # nearest marker pixel to the centre within +-half
        seed = -1
        for d in range(half + 1):
            for j in (ci - d, ci + d):
                if lo_v <= j <= hi_v and binary[v, j]:
                    seed = j
                    break
            if seed >= 0:
                break
        if seed < 0:
            continue
        first = seed
        while first - 1 >= lo_v and binary[v, first - 1] and first - 1 >= ci - half:
            first -= 1
        last = seed
        while last + 1 <= hi_v and binary[v, last + 1] and last + 1 <= ci + half:
            last += 1
        if first - 1 - m < lo_v or last + 1 + m > hi_v:
            continue
        paint = bev[v, first]
        for j in range(first, last + 1):
            if bev[v, j] > paint:
                paint = bev[v, j]
        bg_l = 0.0
        for j in range(first - 1 - m, first - 1):
            bg_l += bev[v, j]
        bg_l /= m
        bg_r = 0.0
        for j in range(last + 2, last + 2 + m):
            bg_r += bev[v, j]
        bg_r /= m
        contrast[r] = paint - 0.5 * (bg_l + bg_r)
        if mode == 0:
            ul[r] = first - 0.5
            ur[r] = last + 0.5
            continue
        half_l = 0.5 * (bg_l + paint)
        half_r = 0.5 * (bg_r + paint)
        jl = first
        while jl >= lo_v and bev[v, jl] >= half_l:
            jl -= 1
        jr = last
        while jr <= hi_v and bev[v, jr] >= half_r:
            jr += 1
        if jl < lo_v or jr > hi_v:
            continue
        p0, p1 = bev[v, jl], bev[v, jl + 1]
        q0, q1 = bev[v, jr - 1], bev[v, jr]
        if not (p1 > p0 and q0 > q1):
            continue
        a = jl + (half_l - p0) / (p1 - p0)
        b = (jr - 1) + (q0 - half_r) / (q0 - q1)
        if not b > a:
            continue
        if mode == 1:
            ul[r] = a
            ur[r] = b
            continue
        # mode 2: centroid and area above a linear road level
        fwhm = b - a
        if fwhm >= 2.5 * wpx + 2.0:
            continue
        c0 = 0.5 * (a + b)
        hw = 0.5 * fwhm + max(fwhm, wpx)
        mm = max(3.0, wpx)
        i0 = int(np.ceil(c0 - hw))
        i1 = int(np.floor(c0 + hw))
        l0 = int(np.floor(c0 - hw - mm))
        r1 = int(np.ceil(c0 + hw + mm))
        if l0 < lo_v or r1 > hi_v or i1 <= i0 or i0 <= l0 or r1 <= i1:
            continue
        sl = 0.0
        for j in range(l0, i0):
            sl += bev[v, j]
        sl /= (i0 - l0)
        sr = 0.0
        for j in range(i1 + 1, r1 + 1):
            sr += bev[v, j]
        sr /= (r1 - i1)
        uL = 0.5 * (l0 + i0 - 1)
        uR = 0.5 * (i1 + 1 + r1)
        beta = (sr - sl) / max(uR - uL, 1.0)
        alpha = sl - beta * uL
        A = 0.0
        M1 = 0.0
        for j in range(i0, i1 + 1):
            q = bev[v, j] - alpha - beta * j
            A += q
            M1 += q * j
        if not A > 0:
            continue
        cen = M1 / A
        ul[r] = cen - 0.5 * A
        ur[r] = cen + 0.5 * A
    return ul, ur, contrast


_MODES = {"binary": 0, "subpixel": 1, "area": 2}


@nb.njit(cache=True)
def _follow_line(bev, binary, start, n_windows, half_window, min_pix, half_win_rows, c_lo, c_hi, lo, hi, half, wpx,
                 mode, min_rows):  # pragma: no cover (numba)
    """One line from its start column: the sliding windows (:func:`_track`), the centre line
    through them (degree 2 from four windows, else 1) on every row they span, ``half_win_rows``
    beyond the end windows, within the columns ``(c_lo, c_hi)``, and both edges on those rows
    (:func:`_measure_rows`). ``(ok, rows, ul, ur, contrast, good)``, ``good`` where both edges
    were found; not ``ok`` with fewer than two windows or ``min_rows`` rows."""
    wv, wu = _track_nb(binary, start, n_windows, half_window, min_pix)
    nothing = (False, np.empty(0, np.int64), np.empty(0), np.empty(0), np.empty(0), np.empty(0, np.bool_))
    if wv.size < 2:
        return nothing
    deg = 1 if wv.size < 4 else 2
    cfit, _ = _polyfit_nb(wv, wu, deg)
    v_lo = max(0, int(wv.min() - half_win_rows))
    v_hi = min(binary.shape[0] - 1, int(wv.max() + half_win_rows))
    rows, centers = _centre_rows(cfit, v_lo, v_hi, c_lo, c_hi)
    if rows.size < min_rows:
        return nothing
    ul, ur, contrast = _measure_rows(bev, binary, rows, centers, lo, hi, half, wpx, mode)
    good = np.isfinite(ul) & np.isfinite(ur)
    if good.sum() < min_rows:
        return nothing
    return True, rows, ul, ur, contrast, good


@nb.njit(cache=True)
def _left_edge_distance(va, ca, va0, vb, cb, vb0):  # pragma: no cover (numba)
    """Median distance between two markers' fitted left edges on the rows both cover (sorted
    ``va``, ``vb``); inf without common rows."""
    d = np.empty(min(va.size, vb.size))
    n, i, j = 0, 0, 0
    while i < va.size and j < vb.size:
        if va[i] < vb[j]:
            i += 1
        elif vb[j] < va[i]:
            j += 1
        else:
            xa, xb = (va[i] - va0) * 0.01, (va[i] - vb0) * 0.01
            ua, ub = 0.0, 0.0
            for c in ca:
                ua = ua * xa + c
            for c in cb:
                ub = ub * xb + c
            d[n] = abs(ua - ub)
            n += 1
            i += 1
            j += 1
    return np.median(d[:n]) if n else np.inf


@nb.njit(cache=True)
def _median_where(a, keep):  # pragma: no cover (numba)
    """:func:`_median` of ``a[keep]`` (``keep`` not empty)."""
    return np.median(a[keep])


@nb.njit(cache=True)
def _area_edges(ul, ur, contrast):  # pragma: no cover (numba)
    """In place, the edges ``centre -+ area / 2`` of the area measurement divided by the paint
    ``contrast`` (numpy's ``0.5 (ul + ur)``, ``0.5 (ur - ul) / contrast`` element by element)."""
    for i in range(ul.size):
        cen = 0.5 * (ul[i] + ur[i])
        hw = 0.5 * (ur[i] - ul[i]) / contrast
        ul[i] = cen - hw
        ur[i] = cen + hw


@nb.njit(cache=True)
def _robust_fit_pair(v, ul, ur, deg, v0):  # pragma: no cover (numba)
    """A marker's left and right edges, each fitted as ``u(v - v0)`` with one pass of rejection at 3
    robust sigma (:func:`_robust_fit_nb`; ``deg`` already capped at ``v.size - 2``), in one call:
    ``(coef, rms, inliers)`` of each, coefficients highest power first, in ``(v - v0) / 100``."""
    fl, rl, kl = _robust_fit_nb(v, ul, deg, v0)
    fr, rr, kr = _robust_fit_nb(v, ur, deg, v0)
    return fl, rl, kl, fr, rr, kr


@nb.njit(cache=True)
def _plausible_rows(ul, ur, contrast, good, wpx, min_rows):  # pragma: no cover (numba)
    """The rows of ``good`` whose marker is 0.4 to 2.5 widths (+2 px) wide and has at least 0.6
    of the median contrast of those: ``(ok, rows kept, median contrast)``, not ``ok`` when fewer
    than ``min_rows`` are left at either step."""
    width = ur - ul
    good = good & (width > 0.4 * wpx) & (width < 2.5 * wpx + 2)
    if good.sum() < min_rows:
        return False, good, np.nan
    c_med = np.median(contrast[good])
    good &= contrast > 0.6 * c_med
    return good.sum() >= min_rows, good, c_med


@nb.njit(cache=True)
def _polyfit_nb(x, y, deg):  # pragma: no cover (numba)
    n = x.shape[0]
    V = np.empty((n, deg + 1))
    for i in range(n):
        p = 1.0
        for k in range(deg, -1, -1):
            V[i, k] = p
            p *= x[i]
    return np.linalg.solve(V.T @ V, V.T @ y), V


@nb.njit(cache=True)
def _robust_fit_nb(v, u, deg, v0):  # pragma: no cover (numba)
    x = (v - v0) * 0.01
    c, V = _polyfit_nb(x, u, deg)
    res = u - V @ c
    s = 1.4826 * np.median(np.abs(res)) + 1e-3
    keep = np.abs(res) < 3.0 * s + 0.05
    nk = keep.sum()
    if nk > deg + 2 and nk < keep.size:
        c, _ = _polyfit_nb(x[keep], u[keep], deg)
        res = u - V @ c
    rms = np.sqrt(np.mean(res[keep] ** 2)) if nk > 0 else np.nan
    return c, rms, keep


def detect_markers(bev: np.ndarray, valid_lo: np.ndarray, valid_hi: np.ndarray, dx_m: float, dy_m: float,
                   marker_width_m: float, opts: LaneOptions = LaneOptions()) -> list[Marker]:
    """Painted lines in a grey BEV, sorted left to right (increasing ``u``).

    Parameters
    ----------
    bev : (h_pix, w_pix) uint8 or float32 array
        Grey BEV.
    valid_lo, valid_hi : (h_pix,) arrays
        Columns of each row that come from inside the camera image (:meth:`Bev.valid_columns`).
    dx_m, dy_m : float
        BEV pixel size forward and lateral, m.
    marker_width_m : float
        Painted line width, m (the filter's scale).
    """
    Hh, W = bev.shape
    wpx = marker_width_m / dy_m
    width = int(round(max(wpx, 1.0)))
    resp = marker_response(bev, width)
    # Responses within 1.5 marker widths of the image's footprint are artefacts of the black fill.
    margin = max(2.0, 1.5 * wpx)
    lo64, hi64 = np.asarray(valid_lo, np.float64), np.asarray(valid_hi, np.float64)
    thr = _threshold(resp, width, lo64, hi64, margin, opts)
    binary = _binarize(resp, thr, lo64, hi64, margin)
    binary = _remove_small_blobs(binary, max(2, int(round(opts.min_blob_m / dx_m))))
    min_rows = max(3, int(round(opts.min_line_m / dx_m)))
    starts = _line_starts(binary, min_rows // 2, max(3, int(round(opts.min_line_gap_m / dy_m))))
    if not starts:
        return []
    half_window = max(3, int(round(opts.window_m / dy_m)))
    min_pix = max(3, int(round(0.3 * (Hh / opts.n_windows) * max(wpx, 1.0) * 0.5)))
    half = max(4, int(round(1.6 * wpx)) + 2)
    found = []
    for s in starts:
        # _track_nb, the centre line through its windows on every row they span, _measure_rows
        # there, in one compiled call (a dozen numpy calls and conversions per line before)
        ok, rows, ul, ur, contrast, good = _follow_line(
            bev, binary, float(s), int(opts.n_windows), half_window, float(min_pix),
            Hh / opts.n_windows / 2, 2 * wpx, W - 1 - 2 * wpx, lo64, hi64, int(half), float(wpx), _MODES[opts.edges],
            min_rows)
        if ok:
            found.append((rows, ul, ur, contrast, good))
    if opts.edges == "area" and found:
        # One paint contrast for all markers (the best resolved one's), so that the widths keep
        # their ratio (eq. (8) needs only the ratio).
        c_all = max(float(_median_where(f[3], f[4])) for f in found)
        for f in found:
            _area_edges(f[1], f[2], max(c_all, 1e-6))
    markers: list[Marker] = []
    for rows, ul, ur, contrast, good in found:
        ok, good, c_med = _plausible_rows(ul, ur, contrast, good, float(wpx), min_rows)
        if not ok:
            continue
        m = Marker(rows[good].astype(float), ul[good], ur[good], float(c_med))
        m.v0 = float(np.add.reduce(m.v) / m.v.size)       # m.v.mean() without its dispatch
        fl, rl, kl, fr, rr, kr = _robust_fit_pair(m.v, m.u_left, m.u_right, min(opts.fit_degree, max(0, m.v.size - 2)),
                                                  m.v0)
        m.fit_left, m.fit_right, m.rms_left, m.rms_right = fl, fr, rl, rr
        m.inliers = kl & kr
        if np.count_nonzero(m.inliers) < min_rows:
            continue
        markers.append(m)
    # Merge duplicates (two starts tracking the same line).
    markers.sort(key=lambda mk: float(np.add.reduce(mk.u_center) / mk.u_center.size))     # np.mean
    out: list[Marker] = []
    for mk in markers:
        if out:
            prev = out[-1]
            if _left_edge_distance(prev.v, prev.fit_left, prev.v0, mk.v, mk.fit_left, mk.v0) < wpx:
                if mk.v.size > prev.v.size:
                    out[-1] = mk
                continue
        out.append(mk)
    return out
