"""IMU samples: alignment of the decoded frames to common sample times, the vehicle frame, the table.

Alignment rule (the same in the log path here and in the streaming path of
:mod:`imu.can_source`; ``tests/test_imu_align.py`` checks that they agree):

* every accepted frame of the *clock* source (the message of the first mapped gyro/accel channel)
  opens one sample, at that frame's time ``T``;
* a frame of another IMU source at time ``t`` joins the earliest sample with
  ``t - align_window_s <= T <= t + align_window_s``; if that sample already holds a frame of the
  same source, the earlier frame wins and the later one is counted as unaligned; a frame with no
  sample in reach is unaligned;
* speed is held: each sample takes the latest valid speed frame with ``t_speed < T`` if it is at
  most ``gap_limit_s`` old, else NaN; ``fresh_speed`` marks samples that got a new one.

Gyro and accel values are never held or interpolated: a channel without a valid frame in the
sample is NaN with its ``fresh_*`` flag False. Values are rotated into the vehicle frame
(ISO 8855) with :attr:`ImuMount.R_v_from_imu` and stay at the IMU's location: lever-arm
compensation is the filter's job (:attr:`ImuMount.position_m`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, Iterable

import numpy as np
import pandas as pd

from .config import ACCEL, CHANNELS, GYRO, ImuMount

__all__ = [
    "VALUE_COLUMNS", "FRESH_COLUMNS", "COLUMNS", "ImuSample", "Gap", "SourceStats", "ChannelStats",
    "Summary", "vehicle_channel_map", "unavailable_channels", "never_seen", "align", "make_frame", "samples_frame",
    "rate_hz", "median_period_s",
]

_UNIT_SUFFIX = {"gyro": "rad_s", "accel": "m_s2", "speed": "m_s"}
#: Value columns, vehicle frame, in the order of :data:`imu.config.CHANNELS`.
VALUE_COLUMNS = tuple(f"{ch}_{_UNIT_SUFFIX[ch.split('_')[0]]}" for ch in CHANNELS)
#: One boolean per channel: True where the sample holds a new, valid measurement.
FRESH_COLUMNS = tuple(f"fresh_{ch}" for ch in CHANNELS)
#: All columns of the IMU table.
COLUMNS = ("t_s",) + VALUE_COLUMNS + FRESH_COLUMNS


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One IMU sample in the vehicle frame, as the live source yields it (a row of the table).

    ``t_s`` is the clock frame's timestamp (bus clock); rates in rad/s, specific force in m/s^2,
    speed in m/s, NaN where the channel has no valid value; ``fresh_*`` as in the table.
    ``received_s`` is ``time.perf_counter()`` when the frame that released the sample (the one
    that completed it, or showed that nothing more can join) was received; not part of the table.
    """

    t_s: float
    gyro_x_rad_s: float
    gyro_y_rad_s: float
    gyro_z_rad_s: float
    accel_x_m_s2: float
    accel_y_m_s2: float
    accel_z_m_s2: float
    speed_m_s: float
    fresh_gyro_x: bool
    fresh_gyro_y: bool
    fresh_gyro_z: bool
    fresh_accel_x: bool
    fresh_accel_y: bool
    fresh_accel_z: bool
    fresh_speed: bool
    received_s: float = math.nan

    def row(self) -> tuple:
        """The table row (``COLUMNS`` order)."""
        return tuple(getattr(self, c) for c in COLUMNS)


@dataclass(frozen=True)
class Gap:
    """No accepted frame of ``source`` for ``duration_s`` (> gap_limit_s) after ``start_s``."""

    source: str
    start_s: float
    duration_s: float


#: Why a mapped frame was not used (:class:`SourceStats` counts each); ``other_channel`` is
#: expected when ``[can] channel`` picks one bus of a multi-channel log.
SKIP_KINDS = ("wrong_length", "duplicates", "backwards", "remote", "other_channel", "bad_timestamp", "unaligned")


