"""Cache keys of simulated drives: a scenario's bytes and the simulator's code.

The code is hashed as its syntax tree without docstrings (and so without comments, blank lines
and line numbers): an edit to a docstring renders the same drive and must not cost a render of
every cached drive (the five benchmark drives take about 15 min on two cores; a docstring edit
to ``road.py`` forced one in the seventeenth session).
"""

from __future__ import annotations

import ast
import hashlib
from collections.abc import Iterable
from pathlib import Path

__all__ = ["code_digest", "drive_key"]


def _is_docstring(node: ast.stmt) -> bool:
    return isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)


def code_digest(path: str | Path) -> bytes:
    """The module at ``path`` as its syntax tree without string statements (docstrings, and
    the strings some write after an attribute): what decides what it computes."""
    tree = ast.parse(Path(path).read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        for field in ("body", "orelse", "finalbody"):
            body = getattr(node, field, None)
            if isinstance(body, list) and body and isinstance(body[0], ast.stmt):
                kept = [n for n in body if not _is_docstring(n)]
                setattr(node, field, kept or [ast.Pass()])
    return ast.dump(tree).encode()


def drive_key(scenario: bytes, modules: Iterable[str | Path]) -> str:
    """12 hex digits of the SHA-256 of a scenario file's bytes and the modules' code."""
    h = hashlib.sha256(scenario)
    for path in modules:
        h.update(code_digest(path))
    return h.hexdigest()[:12]
