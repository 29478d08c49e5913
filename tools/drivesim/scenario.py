"""Scenario files: a TOML description of one simulated drive, checked key by key.

A scenario uses the contract's ``[camera]``, ``[mount]``, ``[road]`` and ``[imu]`` keys
(``[camera]`` may give ``hfov_deg`` instead of ``fx``) and adds what only a simulator needs.
Every key is listed in the README ("Scenario files"; units are in the names, defaults in
:func:`parse_scenario`); an unknown or badly typed key is a one-line error naming it.
"""

from __future__ import annotations

import math
import unicodedata
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imu.config import ImuMount
from imu.errors import ImuError

from fusion.config import Table, parse_camera, parse_mount, read_toml
from fusion.errors import ConfigError
from vision.camera import Camera, Mount

from .render import Look, Markings
from .road import Segment
from .trajectory import Manoeuvre, Motion

__all__ = ["Scenario", "ImuSpec", "VideoSpec", "CanSpec", "load_scenario", "parse_scenario"]

LOG_FORMATS = ("asc", "blf", "log", "trc", "csv", "mf4")
CODECS = ("mp4v", "ffv1", "mjpg", "png")
#: The frame sizes the simulator renders, px a side. At least 64: OpenCV's writers fail far below
#: (mp4v and ffv1 refuse 1x1, MJPG's corrupted the heap and killed the process at 4x4), and the
#: estimator finds nothing much below it (tiny_banked_curve over 4 s: no valid frame at 96x54,
#: 5 % at 128x72, 12 % at 160x90), while a drive it fails on can still be made. At most 4096: a
#: frame takes about 150 bytes a pixel to render (measured: float64 radiance, sub-pixel buffers,
#: the sensor's noise), 2.5 GB at 4096x4096 (a review's 20000x20000 failed allocating 3 GiB),
#: and mp4v writes at most 8190; the papers' cameras are 1920x1080 at most.
FRAME_PX = (64, 4096)


@dataclass(frozen=True)
class ImuSpec:
    """The simulated IMU and wheel-speed sensor (noise as 1-sigma per sample)."""

    axes: tuple[str, str, str] = ("x", "-y", "-z")
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.5)
    rate_hz: float = 100.0
    start_s: float = 0.0
    gyro_noise_deg_s: float = 0.05
    gyro_bias_deg_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_bias_walk_deg_s_sqrt_s: float = 0.0
    accel_noise_m_s2: float = 0.03
    accel_bias_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: The accelerometer's bias after calibration as its datasheet gives it (1-sigma, every
    #: axis): what the drive's config tells the filter (``[fusion] accel_bias_sigma_m_s2``),
    #: whatever bias this drive drew. Until 2026-11-26 the configs gave the filter the drawn
    #: biases' own magnitudes per axis, which no user knows.
    accel_bias_sigma_m_s2: float = 0.05
    accel_bias_walk_m_s2_sqrt_s: float = 0.0
    pitch_rate: bool = True
    speed_rate_hz: float = 50.0
    speed_noise_m_s: float = 0.02
    speed_scale: float = 1.0


@dataclass(frozen=True)
class VideoSpec:
    fps: float = 30.0
    start_s: float = 0.0
    codec: str = "mp4v"
    #: Error added to the times written in frames.csv (a mis-synchronised logger), s.
    camera_time_offset_s: float = 0.0


@dataclass(frozen=True)
class CanSpec:
    format: str = "asc"
    extra_traffic: bool = True
    start_epoch_s: float = 1.7e9


@dataclass(frozen=True)
class Scenario:
    name: str
    duration_s: float
    seed: int
    camera: Camera
    mount: Mount
    markings: Markings
    segments: tuple[Segment, ...]
    motion: Motion
    imu: ImuSpec
    video: VideoSpec
    can: CanSpec
    look: Look = field(default_factory=Look)
    supersample: int = 4
    truth_rate_hz: float = 100.0
    description: str = ""
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)  # start curvature 1/m, bank deg, grade %
    source: Path | None = None

    @property
    def n_frames(self) -> int:
        return max(0, int(math.floor((self.duration_s - self.video.start_s) * self.video.fps + 1e-9)))

    @property
    def marker_width_m(self) -> float:
        return self.markings.widths_m[2]


