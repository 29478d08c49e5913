"""Fusion: EKF of CAN IMU rates and vision angles; road bank angle with its uncertainty."""

__all__ = ["frames"]


def __getattr__(name):
    # ``fusion.frames`` is :mod:`vision.frames`, loaded on first use (numba: the command line's
    # start-up need not wait for it)
    if name == "frames":
        import importlib

        return importlib.import_module("vision.frames")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
