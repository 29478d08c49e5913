"""Config files (TOML, INTERFACE.md): read, checked key by key, turned into frozen dataclasses.

Every error names the file, the table and the key, and says what was expected, e.g.
``config.toml: [camera] fx must be a number, got 'abc'``.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from imu.config import CanMapping, ImuMount
from imu.errors import ImuError
from vision.camera import Camera, Mount, RoadMarkings
from vision.errors import VisionError

from .errors import ConfigError

__all__ = ["DriveConfig", "VideoTiming", "Table", "load_config", "read_toml", "parse_config", "parse_tables"]


@dataclass(frozen=True)
class VideoTiming:
    """Frame times when there is no ``frames.csv``: ``t = start_s + frame / fps``."""

    fps: float = 30.0
    start_s: float = 0.0


@dataclass(frozen=True)
class DriveConfig:
    """Everything a config file describes."""

    camera: Camera
    mount: Mount
    road: RoadMarkings
    imu: ImuMount
    can: CanMapping | None
    video: VideoTiming
    #: Free-form tables that other modules read with their own checks (``[vision]``, ``[fusion]``).
    extra: dict[str, dict] = field(default_factory=dict)
    path: Path | None = None


def read_toml(path: str | Path) -> dict:
    """Parse a TOML file; a missing file or bad syntax is a one-line :class:`ConfigError`."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = f.read()
        # a byte-order mark (some Windows editors write one) is not TOML, but means no harm
        return tomllib.loads(data.removeprefix(b"\xef\xbb\xbf").decode("utf-8"))
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: not UTF-8 text, as TOML must be ({e.reason} at byte {e.start})") from None
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, expected a TOML file") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from None


class Table:
    """Typed access to one TOML table that remembers which keys were read.

    ``get`` checks the type and range and raises :class:`ConfigError` naming the key;
    ``done`` rejects keys nobody read (typos such as ``heigth_m``).
    """

    def __init__(self, data: dict, name: str, source: str) -> None:
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: [{name}] must be a table, got {type(data).__name__}")
        self.data, self.name, self.source = data, name, source
        self._read: set[str] = set()
        self._known: set[str] = set()

    def where(self, key: str) -> str:
        return f"{self.source}: [{self.name}] {key}"

    def error(self, key: str, msg: str) -> ConfigError:
        return ConfigError(f"{self.where(key)} {msg}")

    def has(self, key: str) -> bool:
        """Whether ``key`` is given; an optional key asked about is a key of the table (named
        among the known ones when :meth:`done` rejects a typo)."""
        self._known.add(key)
        return key in self.data

    def get(self, key: str, kind: str, default: Any = ..., *, min: float | None = None,
            max: float | None = None, choices: tuple | None = None, length: int | None = None) -> Any:
        """Read ``key`` as ``kind`` in {"float", "int", "bool", "str", "floats", "strs", "table"}."""
        self._read.add(key)
        if key not in self.data:
            if default is ...:
                raise self.error(key, f"is missing (expected {_KIND_TEXT[kind]})")
            return default
        value = _convert(self.data[key], kind)
        if value is None:
            raise self.error(key, f"must be {_KIND_TEXT[kind]}, got {self.data[key]!r}")
        if length is not None and len(value) != length:
            raise self.error(key, f"needs {length} entries, got {len(value)}")
        for v in value if kind == "floats" else [value] if kind in ("float", "int") else []:
            if min is not None and v < min or max is not None and v > max:
                rng = f">= {min}" if max is None else f"<= {max}" if min is None else f"within [{min}, {max}]"
                raise self.error(key, f"must be {rng}, got {v!r}")
        if choices is not None and value not in choices:
            raise self.error(key, f"must be one of {', '.join(map(repr, choices))}, got {value!r}")
        return value

    def sub(self, key: str, required: bool = False) -> "Table":
        """A nested table (``[can.signals]``)."""
        self._read.add(key)
        if key not in self.data and not required:
            return Table({}, f"{self.name}.{key}", self.source)
        if key not in self.data:
            raise self.error(key, "is missing (expected a table)")
        return Table(self.data[key], f"{self.name}.{key}", self.source)

    def known(self, *keys: str) -> None:
        """Keys this table may hold that may go unread and unasked (another key given instead):
        named among the known ones when :meth:`done` rejects a typo."""
        self._known.update(keys)

    def done(self) -> None:
        unknown = sorted(set(self.data) - self._read)
        if unknown and unknown[0] in self._known:    # a key of the table, but not with the others
            raise self.error(unknown[0], f"is not used together with the keys given "
                                         f"({', '.join(sorted(k for k in self._read if k in self.data))}): one or the other")
        if unknown:
            raise self._not_known(unknown[0], sorted(self._read | self._known))

    def reject_unknown(self, keys) -> None:
        """Raise for a key the table holds that is not one of ``keys``, before any other check
        can say something less to the point (a required key missing, where the unknown one was
        its typo)."""
        stray = sorted(set(self.data) - set(keys))
        if stray:
            raise self._not_known(stray[0], sorted(keys))

    def _not_known(self, key: str, known: list):
        return self.error(key, f"is not a known key ({did_you_mean(key, known)}known: {', '.join(known) or 'none'})")


