"""Vectorised signal decoding: many frames of one message at once, with numpy.

cantools decodes one frame per call (about 10 us each); here every mapped signal of a message is
pulled out of an ``(n, width)`` byte matrix with a few array operations. The result is
*identical* to ``cantools Message.decode(data, decode_choices=False)`` for every value below
2**53 (``tests/test_imu_decode.py`` proves it on random layouts, both byte orders, signed,
float and multiplexed signals and CAN FD lengths).

Bit numbering follows the DBC (and cantools): a little-endian (Intel) signal starts at its least
significant bit, bit ``i`` being bit ``i % 8`` of byte ``i // 8``; a big-endian (Motorola) signal
starts at its most significant bit in the same "sawtooth" numbering, whose network position
(0 = most significant bit of byte 0) is ``8 * (start // 8) + 7 - start % 8``.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .dbc import MuxCondition, SourcePlan

__all__ = [
    "frames_matrix", "extract_raw", "physical", "mux_present", "SourceValues", "decode_source",
    "raw_scalar", "physical_scalar", "decode_frame",
]

_U64 = np.uint64


def frames_matrix(payloads: Sequence[bytes], width: int) -> tuple[np.ndarray, np.ndarray]:
    """Stack payloads into an ``(n, width)`` uint8 matrix, zero-padded or cut to ``width``.

    Returns the matrix and each payload's original length (int64, bytes).
    """
    n = len(payloads)
    lengths = np.fromiter((len(p) for p in payloads), dtype=np.int64, count=n)
    out = np.zeros((n, width), dtype=np.uint8)
    if n == 0:
        return out, lengths
    if np.all(lengths == width):
        out[:] = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(n, width)
        return out, lengths
    for length in np.unique(lengths):
        rows = np.flatnonzero(lengths == length)
        k = int(min(length, width))
        if k == 0:
            continue
        if length <= width:
            blob = b"".join(bytes(payloads[i]) for i in rows)
        else:
            blob = b"".join(bytes(payloads[i])[:k] for i in rows)
        out[rows, :k] = np.frombuffer(blob, dtype=np.uint8).reshape(len(rows), k)
    return out, lengths


def _bit_span(sig: Any) -> tuple[int, int]:
    """(first, last) bit of a signal: LSB-first index for little endian, network index for big."""
    if sig.byte_order == "little_endian":
        return sig.start, sig.start + sig.length - 1
    msb = 8 * (sig.start // 8) + 7 - sig.start % 8
    return msb, msb + sig.length - 1


def extract_raw(data: np.ndarray, sig: Any) -> np.ndarray:
    """Raw unsigned bits of ``sig`` from an ``(n, width)`` uint8 matrix, as uint64.

    Standard CAN (``width == 8``) reads each row as one 64-bit word (``<u8`` or ``>u8``) and
    shifts; longer CAN FD frames assemble only the (at most 9) bytes the signal touches.
    """
    n, width = data.shape
    length = int(sig.length)
    first, last = _bit_span(sig)
    mask = _U64((1 << length) - 1) if length < 64 else None
    if width == 8:
        rows = np.ascontiguousarray(data)
        if sig.byte_order == "little_endian":
            raw = rows.view("<u8")[:, 0] >> _U64(first)
        else:
            raw = rows.view(">u8")[:, 0].astype(_U64) >> _U64(63 - last)
        return raw & mask if mask is not None else raw.astype(_U64, copy=False)
    b0, b1 = first // 8, last // 8
    nbytes = b1 - b0 + 1
    cols = data[:, b0:b1 + 1].astype(_U64)
    if sig.byte_order == "little_endian":
        shift = first % 8
        word = np.zeros(n, dtype=_U64)
        for j in range(min(nbytes, 8)):
            word |= cols[:, j] << _U64(8 * j)
        raw = word >> _U64(shift)
        if nbytes == 9:  # only when shift > 0: the top bits come from a ninth byte
            raw |= cols[:, 8] << _U64(64 - shift)
    else:
        shift = 7 - last % 8
        if nbytes <= 8:
            word = np.zeros(n, dtype=_U64)
            for j in range(nbytes):
                word |= cols[:, j] << _U64(8 * (nbytes - 1 - j))
            raw = word >> _U64(shift)
        else:
            word = np.zeros(n, dtype=_U64)
            for j in range(8):
                word |= cols[:, j] << _U64(8 * (7 - j))
            raw = (word << _U64(8 - shift)) | (cols[:, 8] >> _U64(shift))
    return raw & mask if mask is not None else raw


def physical(data: np.ndarray, sig: Any) -> np.ndarray:
    """Physical value ``raw * scale + offset`` (DBC units), float64, as cantools computes it.

    Signed signals are two's complement; float signals (16, 32 or 64 bits) are IEEE 754.
    """
    raw = extract_raw(data, sig)
    length = int(sig.length)
    if sig.is_float:
        with np.errstate(invalid="ignore"):  # signalling NaNs in the payload are just NaN here
            if length == 64:
                value = raw.view(np.float64)
            elif length == 32:
                value = raw.astype(np.uint32).view(np.float32).astype(np.float64)
            else:
                value = raw.astype(np.uint16).view(np.float16).astype(np.float64)
    else:
        if not sig.is_signed:
            ival = raw
        elif length == 64:
            ival = raw.view(np.int64)
        else:
            negative = (raw >> _U64(length - 1)) & _U64(1)
            ival = raw.astype(np.int64) - (negative.astype(np.int64) << np.int64(length))
        value = ival.astype(np.float64)
        if _integer_conversion(sig):
            out = value * float(sig.conversion.scale) + float(sig.conversion.offset)
            # cantools keeps an exact Python int here: beyond 2^53 the float arithmetic would
            # round twice (the raw value, then the sum), so those rows are computed exactly
            big = np.flatnonzero(np.abs(out) >= _EXACT_LIMIT)
            for i in big:
                out[i] = float(int(ival[i]) * sig.conversion.scale + sig.conversion.offset)
            return out
    conv = sig.conversion
    # Python floats, as cantools computes: inf * 0 is NaN and an overflow is inf, silently
    with np.errstate(invalid="ignore", over="ignore"):
        return value * float(conv.scale) + float(conv.offset)


#: Below this magnitude raw * scale + offset is exact in float64 for integer scale and offset
#: (with a margin for the rounding of the estimate that decides it).
_EXACT_LIMIT = 2.0**53 * (1.0 - 2.0**-10)


def _integer_conversion(sig: Any) -> bool:
    """Scale and offset both integers: cantools then returns exact integers."""
    conv = sig.conversion
    return all(isinstance(v, int) and not isinstance(v, bool) for v in (conv.scale, conv.offset))


def mux_present(data: np.ndarray, mux: Sequence[MuxCondition]) -> np.ndarray:
    """Rows whose multiplexer chain selects the signal (``int(value) in ids``, as cantools)."""
    present = np.ones(data.shape[0], dtype=bool)
    for cond in mux:
        value = physical(data, cond.signal)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(value)
            mux_no = np.where(ok, np.trunc(np.where(ok, value, 0.0)), -1).astype(np.int64)
        present &= ok & np.isin(mux_no, np.fromiter(cond.ids, dtype=np.int64, count=len(cond.ids)))
    return present


@dataclass
class SourceValues:
    """Decoded frames of one source.

    ``present[i]`` is False for frames the multiplexer assigns to other signals; ``si`` is
    ``(n, k)`` in rad/s, m/s^2 or m/s for the source's k signals, NaN where ``valid`` is False;
    ``out_of_range`` and ``raw_invalid`` (``(n, k)`` bool) mark present frames outside the DBC
    range or equal to the signal's "invalid" raw value.
    """

    present: np.ndarray
    si: np.ndarray
    valid: np.ndarray
    out_of_range: np.ndarray
    raw_invalid: np.ndarray


def decode_source(data: np.ndarray, src: SourcePlan, range_check: bool) -> SourceValues:
    """Decode every mapped signal of ``src`` from an ``(n, width)`` frame matrix.

    Parameters
    ----------
    data : ndarray of uint8, shape (n, width)
        Payloads padded to the message length.
    src : SourcePlan
    range_check : bool
        Values outside the DBC ``[minimum|maximum]`` become invalid when True (counted always).
    """
    n = data.shape[0]
    k = len(src.signals)
    present = mux_present(data, src.mux) if src.mux else np.ones(n, dtype=bool)
    si = np.empty((n, k))
    valid = np.empty((n, k), dtype=bool)
    oor = np.zeros((n, k), dtype=bool)
    rinv = np.zeros((n, k), dtype=bool)
    for j, plan in enumerate(src.signals):
        phys = physical(data, plan.signal)
        ok = np.isfinite(phys)
        outside = np.zeros(n, dtype=bool)
        with np.errstate(invalid="ignore"):
            if plan.minimum is not None and plan.maximum is not None and plan.minimum < plan.maximum:
                outside = (phys < plan.minimum) | (phys > plan.maximum)
        bad_raw = np.zeros(n, dtype=bool)
        if plan.invalid_raw:
            bad_raw = np.isin(extract_raw(data, plan.signal), np.array(sorted(plan.invalid_raw), dtype=np.uint64))
        oor[:, j] = outside & present
        rinv[:, j] = bad_raw & present
        ok &= ~bad_raw
        if range_check:
            ok &= ~outside
        valid[:, j] = ok & present
        si[:, j] = np.where(valid[:, j], phys * plan.factor_si, np.nan)
    return SourceValues(present=present, si=si, valid=valid, out_of_range=oor, raw_invalid=rinv)


# --- scalar twin for the live path -----------------------------------------------------------
# One frame at a time the numpy path costs ~100 us in array overheads; these functions do the same
# arithmetic on Python ints and floats (the same IEEE-754 double operations, so identical results,
# checked in tests/test_imu_decode.py) in a few microseconds.

def raw_scalar(payload: bytes, sig: Any) -> int:
    """Raw unsigned bits of ``sig`` from one payload (at least the message length)."""
    length = int(sig.length)
    first, last = _bit_span(sig)
    if sig.byte_order == "little_endian":
        word = int.from_bytes(payload, "little")
        return (word >> first) & ((1 << length) - 1)
    word = int.from_bytes(payload, "big")
    return (word >> (8 * len(payload) - 1 - last)) & ((1 << length) - 1)


def physical_scalar(payload: bytes, sig: Any) -> float:
    """:func:`physical` for one payload."""
    raw = raw_scalar(payload, sig)
    length = int(sig.length)
    if sig.is_float:
        fmt = {16: ">e", 32: ">f", 64: ">d"}[length]
        value = struct.unpack(fmt, raw.to_bytes(length // 8, "big"))[0]
    else:
        ival = raw - (1 << length) if sig.is_signed and raw >> (length - 1) else raw
        if _integer_conversion(sig):   # exact, then rounded once, as cantools
            return float(ival * sig.conversion.scale + sig.conversion.offset)
        value = float(ival)
    conv = sig.conversion
    # Python floats, as cantools computes: inf * 0 is NaN and an overflow is inf, silently
    with np.errstate(invalid="ignore", over="ignore"):
        return value * float(conv.scale) + float(conv.offset)


def decode_frame(payload: bytes, src: SourcePlan, range_check: bool) -> tuple[bool, list, list, list, list]:
    """:func:`decode_source` for one payload (padded to the message length).

    Returns ``(present, si, valid, out_of_range, raw_invalid)``, the last four per signal.
    """
    for cond in src.mux:
        v = physical_scalar(payload, cond.signal)
        if not math.isfinite(v) or int(v) not in cond.ids:
            return False, [], [], [], []
    si, valid, oor, rinv = [], [], [], []
    for plan in src.signals:
        phys = physical_scalar(payload, plan.signal)
        ok = math.isfinite(phys)
        outside = (plan.minimum is not None and plan.maximum is not None and plan.minimum < plan.maximum
                   and (phys < plan.minimum or phys > plan.maximum))
        bad_raw = bool(plan.invalid_raw) and raw_scalar(payload, plan.signal) in plan.invalid_raw
        oor.append(int(outside))
        rinv.append(int(bad_raw))
        ok = ok and not bad_raw and not (range_check and outside)
        valid.append(ok)
        si.append(phys * plan.factor_si if ok else math.nan)
    return True, si, valid, oor, rinv
