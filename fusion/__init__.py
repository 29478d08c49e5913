"""Fusion: EKF of CAN IMU rates and vision angles; road bank angle with its uncertainty."""

from vision import frames

__all__ = ["frames"]
