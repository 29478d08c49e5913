"""Road geometry: a reference line made of clothoids, with bank and grade, as a ruled surface.

The reference line is the road's centre (the dashed centre marking). It is a chain of segments;
along each one the curvature changes linearly with the horizontal station ``s`` (a clothoid;
equal end curvatures give an arc or a straight), its slope eased in and out over ``EASE_M`` at
each end of a transition (:func:`ease`). A plain clothoid's curvature has a corner at each
joint, which a vehicle following the road turns into a step of its roll rate (a motorcycle's
lean follows the curvature) and, off the centre line, of its longitudinal acceleration: the
simulated IMU then showed a one-sample specific-force spike at every joint (12 m/s^2 sideways
at 90 km/h, 28 on a 40 deg lean) and a pitch-rate step, which no rider or suspension makes.
The grade ``dz/ds`` and the bank follow
septic smoothsteps (C3) from the previous segment's end values, so that the vertical
acceleration of a path off the centre line stays continuous (a plain cubic bank runoff makes a
motorcycle's lean jump by ~0.2 deg where the runoff ends). Coordinates: world ``w`` is east-north-up with the road
starting at the origin heading east.

The surface is ``S(s, d) = C(s) + d * y_ref(s)`` with ``C`` the 3-D reference line and
``y_ref = Rz(theta) Ry(-atan(grade)) Rx(bank) e_y`` the road's lateral axis; ``d`` is the
lateral offset, positive to the left. Markings sit at constant ``d``.

The geometry is tabulated at nodes every ``STEP_M`` (and at every segment start). The truth
(trajectory, tests) evaluates it exactly from the node below: heading, grade and bank are
polynomials, the position is a Gauss-Legendre integral of the heading. The renderer's njit
kernel uses Taylor series from the same nodes (position to u^4, 1e-9 m or better on the bundled
scenarios' centre lines; lateral axis to u^2, about 1e-8): the pictures and the truth agree to
far below a micro-pixel. (On segments under 10 m the eases fall inside a node interval, which the
quartic cannot follow: a 0.5 m transition to 1/5 m was off by 3.5e-4 m, a review measured.)

The renderer's kernels inline :func:`eval_surface` into ``render.py``'s compiled code, and
numba's on-disk cache checks only the calling module's file: after editing this file, delete
``tools/drivesim/__pycache__/*.nbi`` and ``*.nbc`` (and ``tools/__pycache__``'s) or the old
surface is rendered.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

__all__ = ["EASE_M", "Segment", "Road", "STEP_M", "ease"]

STEP_M = 0.25
#: Length over which a transition's curvature slope eases in and out at each end, m (half the
#: segment when it is shorter than two of them): 0.18 s at 100 km/h, the time a rider takes to
#: build the lean rate up rather than at once.
EASE_M = 5.0

# Node table columns.
(S, CX, CY, CZ, TH, K, DK, G, DG,
 YX, YY, YZ, Y1X, Y1Y, Y1Z, Y2X, Y2Y, Y2Z, BANK, DDK, NCOL) = range(21)


@dataclass(frozen=True)
class Segment:
    """One piece of road.

    Parameters
    ----------
    length_m : float
        Horizontal length, m.
    curvature_1_m : float
        Curvature at the segment's end, 1/m, positive turning left; it changes linearly from the
        previous segment's end value (a clothoid, its slope eased over ``EASE_M`` at each end:
        :func:`ease`), so a constant-curvature arc needs a transition segment before it.
    bank_deg : float
        Bank at the segment's end, deg, positive raising the left edge; septic smoothstep from
        the previous end value.
    grade_pct : float
        Grade ``100 dz/ds`` at the segment's end, %; septic smoothstep from the previous end value.
    """

    length_m: float
    curvature_1_m: float = 0.0
    bank_deg: float = 0.0
    grade_pct: float = 0.0


def _lateral_axis(th, g, b):
    """``Rz(th) Ry(p) Rx(b) e_y`` with ``p = -atan(g)``."""
    p = -np.arctan(g)
    cth, sth, cp, sp, cb, sb = np.cos(th), np.sin(th), np.cos(p), np.sin(p), np.cos(b), np.sin(b)
    return np.stack([cth * sp * sb - sth * cb, sth * sp * sb + cth * cb, cp * sb], axis=-1)


def smooth7(x):
    """Septic smoothstep ``35x^4 - 84x^5 + 70x^6 - 20x^7``, clipped to [0, 1]: C3 at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return x**4 * (35.0 + x * (-84.0 + x * (70.0 - 20.0 * x)))


