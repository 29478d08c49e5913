"""Exceptions of the imu package."""

__all__ = ["ImuError", "ImuConfigError", "DecodeError"]


class ImuError(ValueError):
    """Root of the imu package's errors."""


class ImuConfigError(ImuError):
    """Bad ``[imu]``, ``[can]`` or ``[can.signals]`` settings, or a DBC that does not match them."""


class DecodeError(ImuError):
    """A log or DBC that cannot be read; the message names the file, line or frame ID."""
