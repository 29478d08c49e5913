"""Write one simulated drive to disk in the contract's format (INTERFACE.md).

Files in the output folder:

* ``video.mp4`` (codec mp4v; ``video.avi`` for ffv1/mjpg; ``video/`` PNG frames for png);
* ``frames.csv``: ``frame,t_s`` in the CAN log's clock (plus ``[video] camera_time_offset_s``,
  the simulated synchronisation error, which the config's ``[video] start_s`` has too);
* ``can.<format>`` and the DBC, ``config.toml``;
* ``truth.csv`` at ``[truth] rate_hz``: the contract's columns plus extras
  (``yaw_world_deg``, ``road_pitch_deg``, ``station_m``, ``lateral_offset_m``, ``speed_m_s``,
  ``curvature_1_m``), in the log clock;
* ``truth_frames.csv``: the same per video frame, with ``frame`` and the true capture time;
* ``imu_truth.csv``: true angular rate and specific force (vehicle frame, at the IMU) and the
  biases, at the IMU's sample times in the log clock;
* ``scenario.toml``: the scenario it came from; ``preview.png``: the first frame.

The folder is written as ``<out>.partial`` and renamed when complete, so an interrupted run
never leaves a drive that looks whole; its first file, :data:`fusion.drive.SIMULATION_MARKER`
(removed before the rename), tells a later run that the folder is an unfinished simulation's.
"""

from __future__ import annotations

import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from tqdm import tqdm

from fusion.drive import SIMULATION_MARKER
from fusion.errors import ConfigError, InputError

from .imu_model import simulate_imu
from .render import Renderer
from .road import Road, Segment
from .scenario import Scenario
from .trajectory import MAX_CAR_SIDE_GRIP, MAX_LEAN_DEG, Trajectory

__all__ = ["DriveFiles", "SIM_ATTITUDE_WALK_DEG_SQRT_S", "build_road", "render_frames", "simulate", "truth_frame"]

VIDEO_NAMES = {"mp4v": "video.mp4", "ffv1": "video.avi", "mjpg": "video.avi", "png": "video"}
#: The attitude motion the simulated gyros do not see, as the filter's allowance for it
#: (``[fusion] attitude_walk_deg_sqrt_s``; the default, 0.05, is for a real vehicle's gyros):
#: the simulated IMU's rates are the trajectory's exactly, plus bias and white noise, so what
#: integrating them leaves out beyond that noise is the filter's 100 Hz integration of the
#: simulated motion (at 1 kHz it vanishes). Measured with :func:`fusion.metrics.gyro_attitude_drift`
#: (decoded rates less the true bias, windows of 1 and 4 s, the gyro noise's 0.005 deg/sqrt(s)
#: included) on the bundled sample drive: 0.0056 / 0.0067 / 0.0027 deg/sqrt(s) in roll / pitch /
#: yaw over 1 s, 0.0033 / 0.0093 / 0.0026 over 4 s; on the five benchmark drives 0.0021-0.0068
#: (README, "What the gyros leave out of the attitude"). 0.01 with the noise's 0.005 allows 0.0112.
#: Until the road's clothoid joints were eased (:data:`drivesim.road.EASE_M`) this was 0.02: the
#: roll rate stepped at every joint and the 100 Hz integration lost 0.02-0.03 deg of pitch there
#: (the sample drive's pitch drifted 0.0125 / 0.0145 deg/sqrt(s); ``tests/test_simulator.py``
#: checks the allowance on the sample drive).
SIM_ATTITUDE_WALK_DEG_SQRT_S = 0.01


@dataclass(frozen=True)
class DriveFiles:
    """Paths of a written drive."""

    root: Path
    video: Path
    frames: Path
    can_log: Path
    dbc: Path
    config: Path
    truth: Path
    truth_frames: Path
    imu_truth: Path

    @classmethod
    def in_dir(cls, root: Path, codec: str = "mp4v", can_format: str = "asc", dbc_name: str = "vifusion_imu.dbc"):
        root = Path(root)
        return cls(root, root / VIDEO_NAMES[codec], root / "frames.csv", root / f"can.{can_format}",
                   root / dbc_name, root / "config.toml", root / "truth.csv",
                   root / "truth_frames.csv", root / "imu_truth.csv")


