"""Exceptions of the imu package."""

__all__ = ["ImuError", "ImuConfigError", "DecodeError", "BusError"]


class ImuError(ValueError):
    """Root of the imu package's errors."""


class ImuConfigError(ImuError):
    """Bad ``[imu]``, ``[can]`` or ``[can.signals]`` settings, or a DBC that does not match them."""


class DecodeError(ImuError):
    """A log or DBC that cannot be read; the message names the file, line or frame ID."""


class BusError(ImuError):
    """A live bus that failed (closed, a driver error) or whose IMU frames stopped for longer than
    :class:`imu.LiveSource`'s ``imu_timeout_s``; raised after the samples still open are yielded."""