def _segment(t: Table) -> Segment:
    length = t.get("length_m", "float", min=0.1)
    if t.has("radius_m") and t.has("curvature_1_m"):    # one was named "not a known key"
        raise t.error("radius_m", "and curvature_1_m both given: give one (curvature_1_m = 1 / radius_m)")
    if t.has("radius_m"):
        r = t.get("radius_m", "float")
        if r == 0:
            raise t.error("radius_m", "must not be 0 (use curvature_1_m = 0 for a straight)")
        if abs(r) < 5.0:   # curvature_1_m's limit, 0.2 1/m
            raise t.error("radius_m", f"must be at least 5 m either way (a curvature of at most 0.2 1/m), got {r:g}")
        curvature = 1.0 / r
    else:
        curvature = t.get("curvature_1_m", "float", 0.0, min=-0.2, max=0.2)
    seg = Segment(length, curvature, t.get("bank_deg", "float", 0.0, min=-20.0, max=20.0),
                  t.get("grade_pct", "float", 0.0, min=-20.0, max=20.0))
    t.done()
    return seg


def _manoeuvre(t: Table, lane_width_m: float) -> Manoeuvre:
    kind = t.get("kind", "str", choices=("lane_change", "double_lane_change", "weave"))
    m = Manoeuvre(
        kind=kind,
        start_m=t.get("start_m", "float", min=0.0),
        length_m=t.get("length_m", "float", min=1.0),
        shift_m=t.get("shift_m", "float", lane_width_m if kind != "weave" else 0.3,
                      min=-3 * lane_width_m, max=3 * lane_width_m),
        hold_m=t.get("hold_m", "float", 30.0, min=0.0),
        repeat=t.get("repeat", "int", 1, min=1, max=1000),
        period_m=t.get("period_m", "float", 0.0, min=0.0),
    )
    if m.repeat > 1 and m.period_m <= 0:
        raise t.error("period_m", "must be > 0 when repeat > 1")
    t.done()
    return m


def _list_of_tables(root: Table, key: str) -> list[Table]:
    root._read.add(key)
    items = root.data.get(key, [])
    if not isinstance(items, list) or not all(isinstance(x, dict) for x in items):
        raise root.error(key, "must be an array of tables ([[...]])")
    return [Table(x, f"{root.name}.{key}#{i + 1}", root.source) for i, x in enumerate(items)]


