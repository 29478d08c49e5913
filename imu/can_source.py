"""IMU samples from a live CAN bus (any python-can ``BusABC``), one frame at a time.

:class:`StreamDecoder` applies the log path's acceptance rules (:mod:`imu.log_source`) and
alignment rule (:mod:`imu.samples`) incrementally, so a stream of messages gives the same samples
as the log of that stream; ``tests/test_imu_align.py`` and ``tests/test_imu_live.py`` check it.
A sample is yielded as soon as it is complete (its clock frame and one frame of every other IMU
source have arrived), so the latency from the last frame's arrival is only the decode time.
A sample that stays incomplete is yielded when a later frame shows that nothing can join it any
more, or, on a quiet bus, ``align_window_s`` plus a margin after its clock frame arrived. With
``[can] reorder_tolerance_s`` every accepted frame is first held for that much bus time (frames
of other IDs stamped before it may still come) and aligned in time order: that much latency.
A frame stamped more than ``gap_limit_s`` after the previous one of its ID (a clock glitch, or
the ID back after a gap) holds the frames after it until that ID's next frame says which: the
log path's rule, at the latency of one frame of that ID, only then.

:class:`LiveSource` wraps a bus::

    with can.Bus(interface="socketcan", channel="can0") as bus:
        for sample in LiveSource(bus, cfg.can, cfg.imu):
            ...
"""

from __future__ import annotations

import heapq
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Iterator

import can

from .config import ACCEL, CHANNELS, GYRO, CanMapping, ImuMount
from .dbc import DecodePlan, resolve
from .decode import decode_frame
from .errors import BusError
from .samples import (
    VALUE_COLUMNS, ChannelStats, Gap, ImuSample, SourceStats, Summary, unavailable_channels,
    vehicle_channel_map,
)

__all__ = ["StreamDecoder", "LiveSource"]

#: On a quiet bus, how long past the alignment window a sample waits for its other frames
#: before it is yielded incomplete, s. Generous on purpose: a loaded machine wakes the reading
#: thread late, and a tight margin would then split samples that the log path joins. It does
#: not delay complete samples, which are yielded as soon as their last frame arrives.
QUIET_BUS_MARGIN_S = 0.02
#: Mapped frames in a row older than the newest accepted one after which the bus clock is
#: taken to have restarted (a logger or interface restart, a stepped clock): about 70 ms of an
#: IMU bus. Fewer are counted as ``backwards`` and dropped; without this one bad stamp silenced
#: the stream for good. (A single frame stamped far ahead of its neighbours is a glitch, which
#: the glitch gate drops before it gets here: :data:`SUSPECT_WAIT_S`.)
CLOCK_RESET_AFTER = 20
#: Frames dropped as running backwards, beyond 10 and this share of the mapped frames, put a line
#: in :attr:`StreamDecoder.warnings` (the log path stops with an error at the same share).
BACKWARDS_WARN_FRACTION = 0.01

#: How long frames wait behind a frame stamped more than ``gap_limit_s`` after the previous one
#: of its ID, for that ID's next frame to say whether the stamp was a glitch (the next is more
#: than ``gap_limit_s`` behind it: dropped as a bad timestamp, as the log path does) or the
#: resumption after a gap (taken): s of arrival time, and at most this many mapped frames (a
#: stream fed faster than real time). Beyond either the frame is taken, as the log path takes
#: the last frame of an ID. (Not the waiting frames' stamps: a glitch among them would end it.)
SUSPECT_WAIT_S = 0.5
SUSPECT_WAIT_FRAMES = 1000

#: Without ``[can] channel``, a mapped ID is taken from the first bus channel it comes on, and
#: from another once that one has carried the ID for longer than ``gap_limit_s`` (the decoder's
#: gap) and in at least this many frames with none on the first: a stray copy on a second
#: channel (a gateway's echo, a second interface) had locked the ID there for the whole drive.
#: Timed by the stamps of the channel that carries the ID alone (two interfaces' clocks are not
#: compared), and in frames too so that one far-off stamp cannot move the lock.
RELOCK_MIN_FRAMES = 3
#: Frames of a mapped ID on channels other than the one taken, at least this many and beyond this
#: share of the ID's frames, put one line in :attr:`StreamDecoder.warnings` (two channels that
#: both carry it give half; a stray echo a few per cent).
OTHER_CHANNEL_WARN_FRAMES = 100
OTHER_CHANNEL_WARN_SHARE = 0.25
#: Distinct unknown IDs counted by ID (``unknown_ids``); the frames of further ones are counted in
#: one number (a bus of random extended IDs grew the dict by 46 MB in 500,000 frames, a review).
MAX_UNKNOWN_IDS = 1000