def _smooth7_integral(x):
    """Integral of :func:`smooth7` from 0 to x, for x in [0, 1]."""
    return x**5 * (7.0 + x * (-14.0 + x * (10.0 - 2.5 * x)))


def _smooth7_integral2(x):
    """Integral of :func:`_smooth7_integral` from 0 to x, for x in [0, 1] (5/36 at 1)."""
    return x**6 * (7.0 / 6.0 + x * (-2.0 + x * (1.25 - 5.0 / 18.0 * x)))


def ease(x, a):
    """A transition's shape along it, ``x = u / L``, with its slope eased over ``a`` of it at each end.

    Returns ``(H, J, p, dp)``: ``H`` goes from 0 to 1 (the curvature is ``k0 + (k1 - k0) H``),
    ``J`` is its integral from 0 (the heading's part, 1/2 at the end as a plain clothoid's),
    ``p = dH/dx`` and ``dp`` its derivative. ``p`` is ``1 / (1 - a)`` in the middle and rises to
    it from 0 along a septic smoothstep (C3) over ``[0, a]``, falling symmetrically over
    ``[1 - a, 1]``, ``0 < a <= 1/2``. Outside ``[0, 1]`` the curvature holds its end value
    (``J`` continues linearly after 1).
    """
    x = np.asarray(x, dtype=float)
    c = 1.0 / (1.0 - a)
    xc = np.clip(x, 0.0, 1.0)
    y1, y3 = np.clip(xc / a, 0.0, 1.0), np.clip((1.0 - xc) / a, 0.0, 1.0)
    ja = c * a * a * 5.0 / 36.0                           # J(a)
    j_1a = ja + c * (1.0 - a) * (1.0 - 2.0 * a) / 2       # J(1 - a)
    first, last = xc < a, xc > 1.0 - a
    H = np.where(first, c * a * _smooth7_integral(y1),
                 np.where(last, 1.0 - c * a * _smooth7_integral(y3), c * (xc - a / 2)))
    J = np.where(first, c * a * a * _smooth7_integral2(y1),
                 np.where(last, j_1a + (xc - 1.0 + a) - (ja - c * a * a * _smooth7_integral2(y3)),
                          ja + c * ((xc - a / 2) ** 2 - a * a / 4) / 2))
    J = J + np.maximum(x - 1.0, 0.0)
    inside = (x >= 0.0) & (x <= 1.0)
    p = np.where(inside, np.where(first, c * smooth7(y1), np.where(last, c * smooth7(y3), c)), 0.0)
    ds1, ds3 = 140.0 * (y1 * (1.0 - y1)) ** 3, 140.0 * (y3 * (1.0 - y3)) ** 3
    dp = np.where(inside, np.where(first, c / a * ds1, np.where(last, -c / a * ds3, 0.0)), 0.0)
    return H, J, p, dp


# Per-segment parameters of the exact evaluation.
(G_S0, G_L, G_TH0, G_K0, G_K1, G_A, G_B0, G_B1, G_GR0, G_GR1, G_Z0) = range(11)


