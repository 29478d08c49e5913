"""Exceptions of the fusion package and the command line."""

__all__ = ["FusionError", "ConfigError", "InputError"]


class FusionError(ValueError):
    """Root of the errors that the command line reports as one line, exit status 2."""


class ConfigError(FusionError):
    """A config or scenario file has a missing, unknown or badly typed key."""


class InputError(FusionError):
    """An input file is missing, unreadable, or inconsistent with the others."""
