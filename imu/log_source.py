"""IMU samples from a CAN log file of any format python-can reads.

python-can's readers do the parsing (``.asc .blf .csv .log .trc .mf4``, and ``.gz`` of the text
ones); this module makes them robust and fast for the IMU:

* **Only mapped frame IDs are kept.** The loop over messages does one set lookup per frame;
  everything else is counted (unknown IDs by ID) and dropped. Kept frames are packed every
  8192 messages into numpy arrays, then decoded per message with :mod:`imu.decode`.
* **Bad input is counted, not fatal.** A line a text reader cannot parse is skipped and counted
  (the reader is restarted after it, with the file's header lines replayed so the format state
  survives); a binary log that breaks off keeps what came before and is marked incomplete; the
  readers' own log warnings are counted instead of printed. Files that give nothing readable,
  and logs whose clock runs backwards for more than 1 % of the mapped frames, stop with a
  one-line :class:`~imu.errors.DecodeError` naming the file and the line or frame ID.
* **Frame acceptance** (the same rules as the live path in :mod:`imu.can_source`), in order:
  error frames, IDs with the other standard/extended flag, other bus channels, remote frames,
  non-finite timestamps, frames shorter than the DBC length (unless ``pad_short_frames``),
  timestamps earlier than an already accepted mapped frame ("backwards"), and a second frame of
  the same source at the same timestamp, or with the same bytes within ``align_window_s`` of it
  (an echo: "duplicate") are skipped and counted per message.

Timestamps are those python-can's ``LogReader`` returns with default arguments (the log clock of
``INTERFACE.md``).
"""

from __future__ import annotations

import gc
import gzip
import logging
import math
import re
import string
import sys
import warnings
from collections import Counter, deque
from contextlib import contextmanager
from dataclasses import dataclass, field
from itertools import chain, islice
from operator import attrgetter
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import can
import numpy as np
import pandas as pd
from can.io.generic import TextIOMessageReader
from can.util import dlc2len, len2dlc

from .config import CHANNELS, CanMapping, ImuMount, split_signal
from .dbc import DecodePlan, resolve
from .decode import decode_source
from .errors import DecodeError, ImuConfigError
from .samples import (
    VALUE_COLUMNS, ChannelStats, SourceFrames, SourceStats, Summary, align, find_gaps, make_frame, median_period_s, rate_hz,
    unavailable_channels, vehicle_channel_map,
)

__all__ = ["read_log", "LOG_SUFFIXES", "iter_messages", "ReadState"]

#: Log formats python-can reads (``.gz`` of the text ones too).
LOG_SUFFIXES = tuple(sorted(s for s in can.io.MESSAGE_READERS if s != ".db"))

_BATCH = 2048
#: Unreadable lines tolerated before the file is declared not a log of its format.
_MAX_BAD_LINES_FRACTION = 0.5
#: A clock that runs backwards for more than this fraction of mapped frames stops the read.
_MAX_BACKWARDS_FRACTION = 0.01


@dataclass
class ReadState:
    """What the robust reader saw besides messages."""

    path: Path
    fmt: str
    bad_lines: int = 0
    warnings: int = 0
    problems: list[str] = field(default_factory=list)
    complete: bool = True
    messages: int = 0
    position: Callable[[], int] | None = None
    size: int | None = None
    #: A text log's line being read (set by the reader of text logs), and the line at which a
    #: reader last logged a warning: the TRC reader logs a line it cannot parse and goes on.
    line: Callable[[], int] | None = None
    warning_line: int = -1
    #: Lines a reader passed over with only an INFO log, by the type it named: the TRC reader's
    #: "Unsupported type" (a PCAN status, error counter or error frame record, or a frame line
    #: whose type column is garbled), and the line of the first.
    unread_types: dict[str, int] = field(default_factory=dict)
    first_unread_line: int = -1

    stop_reason: str = ""               # why the read stopped early (the first cause)

    def problem(self, text: str) -> None:
        if len(self.problems) < 20:
            self.problems.append(_one_line(text))

    def stopped(self, text: str) -> None:
        """The read stopped before the file's end (or the file broke off), for this reason."""
        self.complete = False
        self.problem(text)
        if not self.stop_reason:
            self.stop_reason = _one_line(text)


def _without_traceback(text: str) -> str:
    """A reader's message without the traceback asammdf puts into its messages and logged
    warnings (a review: 300 characters of one in the one-line error): what comes before it and
    its last line, the cause."""
    head, sep, tb = text.partition("Traceback (most recent call last)")
    if not sep:
        return text
    lines = [line.strip() for line in tb.splitlines() if line.strip()]
    return f"{head.strip()} {lines[-1] if lines else ''}".strip()


def _cause(e: Exception) -> str:
    """A reader's exception as a short cause."""
    return " ".join(_without_traceback(str(e)).split())[:200] or type(e).__name__


def _one_line(text: str) -> str:
    """A problem's text as the summary keeps it: one line, at most 300 characters."""
    return " ".join(text.split())[:300]


