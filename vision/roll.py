"""Roll from the widths of the lane markers in the BEV (Alrazouk et al. 2024, section IV).

A cross-section of the road seen by a camera rolled by ``phi`` about the lane direction shows
the road point at lateral position ``Y`` (m, left positive, camera height ``H``) under the
angle ``alpha = atan(Y / H) + phi`` from the nadir. The rolled BEV shows it at
``f_vx tan(alpha)``; eq. (9) recovers ``alpha = atan2(p, f_vx)`` from the BEV column ``p``
(pixels from the nadir column). Undoing ``phi`` makes every width true again:

* eq. (8), two markers (edges ``a, b`` of one, ``c, d`` of the other, in the same left-to-right
  order): ``tan(a - phi) - tan(b - phi) - tan(c - phi) + tan(d - phi) = 0``, i.e. equal widths;
  with known unequal widths ``w1, w2`` the second pair is weighted by ``w1 / w2``;
* eq. (10), three lines (centres ``a1, a2, a3`` left to right):
  ``tan(a1 - phi) - 2 tan(a2 - phi) + tan(a3 - phi) = 0``, i.e. equal lane widths.

All of them are ``f(phi) = sum_k c_k tan(alpha_k - phi) = 0`` with coefficients ``c``
(:func:`coefficients_eq8`, :func:`coefficients_eq10`). Two solvers:

* :func:`solve_numeric`: Brent's method on ``f`` inside the bracket where every
  ``|alpha_k - phi| < pi/2`` (eq. (8) is continuous there), started around the seed and widened
  until the sign changes; it also takes a stack of cross-sections and solves their sum;
* :func:`solve_pade`: the paper's section IV.C, ``tan x ~ N(x) / D(x)`` (Pade [5/4]) turns
  ``f = 0`` into ``sum_k c_k N_k prod_{j != k} D_j = 0``, a polynomial of degree
  ``5 + 4 (n - 1)`` in ``phi`` (17 for eq. (8), 13 for eq. (10)); the real root nearest the seed.

Corrections to the paper, decided by round trip (tests/test_vision_roll.py):

* the Pade numerator is ``N(x) = x - x^3 / 9 + x^5 / 945`` (the [5/4] approximant of tan,
  ``(945 x - 105 x^3 + x^5) / (945 - 420 x^2 + 15 x^4)``); the paper prints ``5/9`` for the cubic
  coefficient, which makes ``N/D = x - 2 x^3 / 9 + ...`` instead of ``x + x^3 / 3 + ...``;
* eq. (14)'s derivation divides by ``q(a') + q(b') + q(c') + q(d')`` (the sum of
  ``|dg/dphi|``), but ``f`` depends on ``phi`` through the *signed* sum
  ``-sum_k c_k sec^2(alpha_k - phi)``, which nearly cancels (it is of the order of the marker
  width over ``H`` times ``tan alpha``): the expression before the final inequalities is 10 to
  50 times too small (the final ``dp / f_vx`` happens to be loose enough to land near the right
  order for the second term; the first term, ``w_pix / (4 W_met) dw``, is not even in radians).
  :func:`roll_sigma` propagates the edge errors through the signed derivative (first order,
  implicit function) and keeps eq. (14) as printed in :func:`roll_bound_eq14`;
* the sign of the recovered angle: ``phi`` solving eq. (8) is the BEV's residual roll
  ``phi_bev - phi_true`` about the lane direction (the XYZ roll of the camera when the BEV
  pitch and yaw are the vanishing point's), so the camera's roll is ``phi_bev - phi``.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .errors import VisionError

__all__ = [
    "coefficients_eq8",
    "coefficients_eq10",
    "residual",
    "solve_numeric",
    "solve_pade",
    "solve_exact",
    "pade_tan",
    "pade_polynomial",
    "roll_sigma",
    "roll_bound_eq14",
]

HALF_PI = 0.5 * math.pi


def coefficients_eq8(width_ratio: float = 1.0) -> np.ndarray:
    """Eq. (8) for edges ``(a, b, c, d)``: ``[1, -1, -r, r]`` with ``r = w1 / w2`` (1: equal widths)."""
    r = float(width_ratio)
    return np.array([1.0, -1.0, -r, r])


def coefficients_eq10() -> np.ndarray:
    """Eq. (10) for line centres ``(a1, a2, a3)``: ``[1, -2, 1]``."""
    return np.array([1.0, -2.0, 1.0])


def residual(phi_rad, alphas_rad, coef) -> np.ndarray:
    """``f(phi) = sum_k c_k tan(alpha_k - phi)`` (eqs. (8), (10)); ``alphas`` ``(..., n)``."""
    a = np.asarray(alphas_rad, dtype=float)
    return np.tan(a - np.asarray(phi_rad)[..., None]) @ np.asarray(coef, dtype=float)


def _domain(alphas: np.ndarray) -> tuple[float, float]:
    """``phi`` interval where every ``|alpha_k - phi| < pi/2``."""
    return float(alphas.max()) - HALF_PI, float(alphas.min()) + HALF_PI


def solve_numeric(alphas_rad, coef, seed_rad: float = 0.0, *, span_rad: float = math.radians(5.0),
                  xtol: float = 1e-12) -> float:
    """Root of ``sum_rows f_row(phi)`` by Brent's method, bracketed around ``seed_rad``.

    Parameters
    ----------
    alphas_rad : (n,) or (rows, n) array
        Angles of the edges (or line centres) from the nadir, rad, one cross-section per row.
    coef : (n,) array
        :func:`coefficients_eq8` or :func:`coefficients_eq10`.
    seed_rad : float
        Where to start looking (the previous frame's residual, usually 0).
    span_rad : float
        First half-width of the bracket; doubled until ``f`` changes sign.

    Returns
    -------
    float
        ``phi`` in rad, the root nearest the seed within the continuous domain.

    Raises
    ------
    VisionError
        If no sign change is found in the domain.
    """
    a = np.ascontiguousarray(np.atleast_2d(np.asarray(alphas_rad, dtype=float)))
    c = np.ascontiguousarray(np.asarray(coef, dtype=float))
    finite, a_max, a_min = _finite_max_min(a)       # np.isfinite(a).all(), a.max(), a.min() in one call
    if not finite:
        raise VisionError("roll: non-finite edge angles")
    lo_dom, hi_dom = (a_max - HALF_PI, a_min + HALF_PI) if a.size else _domain(a)    # (empty: numpy's error)
    eps = 1e-9
    lo_dom, hi_dom = lo_dom + eps, hi_dom - eps
    if not lo_dom < hi_dom:
        raise VisionError("roll: edges span more than 180 deg")
    seed = min(max(seed_rad, lo_dom), hi_dom)
    ok, phi = _bracket_and_solve(a, c, float(seed), float(span_rad), lo_dom, hi_dom, float(xtol))
    if not ok:
        raise VisionError("roll: the width equation has no root (markers not seen as a pair)")
    return phi


@nb.njit(cache=True)
def _finite_max_min(a):  # pragma: no cover (numba)
    """Whether all of ``a`` (2-D) is finite, and its maximum and minimum (when it is)."""
    hi, lo = -np.inf, np.inf
    for r in range(a.shape[0]):
        for k in range(a.shape[1]):
            v = a[r, k]
            if not math.isfinite(v):
                return False, np.nan, np.nan
            hi = max(hi, v)
            lo = min(lo, v)
    return True, hi, lo


#: Brent's relative tolerance, as SciPy's ``brentq`` defaults it.
_RTOL = 4.0 * float(np.finfo(float).eps)


@nb.njit(cache=True)
def _width_f(a, c, phi):  # pragma: no cover (numba)
    """``sum_k c_k sum_rows tan(a[row, k] - phi)``."""
    total = 0.0
    for k in range(a.shape[1]):
        s = 0.0
        for r in range(a.shape[0]):
            s += math.tan(a[r, k] - phi)
        total += s * c[k]
    return total


@nb.njit(cache=True)
def _bracket_and_solve(a, c, seed, span, lo_dom, hi_dom, xtol):  # pragma: no cover (numba)
    """:func:`solve_numeric`'s search: the bracket around ``seed`` widened until ``f`` changes
    sign (the sign change nearest the seed), then Brent's method. ``(found, phi)``."""
    f0 = _width_f(a, c, seed)
    if f0 == 0.0:
        return True, seed
    while True:
        lo, hi = max(seed - span, lo_dom), min(seed + span, hi_dom)
        flo, fhi = _width_f(a, c, lo), _width_f(a, c, hi)
        left = np.sign(flo) != np.sign(f0)
        right = np.sign(fhi) != np.sign(f0)
        if left and (not right or seed - lo <= hi - seed):
            return True, _brentq(a, c, lo, seed, xtol, _RTOL, 200)
        if right:
            return True, _brentq(a, c, seed, hi, xtol, _RTOL, 200)
        if lo <= lo_dom and hi >= hi_dom:
            return False, math.nan
        span *= 2.0


@nb.njit(cache=True)
def _brentq(a, c, xa, xb, xtol, rtol, maxiter):  # pragma: no cover (numba)
    """Brent's method as SciPy's ``brentq`` (scipy/optimize/Zeros/brentq.c), on :func:`_width_f`."""
    xpre, xcur = xa, xb
    xblk, fblk, spre, scur = 0.0, 0.0, 0.0, 0.0
    fpre, fcur = _width_f(a, c, xpre), _width_f(a, c, xcur)
    if fpre == 0.0:
        return xpre
    if fcur == 0.0:
        return xcur
    for _ in range(maxiter):
        if fpre != 0.0 and fcur != 0.0 and (fpre < 0.0) != (fcur < 0.0):
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if abs(fblk) < abs(fcur):
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        delta = (xtol + rtol * abs(xcur)) / 2.0
        sbis = (xblk - xcur) / 2.0
        if fcur == 0.0 or abs(sbis) < delta:
            return xcur
        if abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:
                stry = -fcur * (xcur - xpre) / (fcur - fpre)          # interpolate
            else:
                dpre = (fpre - fcur) / (xpre - xcur)                  # extrapolate
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
            if 2.0 * abs(stry) < min(abs(spre), 3.0 * abs(sbis) - delta):
                spre, scur = scur, stry                               # good short step
            else:
                spre, scur = sbis, sbis                               # bisect
        else:
            spre, scur = sbis, sbis
        xpre, fpre = xcur, fcur
        if abs(scur) > delta:
            xcur += scur
        else:
            xcur += delta if sbis > 0 else -delta
        fcur = _width_f(a, c, xcur)
    return xcur


def pade_tan(x):
    """Numerator and denominator of the Pade [5/4] approximant of ``tan x`` (section IV.C,
    with the cubic coefficient corrected to 1/9)."""
    x = np.asarray(x, dtype=float)
    x2 = x * x
    return x * (1.0 + x2 * (-1.0 / 9.0 + x2 / 945.0)), 1.0 + x2 * (-4.0 / 9.0 + x2 / 63.0)


# N(x) and D(x) as polynomials in x, lowest power first.
_N = np.array([0.0, 1.0, 0.0, -1.0 / 9.0, 0.0, 1.0 / 945.0])
_D = np.array([1.0, 0.0, -4.0 / 9.0, 0.0, 1.0 / 63.0])


def _compose_shift(p: np.ndarray, a: float) -> np.ndarray:
    """Coefficients (lowest first) in ``phi`` of ``p(a - phi)``."""
    P = np.polynomial.Polynomial(p)
    return P(np.polynomial.Polynomial([a, -1.0])).coef


def pade_polynomial(alphas_rad, coef) -> np.ndarray:
    """Coefficients (lowest power first) of ``sum_k c_k N(a_k - phi) prod_{j != k} D(a_j - phi)``.

    Degree ``5 + 4 (n - 1)``: 17 for eq. (8), 13 for eq. (10).
    """
    a = np.asarray(alphas_rad, dtype=float).ravel()
    c = np.asarray(coef, dtype=float)
    Ns = [_compose_shift(_N, ak) for ak in a]
    Ds = [_compose_shift(_D, ak) for ak in a]
    deg = 5 + 4 * (len(a) - 1)
    total = np.zeros(deg + 1)
    for k in range(len(a)):
        term = Ns[k] * c[k]
        for j in range(len(a)):
            if j != k:
                term = np.polynomial.polynomial.polymul(term, Ds[j])
        total[: term.size] += term
    return total


def solve_pade(alphas_rad, coef, seed_rad: float = 0.0) -> float:
    """Real root of the Pade polynomial (:func:`pade_polynomial`) nearest ``seed_rad``, rad.

    Only one cross-section (``alphas`` of shape ``(n,)``) per call.
    """
    a = np.asarray(alphas_rad, dtype=float)
    if a.ndim != 1:
        raise VisionError("solve_pade takes one cross-section; solve each row separately")
    if not np.all(np.isfinite(a)):
        raise VisionError("roll: non-finite edge angles")
    p = pade_polynomial(a, coef)
    # Roots in the shifted variable x = phi - seed keep the companion matrix well conditioned.
    p_shift = np.polynomial.Polynomial(p)(np.polynomial.Polynomial([seed_rad, 1.0])).coef
    nz = np.flatnonzero(np.abs(p_shift) > 0)
    if nz.size == 0:
        raise VisionError("roll: degenerate Pade polynomial")
    roots = np.roots(p_shift[: nz[-1] + 1][::-1])
    lo, hi = _domain(a)
    real = roots[np.abs(roots.imag) < 1e-7 * (1.0 + np.abs(roots.real))].real + seed_rad
    real = real[(real > lo) & (real < hi)]
    if real.size == 0:
        raise VisionError("roll: the Pade polynomial has no real root in the domain")
    x = float(real[np.argmin(np.abs(real - seed_rad))])
    # Polish on the Pade polynomial itself (Newton), removing the eigenvalue solver's rounding.
    P = np.polynomial.Polynomial(p)
    dP = P.deriv()
    for _ in range(3):
        d = dP(x)
        if d == 0:
            break
        x -= P(x) / d
    return x


def solve_exact(alphas_rad, coef) -> np.ndarray:
    """All roots via ``t = tan(phi)``: ``tan(a - phi) = (A - t) / (1 + A t)``, ``A = tan a``, so
    ``f = 0`` is a polynomial of degree ``n`` in ``t``, exact (no approximation of tan).

    Not in the paper; used to cross-check the two solvers. Returns real roots, rad.
    """
    a = np.asarray(alphas_rad, dtype=float).ravel()
    c = np.asarray(coef, dtype=float)
    A = np.tan(a)
    total = np.zeros(len(a) + 1)
    for k in range(len(a)):
        term = np.array([A[k] * c[k], -c[k]])
        for j in range(len(a)):
            if j != k:
                term = np.polynomial.polynomial.polymul(term, [1.0, A[j]])
        total[: term.size] += term
    nz = np.flatnonzero(np.abs(total) > 1e-300)
    roots = np.roots(total[: nz[-1] + 1][::-1])
    real = roots[np.abs(roots.imag) < 1e-9 * (1 + np.abs(roots.real))].real
    return np.arctan(real)


def roll_sigma(alphas_rad, coef, phi_rad: float, sigma_alpha_rad, sigma_f: float = 0.0) -> float:
    """1-sigma of the root from independent errors of the angles (first order).

    ``sigma_phi^2 = (sum_k (c_k sec^2(a_k - phi) sigma_k)^2 + sigma_f^2) / (sum_k c_k sec^2(a_k - phi))^2``

    ``sigma_f`` is the error of ``f`` itself, e.g. the painted widths' tolerance ``dw / H``
    (the first term of eq. (14)). For a stack of cross-sections pass ``(rows, n)`` angles;
    their errors are taken as fully correlated along a fitted edge (the fit is one curve),
    so the rows are averaged before propagating.
    """
    a = np.atleast_2d(np.asarray(alphas_rad, dtype=float))
    c = np.asarray(coef, dtype=float)
    q = 1.0 / np.cos(a - phi_rad) ** 2          # sec^2
    dfdphi = -(q @ c).mean()
    s = np.broadcast_to(np.asarray(sigma_alpha_rad, dtype=float), a.shape)
    num = np.sum(((c * q * s).mean(axis=0)) ** 2) + sigma_f**2
    if dfdphi == 0:
        return math.inf
    return float(math.sqrt(num) / abs(dfdphi))


def roll_bound_eq14(w_pix: int, W_met: float, h_m: float, dw_m: float, dp_px: float) -> float:
    """Eq. (14) as printed: ``dphi <= w_pix / (4 W_met) dw + W_met / (h w_pix) dp``, rad.

    Kept for comparison only; see the module docstring for why it is far too small.
    """
    return w_pix / (4.0 * W_met) * dw_m + W_met / (h_m * w_pix) * dp_px