def parse_scenario(data: dict, source: str) -> Scenario:
    """Build a :class:`Scenario` from parsed TOML; errors name ``source``, the table and key."""
    known = {"scenario", "camera", "mount", "road", "motion", "imu", "video", "can", "render", "truth"}
    for name in data:
        if not isinstance(data[name], dict):   # a key before any [table] (it was "[name] is not a known table")
            raise ConfigError(f"{source}: {name} is given before any [table] header: put it under its table "
                              "(the file begins with [scenario])")
        if name not in known:
            raise ConfigError(f"{source}: [{name}] is not a known table (known: {', '.join(sorted(known))})")

    def table(name: str) -> Table:
        return Table(data.get(name, {}), name, source)

    sc = table("scenario")
    name = sc.get("name", "str", Path(source).stem)
    if any(unicodedata.category(c) == "Cc" for c in name):   # a newline in it broke the summary line
        raise sc.error("name", f"must not hold control characters (a newline, a tab), got {name!r}")
    duration = sc.get("duration_s", "float", min=0.1, max=3600.0)
    # numpy's generators take no negative seed, the renderer's compiled code none of 2^63 or more
    seed = sc.get("seed", "int", 0, min=0, max=2**63 - 1)
    vehicle = sc.get("vehicle", "str", "motorcycle", choices=("motorcycle", "car"))
    description = sc.get("description", "str", "")
    sc.done()

    for required in ("camera", "mount"):
        if required not in data:
            raise ConfigError(f"{source}: [{required}] is missing")
    camera = parse_camera(table("camera"))
    mount = parse_mount(table("mount"))

    rd = table("road")
    lane = rd.get("lane_width_m", "float", 3.5, min=1.0, max=10.0)
    marker = rd.get("marker_width_m", "float", 0.15, min=0.02, max=1.0)
    widths = rd.get("marker_widths_m", "floats", (marker,) * 3, length=3, min=0.02, max=1.0)
    markings = Markings(
        lane_width_m=lane, widths_m=widths, center_line=rd.get("center_line", "bool", True),
        dash_m=rd.get("dash_m", "float", 6.0, min=0.1), gap_m=rd.get("gap_m", "float", 12.0, min=0.0),
        dash_phase_m=rd.get("dash_phase_m", "float", 0.0), shoulder_m=rd.get("shoulder_m", "float", 0.5, min=0.0),
    )
    start = (rd.get("start_curvature_1_m", "float", 0.0, min=-0.2, max=0.2),
             rd.get("start_bank_deg", "float", 0.0, min=-20.0, max=20.0),
             rd.get("start_grade_pct", "float", 0.0, min=-20.0, max=20.0))
    seg_tables = _list_of_tables(rd, "segment")
    if not seg_tables:
        raise rd.error("segment", "needs at least one [[road.segment]]")
    segments = tuple(_segment(t) for t in seg_tables)
    rd.done()

    mo = table("motion")
    profile = None
    if mo.has("speed_profile"):
        mo._read.add("speed_profile")
        raw = mo.data["speed_profile"]
        if not (isinstance(raw, list) and raw and all(isinstance(k, list) and len(k) == 2 for k in raw)):
            raise mo.error("speed_profile", "must be a list of [t_s, speed_kmh] pairs")
        try:
            profile = tuple((float(a), float(b)) for a, b in raw)
        except (TypeError, ValueError):
            raise mo.error("speed_profile", "must be a list of [t_s, speed_kmh] pairs") from None
        if not all(math.isfinite(a) and 0.0 <= a <= 1e6 for a, _ in profile):
            raise mo.error("speed_profile", "times must be finite, 0 to 1e6 s")
        if not all(1.0 <= b <= 400.0 for _, b in profile):   # speed_kmh's range (NaN fails too)
            raise mo.error("speed_profile", f"speeds must be 1 to 400 km/h, got {[b for _, b in profile]}")
        if any(b2 <= a2 for (a2, _), (b2, _) in zip(profile[:-1], profile[1:])):
            raise mo.error("speed_profile", "times must increase")
        if mo.has("speed_kmh"):
            raise mo.error("speed_kmh", "and speed_profile both given: the profile alone sets the speed")
    motion = Motion(
        vehicle=vehicle,
        speed_kmh=mo.get("speed_kmh", "float", 100.0, min=1.0, max=400.0),
        speed_profile=profile or (),
        start_station_m=mo.get("start_station_m", "float", 20.0, min=0.0, max=1e5),
        lateral_offset_m=mo.get("lateral_offset_m", "float", -lane / 2, min=-3 * lane, max=3 * lane),
        manoeuvres=tuple(_manoeuvre(t, lane) for t in _list_of_tables(mo, "manoeuvre")),
        pitch_amplitude_deg=mo.get("pitch_amplitude_deg", "float", 0.3, min=0.0, max=10.0),
        pitch_frequency_hz=mo.get("pitch_frequency_hz", "float", 1.3, min=0.0, max=20.0),
        pitch_phase_deg=mo.get("pitch_phase_deg", "float", 0.0),
        pitch_per_decel_deg=mo.get("pitch_per_decel_deg", "float", 0.3, min=0.0, max=5.0),
        car_roll_gain_deg=mo.get("car_roll_gain_deg", "float", 0.5, min=0.0, max=5.0),
        wheelbase_m=mo.get("wheelbase_m", "float", 0.0, min=0.0, max=10.0),
    )
    mo.done()
    if motion.manoeuvres:
        # the manoeuvres add up (a lane change repeated shifts again each time): the offset they
        # reach is held to the same three lanes as lateral_offset_m (a review: 92.7 m)
        ends = [m.start_m + max(m.repeat - 1, 0) * m.period_m + 2 * m.length_m + m.hold_m for m in motion.manoeuvres]
        s_grid = np.linspace(min(m.start_m for m in motion.manoeuvres), max(ends), 20001)
        reach = float(np.max(np.abs(motion.lateral_offset_m + sum(m.offset(s_grid) for m in motion.manoeuvres))))
        if reach > 3 * lane + 1e-9:
            raise mo.error("manoeuvre", f"the manoeuvres take the vehicle {reach:.1f} m off the centre line, "
                                        f"more than three lanes ({3 * lane:g} m)")

    im = table("imu")
    imu = ImuSpec(
        axes=im.get("axes", "strs", ("x", "-y", "-z"), length=3),
        position_m=im.get("position_m", "floats", (0.0, 0.0, 0.5), length=3),
        rate_hz=im.get("rate_hz", "float", 100.0, min=1.0, max=2000.0),
        start_s=im.get("start_s", "float", 0.0, min=0.0),
        gyro_noise_deg_s=im.get("gyro_noise_deg_s", "float", 0.05, min=0.0),
        gyro_bias_deg_s=im.get("gyro_bias_deg_s", "floats", (0.0, 0.0, 0.0), length=3),
        gyro_bias_walk_deg_s_sqrt_s=im.get("gyro_bias_walk_deg_s_sqrt_s", "float", 0.0, min=0.0),
        accel_noise_m_s2=im.get("accel_noise_m_s2", "float", 0.03, min=0.0),
        accel_bias_m_s2=im.get("accel_bias_m_s2", "floats", (0.0, 0.0, 0.0), length=3),
        accel_bias_sigma_m_s2=im.get("accel_bias_sigma_m_s2", "float", 0.05, min=1e-3, max=10.0),
        accel_bias_walk_m_s2_sqrt_s=im.get("accel_bias_walk_m_s2_sqrt_s", "float", 0.0, min=0.0),
        pitch_rate=im.get("pitch_rate", "bool", True),
        speed_rate_hz=im.get("speed_rate_hz", "float", 50.0, min=0.1, max=1000.0),
        speed_noise_m_s=im.get("speed_noise_m_s", "float", 0.02, min=0.0),
        speed_scale=im.get("speed_scale", "float", 1.0, min=0.5, max=1.5),
    )
    im.done()
    try:
        ImuMount(imu.axes, imu.position_m)
    except ImuError as e:
        raise ConfigError(f"{source}: {e}") from None

    vi = table("video")
    video = VideoSpec(
        fps=vi.get("fps", "float", 30.0, min=0.1, max=1000.0),
        start_s=vi.get("start_s", "float", 0.0, min=0.0),
        codec=vi.get("codec", "str", "mp4v", choices=CODECS),
        camera_time_offset_s=vi.get("camera_time_offset_s", "float", 0.0, min=-10.0, max=10.0),
    )
    vi.done()
    _check_frame_size(camera, video.codec, source)

    cn = table("can")
    can = CanSpec(
        format=cn.get("format", "str", "asc", choices=LOG_FORMATS),
        extra_traffic=cn.get("extra_traffic", "bool", True),
        # seconds since 1970 (1e10 is the year 2286; milliseconds, 1.7e12, are a mistake the log
        # readers would refuse or the ASC writer's calendar fail on)
        start_epoch_s=cn.get("start_epoch_s", "float", 1.7e9, min=0.0, max=1e10),
    )
    cn.done()

    rn = table("render")
    default = Look()
    look = Look(
        blur_sigma_px=rn.get("blur_sigma_px", "float", default.blur_sigma_px, min=0.0, max=10.0),
        read_noise_dn=rn.get("read_noise_dn", "float", default.read_noise_dn, min=0.0, max=50.0),
        shot_noise_gain=rn.get("shot_noise_gain", "float", default.shot_noise_gain, min=0.0, max=10.0),
        texture_fine=rn.get("texture_fine", "float", default.texture_fine, min=0.0, max=0.5),
        texture_coarse=rn.get("texture_coarse", "float", default.texture_coarse, min=0.0, max=0.5),
        max_distance_m=rn.get("max_distance_m", "float", default.max_distance_m, min=10.0, max=1000.0),
    )
    supersample = rn.get("supersample", "int", 4, min=4, max=16)
    rn.done()

    tr = table("truth")
    truth_rate = tr.get("rate_hz", "float", 100.0, min=1.0, max=10000.0)
    tr.done()

    if video.start_s >= duration:
        raise ConfigError(f"{source}: [video] start_s must be < [scenario] duration_s")
    if math.floor((duration - video.start_s) * video.fps + 1e-9) < 1:    # was a drive of no frames, exit 0
        raise ConfigError(f"{source}: [video] fps = {video.fps:g} gives no frame in the {duration - video.start_s:g} s "
                          f"from [video] start_s to [scenario] duration_s: a drive needs frames (fps at least "
                          f"{1.0 / (duration - video.start_s):.3g})")
    if imu.start_s >= duration:
        raise ConfigError(f"{source}: [imu] start_s must be < [scenario] duration_s")
    return Scenario(name=name, duration_s=duration, seed=seed, camera=camera, mount=mount,
                    markings=markings, segments=segments, motion=motion, imu=imu, video=video,
                    can=can, look=look, supersample=supersample, truth_rate_hz=truth_rate,
                    description=description, start=start, source=Path(source))


def _check_frame_size(camera: Camera, codec: str, source: str) -> None:
    """:data:`FRAME_PX`, and even sizes for the video codecs: mp4v, ffv1 and mjpg write an odd
    width or height one pixel smaller (a review: 321x181 wrote 320x180 frames, and the config's
    321x181 then failed ``vifusion vision``); PNG frames keep any size."""
    size = f"[camera] width x height = {camera.width}x{camera.height}"
    lo, hi = FRAME_PX
    if not (lo <= camera.width <= hi and lo <= camera.height <= hi):
        raise ConfigError(f"{source}: {size}: the simulator renders {lo} to {hi} px a side (the estimator finds "
                          f"nothing on smaller frames; a larger one takes over 2.5 GB to render)")
    if codec != "png" and (camera.width % 2 or camera.height % 2):
        even = f"{camera.width - camera.width % 2}x{camera.height - camera.height % 2}"
        raise ConfigError(f"{source}: {size}: the {codec} codec writes even sizes only (it would write {even} "
                          f"frames, which the config would not describe): give an even width and height, or "
                          f'[video] codec = "png"')


def load_scenario(path: str | Path) -> Scenario:
    path = Path(path)
    return parse_scenario(read_toml(path), str(path))
