"""Output files appear whole or not at all: each is written under ``PATH.partial`` beside it and
renamed over ``PATH`` (``os.replace``, atomic on one file system); an error or an interrupt
meanwhile removes the partial file, so no half-written table, report or calibration is left
looking complete under any name."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

__all__ = ["write_atomically", "write_bytes_atomically"]


def write_atomically(path: Path, write: Callable[[Path], object]) -> None:
    """``write(tmp)`` writes the file at ``tmp``, which is then renamed to ``path``."""
    path = Path(path)
    tmp = path.with_name(path.name + ".partial")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:       # a full disk, an interrupt: no half file left under any name
        tmp.unlink(missing_ok=True)
        raise


def write_bytes_atomically(path: Path, data: bytes) -> None:
    """``data`` as the whole content of ``path``."""
    write_atomically(path, lambda tmp: tmp.write_bytes(data))
