"""Frames, rotations and Euler conventions: the one place that defines them.

Every module of vifusion (vision, fusion, the simulator) takes its rotations from here;
``fusion`` re-exports this module as ``fusion.frames``. Conventions (``INTERFACE.md``):

* road ``o``: x along the lane markings, y left, z normal to the road surface, up;
* level ``g``: same heading as ``o``, z against gravity;
* vehicle ``v`` (ISO 8855): x forward, y left, z up, origin at the front-wheel contact point;
* camera ``cs``: ``v`` turned down by the mount tilt mu about its y axis,
  ``R_v_from_cs = Ry(mu)`` (Alrazouk et al. 2024, eq. (22), ``vR_cs``);
* pinhole ``cp``: x right, y down, z along the optical axis,
  ``R_cs_from_cp = [[0,0,1],[-1,0,0],[0,-1,0]]`` (Alrazouk et al. 2024, eq. (1));
* attitude: ``R_o_from_v = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (ZYX). Positive roll leans right,
  positive pitch is nose down, positive yaw is nose left;
* road bank: ``R_g_from_o = Ry(road_pitch) @ Rx(bank)``, positive bank raises the left edge,
  so with zero yaw and pitch ``roll_world = bank + roll``.

Matrices are named ``R_a_from_b``: they take coordinates in ``b`` to coordinates in ``a``, so
``R_o_from_v = R_o_from_cs @ R_cs_from_v`` reads right. All functions take radians and
broadcast over leading dimensions (angles of shape ``(...)`` give matrices ``(..., 3, 3)``).

Euler orders are named by the product they stand for: ``"zyx"`` is ``Rz(a) @ Ry(b) @ Rx(c)``
with angles ``(a, b, c)``; ``"xyz"`` is ``Rx(a) @ Ry(b) @ Rz(c)``; ``"yxz"`` is
``Ry(a) @ Rx(b) @ Rz(c)``. Each is unique for a middle angle inside (-pi/2, pi/2).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = [
    "Rx",
    "Ry",
    "Rz",
    "R_CS_FROM_CP",
    "R_v_from_cs",
    "R_v_from_cp",
    "matrix_from_euler",
    "euler_from_matrix",
    "R_from_rpy",
    "rpy_from_R",
    "roll_xyz_from_zyx",
    "wrap_angle",
    "skew",
    "so3_log",
    "so3_exp",
    "R_from_rpy_scalar",
    "rpy_from_R_scalar",
    "so3_exp_scalar",
]

#: Pinhole frame to camera frame, ``cs`` from ``cp`` (Alrazouk et al. 2024, eq. (1)).
R_CS_FROM_CP = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
R_CS_FROM_CP.setflags(write=False)


#: The (i, j) planes of :func:`Rx`, :func:`Ry`, :func:`Rz`, and those of each Euler order's factors.
_PLANE = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}
_EULER_PLANES = {order: tuple(k for axis in order for k in _PLANE[axis]) for order in ("zyx", "xyz", "yxz")}


def _rot(angle_rad, i: int, j: int) -> np.ndarray:
    """Rotation by ``angle_rad`` in the (i, j) plane, i.e. about the remaining axis."""
    if isinstance(angle_rad, (float, int)) and not isinstance(angle_rad, bool):
        # Scalar fast path (the estimator builds many single matrices per frame): same result.
        return _rot_scalar(float(angle_rad), i, j)
    a = np.asarray(angle_rad, dtype=float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    k = 3 - i - j
    R[..., k, k] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


@nb.njit(cache=True)
def _rot_scalar(angle: float, i: int, j: int) -> np.ndarray:
    """:func:`_rot` of one angle, compiled (the filter's and the estimator's kernels call it)."""
    c, s = math.cos(angle), math.sin(angle)
    R = np.eye(3)
    R[i, i] = c
    R[j, j] = c
    R[i, j] = -s
    R[j, i] = s
    return R


def Rx(angle_rad) -> np.ndarray:
    """Right-handed rotation about x: ``[[1,0,0],[0,c,-s],[0,s,c]]``."""
    return _rot(angle_rad, *_PLANE["x"])


def Ry(angle_rad) -> np.ndarray:
    """Right-handed rotation about y: ``[[c,0,s],[0,1,0],[-s,0,c]]``."""
    return _rot(angle_rad, *_PLANE["y"])


def Rz(angle_rad) -> np.ndarray:
    """Right-handed rotation about z: ``[[c,-s,0],[s,c,0],[0,0,1]]``."""
    return _rot(angle_rad, *_PLANE["z"])


_AXIS = {"x": Rx, "y": Ry, "z": Rz}


def R_v_from_cs(tilt_rad) -> np.ndarray:
    """Camera frame ``cs`` to vehicle frame: ``Ry(mu)``, mu > 0 looks down.

    Alrazouk et al. 2024, eq. (22): ``vR_cs = [[cos mu, 0, sin mu], [0, 1, 0], [-sin mu, 0, cos mu]]``.
    """
    return Ry(tilt_rad)


def R_v_from_cp(tilt_rad) -> np.ndarray:
    """Pinhole frame ``cp`` to vehicle frame: ``Ry(mu) @ R_CS_FROM_CP``."""
    return R_v_from_cs(tilt_rad) @ R_CS_FROM_CP


def matrix_from_euler(order: str, a, b, c) -> np.ndarray:
    """Rotation matrix ``R_order[0](a) @ R_order[1](b) @ R_order[2](c)``.

    Parameters
    ----------
    order : {"zyx", "xyz", "yxz"}
        Axes of the three factors, left to right.
    a, b, c : float or array, rad
        Angles of the three factors, broadcast together.
    """
    _check_order(order)
    if isinstance(a, float) and isinstance(b, float) and isinstance(c, float):
        return _euler_scalar(a, b, c, _EULER_PLANES[order])   # the estimator builds ~10 a frame
    return _AXIS[order[0]](a) @ _AXIS[order[1]](b) @ _AXIS[order[2]](c)


@nb.njit(cache=True)
def _euler_scalar(a: float, b: float, c: float, planes) -> np.ndarray:
    """:func:`matrix_from_euler` of three floats; ``planes``: the factors' (i, j) planes."""
    return (_rot_scalar(a, planes[0], planes[1]) @ _rot_scalar(b, planes[2], planes[3])
            @ _rot_scalar(c, planes[4], planes[5]))


