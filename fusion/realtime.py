"""Embedding in a vehicle: raw CAN messages and camera frames in, the latest estimate out.

:class:`LiveFusion` joins the three streaming parts: :class:`imu.StreamDecoder` (CAN frames
to IMU samples, the same decode as the log path), :class:`vision.estimator.Estimator` (one
frame to roll, pitch, yaw relative to the road) and :class:`fusion.engine.FusionStream` (the
EKF). Frames may be handed in late, after the CAN samples of their capture time, as a vision
thread that takes longer than an IMU interval would: the filter rolls back and re-propagates.
The methods may be called from different threads (a bus thread, a camera thread): the filter
is behind a lock, and the vision estimator runs outside it. A bus clock that restarts (the
decoder's :data:`imu.can_source.CLOCK_RESET_AFTER`) restarts the filter, keeping the IMU
biases; so does a gap in the IMU samples (:attr:`fusion.options.FusionOptions.max_imu_gap_s`).

Example (a live bus; the README's "Embedding" has a whole program with a camera thread)::

    live = LiveFusion("config.toml")      # or a DriveConfig (fusion.config.load_config)
    live.warm_up()                        # the compiled kernels loaded before the drive
    for msg in bus:                       # python-can messages
        live.push_can(msg)
        ...
        live.push_frame(t_s, grey)        # whenever a frame has been captured (bus clock)
        est = live.estimate()             # Estimate with 1-sigma, rad
    write_calibration(live.calibration(), "calibration.toml", mount=live.mount)   # when the vehicle stops

Frames: the estimator works on grey. The offline run hands it a video's decoded luma plane
(:meth:`vision.video.FrameSource.grey_frames`); a BGR picture (OpenCV's ``VideoCapture``) is
converted with ``cv2.COLOR_BGR2GRAY``, a grey a few levels off the luma after a codec's colour
round trip: the same drive then gives somewhat different vision results (another draw; on the
640x360 sample drive, whose vision is overconfident in its curve, the fused bank varies between
0.2 and 0.46 deg RMS with such changes, README "Commands").
"""

from __future__ import annotations

import math
import operator
import os
import threading
from collections import deque

import can
import numpy as np

from imu import StreamDecoder
from vision.estimator import Estimator, VisionEstimate
from vision.options import options_from_table
from vision.twistmap import travel_between

from .calibration import calibration_from_state, pitch_gyro_prior_deg_s
from .config import DriveConfig, load_config
from .drive import last_speed
from .engine import Estimate, FusionStream
from .errors import ConfigError
from .options import fusion_options_from_table
from .pipeline import GLITCH_COUNTS, glitch_warnings, implausible_vision_warning, vision_refused_warning

__all__ = ["LiveFusion"]

#: Frames in a row refused for their stamps after which ``LiveFusion.warnings`` says the camera's
#: clock may be off (a second at 30 fps; one repeated frame or one bad stamp is not): stamped at
#: or before the last one taken (stepped back), too far ahead of the bus, or too old for the
#: filter's history.
CLOCK_BACK_WARN_FRAMES = 30
#: A frame stamped this far ahead of the newest IMU sample (or before the first one) and of the
#: frame before it (s) is taken provisionally, and so are the frames after it that stay this far
#: ahead of the bus (a glitch of several frames): should a frame then come stamped before them,
#: and after the frame before the first of them, their stamps were a glitch and they are taken
#: back (:meth:`LiveFusion.push_frame`). A frame is normally stamped at or behind the bus
#: (handed in after its capture) or a bus latency ahead, and a frame period after the one before
#: it.
GLITCH_LEAD_S = 0.1
#: Frames taken provisionally in a row at most (a third of a second at 30 fps): a longer run is
#: the camera's clock that jumped ahead, and its frames are kept for good (a frame stamped
#: between two of them, reordered, would otherwise take back the ones after it).
MAX_GLITCH_FRAMES = 10
#: The span of the bus clock (s) over which the share of the results the filter's gate refused
#: is judged live, once it has passed since the start or a clock restart
#: (:data:`fusion.pipeline.VISION_REFUSED_WARN`; offline: the whole drive).
VISION_REFUSED_SPAN_S = 10.0
#: Lines in ``warnings`` up to which a gap in the IMU samples adds its own (a bus that drops out
#: every second would otherwise grow the list for good; the count goes on), and each kind of
#: frames refused in a row for their stamps (:meth:`LiveFusion._count_in_row`).
_MAX_GAP_LINES = 20


