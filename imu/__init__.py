"""IMU: calibrated angular rate, specific force and speed from CAN logs or a live bus.

``read_log`` turns a CAN log of any format python-can reads into the IMU table (vehicle frame,
SI units, one row per IMU sample, per-channel freshness flags); ``LiveSource`` yields the same
samples from a live python-can bus. The DBC (cantools) and ``[can.signals]`` say where each
channel is; units come from the DBC unit strings (:mod:`imu.units`). ``read_oxts`` makes the same
table of a KITTI OXTS recording (:mod:`imu.oxts`).
"""

from .can_source import LiveSource, StreamDecoder
from .config import ACCEL, CHANNELS, GYRO, CanMapping, ImuMount
from .dbc import DecodePlan, load_dbc, resolve
from .errors import DecodeError, ImuConfigError, ImuError
from .log_source import LOG_SUFFIXES, iter_messages, read_log
from .oxts import read_oxts
from .samples import (
    COLUMNS, FRESH_COLUMNS, VALUE_COLUMNS, ChannelStats, Gap, ImuSample, SourceStats, Summary, samples_frame,
)
from .units import si_factor

__all__ = [
    "read_log", "read_oxts", "LiveSource", "StreamDecoder", "iter_messages", "LOG_SUFFIXES",
    "ImuMount", "CanMapping", "CHANNELS", "GYRO", "ACCEL",
    "load_dbc", "resolve", "DecodePlan", "si_factor",
    "COLUMNS", "VALUE_COLUMNS", "FRESH_COLUMNS", "ImuSample", "Summary", "SourceStats", "ChannelStats", "Gap",
    "samples_frame",
    "ImuError", "ImuConfigError", "DecodeError",
]
