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

from .noise import S
from .engine import StepRecord

__all__ = ["rts_smooth"]

_ANGLE_STATES = [S.ROLL_W, S.PITCH_W, S.YAW_REL, S.BANK, S.GRADE]


def _diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = a - b
    d[..., _ANGLE_STATES] = wrap_angle(d[..., _ANGLE_STATES])
    return d


def rts_smooth(steps: list[StepRecord], x0: np.ndarray, P0: np.ndarray, keep: np.ndarray | None = None):
    """Smooth the recorded steps of a :class:`fusion.engine.FusionStream` run.

    Parameters
    ----------
    steps : list of StepRecord
        In time order; ``steps[k]`` propagates from step k-1 (or the initial state) to k.
    x0, P0 : the posterior at the first IMU sample (before the first step)
    keep : (N + 1,) bool, optional
        Which smoothed elements to return (element 0 is the first sample, element k + 1 the
        state after ``steps[k]``); all by default. The recursion runs through every element.

    Returns
    -------
    xs : (M, n) smoothed states of the kept elements, in time order
    Ps : (M, n, n) their covariances

    The recursion works one step at a time on the records and writes only the kept rows: its
    memory is the output's, not five stacked copies of the records (an hour-long drive's
    records are some 3 GB, 16 x 16 covariances at about 130 steps a second).
    """
    n = len(steps)
    keep = np.ones(n + 1, dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
    if keep.shape != (n + 1,):
        raise ValueError(f"keep must have {n + 1} elements, got {keep.shape}")
    dim = len(x0)
    m = int(keep.sum())
    xs, Ps = np.empty((m, dim)), np.empty((m, dim, dim))
    x_next, P_next = (steps[-1].x_post, steps[-1].P_post) if n else (x0, P0)
    row = m - 1
    if keep[n]:
        xs[row], Ps[row] = x_next, P_next
        row -= 1
    for k in range(n - 1, -1, -1):
        # smoothing element k (state after steps[k-1]) from element k+1 (after steps[k])
        x_post, P_post = (steps[k - 1].x_post, steps[k - 1].P_post) if k else (x0, P0)
        st = steps[k]
        try:
            P_prior_inv = np.linalg.inv(st.P_prior)
        except np.linalg.LinAlgError:
            # a state held exactly (zero variance and zero process noise, e.g. a bias whose
            # prior and walk were both set to 0): it takes no correction from later steps
            P_prior_inv = np.linalg.pinv(st.P_prior, hermitian=True)
        C = P_post @ st.F.T @ P_prior_inv
        x_next = x_post + C @ _diff(x_next, st.x_prior)
        P_next = P_post + C @ (P_next - st.P_prior) @ C.T
        if keep[k]:
            xs[row], Ps[row] = x_next, P_next
            row -= 1
    xs[:, _ANGLE_STATES] = wrap_angle(xs[:, _ANGLE_STATES])
    return xs, Ps
