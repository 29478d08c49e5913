"""How the IMU sits in the vehicle and how its channels are found on the CAN bus."""

from __future__ import annotations

import math
import numbers

from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Mapping

import numpy as np

from .errors import ImuConfigError
from .units import si_factor

#: The largest IMU position from the vehicle origin taken, m per axis (a truck is 20 m long; a
#: value in millimetres is not a position).
MAX_LEVER_ARM_M = 20.0

__all__ = ["CHANNELS", "GYRO", "ACCEL", "ImuMount", "CanMapping"]

GYRO = ("gyro_x", "gyro_y", "gyro_z")
ACCEL = ("accel_x", "accel_y", "accel_z")
#: IMU channels that ``[can.signals]`` may map, in the IMU's own axes (speed has none).
CHANNELS = GYRO + ACCEL + ("speed",)

_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class ImuMount:
    """IMU axes and lever arm.

    ``axes[i]`` names the IMU axis, with sign, that points along vehicle axis i: the contract's
    ``["x", "-y", "-z"]`` is an FRD-mounted IMU (vehicle y = -IMU y, vehicle z = -IMU z).
    ``position_m`` is the IMU origin in the vehicle frame, m.
    """

    axes: tuple[str, str, str] = ("x", "y", "z")
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        axes = tuple(str(a).strip().lower() for a in self.axes)
        if len(axes) != 3:
            raise ImuConfigError(f"[imu] axes needs three entries, got {[str(a) for a in self.axes]}")
        names = [a.lstrip("+-") for a in axes]
        if sorted(names) != ["x", "y", "z"] or any(len(a) - len(n) > 1 for a, n in zip(axes, names)):
            raise ImuConfigError(
                f'[imu] axes must be a signed permutation of "x", "y", "z", got {[str(a) for a in self.axes]}'
            )
        # one spelling of each axis ("+x" is "x"): a calibration compares them (a review)
        object.__setattr__(self, "axes", tuple(a[1:] if a.startswith("+") else a for a in axes))
        if abs(np.linalg.det(self.R_v_from_imu) - 1.0) > 1e-9:
            raise ImuConfigError(f"[imu] axes {list(axes)} is a reflection, not a rotation")
        p = tuple(float(x) for x in self.position_m)
        if len(p) != 3 or not all(math.isfinite(x) for x in p):
            raise ImuConfigError(f"[imu] position_m needs three finite numbers, got {list(p)}")
        if max(abs(x) for x in p) > MAX_LEVER_ARM_M:
            raise ImuConfigError(f"[imu] position_m {list(p)}: more than {MAX_LEVER_ARM_M:g} m from the vehicle origin "
                                 "(the front wheel's contact point): metres expected")
        object.__setattr__(self, "position_m", p)

    @property
    def R_v_from_imu(self) -> np.ndarray:
        """Signed permutation taking IMU-axis vectors to vehicle-frame vectors."""
        R = np.zeros((3, 3))
        for i, a in enumerate(self.axes):
            R[i, _AXIS_INDEX[a[-1]]] = -1.0 if a.startswith("-") else 1.0
        return R


def split_signal(ref: str) -> tuple[str, bool]:
    """``[can.signals]``'s ``"MESSAGE.SIGNAL"`` or ``"-MESSAGE.SIGNAL"`` (a signal counted the
    other way than its IMU axis): the reference without the sign, and whether it had one."""
    return (ref[1:], True) if ref.startswith("-") else (ref, False)


