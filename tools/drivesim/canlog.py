"""The simulator's CAN side: IMU and wheel-speed samples onto a CAN log, through a real DBC.

The bus (``data/vifusion_imu.dbc``) is a simulated motorcycle powertrain CAN at 500 kbit/s:

==============  =========  ======  =====================================================
message         ID         rate    content
==============  =========  ======  =====================================================
IMU_RATE        0x174      IMU     RateX/Y/Z, 0.005 deg/s per bit (Intel), status, counter, CRC
IMU_ACC         0x178      IMU     AccX/Y/Z, 0.0001274 g per bit, sent ``ACC_DELAY_S`` after IMU_RATE
ABS_SPEED       0x122      speed   WheelSpeedFront/Rear, 0.01 km/h per bit (Motorola), counter, CRC
ENGINE_1        0x100      100 Hz  engine speed, throttle, gear (extra traffic)
ENGINE_2        0x500      10 Hz   temperatures, battery voltage (extra traffic)
DASH_STATUS     0x3E8      10 Hz   multiplexed: odometer / trip and fuel / ride mode (extra traffic)
CCVS1           0x18FEF100 10 Hz   extended ID, J1939-style vehicle speed (extra traffic)
TPMS_STATUS     0x18FF5021 2 Hz    extended ID, tyre pressures (extra traffic)
(NM frames)     0x51A      10 Hz   network management, not in the DBC (extra traffic)
==============  =========  ======  =====================================================

The IMU layout follows a Bosch MM5.10-class sensor (rates in deg/s, accelerations in g); without a
pitch-rate channel (``include_pitch_rate=False``, as the MM5.10) RateY carries 0xFFFF, its "SNA"
value, which lies outside the DBC range, and :func:`signal_map` leaves ``gyro_y`` out.

Every payload is encoded by cantools from the DBC; every file is written by python-can's writer
for the suffix. :func:`write_can_log` returns the offset between drive time and the timestamps
python-can's ``LogReader`` gives back for that file (``tests/test_canlog.py`` checks it for every
frame of every format).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import can
import cantools
import numpy as np
import pandas as pd

__all__ = ["DBC_PATH", "ACC_DELAY_S", "LOG_FORMATS", "signal_map", "imu_ranges", "write_can_log", "clock_offset_s"]

#: The simulator's DBC; the simulator copies it next to the log.
DBC_PATH = Path(__file__).resolve().parent / "data" / "vifusion_imu.dbc"
#: IMU_ACC is sent this long after IMU_RATE (at most a quarter of the IMU period), s.
ACC_DELAY_S = 350e-6
#: Suffixes write_can_log writes (python-can writers).
LOG_FORMATS = (".asc", ".blf", ".log", ".trc", ".csv", ".mf4")
#: BLF start times before this (1990-01-01) are stored as "no date" by python-can.
_BLF_MIN_EPOCH_S = 631152000

_IMU_COLUMNS = ("gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s", "accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2")
_G = 9.80665  # m/s^2 per g, standard gravity
_SNA_16 = 0xFFFF


def signal_map(include_pitch_rate: bool = True) -> dict[str, str]:
    """``[can.signals]`` for :data:`DBC_PATH`: IMU channels (IMU axes) and speed."""
    m = {"gyro_x": "IMU_RATE.RateX", "gyro_y": "IMU_RATE.RateY", "gyro_z": "IMU_RATE.RateZ",
         "accel_x": "IMU_ACC.AccX", "accel_y": "IMU_ACC.AccY", "accel_z": "IMU_ACC.AccZ",
         "speed": "ABS_SPEED.WheelSpeedFront"}
    if not include_pitch_rate:
        del m["gyro_y"]
    return m


def imu_ranges(dbc_path=None, include_pitch_rate: bool = True) -> dict[str, tuple[float, float, str]]:
    """What each column of :func:`write_can_log`'s ``imu`` table can carry: ``(low, high,
    signal)``, the DBC range of its signal in the table's units (rad/s, m/s^2) and the signal's
    ``MESSAGE.SIGNAL``. A value at either end or beyond is written as that end (saturated,
    :func:`_encode`); without the pitch rate ``gyro_y_rad_s`` is not sent and not listed."""
    db = cantools.database.load_file(dbc_path or DBC_PATH)
    out = {}
    for col, name in zip(_IMU_COLUMNS, ("RateX", "RateY", "RateZ", "AccX", "AccY", "AccZ")):
        if col == "gyro_y_rad_s" and not include_pitch_rate:
            continue
        msg = db.get_message_by_name("IMU_RATE" if col.startswith("gyro") else "IMU_ACC")
        sig = msg.get_signal_by_name(name)
        to_si = math.radians(1.0) if col.startswith("gyro") else _G    # as _imu_frames encodes them
        out[col] = (sig.minimum * to_si, sig.maximum * to_si, f"{msg.name}.{name}")
    return out


def _crc8_j1850(data: bytes) -> int:
    crc = 0xFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def _with_crc(payload: bytes) -> bytes:
    return payload[:7] + bytes([_crc8_j1850(payload[:7])])


def _check_table(df: Any, name: str, columns: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(df, pd.DataFrame):
        raise ValueError(f"{name} must be a pandas DataFrame, got {type(df).__name__}")
    missing = [c for c in ("t_s",) + columns if c not in df.columns]
    if missing:
        raise ValueError(f"{name} lacks column(s) {', '.join(missing)}")
    t = df["t_s"].to_numpy(dtype=float)
    v = df[list(columns)].to_numpy(dtype=float)
    if len(t) == 0:
        raise ValueError(f"{name} has no rows")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
        raise ValueError(f"{name} has NaN or infinite values")
    if np.any(np.diff(t) <= 0):
        raise ValueError(f"{name}.t_s must increase strictly")
    return t, v


def clock_offset_s(suffix: str, start_epoch_s: float, t_first_s: float) -> float | None:
    """Offset ``LogReader timestamp - drive time`` for a python-can writer, when it is known a priori.

    Frames are written with timestamps ``start_epoch_s + t`` (t in drive time, s). python-can's
    readers give back: ``.blf .log .csv .mf4`` the absolute timestamp (``.blf`` stores the start
    in its header; before 1990 it stores "no date" and times count from the first frame's
    millisecond); ``.asc`` seconds since the first frame; ``.trc`` the first frame's time from its
    header (rounded to a microsecond) plus milliseconds since it, so its offset is read back from
    the file (returns None here).
    """
    suffix = suffix.lower()
    if suffix in (".log", ".csv", ".mf4"):
        return float(start_epoch_s)
    if suffix == ".blf":
        first = start_epoch_s + t_first_s
        if first >= _BLF_MIN_EPOCH_S:
            return float(start_epoch_s)
        return float(start_epoch_s - int(first * 1000) / 1000)
    if suffix == ".asc":
        return -float(t_first_s)
    return None


def write_can_log(out_path, imu, speed, *, dbc_path=None, start_epoch_s=1.7e9, extra_traffic=True,
                  include_pitch_rate=True, seed=0) -> float:
    """Write IMU and wheel-speed samples as a CAN log, encoded through the DBC.

    Parameters
    ----------
    out_path : str or Path
        Log file; its suffix (``.asc .blf .log .trc .csv .mf4``) picks python-can's writer.
    imu : pandas.DataFrame
        ``t_s`` (drive time, s, strictly increasing), ``gyro_x_rad_s`` .. ``gyro_z_rad_s`` (rad/s)
        and ``accel_x_m_s2`` .. ``accel_z_m_s2`` (specific force, m/s^2) in the IMU's OWN axes,
        noise and bias applied. IMU_RATE is sent at ``t_s``, IMU_ACC ``min(ACC_DELAY_S, period/4)``
        later. Values beyond the DBC range saturate at it, as the sensor's output would.
    speed : pandas.DataFrame
        ``t_s`` (s), ``speed_m_s`` (wheel speed, m/s, clipped at 0), sent as ABS_SPEED at ``t_s``.
    dbc_path : str or Path, optional
        Database to encode with (default :data:`DBC_PATH`); must hold the messages of
        :func:`signal_map` and, with ``extra_traffic``, those of the extra traffic.
    start_epoch_s : float
        Wall-clock time (Unix epoch, s) of drive time 0, >= 0.
    extra_traffic : bool
        Add the engine, dashboard (multiplexed), J1939 (extended IDs), TPMS and NM frames.
    include_pitch_rate : bool
        False: an IMU without pitch rate (RateY = SNA); see :func:`signal_map`.
    seed : int
        Seed of the extra traffic's content and phases.

    Returns
    -------
    float
        ``clock_offset_s``: python-can's ``LogReader(out_path)`` returns, with default
        arguments, ``t + clock_offset_s`` for a frame sent at drive time ``t`` (to the format's
        time resolution: 1 us for .asc/.log/.trc, 1 ns for .blf, float64 for .csv/.mf4, and
        float64 at the epoch, about 0.24 us at 1.7e9 s).
    """
    out_path = Path(out_path)
    suffix = out_path.suffix.lower()
    if suffix not in LOG_FORMATS:
        raise ValueError(f"{out_path}: unsupported log suffix {suffix!r}, expected one of {', '.join(LOG_FORMATS)}")
    if not (isinstance(start_epoch_s, (int, float)) and math.isfinite(start_epoch_s) and start_epoch_s >= 0):
        raise ValueError(f"start_epoch_s must be a finite number >= 0, got {start_epoch_s!r}")
    t_imu, v_imu = _check_table(imu, "imu", _IMU_COLUMNS)
    t_spd, v_spd = _check_table(speed, "speed", ("speed_m_s",))
    db = cantools.database.load_file(dbc_path or DBC_PATH)
    frames = _imu_frames(db, t_imu, v_imu, include_pitch_rate) + _speed_frames(db, t_spd, v_spd[:, 0])
    if extra_traffic:
        t0 = min(t_imu[0], t_spd[0])
        t1 = max(t_imu[-1], t_spd[-1])
        frames += _extra_frames(db, t0, t1, t_spd, v_spd[:, 0], np.random.default_rng(seed))
    # bus order: time, then arbitration priority (lower ID first) for equal times
    frames.sort(key=lambda f: (f[0], f[1], f[2]))
    t_first = frames[0][0]
    out_path.parent.mkdir(parents=True, exist_ok=True)
    with can.Logger(out_path) as writer:
        _drive_header(writer, out_path, start_epoch_s + t_first)
        for t, aid, ext, payload in frames:
            writer.on_message_received(can.Message(
                timestamp=start_epoch_s + t, arbitration_id=aid, is_extended_id=ext, data=payload,
                dlc=len(payload), channel=0, is_rx=True,
            ))
    offset = clock_offset_s(suffix, start_epoch_s, t_first)
    if offset is None:  # .trc: the first frame reads back as the header's start time exactly
        with can.LogReader(out_path) as reader:
            first = next(iter(reader))
        offset = first.timestamp - t_first
    return float(offset) + 0.0  # no -0.0 when the first frame is at drive time 0


def _drive_header(writer: Any, out_path: Path, first_epoch_s: float) -> None:
    """The header fields python-can's writers take from the machine, taken from the drive: the
    ASC ``date`` line (the time of writing) as the first frame's time, as its ``Begin
    Triggerblock`` line has it; the TRC file name (the absolute path written to, a simulation's
    ``.partial`` folder) as the file's name; the MF4 start time (the time of writing, which the
    frames' times are stored relative to) as the first frame's. A simulated drive is then the
    same to the byte when simulated again on the same machine."""
    from datetime import datetime

    if isinstance(writer, can.ASCWriter):        # its three header lines are written, nothing else yet
        date = writer._format_header_datetime(datetime.fromtimestamp(first_epoch_s))
        writer.file.seek(0)
        writer.file.truncate()
        writer.file.write(f"date {date}\nbase hex  timestamps absolute\ninternal events logged\n")
    elif isinstance(writer, can.TRCWriter):      # its header is written with the first frame
        writer.filepath = out_path.name
    elif isinstance(writer, can.MF4Writer):      # its start time, which the frames' times count from
        writer._mdf.header.start_time = datetime.fromtimestamp(first_epoch_s)
        writer.last_timestamp = writer._start_time = first_epoch_s


def _encode(msg: Any, values: dict[str, float]) -> bytes:
    """The frame of ``values``, each saturated at its signal's DBC range as a sensor's output
    saturates: at the last raw value that is a measurement. The simulator's DBC names the top
    raw value of each IMU signal "SNA", and cantools rounds the range's maximum onto it, so a
    saturated value read back as "no measurement" (a review: an accelerometer bias of 1e5 m/s^2
    gave "accel_x never seen"); it is stepped back one resolution from such a value."""
    from imu.dbc import invalid_choice

    clipped, saturated = {}, []
    for sig in msg.signals:
        if sig.name not in values:
            continue
        v = values[sig.name]
        if sig.minimum is not None and sig.maximum is not None:
            if not sig.minimum < v < sig.maximum:   # at the range's end or beyond (NaN: as before)
                if v == v:
                    saturated.append(sig)
            v = min(max(v, sig.minimum), sig.maximum)
        clipped[sig.name] = v
    data = bytes(msg.encode(clipped, scaling=True, padding=False, strict=True))
    for _ in range(4):
        raw = msg.decode(data, decode_choices=False, scaling=False) if saturated else {}
        bad = [sig for sig in saturated if invalid_choice(str((sig.choices or {}).get(raw[sig.name], "")))]
        if not bad:
            return data
        for sig in bad:   # one resolution back into the range
            clipped[sig.name] -= math.copysign(abs(sig.scale), clipped[sig.name] - (sig.minimum + sig.maximum) / 2)
        data = bytes(msg.encode(clipped, scaling=True, padding=False, strict=True))
    return data


def _imu_frames(db: Any, t: np.ndarray, v: np.ndarray, pitch: bool) -> list[tuple]:
    rate = db.get_message_by_name("IMU_RATE")
    acc = db.get_message_by_name("IMU_ACC")
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.01
    delay = min(ACC_DELAY_S, period / 4)
    deg = np.degrees(v[:, :3])
    g = v[:, 3:] / _G
    out = []
    for i in range(len(t)):
        counter = i % 16
        rv = {"RateX": deg[i, 0], "RateY": deg[i, 1] if pitch else 0.0, "RateZ": deg[i, 2],
              "RateStatus": 0 if pitch else 0b0010, "RateCounter": counter, "RateCRC": 0}
        payload = bytearray(_encode(rate, rv))
        if not pitch:  # no pitch-rate channel: RateY carries its SNA value
            payload[2:4] = _SNA_16.to_bytes(2, "little")
        out.append((float(t[i]), rate.frame_id, False, _with_crc(bytes(payload))))
        av = {"AccX": g[i, 0], "AccY": g[i, 1], "AccZ": g[i, 2], "AccStatus": 0, "AccCounter": counter, "AccCRC": 0}
        out.append((float(t[i]) + delay, acc.frame_id, False, _with_crc(_encode(acc, av))))
    return out


def _speed_frames(db: Any, t: np.ndarray, v_m_s: np.ndarray) -> list[tuple]:
    msg = db.get_message_by_name("ABS_SPEED")
    out = []
    for i in range(len(t)):
        kmh = max(float(v_m_s[i]), 0.0) * 3.6
        payload = _encode(msg, {"WheelSpeedFront": kmh, "WheelSpeedRear": kmh, "AbsActiveFront": 0,
                                "AbsActiveRear": 0, "AbsCounter": i % 16, "AbsCRC": 0})
        out.append((float(t[i]), msg.frame_id, False, _with_crc(payload)))
    return out


def _grid(t0: float, t1: float, period_s: float, rng: np.random.Generator) -> np.ndarray:
    """Send times on a microsecond grid: a random phase, the period, up to 50 us of jitter."""
    phase = rng.uniform(0.0, period_s)
    n = int(math.floor((t1 - t0 - phase) / period_s)) + 1 if t1 - t0 > phase else 0
    t = t0 + phase + period_s * np.arange(max(n, 0)) + rng.uniform(0.0, 50e-6, max(n, 0))
    return np.round(t * 1e6) / 1e6


def _extra_frames(db: Any, t0: float, t1: float, t_spd: np.ndarray, v_spd: np.ndarray,
                  rng: np.random.Generator) -> list[tuple]:
    """Other nodes' traffic: engine, dashboard (multiplexed), J1939 (extended), TPMS, NM."""
    def speed_at(t: np.ndarray) -> np.ndarray:
        return np.interp(t, t_spd, v_spd)

    out: list[tuple] = []
    eng1 = db.get_message_by_name("ENGINE_1")
    ts = _grid(t0, t1, 0.010, rng)
    v = speed_at(ts)
    for k, t in enumerate(ts):
        gear = int(min(6, max(1, 1 + v[k] // 8)))
        rpm = float(min(12000.0, 1200.0 + 9.55 * v[k] / 0.3 * (3.2 - 0.3 * gear) * 2.5))
        out.append((float(t), eng1.frame_id, False, _encode(eng1, {
            "EngineSpeed": rpm, "ThrottlePosition": float(20 + 10 * math.sin(0.3 * t)), "GearPosition": gear,
            "ClutchSwitch": 0, "EngineTorque": float(30 + rng.normal(0, 2))})))
    eng2 = db.get_message_by_name("ENGINE_2")
    for t in _grid(t0, t1, 0.100, rng):
        out.append((float(t), eng2.frame_id, False, _encode(eng2, {
            "CoolantTemp": 88.0, "OilTemp": 95.0, "BatteryVoltage": 13.8, "AmbientTemp": 21.0})))
    dash = db.get_message_by_name("DASH_STATUS")
    odo = 12345.6
    for k, t in enumerate(_grid(t0, t1, 0.100, rng)):
        mux = k % 3
        values = [{"DashMux": 0, "Odometer": odo + float(t) * 0.02},
                  {"DashMux": 1, "TripA": 123.4, "FuelLevel": 62.5},
                  {"DashMux": 2, "RideMode": 2, "TurnIndicators": 0, "HighBeam": 0}][mux]
        out.append((float(t), dash.frame_id, False, bytes(dash.encode(values, strict=True))))
    ccvs = db.get_message_by_name("CCVS1")
    ts = _grid(t0, t1, 0.100, rng)
    for t, vv in zip(ts, speed_at(ts)):
        out.append((float(t), ccvs.frame_id, True, _encode(ccvs, {
            "WheelBasedVehicleSpeed": float(max(vv, 0.0) * 3.6), "CruiseControlActive": 0})))
    tpms = db.get_message_by_name("TPMS_STATUS")
    for t in _grid(t0, t1, 0.500, rng):
        out.append((float(t), tpms.frame_id, True, _encode(tpms, {
            "FrontPressure": 228.0, "RearPressure": 248.0, "FrontTemp": 35.0, "RearTemp": 38.0})))
    for t in _grid(t0, t1, 0.100, rng):  # AUTOSAR-style NM frame of node 0x1A, not in the DBC
        out.append((float(t), 0x51A, False, bytes([0x1A, 0x10, 0, 0, 0, 0, 0, 0])))
    return out