def _refused(reason: str) -> VisionEstimate:
    """The result of a frame not given to the estimator."""
    nan = math.nan
    return VisionEstimate(nan, nan, nan, nan, nan, nan, False, reason=reason)


def _stamp(t_s, method: str) -> float:
    """A capture time as a float; a caller's non-number is a TypeError that says so (NaN is a
    number: refused and counted as a bad stamp). So is a numpy float narrower than float64: a
    float32 keeps 24 bits, steps of 128 s at a bus clock of 1.7e9 s (Unix time), and its frames
    were refused as "the camera's clock stepped back" (a review). Refused at any value, so that
    a drive does not start to fail once its clock has grown (a 0-d array of one too, which got
    past the first form of the check). A string or a bool is no time either (float("17.0") and
    True had been taken)."""
    dtype = getattr(t_s, "dtype", None)
    if dtype is not None and dtype.kind == "f" and np.finfo(dtype).nmant < np.finfo(np.float64).nmant:
        value = np.asarray(t_s)
        raise TypeError(f"{method} takes the capture time as a float64 (or Python float), got a {dtype}: "
                        f"{np.finfo(dtype).nmant + 1} bits, steps of {float(np.spacing(np.abs(value))):.3g} s at "
                        f"{value}")
    if isinstance(t_s, (str, bytes, bool, np.bool_)):
        raise TypeError(f"{method} takes the capture time in seconds on the bus clock, got {t_s!r}")
    try:
        return float(t_s)
    except (TypeError, ValueError):
        raise TypeError(f"{method} takes the capture time in seconds on the bus clock, got {t_s!r}") from None
    except OverflowError:     # a number beyond a float (10**400; its repr can be too long to print)
        raise ValueError(f"{method} takes the capture time in seconds on the bus clock, got "
                         f"{type(t_s).__name__} beyond a float's range") from None