_IMU = set(GYRO + ACCEL)
#: Gaps kept per source for the summary of a long-running stream.
_MAX_GAPS = 1000
#: Lines in ``warnings`` of IDs moved to another channel (a flapping pair would grow it for good).
_MAX_RELOCK_LINES = 20
#: Valid speed frames kept while no sample asks for them (a bus without the clock message).
_MAX_SPEED_HISTORY = 4096


@dataclass
class _Group:
    """An open sample: the clock frame's time and the IMU channel values that joined it."""

    t_s: float
    received_s: float
    values: dict = field(default_factory=dict)
    sources: set = field(default_factory=set)
    emitted: bool = False


@dataclass
class _Clock:
    """Stamps on the bus clock: the span and frame intervals of the current clock and of those
    before it (a clock reset starts a new span: the summary's rates do not mix clocks)."""

    last_t: float = -math.inf
    first_t: float = math.nan
    clock_frames: int = 0
    span_before_s: float = 0.0
    intervals_before: int = 0

    def new_clock(self) -> None:
        if self.clock_frames:
            self.span_before_s += self.last_t - self.first_t
            self.intervals_before += self.clock_frames - 1
        self.clock_frames = 0
        self.last_t = -math.inf

    def stamp(self, t: float) -> None:
        """One more frame (or sample) at ``t`` on the current clock."""
        if not self.clock_frames:
            self.first_t = t
        self.clock_frames += 1
        self.last_t = t

    def span_s(self) -> float:
        """Time covered on all clocks so far, s."""
        return self.span_before_s + (self.last_t - self.first_t if self.clock_frames else 0.0)

    def intervals(self) -> int:
        return self.intervals_before + max(self.clock_frames - 1, 0)


@dataclass
class _SourceCount(_Clock):
    frames: int = 0
    duplicates: int = 0
    unaligned: int = 0
    last_payload: bytes = b""
    gaps: list = field(default_factory=list)
    valid: dict = field(default_factory=dict)
    invalid: dict = field(default_factory=dict)
    out_of_range: dict = field(default_factory=dict)
    #: each channel's valid values on the clock: their rate is the log path's, ``(n - 1) / span``
    valid_clocks: dict = field(default_factory=dict)

    def new_clock(self) -> None:
        super().new_clock()
        for c in self.valid_clocks.values():
            c.new_clock()


@dataclass
class _ChannelLock:
    """The bus channel a mapped ID is taken from (no ``[can] channel``), and the run of frames of
    it on one other channel since the last on this one (:data:`RELOCK_MIN_FRAMES`)."""

    channel: Any
    taken: int = 0                 # frames of the ID on ``channel`` (on the channels taken before too)
    run_channel: Any = None
    run_first_t: float = math.nan
    run_frames: int = 0
    share_said: bool = False


def _rate(intervals: int, span_s: float) -> float:
    return intervals / span_s if intervals > 0 and span_s > 0 else math.nan


