"""Joint model of the lane lines on the road plane (beyond the paper).

Projected onto the road with the current pose estimate, the lane-marker edges are fitted
together as

    y_(j,s)(x) = a_(j,s) + b_j x + c_2 x^2 + c_3 x^3          (x forward, y left, m)

with an offset ``a`` per edge (line ``j``, side ``s``), a slope ``b_j`` per line and a shape
``c`` common to the road, scaled per line by ``1 / (1 - kappa0 a_j)`` (concentric arcs: a line
``a_j`` to the left of the camera has curvature ``kappa0 / (1 - kappa0 a_j)``; a second pass
uses the first pass's ``kappa0``). Residual pitch makes the lines converge (``b_j`` grows with ``a_j``),
residual yaw tilts them all: the tangents at the vehicle, ``(a_j, b_j)``, give the lane direction
(:func:`lane_direction`), and the offsets at any ``x`` the cross-sections for eqs. (8), (10).
Sharing the shape lets the dashed centre line, seen in short pieces, borrow the curvature of
the solid lines instead of extrapolating its own.

The covariance is inflated by ``(1 + rho) / (1 - rho)``, ``rho`` the lag-1 autocorrelation of
the weighted residuals along the edges (road texture and interpolation make neighbours share
their errors), so that the significance test of the shape and the reported sigmas hold.

Weights: each point gets ``indep(x) / var(x)``. ``indep = min(1, f_y H dx / x^2)``: a BEV row
far away re-samples an image row already used (``f_y H / x^2`` image rows per metre against
``1 / dx`` BEV rows). ``var = s_b^2 + s_i^2 q^2``: a floor constant in metres (the BEV's sub-pixel
precision, the road texture) and a part proportional to ``q``, the metres of lateral position
per unit of measurement error (``q = x`` for BEV rows; for cuts in the image, the metres per
pixel along the cut), fitted to the squared residuals of a first pass (feasible generalised
least squares): on the rendered drives BEV residuals are nearly constant in metres up to 20 m,
so ``1 / x^2`` weights would throw most of the data away. Points beyond 4 sigma of that model
after the first pass get no weight in the second.

Vertical curvature (beyond the paper). The road is not a plane: on a curve of curvature
``kappa`` banked by ``b`` the surface seen from its tangent plane at the vehicle drops by
``z(x) = -sin(b) kappa x^2 / 2`` (to first order whatever the lateral position: the lateral axis
is tilted by the bank while the curve bends it), and a sag or crest of the road adds its own
``x^2 / 2`` term. The points are therefore projected onto ``z = -H + zeta (x - x0)^2 / 2``
(:func:`vision.ipm.ground_from_rays`) with the current ``zeta``, and the fit carries one more
column, the first-order change of the projected points when ``zeta`` is off by ``dzeta``:

    y_k(x) + dzeta u^2 / (2 D) (y_k(x) - x y_k'(x)),   u = x - x0,   D = H - zeta u^2 / 2 + zeta u x

(``y - x y' = a_k - s_j (c_2 t^2 + 2 c_3 t^3)``, from the previous pass; the raw ``y`` in the
first). A planar IPM reads a sag as the lines spreading apart quadratically, in proportion to
their lateral position ``a_j``; a pitch error spreads them linearly (``b_j`` grows with ``a_j``)
and a horizontal curve bends them all alike: the three are separable with two lines or more.
The estimator updates ``zeta += dzeta`` and projects again until it stops moving, so the
linearisation only has to point the right way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from .errors import VisionError

__all__ = ["LaneModel", "fit_lane_model", "fit_lane_model_points", "lane_direction"]

_XS = 10.0  # m, scale of x in the shape columns (conditioning)


@dataclass
class LaneModel:
    """Fitted lanes; ``edge_line[k]``, ``edge_side[k]`` say which line and side edge ``k`` is."""

    a: np.ndarray            # (K,) offsets of the edges at x = 0, m
    b: np.ndarray            # (J,) slopes of the lines at x = 0
    c: np.ndarray            # (deg - 1,) shape coefficients of (x/10)^2, (x/10)^3, m
    cov: np.ndarray          # covariance of [a, b, c]
    edge_line: np.ndarray
    edge_side: np.ndarray
    x_min: np.ndarray        # (K,) range of the data of each edge, m
    x_max: np.ndarray
    rms_m: float             # weighted RMS residual scaled to 10 m, m
    n: int
    line_scale: np.ndarray = None  # (J,) shape scale of each line (concentric lines)  # type: ignore[assignment]
    #: Correction ``dzeta`` of the vertical curvature the points were projected with, 1/m (last
    #: parameter of ``cov``); 0 without the column.
    dzeta: float = 0.0
    #: ``(H, x0, zeta)`` of the projection when the fit has the vertical-curvature column, else None.
    sag: tuple | None = None
    #: 1-sigma of ``zeta`` before it was set to 0 for want of significance (NaN: it was not).
    zeta_free_sigma: float = math.nan
    #: Where ``dzeta`` was held (:meth:`held_at`; None where not): ``zeta`` (1/m, the
    #: projection's plus ``dzeta``) and its 1-sigma as the fit found them, and the parameters'
    #: change per 1/m of ``dzeta`` in that fit.
    zeta_hold: tuple | None = None
    #: The fit's points and second-pass weights, vertical-curvature column and inverse normal
    #: matrix, for :meth:`linear_response` (None: not from :func:`fit_lane_model_points`).
    linear: tuple | None = None
    #: The priors on ``dzeta`` applied since the fit, ``(index, gain)`` each (:meth:`with_dzeta_prior`).
    prior_gains: tuple = ()

    def __post_init__(self) -> None:
        if self.line_scale is None:
            self.line_scale = np.ones(self.b.size)

    @property
    def has_sag(self) -> bool:
        return self.sag is not None

    @property
    def i_dzeta(self) -> int:
        """Index of ``dzeta`` in ``cov`` (-1 without it)."""
        return self.a.size + self.b.size + self.c.size if self.sag is not None else -1

    @property
    def sigma_dzeta(self) -> float:
        """1-sigma of ``dzeta``, 1/m (0 without the column)."""
        i = self.i_dzeta
        return math.sqrt(max(float(self.cov[i, i]), 0.0)) if i >= 0 else 0.0

    def with_dzeta_prior(self, dzeta_1_m: float, sigma_1_m: float) -> "LaneModel":
        """The model updated with the prior ``dzeta ~ N(dzeta_1_m, sigma_1_m^2)`` (a scalar
        Kalman update of all parameters: exact for the linear model, so a frame whose lines
        hardly see the vertical curvature keeps the prior's and says so in ``cov``)."""
        i = self.i_dzeta
        if i < 0 or not math.isfinite(sigma_1_m) or sigma_1_m <= 0:
            return self
        p, cov, g = _dzeta_update(self.cov, self.a, self.b, self.c, float(self.dzeta), i, float(dzeta_1_m),
                                  float(sigma_1_m**2))
        K, J, nc = self.a.size, self.b.size, self.c.size
        out = object.__new__(LaneModel)          # a copy with new parameters (no __init__: 1670 a second)
        out.__dict__.update(self.__dict__)
        out.a, out.b, out.c, out.dzeta, out.cov = p[:K], p[K:K + J], p[K + J:K + J + nc], float(p[i]), cov
        out.prior_gains = self.prior_gains + ((i, g),)
        return out

    def held_at(self, dzeta_1_m: float) -> "LaneModel":
        """The model with ``dzeta`` held at ``dzeta_1_m`` (a prior of 1e-9 1/m), remembering
        what the fit said of it in :attr:`zeta_hold` (the first hold's, when held again)."""
        i = self.i_dzeta
        out = self.with_dzeta_prior(dzeta_1_m, 1e-9)
        if i >= 0 and self.zeta_hold is None and out is not self:
            var = float(self.cov[i, i])
            gain = self.cov[:, i] / var if var > 0.0 else np.zeros(self.cov.shape[0])
            out.zeta_hold = (float(self.sag[2]) + self.dzeta, math.sqrt(max(var, 0.0)), gain)
        return out

    def zeta_consider_cov(self) -> np.ndarray | None:
        """What holding ``dzeta`` took out of the parameters' covariance (a Schmidt "consider"
        term): ``g g^T ((zeta_free - zeta_held)^2 + sigma_free^2)``, ``g`` the parameters' change
        per 1/m of ``dzeta`` in the free fit. None where it was not held."""
        if self.zeta_hold is None:
            return None
        free, sigma, gain = self.zeta_hold
        held = float(self.sag[2]) + self.dzeta
        return np.outer(gain, gain) * ((free - held) ** 2 + sigma ** 2)

    def linear_response(self, dy: np.ndarray, priors: bool = True) -> np.ndarray:
        """Change of the parameters ``[a, b, c, dzeta]`` when the fit's points (``linear[0:2]``,
        ``x`` and ``y`` in the fit's order) move laterally by ``dy``: ``Ai A^T W dy`` of the
        second pass, then each prior on ``dzeta`` applied since (a Kalman update is linear in
        the parameters; ``priors=False``: the fit's own response, without them). The design is held: a refit would also re-derive its weights, the lines'
        concentric scale and the ``dzeta`` column from the moved points, which on curves adds a
        first-order term through the scale (at 5e-3 1/m: slopes 7 %, curvature 1.3 % off;
        tests/test_vision_kernels.py)."""
        x, _, k_of, w, zc, Ai, nz = self.linear
        K, J, nc = self.a.size, self.b.size, self.c.size
        r = _linear_rhs(x / _XS, w, zc, k_of, self.edge_line, self.line_scale, K, J, nc, nz,
                        np.ascontiguousarray(dy, np.float64))
        dp = Ai @ r
        dp[K:K + J] /= _XS                  # slopes per t = x / 10 -> per metre
        for i, g in self.prior_gains if priors else ():
            dp = dp - g * dp[i]
        return dp

    def zeta_column(self, k: int, x) -> np.ndarray:
        """``u^2 / (2 D) (y_k - x y_k')`` at ``x``: the change of the projected ``y`` of edge ``k``
        per unit of ``dzeta`` (module docstring)."""
        x = np.asarray(x, float)
        if self.sag is None:
            return np.zeros_like(x)
        return sag_weight(x, *self.sag) * self._flat(k, x)

    def _flat(self, k: int, x):
        """``y_k(x) - x y_k'(x)`` (the slope ``b`` drops out)."""
        j = self.edge_line[k]
        t = np.asarray(x, float) / _XS
        out = np.full_like(t, float(self.a[k]))
        for i, ci in enumerate(self.c):
            p = i + 2
            out = out - self.line_scale[j] * (p - 1) * ci * t**p
        return out

    @property
    def n_edges(self) -> int:
        return self.a.size

    @property
    def n_lines(self) -> int:
        return self.b.size

    def _shape(self, x):
        x = np.asarray(x, float) / _XS
        return sum(ci * x ** (i + 2) for i, ci in enumerate(self.c)) if self.c.size else np.zeros_like(x)

    @property
    def kappa0(self) -> float:
        """Curvature at the camera's lateral position (y = 0), 1/m."""
        return 2.0 * float(self.c[0]) / _XS**2 if self.c.size else 0.0

    def _shape_d(self, x, order=1):
        x = np.asarray(x, float) / _XS
        out = np.zeros_like(x)
        for i, ci in enumerate(self.c):
            p = i + 2
            if order == 1:
                out = out + ci * p * x ** (p - 1) / _XS
            else:
                out = out + ci * p * (p - 1) * x ** (p - 2) / _XS**2
        return out

    def y_edges(self, ks, x) -> np.ndarray:
        """Lateral positions ``(len(ks), len(x))`` of edges ``ks`` at ``x``, m."""
        return _y_edges(self.a, self.b, self.c, self.line_scale, self.edge_line, np.asarray(ks, np.int64).reshape(-1),
                        np.ascontiguousarray(x, np.float64).reshape(-1))

    def y(self, k: int, x, shape=None):
        """Lateral position of edge ``k`` at ``x``, m (``shape``: :meth:`_shape` at ``x``, when the
        caller has it: it is common to all edges)."""
        j = self.edge_line[k]
        return self.a[k] + self.b[j] * np.asarray(x, float) + self.line_scale[j] * (self._shape(x) if shape is None
                                                                                      else shape)

    def slope(self, j: int, x):
        return self.b[j] + self.line_scale[j] * self._shape_d(x, 1)

    def _row(self, k: int, x):
        """Derivatives of ``y(k, x)`` with respect to the parameters ``[a, b, c, dzeta]``: the
        road's lines do not depend on ``dzeta`` (it moves the projected points, not the lines),
        but through ``cov`` their uncertainty includes it."""
        x = np.atleast_1d(np.asarray(x, float))
        K, J = self.n_edges, self.n_lines
        R = np.zeros((x.size, self.cov.shape[0]))
        R[:, k] = 1.0
        R[:, K + self.edge_line[k]] = x
        for i in range(self.c.size):
            R[:, K + J + i] = self.line_scale[self.edge_line[k]] * (x / _XS) ** (i + 2)
        return R

    def mean_y_and_rows(self, ks, x) -> tuple[np.ndarray, np.ndarray]:
        """Mean of :meth:`y` and of :meth:`_row` over edges ``ks`` at ``x`` (a cross-section's
        line centre, or one edge), in one pass."""
        return _mean_y_and_rows(self.a, self.b, self.c, self.line_scale, self.edge_line,
                                np.asarray(ks, np.int64).reshape(-1), np.atleast_1d(np.asarray(x, float)),
                                self.cov.shape[0])

    def slope_row(self, j: int, x: float) -> np.ndarray:
        """Derivatives of ``slope(j, x)`` with respect to the parameters."""
        K, J = self.n_edges, self.n_lines
        R = np.zeros(self.cov.shape[0])
        R[K + j] = 1.0
        t = float(x) / _XS
        for i in range(self.c.size):
            p = i + 2
            R[K + J + i] = self.line_scale[j] * p * t ** (p - 1) / _XS
        return R

    def curvature_and_row(self, j: int, x: float) -> tuple[float, np.ndarray]:
        """Curvature of line ``j`` at ``x`` (1/m, positive turning left) and its derivatives (to
        first order in the slope) with respect to the parameters, the slope they share computed
        once."""
        K, J = self.n_edges, self.n_lines
        s1 = float(self.slope(j, x))
        kappa = self.line_scale[j] * float(self._shape_d(x, 2)) / (1.0 + s1 * s1) ** 1.5
        R = np.zeros(self.cov.shape[0])
        t = float(x) / _XS
        g = self.line_scale[j] / (1.0 + s1 * s1) ** 1.5
        for i in range(self.c.size):
            p = i + 2
            R[K + J + i] = g * p * (p - 1) * t ** (p - 2) / _XS**2
        return kappa, R

    def sigma_y(self, k: int, x) -> np.ndarray:
        """1-sigma of ``y(k, x)``, m."""
        R = self._row(k, x)
        return np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", R, self.cov, R), 0.0))

    def sigma_b(self, j: int) -> float:
        i = self.n_edges + j
        return math.sqrt(max(float(self.cov[i, i]), 0.0))      # np.sqrt's value, without its dispatch


@nb.njit(cache=True)
def _mean_y_and_rows(a, b, c, line_scale, edge_line, ks, x, P):  # pragma: no cover (numba)
    """:meth:`LaneModel.mean_y_and_rows` (compiled: it runs for every cross-section)."""
    K, J, nc = a.size, b.size, c.size
    w = 1.0 / ks.size
    y = np.zeros(x.size)
    R = np.zeros((x.size, P))
    for k in ks:
        j = edge_line[k]
        s = line_scale[j]
        for r in range(x.size):
            t = x[r] / _XS
            tp = t * t
            shape = 0.0
            R[r, k] += w
            R[r, K + j] += w * x[r]
            for i in range(nc):
                shape += c[i] * tp
                R[r, K + J + i] += w * s * tp
                tp *= t
            y[r] += w * (a[k] + b[j] * x[r] + s * shape)
    return y, R


@nb.njit(cache=True)
def _linear_rhs(t, w, zc, k_of, edge_line, scale, K, J, nc, nz, dy):  # pragma: no cover (numba)
    """``A^T W dy`` of the fit's design (columns ``a_k``, ``b_j t``, ``s_j t^p``, ``zc``)."""
    r = np.zeros(K + J + nc + nz)
    for i in range(t.size):
        k = k_of[i]
        j = edge_line[k]
        wi = w[i] * dy[i]
        r[k] += wi
        r[K + j] += wi * t[i]
        tp = t[i] * t[i]
        for c in range(nc):
            r[K + J + c] += wi * scale[j] * tp
            tp *= t[i]
        if nz:
            r[K + J + nc] += wi * zc[i]
    return r


@nb.njit(cache=True)
def _line_at(a, b, c, line_scale, edge_line, j, x):  # pragma: no cover (numba)
    """Line ``j``'s mean lateral position over its edges and its slope at ``x``."""
    t = x / _XS
    shape, dshape, tp = 0.0, 0.0, t
    for i in range(c.size):
        dshape += c[i] * (i + 2) * tp / _XS
        tp *= t
        shape += c[i] * tp
    s = line_scale[j]
    y, n = 0.0, 0
    for k in range(a.size):
        if edge_line[k] == j:
            y += a[k]
            n += 1
    return y / n + b[j] * x + s * shape, b[j] + s * dshape


@nb.njit(cache=True)
def _direction_of_two(a, b, c, line_scale, edge_line, cov, j0, j1, H, x0):  # pragma: no cover (numba)
    """:func:`lane_direction` of two lines, the same operations on numbers: ``(ok, d)``."""
    K = a.size
    rows = np.empty((2, 3))
    for q in range(2):
        j = j0 if q == 0 else j1
        yj, bj = _line_at(a, b, c, line_scale, edge_line, j, x0)
        n0, n1, n2 = H * bj, -H, x0 * bj - yj
        cjj = cov[K + j, K + j]
        sb = math.sqrt(0.0 if 0.0 > cjj else cjj)           # LaneModel.sigma_b (max as Python's)
        w = 1.0 / (math.sqrt(n0 * n0 + n1 * n1 + n2 * n2) * (1e-9 if 1e-9 > sb else sb))
        rows[q, 0], rows[q, 1], rows[q, 2] = n0 * w, n1 * w, n2 * w
    d = np.empty(3)
    d[0] = rows[0, 1] * rows[1, 2] - rows[0, 2] * rows[1, 1]
    d[1] = rows[0, 2] * rows[1, 0] - rows[0, 0] * rows[1, 2]
    d[2] = rows[0, 0] * rows[1, 1] - rows[0, 1] * rows[1, 0]
    nd = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    if nd == 0:
        return False, d
    d = d / nd
    if d[0] < 0:
        d = -d
    if not (math.isfinite(d[0]) and math.isfinite(d[1]) and math.isfinite(d[2])) or d[0] < 0.5:
        return False, d
    return True, d


@nb.njit(cache=True)
def _y_edges(a, b, c, line_scale, edge_line, ks, x):  # pragma: no cover (numba)
    """:meth:`LaneModel.y_edges`: numpy's array operations point by point, in numpy's order
    (one call instead of a dozen on arrays of a few cross-sections)."""
    shape = np.empty(x.size)
    for r in range(x.size):
        t = x[r] / _XS
        sh = 0.0
        tp = t * t
        for ci in c:
            sh = sh + ci * tp
            tp = tp * t
        shape[r] = sh
    out = np.empty((ks.size, x.size))
    for q in range(ks.size):
        k = ks[q]
        j = edge_line[k]
        for r in range(x.size):
            out[q, r] = a[k] + b[j] * x[r] + line_scale[j] * shape[r]
    return out


@nb.njit(cache=True)
def _dzeta_update(cov, a, b, c, dzeta, i, dzeta_prior, var_prior):  # pragma: no cover (numba)
    """The scalar Kalman update of :meth:`LaneModel.with_dzeta_prior`: ``(parameters, cov, gain)``,
    numpy's array operations element by element (``Ce / s``, ``p + g (d - dzeta)``,
    ``cov - outer(g, Ce)``)."""
    n = cov.shape[0]
    Ce = cov[:, i].copy()
    s = Ce[i] + var_prior
    g = Ce / s
    step = dzeta_prior - dzeta
    K, J, nc = a.size, b.size, c.size
    p = np.empty(n)
    p[:K] = a
    p[K:K + J] = b
    p[K + J:K + J + nc] = c
    p[K + J + nc] = dzeta
    for r in range(n):
        p[r] = p[r] + g[r] * step
    out = np.empty((n, n))
    for r in range(n):
        for q in range(n):
            out[r, q] = cov[r, q] - g[r] * Ce[q]
    return p, out, g


def sag_weight(x, height_m: float, x0_m: float, zeta_1_m: float):
    """``u^2 / (2 D)``, ``u = x - x0``, ``D = H - zeta u^2 / 2 + zeta u x`` (module docstring)."""
    x = np.asarray(x, float)
    return _sag_weight(np.ascontiguousarray(x.reshape(-1)), float(height_m), float(x0_m), float(zeta_1_m)).reshape(x.shape)


@nb.njit(cache=True)
def _sag_weight(x, H, x0, zeta):  # pragma: no cover (numba)
    out = np.empty(x.size)
    for i in range(x.size):
        u = x[i] - x0
        out[i] = u * u / (2.0 * (H - 0.5 * zeta * u * u + zeta * u * x[i]))
    return out


def fit_lane_model(xs: list[np.ndarray], ys: list[np.ndarray], edge_line, edge_side, shape_degree: int,
                   rows_per_m: float, *, select: bool = True, t_min: float = 3.0,
                   qs: list[np.ndarray] | None = None, sag: tuple[float, float, float] | None = None) -> LaneModel:
    """Weighted least squares of the joint model; with ``select``, straight lines when no shape
    term is significant (``|c| > t_min sigma_c``, from the highest down, on the inflated
    covariance), else the full ``shape_degree``.

    On a straight road the shape only adds variance to the tangent at the vehicle. On a curve
    the cubic term (a clothoid's changing curvature) is rarely significant on its own, yet
    leaving it out biases the tangent by up to 0.2 deg in a clothoid (measured on Table I
    scenario 2: yaw RMSE 0.056 deg with a term-by-term test, 0.039 deg keeping the cubic).

    ``sag = (H, x0, zeta)``: the points were projected onto the surface of vertical curvature
    ``zeta`` (:func:`vision.ipm.ground_from_rays`); the fit adds the column of ``dzeta`` (module
    docstring). It is kept whatever the shape selected.

    Parameters
    ----------
    xs, ys : lists of arrays
        Road coordinates of each edge's points, m.
    edge_line, edge_side : sequences of int
        Line index (0..J-1, left to right) and side (0 left, 1 right) of each edge.
    shape_degree : int
        Highest power of the common shape (1: straight lines, 2: + x^2, 3: + x^3).
    rows_per_m : float
        ``f_y H dx``: where samples stop being independent (``x^2`` beyond it); ``inf`` for
        points that are all independent.
    qs : list of arrays, optional
        Per point, the metres of lateral position per unit of measurement error (for cuts in the
        image, metres per pixel along the cut); the noise model is ``s_b^2 + s_i^2 q^2``.
        Default ``q = x``.
    """
    counts = np.array([len(xi) for xi in xs], np.int64)
    return fit_lane_model_points(np.concatenate(xs), np.concatenate(ys), counts, edge_line, edge_side, shape_degree,
                                 rows_per_m, select=select, t_min=t_min,
                                 q=None if qs is None else np.concatenate(qs), sag=sag)


def fit_lane_model_points(x: np.ndarray, y: np.ndarray, counts: np.ndarray, edge_line, edge_side,
                          shape_degree: int, rows_per_m: float, *, select: bool = True, t_min: float = 3.0,
                          q: np.ndarray | None = None, sag: tuple[float, float, float] | None = None) -> LaneModel:
    """:func:`fit_lane_model` of the points of all edges in one array, edge after edge
    (``counts[k]`` points of edge ``k``)."""
    pts = _Points(x, y, counts, edge_line, edge_side, q, sag)
    m = _fit(pts, shape_degree, rows_per_m)
    if not select or m.c.size == 0:
        return m
    full = m
    while m.c.size >= 1:
        i = m.a.size + m.b.size + m.c.size - 1
        if abs(m.c[-1]) > t_min * math.sqrt(max(float(m.cov[i, i]), 0.0)):
            break
        m = _fit(pts, m.c.size, rows_per_m)
    # A curve keeps its full shape: the rate of change of curvature (clothoid) is rarely
    # significant on its own, but leaving it out biases the tangent at the vehicle.
    return full if m.c.size >= 1 else m


class _Points:
    """The fit's data, prepared once for the fits of several shape degrees: coordinates,
    edge of each point, noise scale ``q`` (default ``x``), the vertical-curvature column's weight
    ``u^2 / (2 D)`` (:func:`sag_weight`) when ``sag = (H, x0, zeta)``, each edge's range."""

    def __init__(self, x, y, counts, edge_line, edge_side, q, sag) -> None:
        self.x = np.ascontiguousarray(x, np.float64)
        self.y = np.ascontiguousarray(y, np.float64)
        counts = np.asarray(counts, np.int64)
        self.K = counts.size
        self.edge_line = np.asarray(edge_line, np.int64)
        self.edge_side = np.asarray(edge_side, int)
        self.J = int(self.edge_line.max()) + 1
        if counts.min() < 1:
            raise VisionError("lane model is singular (an edge without points)")
        self.q = self.x if q is None else np.ascontiguousarray(q, np.float64)
        self.sag = None if sag is None else tuple(float(v) for v in sag)
        H, x0, zeta = self.sag if sag is not None else (1.0, 0.0, 0.0)
        self.k_of, self.z, self.x_min, self.x_max = _prepare(self.x, counts, sag is not None, H, x0, zeta)


@nb.njit(cache=True)
def _prepare(x, counts, has_sag, H, x0, zeta):  # pragma: no cover (numba)
    """Edge of each point, the sag column's weight (:func:`sag_weight`), each edge's range."""
    K = counts.size
    k_of = np.empty(x.size, np.int64)
    x_min = np.empty(K)
    x_max = np.empty(K)
    i = 0
    for k in range(K):
        lo, hi = np.inf, -np.inf
        for _ in range(counts[k]):
            k_of[i] = k
            lo, hi = min(lo, x[i]), max(hi, x[i])
            i += 1
        x_min[k], x_max[k] = lo, hi
    z = _sag_weight(x, H, x0, zeta) if has_sag else np.empty(0)
    return k_of, z, x_min, x_max


def _fit(pts: _Points, shape_degree: int, rows_per_m: float) -> LaneModel:
    """Weighted least squares of the joint model (module docstring) of degree ``shape_degree``
    (highest power of the common shape: 1 straight lines, 2 + x^2, 3 + x^3)."""
    K, J = pts.K, pts.J
    nc = max(0, shape_degree - 1)
    nz = 0 if pts.sag is None else 1
    if pts.x.size < K + J + nc + nz + 2:
        raise VisionError("too few edge points for the lane model")
    ok, p, cov, s2, scale, w, zc, Ai = _fit_core(pts.x, pts.y, pts.q, pts.z, pts.k_of, pts.edge_line, K, J, nc, nz,
                                                 float(min(rows_per_m, 1e300)))
    if not ok:
        raise VisionError("lane model is singular (an edge without points?)")
    m = LaneModel(p[:K], p[K:K + J], p[K + J:K + J + nc], cov, pts.edge_line, pts.edge_side, pts.x_min.copy(),
                  pts.x_max.copy(), math.sqrt(s2), int(pts.x.size), scale,
                  float(p[K + J + nc]) if nz else 0.0, pts.sag)
    m.linear = (pts.x, pts.y, pts.k_of, w, zc, Ai, nz)
    return m


@nb.njit(cache=True)
def _residuals(p, y, t, k_of, edge_line, scale, zc, K, J, nc, nz, out):  # pragma: no cover (numba)
    """``out = y - prediction`` of parameters ``p``, edge by edge (the points are in edge order)."""
    n = t.shape[0]
    dz = p[K + J + nc] if nz else 0.0
    i0 = 0
    while i0 < n:
        k = k_of[i0]
        i1 = i0
        while i1 < n and k_of[i1] == k:
            i1 += 1
        j = edge_line[k]
        a, b, s = p[k], p[K + j], scale[j]
        for m in range(i1 - i0):          # a loop from 0 over the edge's points
            i = i0 + m
            ti = t[i]
            tp = ti * ti
            shape = 0.0
            for c in range(nc):
                shape += p[K + J + c] * tp
                tp *= ti
            pred = a + b * ti + s * shape
            if nz:
                pred += dz * zc[i]
            out[i] = y[i] - pred
        i0 = i1


@nb.njit(cache=True)
def _zeta_column(p, y, t, z, k_of, edge_line, scale, zc, K, J, nc, first):  # pragma: no cover (numba)
    """``zc = z (y - x y')``: from the data's own ``y`` in the first pass, else from ``p``."""
    for i in range(t.shape[0]):
        if first:
            zc[i] = z[i] * y[i]
            continue
        k = k_of[i]
        j = edge_line[k]
        f = p[k]
        tp = t[i] * t[i]
        for c in range(nc):
            f -= scale[j] * (c + 1) * p[K + J + c] * tp
            tp *= t[i]
        zc[i] = z[i] * f


@nb.njit(cache=True)
def _spd_inverse(A, out):  # pragma: no cover (numba)
    """Inverse of the symmetric positive definite ``A`` into ``out`` by Cholesky (the normal
    equations are small, 9 to 15 unknowns: loops beat two LAPACK calls here). False when
    ``A`` is not positive definite (an edge or a line without points)."""
    n = A.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 1e-300 * max(1.0, abs(A[j, j])):
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            v = A[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k]
            L[i, j] = v / L[j, j]
    # inverse of L (lower triangular), then A^-1 = L^-T L^-1
    Li = np.zeros((n, n))
    for i in range(n):
        Li[i, i] = 1.0 / L[i, i]
        for j in range(i):
            v = 0.0
            for k in range(j, i):
                v -= L[i, k] * Li[k, j]
            Li[i, j] = v / L[i, i]
    for i in range(n):
        for j in range(i, n):
            v = 0.0
            for k in range(j, n):
                v += Li[k, i] * Li[k, j]
            out[i, j] = v
            out[j, i] = v
    return True


@nb.njit(cache=True)
def _normal_equations(t, y, w, zc, k_of, edge_line, scale, K, J, nc, nz, A, rhs):  # pragma: no cover (numba)
    """Adds the weighted normal equations of the fit's design to ``A`` (upper triangle) and ``rhs``.

    Row i has non-zeros only in the columns a_k, b_j, shape, dzeta of its edge k and line j:
    each edge's (m x m) block is accumulated densely, then added in at those columns. Up to two
    shape columns (``fit_degree`` <= 3) the block's sums are scalars, one independent chain each
    (the columns not fitted are 0 and their sums dropped): the same products added in the same
    order as in an array, 1.6 times faster (an array's sums wait on each other through memory)."""
    n = t.shape[0]
    m = 2 + nc + nz
    idx = np.zeros(m, np.int64)
    if nc > 2:
        _normal_equations_any(t, y, w, zc, k_of, edge_line, scale, K, J, nc, nz, A, rhs, idx)
        return
    # slot of each column among (1, t, s t^2, s t^3, zc)
    slot = np.zeros(m, np.int64)
    slot[1] = 1
    for c in range(nc):
        slot[2 + c] = 2 + c
    if nz:
        slot[m - 1] = 4
    S = np.zeros((5, 5))
    rs = np.zeros(5)
    i = 0
    while i < n:
        k = k_of[i]
        j = edge_line[k]
        sj = scale[j]
        _block_index(idx, k, j, K, J, nc, nz)
        s00 = s01 = s02 = s03 = s04 = s11 = s12 = s13 = s14 = s22 = s23 = s24 = s33 = s34 = s44 = 0.0
        r0 = r1 = r2 = r3 = r4 = 0.0
        while i < n and k_of[i] == k:
            wi = w[i]
            yi = y[i]
            c1 = t[i]
            tp = t[i] * t[i]
            c2 = 0.0
            c3 = 0.0
            if nc >= 1:
                c2 = sj * tp
                tp *= t[i]
            if nc >= 2:
                c3 = sj * tp
            c4 = zc[i] if nz else 0.0
            w0 = wi * 1.0
            w1 = wi * c1
            w2 = wi * c2
            w3 = wi * c3
            w4 = wi * c4
            r0 += w0 * yi
            r1 += w1 * yi
            r2 += w2 * yi
            r3 += w3 * yi
            r4 += w4 * yi
            s00 += w0 * 1.0
            s01 += w0 * c1
            s02 += w0 * c2
            s03 += w0 * c3
            s04 += w0 * c4
            s11 += w1 * c1
            s12 += w1 * c2
            s13 += w1 * c3
            s14 += w1 * c4
            s22 += w2 * c2
            s23 += w2 * c3
            s24 += w2 * c4
            s33 += w3 * c3
            s34 += w3 * c4
            s44 += w4 * c4
            i += 1
        S[0, 0], S[0, 1], S[0, 2], S[0, 3], S[0, 4] = s00, s01, s02, s03, s04
        S[1, 1], S[1, 2], S[1, 3], S[1, 4] = s11, s12, s13, s14
        S[2, 2], S[2, 3], S[2, 4] = s22, s23, s24
        S[3, 3], S[3, 4] = s33, s34
        S[4, 4] = s44
        rs[0], rs[1], rs[2], rs[3], rs[4] = r0, r1, r2, r3, r4
        for u in range(m):
            rhs[idx[u]] += rs[slot[u]]
            for v in range(u, m):   # the upper triangle: idx is increasing
                A[idx[u], idx[v]] += S[slot[u], slot[v]]


@nb.njit(cache=True, inline="always")
def _block_index(idx, k, j, K, J, nc, nz):  # pragma: no cover (numba)
    """The unknowns of one edge's block of the normal equations: its offset ``k``, its line's
    ``K + j``, the shape columns, the vertical curvature's last."""
    idx[0] = k
    idx[1] = K + j
    for c in range(nc):
        idx[2 + c] = K + J + c
    if nz:
        idx[idx.size - 1] = K + J + nc


@nb.njit(cache=True)
def _normal_equations_any(t, y, w, zc, k_of, edge_line, scale, K, J, nc, nz, A, rhs, idx):  # pragma: no cover (numba)
    """:func:`_normal_equations` for any number of shape columns, the block in an array."""
    n = t.shape[0]
    m = 2 + nc + nz
    col = np.zeros(m)
    Ab = np.zeros((m, m))
    rb = np.zeros(m)
    i = 0
    while i < n:
        k = k_of[i]
        j = edge_line[k]
        sj = scale[j]
        _block_index(idx, k, j, K, J, nc, nz)
        Ab[:, :] = 0.0
        rb[:] = 0.0
        col[0] = 1.0
        while i < n and k_of[i] == k:
            wi = w[i]
            yi = y[i]
            col[1] = t[i]
            tp = t[i] * t[i]
            for c in range(nc):
                col[2 + c] = sj * tp
                tp *= t[i]
            if nz:
                col[m - 1] = zc[i]
            for u in range(m):
                wu = wi * col[u]
                rb[u] += wu * yi
                for v in range(u, m):
                    Ab[u, v] += wu * col[v]
            i += 1
        for u in range(m):
            rhs[idx[u]] += rb[u]
            for v in range(u, m):   # the upper triangle: idx is increasing
                A[idx[u], idx[v]] += Ab[u, v]


@nb.njit(cache=True)
def _fit_core(x, y, q, z, k_of, edge_line, K, J, nc, nz, rows_per_m):  # pragma: no cover (numba)
    """Two passes of weighted normal equations; returns ``(ok, p, cov, s2, line_scale, w, zc,
    Ai)``, the last three the second pass's weights, vertical-curvature column and inverse
    normal matrix (per ``t = x / 10`` for the slopes: :meth:`LaneModel.linear_response`).

    Pass 1: weights ``indep(x)``. Pass 2: ``indep(x) / var(x)`` with ``var = s_b^2 + s_i^2 x^2``
    fitted to pass 1's squared residuals, and the shape columns of line ``j`` scaled by
    ``1 / (1 - kappa0 a_j)`` (concentric lines). Slopes and the shape use ``t = x / 10``.
    With ``nz = 1`` the last parameter is ``dzeta``, column ``z (y - x y')`` (module docstring).
    """
    n = x.shape[0]
    P = K + J + nc + nz
    t = x / 10.0
    indep = np.empty(n)
    for i in range(n):
        indep[i] = 1.0 / max(1.0, x[i] * x[i] / max(rows_per_m, 1e-9))
    w = indep.copy()
    scale = np.ones(J)
    p = np.zeros(P)
    Ai = np.zeros((P, P))
    zc = np.zeros(n)
    res = np.empty(n)
    if nz:
        _zeta_column(p, y, t, z, k_of, edge_line, scale, zc, K, J, nc, True)
    for npass in range(2):
        if npass == 1:
            # residuals of pass 1 -> variance model and concentric scale
            g00 = 0.0
            g01 = 0.0
            g11 = 0.0
            b0 = 0.0
            b1 = 0.0
            mr2 = 0.0
            _residuals(p, y, t, k_of, edge_line, scale, zc, K, J, nc, nz, res)
            for i in range(n):
                r = res[i]
                g0 = indep[i]
                g1 = indep[i] * q[i] * q[i]
                rr = indep[i] * r * r
                g00 += g0 * g0
                g01 += g0 * g1
                g11 += g1 * g1
                b0 += g0 * rr
                b1 += g1 * rr
                mr2 += r * r
            det = g00 * g11 - g01 * g01
            sb = (g11 * b0 - g01 * b1) / det if det != 0.0 else b0 / max(g00, 1e-300)
            si = (g00 * b1 - g01 * b0) / det if det != 0.0 else 0.0
            floor = 1e-8 + 1e-3 * mr2 / n
            for i in range(n):
                var = max(sb, floor) + max(si, 0.0) * q[i] * q[i]
                w[i] = indep[i] / var
            # Outliers (beyond 4 sigma of the noise model) get no weight in the second pass.
            for i in range(n):
                if res[i] * res[i] * w[i] > 16.0 * indep[i]:
                    w[i] = 0.0
            if nc > 0:
                kappa0 = 2.0 * p[K + J] / 100.0
                for j in range(J):
                    sa = 0.0
                    ca = 0
                    for k in range(K):
                        if edge_line[k] == j:
                            sa += p[k]
                            ca += 1
                    a_line = sa / max(ca, 1)
                    scale[j] = 1.0 / min(max(1.0 - kappa0 * a_line, 0.5), 2.0)
            if nz:
                _zeta_column(p, y, t, z, k_of, edge_line, scale, zc, K, J, nc, False)
        wm = w.mean()
        for i in range(n):
            w[i] /= wm
        A = np.zeros((P, P))
        rhs = np.zeros(P)
        _normal_equations(t, y, w, zc, k_of, edge_line, scale, K, J, nc, nz, A, rhs)
        for u in range(P):
            for v in range(u):
                A[u, v] = A[v, u]
        ok = _spd_inverse(A, Ai)
        if not ok:
            return False, p, Ai, 0.0, scale, w, zc, Ai
        p = Ai @ rhs
    # residuals, variance, lag-1 autocorrelation along each edge
    _residuals(p, y, t, k_of, edge_line, scale, zc, K, J, nc, nz, res)
    rw = np.empty(n)
    for i in range(n):
        rw[i] = res[i] * math.sqrt(w[i])
    den = 0.0
    for i in range(n):
        den += rw[i] * rw[i]
    num = 0.0
    for i in range(1, n):
        if k_of[i] == k_of[i - 1]:
            num += rw[i] * rw[i - 1]
    s2 = den / max(1, n - P)
    rho = min(max(num / den, 0.0), 0.98) if den > 0 else 0.0
    cov = Ai * s2 * (1.0 + rho) / (1.0 - rho)
    # slopes were fitted per t = x / 10: back to per metre
    for j in range(J):
        p[K + j] /= 10.0
        for q_ in range(P):
            cov[K + j, q_] /= 10.0
            cov[q_, K + j] /= 10.0
    return True, p, cov, s2, scale, w, zc, Ai


def lane_direction(model: LaneModel, height_m: float, lines=None, x0_m: float = 0.0) -> np.ndarray | None:
    """Common direction of the lane lines at the vehicle (``x = x0``, the contact point) in the
    current road frame (unit, forward).

    Each line's tangent at ``x0`` (through ``(x0, y_j, -H)``, direction ``(1, y'_j, 0)``: the road
    touches the plane ``z = -H`` there) and the optical centre span a plane with normal
    ``n_j = (H y'_j, -H, x0 y'_j - y_j)``; the lane direction is orthogonal to all of them
    (weighted by the inverse 1-sigma of the line's slope; least squares for three lines).
    Returns None when the normals do not determine it.
    """
    J = model.n_lines
    lines = range(J) if lines is None else lines
    x0_m = float(x0_m)
    if len(lines) == 2:
        ok, d = _direction_of_two(model.a, model.b, model.c, model.line_scale, model.edge_line, model.cov,
                                  int(lines[0]), int(lines[1]), float(height_m), x0_m)
        return d if ok else None
    rows = []
    for j in lines:
        yj, bj = _line_at(model.a, model.b, model.c, model.line_scale, model.edge_line, int(j), x0_m)
        n = (height_m * bj, -height_m, x0_m * bj - yj)
        w = 1.0 / (math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]) * max(model.sigma_b(j), 1e-9))
        rows.append((n[0] * w, n[1] * w, n[2] * w))
    if len(rows) < 2:
        return None
    if len(rows) == 2:
        a, b = rows
        d = np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])
        nd = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if nd == 0:
            return None
        d = d / nd
    else:
        _, _, vt = np.linalg.svd(np.asarray(rows))
        d = vt[-1]
    if d[0] < 0:
        d = -d
    if not (math.isfinite(d[0]) and math.isfinite(d[1]) and math.isfinite(d[2])) or d[0] < 0.5:
        return None
    return d