def build_road(scenario: Scenario) -> Road:
    """The scenario's road, extended with its last curvature, bank and grade so that the
    camera sees road up to ``max_distance_m`` beyond where the drive ends."""
    m = scenario.motion
    v_max = max([m.speed_kmh] + [k[1] for k in m.speed_profile]) / 3.6
    need = m.start_station_m + v_max * scenario.duration_s * 1.1 + scenario.look.max_distance_m + 50.0
    segs = list(scenario.segments)
    total = sum(s.length_m for s in segs)
    if total < need:
        last = segs[-1]
        segs.append(Segment(need - total, last.curvature_1_m, last.bank_deg, last.grade_pct))
    c, b, g = scenario.start
    return Road(segs, c, b, g)


def truth_frame(traj: Trajectory, t_drive_s: np.ndarray, t_clock_s: np.ndarray) -> pd.DataFrame:
    """Truth table: angles in degrees with the contract's names, extras in SI units."""
    tr = traj.truth(t_drive_s)
    df = pd.DataFrame({"t_s": t_clock_s})
    for k in ("roll", "pitch", "yaw", "bank", "roll_world", "pitch_world", "yaw_world", "road_pitch"):
        df[f"{k}_deg"] = np.degrees(tr[k])
    for k in ("station_m", "lateral_offset_m", "speed_m_s", "curvature_1_m"):
        df[k] = tr[k]
    return df


def _write_table(df: pd.DataFrame, path: Path) -> None:
    """CSV with 9 significant digits, except the times: microseconds, whatever the epoch
    (a BLF log's clock is absolute epoch seconds, where 9 digits would be whole seconds)."""
    df = df.copy()
    df["t_s"] = df["t_s"].map("{:.6f}".format)
    df.to_csv(path, index=False, float_format="%.9g")


def render_frames(scenario: Scenario, t_drive_s, *, road: Road | None = None, traj: Trajectory | None = None,
                  rng: np.random.Generator | None = None, sensor: bool = True):
    """Yield the camera frames (uint8 BGR, or linear float radiance with ``sensor=False``) at
    drive times ``t_drive_s``, without writing anything: for tests and benchmarks."""
    road = road or build_road(scenario)
    traj = traj or Trajectory(road, scenario.motion)
    rng = rng or np.random.default_rng(scenario.seed)
    renderer = Renderer(road, scenario.camera, scenario.markings, scenario.look,
                        supersample=scenario.supersample, texture_seed=scenario.seed + 1)
    t = np.atleast_1d(np.asarray(t_drive_s, dtype=float))
    poses = traj.pose(t)
    R_v_from_cp, cam_v = scenario.mount.R_v_from_cp, scenario.mount.position_v
    for f in range(len(t)):
        R_w_from_v, P = poses["R_w_from_v"][f], poses["P_w"][f]
        rad = renderer.radiance(R_w_from_v @ R_v_from_cp, P + R_w_from_v @ cam_v,
                                poses["s"][f], poses["d"][f], poses["R_w_from_o"][f], P)
        yield renderer.sensor(rad, rng) if sensor else rad


def _degrees_text(angle_rad: float) -> str:
    """The shortest decimal of ``angle_rad`` in degrees that reads back to the same radians:
    a scenario's 15 deg tilt is ``15.0``, not ``math.degrees``'s ``14.999999999999998``, and the
    config still gives the filter and the estimator the very angle the drive was rendered with.
    An angle no rounding of its degrees reads back to (not one a scenario's degrees give) is
    written as ``repr(math.degrees(angle_rad))``, within a float's rounding of it."""
    deg = math.degrees(angle_rad)
    for digits in range(17):
        text = repr(round(deg, digits))
        if math.radians(float(text)) == angle_rad:
            return text
    return repr(deg)