class StreamDecoder:
    """Frames in, samples out: the incremental twin of :func:`imu.read_log`.

    Parameters
    ----------
    mapping : CanMapping
    mount : ImuMount
    db : cantools Database, optional
        Instead of loading ``mapping.dbc_path``.

    Notes
    -----
    Feed messages in arrival order with :meth:`push`; call :meth:`expire` now and then on a
    quiet bus and :meth:`flush` at the end. Without ``[can] channel`` the first bus channel a
    mapped ID is seen on is used and frames of that ID from other channels are counted as
    ``other_channel`` (the log path stops with an error instead, as it sees the whole file),
    until another channel carries the ID while that one is silent (:data:`RELOCK_MIN_FRAMES`):
    the ID is then taken from it (``channel_relocked`` in the summary, a line in ``warnings``).
    """

    def __init__(self, mapping: CanMapping, mount: ImuMount, db: Any | None = None, *,
                 plan: DecodePlan | None = None) -> None:
        self.plan = plan if plan is not None else resolve(mapping, db)
        self.mapping = self.plan.mapping
        self.mount = mount
        self.window_s = self.mapping.align_window_s
        self.gap_limit_s = self.mapping.gap_limit_s
        self._by_id: dict[int, list[int]] = {}
        for i, s in enumerate(self.plan.sources):
            self._by_id.setdefault(s.frame_id, []).append(i)
        self._msg = {fid: self.plan.sources[idx[0]] for fid, idx in self._by_id.items()}
        self._imu_sources = {i for i, s in enumerate(self.plan.sources)
                             if any(p.channel in _IMU for p in s.signals)}
        self._imu_ids = frozenset(self.plan.sources[i].frame_id for i in self._imu_sources)
        self._clock = self.plan.clock
        self._vmap = vehicle_channel_map(mount)
        self._chan_lock: dict[int, _ChannelLock] = {}
        self._relock_lines = 0
        self._last_t = -math.inf
        self._id_last_t: dict[int, float] = {}
        self._reorder_s = float(self.mapping.reorder_tolerance_s)
        self._held: list[tuple] = []       # frames held for the reorder tolerance (a heap by time)
        self._held_n = 0
        self._released_t = -math.inf       # the newest frame released from it
        self._backwards_in_row = 0
        self._id_seen_t: dict[int, float] = {}   # the newest stamp of each ID through the filters
        self._suspect: tuple | None = None        # a frame far ahead of its ID's previous one
        self._gate: deque[tuple] = deque()        # frames that came after it, in arrival order
        #: Times the bus clock was taken to have restarted (:data:`CLOCK_RESET_AFTER`).
        self.clock_resets = 0
        #: What the stream said of itself (frames out of time order dropped): the log path's
        #: errors, as lines, since a live bus cannot be refused.
        self.warnings: list[str] = []
        self._backwards, self._backwards_said = 0, False
        self._src = [_SourceCount() for _ in self.plan.sources]
        self._msg_counts: dict[int, dict[str, int]] = {fid: {} for fid in self._by_id}
        self._open: deque[_Group] = deque()
        self._refs: deque[_Group] = deque()
        self._pending: deque[tuple] = deque()
        self._speed: deque[tuple[float, float, int]] = deque(maxlen=_MAX_SPEED_HISTORY)
        self._speed_n = 0
        self._prev_speed_idx = -1
        self.frames_read = 0
        self.frames_mapped = 0
        #: Data frames of the IMU's own messages (gyro and accelerometer; not the wheel speed)
        #: on the bus channel taken: what :class:`LiveSource`'s ``imu_timeout_s`` waits for.
        self.imu_frames = 0
        self.unknown_ids: dict[str, int] = {}
        #: Frames of unknown IDs beyond the first :data:`MAX_UNKNOWN_IDS` (not kept by ID).
        self.unknown_more_frames = 0
        self.unmapped_frames = 0
        self.error_frames = 0
        self.samples = 0
        self._samples = _Clock()     # the samples' time spans, per bus clock

    # --- frame acceptance (same order as imu.log_source._finish) ---------------------------
    def push(self, msg: can.Message, received_s: float | None = None) -> list[ImuSample]:
        """Take one message; return the samples it completes or closes (often none or one)."""
        received_s = time.perf_counter() if received_s is None else received_s
        self.frames_read += 1
        aid = msg.arbitration_id
        idx = self._by_id.get(aid)
        if idx is None:
            if msg.is_error_frame:   # its ID is the error's class, whatever the DBC names so
                self.error_frames += 1
            elif aid in self.plan.known_ids:
                self.unmapped_frames += 1
            else:
                self._count_unknown(f"0x{aid:X}")
            return []
        self.frames_mapped += 1
        ref = self._msg[aid]
        counts = self._msg_counts[aid]
        if msg.is_error_frame:
            self.error_frames += 1
            return []
        if bool(msg.is_extended_id) != ref.is_extended:
            self._count_unknown(f"0x{aid:X}" + ("x" if msg.is_extended_id else " (standard)"))
            return []
        if self.mapping.channel is not None:
            if str(msg.channel) != str(self.mapping.channel):
                counts["other_channel"] = counts.get("other_channel", 0) + 1
                return []
        else:
            lock = self._chan_lock.get(aid)
            if lock is None:
                lock = self._chan_lock[aid] = _ChannelLock(msg.channel)
            if lock.channel == msg.channel:
                lock.taken += 1
                if not msg.is_remote_frame:     # (a request is no sign that the channel carries it)
                    lock.run_frames = 0
            elif not self._relock(aid, lock, msg):
                counts["other_channel"] = counts.get("other_channel", 0) + 1
                self._judge_other_channel(aid, lock, counts["other_channel"])
                return []
        if msg.is_remote_frame:
            counts["remote"] = counts.get("remote", 0) + 1
            return []
        if aid in self._imu_ids:
            self.imu_frames += 1
        t = msg.timestamp
        if not (math.isfinite(t) and abs(t) < 1e12):
            counts["bad_timestamp"] = counts.get("bad_timestamp", 0) + 1
            return []
        data = bytes(msg.data)
        length = ref.length
        if len(data) < length:
            if self.mapping.pad_short_frames:
                counts["padded"] = counts.get("padded", 0) + 1
            else:
                counts["wrong_length"] = counts.get("wrong_length", 0) + 1
                return []
        elif len(data) > length:
            counts["excess_length"] = counts.get("excess_length", 0) + 1
        payload = data[:length].ljust(length, b"\0")
        prev = self._id_seen_t.get(aid)
        self._id_seen_t[aid] = t
        if self._suspect is None and not (prev is not None and t - prev > self.gap_limit_s):
            return self._accept(aid, idx, t, payload, received_s)      # the usual case
        self._gate.append((aid, idx, t, payload, received_s, prev))
        return self._pump()

    def _count_unknown(self, key: str) -> None:
        """One frame of an ID the DBC does not have: by ID for the first :data:`MAX_UNKNOWN_IDS`
        IDs, in ``unknown_more_frames`` beyond."""
        n = self.unknown_ids.get(key)
        if n is not None:
            self.unknown_ids[key] = n + 1
        elif len(self.unknown_ids) < MAX_UNKNOWN_IDS:
            self.unknown_ids[key] = 1
        else:
            self.unknown_more_frames += 1

    def _relock(self, aid: int, lock: _ChannelLock, msg: can.Message) -> bool:
        """Whether a frame of ``aid`` on a channel other than the one taken moves the ID to its
        channel: that channel has carried it for longer than ``gap_limit_s`` by its own stamps,
        in :data:`RELOCK_MIN_FRAMES` frames or more, with none on the channel taken."""
        t = msg.timestamp
        if msg.is_remote_frame or not (isinstance(t, (int, float)) and math.isfinite(t)):
            return False      # no data, or no time to measure the run by (a NaN had held it for good)
        if not (lock.run_frames and lock.run_channel == msg.channel):
            lock.run_channel, lock.run_first_t, lock.run_frames = msg.channel, t, 1
            return False
        lock.run_frames += 1
        if not (t - lock.run_first_t > self.gap_limit_s and lock.run_frames >= RELOCK_MIN_FRAMES):
            return False
        counts = self._msg_counts[aid]
        counts["channel_relocked"] = counts.get("channel_relocked", 0) + 1
        if self._relock_lines < _MAX_RELOCK_LINES:
            self._relock_lines += 1
            src = self._msg[aid]
            self.warnings.append(
                f"frame {src.id_text} ({src.message.name}) taken from bus channel {msg.channel!r} from {t:.3f} s on: "
                f"channel {lock.channel!r}, where it came first, carried none of it while channel {msg.channel!r} "
                f"carried {lock.run_frames} frames in {t - lock.run_first_t:.3f} s ([can] channel picks one; the "
                "summary's channel_relocked counts such moves)")
        lock.channel, lock.run_frames = msg.channel, 0
        lock.taken += 1
        # the ID's stamps so far were the other channel's (another interface's clock, perhaps):
        # not the previous frame of its order and glitch rules
        self._id_seen_t.pop(aid, None)
        self._id_last_t.pop(aid, None)
        return True

    def _judge_other_channel(self, aid: int, lock: _ChannelLock, other: int) -> None:
        """Say once per ID when its frames on other channels pass :data:`OTHER_CHANNEL_WARN_FRAMES`
        and :data:`OTHER_CHANNEL_WARN_SHARE` of its frames while the channel taken carries it too
        (they were only counted, in the summary)."""
        if lock.share_said or other < OTHER_CHANNEL_WARN_FRAMES \
                or other <= OTHER_CHANNEL_WARN_SHARE * (other + lock.taken):
            return
        lock.share_said = True
        src = self._msg[aid]
        self.warnings.append(
            f"frame {src.id_text} ({src.message.name}) comes on more than one bus channel: {other} of "
            f"{other + lock.taken} frames on others than {lock.channel!r}, which is used ([can] channel picks one)")

    def _pump(self, force: bool = False, force_one: bool = False) -> list[ImuSample]:
        """Frames through the glitch gate, in arrival order. A frame stamped more than
        ``gap_limit_s`` after the previous frame of its ID waits, and the frames after it with
        it, for that ID's next frame: more than ``gap_limit_s`` behind it, the stamp was a glitch
        (counted as a bad timestamp, dropped); otherwise the ID resumed after a gap, and the
        frame is taken, then those that waited. The log path's rule, frame by frame: without it
        one far-future stamp made the next 20 frames 'backwards' and restarted the bus clock.
        ``force`` (end of stream): a frame still waiting is taken; ``force_one`` (a quiet bus):
        the one waiting now is, a later one waits for its own ID's next frame."""
        out: list[ImuSample] = []
        gate, limit = self._gate, self.gap_limit_s
        while gate or ((force or force_one) and self._suspect is not None):
            sus = self._suspect
            if sus is None:
                aid, idx, t, payload, received_s, prev = gate.popleft()
                if prev is not None and t - prev > limit:
                    self._suspect = (aid, idx, t, payload, received_s, prev)
                else:
                    out += self._accept(aid, idx, t, payload, received_s)
                continue
            nxt = next((g for g in gate if g[0] == sus[0]), None)
            if nxt is None and not (force or force_one) and len(gate) < SUSPECT_WAIT_FRAMES \
                    and not (gate and gate[-1][4] - sus[4] > SUSPECT_WAIT_S):
                break                                    # its ID's next frame is yet to come
            self._suspect, force_one = None, False
            if nxt is not None and sus[2] - nxt[2] > limit:
                counts = self._msg_counts[sus[0]]
                counts["bad_timestamp"] = counts.get("bad_timestamp", 0) + 1
            else:
                out += self._accept(*sus[:5])
        return out

    def _accept(self, aid: int, idx: list[int], t: float, payload: bytes, received_s: float) -> list[ImuSample]:
        """A frame through the filters and the glitch gate: the order rules (backwards, the
        reorder tolerance, a restarted clock), then decoded, or held for the tolerance."""
        tol = self._reorder_s
        out: list[ImuSample] = []
        if t < self._last_t - tol or t < self._id_last_t.get(aid, -math.inf) or t < self._released_t:
            self._backwards_in_row += 1
            if self._backwards_in_row < CLOCK_RESET_AFTER:
                counts = self._msg_counts[aid]
                counts["backwards"] = counts.get("backwards", 0) + 1
                self._backwards += 1
                if not self._backwards_said and self._backwards > max(10, BACKWARDS_WARN_FRACTION * self.frames_mapped):
                    self._backwards_said = True
                    # frames of different IDs a little out of order (a merged or buffering logger):
                    # each one dropped, a source silenced without a word (a review: a wheel speed 1 ms
                    # late gave no speed for a whole drive; the log path refuses such a log)
                    self.warnings.append(
                        f"{self._backwards} of {self.frames_mapped} mapped frames dropped as running backwards in "
                        f"time (first kind: 0x{aid:X}, {self._last_t - t:.6f} s behind): frames of different IDs "
                        "out of order on the bus? [can] reorder_tolerance_s takes them in time order")
                return []
            out = self._release(math.inf, received_s)     # the old clock's held frames first
            self._reset_clock()
        self._backwards_in_row = 0
        self._last_t = max(self._last_t, t)
        self._id_last_t[aid] = t
        if tol <= 0:
            return out + self._decode(idx, t, payload, received_s)
        # held until no frame of another ID stamped before it can still be taken
        heapq.heappush(self._held, (t, self._held_n, idx, payload, received_s))
        self._held_n += 1
        return out + self._release(self._last_t - tol, received_s)

    def _release(self, t_limit: float, released_s: float) -> list[ImuSample]:
        """Decode the held frames (reorder tolerance) stamped at or before ``t_limit``, in time
        order, as if they arrived at ``released_s`` (the quiet-bus expiry of the samples they
        open counts from then, not from their arrival a tolerance earlier). A frame stamped
        before the last one released is too late from then on (``backwards``)."""
        out: list[ImuSample] = []
        while self._held and self._held[0][0] <= t_limit:
            t, _, idx, payload, _ = heapq.heappop(self._held)
            self._released_t = t
            out += self._decode(idx, t, payload, released_s)
        return out

    def _decode(self, idx: list[int], t: float, payload: bytes, received_s: float) -> list[ImuSample]:
        """One accepted frame's sources: decoded, counted, aligned."""
        out: list[ImuSample] = []
        for si in idx:
            src = self.plan.sources[si]
            present, si_row, valid_row, oor, _ = decode_frame(payload, src, self.mapping.range_check)
            if not present:
                continue
            sc = self._src[si]
            if t == sc.last_t or (t - sc.last_t < self.window_s and payload == sc.last_payload):
                sc.duplicates += 1      # a repeat, or an echo (imu.log_source._duplicates)
                continue
            sc.last_payload = payload
            if sc.frames and math.isfinite(sc.last_t) and t - sc.last_t > self.gap_limit_s and len(sc.gaps) < _MAX_GAPS:
                sc.gaps.append(Gap(src.name, sc.last_t, t - sc.last_t))
            sc.frames += 1
            sc.stamp(t)
            for j, p in enumerate(src.signals):
                if valid_row[j]:
                    sc.valid[p.channel] = sc.valid.get(p.channel, 0) + 1
                    clock = sc.valid_clocks.get(p.channel)
                    if clock is None:
                        clock = sc.valid_clocks[p.channel] = _Clock()
                    clock.stamp(t)
                else:
                    sc.invalid[p.channel] = sc.invalid.get(p.channel, 0) + 1
                sc.out_of_range[p.channel] = sc.out_of_range.get(p.channel, 0) + oor[j]
            out.extend(self._event(si, t, si_row, valid_row, received_s))
        return out

    def _reset_clock(self) -> None:
        """:data:`CLOCK_RESET_AFTER` frames in a row older than the newest: the bus clock
        restarted or stepped (or one frame carried a far-future stamp). Take the new clock: the
        samples still open straddle the step and are dropped, as is the speed history."""
        self.clock_resets += 1
        for g in self._open:
            g.emitted = True
        self._open.clear()
        self._refs.clear()
        for _, sp, _ in self._pending:
            self._src[sp].unaligned += 1
        self._pending.clear()
        self._speed.clear()
        for sc in self._src:
            sc.new_clock()
        self._samples.new_clock()
        self._last_t = -math.inf
        self._id_last_t.clear()
        self._released_t = -math.inf

    # --- alignment (same rule as imu.samples.align) ------------------------------------------
    def _event(self, si: int, t: float, si_row: list, valid_row: list,
               received_s: float) -> list[ImuSample]:
        w = self.window_s
        out = self._close_before(t - w, received_s)
        src = self.plan.sources[si]
        imu = [(p.channel, float(si_row[j]), bool(valid_row[j])) for j, p in enumerate(src.signals)
               if p.channel in _IMU]
        for j, p in enumerate(src.signals):
            if p.channel == "speed" and valid_row[j]:
                self._speed.append((t, float(si_row[j]), self._speed_n))
                self._speed_n += 1
        if si == self._clock:
            g = _Group(t_s=t, received_s=received_s)
            self._join(g, si, imu)
            self._open.append(g)
            self._refs.append(g)
            pending, self._pending = self._pending, deque()
            for (tp, sp, imu_p) in pending:  # all within the window: older ones expired above
                if sp in g.sources:
                    self._src[sp].unaligned += 1
                else:
                    self._join(g, sp, imu_p)
        elif imu:
            g = next((r for r in self._refs if r.t_s >= t - w), None)
            if g is None:
                self._pending.append((t, si, imu))
            elif g.emitted or si in g.sources:
                self._src[si].unaligned += 1
            else:
                self._join(g, si, imu)
        while self._open and self._open[0].sources >= self._imu_sources:
            out.append(self._emit(self._open.popleft(), received_s))
        return out

    @staticmethod
    def _join(g: _Group, si: int, imu: list) -> None:
        g.sources.add(si)
        for ch, v, ok in imu:
            g.values[ch] = (v, ok)

    def _close_before(self, t_limit: float, received_s: float) -> list[ImuSample]:
        """Emit samples no frame at or after ``t_limit + window`` can join; expire pending frames."""
        out = []
        while self._open and self._open[0].t_s < t_limit:
            out.append(self._emit(self._open.popleft(), received_s))
        while self._refs and self._refs[0].t_s < t_limit and self._refs[0].emitted:
            self._refs.popleft()
        while self._pending and self._pending[0][0] < t_limit:
            self._src[self._pending.popleft()[1]].unaligned += 1
        return out

    def _emit(self, g: _Group, released_s: float) -> ImuSample:
        """The sample of group ``g``; ``released_s`` is when the frame that released it arrived."""
        g.emitted = True
        T = g.t_s
        while len(self._speed) > 1 and self._speed[1][0] < T:
            self._speed.popleft()
        speed, idx, fresh_speed = self._speed_rule(self._speed[0] if self._speed else None, T,
                                                   self._prev_speed_idx)
        self._prev_speed_idx = idx
        vals: dict[str, Any] = {"t_s": T}
        for vch, ich, sign in self._vmap:
            if vch == "speed":
                continue
            v, ok = g.values.get(ich, (math.nan, False))
            col = VALUE_COLUMNS[CHANNELS.index(vch)]
            vals[col] = (-v if sign < 0 else v) if ok else math.nan
            vals[f"fresh_{vch}"] = bool(ok)
        vals["speed_m_s"] = speed
        vals["fresh_speed"] = bool(fresh_speed)
        self.samples += 1
        self._samples.stamp(T)
        return ImuSample(received_s=released_s, **vals)

    def pending_speeds(self, t_limit: float) -> list[tuple[float, float]]:
        """``(t_s, m/s)`` of the fresh wheel speeds the samples still open at or before
        ``t_limit`` will carry when they are released (the rule of :meth:`_emit`, on the speed
        frames received so far), without releasing them: what a frame captured at ``t_limit``
        and handed in before the align window has passed its time can know of the speed."""
        out = []
        prev, speeds, k = self._prev_speed_idx, list(self._speed), 0
        for g in self._open:
            if g.t_s > t_limit:
                break
            while k + 1 < len(speeds) and speeds[k + 1][0] < g.t_s:
                k += 1
            v, prev, fresh = self._speed_rule(speeds[k] if speeds else None, g.t_s, prev)
            if fresh:
                out.append((g.t_s, v))
        return out

    def _speed_rule(self, frame: tuple | None, T: float, prev_idx: int) -> tuple[float, int, bool]:
        """A sample at ``T``'s wheel speed from ``frame`` ``(t_s, m/s, counter)``, the latest
        speed frame before ``T`` kept so far: ``(m/s, counter, fresh)``, the speed NaN when the
        frame is not before ``T`` or older than ``gap_limit_s``, fresh when it is a speed frame
        after the one the sample before took (counter ``prev_idx``)."""
        if frame is None or not frame[0] < T:
            return math.nan, -1, False
        ts, v, idx = frame
        speed = v if T - ts <= self.gap_limit_s else math.nan
        return speed, idx, not math.isnan(speed) and idx > prev_idx

    def next_expiry_s(self) -> float:
        """When :meth:`expire` (default margin) next has something to do, ``time.perf_counter()``
        seconds: a frame waiting in the glitch gate too long (nothing else expires meanwhile),
        a held frame (reorder tolerance) or an open sample past its wait; ``inf``: nothing waits."""
        if self._suspect is not None:
            return self._suspect[4] + SUSPECT_WAIT_S
        t = math.inf
        if self._open:
            t = self._open[0].received_s + self.window_s + QUIET_BUS_MARGIN_S
        if self._held:
            t = min(t, self._held[0][4] + self._reorder_s + QUIET_BUS_MARGIN_S)
        return t

    def expire(self, now_s: float | None = None, margin_s: float | None = None) -> list[ImuSample]:
        """On a quiet bus: emit samples whose clock frame arrived more than window + margin ago.

        ``now_s`` and the arrival times are ``time.perf_counter()`` seconds.
        """
        now_s = time.perf_counter() if now_s is None else now_s
        margin_s = QUIET_BUS_MARGIN_S if margin_s is None else margin_s
        out = []
        if self._suspect is not None and now_s - self._suspect[4] > SUSPECT_WAIT_S:   # its ID fell silent
            out += self._pump(force_one=True)
        if self._suspect is not None:
            # frames wait in the glitch gate: the samples and held frames they may join or
            # precede wait with them (the log path has them all at once)
            return out
        while self._held and now_s - self._held[0][4] > self._reorder_s + margin_s:   # held too long
            out += self._release(self._held[0][0], now_s)
        while self._open and now_s - self._open[0].received_s > self.window_s + margin_s:
            out.append(self._emit(self._open.popleft(), now_s))
        return out

    def flush(self) -> list[ImuSample]:
        """End of stream: emit every open sample; pending frames are unaligned."""
        now_s = time.perf_counter()
        out = self._pump(force=True)
        out += self._release(math.inf, now_s)
        out += [self._emit(g, now_s) for g in self._open]
        self._open.clear()
        for _, sp, _ in self._pending:
            self._src[sp].unaligned += 1
        self._pending.clear()
        return out

    # --- report --------------------------------------------------------------------------
    @property
    def unavailable(self) -> tuple[str, ...]:
        """Vehicle-frame value columns no mapped signal feeds (always NaN)."""
        return unavailable_channels(self.mapping.signals, self.mount)

    def summary(self, log: str = "live bus") -> Summary:
        """Counts so far, in the same form as the log path's summary."""
        sources = []
        seen: set[int] = set()
        for si, s in enumerate(self.plan.sources):
            sc = self._src[si]
            counts = self._msg_counts[s.frame_id] if s.frame_id not in seen else {}
            seen.add(s.frame_id)
            sources.append(SourceStats(
                name=s.name, frame_id=s.id_text, frames=sc.frames, rate_hz=_rate(sc.intervals(), sc.span_s()),
                duplicates=sc.duplicates, unaligned=sc.unaligned, gaps=tuple(sc.gaps),
                first_s=sc.first_t if sc.clock_frames else math.nan,
                last_s=sc.last_t if sc.clock_frames else math.nan, **counts,
            ))
        value_col = dict(zip(CHANNELS, VALUE_COLUMNS))
        col_of = {ich: value_col[vch] for vch, ich, _ in self._vmap}
        channels = []
        for si, s in enumerate(self.plan.sources):
            sc = self._src[si]
            for p in s.signals:
                n_ok = sc.valid.get(p.channel, 0)
                clock = sc.valid_clocks.get(p.channel)
                channels.append(ChannelStats(
                    channel=p.channel, column=col_of[p.channel], ref=p.ref, unit=p.unit,
                    decoded=n_ok, invalid=sc.invalid.get(p.channel, 0),
                    out_of_range=sc.out_of_range.get(p.channel, 0), minimum=p.minimum, maximum=p.maximum,
                    rate_hz=_rate(clock.intervals(), clock.span_s()) if clock else math.nan,  # valid values per second
                ))
        span = self._samples.span_s()
        return Summary(
            log=log, frames_read=self.frames_read, frames_mapped=self.frames_mapped, samples=self.samples,
            duration_s=float(span) if self.samples else 0.0,
            sample_rate_hz=_rate(self._samples.intervals(), span),
            clock=self.plan.sources[self._clock].name, sources=tuple(sources), channels=tuple(channels),
            unavailable=self.unavailable, unknown_ids=dict(self.unknown_ids),
            unknown_more_frames=self.unknown_more_frames,
            unmapped_frames=self.unmapped_frames, error_frames=self.error_frames,
            range_check=self.mapping.range_check,
        )