class _Lines:
    """Line iterator handed to python-can's text readers: counts lines and replays the header."""

    def __init__(self, f: Any, asc: bool = False) -> None:
        self.f = f
        self.asc = asc                  # look for frame lines the ASC reader passes over
        self.dropped: list[int] = []    # ASC frame lines the reader passed over (line numbers)
        self.line_no = 0
        self.chars = 0
        self.replay: deque[str] = deque()
        self.recording = True
        self.recorded: list[str] = []
        self.last = ""                  # the last line that was not blank
        self.unterminated = False       # the last line has no line end: complete or cut?
        self.cut = False                # ... cut off mid-way: its frame is not read

    def __iter__(self) -> "_Lines":
        return self

    def __next__(self) -> str:
        if self.replay:
            return self.replay.popleft()
        line = next(self.f)
        if not line.endswith("\n") and line.strip():
            # only a file's last line can lack its line end: a complete line of a writer that
            # leaves the final line end out, or a line cut off mid-way (judged in _iter_text)
            self.unterminated = True
            line += "\n"
        self.line_no += 1
        self.chars += len(line)
        if self.asc and not ASC_MESSAGE_REGEX.match(line.lstrip()) and _asc_frame_like(line):
            self.dropped.append(self.line_no)
        if self.recording:
            self.recorded.append(line)
        if line.strip():
            self.last = line
        return line

    def close(self) -> None:  # python-can's reader.stop() closes its file; we close the real one
        pass


#: The pattern by which python-can's ASC reader takes a line for a frame (its own, where it has
#: it under this name: python-can >= 4.4 does).
ASC_MESSAGE_REGEX = getattr(can.io.asc, "ASC_MESSAGE_REGEX", None) or re.compile(
    r"\d+\.\d+\s+(\d+\s+(\w+\s+(Tx|Rx)|ErrorFrame)|CANFD)", re.ASCII | re.IGNORECASE)

#: The form of an ASC frame line, whatever its fields hold (:func:`_asc_frame_like`).
_ASC_FRAME_LIKE = re.compile(r"\s(?:Rx|Tx)\s+[dr]\s|^\s*\S+\s+CANFD\s|^\s*\d\S*\s+\d+\s+errorframe"
                             r"|^\s*\d+[.,]\d*\s+\d+\s+[0-9a-f]+x?\s", re.IGNORECASE)


def _asc_frame_like(line: str) -> bool:
    """Whether an ASC line has the form of a CAN frame whatever its fields hold: ``Rx`` or ``Tx``
    followed by ``d`` (data) or ``r`` (remote), ``time CANFD ...``, ``time channel
    ErrorFrame``, or a time, a channel and a hexadecimal ID (the rest overwritten: a review's
    file with 200 bytes of garbage mid-file). python-can's reader passes over a line its
    pattern (``ASC_MESSAGE_REGEX``) does not match, as it does over comments and other events
    (LIN, statistics, chip states), without a word: such a line of this form (a decimal comma
    in the time, a stray character) is a frame lost."""
    return _ASC_FRAME_LIKE.search(line) is not None


#: python-can's TRC reader's INFO for a line it passes over (its type is the one argument).
_TRC_UNSUPPORTED = "TRCReader: Unsupported type '%s'"


class _CountWarnings(logging.Handler):
    """Counts the readers' warnings, and the lines the TRC reader passes over with only an INFO
    log (a review: those were lost without a count)."""

    def __init__(self, state: ReadState) -> None:
        super().__init__(logging.INFO)
        self.state = state

    def emit(self, record: logging.LogRecord) -> None:
        if record.levelno < logging.WARNING:
            if record.msg == _TRC_UNSUPPORTED and record.args:
                kind = str(record.args[0])[:12]
                st = self.state
                st.unread_types[kind] = st.unread_types.get(kind, 0) + 1
                if st.first_unread_line < 0 and st.line is not None:
                    st.first_unread_line = st.line()
            return
        self.state.warnings += 1
        if self.state.line is not None:
            self.state.warning_line = self.state.line()
        if self.state.warnings <= 3:
            self.state.problem(f"reader warning: {_without_traceback(record.getMessage())}")


@contextmanager
def _quiet_readers(state: ReadState) -> Iterator[None]:
    """Count python-can's and asammdf's logged warnings instead of printing them."""
    handler = _CountWarnings(state)
    saved = []
    for name in ("can", "asammdf"):
        lg = logging.getLogger(name)
        saved.append((lg, lg.propagate, list(lg.handlers), lg.level))
        lg.handlers = [handler]  # asammdf brings its own stream handler
        lg.propagate = False
    trc = logging.getLogger("can.io.trc")
    saved.append((trc, trc.propagate, list(trc.handlers), trc.level))
    trc.setLevel(logging.INFO)   # its passed-over lines are INFO records (counted, not printed)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        for lg, prop, handlers, level in saved:
            lg.handlers = handlers
            lg.propagate = prop
            lg.setLevel(level)


@contextmanager
def _quiet_unraisable() -> Iterator[None]:
    """Silence "Exception ignored in __del__" reports of half-built third-party readers."""
    saved = sys.unraisablehook
    sys.unraisablehook = lambda unraisable: None
    try:
        yield
    finally:
        sys.unraisablehook = saved


def log_suffix(path: Path) -> tuple[str, bool]:
    """A log file's format suffix (lower case) and whether it is gzipped (``can.asc.gz``)."""
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz" and len(suffixes) >= 2:
        return suffixes[-2], True
    return (suffixes[-1] if suffixes else ""), False