def _config_toml(scenario: Scenario, dbc_name: str, signals: dict[str, str], fps: float, start_s: float) -> str:
    c, mnt, mk, imu = scenario.camera, scenario.mount, scenario.markings, scenario.imu
    lines = [
        f"# Written by vifusion simulate from scenario {scenario.name!r}.",
        "[camera]",
        f"width = {c.width}", f"height = {c.height}",
        f"fx = {c.fx!r}", f"fy = {c.fy!r}", f"cx = {c.cx!r}", f"cy = {c.cy!r}",
        f"distortion = [{', '.join(repr(float(x)) for x in c.distortion)}]",
        "", "[mount]",
        f"height_m = {mnt.height_m!r}", f"tilt_deg = {_degrees_text(mnt.tilt_rad)}",
    ]
    if mnt.x_m:
        lines.append(f"x_m = {mnt.x_m!r}")
    lines += ["", "[road]", f"lane_width_m = {mk.lane_width_m!r}", f"marker_width_m = {mk.widths_m[2]!r}",
              f"center_line = {'true' if mk.center_line else 'false'}"]
    if len(set(mk.widths_m)) > 1:
        lines.append(f"marker_widths_m = [{', '.join(repr(w) for w in mk.widths_m)}]")
    lines += ["", "[imu]", f"axes = [{', '.join(repr(a).replace(chr(39), chr(34)) for a in imu.axes)}]",
              f"position_m = [{', '.join(repr(float(p)) for p in imu.position_m)}]",
              "", "[can]", f'dbc = "{dbc_name}"', "", "[can.signals]"]
    lines += [f'{k} = "{v}"' for k, v in signals.items()]
    lines += ["", "[video]", f"fps = {fps!r}", f"start_s = {start_s!r}"]
    # The simulated IMU's datasheet values, as a user would enter theirs: gyro and
    # accelerometer noise, and the accelerometer's calibration residual (the scenario's
    # accel_bias_sigma_m_s2, not the bias this drive drew, which a user does not know). The
    # simulated vehicle has no vibration, suspension heave or road roughness (its specific
    # force is the model's to 0.002 m/s^2), so its accelerometer's noise is all the filter's
    # accelerometer allowance needs (the default is a real car's, NoiseModel.accel_meas_m_s2);
    # likewise its gyros have no scale-factor error, misalignment or vibration, so the attitude
    # allowance is SIM_ATTITUDE_WALK_DEG_SQRT_S. The road-model allowances stay at their defaults.
    lines += ["", "[fusion]", f"gyro_noise_deg_s = {max(imu.gyro_noise_deg_s, 1e-3)!r}",
              "accel_noise_m_s2 = [" + ", ".join([repr(max(imu.accel_noise_m_s2, 1e-3))] * 3) + "]",
              f"accel_noise_rate_hz = {imu.rate_hz!r}",
              f"accel_bias_sigma_m_s2 = {imu.accel_bias_sigma_m_s2!r}",
              f"attitude_walk_deg_sqrt_s = {SIM_ATTITUDE_WALK_DEG_SQRT_S!r}"]
    if scenario.motion.wheelbase_m > 0.0:
        # the vehicle's geometry, as a user would measure it (without one the config's text is
        # as it was)
        lines += [f"wheelbase_m = {scenario.motion.wheelbase_m!r}"]
    lines += [""]
    return "\n".join(lines)


def _open_video(path: Path, codec: str, fps: float, size: tuple[int, int]):
    if codec == "png":
        path.mkdir(parents=True, exist_ok=True)
        return None
    fourcc = {"mp4v": "mp4v", "ffv1": "FFV1", "mjpg": "MJPG"}[codec]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, size)
    if not writer.isOpened():
        raise InputError(f"{path}: OpenCV cannot write {codec} video on this machine")
    return writer


