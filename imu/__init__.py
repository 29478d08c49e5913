"""IMU: calibrated angular rate, specific force and speed from CAN logs or a live bus.

``read_log`` turns a CAN log of any format python-can reads into the IMU table (vehicle frame,
SI units, one row per IMU sample, per-channel freshness flags); ``LiveSource`` yields the same
samples from a live python-can bus. The DBC (cantools) and ``[can.signals]`` say where each
channel is; units come from the DBC unit strings (:mod:`imu.units`). ``read_oxts`` makes the same
table of a KITTI OXTS recording (:mod:`imu.oxts`).
"""

from .config import ACCEL, CHANNELS, GYRO, CanMapping, ImuMount
from .errors import BusError, DecodeError, ImuConfigError, ImuError
from .units import si_factor

__all__ = [
    "read_log", "read_oxts", "LiveSource", "StreamDecoder", "iter_messages", "LOG_SUFFIXES",
    "ImuMount", "CanMapping", "CHANNELS", "GYRO", "ACCEL",
    "load_dbc", "resolve", "DecodePlan", "si_factor",
    "COLUMNS", "VALUE_COLUMNS", "FRESH_COLUMNS", "ImuSample", "Summary", "SourceStats", "ChannelStats", "Gap",
    "samples_frame",
    "ImuError", "ImuConfigError", "DecodeError", "BusError",
]

#: What loads on first use (python-can, asammdf, cantools, pandas: half a second of imports that
#: a command's start-up, and a Ctrl-C during it, need not wait for; ``from imu import read_log``
#: works as before).
_LAZY = {
    "LiveSource": "can_source", "StreamDecoder": "can_source",
    "DecodePlan": "dbc", "load_dbc": "dbc", "resolve": "dbc",
    "LOG_SUFFIXES": "log_source", "iter_messages": "log_source", "read_log": "log_source",
    "read_oxts": "oxts",
    "COLUMNS": "samples", "FRESH_COLUMNS": "samples", "VALUE_COLUMNS": "samples", "ChannelStats": "samples",
    "Gap": "samples", "ImuSample": "samples", "SourceStats": "samples", "Summary": "samples",
    "samples_frame": "samples",
}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
