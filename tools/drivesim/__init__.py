"""drivesim: a drive simulator with exact ground truth (our stand-in for BikeSim).

Road of clothoids with bank and grade (:mod:`.road`), vehicle motion and exact attitude
(:mod:`.trajectory`), ray-cast camera frames (:mod:`.render`), IMU and wheel speed
(:mod:`.imu_model`) encoded onto a CAN log (:mod:`.canlog`), all written by :mod:`.drive` from a
scenario file (:mod:`.scenario`). ``vifusion simulate SCENARIO --out DIR`` is the command.
"""

__all__ = ["load_scenario", "simulate"]


def __getattr__(name):
    # Lazy: importing drivesim must not compile the renderer.
    if name == "load_scenario":
        from .scenario import load_scenario
        return load_scenario
    if name == "simulate":
        from .drive import simulate
        return simulate
    raise AttributeError(name)