def simulate(scenario: Scenario, out_dir: str | Path, *, progress: bool = True,
             max_frames: int | None = None, render_video: bool = True, overwrite: bool = False) -> DriveFiles:
    """Simulate ``scenario`` into ``out_dir`` (written as ``OUT.partial``, renamed at the end,
    removed on an error); see the module docstring for the files. ``overwrite`` replaces an
    earlier simulated drive, and refuses a folder holding anything else."""
    from .canlog import DBC_PATH

    out_dir = Path(os.path.abspath(out_dir))      # '.' and '..' name the folders they are
    if not out_dir.name:
        raise InputError(f"{out_dir}: the root is not an output folder")
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is a file")
    if out_dir.is_dir() and any(out_dir.iterdir()):
        if not overwrite:
            raise InputError(f"{out_dir}: exists and is not empty (use --force to replace it)")
        other = sorted(p.name for p in out_dir.iterdir() if not _simulator_wrote(p.name))
        if other:   # --force replaces a drive, not a folder of anything (a review: '--out ..' emptied the parent)
            raise InputError(f"{out_dir} holds files a simulation did not write ({', '.join(other[:3])}"
                             f"{', ...' if len(other) > 3 else ''}): --force replaces only a simulated drive")
        if not all((out_dir / name).is_file() for name in _SIMULATED_ONLY):
            # a recorded drive has the same layout; only a simulation writes these
            raise InputError(f"{out_dir} is not a simulated drive (no {' or '.join(_SIMULATED_ONLY)}): --force "
                             "replaces only a simulated drive")
    tmp = out_dir.with_name(out_dir.name + ".partial")
    if tmp.is_file() or (tmp.is_dir() and any(tmp.iterdir()) and (
            any(not _simulator_wrote(p.name) for p in tmp.iterdir())
            or not any((tmp / n).is_file() for n in (SIMULATION_MARKER, "imu_truth.csv")))):
        # an unfinished simulation's folder is replaced (empty, or with the marker written first,
        # or the IMU truth, of a simulation from before the marker); a user's of that name is
        # not (a review: 'mydata.partial/notes.txt', and a folder holding only a config.toml,
        # were deleted without a word)
        raise InputError(f"{tmp} exists and is not an unfinished simulation's folder: move it, or give "
                         "another --out")
    plan = _plan(scenario)      # nothing touched yet: a drive no vehicle or IMU could give is refused here
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    try:
        (tmp / SIMULATION_MARKER).write_text("an unfinished 'vifusion simulate': simulate the drive again\n")
        _simulate_into(scenario, plan, tmp, progress=progress, max_frames=max_frames, render_video=render_video)
        (tmp / SIMULATION_MARKER).unlink()
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)    # no half drive left to look like one
        raise
    if out_dir.exists():
        shutil.rmtree(out_dir)
    tmp.rename(out_dir)
    return DriveFiles.in_dir(out_dir, scenario.video.codec, scenario.can.format, DBC_PATH.name)


#: Files only a simulation writes (the truth of the IMU and of each frame): a folder without them
#: is not one :func:`simulate` may replace, whatever else it holds.
_SIMULATED_ONLY = ("imu_truth.csv", "truth_frames.csv")


def _simulator_wrote(name: str) -> bool:
    """Whether a file of this name is one :func:`simulate` writes."""
    return (name in {"frames.csv", "config.toml", "truth.csv", "truth_frames.csv", "imu_truth.csv", "scenario.toml",
                     "preview.png", SIMULATION_MARKER, *VIDEO_NAMES.values()}
            or name.startswith("can.") or name.endswith(".dbc"))


@dataclass(frozen=True)
class _Plan:
    """What a drive is, computed before anything is written: the motion, the IMU's samples and
    the truth (the frames alone are rendered while writing). ``rng`` goes on to the frames."""

    road: Road
    traj: Trajectory
    rng: np.random.Generator
    imu_meas: pd.DataFrame
    speed: pd.DataFrame
    imu_true: pd.DataFrame
    t_truth: np.ndarray
    truth: pd.DataFrame     # at t_truth, in drive time


def _plan(scenario: Scenario) -> _Plan:
    """The drive's motion and IMU, refused (:class:`ConfigError`, one line) where no vehicle
    could drive it or the simulated IMU's CAN signals could not carry it (a review: 200 km/h on a
    50 m radius leaned 81 deg and its 6.1 g were clipped at the DBC's 4.18 g without a word)."""
    rng = np.random.default_rng(scenario.seed)
    road = build_road(scenario)
    traj = Trajectory(road, scenario.motion)
    t_truth = np.arange(int(math.floor(scenario.duration_s * scenario.truth_rate_hz + 1e-9)) + 1) / scenario.truth_rate_hz
    truth = truth_frame(traj, t_truth, t_truth)
    _check_vehicle_limits(scenario, traj, truth)
    imu_meas, speed, imu_true = simulate_imu(traj, scenario.imu, scenario.duration_s, rng)
    _check_imu_range(scenario, imu_meas, imu_true)
    return _Plan(road, traj, rng, imu_meas, speed, imu_true, t_truth, truth)


