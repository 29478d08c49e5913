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

    [imu]
    axes = ["x", "-y", "-z"]
    position_m = [0, 0, 0.5]

and ``vifusion run --calibration FILE`` starts the next drive from it (the keys override the
config's ``[fusion]``; they can also be written there). The biases are in the vehicle frame of
the IMU as it was mounted, so ``[imu]`` records that mount: a drive whose ``[imu] axes`` differ
is refused (:func:`apply_calibration`; the same biases turned by another mount are wrong by
twice their size on a flipped axis); one whose ``position_m`` differs is warned
(:func:`mount_warnings`: the biases are the sensor's, wherever it sits, but another position
often means another vehicle's IMU). A file without ``[imu]`` (written before it was added, or by
hand) is taken as it is. The sigmas are the filter's at the end of the drive: if the IMU was
switched off in between, add its turn-on repeatability (datasheet) before reusing them.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from imu.config import ImuMount
from imu.errors import ImuConfigError

from .config import Table, read_toml
from .errors import ConfigError
from .files import write_bytes_atomically
from .noise import NoiseModel, S

__all__ = ["CALIBRATION_KEYS", "calibration_table", "calibration_from_state", "pitch_gyro_prior_deg_s",
           "write_calibration", "read_calibration", "apply_calibration", "mount_warnings"]

#: The ``[fusion]`` keys of a calibration (vehicle frame).
CALIBRATION_KEYS = ("gyro_bias_deg_s", "gyro_bias_sigma_deg_s", "accel_bias_m_s2", "accel_bias_sigma_m_s2")
#: Where :func:`read_calibration` puts the file's ``[imu] axes`` and ``position_m`` (absent when
#: it has none).
MOUNT_KEY = "imu_axes"
POSITION_KEY = "imu_position_m"
#: Positions closer than this are the same, m: the file keeps 6 significant digits (3 um at 1.5 m).
_SAME_POSITION_M = 1e-3


def pitch_gyro_prior_deg_s(noise: NoiseModel) -> tuple[float, float]:
    """The y gyro bias a run without a pitch gyro hands on: the prior it started from (mean and
    1-sigma, deg/s): it measured nothing of it."""
    return math.degrees(noise.gyro_bias_prior_rad_s[1]), math.degrees(float(noise.init_gyro_bias_sigma_rad_s[1]))


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


def write_calibration(table: dict[str, list[float]], path: str | Path, source: str = "",
                      mount: ImuMount | None = None) -> None:
    """Write a calibration (:func:`calibration_table`, :func:`calibration_from_state`) as TOML,
    under a temporary name, then renamed; with ``mount``, the IMU's ``[imu] axes`` and
    ``position_m`` that the vehicle-frame biases belong to."""
    path = Path(path)
    lines = ["# IMU biases at the end of a vifusion run (vehicle frame); start the next drive of this IMU",
             "# from them with `vifusion run --calibration " + path.name + "`."]
    if source:
        lines.append(f"# from: {source}")
    lines.append("[fusion]")
    lines += [f"{k} = [{', '.join(f'{x:.6g}' for x in v)}]" for k, v in table.items() if k != MOUNT_KEY]
    if mount is not None:
        lines += ["", "[imu]   # the mount these vehicle-frame biases belong to",
                  "axes = [" + ", ".join(f'"{a}"' for a in mount.axes) + "]",
                  "position_m = [" + ", ".join(f"{x:.6g}" for x in mount.position_m) + "]"]
    write_bytes_atomically(path, ("\n".join(lines) + "\n").encode())


def read_calibration(path: str | Path) -> dict:
    """The ``[fusion]`` keys of a calibration file, checked: only :data:`CALIBRATION_KEYS`, each
    three numbers, sigmas not negative (0: a bias held, as the config's ``[fusion]`` allows), and
    under :data:`MOUNT_KEY` the ``[imu] axes`` of the mount when the file gives it. Errors are
    one-line :class:`fusion.errors.ConfigError` naming the file and key."""
    data = read_toml(path)
    extra = sorted(set(data) - {"fusion", "imu"})
    if extra:
        raise ConfigError(f"{path}: [{extra[0]}] does not belong in a calibration file (only [fusion] and [imu])")
    t = Table(data.get("fusion", {}), "fusion", str(path))
    out: dict = {}
    for key in CALIBRATION_KEYS:
        value = t.get(key, "floats", None, length=3, min=0.0 if "sigma" in key else None)
        if value is not None:
            out[key] = list(value)
    t.done()
    if not out:
        raise ConfigError(f"{path}: [fusion] has none of {', '.join(CALIBRATION_KEYS)}")
    if "imu" in data:
        m = Table(data["imu"], "imu", str(path))
        axes, position = m.get("axes", "strs", None, length=3), m.get("position_m", "floats", None, length=3)
        m.done()
        try:   # checked as the config's [imu] is, with or without the axes
            mount = ImuMount(tuple(axes or ("x", "y", "z")), tuple(position or (0.0, 0.0, 0.0)))
        except ImuConfigError as e:
            raise ConfigError(f"{path}: {e}") from None
        if axes is not None:
            out[MOUNT_KEY] = list(mount.axes)
        if position is not None:
            out[POSITION_KEY] = list(mount.position_m)
    return out


def apply_calibration(fusion_table: dict, cal: dict, mount: ImuMount, source: str | Path) -> dict:
    """``fusion_table`` with a calibration's keys (:func:`read_calibration`) over it, after
    checking that the calibration was made with this drive's IMU axes (``source`` names it in
    the error)."""
    axes = cal.get(MOUNT_KEY)
    if axes is not None and list(axes) != list(mount.axes):
        raise ConfigError(f"{source}: a calibration of the IMU mounted with [imu] axes = {list(axes)}, "
                          f"but this drive's are {list(mount.axes)}: its biases are in the vehicle frame of "
                          "that mount")
    return {**fusion_table, **{k: v for k, v in cal.items() if k not in (MOUNT_KEY, POSITION_KEY)}}


def mount_warnings(cal: dict, mount: ImuMount, source: str | Path) -> list[str]:
    """A line when the calibration's IMU sat elsewhere than this drive's ``[imu] position_m``
    says (a review: a campaign took another vehicle's calibration without a word). Not refused:
    a bias is the sensor's, wherever it is mounted, and a corrected position keeps it."""
    position = cal.get(POSITION_KEY)
    if position is None or max(abs(a - b) for a, b in zip(position, mount.position_m)) < _SAME_POSITION_M:
        return []
    fmt = lambda p: "[" + ", ".join(f"{x:g}" for x in p) + "]"   # noqa: E731
    return [f"{source}: a calibration of the IMU at [imu] position_m = {fmt(position)}, but this drive's is at "
            f"{fmt(mount.position_m)}: its biases hold for the same IMU moved, not for another vehicle's"]
