"""The IMU's biases carried from one drive to the next: bank campaigns with one vehicle.

At constant speed the lateral accelerometer bias cannot be told from a bank offset (both shift
the lateral specific force by ``g`` times an angle: 0.04 m/s^2 is 0.23 deg of bank), and the
yaw-rate bias is learnt only slowly, from the heading against the lane curvature (0.1 deg/s is
0.22 deg of bank at 22 m/s, through the centripetal term). A 20 s drive through one banked
curve cannot resolve them; a drive with curves both ways can, and the IMU is the same on every
drive of a campaign. ``vifusion run`` writes its end-of-drive bias estimates with their 1-sigma
(the filter's covariance at the last sample; the smoother's equals it there) to
``calibration.toml``::

    [fusion]
    gyro_bias_deg_s = [0.2014, 0.1499, -0.3167]
    gyro_bias_sigma_deg_s = [0.0105, 0.0107, 0.0171]
    accel_bias_m_s2 = [0.0462, 0.0215, -0.0137]
    accel_bias_sigma_m_s2 = [0.0174, 0.019, 0.0112]

and ``vifusion run --calibration FILE`` starts the next drive from it (the keys override the
config's ``[fusion]``; they can also be written there). The sigmas are the filter's at the end
of the drive: if the IMU was switched off in between, add its turn-on repeatability (datasheet)
before reusing them.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from .config import Table, read_toml
from .ekf import NoiseModel, S
from .errors import ConfigError
from .files import write_bytes_atomically

__all__ = ["CALIBRATION_KEYS", "calibration_table", "calibration_from_state", "pitch_gyro_prior_deg_s",
           "write_calibration", "read_calibration"]

#: The ``[fusion]`` keys of a calibration (vehicle frame).
CALIBRATION_KEYS = ("gyro_bias_deg_s", "gyro_bias_sigma_deg_s", "accel_bias_m_s2", "accel_bias_sigma_m_s2")


def pitch_gyro_prior_deg_s(noise: NoiseModel) -> tuple[float, float]:
    """The y gyro bias a run without a pitch gyro hands on: the prior it started from (mean and
    1-sigma, deg/s): it measured nothing of it."""
    sigma = np.broadcast_to(np.asarray(noise.init_gyro_bias_rad_s, dtype=float), (3,))[1]
    return math.degrees(noise.gyro_bias_prior_rad_s[1]), math.degrees(float(sigma))


def calibration_table(fused: pd.DataFrame, pitch_gyro_prior: tuple[float, float] | None = None) -> dict[str, list[float]]:
    """The bias estimates and their 1-sigma at the last sample of a fused table, as ``[fusion]``
    keys (``gyro_bias_*_deg_s``, ``accel_bias_*_m_s2`` and their ``*_sigma_*`` columns). A run
    without a pitch gyro has no y gyro bias (NaN in the table): give ``pitch_gyro_prior``
    (:func:`pitch_gyro_prior_deg_s`) for its entry."""
    last = fused.iloc[-1].copy()
    if pitch_gyro_prior is not None:
        last["gyro_bias_y_deg_s"], last["gyro_bias_y_sigma_deg_s"] = pitch_gyro_prior
    out = {
        "gyro_bias_deg_s": [float(last[f"gyro_bias_{a}_deg_s"]) for a in "xyz"],
        "gyro_bias_sigma_deg_s": [float(last[f"gyro_bias_{a}_sigma_deg_s"]) for a in "xyz"],
        "accel_bias_m_s2": [float(last[f"accel_bias_{a}_m_s2"]) for a in "xyz"],
        "accel_bias_sigma_m_s2": [float(last[f"accel_bias_{a}_sigma_m_s2"]) for a in "xyz"],
    }
    bad = [k for k, v in out.items() if not all(math.isfinite(x) for x in v)]
    if bad:
        raise ValueError(f"the fused table's last sample has no finite {bad[0]}")
    return out


def calibration_from_state(x: np.ndarray, P: np.ndarray,
                           pitch_gyro_prior: tuple[float, float] | None = None) -> dict[str, list[float]]:
    """The same keys from a filter state and covariance (:class:`fusion.ekf.AttitudeEKF` ``x, P``):
    what an embedded filter saves when it stops (:meth:`fusion.realtime.LiveFusion.calibration`);
    ``pitch_gyro_prior`` as for :func:`calibration_table` (without a pitch gyro, that state is
    the pitch rate ``q = r tan(roll)`` leaves out)."""
    d = np.sqrt(np.maximum(np.diag(P), 0.0))
    bias, sigma = np.degrees(x[S.GYRO_BIAS]), np.degrees(d[S.GYRO_BIAS])
    if pitch_gyro_prior is not None:
        bias[1], sigma[1] = pitch_gyro_prior
    return {"gyro_bias_deg_s": bias.tolist(),
            "gyro_bias_sigma_deg_s": sigma.tolist(),
            "accel_bias_m_s2": x[S.ACCEL_BIAS].tolist(), "accel_bias_sigma_m_s2": d[S.ACCEL_BIAS].tolist()}


def write_calibration(table: dict[str, list[float]], path: str | Path, source: str = "") -> None:
    """Write a calibration (:func:`calibration_table`, :func:`calibration_from_state`) as TOML,
    under a temporary name, then renamed."""
    path = Path(path)
    lines = ["# IMU biases at the end of a vifusion run (vehicle frame); start the next drive of this IMU",
             "# from them with `vifusion run --calibration " + path.name + "`."]
    if source:
        lines.append(f"# from: {source}")
    lines.append("[fusion]")
    lines += [f"{k} = [{', '.join(f'{x:.6g}' for x in v)}]" for k, v in table.items()]
    write_bytes_atomically(path, ("\n".join(lines) + "\n").encode())


def read_calibration(path: str | Path) -> dict:
    """The ``[fusion]`` keys of a calibration file, checked: only :data:`CALIBRATION_KEYS`, each
    three numbers, sigmas positive. Errors are one-line :class:`fusion.errors.ConfigError` naming
    the file and key."""
    data = read_toml(path)
    extra = sorted(set(data) - {"fusion"})
    if extra:
        raise ConfigError(f"{path}: [{extra[0]}] does not belong in a calibration file (only [fusion])")
    t = Table(data.get("fusion", {}), "fusion", str(path))
    out = {}
    for key in CALIBRATION_KEYS:
        value = t.get(key, "floats", None, length=3, min=1e-9 if "sigma" in key else None)
        if value is not None:
            out[key] = list(value)
    t.done()
    if not out:
        raise ConfigError(f"{path}: [fusion] has none of {', '.join(CALIBRATION_KEYS)}")
    return out
