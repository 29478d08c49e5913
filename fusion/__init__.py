"""Fusion: EKF of CAN IMU rates and vision angles; road bank angle with its uncertainty."""

__all__ = ["frames"]


def __getattr__(name):
    # ``fusion.frames`` re-exports :mod:`vision.frames`, loaded on first use (numba: the command
    # line's start-up need not wait for it); ``import fusion.frames`` loads it too
    if name == "frames":
        import importlib

        return importlib.import_module(".frames", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