def iter_messages(path: str | Path, state: ReadState | None = None) -> Iterator[can.Message]:
    """Messages of a log file, as python-can's ``LogReader(path)`` gives them, but robust.

    Unparseable text lines are skipped and counted in ``state.bad_lines``; a binary file that
    breaks off ends the iteration with ``state.complete = False``.

    Raises
    ------
    DecodeError
        Missing file, unknown format, a file the reader cannot open, or a text file whose lines
        are mostly unreadable.
    """
    path = Path(path)
    suffix, gz = log_suffix(path)
    state = state if state is not None else ReadState(path, suffix)
    if not path.exists():
        raise DecodeError(f"{path}: no such log file")
    if path.is_dir():
        raise DecodeError(f"{path}: is a directory, expected a CAN log")
    cls = can.io.MESSAGE_READERS.get(suffix)
    if cls is None or suffix == ".db":
        raise DecodeError(
            f"{path}: unknown log format '{suffix or path.name}' (python-can reads {', '.join(LOG_SUFFIXES)})"
        )
    state.size = path.stat().st_size
    if state.size == 0:
        raise DecodeError(f"{path}: the file is empty (0 bytes)")
    if issubclass(cls, TextIOMessageReader):
        yield from _iter_text(path, cls, gz, state)
    else:
        yield from _iter_binary(path, cls, gz, state)


def _iter_text(path: Path, cls: type, gz: bool, state: ReadState) -> Iterator[can.Message]:
    opener = (lambda: gzip.open(path, "rt", encoding="utf-8", errors="replace")) if gz else \
        (lambda: open(path, "r", encoding="utf-8", errors="replace", newline=None))
    with opener() as f:
        feed = _Lines(f, asc=state.fmt == ".asc")
        state.position = (lambda: feed.chars) if not gz else None
        state.line = lambda: feed.line_no
        first = True
        last_fail = -1
        header: list[str] = []
        while True:
            try:
                reader = cls(feed)
                it = iter(reader)
                if first:
                    msg = next(it)  # the header is every line consumed before this message's line
                    feed.recording = False
                    header = feed.recorded[:-1]
                    first = False
                    if _whole(msg, feed, state.fmt) and _asc_bytes_whole(msg, feed, state, header):
                        yield msg
                for msg in it:
                    if _whole(msg, feed, state.fmt) and _asc_bytes_whole(msg, feed, state, header):
                        yield msg
                _check_end(feed, header, state)
                return
            except StopIteration:
                _check_end(feed, header, state)
                return
            except (EOFError, OSError, gzip.BadGzipFile) as e:  # the file itself broke off
                state.stopped(f"line {feed.line_no}: file read failed: {type(e).__name__}: {e}")
                return
            except Exception as e:  # noqa: BLE001 - python-can's text parsers raise many types
                if feed.unterminated:  # the last line, without line end, does not parse: cut off
                    feed.cut = True
                    _check_end(feed, header, state)
                    return
                state.bad_lines += 1
                if state.bad_lines <= 5:
                    state.problem(f"line {feed.line_no}: unreadable {path.suffix} line skipped: "
                                  f"{type(e).__name__}: {e}")
                if state.bad_lines > 50 and state.bad_lines > _MAX_BAD_LINES_FRACTION * max(feed.line_no, 1):
                    raise DecodeError(
                        f"{path}: line {feed.line_no}: not a readable {path.suffix} log "
                        f"({state.bad_lines} of {feed.line_no} lines unreadable; first: "
                        f"{state.problems[0] if state.problems else type(e).__name__})"
                    ) from None
                if first:
                    feed.recording = False
                    header = feed.recorded[:-1]
                    first = False
                if feed.line_no == last_fail:
                    raise DecodeError(f"{path}: line {feed.line_no}: not a readable {path.suffix} log: "
                                      f"{type(e).__name__}: {e}") from None
                last_fail = feed.line_no
                feed.replay = deque(header)


def _whole(msg: can.Message, feed: _Lines, fmt: str = "") -> bool:
    """False for the frame of a last line without line end that a writer cut off mid-line: it
    holds fewer data bytes than its DLC field announces (ASC, TRC, CSV state the DLC), or its
    data end in half a byte (the readers take a lone last hex digit, or a candump line's odd last
    digit, for a whole byte). A candump line cut between two bytes looks like a shorter frame: the
    decoder counts it as a wrong length when the DBC says otherwise. An ASC line may go on after
    its data (a CAN FD line's duration, flags, CRC and bit timings; CANoe's ``Length = ...
    ID = ...``): a lone digit there is a whole field, not a cut data byte (``fmt``: the log's
    suffix)."""
    if not feed.unterminated or msg.is_remote_frame:
        return True
    tokens = feed.last.split()
    last = tokens[-1] if tokens else ""
    data_ends_line = fmt != ".asc" or _asc_data_end(tokens) >= len(tokens)
    cut = len(msg.data) < msg.dlc or (msg.dlc > 0 and data_ends_line and len(last) == 1 and last in string.hexdigits)
    if "#" in last:  # candump: ID#DATA or ID##<flags>DATA (CAN FD)
        hexdata = last.split("#", 1)[1]
        hexdata = hexdata[2:] if hexdata.startswith("#") else hexdata
        cut = cut or len(hexdata) % 2 == 1
    if cut:
        feed.cut = True
    return not cut


#: A classic ASC data line with ``n`` data bytes of two hex digits each, by ``n``.
_ASC_WHOLE_BYTES = [re.compile(r"[RT]x +d +[0-9A-Fa-f]{1,2}" + r" +[0-9A-Fa-f]{2}" * n + r"\s")
                    for n in range(9)]


