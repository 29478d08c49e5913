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

Weights: a BEV row far away re-samples the same image row many times and the lateral error of an
image pixel grows with the distance, so each point ``i`` gets the weight
``1 / (x_i^2 max(1, x_i^2 / (f_y H dx)))`` (``f_y H / x^2`` image rows per metre of road,
``1 / dx`` BEV rows per metre): the far points count as the independent samples they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import VisionError

__all__ = ["LaneModel", "fit_lane_model", "lane_direction"]

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

    def __post_init__(self) -> None:
        if self.line_scale is None:
            self.line_scale = np.ones(self.b.size)

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

    def y(self, k: int, x):
        """Lateral position of edge ``k`` at ``x``, m."""
        j = self.edge_line[k]
        return self.a[k] + self.b[j] * np.asarray(x, float) + self.line_scale[j] * self._shape(x)

    def slope(self, j: int, x):
        return self.b[j] + self.line_scale[j] * self._shape_d(x, 1)

    def curvature(self, j: int, x) -> float:
        """Curvature of line ``j`` at ``x``, 1/m, positive turning left."""
        s1 = float(self.slope(j, x))
        return self.line_scale[j] * float(self._shape_d(x, 2)) / (1.0 + s1 * s1) ** 1.5

    def _row(self, k: int, x):
        x = np.atleast_1d(np.asarray(x, float))
        K, J = self.n_edges, self.n_lines
        R = np.zeros((x.size, K + J + self.c.size))
        R[:, k] = 1.0
        R[:, K + self.edge_line[k]] = x
        for i in range(self.c.size):
            R[:, K + J + i] = self.line_scale[self.edge_line[k]] * (x / _XS) ** (i + 2)
        return R

    def sigma_y(self, k: int, x) -> np.ndarray:
        """1-sigma of ``y(k, x)``, m."""
        R = self._row(k, x)
        return np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", R, self.cov, R), 0.0))

    def sigma_b(self, j: int) -> float:
        i = self.n_edges + j
        return float(np.sqrt(max(self.cov[i, i], 0.0)))


def fit_lane_model(xs: list[np.ndarray], ys: list[np.ndarray], edge_line, edge_side, shape_degree: int,
                   rows_per_m: float, *, select: bool = True, t_min: float = 3.0) -> LaneModel:
    """Weighted least squares of the joint model; with ``select``, the highest shape term is
    kept only when it is significant (``|c| > t_min sigma_c``), else the degree is lowered.

    A cubic term follows a clothoid's changing curvature, but on a straight or circular road it
    only adds variance to the tangent at the vehicle (model selection by a t-test).
    """
    m = _fit(xs, ys, edge_line, edge_side, shape_degree, rows_per_m)
    while select and m.c.size >= 2:
        i = m.a.size + m.b.size + m.c.size - 1
        if abs(m.c[-1]) > t_min * np.sqrt(max(m.cov[i, i], 0.0)):
            break
        m = _fit(xs, ys, edge_line, edge_side, m.c.size, rows_per_m)
    return m


def _fit(xs: list[np.ndarray], ys: list[np.ndarray], edge_line, edge_side, shape_degree: int,
         rows_per_m: float) -> LaneModel:
    """Weighted least squares of the joint model (module docstring).

    Parameters
    ----------
    xs, ys : lists of arrays
        Road coordinates of each edge's points, m.
    edge_line, edge_side : sequences of int
        Line index (0..J-1, left to right) and side (0 left, 1 right) of each edge.
    shape_degree : int
        Highest power of the common shape (1: straight lines, 2: + x^2, 3: + x^3).
    rows_per_m : float
        ``f_y H``: image rows per metre of road at 1 m (``f_y H / x^2`` at ``x``) over BEV rows per
        metre, i.e. ``f_y H dx``: where samples stop being independent.
    """
    K = len(xs)
    edge_line = np.asarray(edge_line, int)
    J = int(edge_line.max()) + 1
    nc = max(0, shape_degree - 1)
    x = np.concatenate(xs)
    y = np.concatenate(ys)
    if x.size < K + J + nc + 2:
        raise VisionError("too few edge points for the lane model")
    k_of = np.concatenate([np.full(len(xi), k) for k, xi in enumerate(xs)])
    X = np.zeros((x.size, K + J + nc))
    X[np.arange(x.size), k_of] = 1.0
    X[np.arange(x.size), K + edge_line[k_of]] = x
    shape_cols = np.stack([(x / _XS) ** (i + 2) for i in range(nc)], axis=1) if nc else np.zeros((x.size, 0))
    X[:, K + J:] = shape_cols
    x2 = np.maximum(x * x, 1.0)
    w = 1.0 / (x2 * np.maximum(1.0, x2 / max(rows_per_m, 1e-9)))
    w = w / w.mean()
    for concentric in (False, True):
        if concentric:
            # Lines are concentric: a line offset by a from the camera has curvature
            # kappa0 / (1 - kappa0 a); scale its shape columns accordingly (second pass).
            kappa0 = 2.0 * p[K + J] / _XS**2 if nc else 0.0
            a_line = np.array([p[:K][edge_line == j].mean() for j in range(J)])
            scale = 1.0 / np.clip(1.0 - kappa0 * a_line, 0.5, 2.0)
            if nc == 0 or np.all(np.abs(scale - 1.0) < 1e-6):
                break
            X[:, K + J:] = shape_cols * scale[edge_line[k_of]][:, None]
        Xw = X * w[:, None]
        A = X.T @ Xw
        try:
            Ai = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            raise VisionError("lane model is singular (an edge without points?)") from None
        p = Ai @ (Xw.T @ y)
    line_scale = scale if nc and concentric else np.ones(J)
    r = y - X @ p
    dof = max(1, x.size - p.size)
    s2 = float((w * r * r).sum() / dof)
    cov = Ai * s2
    x_min = np.array([float(xi.min()) for xi in xs])
    x_max = np.array([float(xi.max()) for xi in xs])
    return LaneModel(p[:K], p[K:K + J], p[K + J:], cov, edge_line, np.asarray(edge_side, int), x_min, x_max,
                     float(np.sqrt(s2)), int(x.size), line_scale)


def lane_direction(model: LaneModel, height_m: float, x0: float = 0.0, lines=None) -> np.ndarray | None:
    """Common direction of the lane lines at ``x0`` in the current road frame (unit, forward).

    Each line's tangent at ``x0`` and the optical centre span a plane with normal
    ``n_j = (x0, y_j, -H) x (1, y'_j, 0)``; the lane direction is orthogonal to all of them
    (weighted by the inverse 1-sigma of the line's slope; least squares for three lines).
    Returns None when the normals do not determine it.
    """
    J = model.n_lines
    lines = range(J) if lines is None else lines
    rows = []
    for j in lines:
        ks = np.flatnonzero(model.edge_line == j)
        yj = float(np.mean([model.y(k, x0) for k in ks]))
        bj = float(model.slope(j, x0))
        n = np.cross(np.array([x0, yj, -height_m]), np.array([1.0, bj, 0.0]))
        n /= np.linalg.norm(n)
        rows.append(n / max(model.sigma_b(j), 1e-9))
    N = np.asarray(rows)
    if N.shape[0] < 2:
        return None
    _, _, vt = np.linalg.svd(N)
    d = vt[-1]
    if d[0] < 0:
        d = -d
    if not np.all(np.isfinite(d)) or d[0] < 0.5:
        return None
    return d