@dataclass(frozen=True)
class SourceStats:
    """Frame counts of one mapped source (a message, or one multiplexer value of it).

    ``frames`` were accepted (decoded); the others were skipped for the reason named.
    ``rate_hz`` is the mean rate of accepted frames (gaps included).
    """

    name: str
    frame_id: str
    frames: int
    rate_hz: float
    wrong_length: int = 0
    padded: int = 0
    excess_length: int = 0
    duplicates: int = 0
    backwards: int = 0
    remote: int = 0
    other_channel: int = 0
    bad_timestamp: int = 0
    unaligned: int = 0
    #: Times the live decoder moved the message to another bus channel (no ``[can] channel``:
    #: the one it came on first fell silent while another carried it).
    channel_relocked: int = 0
    gaps: tuple[Gap, ...] = ()
    #: Times of the first and last accepted frame (on the current bus clock, live), s.
    first_s: float = math.nan
    last_s: float = math.nan

    @property
    def skipped(self) -> int:
        return sum(getattr(self, k) for k in SKIP_KINDS)


@dataclass(frozen=True)
class ChannelStats:
    """One mapped channel (IMU axes) and the vehicle column it feeds.

    ``decoded`` frames carried a valid value; ``invalid`` did not (outside the DBC range with
    ``range_check``, or the signal's invalid raw value); ``out_of_range`` counts values outside
    the DBC range whether or not they were kept.
    """

    channel: str
    column: str
    ref: str
    unit: str
    decoded: int
    invalid: int
    out_of_range: int
    rate_hz: float
    #: The DBC's ``[minimum|maximum]`` of the signal (None where it gives none), in ``unit``.
    minimum: float | None = None
    maximum: float | None = None

    @property
    def dbc_range(self) -> str:
        """`` [minimum|maximum] unit`` as the messages quote it ("" where the DBC gives none)."""
        if self.minimum is None or self.maximum is None:
            return ""
        return f" [{self.minimum:g}|{self.maximum:g}] {self.unit}"


#: A source that starts this long after the clock message, or stops this long before it, is
#: said in the summary (s).
LATE_START_S = 1.0


