"""The vehicle's DBC: loading it with cantools and resolving ``[can.signals]`` against it.

:func:`load_dbc` turns every way a DBC can fail to load into one line naming the file (and the
line, for syntax errors). :func:`resolve` checks each mapped ``MESSAGE.SIGNAL`` against the
database, reads its unit and builds a :class:`DecodePlan`: which frame IDs to decode, how, and
which message's frames set the sample clock.

A *source* is one stream of frames: a message, or the frames of a multiplexed message that carry
one multiplexer value. Signals of one source are decoded from the same frames; the alignment of
:mod:`imu.samples` works on sources.
"""

from __future__ import annotations

import difflib
import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cantools

from .config import ACCEL, CHANNELS, GYRO, CanMapping, split_signal
from .errors import DecodeError, ImuConfigError
from .units import si_factor

__all__ = ["MuxCondition", "SignalPlan", "SourcePlan", "DecodePlan", "load_dbc", "resolve"]


@dataclass(frozen=True)
class MuxCondition:
    """A frame carries a multiplexed signal only when ``int(multiplexer) in ids``."""

    signal: Any  # cantools.database.can.Signal
    ids: frozenset[int]


@dataclass(frozen=True)
class SignalPlan:
    """One mapped channel: where it is and how to turn it into SI.

    ``factor_si`` multiplies the DBC physical value (``raw * scale + offset``) to rad/s, m/s^2
    or m/s, negative for a signal mapped as ``"-MESSAGE.SIGNAL"`` (counted the other way than
    the IMU axis: the range check is on the DBC's value, before it); ``resolution_si`` is one
    raw step in SI. ``minimum``/``maximum`` are the DBC's
    physical range (None where the DBC gives none). ``invalid_raw``: raw values (unsigned bits)
    that are no measurement: the signal's ``raw_invalid`` and the value-table entries named as
    such (:data:`INVALID_CHOICE`, e.g. ``VAL_ ... 65535 "SNA"``).
    """

    channel: str
    ref: str
    signal: Any  # cantools.database.can.Signal
    unit: str
    factor_si: float
    resolution_si: float
    minimum: float | None
    maximum: float | None
    invalid_raw: frozenset = frozenset()


@dataclass(frozen=True)
class SourcePlan:
    """A stream of frames: message ``frame_id`` restricted by ``mux`` (empty: every frame)."""

    name: str
    frame_id: int
    is_extended: bool
    length: int
    message: Any  # cantools.database.can.Message
    mux: tuple[MuxCondition, ...]
    signals: tuple[SignalPlan, ...]

    @property
    def id_text(self) -> str:
        return f"0x{self.frame_id:X}" + ("x" if self.is_extended else "")


@dataclass(frozen=True)
class DecodePlan:
    """Everything the decoders need, resolved once from the DBC and the mapping.

    ``clock`` indexes the source whose frames define the sample times: the source of the first
    mapped channel in the order gyro_x, gyro_y, gyro_z, accel_x, accel_y, accel_z (IMU axes).
    ``known_ids`` holds every frame ID of the DBC, to tell unmapped traffic from unknown IDs.
    """

    dbc_path: Path
    sources: tuple[SourcePlan, ...]
    clock: int
    known_ids: frozenset[int]
    mapping: CanMapping

    @property
    def channel_plans(self) -> dict[str, tuple[int, SignalPlan]]:
        """IMU-axes channel -> (source index, plan)."""
        return {sp.channel: (i, sp) for i, src in enumerate(self.sources) for sp in src.signals}

    @property
    def mapped_ids(self) -> frozenset[int]:
        return frozenset(s.frame_id for s in self.sources)


# (cantools quotes the text, and its message as a whole: 'DBC: "... column 1: ">>!<<hello""')
_SYNTAX = re.compile(r"line (\d+), column (\d+): \"(.*?)\"\"?$", re.S)


#: cantools' refusal of VAL_ entries whose signal no message has: ``VAL_ <frame id> <signal>``.
_UNUSED_VAL = re.compile(r"VAL_ (\d+) (\w+)")