def _asc_bytes_whole(msg: can.Message, feed: _Lines, state: ReadState, header: list[str]) -> bool:
    """False (the line skipped and counted unreadable) for an ASC frame line whose data bytes
    are not each two hex digits, as every ASC writer puts them: python-can's reader takes a lone
    digit for a whole byte, so a line with a character lost mid-file read as a frame with its
    bytes shifted (a review). The last line without line end is :func:`_whole`'s to judge (cut
    off), a log in ``base dec`` is left alone."""
    if not feed.asc or feed.unterminated or msg.is_remote_frame or msg.is_error_frame or not msg.dlc:
        return True
    if len(msg.data) <= 8 and _ASC_WHOLE_BYTES[len(msg.data)].search(feed.last) is not None:
        return True    # (the common line, without splitting it)
    tokens = feed.last.split()
    end = _asc_data_end(tokens)
    start = end - len(msg.data)
    if start < 0 or all(len(t) == 2 for t in tokens[start:end]):
        return True
    if any(h.split()[:2] == ["base", "dec"] for h in header):
        return True
    state.bad_lines += 1
    if state.bad_lines <= 5:
        state.problem(f"line {feed.line_no}: .asc frame line with a data byte that is not two hex digits skipped: "
                      f"{feed.last.strip()[:80]}")
    return False


def _asc_data_end(tokens: list[str]) -> int:
    """Index of the first token after the data bytes of an ASC frame line, as python-can's reader
    takes them (classic: ``time channel id dir d dlc data...``; CAN FD: ``time CANFD channel dir
    id [name] brs esi dlc length data...``); the line's length when it cannot tell."""
    try:
        if len(tokens) > 1 and tokens[1].upper() == "CANFD":
            brs = 5 if tokens[5].isdigit() else 6        # after the ID: brs, or a symbolic name
            return brs + 4 + int(tokens[brs + 3])        # brs esi dlc length, then the data
        return 6 + min(8, dlc2len(int(tokens[5], 16)))
    except (IndexError, ValueError):
        return len(tokens)


def _check_end(feed: _Lines, header: list[str], state: ReadState) -> None:
    """A text log whose last line, without line end, does not parse or misses data bytes was cut
    off mid-line (that line is not read; a complete last line without line end is read);
    a Vector ASC log that opened a ``Begin TriggerBlock`` and does not close it broke off
    (python-can's writer and CANoe close it when the recording ends): marked incomplete. A last
    line without line end that the reader logged a warning for (TRC: "Failed to parse
    message", the line skipped) is cut too: a TRC log cut before a line's data was read as
    complete (a review)."""
    if feed.unterminated and state.warning_line == feed.line_no:
        feed.cut = True
    if state.unread_types:
        n = sum(state.unread_types.values())
        state.bad_lines += n
        kinds = ", ".join(f"'{k}' {v}" for k, v in sorted(state.unread_types.items(), key=lambda kv: -kv[1])[:5])
        state.problem(f"line {state.first_unread_line}: {n} {state.fmt} line(s) of a record type the reader does "
                      f"not take (status, error counter, error frame, or a garbled type column: {kinds}) skipped")
    if feed.unterminated and feed.dropped and feed.dropped[-1] == feed.line_no:
        feed.dropped.pop()     # the last line, passed over: cut off
        feed.cut = True
    if feed.dropped:
        state.bad_lines += len(feed.dropped)
        more = len(feed.dropped) - 1
        lines = ", ".join(str(n) for n in feed.dropped[1:6]) + (" ..." if more > 5 else "")
        state.problem(f"line {feed.dropped[0]}: .asc frame line the reader does not take (a decimal comma, a stray "
                      f"character) skipped" + (f"; {more} more (line {lines})" if more else ""))
        if len(feed.dropped) > 50 and state.bad_lines > _MAX_BAD_LINES_FRACTION * max(feed.line_no, 1):
            raise DecodeError(f"{state.path}: not a readable .asc log ({state.bad_lines} of {feed.line_no} lines "
                              f"unreadable; first: {state.problems[-1]})")
    if feed.cut:
        state.stopped(f"line {feed.line_no}: the file ends inside it (no line end, frame not whole): "
                      "truncated, that line not read")
    elif state.fmt == ".asc" and any(h.lstrip().lower().startswith("begin triggerblock") for h in header) \
            and not feed.last.lstrip().lower().startswith("end triggerblock"):
        state.stopped(f"line {feed.line_no}: no 'End TriggerBlock' at the end: truncated")


def _iter_binary(path: Path, cls: type, gz: bool, state: ReadState) -> Iterator[can.Message]:
    fmt = path.suffix.upper().lstrip(".")
    error = None
    with _quiet_unraisable():
        try:
            reader = cls(gzip.open(path, "rb")) if gz else cls(path)
        except Exception as e:  # noqa: BLE001 - python-can/asammdf raise many types on garbage
            error = f"{path}: not a readable {fmt} log: {type(e).__name__}: {_cause(e)}"
        if error is not None:
            gc.collect()  # half-built readers (asammdf's MDF4) complain in __del__: let them, quietly
    if error is not None:
        raise DecodeError(error)
    f = getattr(reader, "file", None)
    if f is not None and hasattr(f, "tell") and not gz:
        state.position = f.tell
    try:
        try:
            yield from (_without_zeroed_records(reader, state) if state.fmt == ".mf4" else reader)
        except Exception as e:  # noqa: BLE001
            # (no count here: the reader's messages are counted per batch, and the summary says
            # how many frames were read; "after 0 messages" had been said after 376, a review)
            state.stopped(f"reading stopped before the file's end: {type(e).__name__}: "
                          f"{' '.join(str(e).split())[:200] or 'corrupt data'}")
        announced = getattr(reader, "file_size", None)
        if isinstance(announced, int) and announced > (state.size or 0) and not gz:
            state.stopped(f"file has {state.size} bytes but its {fmt} header says {announced}: truncated")
    finally:
        try:
            reader.stop()
        except Exception:  # noqa: BLE001 - closing a half-read file must not hide the real outcome
            pass