@dataclass(frozen=True)
class CanMapping:
    """Where each IMU channel lives on the bus.

    ``signals`` maps channel names of :data:`CHANNELS` to ``"MESSAGE.SIGNAL"``; ``units``
    overrides the DBC unit string per channel; gaps longer than ``gap_limit_s`` are reported
    and never interpolated across.

    Attributes
    ----------
    align_window_s : float
        Frames of the other IMU messages join the sample of the clock message (the message of
        the first mapped gyro/accel channel) when they are at most this far from it in time, s.
        Rate and acceleration frames of one IMU sample arrive a few hundred microseconds apart.
    range_check : bool
        Values outside the DBC signal's ``[minimum|maximum]`` are invalid (NaN, not fresh) when
        True; when False they are passed on and only counted. Some real DBCs (opendbc) give raw
        ranges such as ``[0|65535]`` for signed quantities and need False.
    pad_short_frames : bool
        Frames shorter than the DBC length are zero-padded and decoded (counted as padded) when
        True, skipped and counted as wrong length when False. Some loggers drop trailing zero
        bytes (comma2k19's raw arrays).
    reorder_tolerance_s : float
        How far a mapped frame's timestamp may lie behind the newest accepted one (of another
        frame ID) and still be taken, s. 0 (the default): a log is in time order, as one bus's
        logger writes it. A log merged from several buses (``candump any``, two interfaces)
        can hold frames of different IDs a little out of order; with a tolerance they are
        taken in time order (the live decoder holds frames that long before it aligns them:
        that much latency). Within one frame ID the order must hold.
    channel : int, str or None
        Decode only frames from this bus channel as python-can reports it for the log format
        (``0`` for .asc/.blf, ``"can0"`` for candump .log); None takes every channel but stops
        with an error if a mapped frame ID shows up on more than one.
    """

    dbc_path: Path | None               # None: given elsewhere (a command's --dbc), before decoding
    signals: Mapping[str, str]
    units: Mapping[str, str] = field(default_factory=dict)
    gap_limit_s: float = 0.1
    align_window_s: float = 0.002
    range_check: bool = True
    pad_short_frames: bool = False
    channel: int | str | None = None
    reorder_tolerance_s: float = 0.0

    def __post_init__(self) -> None:
        for ch, ref in self.signals.items():
            if ch not in CHANNELS:
                raise ImuConfigError(f"[can.signals] {ch}: unknown channel, expected one of {', '.join(CHANNELS)}")
            body, negated = split_signal(ref) if isinstance(ref, str) else (ref, False)
            if negated and ch == "speed":
                raise ImuConfigError(f'[can.signals] speed = {ref!r}: a speed has no axis to count the other way '
                                     "(its sign is the DBC's)")
            if not isinstance(body, str) or body.count(".") != 1 or body.startswith((".", "-")) or body.endswith("."):
                raise ImuConfigError(f'[can.signals] {ch} must be "MESSAGE.SIGNAL" (or "-MESSAGE.SIGNAL" for a '
                                     f"signal counted the other way), got {ref!r}")
        for ch, unit in self.units.items():
            if ch not in self.signals:
                raise ImuConfigError(f"[can.units] {ch}: no such mapped channel")
            si_factor(unit, ch, f"[can.units] {ch}")   # a unit of its quantity: said at the config, not at decode
        if not (self.gap_limit_s > 0 and math.isfinite(self.gap_limit_s)):
            raise ImuConfigError(f"[can] gap_limit_s must be > 0, got {self.gap_limit_s}")
        if not 0 < self.align_window_s < self.gap_limit_s:
            raise ImuConfigError(
                f"[can] align_window_s must be > 0 and < gap_limit_s = {self.gap_limit_s}, got {self.align_window_s}"
            )
        if isinstance(self.reorder_tolerance_s, bool) or not isinstance(self.reorder_tolerance_s, numbers.Real) \
                or not 0 <= self.reorder_tolerance_s <= 1.0:
            raise ImuConfigError(f"[can] reorder_tolerance_s must be in 0 .. 1 s, got {self.reorder_tolerance_s}")
        if not any(ch in self.signals for ch in GYRO + ACCEL):
            raise ImuConfigError(
                f"[can.signals] maps no gyro or accel channel (got {', '.join(self.signals) or 'none'}): "
                "an IMU needs at least one"
            )
        if isinstance(self.channel, numbers.Integral) and not isinstance(self.channel, bool):
            object.__setattr__(self, "channel", int(self.channel))   # numpy integers too
        if self.channel is not None and (isinstance(self.channel, bool) or not isinstance(self.channel, (int, str))):
            raise ImuConfigError(f"[can] channel must be an integer or a string, got {self.channel!r}")
        for key in ("range_check", "pad_short_frames"):
            if not isinstance(getattr(self, key), (bool, np.bool_)):
                raise ImuConfigError(f"[can] {key} must be true or false, got {getattr(self, key)!r}")
        if self.dbc_path is not None:
            object.__setattr__(self, "dbc_path", Path(self.dbc_path))
        object.__setattr__(self, "signals", MappingProxyType(dict(self.signals)))
        object.__setattr__(self, "units", MappingProxyType(dict(self.units)))
