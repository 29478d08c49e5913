"""Pitch and yaw of the camera from the vanishing point of the lane lines
(Alrazouk et al. 2024, section V).

The lane direction ``e_x`` of the road frame projects to the vanishing point ``v`` with
``s v = K r3`` (eq. (16)), ``r3 = K^-1 v / |K^-1 v|`` (eq. (17)) the lane direction in ``cp``.
Writing the camera's attitude in the road frame as ``R_o_from_cs = Rx(phi1) Ry(theta1) Rz(psi1)``
(XYZ), the lane direction seen from the camera is ``R_cs_from_o e_x = (cos psi1 cos theta1,
-sin psi1 cos theta1, sin theta1)``, independent of ``phi1``, and in ``cp`` (eq. (20))

    r3 = (sin psi1 cos theta1, -sin theta1, cos psi1 cos theta1),

so ``psi1 = atan2(r3[0], r3[2])`` and ``theta1 = -asin(r3[1])``: the pan and tilt of the YXZ
form are the XYZ yaw and pitch (section V.A). Corrections, checked by round trip
(tests/test_vision_vanishing.py):

* the error analysis (section V.B) writes ``theta = arcsin(r3(2))``; with ``r3`` as in eq. (20)
  it is ``-arcsin(r3(2))`` (as the paper itself writes in section V), so a vanishing point
  above the principal point is a camera pitched down;
* its derivatives ``h1, h2`` are not used: :func:`angle_sigmas` propagates the vanishing point's
  error through the exact Jacobian of ``(psi, theta)`` with respect to ``(x, y)``, numerically.

The vanishing point's uncertainty follows section V.B: two points per line (``A, B`` on the
right line, ``C, D`` on the left one), each moved by ``+-dp`` in both coordinates; the extreme
intersections bound ``x`` and ``y`` (:func:`vp_bounds`).
"""

from __future__ import annotations

import math

import numpy as np

from .errors import VisionError

__all__ = [
    "r3_from_vp",
    "vp_from_r3",
    "yaw_pitch_from_r3",
    "r3_from_yaw_pitch",
    "intersect_lines",
    "line_through",
    "vp_bounds",
    "angle_sigmas",
]


def r3_from_vp(K, vp_px) -> np.ndarray:
    """Eq. (17): unit lane direction in ``cp`` from the vanishing point (undistorted pixels).

    ``vp_px`` may be homogeneous ``(x, y, w)`` (``w = 0``: at infinity in the image); the sign
    is chosen so that the direction points forward (``z > 0``) or, at infinity, keeps ``w``'s.
    """
    v = np.asarray(vp_px, dtype=float)
    if v.shape[-1] == 2:
        v = np.concatenate([v, np.ones(v.shape[:-1] + (1,))], axis=-1)
    r = v @ np.linalg.inv(np.asarray(K, dtype=float)).T
    n = np.linalg.norm(r, axis=-1, keepdims=True)
    if np.any(n == 0):
        raise VisionError("vanishing point: zero direction")
    r = r / n
    return np.where(r[..., 2:3] < 0, -r, r)


def vp_from_r3(K, r3) -> np.ndarray:
    """Pixel of the vanishing point of direction ``r3`` (``cp``, z > 0)."""
    p = np.asarray(r3, dtype=float) @ np.asarray(K, dtype=float).T
    return p[..., :2] / p[..., 2:3]


def yaw_pitch_from_r3(r3) -> tuple[float, float]:
    """``(psi1, theta1)``: XYZ yaw and pitch of ``cs`` relative to the road, rad (eq. (20))."""
    r = np.asarray(r3, dtype=float)
    return float(np.arctan2(r[0], r[2])), float(-np.arcsin(min(max(r[1], -1.0), 1.0)))     # np.clip of a number


def r3_from_yaw_pitch(psi1_rad: float, theta1_rad: float) -> np.ndarray:
    """Eq. (20): ``(sin psi cos theta, -sin theta, cos psi cos theta)``."""
    return np.array([math.sin(psi1_rad) * math.cos(theta1_rad), -math.sin(theta1_rad),
                     math.cos(psi1_rad) * math.cos(theta1_rad)])


def line_through(p, q) -> np.ndarray:
    """Homogeneous line through two image points ``(x, y)``."""
    return np.cross(np.append(np.asarray(p, float), 1.0), np.append(np.asarray(q, float), 1.0))