@dataclass(frozen=True)
class Summary:
    """What a log or a live stream gave: counts, rates, gaps, and what went wrong.

    ``complete`` is False when the reader stopped before the end of the file (truncated or
    corrupt binary log): the table then holds what came before.
    """

    log: str
    frames_read: int
    frames_mapped: int
    samples: int
    duration_s: float
    sample_rate_hz: float
    clock: str
    sources: tuple[SourceStats, ...]
    channels: tuple[ChannelStats, ...]
    unavailable: tuple[str, ...]
    unknown_ids: dict[str, int] = field(default_factory=dict)
    #: Frames of unknown IDs not counted by ID (the live decoder keeps the first 1000 IDs).
    unknown_more_frames: int = 0
    unmapped_frames: int = 0
    error_frames: int = 0
    bad_lines: int = 0
    reader_warnings: int = 0
    problems: tuple[str, ...] = ()
    complete: bool = True
    stop_reason: str = ""             # why the read stopped early (one of ``problems``)
    range_check: bool = True          # ``[can] range_check``: values outside the DBC range made invalid

    @property
    def decode_errors(self) -> int:
        """Mapped frames that were not used, for any reason, plus unreadable log lines."""
        return sum(s.skipped for s in self.sources) + self.bad_lines

    @property
    def gaps(self) -> tuple[Gap, ...]:
        return tuple(g for s in self.sources for g in s.gaps)

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON types (for ``DataFrame.attrs`` and parquet metadata)."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["sources"] = [{**{f.name: getattr(s, f.name) for f in fields(s)},
                         "gaps": [[g.source, g.start_s, g.duration_s] for g in s.gaps]} for s in self.sources]
        d["channels"] = [{f.name: getattr(c, f.name) for f in fields(c)} for c in self.channels]
        d["decode_errors"] = self.decode_errors
        return _jsonable(d)

    def span_lines(self) -> list[str]:
        """Sources that start more than :data:`LATE_START_S` after the clock message or stop
        that long before it: not gaps between two frames, which the gap finder sees (a wheel
        speed that came 6 s late had read 'gaps: none')."""
        clock = next((s for s in self.sources if s.name == self.clock), None)
        if clock is None or not clock.frames:
            return []
        out = []
        for s in self.sources:
            if s is clock or not s.frames:
                continue
            late, early = s.first_s - clock.first_s, clock.last_s - s.last_s
            if late > LATE_START_S:
                out.append(f"source {s.name} starts {late:.1f} s after {self.clock}")
            if early > LATE_START_S:
                out.append(f"source {s.name} stops {early:.1f} s before {self.clock}")
        return out

    def range_lines(self) -> list[str]:
        """Channels with values outside their DBC ``[minimum|maximum]`` that ``range_check`` made
        invalid, each with the count and the key that keeps them: a DBC with a wrong range (or a
        signal declared float that is not) had dropped them with no word of the range (a review)."""
        if not self.range_check:
            return []
        out = []
        for c in self.channels:
            if c.out_of_range:
                out.append(f"{c.column} ({c.ref}): {c.out_of_range} of {c.decoded + c.invalid} values outside the "
                           f"DBC's range{c.dbc_range} were dropped as invalid ([can] range_check = false keeps them)")
        return out

    def lines(self) -> list[str]:
        """Human-readable report, one item per line."""
        out = [f"log: {self.log}: {self.frames_read} frames read, {self.frames_mapped} of mapped messages"
               + ("" if self.complete else " (READ STOPPED EARLY, see problems)")]
        out.append(f"samples: {self.samples} over {self.duration_s:.3f} s at {self.sample_rate_hz:.1f} Hz "
                   f"(clock: {self.clock})")
        out.append("channel  column          signal                           unit    decoded  invalid  out_of_range  rate_Hz")
        for c in self.channels:
            out.append(f"{c.channel:<8} {c.column:<15} {c.ref:<32} {c.unit:<7} {c.decoded:>7}  {c.invalid:>7}  "
                       f"{c.out_of_range:>12}  {c.rate_hz:>7.1f}")
        for col in self.unavailable:
            out.append(f"{col}: UNAVAILABLE (not mapped): NaN, fresh flag always False")
        for s in self.sources:
            skipped = {k: getattr(s, k) for k in ("wrong_length", "padded", "excess_length", "duplicates",
                                                  "backwards", "remote", "other_channel", "channel_relocked",
                                                  "bad_timestamp", "unaligned") if getattr(s, k)}
            extra = ", ".join(f"{k} {v}" for k, v in skipped.items()) or "nothing skipped"
            out.append(f"source {s.name} ({s.frame_id}): {s.frames} frames, {s.rate_hz:.1f} Hz, {extra}, "
                       f"{len(s.gaps)} gaps")
        gaps = self.gaps
        if gaps:
            shown = "; ".join(f"{g.source} at {g.start_s:.3f} s for {g.duration_s:.3f} s" for g in gaps[:5])
            out.append(f"gaps: {len(gaps)} ({shown}{'; ...' if len(gaps) > 5 else ''})")
        else:
            out.append("gaps: none")
        out += self.span_lines()
        out += self.range_lines()
        if self.unknown_ids:
            top = sorted(self.unknown_ids.items(), key=lambda kv: -kv[1])
            shown = ", ".join(f"{k} ({v})" for k, v in top[:8])
            more = (f"; and {self.unknown_more_frames} frames of further IDs (the first {len(top)} are counted by ID)"
                    if self.unknown_more_frames else "")
            out.append(f"unknown IDs (not in the DBC): {len(top)}: {shown}{', ...' if len(top) > 8 else ''}{more}")
        else:
            out.append("unknown IDs (not in the DBC): none")
        out.append(f"unmapped frames of DBC messages: {self.unmapped_frames}; error frames: {self.error_frames}")
        out.append(f"decode errors: {self.decode_errors} (unreadable lines {self.bad_lines}, "
                   f"reader warnings {self.reader_warnings})")
        for p in self.problems:
            out.append(f"problem: {p}")
        return out


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        v = float(x)
        return v if math.isfinite(v) else None
    return x