def _check_vehicle_limits(scenario: Scenario, traj: Trajectory, truth: pd.DataFrame) -> None:
    """A motorcycle leaning beyond :data:`MAX_LEAN_DEG` to the road, or a car whose tyres would
    take more than :data:`MAX_CAR_SIDE_GRIP` of side force, at any of the truth's times."""
    if scenario.motion.vehicle == "motorcycle":
        value, bound = np.abs(truth["roll_deg"].to_numpy()), MAX_LEAN_DEG
        what = "the motorcycle would lean {:.0f} deg to the road".format
        limit = (f"beyond the {MAX_LEAN_DEG:g} deg a motorcycle's tyres hold (a side force of "
                 f"tan({MAX_LEAN_DEG:g} deg) = {math.tan(math.radians(MAX_LEAN_DEG)):.2f} times the load)")
    else:
        value, bound = np.abs(traj.side_grip(truth["t_s"].to_numpy())), MAX_CAR_SIDE_GRIP
        what = "the car's tyres would take a side force of {:.2f} g".format
        limit = f"beyond the {MAX_CAR_SIDE_GRIP:g} g a car's road tyres hold"
    if not np.any(value > bound):
        return
    i = int(np.argmax(np.nan_to_num(value, posinf=np.finfo(float).max)))
    k = float(truth["curvature_1_m"].iloc[i])
    road = f"a {1.0 / abs(k):.0f} m radius" if abs(k) > 1e-9 else "a straight"
    where = f"at {truth['t_s'].iloc[i]:.2f} s, {truth['speed_m_s'].iloc[i] * 3.6:.0f} km/h on {road}"
    change = ("[motion] speed_profile" if scenario.motion.speed_profile else "[motion] speed_kmh") + \
        " or the road's curvature ([[road.segment]] curvature_1_m or radius_m)"
    if scenario.motion.manoeuvres:
        change += " or the manoeuvres ([[motion.manoeuvre]] a longer length_m, a smaller shift_m)"
    shown = what(float(value[i])) if np.isfinite(value[i]) else "the road would not carry the vehicle (it would take off)"
    raise ConfigError(f"{scenario.source}: {shown} {where}, {limit}: lower {change}")


def _check_imu_range(scenario: Scenario, measured: pd.DataFrame, truth: pd.DataFrame) -> None:
    """An IMU channel (with its bias and noise) at or beyond the range its CAN signal carries,
    which the log would hold as the range's end: named with its largest value, the range and
    the scenario's key that puts it there (the motion, the bias or the noise, whichever is the
    largest part of it)."""
    from imu.config import ImuMount

    from .canlog import DBC_PATH, imu_ranges

    spec = scenario.imu
    R_imu_from_v = ImuMount(spec.axes, spec.position_m).R_v_from_imu.T
    for col, (lo, hi, signal) in imu_ranges(DBC_PATH, spec.pitch_rate).items():
        v = measured[col].to_numpy()
        out = (v <= lo) | (v >= hi)
        if not np.any(out):
            continue
        kind, axis = col.split("_")[:2]
        k = "xyz".index(axis)
        unit = "rad_s" if kind == "gyro" else "m_s2"

        def in_imu_axes(fmt):   # a truth column triple (vehicle frame) in the IMU's axes, axis k
            return truth[[fmt.format(a) for a in "xyz"]].to_numpy() @ R_imu_from_v[k]

        motion = in_imu_axes(f"{kind}_{{}}_{unit}")
        bias = in_imu_axes(f"{kind}_bias_{{}}_{unit}")
        parts = {"motion": np.max(np.abs(motion)), "bias": np.max(np.abs(bias)),
                 "noise": np.max(np.abs(v - motion - bias))}
        i = int(np.flatnonzero(out)[np.argmax(np.abs(v[out]))])
        scale, shown = (math.degrees(1.0), "deg/s") if kind == "gyro" else (1.0, "m/s^2")
        key = {"motion": "lower [motion] speed_kmh or the road's curvature, or a gentler manoeuvre",
               "bias": f"a smaller [imu] {kind}_bias_{'deg_s' if kind == 'gyro' else 'm_s2'}"
                       f" (or {kind}_bias_walk_{'deg_s_sqrt_s' if kind == 'gyro' else 'm_s2_sqrt_s'})",
               "noise": f"a smaller [imu] {kind}_noise_{'deg_s' if kind == 'gyro' else 'm_s2'}"}
        cause = max(parts, key=parts.get)
        raise ConfigError(
            f"{scenario.source}: the simulated IMU's {kind}_{axis} (its own axes) reaches {v[i] * scale:.4g} {shown} "
            f"at {measured['t_s'].iloc[i]:.2f} s, beyond the {lo * scale:.4g} to {hi * scale:.4g} {shown} its CAN "
            f"signal {signal} carries (the log would hold the range's end); of it the motion gives up to "
            f"{parts['motion'] * scale:.3g}, the bias {parts['bias'] * scale:.3g}, the noise {parts['noise'] * scale:.3g}: "
            f"{key[cause]}")