class LiveFusion:
    """CAN messages and frames in, :class:`fusion.engine.Estimate` out; see the module docstring."""

    def __init__(self, config: DriveConfig | str | os.PathLike) -> None:
        if not isinstance(config, DriveConfig):
            config = load_config(config)       # a config file's path
        if config.can is None:
            raise ConfigError("LiveFusion needs the [can] table of the config")
        source = str(config.path or "config")
        fusion_opts, self.settings = fusion_options_from_table(config.extra.get("fusion"), source)
        self.decoder = StreamDecoder(config.can, config.imu)
        #: The IMU's mount (``[imu]``): what a calibration of its vehicle-frame biases belongs to.
        self.mount = config.imu
        self.has_pitch_rate = "gyro_y_rad_s" not in self.decoder.unavailable
        self.vision = Estimator(config.camera, config.mount, config.road,
                                options_from_table(config.extra.get("vision"), source))
        self.stream = FusionStream(config.imu.position_m, self.has_pitch_rate, fusion_opts)
        self.samples = 0
        #: Frames not after the previous frame (skipped), frames taken back as stamp glitches
        #: (:data:`GLITCH_LEAD_S`), restarts of the filter on a bus clock that went back. (IMU samples the decoder released without every gyro and
        #: accelerometer value are the stream's ``counts["imu_invalid"]``.)
        self.counts = dict(frames_out_of_order=0, frames_bad_time=0, frames_stamp_glitch=0, clock_restarts=0)
        self.warnings: list[str] = []
        self._glitches_said: set[str] = set()    # the kinds of glitch_warnings said
        self._decoder_said = 0                 # the decoder's warnings copied into ours
        if self.settings.estimate_time_offset:
            self.warnings.append("[fusion] estimate_time_offset needs the whole drive and is not done live: "
                                 f"camera_time_offset_s = {self.settings.camera_time_offset_s:g} s is used")
        if self.settings.smooth:
            self.warnings.append("[fusion] smooth needs the whole drive and is not done live: "
                                 "the estimates are the forward filter's")
        self._lock = threading.RLock()
        self._speeds: deque = deque(maxlen=256)    # recent fresh wheel speeds: (t_s, m/s)
        self._last_frame = (math.nan, math.nan)    # the last frame: (t_s, speed then)
        self._last_estimate: VisionEstimate | None = None
        # the last frames, taken provisionally (GLITCH_LEAD_S), oldest first: for each, its capture
        # time, and the last frame, last estimate and estimator state before it
        self._provisional: list[tuple] = []
        # (bus time, results used, refused) at each result handed to the filter, over the last
        # VISION_REFUSED_SPAN_S of the bus; whether the share refused was said
        self._gate_log: deque = deque()
        self._gate_said = False
        # frames in a row refused for their stamps: not after the last one taken, too far ahead
        # of the bus, their results too old for the filter (CLOCK_BACK_WARN_FRAMES)
        self._in_row = dict(behind=0, ahead=0, old=0)
        self._in_row_said = dict(behind=0, ahead=0, old=0)   # lines said per kind (_MAX_GAP_LINES)
        # the bus's newest sample when the frames ahead of it in a row began, and the newest
        # result taken (not refused as ahead): whether the bus or the camera is off (_count_ahead)
        self._ahead_from_t = math.nan
        self._taken_t = -math.inf

    def warm_up(self, seconds: float = 1.0) -> float:
        """Load the compiled kernels before the drive: the bundled sample drive's first
        ``seconds`` through a throwaway ``LiveFusion`` of its own config (CAN messages, frames,
        estimates), so that the first calls of a drive do not wait for them (a review: the first
        ``push_frame`` took 256 ms, the first ``push_can`` 93 ms, and ``estimate()`` from another
        thread waited up to 58 ms behind them, over a 30 fps frame period). This object's state
        is untouched. Returns the seconds it took (about half a second here)."""
        import time

        from vision.video import FrameSource

        from .drive import SAMPLE_DRIVE, find_drive_files, read_frame_times

        t0 = time.perf_counter()
        files = find_drive_files(SAMPLE_DRIVE)
        config = load_config(files.config)
        scratch = LiveFusion(config)
        frames = read_frame_times(files.frames, config.video)
        with can.LogReader(files.can_log) as reader:
            messages = iter(reader)
            pending = next(messages, None)
            start = None
            for t_frame, image in zip(frames["t_s"], FrameSource(files.video).grey_frames()):
                while pending is not None and pending.timestamp <= t_frame:
                    scratch.push_can(pending)
                    start = pending.timestamp if start is None else start
                    pending = next(messages, None)
                scratch.push_frame(t_frame, image)
                scratch.estimate()
                if start is not None and t_frame - start > seconds:
                    break
        return time.perf_counter() - t0

    def push_can(self, msg, received_s: float | None = None) -> int:
        """One CAN message (python-can ``Message``); returns how many IMU samples it released
        that the filter used (a sample missing a gyro or accelerometer value is skipped and
        counted in ``stream.counts["imu_invalid"]``)."""
        if not isinstance(msg, can.Message):
            # (an object with only an ID and data had failed inside the decoder: a review)
            raise TypeError(f"push_can takes a python-can Message, got {type(msg).__name__}")
        try:        # any integer, a numpy.int64 from a table of IDs too (refused, a review); a bool is no ID
            operator.index(msg.arbitration_id)
            integral = not isinstance(msg.arbitration_id, bool)
        except TypeError:
            integral = False
        if not integral or isinstance(msg.timestamp, bool) or not isinstance(msg.timestamp, (int, float)):
            raise TypeError(f"push_can takes a python-can Message with an integer arbitration_id and a number "
                            f"as timestamp, got {msg.arbitration_id!r} and {msg.timestamp!r}")
        n = 0
        with self._lock:
            for s in self.decoder.push(msg, received_s):
                gyro = (s.gyro_x_rad_s, 0.0 if not self.has_pitch_rate else s.gyro_y_rad_s, s.gyro_z_rad_s)
                accel = (s.accel_x_m_s2, s.accel_y_m_s2, s.accel_z_m_s2)
                if not s.t_s > self.stream.t_s and math.isfinite(self.stream.t_s):
                    # the decoder took a new bus clock: nothing carries across but the biases
                    self.stream.restart(clock_reset=True)
                    self._speeds.clear()
                    self._last_frame = (math.nan, math.nan)
                    self._gate_log.clear()             # its times are of the clock before
                    self._taken_t = -math.inf
                    self.counts["clock_restarts"] += 1
                # an incomplete sample (a value missing) is skipped and counted by the stream;
                # its wheel speed still dates the frames
                gaps, before = self.stream.counts["imu_gaps"], self.stream.t_s
                n += self.stream.add_imu(s.t_s, gyro, accel, s.speed_m_s, s.fresh_speed)
                if gaps < self.stream.counts["imu_gaps"] <= _MAX_GAP_LINES:
                    # said as the offline run says it (only counted here before, a review)
                    self.warnings.append(f"the IMU samples stopped for {s.t_s - before:.2f} s at {before:.3f} s: the "
                                         "filter started again, keeping the IMU biases (stream.counts['imu_gaps'])")
                if math.isfinite(self._last_frame[0]) and self.stream.too_far_ahead(self._last_frame[0]):
                    # a frame stamped far ahead before the bus had a time: not the last frame
                    self._last_frame = (math.nan, math.nan)
                if s.fresh_speed and math.isfinite(s.speed_m_s):
                    self._speeds.append((s.t_s, s.speed_m_s))
            self.samples += n
            self._say_glitches()
            if len(self.decoder.warnings) > self._decoder_said:   # the bus's own (frames out of order)
                self.warnings += self.decoder.warnings[self._decoder_said:]
                self._decoder_said = len(self.decoder.warnings)
        return n

    def push_frame(self, t_s: float, image) -> VisionEstimate:
        """A camera frame captured at ``t_s`` (bus clock, before the configured camera offset).
        The estimator is told the distance travelled since the last frame from the wheel speed
        (for the road's twist, :attr:`vision.options.EstimatorOptions.road_twist`), by the rule
        of the offline run (:func:`fusion.drive.last_speed`) over the samples the bus has
        released and those still open in the decoder's align window
        (:meth:`imu.StreamDecoder.pending_speeds`). A frame handed in before the CAN frames of
        its capture time have arrived sees the speed before, a few millimetres of travel off the
        offline run's, which the road-twist map can turn into visibly different angles on some
        frames (README, "Embedding").

        A frame not after the previous one (a repeated or reordered frame) is skipped and counted
        (``counts``): the estimator's road map moves forward only; the previous result is
        returned. A frame whose stamp is not finite, or too far ahead of the bus
        (``stream.counts["vision_future"]``: a bad stamp, a camera clock that stepped), is
        refused before the estimator, and does not hold back the frames after it: an invalid
        estimate whose ``reason`` says why is returned. A frame stamped ahead of the bus and of the frame
        before it by more than :data:`GLITCH_LEAD_S` is taken provisionally, with the frames after it that stay
        that far ahead (up to :data:`MAX_GLITCH_FRAMES`): the next frame stamped before them (and after the
        frame before them) takes them back as a stamp glitch (:meth:`_take_back_glitch`).
        Thirty frames in a row refused for their stamps, or with results too old for
        the filter's history, put a line in ``warnings``. From one thread at a time (the
        estimator keeps the road map between frames)."""
        t_cap = _stamp(t_s, "push_frame") + self.settings.camera_time_offset_s
        if not isinstance(image, np.ndarray):
            raise TypeError(f"push_frame takes the frame as a numpy image (grey or BGR), got {type(image).__name__}")
        with self._lock:
            t0, v0 = self._last_frame
            if not math.isfinite(t_cap):
                self.counts["frames_bad_time"] += 1
                return _refused(f"frame stamp {t_s} is not a time")
            if not t_cap > t0 and math.isfinite(t0) and self._take_back_glitch(t_cap):
                t0, v0 = self._last_frame
            if not t_cap > t0 and math.isfinite(t0):
                self.counts["frames_out_of_order"] += 1
                self._count_in_row("behind", f"stamped at or before the last one taken ({t0:.3f} s; this one "
                                   f"{t_cap:.3f} s): has the camera's clock stepped back? Frames are refused until "
                                   "their stamps pass it (counts['frames_out_of_order'])")
                return self._last_estimate or _refused(f"frame at {t_cap:.3f} s not after the last one taken")
            self._in_row["behind"] = 0
            if self.stream.too_far_ahead(t_cap):
                # a bad stamp, a camera clock that stepped: refused before the estimator, whose
                # road map would move by the stamp's travel, and not the last frame's time
                self.stream.counts["vision_future"] += 1
                self._count_ahead(t_cap)
                return _refused(f"frame at {t_cap:.3f} s too far ahead of the CAN bus ({self.stream.t_s:.3f} s)")
            self._in_row["ahead"] = 0
            # the released samples' speeds and those the samples of the capture time will carry
            # once the align window has passed (the offline run's rule; without the latter a
            # frame handed in at its capture time took the speed before, a few mm of travel off,
            # which the road-twist map turned into other angles on 550 of 600 frames, a review)
            speeds = [*self._speeds, *self.decoder.pending_speeds(t_cap)]
            v = float(last_speed(*np.array(speeds).T, t_cap)[0]) if speeds else math.nan
            # ahead of the bus (or no bus time yet), and a jump from the frame before or after a
            # provisional one (a bus that lags the camera had made every frame provisional, and a
            # reordered frame then took back the good one before it, a review)
            if (not t_cap <= self.stream.t_s + GLITCH_LEAD_S and (not t_cap - t0 <= GLITCH_LEAD_S or self._provisional)
                    and len(self._provisional) < MAX_GLITCH_FRAMES):
                self._provisional.append((t_cap, self._last_frame, self._last_estimate, self.vision.snapshot()))
            else:
                self._provisional.clear()
            self._last_frame = (t_cap, v)
        est = self.vision.estimate(image, travel_m=travel_between(v0, v, t_cap - t0))
        self._last_estimate = est
        self.push_vision(t_s, est)
        return est

    def _take_back_glitch(self, t_cap: float) -> bool:
        """Whether the last frames taken were a stamp glitch, and then take them back: they were
        taken provisionally (ahead of the bus), this frame comes stamped before the first of them
        and after the frame before it, and that first one's result still waits for the IMU (or
        was invalid). The filter, the estimator's state and the last frame are then as if they
        had not come (counted in ``counts["frames_stamp_glitch"]``). Before, one frame stamped
        0.4 s ahead held back the twelve after it as out of order, and its travel moved the
        road-twist map 0.4 s ahead (a review); two in a row, or one before the first IMU sample,
        still did (the twentieth session's list)."""
        chain = self._provisional
        k = next((i for i, (t_glitch, before, _, _) in enumerate(chain)
                  if t_cap < t_glitch and (t_cap > before[0] or math.isnan(before[0]))), None)
        if k is None:
            return False      # (a frame stamped as a provisional one is a repeat of it)
        # each provisional frame's own result: the next one's "last estimate before", the newest's the last
        own = [entry[2] for entry in chain[k + 1:]] + [self._last_estimate]
        first = True
        for (t_glitch, *_), glitch in zip(chain[k:], own):
            if glitch is None or not glitch.valid:
                continue         # never reached the filter (its count in vision_invalid stays)
            # results are applied in time order: when the first still waits, so do the rest
            if not self.stream.withdraw_vision(t_glitch) and first:
                return False     # applied already (or not queued): they stand
            first = False
        _, before, estimate, state = chain[k]
        self.vision.restore(state)
        self._last_frame, self._last_estimate = before, estimate
        self.counts["frames_stamp_glitch"] += len(chain) - k
        del chain[k:]
        return True

    def push_vision(self, t_s: float, est: VisionEstimate) -> None:
        """A vision result computed elsewhere (another thread or process), captured at ``t_s``
        (bus clock, before the configured camera offset). Thirty results in a row dropped for
        their stamps (too far ahead of the bus, or older than the filter's history) put a line
        in ``warnings``."""
        if not isinstance(est, VisionEstimate):
            raise TypeError(f"push_vision takes a vision.VisionEstimate, got {type(est).__name__}")
        t_s = _stamp(t_s, "push_vision")
        with self._lock:
            t_cap = t_s + self.settings.camera_time_offset_s
            # before the first IMU sample the stream drops the oldest queued results itself:
            # not this result's age (a camera that starts first is no clock fault)
            old = self.stream.counts["vision_too_old"] if math.isfinite(self.stream.t_s) else math.inf
            future = self.stream.counts["vision_future"]
            implausible = self.stream.counts["vision_implausible"]
            self.stream.add_vision(t_cap, est.rpy_rad,
                                   (est.roll_sigma_rad, est.pitch_sigma_rad, est.yaw_sigma_rad), est.valid,
                                   est.curvature_1_m, est.lateral_offset_m,
                                   est.curvature_sigma_1_m, est.roll_lookahead_m,
                                   (est.pitch_per_twist_m, est.yaw_per_twist_m),
                                   (est.road_twist_rad_m, est.road_twist_sigma_rad_m), est.twist_response,
                                   (est.vertical_curvature_1_m, est.pitch_per_vertical_curvature_m),
                                   est.yaw_per_curvature_m)
            if self.stream.counts["vision_implausible"] > implausible and not implausible:
                # said once, when the first comes (counted in stream.counts['vision_implausible'])
                self.warnings.append(implausible_vision_warning(1) + ": stream.counts['vision_implausible'] counts them")
            if self.stream.counts["vision_future"] == future and t_cap > self._taken_t:
                self._taken_t = t_cap          # the newest result not refused as ahead (_count_ahead)
            if self.stream.counts["vision_future"] > future:
                # results of another thread or process stamped ahead of the bus were dropped
                # without a word (push_frame said it for its own frames, a review)
                self._count_ahead(t_cap)
            elif self.stream.counts["vision_too_old"] > old:
                self._count_in_row("old", f"with results older than the filter's history (this one "
                                   f"{t_cap:.3f} s, the bus at {self.stream.t_s:.3f} s): is the camera's clock "
                                   "behind, or camera_time_offset_s wrong? (stream.counts['vision_too_old'])")
            elif est.valid:
                self._in_row["old"] = self._in_row["ahead"] = 0
            if not self._gate_said:
                self._judge_gate()
            self._say_glitches()

    def _say_glitches(self) -> None:
        """Say each kind of :func:`fusion.pipeline.glitch_warnings` once, when its first comes
        (a re-acquired gravity reference, samples that could not level the filter, a wheel speed
        refused as a sensor's fault, implausible road twists: counted in ``stream.counts``, said
        only offline before, a review)."""
        c = self.stream.counts
        for key in GLITCH_COUNTS:
            if c[key] and key not in self._glitches_said:
                self._glitches_said.add(key)
                line = glitch_warnings({key: c[key]}, self.stream.options.gravity_reacquire_after_s)[0]
                self.warnings.append(f"{line} (stream.counts['{key}'] counts them)")

    def _judge_gate(self) -> None:
        """Say once when the filter's gate refused more than its share of the results of the last
        :data:`VISION_REFUSED_SPAN_S` of the bus (a camera clock 0.2 s or more off the bus: the
        bank ended 1.05 deg off on the sample drive with no word, a review). Timed by the bus,
        not the results' stamps (a NaN or far-future stamp handed to ``push_vision`` had stopped
        the log's trimming for good, a review), and judged once a whole span has passed since
        the start or a clock restart (the filter's restart refused 9 of its first 60 results, a
        review: 15 % on a right clock)."""
        now = self.stream.t_s
        if not math.isfinite(now):
            return
        c = self.stream.counts
        log = self._gate_log
        log.append((now, c["vision_used"], c["vision_rejected"]))
        while len(log) > 1 and log[1][0] <= now - VISION_REFUSED_SPAN_S:
            log.popleft()
        t_base, used, refused = log[0]
        if now - t_base < VISION_REFUSED_SPAN_S:
            return
        refused = c["vision_rejected"] - refused
        line = vision_refused_warning(refused, refused + c["vision_used"] - used, f" in {VISION_REFUSED_SPAN_S:g} s")
        if line:
            self.warnings.append(line)
            self._gate_said = True

    def _count_ahead(self, t_cap: float) -> None:
        """One more frame in a row refused as too far ahead of the bus, said after
        :data:`CLOCK_BACK_WARN_FRAMES` as what the stamps show: the bus fell silent when it gave
        no IMU sample while these frames came, and the results taken before them went on past
        its newest sample by more than ``max_imu_gap_s`` (the filter's own IMU gap); else the
        camera's clock is ahead of a bus that goes on. (A bus gone silent for 3 s was said as
        "is the camera's clock ahead?", a review.) Judged by the stamps, not by the time the
        calls come, so that a replay faster than real time is judged as its live drive."""
        bus_t = self.stream.t_s
        if not self._in_row["ahead"]:
            self._ahead_from_t = bus_t
        if bus_t == self._ahead_from_t and self._taken_t - bus_t > self.stream.options.max_imu_gap_s:
            what = (f"stamped too far ahead of the CAN bus, which has given no IMU sample since {bus_t:.3f} s while "
                    f"the frames went on (this one {t_cap:.3f} s): has the CAN bus or the IMU gone silent? "
                    "(stream.counts['vision_future']; decoder.summary() counts its frames)")
        else:
            what = (f"stamped too far ahead of the CAN bus (this one {t_cap:.3f} s, the bus at {bus_t:.3f} s): is the "
                    "camera's clock ahead, or camera_time_offset_s wrong? (stream.counts['vision_future'])")
        self._count_in_row("ahead", what)

    def _count_in_row(self, kind: str, what: str) -> None:
        """One more frame in a row refused for its stamp; the warning once at the limit, up to
        :data:`_MAX_GAP_LINES` lines of each kind (a camera whose stamps flap between right and
        ahead added one every 0.3 s for good, a review; the counts go on)."""
        self._in_row[kind] += 1
        if self._in_row[kind] == CLOCK_BACK_WARN_FRAMES and self._in_row_said[kind] < _MAX_GAP_LINES:
            self._in_row_said[kind] += 1
            self.warnings.append(f"{CLOCK_BACK_WARN_FRAMES} frames in a row {what}")

    def estimate(self) -> Estimate:
        """The latest estimate (after the newest IMU sample), with 1-sigma; before the first IMU
        sample, NaN (:meth:`fusion.engine.FusionStream.estimate`)."""
        with self._lock:
            return self.stream.estimate()

    def calibration(self) -> dict[str, list[float]]:
        """The IMU biases now, with 1-sigma, as the ``[fusion]`` keys of a calibration: save them
        when the vehicle stops (``fusion.calibration.write_calibration(..., mount=live.mount)``)
        and start the next drive from them (``[fusion]`` of the config, or ``vifusion run
        --calibration``)."""
        with self._lock:
            ekf = self.stream.ekf
            return calibration_from_state(ekf.x, ekf.P,
                                          None if self.has_pitch_rate else pitch_gyro_prior_deg_s(ekf.noise))