def vehicle_channel_map(mount: ImuMount) -> list[tuple[str, str, float]]:
    """For each vehicle-frame channel: (vehicle channel, IMU channel it comes from, sign).

    ``R_v_from_imu`` is a signed permutation, so each vehicle axis is one IMU axis times +-1;
    speed maps to itself.
    """
    R = mount.R_v_from_imu
    out = []
    for group in (GYRO, ACCEL):
        for i, vch in enumerate(group):
            j = int(np.flatnonzero(R[i])[0])
            out.append((vch, group[j], float(R[i, j])))
    out.append(("speed", "speed", 1.0))
    return out


def unavailable_channels(mapped: Iterable[str], mount: ImuMount) -> tuple[str, ...]:
    """Vehicle-frame value columns that no mapped IMU channel feeds."""
    mapped = set(mapped)
    cols = dict(zip(CHANNELS, VALUE_COLUMNS))
    return tuple(cols[v] for v, src, _ in vehicle_channel_map(mount) if src not in mapped)


def never_seen(table: pd.DataFrame) -> tuple[str, ...]:
    """Value columns of an IMU table (:func:`samples_frame`) that a mapped channel feeds but that
    hold no finite value: the channel's frames never came (the table's ``unavailable`` ones
    have no mapping at all and are not listed)."""
    unavailable = set(table.attrs.get("unavailable", ()))
    return tuple(c for c in VALUE_COLUMNS
                 if c in table and c not in unavailable and not np.isfinite(table[c].to_numpy(dtype=float)).any())


def rate_hz(t_s: np.ndarray) -> float:
    """Mean rate ``(n - 1) / (t_last - t_first)``, Hz (NaN for fewer than two times)."""
    if len(t_s) < 2:
        return math.nan
    span = float(t_s[-1] - t_s[0])
    return (len(t_s) - 1) / span if span > 0 else math.nan


def median_period_s(t_s: np.ndarray) -> float:
    """Median interval between consecutive times, s (NaN for fewer than two)."""
    if len(t_s) < 2:
        return math.nan
    return float(np.median(np.diff(t_s)))


def find_gaps(name: str, t_s: np.ndarray, gap_limit_s: float) -> tuple[Gap, ...]:
    """Intervals between consecutive accepted frames longer than ``gap_limit_s``."""
    if len(t_s) < 2:
        return ()
    dt = np.diff(t_s)
    idx = np.flatnonzero(dt > gap_limit_s)
    return tuple(Gap(name, float(t_s[i]), float(dt[i])) for i in idx)


@dataclass
class SourceFrames:
    """Accepted frames of one source, in time order: times (s), SI values ``(n, k)``, validity."""

    t_s: np.ndarray
    si: np.ndarray
    valid: np.ndarray
    channels: tuple[str, ...]


