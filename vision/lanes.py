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

from dataclasses import dataclass, field

import cv2
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
    and smaller road ``Y``; ``fit_left`` / ``fit_right`` polynomial coefficients of ``u(v)``
    (highest power first, ``numpy.polyval``), ``rms_left`` / ``rms_right`` their residuals, px.
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
        return np.polyval(self.fit_left, v), np.polyval(self.fit_right, v)


def marker_response(bev: np.ndarray, width_px: int) -> np.ndarray:
    """Dark-bright-dark response ``box(u) - max(box(u - w), box(u + w))`` along rows, float32."""
    w = max(1, int(width_px))
    b = cv2.blur(bev, (w, 1), borderType=cv2.BORDER_REPLICATE)
    r = np.zeros_like(b)
    if b.shape[1] > 2 * w:
        r[:, w:-w] = b[:, w:-w] - np.maximum(b[:, :-2 * w], b[:, 2 * w:])
    return r


def _threshold(resp: np.ndarray, opts: LaneOptions) -> float:
    sample = resp[::3, ::3].ravel()
    k = max(0, int(0.995 * sample.size) - 1)
    high = float(np.partition(sample, k)[k]) if sample.size else 0.0
    return max(opts.min_contrast, opts.rel_threshold * high)


def _remove_small_blobs(binary: np.ndarray, min_rows: int) -> np.ndarray:
    n, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    if n <= 1:
        return binary
    keep = stats[:, cv2.CC_STAT_HEIGHT] >= min_rows
    keep[0] = False
    return keep[labels].astype(np.uint8)


