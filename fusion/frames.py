"""Frames, rotations and Euler conventions for the fusion's users: :mod:`vision.frames`,
re-exported (``import fusion.frames``, ``from fusion.frames import R_from_rpy``). Their one
home stays below the filter, in ``vision``, which never imports ``fusion`` (STYLE.md)."""

from vision.frames import *  # noqa: F401,F403
from vision.frames import __all__  # noqa: F401
