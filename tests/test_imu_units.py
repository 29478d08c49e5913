"""DBC unit strings to SI: spellings, the factors themselves, and clear errors."""

from __future__ import annotations

import math

import pytest

from imu import ImuConfigError, si_factor
from imu.units import STANDARD_GRAVITY_M_S2, normalize_unit, quantity_of


@pytest.mark.parametrize("unit, channel, factor", [
    ("deg/s", "gyro_x", math.pi / 180), ("°/s", "gyro_x", math.pi / 180), ("° / s", "gyro_x", math.pi / 180),
    # the degree sign's look-alikes: the masculine ordinal and the ring above
    ("º/s", "gyro_x", math.pi / 180), ("˚/s", "gyro_z", math.pi / 180), ("Deg/Sec", "gyro_y", math.pi / 180),
    ("dps", "gyro_z", math.pi / 180), ("degrees/second", "gyro_z", math.pi / 180),
    ("rad/s", "gyro_z", 1.0), ("rad/sec", "gyro_z", 1.0), ("mrad/s", "gyro_x", 1e-3),
    ("m/s^2", "accel_x", 1.0), ("m/s²", "accel_x", 1.0), ("m/s2", "accel_y", 1.0), ("m/s/s", "accel_z", 1.0),
    ("g", "accel_z", STANDARD_GRAVITY_M_S2), ("G", "accel_z", STANDARD_GRAVITY_M_S2),
    ("mg", "accel_y", STANDARD_GRAVITY_M_S2 / 1000),
    ("km/h", "speed", 1 / 3.6), ("KPH", "speed", 1 / 3.6), ("kmh", "speed", 1 / 3.6),
    ("m/s", "speed", 1.0), ("mph", "speed", 0.44704), ("mi/h", "speed", 0.44704),
])
def test_factor_to_si(unit, channel, factor):
    """Factors are exact definitions: 1 mile = 1609.344 m, 1 g = 9.80665 m/s^2, 1 deg = pi/180 rad."""
    assert si_factor(unit, channel, "x.dbc: M.S") == pytest.approx(factor, rel=1e-15)


def test_physical_checks():
    # 100 km/h is 27.78 m/s; 60 mph is 26.82 m/s; 90 deg/s is pi/2 rad/s
    assert 100 * si_factor("km/h", "speed", "") == pytest.approx(27.7778, abs=1e-4)
    assert 60 * si_factor("mph", "speed", "") == pytest.approx(26.8224, abs=1e-4)
    assert 90 * si_factor("deg/s", "gyro_z", "") == pytest.approx(math.pi / 2, rel=1e-15)


@pytest.mark.parametrize("unit, channel, pattern", [
    ("", "gyro_z", r"imu.dbc: IMU.RateZ has no unit; set \[can.units\] gyro_z to one of rad/s"),
    (None, "speed", r"has no unit; set \[can.units\] speed"),
    ("furlong/fortnight", "speed", r'unknown unit "furlong/fortnight" for speed \(speed\)'),
    ("deg", "gyro_x", r'unknown unit "deg"'),
    ("km/h", "gyro_x", r'unit "km/h" is a speed, but gyro_x needs an angular rate'),
    ("g", "speed", r'unit "g" is an acceleration, but speed needs a speed'),
])
def test_errors_name_signal_and_unit(unit, channel, pattern):
    with pytest.raises(ImuConfigError, match=pattern) as e:
        si_factor(unit, channel, "imu.dbc: IMU.RateZ")
    assert "\n" not in str(e.value)


def test_normalisation():
    assert normalize_unit(" Deg / Sec ") == "deg/s"
    assert normalize_unit("m/s²") == "m/s^2"
    assert quantity_of("rad/s") == "angular rate" and quantity_of("bar") is None