def _simulate_into(scenario: Scenario, plan: _Plan, tmp: Path, *, progress: bool, max_frames: int | None,
                   render_video: bool) -> None:
    from .canlog import DBC_PATH, signal_map, write_can_log

    files = DriveFiles.in_dir(tmp, scenario.video.codec, scenario.can.format, DBC_PATH.name)
    road, traj, rng = plan.road, plan.traj, plan.rng
    offset = write_can_log(files.can_log, plan.imu_meas, plan.speed, dbc_path=DBC_PATH,
                           start_epoch_s=scenario.can.start_epoch_s, extra_traffic=scenario.can.extra_traffic,
                           include_pitch_rate=scenario.imu.pitch_rate, seed=scenario.seed)
    shutil.copyfile(DBC_PATH, files.dbc)
    imu_true = plan.imu_true.assign(t_s=plan.imu_true["t_s"] + offset)
    _write_table(imu_true, files.imu_truth)
    _write_table(plan.truth.assign(t_s=plan.t_truth + offset), files.truth)
    n = scenario.n_frames if max_frames is None else min(max_frames, scenario.n_frames)
    t_frames = scenario.video.start_s + np.arange(n) / scenario.video.fps
    tf = truth_frame(traj, t_frames, t_frames + offset)
    tf.insert(0, "frame", np.arange(n))
    _write_table(tf, files.truth_frames)
    stamped = t_frames + offset + scenario.video.camera_time_offset_s    # as the camera's clock says
    pd.DataFrame({"frame": np.arange(n), "t_s": stamped}).to_csv(files.frames, index=False, float_format="%.9f")
    # the config's start time is the first frame's stamp too: without frames.csv a run takes the
    # frames' times from it, and they had lacked the synchronisation error (a review)
    files.config.write_text(_config_toml(scenario, files.dbc.name, signal_map(scenario.imu.pitch_rate),
                                         scenario.video.fps, float(stamped[0]) if n
                                         else offset + scenario.video.camera_time_offset_s))
    if scenario.source is not None and Path(scenario.source).is_file():
        shutil.copyfile(scenario.source, tmp / "scenario.toml")

    if render_video and n:
        writer = _open_video(files.video, scenario.video.codec, scenario.video.fps,
                             (scenario.camera.width, scenario.camera.height))
        try:
            frames = render_frames(scenario, t_frames, road=road, traj=traj, rng=rng)
            for f, frame in enumerate(tqdm(frames, total=n, desc=f"render {scenario.name}", unit="frame",
                                           disable=not progress)):
                if f == 0:
                    cv2.imwrite(str(tmp / "preview.png"), frame)
                if writer is None:
                    cv2.imwrite(str(files.video / f"{f:06d}.png"), frame)
                else:
                    writer.write(frame)
        finally:
            if writer is not None:
                writer.release()
