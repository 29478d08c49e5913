"""The RTS smoother's recursion against the exact answer: on a linear-Gaussian model the
smoothed states and covariances are the marginals of the joint Gaussian of all states given all
measurements, which a batch solve in information form gives directly. The model has what the
filter's records have: a different F and Q at every step, steps without an update (gated),
a state reset folded into a step's prior (rows of F zeroed, as ``FusionStream._reset``) and a
restart (F = 0, a fresh prior). Written from a review's check (fifteenth session)."""

from __future__ import annotations

import numpy as np

from fusion.engine import StepRecord
from fusion.smoother import rts_smooth

N_STATES, N_STEPS, RESET_AT, RESTART_AT = 16, 40, 17, 29


def _model(seed: int = 1):
    rng = np.random.default_rng(seed)
    n = N_STATES

    def psd(s):
        A = rng.normal(size=(n, n)) * s
        return A @ A.T + np.eye(n) * 1e-4

    x0, P0 = rng.normal(size=n) * 0.05, psd(0.05)
    xt = x0 + np.linalg.cholesky(P0) @ rng.normal(size=n)
    steps = []
    for k in range(N_STEPS):
        F, Q, c = np.eye(n) + rng.normal(size=(n, n)) * 0.05, psd(0.02), np.zeros(n)
        if k == RESET_AT:        # states 2 and 3 set to 0.1 and 0.2, variance 0.04
            F[[2, 3], :] = 0.0
            Q[[2, 3], :] = Q[:, [2, 3]] = 0.0
            Q[2, 2] = Q[3, 3] = 0.04
            c[[2, 3]] = (0.1, 0.2)
        if k == RESTART_AT:
            F, Q, c = np.zeros((n, n)), psd(0.05), rng.normal(size=n) * 0.05
        xt = F @ xt + c + np.linalg.cholesky(Q) @ rng.normal(size=n)
        m = int(rng.integers(2, 6))
        H, R = rng.normal(size=(m, n)), np.eye(m) * 0.01
        z = H @ xt + rng.normal(size=m) * 0.1
        steps.append((F, c, Q, H, R, z, k % 3 != 1))     # every third update gated out
    return x0, P0, steps


def _forward(x0, P0, model):
    x, P, records = x0.copy(), P0.copy(), []
    for k, (F, c, Q, H, R, z, update) in enumerate(model):
        xp, Pp = F @ x + c, F @ P @ F.T + Q
        x, P = xp.copy(), Pp.copy()
        if update:
            K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
            IKH = np.eye(len(x)) - K @ H
            x, P = x + K @ (z - H @ x), IKH @ P @ IKH.T + K @ R @ K.T
        records.append(StepRecord(float(k + 1), F.copy(), xp, Pp, x.copy(), P.copy(), k))
    return records


def _batch(x0, P0, model):
    """Marginal means and covariances of all states given all measurements."""
    n, N = N_STATES, len(model)
    D = n * (N + 1)
    Lam, eta = np.zeros((D, D)), np.zeros(D)

    def add(J, r, W):
        nonlocal Lam, eta
        Lam += J.T @ W @ J
        eta += J.T @ W @ r

    J = np.zeros((n, D))
    J[:, :n] = np.eye(n)
    add(J, x0, np.linalg.inv(P0))
    for k, (F, c, Q, H, R, z, update) in enumerate(model):
        J = np.zeros((n, D))
        J[:, (k + 1) * n:(k + 2) * n], J[:, k * n:(k + 1) * n] = np.eye(n), -F
        add(J, c, np.linalg.inv(Q))
        if update:
            J = np.zeros((len(z), D))
            J[:, (k + 1) * n:(k + 2) * n] = H
            add(J, z, np.linalg.inv(R))
    cov = np.linalg.inv(Lam)
    mean = (cov @ eta).reshape(N + 1, n)
    return mean, np.stack([cov[i * n:(i + 1) * n, i * n:(i + 1) * n] for i in range(N + 1)])


def test_rts_smoother_equals_the_batch_solution():
    x0, P0, model = _model()
    records = _forward(x0, P0, model)
    xs, Ps = rts_smooth(records, x0, P0)
    xb, Pb = _batch(x0, P0, model)
    # both exact: agreement to rounding (measured 1e-13 in x, 2e-15 in P, P's scale 0.1)
    assert np.abs(xs - xb).max() < 1e-9
    assert np.abs(Ps - Pb).max() < 1e-11
    # the last element is the forward filter's posterior (to the rounding of the angles' wrap)
    assert np.abs(xs[-1] - records[-1].x_post).max() < 1e-15 and np.array_equal(Ps[-1], records[-1].P_post)


def test_kept_rows_are_those_of_the_full_recursion():
    """``keep`` (the pipeline keeps the IMU samples' rows, not the vision steps') returns the
    same rows as the full recursion, in order, to the bit."""
    x0, P0, model = _model(seed=2)
    records = _forward(x0, P0, model)
    keep = np.random.default_rng(3).random(N_STEPS + 1) < 0.6
    keep[0] = keep[-1] = True
    xs, Ps = rts_smooth(records, x0, P0)
    xk, Pk = rts_smooth(records, x0, P0, keep=keep)
    assert np.array_equal(xk, xs[keep]) and np.array_equal(Pk, Ps[keep])