def did_you_mean(name: str, known) -> str:
    """``"did you mean X? "`` for the one of ``known`` closest to a name not known, or ``""``."""
    close = difflib.get_close_matches(name, list(known), n=1)
    return f"did you mean {close[0]}? " if close else ""


_KIND_TEXT = {
    "float": "a number", "int": "an integer", "bool": "true or false", "str": "a string",
    "floats": "a list of numbers", "strs": "a list of strings", "table": "a table",
}


def _convert(v: Any, kind: str) -> Any:
    if kind == "float":
        return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else None
    if kind == "int":
        return v if isinstance(v, int) and not isinstance(v, bool) else None
    if kind == "bool":
        return v if isinstance(v, bool) else None
    if kind == "str":
        return v if isinstance(v, str) else None
    if kind == "floats":
        if isinstance(v, list) and all(_convert(x, "float") is not None for x in v):
            return tuple(float(x) for x in v)
        return None
    if kind == "strs":
        return tuple(v) if isinstance(v, list) and all(isinstance(x, str) for x in v) else None
    if kind == "table":
        return v if isinstance(v, dict) else None
    raise ValueError(kind)


def _build(source: str, what: str, make: Callable[[], Any]) -> Any:
    """Run a dataclass constructor, turning its own range checks into ConfigErrors."""
    try:
        return make()
    except (VisionError, ImuError) as e:
        text = str(e)
        raise ConfigError(f"{source}: {text}" if text.startswith(f"[{what}") else f"{source}: [{what}] {text}") from None


def parse_camera(t: Table) -> Camera:
    t.known("fx", "fy", "cx", "cy", "hfov_deg", "distortion")
    width = t.get("width", "int", min=1)
    height = t.get("height", "int", min=1)
    if t.has("hfov_deg") and not t.has("fx"):
        hfov = t.get("hfov_deg", "float", min=1.0, max=179.0)
        dist = t.get("distortion", "floats", (0.0,) * 5)
        t.done()
        return _build(t.source, "camera", lambda: Camera.from_fov(width, height, hfov, distortion=dist))
    if not t.has("fx"):   # a typo of hfov_deg (hfov_dg) is named as one, not as fx missing (a review)
        t.reject_unknown(("width", "height", "fx", "fy", "cx", "cy", "hfov_deg", "distortion"))
    fx = t.get("fx", "float", min=1e-9)
    fy = t.get("fy", "float", fx, min=1e-9)
    for key, f, size in (("fx", fx, width), ("fy", fy, height)):
        # (a focal length of 0.001 was taken, and every frame then failed without a word of why)
        if f < 0.5 * size / math.tan(math.radians(89.5)):
            raise ConfigError(f"{t.source}: [camera] {key} = {f:g} px makes a field of view of 179 deg or more "
                              f"across the {size} px: the focal length is in pixels")
    cx = t.get("cx", "float", (width - 1) / 2.0)
    cy = t.get("cy", "float", (height - 1) / 2.0)
    dist = t.get("distortion", "floats", (0.0,) * 5)
    t.done()
    return _build(t.source, "camera", lambda: Camera(width, height, fx, fy, cx, cy, dist))


def parse_mount(t: Table) -> Mount:
    h = t.get("height_m", "float", min=1e-3, max=20.0)   # a camera 1100 m up is one in millimetres
    tilt = t.get("tilt_deg", "float", min=-89.0, max=89.0)
    x = t.get("x_m", "float", 0.0)
    t.done()
    return _build(t.source, "mount", lambda: Mount(h, math.radians(tilt), x))


def parse_road(t: Table) -> RoadMarkings:
    lane = t.get("lane_width_m", "float", 3.5, min=0.5, max=10.0)
    marker = t.get("marker_width_m", "float", 0.15, min=0.01, max=1.0)
    center = t.get("center_line", "bool", True)
    widths = t.get("marker_widths_m", "floats", None, length=3)
    t.done()
    return _build(t.source, "road", lambda: RoadMarkings(lane, marker, center, widths))