def euler_from_matrix(order: str, R) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angles ``(a, b, c)`` with ``R = R_order[0](a) @ R_order[1](b) @ R_order[2](c)``.

    The middle angle is returned in [-pi/2, pi/2], the others in (-pi, pi].
    """
    _check_order(order)
    R = np.asarray(R, dtype=float)
    if order == "zyx":
        # R = Rz(a) Ry(b) Rx(c): R20 = -sin b, R21 = cos b sin c, R22 = cos b cos c,
        # R10 = sin a cos b, R00 = cos a cos b.
        b = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
        a = np.arctan2(R[..., 1, 0], R[..., 0, 0])
        c = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    elif order == "xyz":
        # R = Rx(a) Ry(b) Rz(c): R02 = sin b, R12 = -sin a cos b, R22 = cos a cos b,
        # R01 = -cos b sin c, R00 = cos b cos c.
        b = np.arcsin(np.clip(R[..., 0, 2], -1.0, 1.0))
        a = np.arctan2(-R[..., 1, 2], R[..., 2, 2])
        c = np.arctan2(-R[..., 0, 1], R[..., 0, 0])
    else:  # "yxz"
        # R = Ry(a) Rx(b) Rz(c): R12 = -sin b, R02 = sin a cos b, R22 = cos a cos b,
        # R10 = cos b sin c, R11 = cos b cos c.
        b = np.arcsin(np.clip(-R[..., 1, 2], -1.0, 1.0))
        a = np.arctan2(R[..., 0, 2], R[..., 2, 2])
        c = np.arctan2(R[..., 1, 0], R[..., 1, 1])
    return a, b, c


def _check_order(order: str) -> None:
    if order not in ("zyx", "xyz", "yxz"):
        raise ValueError(f'Euler order must be "zyx", "xyz" or "yxz", got {order!r}')


def R_from_rpy(roll_rad, pitch_rad, yaw_rad) -> np.ndarray:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)``: the attitude convention of INTERFACE.md."""
    return matrix_from_euler("zyx", yaw_rad, pitch_rad, roll_rad)


