"""Test-wide helpers."""

import os
from pathlib import Path


def shared_data_dir() -> Path:
    """``../shared/data`` of the checkout (INTERFACE: real data recorded by others lives there,
    never copied into the repo). ``VIFUSION_SHARED_DATA`` overrides; otherwise the nearest
    ancestor of the checkout that has ``shared/data``."""
    env = os.environ.get("VIFUSION_SHARED_DATA")
    if env:
        return Path(env)
    repo = Path(__file__).resolve().parents[1]
    for parent in repo.parents:
        if (parent / "shared" / "data").is_dir():
            return parent / "shared" / "data"
    return repo.parent / "shared" / "data"