def _zero_record(msg: can.Message) -> bool:
    return not msg.arbitration_id and not msg.dlc and not msg.is_error_frame and not msg.is_remote_frame


def _without_zeroed_records(reader: Iterable[can.Message], state: ReadState) -> Iterator[can.Message]:
    """An MF4 reader's messages without the records of a stretch of the file that was zeroed
    (a damaged disk or copy): asammdf reads them as frames of ID 0 without data, all at one
    time, without a complaint, and a review found such a log read as complete, its loss only a
    gap and an unknown ID 0x0 in the summary. Two or more such records at one time stamp are
    dropped and counted as a problem (one alone is let through: ID 0 is a valid CAN ID)."""
    held: list[can.Message] = []
    dropped, after, last_t = 0, None, None
    for msg in chain(reader, [None]):     # None: the end, where the held records are judged too
        if msg is not None and _zero_record(msg) and (not held or msg.timestamp == held[0].timestamp):
            held.append(msg)
            continue
        if len(held) > 1:
            dropped += len(held)
            after = last_t if after is None else after
        else:
            yield from held
        held = [msg] if msg is not None and _zero_record(msg) else []
        if msg is not None and not held:
            last_t = msg.timestamp
            yield msg
    if dropped:
        state.bad_lines += dropped
        where = "at its start" if after is None else f"the first after the frame at {after:.3f} s"
        state.problem(f"{dropped} zeroed records (ID 0, no data, all at one time) skipped, {where}: "
                      "the file is damaged there")


@dataclass
class _Packed:
    """Mapped frames in file order, packed from message batches."""

    t: list = field(default_factory=list)
    aid: list = field(default_factory=list)
    flags: list = field(default_factory=list)
    chan: list = field(default_factory=list)
    length: list = field(default_factory=list)
    data: list = field(default_factory=list)


_ERR, _EXT, _RTR = 1, 2, 4


_T, _ID, _DATA = attrgetter("timestamp"), attrgetter("arbitration_id"), attrgetter("data")
_ERRF, _EXTF, _RTRF, _CHAN = (attrgetter("is_error_frame"), attrgetter("is_extended_id"),
                              attrgetter("is_remote_frame"), attrgetter("channel"))


def _pack(hits: list, width: int, chan_codes: dict, out: _Packed) -> None:
    """Append the fields of a batch of messages to ``out`` as numpy arrays (one pass per field)."""
    n = len(hits)
    out.t.append(np.fromiter(map(_T, hits), dtype=np.float64, count=n))
    out.aid.append(np.fromiter(map(_ID, hits), dtype=np.int64, count=n))
    flags = np.fromiter(map(_ERRF, hits), dtype=np.int8, count=n) * _ERR
    flags |= np.fromiter(map(_EXTF, hits), dtype=np.int8, count=n) * _EXT
    flags |= np.fromiter(map(_RTRF, hits), dtype=np.int8, count=n) * _RTR
    out.flags.append(flags)
    chans = list(map(_CHAN, hits))
    for ch in set(chans):
        chan_codes.setdefault(ch, len(chan_codes))
    if len(chan_codes) == 1:
        out.chan.append(np.zeros(n, dtype=np.int32))
    else:
        out.chan.append(np.fromiter(map(chan_codes.__getitem__, chans), dtype=np.int32, count=n))
    datas = list(map(_DATA, hits))
    lengths = np.fromiter(map(len, datas), dtype=np.int64, count=n)
    out.length.append(lengths)
    if n and np.all(lengths == width):
        mat = np.frombuffer(b"".join(datas), dtype=np.uint8).reshape(n, width).copy()
    else:
        mat = np.zeros((n, width), dtype=np.uint8)
        for i, d in enumerate(datas):
            d = bytes(d[:width])
            if d:
                mat[i, :len(d)] = np.frombuffer(d, dtype=np.uint8)
    out.data.append(mat)


def read_log(path: str | Path, mapping: CanMapping, mount: ImuMount, *, progress: bool = False,
             db: Any | None = None) -> tuple[pd.DataFrame, Summary]:
    """Decode the IMU channels of a CAN log into the vehicle-frame IMU table.

    Parameters
    ----------
    path : str or Path
        CAN log, any format python-can reads (``.asc .blf .csv .log .trc .mf4``).
    mapping : CanMapping
        ``[can]``: DBC, signal mapping, unit overrides, gap limit, alignment window.
    mount : ImuMount
        ``[imu]``: axes (IMU to vehicle frame). The lever arm is not applied here.
    progress : bool
        Show a tqdm progress bar on stderr.
    db : cantools Database, optional
        Use this database instead of loading ``mapping.dbc_path``.

    Returns
    -------
    table : pandas.DataFrame
        One row per sample of the clock message: ``t_s`` (log clock, s), ``gyro_[xyz]_rad_s``,
        ``accel_[xyz]_m_s2`` (vehicle frame, at the IMU), ``speed_m_s`` and a boolean
        ``fresh_<channel>`` per channel. ``attrs`` holds ``unavailable`` (value columns no
        mapped signal feeds: all NaN), ``channels``, ``imu_axes``, ``imu_position_m``, ``gaps``,
        ``complete`` and ``summary`` (JSON types).
    summary : Summary

    Raises
    ------
    ImuConfigError
        Mapping does not match the DBC, or ``align_window_s`` is too long for the IMU rate.
    DecodeError
        Unreadable DBC or log, no frame of the clock message, a mapped ID on two bus channels
        without ``[can] channel``, or a clock running backwards.
    """
    path = Path(path)
    plan = resolve(mapping, db)
    state = ReadState(path, log_suffix(path)[0])
    width = max(dlc2len(len2dlc(s.length)) for s in plan.sources)
    bar = _progress_bar(path, state) if progress else None
    gc_was_enabled = gc.isenabled()
    gc.disable()  # python-can allocates a Message per frame; gen-0 scans of the live batch cost 30 %
    try:
        table_inputs = _read_mapped(path, plan, width, state, bar)
    finally:
        if gc_was_enabled:
            gc.enable()
        if bar is not None:
            bar.close()  # leave=False: the bar disappears, errors stay one line
    packed, chan_codes, unknown, error_frames, n_read = table_inputs
    if n_read == 0:
        detail = f": {state.problems[0]}" if state.problems else ""
        raise DecodeError(f"{path}: no CAN frames in the log{detail}")
    return _finish(path, plan, mount, packed, chan_codes, unknown, error_frames, n_read, state)


