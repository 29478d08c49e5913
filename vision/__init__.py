"""Vision: the vehicle's attitude relative to the road from one camera frame.

``estimate(image, camera, mount, seed=None, road=..., options=...)`` for one frame,
:class:`Estimator` for a sequence (it seeds each frame with the last), :func:`estimate_video`
for a whole video. The estimator and its heavy dependencies (OpenCV, numba) load on first use,
as does :mod:`vision.frames` (numba: a quarter second that a command's start-up, and a Ctrl-C
during it, need not wait for).
"""

from .camera import Camera, Mount, RoadMarkings
from .errors import VisionError

__all__ = [
    "Camera", "Mount", "RoadMarkings", "VisionError", "frames",
    "estimate", "Estimator", "VisionEstimate", "EstimatorOptions", "options_from_table",
    "estimate_video", "FrameSource",
]

_LAZY = {
    "estimate": "estimator", "Estimator": "estimator", "VisionEstimate": "estimator",
    "EstimatorOptions": "options", "options_from_table": "options",
    "estimate_video": "video", "FrameSource": "video",
}


def __getattr__(name):
    if name == "frames":
        import importlib

        return importlib.import_module(".frames", __name__)
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
