"""Physical units of CAN signals: the DBC unit string (or a ``[can.units]`` override) to SI.

Every IMU channel is delivered in SI: angular rate in rad/s, specific force in m/s^2, speed in
m/s. A signal's physical value (``raw * scale + offset`` from the DBC) is multiplied by the
factor of its unit; unit strings are matched after normalisation, so ``"deg/s"``, ``"°/s"``,
``"Deg/sec"`` and ``"dps"`` are the same unit. A unit that is not known, or that measures the
wrong quantity (``"km/h"`` for a gyro channel), is an :class:`~imu.errors.ImuConfigError`: a
wrong unit silently scales a rate by 57 or a speed by 3.6.
"""

from __future__ import annotations

import math
import re

from .errors import ImuConfigError

__all__ = ["STANDARD_GRAVITY_M_S2", "QUANTITY", "UNITS", "normalize_unit", "si_factor", "quantity_of"]

#: Standard gravity (CGPM 1901, ISO 80000-3), m/s^2 per g.
STANDARD_GRAVITY_M_S2 = 9.80665

#: What each channel measures.
QUANTITY = {
    "gyro_x": "angular rate", "gyro_y": "angular rate", "gyro_z": "angular rate",
    "accel_x": "acceleration", "accel_y": "acceleration", "accel_z": "acceleration",
    "speed": "speed",
}

#: SI unit of each quantity.
SI_UNIT = {"angular rate": "rad/s", "acceleration": "m/s^2", "speed": "m/s"}

#: Normalised unit spelling -> (quantity, factor to SI).
UNITS: dict[str, tuple[str, float]] = {}


def _add(quantity: str, factor: float, *spellings: str) -> None:
    for s in spellings:
        UNITS[s] = (quantity, factor)


_DEG = math.pi / 180.0
_add("angular rate", 1.0, "rad/s", "rads", "rad/sec", "radps", "radpersecond", "radians/s", "radian/s")
_add("angular rate", 1e-3, "mrad/s")
_add("angular rate", _DEG, "deg/s", "degs", "dps", "degps", "degpersecond", "degree/s", "degrees/s")
_add("angular rate", _DEG * 1e-3, "mdeg/s", "mdps")
_add("acceleration", 1.0, "m/s^2", "m/s2", "ms^-2", "ms-2", "m/s/s", "mps2", "mpss", "m/(s^2)", "m/(s*s)")
_add("acceleration", STANDARD_GRAVITY_M_S2, "g", "gn", "g0", "gravity")
_add("acceleration", STANDARD_GRAVITY_M_S2 * 1e-3, "mg", "milli-g", "millig")
_add("speed", 1.0, "m/s", "ms^-1", "ms-1", "mps", "meter/s", "metre/s", "meters/s", "metres/s")
_add("speed", 1.0 / 3.6, "km/h", "kmh", "kph", "km/hr", "kmph", "km/std")
_add("speed", 0.44704, "mph", "mi/h", "miles/h", "mile/h", "mi/hr")  # 1 mile = 1609.344 m exactly


def normalize_unit(unit: str) -> str:
    """Lower-case, spaces removed, common spellings folded (``"°/sec"`` -> ``"deg/s"``)."""
    u = unit.strip().lower().replace(" ", "").replace("\u00b7", "*")
    u = u.replace("\u00b2", "^2").replace("**", "^").replace("\u00b0", "deg")
    # the degree sign's look-alikes: the masculine ordinal (a Spanish or Italian keyboard's key)
    # and the ring above
    u = u.replace("\u00ba", "deg").replace("\u02da", "deg").replace("\u2212", "-")
    u = re.sub(r"(?<![a-z])(degrees|degree)(?![a-z])", "deg", u)
    u = re.sub(r"(?<![a-z])(radians|radian)(?![a-z])", "rad", u)
    u = re.sub(r"/(secs|sec|seconds|second)$", "/s", u)
    u = re.sub(r"(?<=[a-z])(/hours|/hour)$", "/h", u)
    return u


def quantity_of(unit: str) -> str | None:
    """The quantity a unit string measures, or None if it is not a known unit."""
    hit = UNITS.get(normalize_unit(unit))
    return hit[0] if hit else None


def si_factor(unit: str | None, channel: str, where: str) -> float:
    """Factor that turns a physical value in ``unit`` into SI for ``channel``.

    Parameters
    ----------
    unit : str or None
        Unit string from the DBC or from ``[can.units]``; None or empty means the DBC gives none.
    channel : str
        One of :data:`QUANTITY`'s keys (``"gyro_z"``); fixes the quantity expected.
    where : str
        What to name in errors, e.g. ``'imu.dbc: IMU_RATE.RateZ'``.

    Returns
    -------
    float
        Multiply the physical value by this to get rad/s, m/s^2 or m/s.

    Raises
    ------
    ImuConfigError
        No unit, an unknown unit, or a unit of another quantity.
    """
    want = QUANTITY[channel]
    if unit is None or not str(unit).strip():
        raise ImuConfigError(
            f"{where} has no unit; set [can.units] {channel} to one of "
            f"{', '.join(_examples(want))}"
        )
    hit = UNITS.get(normalize_unit(str(unit)))
    if hit is None:
        raise ImuConfigError(
            f'{where}: unknown unit "{unit}" for {channel} ({want}); known: {", ".join(_examples(want))}'
            + ("" if where.startswith("[can.units]") else f" (set [can.units] {channel} to override)")
        )
    quantity, factor = hit
    if quantity != want:
        raise ImuConfigError(f'{where}: unit "{unit}" is {_a(quantity)}, but {channel} needs {_a(want)}')
    return factor


def _a(noun: str) -> str:
    return ("an " if noun[0] in "aeiou" else "a ") + noun


def _examples(quantity: str) -> list[str]:
    return {"angular rate": ["rad/s", "deg/s", "mrad/s"],
            "acceleration": ["m/s^2", "g", "mg"],
            "speed": ["m/s", "km/h", "mph"]}[quantity]