def _read_mapped(path: Path, plan: DecodePlan, width: int, state: ReadState, bar: Any) -> tuple:
    """The hot loop: keep frames of mapped IDs, count the rest."""
    mapped_ids = plan.mapped_ids
    known = plan.known_ids
    packed = _Packed()
    chan_codes: dict = {}
    unknown: list[int] = []
    error_frames = 0
    n_read = 0
    with _quiet_readers(state):
        it = iter_messages(path, state)
        while True:
            batch = list(islice(it, _BATCH))
            if not batch:
                break
            hits = []
            hit = hits.append
            for msg in batch:
                aid = msg.arbitration_id
                if aid in mapped_ids:
                    hit(msg)
                elif msg.is_error_frame:   # its ID is the error's class, whatever the DBC names so
                    error_frames += 1
                elif aid not in known:
                    unknown.append(aid)
            n_read += len(batch)
            state.messages = n_read
            if hits:
                _pack(hits, width, chan_codes, packed)
            if bar is not None:
                _advance(bar, state)
    return packed, chan_codes, unknown, error_frames, n_read


def _progress_bar(path: Path, state: ReadState) -> Any:
    from tqdm import tqdm

    suffix, gz = log_suffix(path)
    by_bytes = path.is_file() and not gz and suffix != ".mf4"
    total = path.stat().st_size if by_bytes else None
    return tqdm(total=total, unit="B" if by_bytes else " frames", unit_scale=True, desc=path.name,
                leave=False, mininterval=0.2, delay=0.5, disable=None, file=sys.stderr)


def _advance(bar: Any, state: ReadState) -> None:
    if bar.total is not None and state.position is not None:
        try:
            pos = int(state.position())
        except (OSError, ValueError):
            return
        bar.update(max(0, min(pos, bar.total) - bar.n))
    elif bar.total is None:
        bar.update(state.messages - bar.n)