def parse_imu(t: Table) -> ImuMount:
    axes = t.get("axes", "strs", ("x", "y", "z"), length=3)
    pos = t.get("position_m", "floats", (0.0, 0.0, 0.0), length=3)
    t.done()
    return _build(t.source, "imu", lambda: ImuMount(axes, pos))


def parse_can(t: Table, base_dir: Path) -> CanMapping | None:
    if not t.data:
        return None
    dbc = t.get("dbc", "str", None)     # or the command's --dbc (INTERFACE.md's command line gives it)
    gap = t.get("gap_limit_s", "float", 0.1, min=1e-6, max=10.0)
    window = t.get("align_window_s", "float", 0.002, min=1e-6)
    range_check = t.get("range_check", "bool", True)
    pad_short = t.get("pad_short_frames", "bool", False)
    reorder = t.get("reorder_tolerance_s", "float", 0.0, min=0.0, max=1.0)
    channel = t.get("channel", "str" if isinstance(t.data.get("channel"), str) else "int", None)
    signals_t = t.sub("signals", required=True)
    signals = {k: signals_t.get(k, "str") for k in list(signals_t.data)}
    units_t = t.sub("units")
    units = {k: units_t.get(k, "str") for k in list(units_t.data)}
    t.done()
    dbc_path = None if dbc is None else Path(dbc) if Path(dbc).is_absolute() else base_dir / dbc
    return _build(t.source, "can", lambda: CanMapping(
        dbc_path, signals, units, gap, align_window_s=window, range_check=range_check,
        pad_short_frames=pad_short, channel=channel, reorder_tolerance_s=reorder))


def parse_video(t: Table) -> VideoTiming:
    fps = t.get("fps", "float", 30.0, min=1e-3)
    start = t.get("start_s", "float", 0.0)
    t.done()
    return VideoTiming(fps, start)


#: Tables whose keys are checked by other modules (``vision.options``, ``fusion.options``).
FREE_TABLES = ("vision", "fusion")
#: Every table a config may hold.
TABLES = ("camera", "mount", "road", "imu", "can", "video", *FREE_TABLES)


def parse_tables(data: dict, source: str, base_dir: Path, required: tuple[str, ...] = ("camera", "mount")) -> dict:
    """Every table of a parsed config TOML checked key by key, whichever command reads it: a
    table or key vifusion does not know (a typo) is an error wherever the config is read (README:
    ``vifusion can`` and ``vifusion vision`` had taken ``[camera] fxx`` or ``[fusion]
    gyro_noise_degs`` without a word, a review). ``source`` names the file in errors; the tables
    in ``required`` must be there.

    Returns ``{table: built}``: ``road``, ``imu``, ``can``, ``video`` (their defaults when
    absent), ``camera`` and ``mount`` where given (they have no defaults), ``vision``
    (:class:`vision.options.EstimatorOptions`) and ``fusion`` (``(FusionOptions, RunSettings)``).
    """
    from vision.options import options_from_table

    from .options import fusion_options_from_table   # (it reads its table with this module's Table)

    for name in data:
        if name not in TABLES:
            raise ConfigError(f"{source}: [{name}] is not a known table "
                              f"({did_you_mean(name, TABLES)}known: {', '.join(sorted(TABLES))})")
        if not isinstance(data[name], dict):
            raise ConfigError(f"{source}: {name} must be a table ([{name}]), got {data[name]!r}")
    for name in required:
        if name not in data:
            raise ConfigError(f"{source}: [{name}] is missing")

    def table(name: str) -> Table:
        return Table(data.get(name, {}), name, source)

    built = {name: parse(table(name)) for name, parse in (("camera", parse_camera), ("mount", parse_mount))
             if name in data}
    return {**built, "road": parse_road(table("road")), "imu": parse_imu(table("imu")),
            "can": parse_can(table("can"), base_dir), "video": parse_video(table("video")),
            "vision": options_from_table(data.get("vision"), source),
            "fusion": fusion_options_from_table(data.get("fusion"), source)}


def parse_config(data: dict, source: str, base_dir: Path) -> DriveConfig:
    """Build a :class:`DriveConfig` from parsed TOML, every table checked (:func:`parse_tables`);
    ``source`` names the file in errors."""
    t = parse_tables(data, source, base_dir)
    return DriveConfig(camera=t["camera"], mount=t["mount"], road=t["road"], imu=t["imu"], can=t["can"],
                       video=t["video"], extra={k: dict(data[k]) for k in FREE_TABLES if k in data}, path=None)


def load_config(path: str | Path) -> DriveConfig:
    """Read and check a config TOML; relative paths in it are relative to the file."""
    path = Path(path)
    cfg = parse_config(read_toml(path), str(path), path.parent)
    object.__setattr__(cfg, "path", path)
    return cfg