def _printable(text: str) -> str:
    """``text`` with each character that is not printable as its Python escape (``\\x00``): a
    binary file's excerpt in an error had put NUL and control bytes on the terminal (a review)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _text_encoding(path: Path) -> str | None:
    """The encoding of a DBC or SYM file: UTF-8 (a BOM allowed) when its bytes are valid UTF-8,
    else cp1252, the encoding of Vector's tools and cantools' default for these formats; None
    (cantools' default) for other formats. cantools alone reads a DBC as cp1252, and a UTF-8
    unit "°/s" came out "Â°/s", an unknown unit (a review)."""
    if path.suffix.lower() not in (".dbc", ".sym"):
        return None
    try:
        path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        return "cp1252"
    return "utf-8-sig"


def load_dbc(path: str | Path) -> Any:
    """Load a DBC (or any database format cantools reads) with clear one-line errors.

    Parameters
    ----------
    path : str or Path
        The database file.

    Returns
    -------
    cantools.database.can.Database

    Raises
    ------
    DecodeError
        Missing or unreadable file, or a syntax error (the message names file, line and column).

    Notes
    -----
    ``strict=False``: overlapping signals elsewhere in a real DBC do not stop the decoding of the
    mapped ones; :func:`resolve` checks the mapped signals fit their message. Value tables
    (``VAL_``) of signals that no message has are dropped (cantools refuses them).
    """
    path = Path(path)
    if not path.exists():
        raise DecodeError(f"{path}: no such DBC file")
    if path.is_dir():
        raise DecodeError(f"{path}: is a directory, expected a DBC file")
    log = logging.getLogger("cantools")
    level = log.level
    log.setLevel(logging.ERROR)   # its warnings (e.g. two messages with one ID) are ours to word: resolve()
    try:
        encoding = _text_encoding(path)
        try:
            return cantools.database.load_file(path, encoding=encoding, strict=False)
        except cantools.database.UnsupportedDatabaseFormatError as e:
            stale = _UNUSED_VAL.findall(" ".join(str(e).split()))
            if not stale or path.suffix.lower() != ".dbc":
                raise
            # VAL_ tables of signals no message has (a DBC edited by hand, a signal renamed):
            # cantools refuses the whole file even with strict=False; they describe nothing
            # that is decoded, so they are dropped (a review: such a file was refused, and the
            # error hid the mapped signal's own absence)
            text = path.read_text(encoding=encoding or "utf-8")
            for frame_id, signal in stale:
                text = re.sub(rf"(?m)^[ \t]*VAL_[ \t]+{frame_id}[ \t]+{re.escape(signal)}[ \t][^;]*;[ \t]*\r?\n?",
                              "", text)
            return cantools.database.load_string(text, database_format="dbc", strict=False)
    except cantools.database.UnsupportedDatabaseFormatError as e:
        text = " ".join(str(e).split())
        m = _SYNTAX.search(text)
        if m:
            line, col = int(m.group(1)), int(m.group(2))
            near = _printable(m.group(3).replace(">>!<<", "")[:60])
            hint = (f"; the statement before it (line {line - 1}) may lack its ';'"
                    if col == 1 and line > 1 else "")
            raise DecodeError(f"{path}:{line}: DBC syntax error at column {col} near '{near}'{hint}") from None
        raise DecodeError(f"{path}: not a DBC cantools can read: {_printable(text[:200])}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise DecodeError(f"{path}: cannot read DBC: {e}") from None
    except Exception as e:  # noqa: BLE001 - cantools' parsers raise many types on garbage input
        raise DecodeError(f"{path}: cannot parse DBC: {type(e).__name__}: "
                          f"{_printable(' '.join(str(e).split())[:200])}") from None
    finally:
        log.setLevel(level)


def resolve(mapping: CanMapping, db: Any | None = None) -> DecodePlan:
    """Check ``mapping`` against the DBC and build the decode plan.

    Parameters
    ----------
    mapping : CanMapping
        ``[can]`` settings; ``mapping.dbc_path`` is loaded unless ``db`` is given.
    db : cantools Database, optional
        An already loaded database.

    Raises
    ------
    ImuConfigError
        A mapped message or signal is not in the DBC, its unit is missing, unknown or of the
        wrong quantity, one signal is mapped twice, or the signal does not fit its message.
    DecodeError
        The DBC does not load.
    """
    if mapping.dbc_path is None and db is None:
        raise ImuConfigError("[can] dbc is missing: give the DBC as the config's [can] dbc or with --dbc")
    path = Path(mapping.dbc_path) if mapping.dbc_path is not None else Path("DBC")
    if db is None:
        db = load_dbc(path)
    name = str(path)   # as the user gave it, folder and all (load_dbc's errors name it so too)
    names = [m.name for m in db.messages]
    by_source: dict[tuple, list[SignalPlan]] = {}
    src_info: dict[tuple, tuple[Any, tuple[MuxCondition, ...]]] = {}
    seen: dict[str, str] = {}
    for channel in CHANNELS:
        if channel not in mapping.signals:
            continue
        ref = mapping.signals[channel]
        bare, negated = split_signal(ref)   # negated: the signal counts the other way than the IMU axis
        msg_name, sig_name = bare.split(".")
        if bare in seen:
            raise ImuConfigError(f"[can.signals] {channel} and {seen[bare]} both map {bare}")
        seen[bare] = channel
        try:
            msg = db.get_message_by_name(msg_name)
        except KeyError:
            raise ImuConfigError(
                f'{name}: [can.signals] {channel} = "{ref}": no message "{msg_name}" in the DBC'
                + _suggest(msg_name, names)
            ) from None
        if getattr(msg, "is_container", False):
            raise ImuConfigError(f"{name}: {ref}: container messages are not supported")
        id_key = (int(msg.frame_id), bool(msg.is_extended_frame))
        twin = next((m.name for m in db.messages if m.name != msg.name
                     and (int(m.frame_id), bool(m.is_extended_frame)) == id_key), None)
        if twin is not None:
            raise ImuConfigError(f"{name}: messages {msg.name} and {twin} both have ID {msg.frame_id:#x}: "
                                 "their frames cannot be told apart")
        try:
            sig = msg.get_signal_by_name(sig_name)
        except KeyError:
            raise ImuConfigError(
                f'{name}: [can.signals] {channel} = "{ref}": message {msg_name} has no signal "{sig_name}"'
                + _suggest(sig_name, [s.name for s in msg.signals])
            ) from None
        unit_override = mapping.units.get(channel)
        unit = unit_override if unit_override is not None else (sig.unit or "")
        where = f"[can.units] {channel}" if unit_override is not None else f"{name}: {ref}"
        factor = si_factor(unit, channel, where) * (-1.0 if negated else 1.0)
        if not (math.isfinite(float(sig.scale)) and sig.scale != 0 and math.isfinite(float(sig.offset))):
            raise ImuConfigError(f"{name}: {ref}: scale {float(sig.scale):g}, offset {float(sig.offset):g}: "
                                 "the scale must be a finite non-zero number and the offset finite")
        _check_fits(sig, msg, f"{name}: {ref}")
        mux = _mux_chain(sig, msg, f"{name}: {ref}")
        key = (msg.frame_id, bool(msg.is_extended_frame),
               tuple((c.signal.name, tuple(sorted(c.ids))) for c in mux))
        lo, hi = sig.minimum, sig.maximum
        plan = SignalPlan(
            channel=channel, ref=ref, signal=sig, unit=unit, factor_si=factor,
            resolution_si=abs(float(sig.scale) * factor),
            minimum=None if lo is None else float(lo), maximum=None if hi is None else float(hi),
            invalid_raw=_invalid_raw(sig),
        )
        by_source.setdefault(key, []).append(plan)
        src_info[key] = (msg, mux)
    # the mapped signals of one message, across its multiplexer branches, with their selectors
    by_message: dict[tuple, tuple[Any, list]] = {}
    for key, plans in by_source.items():
        msg, mux = src_info[key]
        by_message.setdefault(key[:2], (msg, []))[1].extend(
            [(p.signal, p.ref, mux) for p in plans] + [(c.signal, f"multiplexer {c.signal.name}", ()) for c in mux])
    for msg, signals in by_message.values():
        _check_disjoint(signals, f"{name}: message {msg.name}")
    sources = []
    for key, plans in by_source.items():
        msg, mux = src_info[key]
        label = msg.name + "".join(f"[{c.signal.name}={'|'.join(map(str, sorted(c.ids)))}]" for c in mux)
        sources.append(SourcePlan(
            name=label, frame_id=msg.frame_id, is_extended=bool(msg.is_extended_frame),
            length=int(msg.length), message=msg, mux=mux, signals=tuple(plans),
        ))
    first = next(ch for ch in GYRO + ACCEL if ch in mapping.signals)
    clock = next(i for i, s in enumerate(sources) if any(p.channel == first for p in s.signals))
    known = frozenset(m.frame_id for m in db.messages)
    return DecodePlan(dbc_path=path, sources=tuple(sources), clock=clock, known_ids=known, mapping=mapping)


#: Value-table names that mark a raw value as no measurement (signal not available, error, not
#: yet initialised), as real DBCs write them (matched with '_' and '-' read as spaces) ...
INVALID_CHOICE = re.compile(r"\bsna\b|invalid|error|fault|unavail|\bnot avail|\bn/?a\b|\binit", re.IGNORECASE)
#: ... unless the name says the opposite ('No error', 'NO_FAULT', 'Initialized', 'OK') ...
VALID_CHOICE = re.compile(r"\bno (error|fault|failure)s?\b|\binitiali[sz]ed\b|\bok(ay)?\b", re.IGNORECASE)
#: ... which a negation undoes ('Not initialized', 'not OK').
NEGATED_VALID = re.compile(r"\bnot (initiali[sz]ed|ok(ay)?|valid|ready)\b", re.IGNORECASE)


def invalid_choice(name: str) -> bool:
    """Whether a value-table name marks its raw value as no measurement."""
    text = re.sub(r"[_\-]+", " ", name)
    if NEGATED_VALID.search(text):
        return True
    return bool(INVALID_CHOICE.search(text)) and not VALID_CHOICE.search(text)


def _invalid_raw(sig: Any) -> frozenset:
    """Raw values of ``sig`` that are no measurement (unsigned bits of its length)."""
    mask = (1 << int(sig.length)) - 1
    out = {int(raw) & mask for raw, name in (getattr(sig, "choices", None) or {}).items()
           if invalid_choice(str(name))}
    if sig.raw_invalid is not None:
        out.add(int(sig.raw_invalid) & mask)
    return frozenset(out)


def _suggest(word: str, options: list[str]) -> str:
    close = difflib.get_close_matches(word, options, n=3, cutoff=0.6)
    if close:
        return f" (did you mean {', '.join(close)}?)"
    if not options:
        return " (it has none)"
    shown = ", ".join(sorted(options)[:8])
    return f" (it has {shown}{', ...' if len(options) > 8 else ''})"


def _check_fits(sig: Any, msg: Any, where: str) -> None:
    if sig.byte_order == "little_endian":
        first, last = sig.start, sig.start + sig.length - 1
    else:
        msb = 8 * (sig.start // 8) + 7 - sig.start % 8
        first, last = msb, msb + sig.length - 1
    if sig.length < 1 or sig.length > 64 or first < 0 or last >= 8 * msg.length:
        raise ImuConfigError(
            f"{where}: signal bits {first}..{last} do not fit the {msg.length}-byte message"
        )
    if sig.is_float and sig.length not in (16, 32, 64):
        raise ImuConfigError(f"{where}: a float signal must be 16, 32 or 64 bits, got {sig.length}")


def _bits(sig: Any) -> frozenset[tuple[int, int]]:
    """The (byte, bit) places of a signal in its message (a Motorola signal's ``start`` is its
    most significant bit, the bits running down within a byte, then on to the next byte's bit 7)."""
    if sig.byte_order == "little_endian":
        return frozenset((i // 8, i % 8) for i in range(sig.start, sig.start + sig.length))
    msb = 8 * (sig.start // 8) + 7 - sig.start % 8
    return frozenset((p // 8, 7 - p % 8) for p in range(msb, msb + sig.length))


def _check_disjoint(signals: list[tuple[Any, str, tuple]], where: str) -> None:
    """The mapped signals of one message (with their multiplexer conditions) and its
    multiplexers must not share bits where they can be in one frame: they would decode one
    number as two (cantools' strict check of the whole DBC is off, for the overlaps real DBCs
    have elsewhere, :func:`load_dbc`; such a mapping was accepted, a review). Signals in
    different branches of one multiplexer (disjoint values of it) are never in one frame."""
    for i, (a, name_a, mux_a) in enumerate(signals):
        for b, name_b, mux_b in signals[i + 1:]:
            shared = _bits(a) & _bits(b)
            exclusive = any(ca.signal.name == cb.signal.name and not ca.ids & cb.ids for ca in mux_a for cb in mux_b)
            if shared and a is not b and not exclusive:
                raise ImuConfigError(f"{where}: {name_a} and {name_b} share {len(shared)} bit(s) (byte "
                                     f"{min(shared)[0]}): the DBC's signal layout is wrong")


def _mux_chain(sig: Any, msg: Any, where: str) -> tuple[MuxCondition, ...]:
    chain: list[MuxCondition] = []
    cur = sig
    for _ in range(8):
        if not cur.multiplexer_signal:
            return tuple(reversed(chain))
        ids = cur.multiplexer_ids or []
        parent = msg.get_signal_by_name(cur.multiplexer_signal)
        _check_fits(parent, msg, f"{where} (multiplexer {parent.name})")
        chain.append(MuxCondition(signal=parent, ids=frozenset(int(i) for i in ids)))
        cur = parent
    raise ImuConfigError(f"{where}: multiplexing nested deeper than 8 levels")