class Road:
    """A tabulated road; see the module docstring for the model."""

    def __init__(self, segments: list[Segment], start_curvature_1_m: float = 0.0,
                 start_bank_deg: float = 0.0, start_grade_pct: float = 0.0) -> None:
        if not segments:
            raise ValueError("a road needs at least one segment")
        self.segments = tuple(segments)
        seg_rows, s0, th0, z0 = [], 0.0, 0.0, 0.0
        k0, b0, g0 = start_curvature_1_m, math.radians(start_bank_deg), start_grade_pct / 100.0
        for seg in segments:
            L = float(seg.length_m)
            if not L > 0:
                raise ValueError(f"segment length must be > 0 m, got {L}")
            k1, b1, g1 = seg.curvature_1_m, math.radians(seg.bank_deg), seg.grade_pct / 100.0
            seg_rows.append((s0, L, th0, k0, k1, min(EASE_M / L, 0.5), b0, b1, g0, g1, z0))
            th0 += k0 * L + 0.5 * (k1 - k0) * L   # ease's J(1) = 1/2, as a plain clothoid's
            z0 += g0 * L + (g1 - g0) * L * _smooth7_integral(1.0)
            s0, k0, b0, g0 = s0 + L, k1, b1, g1
        self.length_m = s0
        self._seg = np.array(seg_rows)

        # Nodes every STEP_M within each segment; positions by Gauss-Legendre between nodes.
        s_nodes = np.concatenate([r[G_S0] + np.arange(max(1, int(math.ceil(r[G_L] / STEP_M - 1e-9)))) * STEP_M
                                  for r in self._seg])
        tab = np.zeros((len(s_nodes), NCOL))
        tab[:, S] = s_nodes
        xs, ys = [0.0], [0.0]
        for a, b in zip(s_nodes[:-1], s_nodes[1:]):
            dx, dy = self._xy_increment(np.array([a]), np.array([b - a]))
            xs.append(xs[-1] + dx[0])
            ys.append(ys[-1] + dy[0])
        tab[:, CX], tab[:, CY] = xs, ys
        tab[:, CZ] = self._z(s_nodes)
        tab[:, TH] = self.heading_rad(s_nodes)
        tab[:, K], tab[:, DK], tab[:, DDK] = self._curvature_and_slopes(s_nodes)
        tab[:, G] = self.grade(s_nodes)
        e = 1e-3
        tab[:, DG] = (self.grade(s_nodes + e) - self.grade(s_nodes - e)) / (2 * e)
        tab[:, BANK] = self.bank_rad(s_nodes)
        # Lateral axis and its first two s-derivatives by central differences of the exact
        # expression (table building only; 1e-9 relative).
        ya, y0_, yb = (self.lateral_axis(s_nodes + du) for du in (-e, 0.0, e))
        tab[:, YX:YZ + 1] = y0_
        tab[:, Y1X:Y1Z + 1] = (yb - ya) / (2 * e)
        tab[:, Y2X:Y2Z + 1] = (yb - 2 * y0_ + ya) / e**2
        self.table = np.ascontiguousarray(tab)

    def _seg_index(self, s):
        return np.clip(np.searchsorted(self._seg[:, G_S0], np.asarray(s, dtype=float), side="right") - 1,
                       0, len(self._seg) - 1)

    def _xy_increment(self, s_from, length):
        """Exact ``(dx, dy)`` from ``s_from`` over ``length`` (within one segment), 8-point
        Gauss-Legendre of the heading polynomial: exact to machine precision for |length| <= STEP_M."""
        nodes, weights = np.polynomial.legendre.leggauss(8)
        tau = s_from[..., None] + (length[..., None] / 2.0) * (1.0 + nodes)
        th = self.heading_rad(tau)
        return ((length / 2.0) * (weights * np.cos(th)).sum(-1),
                (length / 2.0) * (weights * np.sin(th)).sum(-1))

    # ---- exact vectorised evaluation (numpy: trajectory, truth, tests) ----

    def _node(self, s):
        s = np.asarray(s, dtype=float)
        i = np.clip(np.searchsorted(self.table[:, S], s, side="right") - 1, 0, len(self.table) - 1)
        return i, s - self.table[i, S]

    def _seg_u(self, s):
        s = np.asarray(s, dtype=float)
        i = self._seg_index(s)
        return self._seg[i], s - self._seg[i, G_S0]

    def centerline(self, s):
        """Reference line ``C(s)`` ``(..., 3)``, exact: Gauss-Legendre from the node below."""
        i, u = self._node(s)
        dx, dy = self._xy_increment(self.table[i, S], u)
        return np.stack([self.table[i, CX] + dx, self.table[i, CY] + dy, self._z(s)], axis=-1)

    def heading_rad(self, s):
        g, u = self._seg_u(s)
        L = g[..., G_L]
        _, J, _, _ = ease(u / L, g[..., G_A])
        return g[..., G_TH0] + g[..., G_K0] * u + (g[..., G_K1] - g[..., G_K0]) * L * J

    def _curvature_and_slopes(self, s):
        """Curvature (1/m) and its first two derivatives along ``s`` (1/m^2, 1/m^3)."""
        g, u = self._seg_u(s)
        L, dk = g[..., G_L], g[..., G_K1] - g[..., G_K0]
        H, _, p, dp = ease(u / L, g[..., G_A])
        return g[..., G_K0] + dk * H, dk / L * p, dk / L**2 * dp

    def curvature_1_m(self, s):
        return self._curvature_and_slopes(s)[0]

    def grade(self, s):
        """``dz/ds`` of the reference line: septic smoothstep between segment end values."""
        g, u = self._seg_u(s)
        return g[..., G_GR0] + (g[..., G_GR1] - g[..., G_GR0]) * smooth7(u / g[..., G_L])

    def _z(self, s):
        g, u = self._seg_u(s)
        L = g[..., G_L]
        x = np.clip(u / L, 0.0, 1.0)
        return (g[..., G_Z0] + g[..., G_GR0] * u
                + (g[..., G_GR1] - g[..., G_GR0]) * (L * _smooth7_integral(x) + np.maximum(u - L, 0.0)))

    def bank_rad(self, s):
        """Bank of the reference line at station ``s``, rad: septic smoothstep between segment
        end values, so that the vertical acceleration of an offset path stays continuous."""
        g, u = self._seg_u(s)
        return g[..., G_B0] + (g[..., G_B1] - g[..., G_B0]) * smooth7(u / g[..., G_L])

    def lateral_axis(self, s):
        """``y_ref(s)``, unit, ``(..., 3)``."""
        return _lateral_axis(self.heading_rad(s), self.grade(s), self.bank_rad(s))

    def surface(self, s, d):
        """Exact surface points ``S(s, d)`` ``(..., 3)``."""
        d = np.asarray(d, dtype=float)
        return self.centerline(s) + d[..., None] * self.lateral_axis(s)

    def frame(self, s, d, eps_m: float = 1e-3):
        """Local road frames ``R_w_from_o`` ``(..., 3, 3)`` at surface points ``(s, d)``.

        x along ``dS/ds`` (parallel to the markings), y along ``dS/dd`` (the lateral axis),
        z = x cross y, the surface normal, up. ``dS/ds`` by a central difference of the exact
        surface (1e-8 rad).
        """
        s = np.asarray(s, dtype=float)
        y = self.lateral_axis(s)
        x = (self.surface(s + eps_m, d) - self.surface(s - eps_m, d)) / (2 * eps_m)
        z = np.cross(x, y)
        z /= np.linalg.norm(z, axis=-1, keepdims=True)
        x = np.cross(y, z)
        return np.stack([x, y, z], axis=-1)

    def surface_taylor(self, s, d):
        """Surface points as the renderer computes them (node Taylor series), for tests."""
        s = np.asarray(s, dtype=float)
        d = np.broadcast_to(np.asarray(d, dtype=float), s.shape)
        P = np.empty(s.shape + (3,))
        _surface_many(self.table, s.ravel(), np.ascontiguousarray(d).ravel(), P.reshape(-1, 3))
        return P


