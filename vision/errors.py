"""Exceptions of the vision package."""

__all__ = ["VisionError"]


class VisionError(ValueError):
    """Bad camera, mount or road description, or an image the caller must not pass on."""