def intersect_lines(lines) -> np.ndarray:
    """Least-squares common point (homogeneous, unit norm) of homogeneous lines ``(n, 3)``.

    Each line is normalised to a unit normal so that the residuals are point-to-line distances
    for points near the image; two lines give their exact intersection.
    """
    L = np.asarray(lines, dtype=float)
    L = L / np.linalg.norm(L[:, :2], axis=1, keepdims=True)
    if L.shape[0] == 2:
        p = np.cross(L[0], L[1])
    else:
        _, _, vt = np.linalg.svd(L)
        p = vt[-1]
    return p / np.linalg.norm(p)


def _intersections(A, B, C, D):
    """Intersections of lines AB and CD for stacked points ``(..., 2)``; ``(..., 2)``."""
    x1, y1 = A[..., 0], A[..., 1]
    x2, y2 = B[..., 0], B[..., 1]
    x3, y3 = C[..., 0], C[..., 1]
    x4, y4 = D[..., 0], D[..., 1]
    den = (x1 - x2) * (y3 - y4) - (y1 - y2) * (x3 - x4)
    a = x1 * y2 - y1 * x2
    b = x3 * y4 - y3 * x4
    with np.errstate(divide="ignore", invalid="ignore"):
        px = (a * (x3 - x4) - (x1 - x2) * b) / den
        py = (a * (y3 - y4) - (y1 - y2) * b) / den
    return np.stack([px, py], axis=-1)


_SIGNS = np.array([[sx, sy] for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)])


def _cross(a, b):
    """Cross product of stacked 3-vectors (numpy's ``cross`` without its axis handling)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def vp_bounds(A, B, C, D, dp_px: float) -> tuple[float, float, np.ndarray]:
    """Section V.B: ``(dx, dy, vp)`` with ``dx = x_max - x_min``, ``dy = y_max - y_min`` over all
    intersections of line ``AB`` and line ``CD`` when each point moves by ``+-dp_px`` in x and y.

    The paper gives closed forms for the extreme pairs (largest and smallest slopes); here all
    4^4 corner combinations are intersected, which contains those pairs.
    """
    A, B, C, D = (np.asarray(p, dtype=float) for p in (A, B, C, D))
    s = _SIGNS * dp_px
    Ai, Bi, Ci, Di = (p + s for p in (A, B, C, D))          # (4, 2) each
    # line AB for all 16 (A, B) corners and line CD for all 16 (C, D): homogeneous, then meet.
    L1 = _cross(np.concatenate([np.repeat(Ai, 4, 0), np.ones((16, 1))], 1),
                  np.concatenate([np.tile(Bi, (4, 1)), np.ones((16, 1))], 1))
    L2 = _cross(np.concatenate([np.repeat(Ci, 4, 0), np.ones((16, 1))], 1),
                  np.concatenate([np.tile(Di, (4, 1)), np.ones((16, 1))], 1))
    X = _cross(L1[:, None, :], L2[None, :, :]).reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        P = X[:, :2] / X[:, 2:3]
    P = P[np.all(np.isfinite(P), axis=1)]
    vp = _intersections(A, B, C, D)
    if P.size == 0 or not np.all(np.isfinite(vp)):
        return math.inf, math.inf, vp
    return float(P[:, 0].max() - P[:, 0].min()), float(P[:, 1].max() - P[:, 1].min()), vp


def angle_sigmas(K, vp_px, sx_px: float, sy_px: float) -> tuple[float, float]:
    """``(sigma_psi, sigma_theta)`` in rad from independent vanishing-point errors ``sx, sy`` (px).

    First-order propagation through eqs. (17), (20) with a central-difference Jacobian. The yaw
    part agrees with the paper's ``dpsi = f_x / (f_x^2 + (u0 - x)^2) dx``.
    """
    vp = np.asarray(vp_px, dtype=float)
    e = 0.5
    pts = vp + np.array([[e, 0.0], [-e, 0.0], [0.0, e], [0.0, -e]])
    r = r3_from_vp(K, pts)
    psi = np.arctan2(r[:, 0], r[:, 2])
    theta = -np.arcsin(np.clip(r[:, 1], -1.0, 1.0))
    J = np.array([[psi[0] - psi[1], psi[2] - psi[3]], [theta[0] - theta[1], theta[2] - theta[3]]]) / (2 * e)
    cov = J @ np.diag([sx_px**2, sy_px**2]) @ J.T
    return float(math.sqrt(cov[0, 0])), float(math.sqrt(cov[1, 1]))