@nb.njit(cache=True, inline="always")
def node_index(tab, s):
    """Index of the last node at or before ``s`` (clamped to the table)."""
    lo, hi = 0, tab.shape[0] - 1
    if s <= tab[0, S]:
        return 0
    if s >= tab[hi, S]:
        return hi
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        if tab[mid, S] <= s:
            lo = mid
        else:
            hi = mid
    return lo


@nb.njit(cache=True, inline="always")
def eval_surface(tab, i, s, d):
    """Surface point ``S(s, d)`` and partials ``S_s``, ``S_d`` from node ``i``.

    Returns ``(px, py, pz, sx, sy, sz, dx, dy, dz)``.
    """
    u = s - tab[i, S]
    th, k, dk, ddk = tab[i, TH], tab[i, K], tab[i, DK], tab[i, DDK]
    c, sn = math.cos(th), math.sin(th)
    # C' = (cos th, sin th), C'' = k (-sin, cos), C''' = dk (-sin, cos) - k^2 (cos, sin),
    # C'''' = ddk (-sin, cos) - 3 k dk (cos, sin) + k^3 (sin, -cos)
    a2x, a2y = -k * sn, k * c
    a3x, a3y = -dk * sn - k * k * c, dk * c - k * k * sn
    a4x = -ddk * sn - 3.0 * k * dk * c + k * k * k * sn
    a4y = ddk * c - 3.0 * k * dk * sn - k * k * k * c
    u2, u3 = u * u, u * u * u
    px = tab[i, CX] + c * u + a2x * u2 / 2.0 + a3x * u3 / 6.0 + a4x * u2 * u2 / 24.0
    py = tab[i, CY] + sn * u + a2y * u2 / 2.0 + a3y * u3 / 6.0 + a4y * u2 * u2 / 24.0
    g, dg = tab[i, G], tab[i, DG]
    pz = tab[i, CZ] + g * u + 0.5 * dg * u2
    tx = c + a2x * u + a3x * u2 / 2.0 + a4x * u3 / 6.0
    ty = sn + a2y * u + a3y * u2 / 2.0 + a4y * u3 / 6.0
    tz = g + dg * u
    yx = tab[i, YX] + tab[i, Y1X] * u + 0.5 * tab[i, Y2X] * u2
    yy = tab[i, YY] + tab[i, Y1Y] * u + 0.5 * tab[i, Y2Y] * u2
    yz = tab[i, YZ] + tab[i, Y1Z] * u + 0.5 * tab[i, Y2Z] * u2
    y1x = tab[i, Y1X] + tab[i, Y2X] * u
    y1y = tab[i, Y1Y] + tab[i, Y2Y] * u
    y1z = tab[i, Y1Z] + tab[i, Y2Z] * u
    return (px + d * yx, py + d * yy, pz + d * yz,
            tx + d * y1x, ty + d * y1y, tz + d * y1z,
            yx, yy, yz)


