"""Rauch-Tung-Striebel smoother for the nonlinear filter's stored steps.

filterpy's ``rts_smoother`` is for linear filters: it predicts with ``F x`` and recomputes
the priors. For the EKF the priors must be the ones the filter actually used (the nonlinear
propagation), with the Jacobian ``F`` of each step::

    C_k   = P_k F_{k+1}^T (P^-_{k+1})^-1
    x^s_k = x_k + C_k (x^s_{k+1} - x^-_{k+1})
    P^s_k = P_k + C_k (P^s_{k+1} - P^-_{k+1}) C_k^T

with ``x_k, P_k`` the posterior after all updates at step k and ``x^-_{k+1}, P^-_{k+1}`` the
stored prior of the next step. Differences of the yaw state are wrapped.
"""

from __future__ import annotations

import numpy as np

from vision.frames import wrap_angle

from .ekf import S
from .engine import StepRecord

__all__ = ["rts_smooth"]

_ANGLE_STATES = [S.ROLL_W, S.PITCH_W, S.YAW_REL, S.BANK, S.GRADE]


def _diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = a - b
    d[..., _ANGLE_STATES] = wrap_angle(d[..., _ANGLE_STATES])
    return d


def rts_smooth(steps: list[StepRecord], x0: np.ndarray, P0: np.ndarray):
    """Smooth the recorded steps of a :class:`fusion.engine.FusionStream` run.

    Parameters
    ----------
    steps : list of StepRecord
        In time order; ``steps[k]`` propagates from step k-1 (or the initial state) to k.
    x0, P0 : the posterior at the first IMU sample (before the first step)

    Returns
    -------
    xs : (N + 1, n) smoothed states, xs[0] at the first sample, xs[k + 1] after steps[k]
    Ps : (N + 1, n, n) their covariances
    """
    n = len(steps)
    x_post = np.stack([x0] + [s.x_post for s in steps])
    P_post = np.stack([P0] + [s.P_post for s in steps])
    if n == 0:
        return x_post, P_post
    x_prior = np.stack([s.x_prior for s in steps])
    P_prior = np.stack([s.P_prior for s in steps])
    F = np.stack([s.F for s in steps])
    try:
        P_prior_inv = np.linalg.inv(P_prior)
    except np.linalg.LinAlgError:
        # a state held exactly (zero variance and zero process noise, e.g. a bias whose prior and
        # walk were both set to 0): it takes no correction from later steps
        P_prior_inv = np.linalg.pinv(P_prior, hermitian=True)
    xs, Ps = x_post.copy(), P_post.copy()
    for k in range(n - 1, -1, -1):
        # smoothing element k (state after steps[k-1]) from element k+1 (after steps[k])
        C = P_post[k] @ F[k].T @ P_prior_inv[k]
        xs[k] = x_post[k] + C @ _diff(xs[k + 1], x_prior[k])
        Ps[k] = P_post[k] + C @ (Ps[k + 1] - P_prior[k]) @ C.T
    xs[:, _ANGLE_STATES] = wrap_angle(xs[:, _ANGLE_STATES])
    return xs, Ps