def rpy_from_R(R) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(roll, pitch, yaw)`` in rad of ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

    This is the extraction of Alrazouk et al. 2024, section VII:
    ``psi = atan2(r21, r11), theta = -asin(r31), phi = atan2(r32, r33)``.
    """
    yaw, pitch, roll = euler_from_matrix("zyx", R)
    return roll, pitch, yaw


def roll_xyz_from_zyx(roll_zyx_rad, pitch_xyz_rad, yaw_xyz_rad):
    """XYZ roll ``phi1`` from the ZYX roll ``phi2`` and the XYZ pitch/yaw of the same matrix.

    Alrazouk et al. 2024, eq. (21): ``phi1 = atan2(cos(theta1) tan(phi2) - sin(psi1) sin(theta1),
    cos(psi1))``, with ``Rx(phi1) Ry(theta1) Rz(psi1) = Rz(psi2) Ry(theta2) Rx(phi2)``.

    Derivation check (no sign slip found): equating element (2,1) and (2,2) of both sides gives
    ``cos(theta2) sin(phi2) = s_psi1 s_theta1 c_phi1 + c_psi1 s_phi1`` and
    ``cos(theta2) cos(phi2) = c_phi1 c_theta1``; dividing, ``tan(phi2) c_phi1 c_theta1 =
    s_psi1 s_theta1 c_phi1 + c_psi1 s_phi1``, i.e. ``tan(phi1) = (c_theta1 tan(phi2) -
    s_psi1 s_theta1) / c_psi1``: eq. (21). Valid for ``|phi2| < pi/2`` (the ``tan``); the
    round-trip test in ``tests/test_frames.py`` checks it against the matrix route.
    """
    return np.arctan2(
        np.cos(pitch_xyz_rad) * np.tan(roll_zyx_rad) - np.sin(yaw_xyz_rad) * np.sin(pitch_xyz_rad),
        np.cos(yaw_xyz_rad),
    )


def wrap_angle(angle_rad):
    """Wrap to [-pi, pi)."""
    return (np.asarray(angle_rad) + np.pi) % (2.0 * np.pi) - np.pi


def skew(w) -> np.ndarray:
    """Cross-product matrix ``[w]x`` with ``[w]x @ u = w x u``; broadcasts over ``(..., 3)``."""
    w = np.asarray(w, dtype=float)
    S = np.zeros(w.shape[:-1] + (3, 3))
    S[..., 0, 1] = -w[..., 2]
    S[..., 0, 2] = w[..., 1]
    S[..., 1, 0] = w[..., 2]
    S[..., 1, 2] = -w[..., 0]
    S[..., 2, 0] = -w[..., 1]
    S[..., 2, 1] = w[..., 0]
    return S


def so3_exp(w) -> np.ndarray:
    """Rotation matrix of the rotation vector ``w`` (rad), Rodrigues' formula; ``(..., 3)``."""
    w = np.asarray(w, dtype=float)
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    small = th < 1e-8
    th_safe = np.where(small, 1.0, th)
    A = np.where(small, 1.0 - th**2 / 6.0, np.sin(th_safe) / th_safe)
    B = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(th_safe)) / th_safe**2)
    return np.eye(3) + A * K + B * (K @ K)


def so3_log(R) -> np.ndarray:
    """Rotation vector (rad) of ``R``, inverse of :func:`so3_exp` for angles below pi."""
    R = np.asarray(R, dtype=float)
    cos_th = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    th = np.arccos(cos_th)
    v = np.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]],
        axis=-1,
    )
    small = th < 1e-6
    sin_th = np.where(small, 1.0, np.sin(th))
    scale = np.where(small, 0.5 + th**2 / 12.0, th / (2.0 * sin_th))
    return v * scale[..., None]


# ---- scalar fast paths (filters call these thousands of times a second) ----


@nb.njit(cache=True)
def R_from_rpy_scalar(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """:func:`R_from_rpy` for one set of floats; compiled, so that the filter's kernels call it."""
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    R[1, 0], R[1, 1], R[1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    R[2, 0], R[2, 1], R[2, 2] = -sp, cp * sr, cp * cr
    return R


@nb.njit(cache=True)
def rpy_from_R_scalar(R) -> tuple[float, float, float]:
    """:func:`rpy_from_R` of one matrix, as floats."""
    return (math.atan2(R[2, 1], R[2, 2]), math.asin(max(-1.0, min(1.0, -R[2, 0]))),
            math.atan2(R[1, 0], R[0, 0]))


_XYZ = _EULER_PLANES["xyz"]
_Y = _PLANE["y"]


@nb.njit(cache=True)
def rpy_from_camera_xyz_scalar(phi1: float, theta1: float, psi1: float, tilt_rad: float) -> tuple[float, float, float]:
    """ZYX ``(roll, pitch, yaw)`` of ``Rx(phi1) Ry(theta1) Rz(psi1) Ry(tilt)^T``: the vehicle's
    attitude from the camera's XYZ angles and the mount tilt (Alrazouk et al. 2024, eq. (22)),
    for one set of floats."""
    return rpy_from_R_scalar(_euler_scalar(phi1, theta1, psi1, _XYZ) @ _rot_scalar(tilt_rad, _Y[0], _Y[1]).T)


@nb.njit(cache=True)
def so3_exp_scalar(wx: float, wy: float, wz: float) -> np.ndarray:
    """:func:`so3_exp` of one rotation vector given as three floats."""
    th2 = wx * wx + wy * wy + wz * wz
    if th2 < 1e-16:
        A, B = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        A, B = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    E = np.empty((3, 3))
    E[0, 0], E[0, 1], E[0, 2] = 1.0 - B * (wy * wy + wz * wz), -A * wz + B * wx * wy, A * wy + B * wx * wz
    E[1, 0], E[1, 1], E[1, 2] = A * wz + B * wx * wy, 1.0 - B * (wx * wx + wz * wz), -A * wx + B * wy * wz
    E[2, 0], E[2, 1], E[2, 2] = -A * wy + B * wx * wz, A * wx + B * wy * wz, 1.0 - B * (wx * wx + wy * wy)
    return E