class LiveSource:
    """Iterate IMU samples from a live python-can bus.

    Parameters
    ----------
    bus : can.BusABC
        Any python-can bus (socketcan, pcan, vector, virtual, ...), opened by the caller.
    mapping : CanMapping
    mount : ImuMount
    db : cantools Database, optional
    poll_s : float
        Longest wait in ``bus.recv``, s; bounds how late :meth:`stop` and quiet-bus samples are.
    imu_timeout_s : float, optional
        Longest time without a data frame of the IMU's messages (those ``[can.signals]`` maps a
        gyro or accelerometer channel to), s, counted from the start of the iteration; then the
        samples still open are yielded and :class:`imu.BusError` is raised. ``None`` (the
        default) waits for ever: a bus may be quiet before the vehicle starts. Other traffic,
        the wheel speed's included, does not count: a dead IMU on a busy bus is still a dead IMU.

    A ``bus.recv`` that fails (a bus closed from another thread, a driver error) ends the
    iteration the same way: the open samples first, then :class:`imu.BusError` naming the bus,
    the frames read and python-can's message (chained). Iterating again goes on reading.

    Examples
    --------
    >>> src = LiveSource(bus, cfg.can, cfg.imu, imu_timeout_s=0.5)   # doctest: +SKIP
    >>> for sample in src:                                           # doctest: +SKIP
    ...     ekf.predict(sample.t_s, sample.gyro_z_rad_s)
    """

    def __init__(self, bus: can.BusABC, mapping: CanMapping, mount: ImuMount, db: Any | None = None,
                 *, poll_s: float = 0.01, imu_timeout_s: float | None = None) -> None:
        if not poll_s > 0:
            raise ValueError(f"poll_s must be > 0, got {poll_s}")
        if imu_timeout_s is not None and not imu_timeout_s > 0:
            raise ValueError(f"imu_timeout_s must be > 0 s or None, got {imu_timeout_s}")
        self.bus = bus
        self.decoder = StreamDecoder(mapping, mount, db)
        self.poll_s = poll_s
        self.imu_timeout_s = imu_timeout_s
        self._stop = threading.Event()

    @property
    def unavailable(self) -> tuple[str, ...]:
        return self.decoder.unavailable

    def stop(self) -> None:
        """Make the iteration end (thread-safe); the samples still open are yielded first."""
        self._stop.set()

    def _name(self) -> str:
        return f"live bus {getattr(self.bus, 'channel_info', '')}".strip()

    def summary(self) -> Summary:
        return self.decoder.summary(self._name())

    @property
    def warnings(self) -> list[str]:
        """What the stream said of itself (:attr:`StreamDecoder.warnings`)."""
        return self.decoder.warnings

    def __iter__(self) -> Iterator[ImuSample]:
        dec = self.decoder
        recv = self.bus.recv
        clock = time.perf_counter
        wait_max = self.poll_s
        timeout = self.imu_timeout_s
        heard_s, heard = clock(), dec.imu_frames
        while not self._stop.is_set():
            now = clock()
            try:
                msg = recv(timeout=min(wait_max, max(0.0, dec.next_expiry_s() - now)))
            except (can.CanError, OSError) as exc:
                yield from dec.flush()
                raise BusError(f"{self._name()}: receiving failed after {dec.frames_read} frames: {exc}") from exc
            now = clock()
            if msg is not None:
                yield from dec.push(msg, now)
            if dec.next_expiry_s() < math.inf:
                yield from dec.expire(now)
            if timeout is not None:
                if dec.imu_frames != heard:
                    heard_s, heard = now, dec.imu_frames
                elif now - heard_s > timeout:
                    yield from dec.flush()
                    raise BusError(f"{self._name()}: no frame of the IMU's messages for {now - heard_s:.2f} s "
                                   f"(imu_timeout_s = {timeout:g}; {dec.frames_read} frames read)")
        yield from dec.flush()