def align(frames: list[SourceFrames], clock: int, window_s: float, gap_limit_s: float,
          mount: ImuMount) -> tuple[dict[str, np.ndarray], list[int]]:
    """Vectorised alignment of accepted frames to the clock source's sample times.

    Parameters
    ----------
    frames : list of SourceFrames
        One per source of the decode plan; channels in IMU axes.
    clock : int
        Index of the clock source.
    window_s, gap_limit_s : float
        ``[can] align_window_s`` and ``gap_limit_s``, s.
    mount : ImuMount
        Axis mapping to the vehicle frame.

    Returns
    -------
    columns : dict of str to ndarray
        The table's columns (``COLUMNS``).
    unaligned : list of int
        Frames per source that joined no sample (always 0 for the clock source).
    """
    T = frames[clock].t_s
    n = len(T)
    imu = {ch: np.full(n, np.nan) for ch in GYRO + ACCEL}
    fresh = {ch: np.zeros(n, dtype=bool) for ch in GYRO + ACCEL}
    unaligned = [0] * len(frames)
    speed_t = np.empty(0)
    speed_v = np.empty(0)
    for si, src in enumerate(frames):
        imu_cols = [j for j, ch in enumerate(src.channels) if ch != "speed"]
        if "speed" in src.channels:
            j = src.channels.index("speed")
            ok = src.valid[:, j]
            speed_t, speed_v = src.t_s[ok], src.si[ok, j]
        if not imu_cols:
            continue
        if si == clock:
            rows = np.arange(n)
            pick = np.arange(n)
        else:
            t = src.t_s
            k = np.searchsorted(T, t - window_s, side="left")
            inside = k < n
            inside[inside] &= T[k[inside]] <= t[inside] + window_s
            cand = np.flatnonzero(inside)
            # first frame (in time order) of this source per sample wins
            _, first = np.unique(k[cand], return_index=True)
            pick = cand[first]
            rows = k[pick]
            unaligned[si] = len(t) - len(pick)
        for j in imu_cols:
            ch = src.channels[j]
            v = src.valid[pick, j]
            imu[ch][rows] = np.where(v, src.si[pick, j], np.nan)
            fresh[ch][rows] = v
    speed, speed_fresh = hold_speed(T, speed_t, speed_v, gap_limit_s)
    cols: dict[str, np.ndarray] = {"t_s": np.asarray(T, dtype=np.float64)}
    value_of = dict(zip(CHANNELS, VALUE_COLUMNS))
    for vch, ich, sign in vehicle_channel_map(mount):
        if vch == "speed":
            continue
        cols[value_of[vch]] = sign * imu[ich] if sign < 0 else imu[ich].copy()
        cols[f"fresh_{vch}"] = fresh[ich].copy()
    cols["speed_m_s"] = speed
    cols["fresh_speed"] = speed_fresh
    return {c: cols[c] for c in COLUMNS}, unaligned


def hold_speed(T: np.ndarray, speed_t: np.ndarray, speed_v: np.ndarray,
               gap_limit_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Latest valid speed strictly before each sample time, if not older than ``gap_limit_s``.

    Strictly before, so that the live path, which yields a sample as soon as it is complete,
    gives the same value as the log path when a speed frame shares the clock frame's timestamp.
    """
    n = len(T)
    if len(speed_t) == 0:
        return np.full(n, np.nan), np.zeros(n, dtype=bool)
    idx = np.searchsorted(speed_t, T, side="left") - 1
    has = idx >= 0
    age = np.where(has, T - speed_t[np.maximum(idx, 0)], np.inf)
    ok = has & (age <= gap_limit_s)
    value = np.where(ok, speed_v[np.maximum(idx, 0)], np.nan)
    prev = np.concatenate(([-1], idx[:-1]))
    return value, ok & (idx > prev)


def make_frame(columns: dict[str, np.ndarray], attrs: dict[str, Any]) -> pd.DataFrame:
    """The IMU table: ``COLUMNS`` with float64 values and bool flags, ``attrs`` attached."""
    df = pd.DataFrame({c: np.asarray(columns[c], dtype=bool if c.startswith("fresh_") else np.float64)
                       for c in COLUMNS})
    df.attrs.update(attrs)
    return df


def samples_frame(samples: Iterable[ImuSample], attrs: dict[str, Any] | None = None) -> pd.DataFrame:
    """The table from live samples (same columns and attrs keys as :func:`imu.read_log`)."""
    rows = [s.row() for s in samples]
    cols = {c: np.array([r[i] for r in rows]) for i, c in enumerate(COLUMNS)}
    if not rows:
        cols = {c: np.empty(0) for c in COLUMNS}
    return make_frame(cols, attrs or {})

