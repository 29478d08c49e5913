"""IMU: calibrated angular rate, specific force and speed from CAN logs or a live bus."""

__all__: list[str] = []