def _finish(path: Path, plan: DecodePlan, mount: ImuMount, packed: _Packed, chan_codes: dict,
            unknown: list[int], error_frames: int, n_read: int, state: ReadState) -> tuple[pd.DataFrame, Summary]:
    mapping = plan.mapping
    width = max(dlc2len(len2dlc(s.length)) for s in plan.sources)
    if packed.t:
        t = np.concatenate(packed.t)
        aid = np.concatenate(packed.aid)
        flags = np.concatenate(packed.flags)
        chan = np.concatenate(packed.chan)
        length = np.concatenate(packed.length)
        data = np.concatenate(packed.data)
    else:
        t = np.empty(0)
        aid = np.empty(0, np.int64)
        flags = np.empty(0, np.int8)
        chan = np.empty(0, np.int32)
        length = np.empty(0, np.int64)
        data = np.empty((0, width), np.uint8)
    n = len(t)
    keep = np.ones(n, dtype=bool)
    per_msg: dict[int, dict[str, int]] = {}
    msg_of = {}
    for s in plan.sources:
        msg_of.setdefault(s.frame_id, s)

    def count(mask: np.ndarray, key: str) -> None:
        for fid in np.unique(aid[mask]):
            per_msg.setdefault(int(fid), {})[key] = int(np.count_nonzero(mask & (aid == fid)))

    is_err = (flags & _ERR) != 0
    unmapped_frames = n_read - n - len(unknown) - error_frames
    error_frames += int(np.count_nonzero(is_err))
    keep &= ~is_err
    want_ext = np.zeros(n, dtype=bool)
    for fid, s in msg_of.items():
        want_ext[aid == fid] = s.is_extended
    other_ext = keep & (((flags & _EXT) != 0) != want_ext)
    unknown_ext = [(int(a), bool(e)) for a, e in zip(aid[other_ext], (flags[other_ext] & _EXT) != 0)]
    keep &= ~other_ext
    names_of_code = {code: ch for ch, code in chan_codes.items()}
    if mapping.channel is not None:
        wanted = {code for ch, code in chan_codes.items() if str(ch) == str(mapping.channel)}
        other = keep & ~np.isin(chan, list(wanted))
        count(other, "other_channel")
        keep &= ~other
    else:
        for fid, s in msg_of.items():
            codes = np.unique(chan[keep & (aid == fid)])
            if len(codes) > 1:
                shown = ", ".join(repr(names_of_code[int(c)]) for c in codes[:4])
                raise DecodeError(
                    f"{path}: frame {s.id_text} ({s.message.name}) appears on bus channels {shown}; "
                    f"set [can] channel to the one the IMU is on"
                )
    remote = keep & ((flags & _RTR) != 0)
    count(remote, "remote")
    keep &= ~remote
    bad_t = keep & ~(np.isfinite(t) & (np.abs(t) < 1e12))
    count(bad_t, "bad_timestamp")
    keep &= ~bad_t
    msg_len = np.zeros(n, dtype=np.int64)
    for fid, s in msg_of.items():
        msg_len[aid == fid] = s.length
    short = keep & (length < msg_len)
    if mapping.pad_short_frames:
        count(short, "padded")
    else:
        count(short, "wrong_length")
        keep &= ~short
    count(keep & (length > msg_len), "excess_length")
    # A stamp far ahead of both neighbours of its message ID (a clock glitch) is a bad timestamp;
    # backwards: earlier than an already accepted mapped frame by more than [can]
    # reorder_tolerance_s (0: at all), or earlier than the last accepted frame of its own ID
    # (dropped frames never raise the max; the streaming twin, imu.can_source.StreamDecoder,
    # sees frames in this order too and holds them for the tolerance).
    idx = np.flatnonzero(keep)
    for fid in np.unique(aid[idx]):
        rows = idx[aid[idx] == fid]
        tr = t[rows]
        if len(tr) >= 3:
            glitch = np.zeros(len(tr), dtype=bool)
            glitch[1:-1] = (tr[1:-1] - tr[:-2] > mapping.gap_limit_s) & (tr[1:-1] - tr[2:] > mapping.gap_limit_s)
            if glitch.any():
                gmask = np.zeros(n, dtype=bool)
                gmask[rows[glitch]] = True
                count(gmask, "bad_timestamp")
                keep[rows[glitch]] = False
    idx = np.flatnonzero(keep)
    if len(idx):
        # behind the newest accepted mapped frame by more than the reorder tolerance, or behind
        # the newest of its own ID (frames dropped here never raise either maximum)
        tk = t[idx]
        prev_max = np.maximum.accumulate(np.concatenate(([-np.inf], tk[:-1])))
        behind = tk < prev_max - mapping.reorder_tolerance_s
        if mapping.reorder_tolerance_s > 0:
            ok_pos = np.flatnonzero(~behind)
            ok_aid = aid[idx[ok_pos]]
            for fid in np.unique(ok_aid):
                pos = ok_pos[ok_aid == fid]
                tf = tk[pos]
                prev_id = np.maximum.accumulate(np.concatenate(([-np.inf], tf[:-1])))
                behind[pos[tf < prev_id]] = True
        back = idx[behind]
        if len(back):
            bmask = np.zeros(n, dtype=bool)
            bmask[back] = True
            count(bmask, "backwards")
            keep[back] = False
            if len(back) > 10 and len(back) > _MAX_BACKWARDS_FRACTION * len(idx):
                i0 = int(back[0])
                jump = float(prev_max[np.searchsorted(idx, i0)] - t[i0])
                hint = ("" if mapping.reorder_tolerance_s > 0 or np.max(prev_max[behind] - tk[behind]) > 0.1 else
                        "; if it was merged from several buses, [can] reorder_tolerance_s takes frames of "
                        "different IDs that far out of order")
                raise DecodeError(
                    f"{path}: timestamps run backwards for {len(back)} of {len(idx)} mapped frames, first at "
                    f"frame 0x{int(aid[i0]):X} t={t[i0]:.6f} s ({jump:.6f} s back): not one continuous recording"
                    + hint
                )
    # decode per source, drop duplicates, align
    frames: list[SourceFrames] = []
    stats_raw = []
    for si, s in enumerate(plan.sources):
        rows = np.flatnonzero(keep & (aid == s.frame_id))
        vals = decode_source(data[rows, :s.length] if len(rows) else np.zeros((0, s.length), np.uint8),
                             s, mapping.range_check)
        pres = vals.present
        rows_p = rows[pres]
        tp = t[rows_p]
        dup = _duplicates(tp, data[rows_p, :s.length], mapping.align_window_s)
        ok = ~dup
        frames.append(SourceFrames(t_s=tp[ok], si=vals.si[pres][ok], valid=vals.valid[pres][ok],
                                   channels=tuple(p.channel for p in s.signals)))
        stats_raw.append((int(np.count_nonzero(dup)), vals.out_of_range[pres][ok].sum(axis=0)))
    period = median_period_s(frames[plan.clock].t_s)
    imu_sources = sum(any(p.channel != "speed" for p in s.signals) for s in plan.sources)
    if math.isfinite(period) and mapping.align_window_s >= 0.5 * period and imu_sources > 1:
        raise ImuConfigError(
            f"[can] align_window_s = {mapping.align_window_s} s is not less than half the "
            f"{plan.sources[plan.clock].name} period ({1e3 * period:.3f} ms): lower it"
        )
    if len(frames[plan.clock].t_s) == 0:
        clock = plan.sources[plan.clock]
        why = "; ".join(f"{k} {v}" for k, v in per_msg.get(clock.frame_id, {}).items())
        raise DecodeError(
            f"{path}: no usable frame of {clock.name} ({clock.id_text}), the IMU clock message, among "
            f"{n_read} frames" + (f" ({why})" if why else "") + (f"; {state.problems[0]}" if state.problems else "")
        )
    columns, unaligned = align(frames, plan.clock, mapping.align_window_s, mapping.gap_limit_s, mount)
    summary = _summary(path, plan, mount, frames, stats_raw, per_msg, unaligned, unknown, unknown_ext,
                       error_frames, unmapped_frames, n_read, n, state, columns)
    attrs = table_attrs(plan, mount, summary)
    return make_frame(columns, attrs), summary