def _line_starts(binary: np.ndarray, min_count: int, min_gap_px: int) -> list[int]:
    """Columns of the histogram peaks (binary pixels per column, lightly smoothed)."""
    hist = binary.sum(axis=0, dtype=np.float32)
    k = max(3, min_gap_px // 4) | 1
    hist = cv2.blur(hist.reshape(1, -1), (k, 1)).ravel()
    starts: list[int] = []
    order = np.argsort(hist)[::-1]
    for c in order[:400]:
        if hist[c] < min_count:
            break
        if all(abs(int(c) - s) >= min_gap_px for s in starts):
            starts.append(int(c))
    return sorted(starts)


def _track(binary: np.ndarray, start_col: int, opts_px: dict) -> tuple[np.ndarray, np.ndarray]:
    """Sliding windows from the bottom (near) to the top (far): window centres ``(v, u)``
    of the windows that held enough marker pixels."""
    Hh, W = binary.shape
    n_win, hw, min_pix = opts_px["n_windows"], opts_px["half_window"], opts_px["min_pix"]
    win_h = Hh / n_win
    c = float(start_col)
    slope = 0.0  # du per dv going up (negative v)
    vs, us = [], []
    for k in range(n_win):
        v1 = int(round(Hh - k * win_h))
        v0 = int(round(Hh - (k + 1) * win_h))
        u0, u1 = int(round(c - hw)), int(round(c + hw)) + 1
        if u1 <= 0 or u0 >= W:
            break
        u0c, u1c = max(u0, 0), min(u1, W)
        cols = binary[v0:v1, u0c:u1c].sum(axis=0, dtype=np.float32)
        tot = float(cols.sum())
        vm = 0.5 * (v0 + v1)
        if tot >= min_pix:
            cnew = u0c + float((cols * np.arange(cols.size)).sum() / tot)
            if vs:
                dv = vm - vs[-1]
                slope = 0.5 * slope + 0.5 * (cnew - us[-1]) / dv if dv != 0 else slope
            vs.append(vm)
            us.append(cnew)
            c = cnew + slope * (-win_h)
        else:
            c = c + slope * (-win_h)
    return np.asarray(vs), np.asarray(us)


def _edges_on_rows(bev: np.ndarray, binary: np.ndarray, rows: np.ndarray, centers: np.ndarray,
                   half: int, wpx: float, mode: str, paint_contrast: float | None = None, valid=None):
    """Both edges of the marker near ``centers`` on each row; NaN where not found.

    The half level of each edge is halfway between the road level on that side and the paint:
    the row's own peak, or ``road level + paint_contrast`` when given (a contrast common to the
    frame, so that a marker blurred below its full brightness is not widened)."""
    W = bev.shape[1]
    n = rows.size
    k = np.arange(-half, half + 1)
    raw_cols = np.rint(centers).astype(int)[:, None] + k[None, :]
    cols = np.clip(raw_cols, 0, W - 1)
    P = bev[rows[:, None], cols]
    if valid is not None:
        # Pixels outside the BEV or the camera image are unknown, not black.
        lo, hi = valid
        P = np.where((raw_cols >= lo[rows][:, None]) & (raw_cols <= hi[rows][:, None]), P, np.nan)
    Bm = binary[rows[:, None], cols].astype(bool)
    # The run of marker pixels containing (or nearest to) the window centre.
    mid = half
    any_ = Bm.any(axis=1)
    idx = np.arange(2 * half + 1)
    dist = np.where(Bm, np.abs(idx[None, :] - mid), 10**6)
    seed = np.argmin(dist, axis=1)
    # Extend the run left and right from the seed while pixels are set.
    notB = ~Bm
    left_stop = np.where(notB & (idx[None, :] < seed[:, None]), idx[None, :], -1).max(axis=1)
    right_stop = np.where(notB & (idx[None, :] > seed[:, None]), idx[None, :], 2 * half + 1).min(axis=1)
    first = left_stop + 1
    last = right_stop - 1
    ok = any_ & (first > 0) & (last < 2 * half)
    base = cols[:, 0].astype(float)
    if mode == "binary":
        ul = base + first - 0.5
        ur = base + last + 0.5
        contrast = np.full(n, np.nan)
        r = np.arange(n)
        peak = P[r, np.clip(seed, 0, 2 * half)]
        contrast = peak - 0.5 * (P[r, np.clip(first - 2, 0, 2 * half)] + P[r, np.clip(last + 2, 0, 2 * half)])
        ul[~ok] = np.nan
        ur[~ok] = np.nan
        return ul, ur, contrast
    r = np.arange(n)
    # Paint level: the brightest pixel of the run (the run is >= 1 px); road levels: the mean of
    # a band one marker width outside the run on each side.
    inside = Bm & (idx[None, :] >= first[:, None]) & (idx[None, :] <= last[:, None])
    paint = np.where(inside, P, -np.inf).max(axis=1)
    m = max(2, int(round(wpx)))
    lb0 = np.clip(first - 1 - m, 0, 2 * half)
    lb1 = np.clip(first - 1, 0, 2 * half)
    rb0 = np.clip(last + 1, 0, 2 * half)
    rb1 = np.clip(last + 1 + m, 0, 2 * half)
    cs = np.concatenate([np.zeros((n, 1), P.dtype), np.cumsum(P, axis=1)], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        bg_l = (cs[r, lb1] - cs[r, lb0]) / np.maximum(lb1 - lb0, 1)
        bg_r = (cs[r, rb1 + 1] - cs[r, rb0 + 1]) / np.maximum(rb1 - rb0, 1)
        if paint_contrast is None:
            half_l = 0.5 * (bg_l + paint)
            half_r = 0.5 * (bg_r + paint)
        else:
            half_l = bg_l + 0.5 * paint_contrast
            half_r = bg_r + 0.5 * paint_contrast
        # Rising crossing: the last index j <= first with P[j] < half_l, then interpolate j..j+1.
        below_l = (P < half_l[:, None]) & (idx[None, :] <= first[:, None])
        jl = np.where(below_l, idx[None, :], -1).max(axis=1)
        jl1 = np.clip(jl + 1, 0, 2 * half)
        pl0, pl1 = P[r, np.clip(jl, 0, 2 * half)], P[r, jl1]
        ul = base + jl + (half_l - pl0) / (pl1 - pl0)
        below_r = (P < half_r[:, None]) & (idx[None, :] >= last[:, None])
        jr = np.where(below_r, idx[None, :], 2 * half + 1).min(axis=1)
        jr0 = np.clip(jr - 1, 0, 2 * half)
        pr0, pr1 = P[r, jr0], P[r, np.clip(jr, 0, 2 * half)]
        ur = base + jr0 + (pr0 - half_r) / (pr0 - pr1)
    good = ok & (jl >= 0) & (jr <= 2 * half) & (pl1 > pl0) & (pr0 > pr1) & (jl < jr)
    contrast = paint - 0.5 * (bg_l + bg_r)
    if mode == "area":
        ul, ur, good = _area_edges(P, cs, ul - base, ur - base, good, wpx)
        ul, ur = ul + base, ur + base
    ul[~good] = np.nan
    ur[~good] = np.nan
    return ul, ur, contrast


def _area_edges(P, cs, ul, ur, good, wpx):
    """Centroid and area of the marker's profile above a linear road level.

    Blur, whatever its width or direction, keeps the area under the profile: area / contrast
    is the marker's width even when the marker is narrower than the blur (far away, or seen
    at a grazing angle, where half-level crossings widen it). Returns the centroid
    ``+- area / 2`` in units of the paint contrast 1 (the caller rescales with a contrast common
    to all markers; eq. (8) only needs the ratio of the widths).
    """
    n, L = P.shape
    fwhm = np.where(good, ur - ul, wpx)
    c0 = np.where(good, 0.5 * (np.nan_to_num(ul) + np.nan_to_num(ur)), 0.5 * L)
    hw = 0.5 * fwhm + np.maximum(fwhm, wpx)
    m = max(3.0, float(wpx))
    i0 = np.ceil(c0 - hw).astype(int)
    i1 = np.floor(c0 + hw).astype(int)
    l0 = np.floor(c0 - hw - m).astype(int)
    r1 = np.ceil(c0 + hw + m).astype(int)
    inside = good & (l0 >= 0) & (r1 <= L - 1) & (i1 > i0)
    i0, i1 = np.clip(i0, 0, L - 1), np.clip(i1, 0, L - 1)
    l0, r1 = np.clip(l0, 0, L - 1), np.clip(r1, 0, L - 1)
    r = np.arange(n)
    idx = np.arange(L, dtype=P.dtype)
    cs1 = np.concatenate([np.zeros((n, 1), P.dtype), np.cumsum(P * idx[None, :], axis=1)], axis=1)
    nl = np.maximum(i0 - l0, 1)
    nr = np.maximum(r1 - i1, 1)
    bgL = (cs[r, i0] - cs[r, l0]) / nl
    bgR = (cs[r, r1 + 1] - cs[r, i1 + 1]) / nr
    uL = 0.5 * (l0 + i0 - 1)
    uR = 0.5 * (i1 + 1 + r1)
    beta = (bgR - bgL) / np.maximum(uR - uL, 1.0)
    alpha = bgL - beta * uL
    nw = (i1 - i0 + 1).astype(float)
    s_i = nw * 0.5 * (i0 + i1)
    s_i2 = (i1 * (i1 + 1) * (2 * i1 + 1) - (i0 - 1) * i0 * (2 * i0 - 1)) / 6.0
    S0 = cs[r, i1 + 1] - cs[r, i0]
    S1 = cs1[r, i1 + 1] - cs1[r, i0]
    A = S0 - (alpha * nw + beta * s_i)
    M1 = S1 - (alpha * s_i + beta * s_i2)
    with np.errstate(invalid="ignore", divide="ignore"):
        cen = M1 / A
    # Rows blurred to more than 2.5 marker widths reach the neighbouring road texture.
    ok = inside & (A > 0) & np.isfinite(cen) & (fwhm < 2.5 * wpx + 2.0)
    return cen - 0.5 * A, cen + 0.5 * A, ok


def _robust_fit(v: np.ndarray, u: np.ndarray, deg: int):
    """``polyfit`` with one pass of rejection at 3 robust sigma; ``(coef, rms, inliers)``."""
    deg = min(deg, max(0, v.size - 2))
    x = (v - v.mean())
    c = np.polyfit(x, u, deg)
    res = u - np.polyval(c, x)
    s = 1.4826 * np.median(np.abs(res)) + 1e-3
    keep = np.abs(res) < 3.0 * s + 0.05
    if keep.sum() > deg + 2 and not keep.all():
        c = np.polyfit(x[keep], u[keep], deg)
        res = u - np.polyval(c, x)
    rms = float(np.sqrt(np.mean(res[keep] ** 2))) if keep.any() else np.nan
    # Back to polynomials in v (not v - mean): compose with the shift.
    coef = np.polynomial.polynomial.Polynomial(c[::-1])
    shifted = coef(np.polynomial.polynomial.Polynomial([-v.mean(), 1.0]))
    full = shifted.coef[::-1]
    if full.size < deg + 1:
        full = np.concatenate([np.zeros(deg + 1 - full.size), full])
    return full, rms, keep


def detect_markers(bev: np.ndarray, valid_lo: np.ndarray, valid_hi: np.ndarray, dx_m: float, dy_m: float,
                   marker_width_m: float, opts: LaneOptions = LaneOptions()) -> list[Marker]:
    """Painted lines in a grey BEV (float32), sorted left to right (increasing ``u``).

    Parameters
    ----------
    bev : (h_pix, w_pix) float32 array
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
    resp = marker_response(bev, int(round(max(wpx, 1.0))))
    # Responses within a marker width of the image border are artefacts of the black fill.
    cols = np.arange(W, dtype=np.float32)[None, :]
    margin = max(2.0, 1.5 * wpx)
    inside = (cols >= valid_lo[:, None] + margin) & (cols <= valid_hi[:, None] - margin)
    resp = np.where(inside, resp, 0.0).astype(np.float32)
    thr = _threshold(resp, opts)
    binary = (resp > thr).astype(np.uint8)
    binary = _remove_small_blobs(binary, max(2, int(round(opts.min_blob_m / dx_m))))
    min_rows = max(3, int(round(opts.min_line_m / dx_m)))
    starts = _line_starts(binary, min_rows // 2, max(3, int(round(opts.min_line_gap_m / dy_m))))
    if not starts:
        return []
    half_window = max(3, int(round(opts.window_m / dy_m)))
    opx = dict(n_windows=opts.n_windows, half_window=half_window,
               min_pix=max(3, int(round(0.3 * (Hh / opts.n_windows) * max(wpx, 1.0) * 0.5))))
    half = max(4, int(round(1.6 * wpx)) + max(2, int(round(wpx))) + 2)
    if opts.edges == "area":
        half = max(half, int(round(6.0 * wpx)) + 4)
    found = []
    for s in starts:
        wv, wu = _track(binary, s, opx)
        if wv.size < 2:
            continue
        # Centre line through the windows, evaluated on every row they span.
        deg = 1 if wv.size < 4 else 2
        cfit = np.polyfit(wv, wu, deg)
        v_lo = max(0, int(wv.min() - Hh / opts.n_windows / 2))
        v_hi = min(Hh - 1, int(wv.max() + Hh / opts.n_windows / 2))
        rows = np.arange(v_lo, v_hi + 1)
        centers = np.polyval(cfit, rows)
        inb = (centers > 2 * wpx) & (centers < W - 1 - 2 * wpx)
        rows, centers = rows[inb], centers[inb]
        if rows.size < min_rows:
            continue
        ul, ur, contrast = _edges_on_rows(bev, binary, rows, centers, half, wpx, opts.edges,
                                          valid=(np.floor(valid_lo), np.ceil(valid_hi)))
        good = np.isfinite(ul) & np.isfinite(ur)
        if good.sum() < min_rows:
            continue
        found.append((rows, ul, ur, contrast, good, centers))
    if opts.edges == "area" and found:
        # One paint contrast for all markers (the best resolved one's), so that the widths keep
        # their ratio (eq. (8) needs only the ratio).
        c_all = max(float(np.median(f[3][f[4]])) for f in found)
        for f in found:
            cen, hw = 0.5 * (f[1] + f[2]), 0.5 * (f[2] - f[1]) / max(c_all, 1e-6)
            f[1][:], f[2][:] = cen - hw, cen + hw
    markers: list[Marker] = []
    for rows, ul, ur, contrast, good, _ in found:
        width = ur - ul
        good = good & (width > 0.4 * wpx) & (width < 2.5 * wpx + 2)
        if good.sum() < min_rows:
            continue
        c_med = float(np.median(contrast[good]))
        good &= contrast > 0.6 * c_med
        if good.sum() < min_rows:
            continue
        m = Marker(rows[good].astype(float), ul[good], ur[good], c_med)
        fl, rl, kl = _robust_fit(m.v, m.u_left, opts.fit_degree)
        fr, rr, kr = _robust_fit(m.v, m.u_right, opts.fit_degree)
        m.fit_left, m.fit_right, m.rms_left, m.rms_right = fl, fr, rl, rr
        m.inliers = kl & kr
        if m.inliers.sum() < min_rows:
            continue
        markers.append(m)
    # Merge duplicates (two starts tracking the same line).
    markers.sort(key=lambda mk: float(np.median(mk.u_center)))
    out: list[Marker] = []
    for mk in markers:
        if out:
            prev = out[-1]
            vv = np.intersect1d(prev.v, mk.v)
            if vv.size and np.median(np.abs(np.polyval(prev.fit_left, vv) - np.polyval(mk.fit_left, vv))) < wpx:
                if mk.v.size > prev.v.size:
                    out[-1] = mk
                continue
        out.append(mk)
    return out