@nb.njit(cache=True)
def _surface_many(tab, s, d, P):
    for n in range(s.shape[0]):
        i = node_index(tab, s[n])
        px, py, pz, _, _, _, _, _, _ = eval_surface(tab, i, s[n], d[n])
        P[n, 0], P[n, 1], P[n, 2] = px, py, pz


@nb.njit(cache=True, inline="always")
def intersect_ray(tab, ox, oy, oz, rx, ry, rz, s, d, lam):
    """Newton on ``o + lam r = S(s, d)`` from the seed ``(s, d, lam)``.

    Returns ``(s, d, lam, ok)``; ``ok`` is False when it did not converge to 1e-7 m.
    """
    for _ in range(12):
        i = node_index(tab, s)
        px, py, pz, sx, sy, sz, dx, dy, dz = eval_surface(tab, i, s, d)
        fx, fy, fz = ox + lam * rx - px, oy + lam * ry - py, oz + lam * rz - pz
        # J = [r, -S_s, -S_d]; solve J delta = -f by Cramer's rule.
        a11, a12, a13 = rx, -sx, -dx
        a21, a22, a23 = ry, -sy, -dy
        a31, a32, a33 = rz, -sz, -dz
        det = (a11 * (a22 * a33 - a23 * a32) - a12 * (a21 * a33 - a23 * a31)
               + a13 * (a21 * a32 - a22 * a31))
        if abs(det) < 1e-12:
            return s, d, lam, False
        bx, by, bz = -fx, -fy, -fz
        dl = (bx * (a22 * a33 - a23 * a32) - a12 * (by * a33 - a23 * bz) + a13 * (by * a32 - a22 * bz)) / det
        ds = (a11 * (by * a33 - a23 * bz) - bx * (a21 * a33 - a23 * a31) + a13 * (a21 * bz - by * a31)) / det
        dd = (a11 * (a22 * bz - by * a32) - a12 * (a21 * bz - by * a31) + bx * (a21 * a32 - a22 * a31)) / det
        # Damp huge steps (far samples near the horizon) to stay on the tabulated road.
        step = max(abs(ds), abs(dd))
        if step > 50.0:
            f = 50.0 / step
            dl, ds, dd = dl * f, ds * f, dd * f
        lam += dl
        s += ds
        d += dd
        if abs(dl) + abs(ds) + abs(dd) < 1e-7:
            return s, d, lam, lam > 0.0
    return s, d, lam, False