def _duplicates(t: np.ndarray, payload: np.ndarray, window_s: float) -> np.ndarray:
    """Frames of one source that repeat the last one kept: at its timestamp, or with its bytes
    within ``window_s`` (``align_window_s``) of it, an echo (a second interface on the bus, a
    gateway forwarding a frame twice). Such a copy of the clock message opened a sample of its
    own that no other frame joined, and the wheel speed went to that incomplete sample. Times
    are non-decreasing (frames behind their ID's newest are dropped before)."""
    dup = np.zeros(len(t), dtype=bool)
    if len(t) < 2:
        return dup
    dt = np.diff(t)
    for i in np.flatnonzero((dt < window_s) | (dt == 0.0)) + 1:   # nothing else can be a copy
        j = i - 1
        while dup[j]:
            j -= 1
        dup[i] = t[i] == t[j] or (t[i] - t[j] < window_s and np.array_equal(payload[i], payload[j]))
    return dup


def _summary(path, plan, mount, frames, stats_raw, per_msg, unaligned, unknown, unknown_ext, error_frames,
             unmapped_frames, n_read, n_mapped, state, columns) -> Summary:
    mapping = plan.mapping
    sources = []
    first_of_msg: set[int] = set()
    for si, s in enumerate(plan.sources):
        fr = frames[si]
        counts = per_msg.get(s.frame_id, {}) if s.frame_id not in first_of_msg else {}
        first_of_msg.add(s.frame_id)
        dups, _ = stats_raw[si]
        sources.append(SourceStats(
            name=s.name, frame_id=s.id_text, frames=len(fr.t_s), rate_hz=rate_hz(fr.t_s),
            duplicates=dups, unaligned=unaligned[si], gaps=find_gaps(s.name, fr.t_s, mapping.gap_limit_s),
            first_s=float(fr.t_s[0]) if len(fr.t_s) else math.nan,
            last_s=float(fr.t_s[-1]) if len(fr.t_s) else math.nan,
            **{k: v for k, v in counts.items()},
        ))
    channels = []
    value_col = dict(zip(CHANNELS, VALUE_COLUMNS))
    col_of = {ich: value_col[vch] for vch, ich, _ in vehicle_channel_map(mount)}
    for si, s in enumerate(plan.sources):
        fr = frames[si]
        _, oor = stats_raw[si]
        for j, p in enumerate(s.signals):
            v = fr.valid[:, j]
            channels.append(ChannelStats(
                channel=p.channel, column=col_of[p.channel], ref=p.ref, unit=p.unit,
                decoded=int(np.count_nonzero(v)), invalid=int(np.count_nonzero(~v)),
                out_of_range=int(oor[j]), rate_hz=rate_hz(fr.t_s[v]), minimum=p.minimum, maximum=p.maximum,
            ))
    unk: dict[str, int] = {}
    for i, c in sorted(Counter(unknown).items()):   # python ints: a reader may give an ID no int64 holds
        unk[f"0x{int(i):X}"] = int(c)
    for a, e in unknown_ext:
        key = f"0x{a:X}" + ("x" if e else " (standard)")
        unk[key] = unk.get(key, 0) + 1
    T = columns["t_s"]
    return Summary(
        log=str(path), frames_read=n_read, frames_mapped=n_mapped, samples=len(T),
        duration_s=float(T[-1] - T[0]) if len(T) else 0.0, sample_rate_hz=rate_hz(T),
        clock=plan.sources[plan.clock].name, sources=tuple(sources), channels=tuple(channels),
        unavailable=unavailable_channels(mapping.signals, mount), unknown_ids=unk,
        unmapped_frames=unmapped_frames,
        error_frames=error_frames, bad_lines=state.bad_lines, reader_warnings=state.warnings,
        problems=tuple(state.problems), complete=state.complete, stop_reason=state.stop_reason,
        range_check=mapping.range_check,
    )


def table_attrs(plan: DecodePlan, mount: ImuMount, summary: Summary) -> dict[str, Any]:
    """``DataFrame.attrs`` of the IMU table (JSON types, so parquet keeps them)."""
    mapping = plan.mapping
    by_col: dict[str, Any] = {}
    plans = plan.channel_plans
    col_of = dict(zip(CHANNELS, VALUE_COLUMNS))
    for vch, ich, sign in vehicle_channel_map(mount):
        if ich in plans:
            p = plans[ich][1]
            bare, negated = split_signal(p.ref)
            by_col[col_of[vch]] = f"{'-' if (sign < 0) != negated else ''}{bare} [{p.unit}]"
        else:
            by_col[col_of[vch]] = None
    return {
        "source": summary.log,
        "clock": summary.clock,
        "channels": by_col,
        "unavailable": list(summary.unavailable),
        "imu_axes": list(mount.axes),
        "imu_position_m": list(mount.position_m),
        "gap_limit_s": mapping.gap_limit_s,
        "align_window_s": mapping.align_window_s,
        "gaps": [[g.source, g.start_s, g.duration_s] for g in summary.gaps],
        "complete": summary.complete,
        "summary": summary.as_dict(),
    }

