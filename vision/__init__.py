"""Vision: the vehicle's attitude relative to the road from one camera frame."""

from .camera import Camera, Mount, RoadMarkings
from .errors import VisionError
from . import frames

__all__ = ["Camera", "Mount", "RoadMarkings", "VisionError", "frames"]
