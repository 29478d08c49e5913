"""The vehicle's attitude relative to the road from one camera frame (Alrazouk et al. 2024).

Pipeline (each step in its own module):

1. IPM (:mod:`vision.ipm`): bird's-eye view at an assumed pose (the seed's, or the fixed mount);
2. lane markers (:mod:`vision.lanes`): both edges of the left, centre and right lines;
3. roll (:mod:`vision.roll`): eq. (8) with two markers, eq. (10) with three lines;
4. pitch and yaw (:mod:`vision.vanishing`): the vanishing point of the lane lines, eqs. (17), (20);
5. the camera's attitude ``R_o_from_cs = Rx(phi1) Ry(theta1) Rz(psi1)``, the vehicle's
   ``R_o_from_v = R_o_from_cs R_v_from_cs^T`` (eq. (22)) and its ZYX angles (section VII).

What the round trip decided (tests/test_vision_geometry.py on exact edges, test_vision_estimator.py
on rendered frames):

* The BEV built with pitch and yaw equal to the vanishing point's differs from the truth by
  ``Q = R_assumed R_o_from_cs^T = Rx(phi0 - phi1)``, a rotation about the lane direction, so the
  widths give the XYZ roll ``phi1`` directly. The BEV of the fixed mount (roll 0, pitch = tilt)
  differs by ``Ry(mu) (Rx(phi1) Ry(theta1) Rz(psi1))^T``, which for ``theta1 = mu, psi1 = 0`` is
  again ``Rx(-phi1)``. The paper reads it as the ZYX roll and converts it with eq. (21); that
  conversion is a slip (0.63 deg at 20 deg lean with mu = 15 deg), kept as ``eq21=True`` in the
  paper preset to measure it.
* Eq. (8)'s root is the BEV's residual roll ``phi_bev - phi1`` (:mod:`vision.roll`).
* The camera rolls with the vehicle about the contact point, so its height above the road is
  ``(R_o_from_v p_cam)_z`` (``h cos(roll) cos(pitch)`` for a camera above the contact point) and
  it moves sideways by ``-h sin(roll)``; eqs. (8), (10) use angles only, but the lateral offset,
  the curvature and the ground coordinates of the refinement use this height.

Beyond the paper (each a switch in :class:`vision.options.EstimatorOptions`, measured side by
side by ``tools/bench_vision.py``):

* the BEV at the previous frame's pose (seed), narrowed to its lines; without a usable seed a
  wide, coarse BEV tried at several leans finds the lines first (no memory needed for
  correctness: the seed only starts the search);
* blur-proof marker edges: centroid and area of each marker's profile (:mod:`vision.lanes`);
* refinement: the detected edge points are re-projected with the new roll, pitch and yaw and
  the lanes fitted again (:mod:`vision.lanemodel`: all edges share the road's shape, weighted by
  their measured noise, concentric on curves), so the single pass's small-angle approximations
  (a BEV row that is not a cross-section, converging lines) vanish; the image is warped again
  when the pose moved by more than ``rewarp_deg``;
* the lane direction at the vehicle (tangents of the fitted lanes of the two outer lines) instead
  of straight lines, so that curves and clothoids do not bias pitch and yaw;
* several cross-sections, known unequal marker widths, and a plausibility check of the lines
  (marker widths and spacing on the road) that turns curbs and absurd balances into
  ``valid=False``.

For the fusion filter, beyond the angles: the road's twist at the cross-sections (their own
rolls' slope along the road, three lines: :func:`_road_twist`) and the outputs' first-order
response to a twist at the vehicle and at the cross-sections (:meth:`Estimator._twist_response`),
with which the filter models what a superelevation runoff in view does to yaw and curvature.

The road's twist in the projection (given the distance travelled per frame, from the wheel
speed): the cross-sections' twists of the frames so far, kept along the road
(:class:`vision.twistmap.TwistMap`), give the bank change ahead; where it reaches
:attr:`EstimatorOptions.road_twist_min_deg` the frame's bird's-eye view and its projection are
onto the road turning about its centre line (:class:`vision.ipm.RoadTwist`), the lane fit
reaching as far as the map does. Pitch, yaw and curvature are then the road's under the vehicle
(no road-in-view terms left for the filter, their sigmas widened by the map's), the roll stays
the one at the cross-sections. Measured through the fusion: ``README``, "Fusion".
"""

from __future__ import annotations

import copy
import itertools
import math
from dataclasses import dataclass, field, replace
from functools import lru_cache

import cv2
import numba as nb
import numpy as np

from .camera import Camera, Mount, RoadMarkings
from .errors import VisionError
from .frames import (R_CS_FROM_CP, R_from_rpy, Ry, euler_from_matrix, matrix_from_euler, roll_xyz_from_zyx, rpy_from_R,
                     rpy_from_camera_xyz_scalar)
from .edges import measure_in_image
from .ipm import Bev, BevGrid, RoadTwist, default_grid, ground_from_rays, undistortion_lookup
from .lanemodel import LaneModel, fit_lane_model_points, lane_direction
from .lanes import LaneOptions, Marker, detect_markers
from .twistmap import TwistMap
from .options import EstimatorOptions
from .roll import (coefficients_eq8, coefficients_eq10, roll_bound_eq14, solve_numeric, solve_pade)
from .vanishing import (intersect_lines, r3_from_vp, r3_from_yaw_pitch, vp_from_r3,
                        yaw_pitch_from_r3)

__all__ = ["VisionEstimate", "Estimator", "estimate", "camera_xyz_from_vehicle", "vehicle_from_camera_xyz"]


# ---------------------------------------------------------------------------------------------
# Result


@dataclass(frozen=True)
class VisionEstimate:
    """One frame's estimate.

    Angles of the vehicle relative to the road, ZYX, INTERFACE conventions (positive roll leans
    right, positive pitch is nose down, positive yaw is nose left), rad. When not ``valid``: NaN
    where no estimate was made (too few lines), the rejected values where a check refused them
    (out of range, implausible lines; ``reason`` says which), kept for diagnosis: never a
    measurement.

    Attributes
    ----------
    roll_rad, pitch_rad, yaw_rad : float
    roll_sigma_rad, pitch_sigma_rad, yaw_sigma_rad : float
        1-sigma, first-order propagation of the edge and vanishing-point errors (from the fit
        residuals) through eqs. (8)/(10) and (17)/(20); see :mod:`vision.roll`, :mod:`vision.vanishing`.
        Where the pose was solved with the vertical curvature held, also the error that leaves:
        held for want of significance, the fit's own estimate of it and its variance through
        the lane parameters (:meth:`LaneModel.zeta_consider_cov`); held because the pose was far
        (a frame without a seed) while the last lane fit took it free, the pose step that fit
        would still take (a first frame on a banked curve: 0.28 deg of pitch, 0.9 of yaw).
    valid : bool
        False when the frame gave no trustworthy estimate; ``reason`` says why.
    curvature_1_m : float
        Curvature of the lane at the vehicle, 1/m, positive turning left (mean of the lines used),
        in the road's tangent plane (the lines' geodesic curvature): on a curve banked by ``b``
        ``kappa cos(b)`` of the horizontal curvature ``kappa`` (0.38 % less at 5 deg), which the
        filter models (``fusion.ekf._lane_plane_curvature``).
    curvature_sigma_1_m : float
        Its 1-sigma, 1/m: the lane model's covariance (vertical curvature included) plus the
        model terms of :data:`CURVATURE_MODEL_SIGMA`.
    vertical_curvature_1_m : float
        ``zeta``: the road surface ahead leaves the tangent plane at the vehicle as
        ``zeta x^2 / 2`` (1/m; positive a sag, negative a crest; ``-kappa sin(bank)`` on a
        banked curve). 0 with ``vertical_curvature=False``.
    vertical_curvature_sigma_1_m : float
        Its 1-sigma from the lane model's covariance, 1/m.
    pitch_per_vertical_curvature_m : float
        The pitch's error, rad, per 1/m of ``vertical_curvature_1_m`` beyond the vertical
        curvature at the vehicle: where that curvature changes across the view (a sag or crest
        coming into view) the single quadratic surface reads the change as pitch
        (:meth:`Estimator._sag_change_response`). NaN where ``zeta`` was held (within
        ``vertical_curvature_t_min`` sigma of 0, or the pose solved with it held).
    yaw_per_curvature_m : float
        The yaw's error, rad, per 1/m of ``curvature_1_m``'s, as the lane fit couples them (a
        line fitted more bent points more to the inside at the vehicle): ``cov(yaw, kappa) /
        var(kappa)`` of the fit's covariance, m (:meth:`Estimator._yaw_per_curvature`; 4-7 m on
        the rendered drives, and it predicts their yaw errors from their curvature errors:
        ``tests/test_vision_estimator.py``). NaN where the fit chose straight lines.
    roll_lookahead_m : float
        How far ahead of the vehicle's contact point the roll was measured, m: the mean distance
        of the cross-sections. In a superelevation runoff the road there is banked differently
        from under the wheels; the fusion filter models the measurement at that distance.
    road_twist_rad_m : float
        How fast the road's bank changes along the road at the cross-sections, rad/m (the
        slope over distance of the cross-sections' own rolls, which differ where the road
        twists: in a superelevation runoff the lanes widen and narrow unequally in the
        projection). Positive where the bank increases ahead (the bank's sign of
        :mod:`vision.frames`); applies ``roll_lookahead_m`` ahead. Three lines only (eq. (10));
        NaN with two, with fewer than two cross-sections, when they span under
        :data:`TWIST_MIN_SPAN_M` or lie where a line was not seen (a gap between the dashes:
        that line extrapolated).
    road_twist_sigma_rad_m : float
        Its 1-sigma from the lane model's covariance, rad/m.
    twist_response : tuple of 6 float
        How the curvature (1/m), pitch and yaw (rad) respond to the road's twist (rad/m) at the
        vehicle and at ``roll_lookahead_m``, in that order per output
        (:meth:`Estimator._twist_response`): the reported values are the road's plus
        ``G_here tau_here + G_ahead tau_ahead``. NaN when not computed; zeros when the
        projection had the road's twist (:mod:`vision.twistmap`), as then ``pitch_per_twist_m``
        and ``yaw_per_twist_m``: no road-in-view terms are left.
    road_twist_span_m : tuple of 2 float
        Where the cross-sections measured ``road_twist_rad_m``, m ahead of the contact point
        (three lines; empty otherwise): what :class:`vision.twistmap.TwistMap` records.
    road_axis : tuple of 5 float
        The centre line of three, in this frame's lane-model form (:class:`vision.ipm.RoadTwist`):
        what the road turns about, and the next frame's start.
    road_twist_used : float
        In a frame projected onto the twisted road (:mod:`vision.twistmap`): the mapped bank
        change from the contact point to ``roll_lookahead_m``, rad, which the roll (then the
        road's there) was taken from the pose by; 0 for a frame projected onto the plane.
    lateral_offset_m : float
        Vehicle origin's offset from the midpoint between the outermost lines used, m, positive
        to the left: with three lines on a two-lane road its centre line, with two the centre of
        the lane between them (``n_lines`` says which; on the simulator's three-line roads the
        frames that see two lines measure from the lane's centre, 1.75 m off the road's).
    line_spacing_m : float
        Distance between neighbouring lines used, m (mean).
    line_offsets_m : tuple of float
        Lateral positions of the used lines' centres relative to the vehicle origin at the
        vehicle, m, positive left, left to right.
    camera_xyz_rad : tuple
        ``(phi1, theta1, psi1)``: the camera's XYZ roll, pitch, yaw relative to the road.
    vp_px : tuple
        Vanishing point of the lane direction, undistorted pixels.
    n_lines : int
        Lines used (2 or 3).
    roll_equation : str
        "eq8", "eq10" or "damon2018".
    edge_rms_px : float
        RMS of the edge fits' residuals, BEV pixels.
    n_edge_points : int
    iterations, warps : int
        Refinement passes and BEV warps used.
    roll_bound_eq14_rad : float
        Eq. (14) as printed (for comparison; far smaller than the real error, see :mod:`vision.roll`).
    method : str
    reason : str
        Empty when valid.
    """

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    roll_sigma_rad: float
    pitch_sigma_rad: float
    yaw_sigma_rad: float
    valid: bool
    curvature_1_m: float = math.nan
    curvature_sigma_1_m: float = math.nan
    vertical_curvature_1_m: float = math.nan
    vertical_curvature_sigma_1_m: float = math.nan
    roll_lookahead_m: float = math.nan
    pitch_per_twist_m: float = 0.0
    yaw_per_twist_m: float = 0.0
    road_twist_rad_m: float = math.nan
    road_twist_sigma_rad_m: float = math.nan
    twist_response: tuple[float, ...] = (math.nan,) * 6
    pitch_per_vertical_curvature_m: float = math.nan
    yaw_per_curvature_m: float = math.nan
    road_twist_span_m: tuple[float, ...] = ()
    road_axis: tuple[float, ...] = ()
    road_twist_used: float = 0.0
    lateral_offset_m: float = math.nan
    line_spacing_m: float = math.nan
    line_offsets_m: tuple[float, ...] = ()
    camera_xyz_rad: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    vp_px: tuple[float, float] = (math.nan, math.nan)
    n_lines: int = 0
    roll_equation: str = ""
    edge_rms_px: float = math.nan
    n_edge_points: int = 0
    iterations: int = 0
    warps: int = 0
    roll_bound_eq14_rad: float = math.nan
    method: str = "alrazouk"
    reason: str = ""
    #: Geometry for drawing (:mod:`vision.debug`); not part of equality or repr.
    debug: object = field(default=None, compare=False, repr=False)

    @classmethod
    def invalid(cls, reason: str, method: str = "alrazouk", debug: object = None, **kw) -> "VisionEstimate":
        nan = math.nan
        return cls(nan, nan, nan, nan, nan, nan, False, method=method, reason=reason, debug=debug, **kw)

    @property
    def rpy_rad(self) -> tuple[float, float, float]:
        return self.roll_rad, self.pitch_rad, self.yaw_rad


@dataclass
class DebugInfo:
    """What :mod:`vision.debug` draws."""

    bev_image: np.ndarray | None = None
    bev: Bev | None = None
    markers: list = field(default_factory=list)
    used: list = field(default_factory=list)
    cross_rows_v: np.ndarray | None = None
    vp_px: tuple[float, float] | None = None
    R_o_from_cp: np.ndarray | None = None
    height_m: float = math.nan
    image_lines: list = field(default_factory=list)
    image_edges: list | None = None
    model: object = None


#: The refinement stops when a pass moves no angle by more than this (rad, 0.0006 deg).
_CONVERGED_RAD = 1e-5
#: Below this last step the lane model of the last pass is kept for the outputs (rad).
_REUSE_RAD = 1e-4
#: Vertical curvature is clamped to this (1/m): a crest or sag of 200 m radius; steeper is no road.
_ZETA_MAX = 5e-3
#: A change of the vertical curvature counts in the convergence test as the slope it makes this
#: far ahead (m).
_ZETA_LEVER_M = 20.0
#: Refinement steps larger than this (rad, 0.1 deg) hold the vertical curvature where it is.
_ZETA_POSE_STEP_RAD = math.radians(0.1)
#: A frame without a seed starts from the mount's pose; on a banked curve its steps stay over
#: :data:`_ZETA_POSE_STEP_RAD` for the ``refine_iterations`` passes, its pose solved with the
#: vertical curvature held at 0: the left-hand 5 deg HD curve's frames 0.28 deg off in pitch and
#: 0.7-0.9 in yaw. While the last pass held it, up to this many passes more (there: 0.007-0.019
#: and 0.02-0.27 deg). Frames with a seed keep ``refine_iterations``: in superelevation runoffs the
#: curvature freed by more passes takes up the road's twist (tried on every frame: the HD
#: drives' vision yaw 0.131 -> 0.196 deg on the left-hand drive, 0.336 -> 0.284 on the right).
UNSEEDED_EXTRA_PASSES = 2
#: Floor of the cross-sections' twist as :class:`vision.twistmap.TwistMap` takes it: absolute
#: (rad/m) plus relative. Against the simulator's truth the planar projection's twist is good to
#: 0.002-0.004 deg/m on steady road and 15-25 % of the twist in runoffs (the fusion floors it the
#: same way).
_TWIST_SIGMA_FLOOR_RAD_M = math.radians(0.004)
_TWIST_SIGMA_REL = 0.25
#: The twist map's 1-sigma as the angles' and the curvature's sigmas take it: against the true
#: twist its errors were 2.5-2.8 times its sigma in the first runoff of the 20 s drives (1.0 on the
#: 60 s drive, 0.4-0.9 on the hold-out drive), where the map is youngest.
_TWIST_MAP_SIGMA_SCALE = 3.0
#: Model terms of the angles' 1-sigma beyond the lane model's covariance (rad): roll, pitch, yaw.
_ANGLE_MODEL_SIGMA_RAD = (0.0, 0.0, 0.0)
#: Model terms of the curvature's 1-sigma: a floor (1/m) and a part proportional to it.
CURVATURE_MODEL_SIGMA = (0.0, 0.0)
#: The road twist is measured when the cross-sections span at least this (m).
TWIST_MIN_SPAN_M = 2.0

# ---------------------------------------------------------------------------------------------
# Attitude conversions (eq. (22))


def camera_xyz_from_vehicle(roll_rad: float, pitch_rad: float, yaw_rad: float, tilt_rad: float):
    """``(phi1, theta1, psi1)`` of ``R_o_from_cs = R_o_from_v Ry(mu)`` in XYZ form."""
    R = R_from_rpy(roll_rad, pitch_rad, yaw_rad) @ Ry(tilt_rad)
    a, b, c = euler_from_matrix("xyz", R)
    return float(a), float(b), float(c)


def vehicle_from_camera_xyz(phi1: float, theta1: float, psi1: float, tilt_rad: float):
    """Eq. (22): ``R_o_from_v = Rx(phi1) Ry(theta1) Rz(psi1) Ry(mu)^T``; returns ZYX
    ``(roll, pitch, yaw)`` and the matrix."""
    R = matrix_from_euler("xyz", phi1, theta1, psi1) @ Ry(tilt_rad).T
    roll, pitch, yaw = rpy_from_R(R)
    return (float(roll), float(pitch), float(yaw)), R


def _R_o_from_cp(phi1: float, theta1: float, psi1: float) -> np.ndarray:
    return matrix_from_euler("xyz", phi1, theta1, psi1) @ R_CS_FROM_CP


def _camera_offset(R_o_from_v: np.ndarray, mount: Mount) -> np.ndarray:
    """Optical centre relative to the contact point, road frame, m."""
    return R_o_from_v @ mount.position_v


# ---------------------------------------------------------------------------------------------
# Small helpers


def _gray(image) -> tuple[np.ndarray | None, str]:
    """uint8 grey image, or ``(None, reason)`` for input that is not a usable picture."""
    if not isinstance(image, np.ndarray):
        return None, f"not an image array ({type(image).__name__})"
    if image.size == 0:
        return None, "empty image"
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (3, 4))):
        return None, f"image must be HxW or HxWx3/4, got shape {image.shape}"
    if image.dtype == np.uint8:
        g = image
    elif image.dtype == np.uint16:
        g = (image / 257.0).astype(np.float32)
    elif np.issubdtype(image.dtype, np.floating) or np.issubdtype(image.dtype, np.integer):
        f = image.astype(np.float32)
        if not np.all(np.isfinite(f)):
            return None, "image has non-finite pixels"
        g = f * 255.0 if float(f.max(initial=0.0)) <= 1.0 else f
    else:
        return None, f"unsupported image dtype {image.dtype}"
    if g.ndim == 3:
        code = cv2.COLOR_BGR2GRAY if g.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        g = cv2.cvtColor(g, code)
    if g.dtype != np.uint8:
        # rounded (a cast truncates: a 16-bit picture came out 0.46 grey levels dark on average)
        g = np.clip(np.rint(g), 0, 255).astype(np.uint8)
    return g, ""


@lru_cache(maxsize=8)
def _undistort_lut(camera: Camera):
    return undistortion_lookup(camera) if camera.has_distortion else None


@dataclass
class _Edge:
    """One marker edge: rays through its sub-pixel points, and bookkeeping."""

    rays: np.ndarray          # (n, 3) in cp
    line: int                 # index into the used lines, left to right
    side: int                 # 0 left edge (larger Y), 1 right edge
    from_image: bool          # cut in the image (each point independent) or a BEV row
    cut_step: np.ndarray | None = None   # (n, 3): ray change for one pixel along the cut


# ---------------------------------------------------------------------------------------------
# Estimator


class Estimator:
    """Estimates frame after frame; keeps the previous estimate as the next frame's seed.

    Parameters
    ----------
    camera : Camera
    mount : Mount
    road : RoadMarkings
    options : EstimatorOptions
    """

    def __init__(self, camera: Camera, mount: Mount, road: RoadMarkings = RoadMarkings(),
                 options: EstimatorOptions = EstimatorOptions()) -> None:
        if not isinstance(camera, Camera) or not isinstance(mount, Mount):
            raise VisionError("Estimator needs a vision.Camera and a vision.Mount")
        self.camera, self.mount, self.road, self.options = camera, mount, road, options
        o = options
        mw = min(road.marker_widths_m)
        coarse = o.edge_domain == "image"
        dx = o.dx_m if o.dx_m is not None else (0.2 if coarse else 0.1)
        g = default_grid(camera, mw, half_width_m=o.half_width_m, dy_m=o.dy_m, dx_m=dx,
                         height_m=mount.height_m, tilt_rad=mount.tilt_rad)
        if coarse and o.dy_m is None:
            g = replace(g, dy_m=float(np.clip(2.0 * g.dy_m, 0.025, 0.05)))
        x_max = g.x_max_m
        if o.refine_iterations > 0:
            # The refinement leaves points beyond fit_range_m out: no need to warp them.
            x_max = min(x_max, o.fit_range_m + 1.0)
        self.grid = BevGrid(o.x_min_m if o.x_min_m is not None else g.x_min_m,
                            o.x_max_m if o.x_max_m is not None else max(x_max, g.x_min_m + 5.0),
                            g.y_min_m, g.y_max_m, g.dx_m, g.dy_m)
        # In the image domain the BEV only tracks the markers: half-level crossings suffice there.
        self.lane_options = LaneOptions(edges=o.edges if not coarse else "subpixel", fit_degree=o.fit_degree)
        self.lut = _undistort_lut(camera)
        self.last: VisionEstimate | None = None
        self._before_last: VisionEstimate | None = None
        self._last_call_valid = False
        self._R_cs_from_v = Ry(mount.tilt_rad).T
        self._height_memo: dict = {}
        self._position_v = mount.position_v      # a property that builds the array each time
        self.twist_map = TwistMap()
        self._map_active = False
        self._twist_probe: np.ndarray | None = None     # where _twist_ahead looks (fixed per object)

    # ---- public ----

    def reset(self) -> None:
        self.last = None
        self._before_last = None
        self._last_call_valid = False
        self.twist_map.reset()
        self._map_active = False

    def snapshot(self) -> tuple:
        """What the next frames' estimates depend on (the last estimates they start from, the
        road-twist map), to :meth:`restore` when a frame turns out not to belong (a live frame
        whose stamp was a glitch, :class:`fusion.realtime.LiveFusion`)."""
        return self.last, self._before_last, self._last_call_valid, self._map_active, copy.deepcopy(self.twist_map)

    def restore(self, snapshot: tuple) -> None:
        """Back to a :meth:`snapshot`: the frames after it as if the frames between were not."""
        self.last, self._before_last, self._last_call_valid, self._map_active, twist_map = snapshot
        self.twist_map = copy.deepcopy(twist_map)    # the snapshot stays as it was, for another restore

    def estimate(self, image, seed=None, *, travel_m: float | None = None, keep_debug: bool = False) -> VisionEstimate:
        """Estimate one frame. ``seed``: a previous :class:`VisionEstimate` or ``(roll, pitch,
        yaw)`` in rad; ``None`` uses the last valid estimate of this object (or no seed).
        ``travel_m``: how far the vehicle moved along the road since the previous frame (from
        the wheel speed), which carries the road's twist measured by the frames before
        (:mod:`vision.twistmap`, :attr:`vision.options.EstimatorOptions.road_twist`); None:
        no map (the road in view is taken as untwisted, the fusion models its twist).
        Never raises for bad pictures: they give ``valid=False`` with a ``reason``."""
        if travel_m is None or not math.isfinite(travel_m) or not self.options.road_twist:
            if self._map_active:
                self.twist_map.reset()
            self._map_active = False
        else:
            self._map_active = True
            self.twist_map.advance(float(travel_m))
        est = self._estimate(image, seed, keep_debug)
        if self._map_active and est.valid and est.road_twist_span_m and math.isfinite(est.road_twist_rad_m):
            sigma = max(est.road_twist_sigma_rad_m, _TWIST_SIGMA_FLOOR_RAD_M + _TWIST_SIGMA_REL * abs(est.road_twist_rad_m))
            self.twist_map.update(*est.road_twist_span_m, est.road_twist_rad_m, sigma)
        return est

    def _twist_ahead(self, axis) -> RoadTwist | None:
        """The road's twist from the map about ``axis`` when it is worth projecting onto: a bank
        change of :attr:`EstimatorOptions.road_twist_min_deg` or more within the fit's reach."""
        o = self.options
        tw = self.twist_map.profile(axis)
        if tw is None:
            return None
        if self._twist_probe is None:
            self._twist_probe = np.linspace(0.0, o.road_twist_fit_range_m, 6)
        b = tw.bank_change(self._twist_probe)
        if float(np.max(np.abs(b))) < math.radians(o.road_twist_min_deg):
            return None
        return tw

    def _estimate(self, image, seed, keep_debug: bool) -> VisionEstimate:
        own_seed = seed is None and self.last is not None and self.last.valid
        if own_seed:
            seed = self.last
        seed_rpy = _seed_rpy(seed)
        if own_seed and self._before_last is not None and seed_rpy is not None:
            # The last two frames in a row were valid: start from their extrapolation (constant
            # rate). A better start only saves a second warp on steady road; in a runoff the
            # previous estimates (this start, and the seed's vertical-curvature prior) move some
            # frames' pitch and yaw by 0.01-0.1 deg (docs/fusion-notes.md, eleventh session).
            prev = _seed_rpy(self._before_last)
            seed_rpy = tuple(2.0 * a - b for a, b in zip(seed_rpy, prev))
        gray, why = _gray(image)
        if gray is None:
            return VisionEstimate.invalid(why, self.options.method)
        if gray.shape != (self.camera.height, self.camera.width):
            return VisionEstimate.invalid(
                f"image is {gray.shape[1]}x{gray.shape[0]}, the camera is {self.camera.width}x{self.camera.height}",
                self.options.method)
        try:
            if self.options.method == "damon2018":
                from .baseline import damon_estimate

                est = damon_estimate(self, gray, seed_rpy, keep_debug)
            else:
                est = self._alrazouk(gray, seed_rpy, keep_debug,
                                     seed if isinstance(seed, VisionEstimate) and seed.valid else None)
        except (VisionError, np.linalg.LinAlgError, FloatingPointError, ValueError) as e:
            est = VisionEstimate.invalid(f"{type(e).__name__}: {e}", self.options.method)
        est = _sanitise(est)
        if est.valid:
            # Extrapolate next time only from two valid frames in a row.
            self._before_last = self.last if self._last_call_valid else None
            self.last = est
        else:
            self._before_last = None
        self._last_call_valid = est.valid
        return est

    # ---- BEV and markers ----

    def bev_at(self, gray: np.ndarray, R_o_from_cp: np.ndarray, height_m: float, grid: BevGrid | None = None,
               surface=None):
        bev = Bev(grid or self.grid, self.camera, R_o_from_cp, height_m, surface)
        img = bev.warp(gray, self.lut)
        lo, hi = bev.valid_columns()
        return bev, img, lo, hi

    def markers_at(self, gray, R_o_from_cp, height_m, lane_options: LaneOptions | None = None,
                   grid: BevGrid | None = None, surface=None):
        bev, img, lo, hi = self.bev_at(gray, R_o_from_cp, height_m, grid, surface)
        mk = detect_markers(img, lo, hi, bev.grid.dx_m, bev.grid.dy_m, min(self.road.marker_widths_m),
                            lane_options or self.lane_options)
        return bev, img, mk

    def select_lines(self, bev: Bev, markers: list[Marker], want_three: bool,
                     curvature_1_m: float = 0.0) -> tuple[list[Marker], list[int]]:
        """The lines for the roll equation, left to right: the nearest on each side of the
        vehicle, plus (for three) the next line whose spacing is most equal.

        Each marker's position is its lateral offset at its near end taken back to the nadir
        along a curve of ``curvature_1_m`` (the previous frame's): on a curve, a dash 30 m ahead
        sits ``kappa x^2 / 2`` (2 m at 200 m radius) off its line's position at the vehicle.
        Markers within 1 m of each other there are dashes of one line; the longest stands for it.
        """
        if len(markers) < 2:
            return [], []
        g = bev.grid
        y0 = np.empty(len(markers))
        extent = np.empty(len(markers))
        for i, m in enumerate(markers):
            v_near = m.v_near           # a property: the inliers' maximum each time
            x_near = float(g.x_max_m - v_near * g.dx_m)                 # g.x_of_row, of a number
            ul, ur = m.u_at(v_near)
            y0[i] = float(g.y_max_m - 0.5 * (ul[0] + ur[0]) * g.dy_m) - 0.5 * curvature_1_m * x_near**2   # g.y_of_col
            extent[i] = v_near - m.v_far
        cand: list[int] = []
        for i in np.argsort(-y0):                      # left to right
            i = int(i)
            if cand and y0[cand[-1]] - y0[i] < 1.0:
                if extent[i] > extent[cand[-1]]:
                    cand[-1] = i
                continue
            cand.append(i)
        if len(cand) < 2:
            return [], []
        left = [i for i in cand if y0[i] > 0.0]
        right = [i for i in cand if y0[i] <= 0.0]
        if not left or not right:
            # Both lines on one side (large lateral offset): take the two nearest the nadir.
            pair = sorted(cand, key=lambda i: abs(y0[i]))[:2]
            pair.sort(key=lambda i: -y0[i])
        else:
            pair = [left[-1], right[0]]
        if not want_three:
            return [markers[i] for i in pair], pair
        pos = [cand.index(i) for i in pair]
        trios = []
        if pos[0] - 1 >= 0 and pos[1] == pos[0] + 1:
            trios.append([cand[pos[0] - 1]] + pair)
        if pos[1] + 1 < len(cand) and pos[1] == pos[0] + 1:
            trios.append(pair + [cand[pos[1] + 1]])
        if not trios:
            return [markers[i] for i in pair], pair

        def unequal(tr):
            s1, s2 = y0[tr[0]] - y0[tr[1]], y0[tr[1]] - y0[tr[2]]
            return abs(s1 - s2) / max(s1, s2, 1e-9)

        best = min(trios, key=unequal)
        if unequal(best) > 0.35:
            return [markers[i] for i in pair], pair
        return [markers[i] for i in best], best

    # ---- the method ----

    def _initial_pose(self, seed_rpy):
        """Camera XYZ angles and height of the first BEV."""
        if self.options.ipm_pose == "seed" and seed_rpy is not None:
            roll, pitch, yaw = seed_rpy
        else:
            roll, pitch, yaw = 0.0, 0.0, 0.0
        return camera_xyz_from_vehicle(roll, pitch, yaw, self.mount.tilt_rad)

    def height_of(self, phi1, theta1, psi1) -> tuple[float, np.ndarray]:
        """Camera height above the road (m) and ``R_o_from_v`` for the camera's XYZ angles."""
        hit = self._pose_terms(phi1, theta1, psi1)
        return hit[0], hit[1]

    def _pose_terms(self, phi1, theta1, psi1) -> tuple[float, np.ndarray, float]:
        """``(H, R_o_from_v, x0)`` of :meth:`height_of` and :meth:`surface_of`, memoised."""
        key = (float(phi1), float(theta1), float(psi1))
        hit = self._height_memo.get(key)
        if hit is None:
            R_o_from_v = matrix_from_euler("xyz", *key) @ self._R_cs_from_v
            hit = (float(R_o_from_v[2] @ self._position_v), R_o_from_v, -float(R_o_from_v[0] @ self._position_v))
            if len(self._height_memo) > 64:
                self._height_memo.clear()
            self._height_memo[key] = hit
        return hit

    def surface_of(self, phi1, theta1, psi1) -> tuple[float, float]:
        """Camera height above the road's tangent plane at the contact point, and the contact
        point's distance ahead of the camera's nadir (m), for the camera's XYZ angles."""
        hit = self._pose_terms(phi1, theta1, psi1)
        return hit[0], hit[2]

    def _alrazouk(self, gray, seed_rpy, keep_debug, seed_est: "VisionEstimate | None" = None) -> VisionEstimate:
        pose = self._initial_pose(seed_rpy)
        zeta0 = self._zeta_prior(seed_est)
        curvature = seed_est.curvature_1_m if seed_est is not None and math.isfinite(seed_est.curvature_1_m) else 0.0
        twist0 = seed_est.road_axis if seed_est is not None and seed_est.road_axis else None
        narrow = self._seeded_grid(seed_est, pose)
        if narrow is not None:
            # Only the part of the BEV around the seed's lines; the whole width if a line is lost.
            result = self._run(gray, pose, keep_debug, narrow, zeta0, curvature, twist0)
            if result.valid and result.n_lines >= seed_est.n_lines:
                return result
        extra = UNSEEDED_EXTRA_PASSES if seed_est is None else 0
        result = self._run(gray, pose, keep_debug, zeta0=zeta0, curvature_1_m=curvature, twist0=twist0,
                           extra_passes=extra)
        if not result.valid and self.options.ipm_pose == "seed":
            # The seed (or the mount's pose) put lines outside the BEV: search for them.
            pose = self._coarse_pose(gray)
            if pose is not None:
                again = self._run(gray, pose, keep_debug)
                if again.valid:
                    return replace(again, warps=again.warps + result.warps)
        return result

    def _zeta_prior(self, seed: "VisionEstimate | None") -> tuple[float, float]:
        """Prior of the vertical curvature, ``(mean, sigma)`` in 1/m: the previous frame's
        estimate with its sigma grown by ``vertical_curvature_walk_1_m``, or ``N(0,
        vertical_curvature_sigma_1_m^2)`` without one (or when that is tighter)."""
        o = self.options
        static = (0.0, o.vertical_curvature_sigma_1_m)
        if seed is None or not (math.isfinite(seed.vertical_curvature_1_m)
                                and math.isfinite(seed.vertical_curvature_sigma_1_m)):
            return static
        s = math.hypot(seed.vertical_curvature_sigma_1_m, o.vertical_curvature_walk_1_m)
        return static if s >= static[1] else (seed.vertical_curvature_1_m, s)

    def _seeded_grid(self, seed: "VisionEstimate | None", pose) -> BevGrid | None:
        """The BEV grid narrowed to the seed's lines (1.2 m beyond the outer ones, widened by
        the curvature's drift over the range), or None without a seed that knows its lines."""
        o = self.options
        if seed is None or not seed.line_offsets_m or o.ipm_pose != "seed" or not o.narrow_bev:
            return None
        g = self.grid
        _, R_o_from_v = self.height_of(*pose)
        cam_y = float(_camera_offset(R_o_from_v, self.mount)[1])
        ys = np.asarray(seed.line_offsets_m) - cam_y
        drift = 0.5 * seed.curvature_1_m * g.x_max_m**2
        # A planar BEV spreads the lines by y zeta x^2 / 2H on a sag (and draws them in on a crest).
        zeta = seed.vertical_curvature_1_m if math.isfinite(seed.vertical_curvature_1_m) else 0.0
        spread = abs(zeta) * g.x_max_m**2 / (2.0 * self.mount.height_m)
        # Three lines painted but the seed saw two: look one lane further on both sides.
        missing = self.road.lane_width_m if (self.road.center_line and seed.n_lines < 3
                                             and o.roll_equation in ("auto", "eq10")) else 0.0
        lo = float(ys.min()) * (1.0 + spread) + min(0.0, drift) - 1.2 - missing
        hi = float(ys.max()) * (1.0 + spread) + max(0.0, drift) + 1.2 + missing
        lo, hi = max(lo, g.y_min_m), min(hi, g.y_max_m)
        if hi - lo < 3.0 or (hi - lo) > 0.9 * (g.y_max_m - g.y_min_m):
            return None
        return replace(g, y_min_m=lo, y_max_m=hi)

    def _run(self, gray, pose, keep_debug, grid: BevGrid | None = None,
             zeta0: tuple[float, float] = (0.0, math.inf), curvature_1_m: float = 0.0, twist0=None,
             extra_passes: int = 0) -> VisionEstimate:
        """BEV at ``pose``, markers, solve; warp again at the new pose when it moved far.
        ``extra_passes``: refinement passes beyond ``refine_iterations`` while the last one held
        the vertical curvature (:data:`UNSEEDED_EXTRA_PASSES`)."""
        o = self.options
        want_three = self.road.center_line and o.roll_equation in ("auto", "eq10")
        warps = 0
        result = None          # (an invalid estimate made only if no warp ran: 8 us a frame)
        # the road's twist the frames before measured, when a runoff is ahead: the view and the
        # projection of this frame are then onto the twisted road
        tw0 = self._twist_ahead(np.asarray(twist0, float)) if self._map_active and twist0 else None
        while warps < o.max_warps:
            H, x0 = self.surface_of(*pose)
            surface = (zeta0[0] if math.isfinite(zeta0[1]) else 0.0, x0, tw0) if tw0 is not None else None
            bev, img, markers = self.markers_at(gray, _R_o_from_cp(*pose), H, grid=grid, surface=surface)
            warps += 1
            image_edges = None
            if o.edge_domain == "image" and markers:
                measured = measure_in_image(gray, markers, bev, self.camera, o.edges)
                markers = [m for m, e in zip(markers, measured) if e is not None]
                image_edges = [e for e in measured if e is not None]
            lines, idx = self.select_lines(bev, markers, want_three, curvature_1_m)
            dbg = DebugInfo(bev_image=img, bev=bev, markers=markers, used=idx) if keep_debug else None
            if len(lines) < 2:
                n = len(markers)
                return VisionEstimate.invalid(f"{n} lane line{'' if n == 1 else 's'} found, need 2", o.method,
                                              debug=dbg, warps=warps)
            used_edges = [image_edges[i] for i in idx] if image_edges is not None else None
            if dbg is not None:
                dbg.image_edges = used_edges
            result = self._solve(bev, lines, pose, H, dbg, warps, used_edges, zeta0, twist0 if tw0 is not None else None,
                                 extra_passes)
            if not result.valid:
                return result
            new = result.camera_xyz_rad
            if math.degrees(max(abs(a - b) for a, b in zip(new, pose))) <= o.rewarp_deg:
                break
            pose = new
        return result if result is not None else VisionEstimate.invalid("no lane markers found", o.method)

    def _coarse_pose(self, gray):
        """Camera pose from a wide, coarse BEV tried at leans of 0, -+15, -+30, -+45 deg: for frames
        without a usable seed. None if no lean shows two lines."""
        g = self.grid
        coarse = BevGrid(g.x_min_m, min(g.x_max_m, 25.0), -20.0, 20.0, 0.15, 0.05)
        for lean in (0.0, -15.0, 15.0, -30.0, 30.0, -45.0, 45.0):
            pose = camera_xyz_from_vehicle(math.radians(lean), 0.0, 0.0, self.mount.tilt_rad)
            H, _ = self.height_of(*pose)
            bev, _, markers = self.markers_at(gray, _R_o_from_cp(*pose), H, grid=coarse)
            lines, _ = self.select_lines(bev, markers, False)
            if len(lines) < 2:
                continue
            res = self._solve(bev, lines, pose, H, None, 1)
            if res.valid:
                return res.camera_xyz_rad
        return None

    def _solve(self, bev: Bev, lines: list[Marker], pose0, H0: float, dbg, warps: int,
               image_edges=None, zeta0: tuple[float, float] = (0.0, math.inf), twist0=None,
               extra_passes: int = 0) -> VisionEstimate:
        """Roll, pitch, yaw (and the vertical curvature, the road's twist) from the lines found in
        one BEV. ``zeta0``: prior ``(mean, sigma)`` of the vertical curvature, 1/m
        (:meth:`_zeta_prior`); ``twist0``: the centre line to start the road's twist about (the
        previous frame's :attr:`VisionEstimate.road_axis`), or None."""
        o, cam = self.options, self.camera
        n_lines = len(lines)
        use_eq10 = n_lines == 3 and o.roll_equation in ("auto", "eq10")
        if o.roll_equation == "eq10" and n_lines != 3:
            return VisionEstimate.invalid(f"eq. (10) needs three lines, found {n_lines}", o.method, debug=dbg)
        # Width ratio of eq. (8): the outermost two markers' known widths (left, centre, right).
        widths = self.road.marker_widths_m
        ratio = (widths[0] / widths[2]) if o.known_widths else 1.0

        # Edge points -> rays in cp.
        edges: list[_Edge] = []
        if image_edges is None:
            # All edges' BEV points to rays in one product: left then right edge of each line.
            us, vs_ = [], []
            for m in lines:
                k = m.inliers
                us += [m.u_left[k], m.u_right[k]]
                v_k = m.v[k]
                vs_ += [v_k, v_k]
            rays = bev.rays_of_bev(np.concatenate(us), np.concatenate(vs_))
            ends = list(itertools.accumulate([u.size for u in us], initial=0))     # np.cumsum's integers
            for i in range(len(us)):
                edges.append(_Edge(rays[ends[i]:ends[i + 1]], i // 2, i % 2, False))
            _stack_edges(edges, rays)        # the lane model's stack is these rays, as they are
        else:
            for j, ie in enumerate(image_edges):
                for side, uv in ((0, ie.left), (1, ie.right)):
                    n_ = cam.normalized(uv)
                    uv1 = uv.copy()
                    uv1[:, 0 if ie.axis == 0 else 1] += 1.0   # one pixel along the cut
                    n1 = cam.normalized(uv1)
                    step = np.concatenate([n1 - n_, np.zeros((n_.shape[0], 1))], -1)
                    edges.append(_Edge(np.concatenate([n_, np.ones((n_.shape[0], 1))], -1), j, side, True, step))
        n_points = int(sum(e.rays.shape[0] for e in edges))
        rms_px = float(np.sqrt(_mean(np.array([m.rms_left**2 + m.rms_right**2 for m in lines])) / 2.0))
        shape_deg = o.fit_degree

        phi, theta, psi = pose0
        # Vertical curvature of the surface the points are projected onto (1/m).
        use_sag = o.vertical_curvature and o.refine_iterations > 0
        zeta_prior, zeta_prior_sigma = zeta0
        zeta = float(min(max(zeta_prior, -_ZETA_MAX), _ZETA_MAX)) if use_sag else 0.0      # np.clip of a number
        sag = zeta if use_sag else None
        # The road's twist about its centre line (three lines), from the frames before
        # (:mod:`vision.twistmap`); the centre line it turns about, from the last lane model
        # (the previous frame's to start with).
        use_twist = self._map_active and twist0 is not None and n_lines == 3 and o.refine_iterations > 0
        axis = np.array(twist0, float) if use_twist and twist0 else None
        tw = None
        iterations = 0
        held_last = False              # the last pose update held zeta where it was
        if o.refine_iterations == 0:
            # ---- the paper's single pass: roll in this BEV, vanishing point of image lines ----
            vs = self._bev_cross_rows(lines)
            if vs is None:
                return VisionEstimate.invalid("the lines do not overlap along the road", o.method, debug=dbg)
            alphas, coef = self._bev_alphas(bev, lines, vs, use_eq10, ratio, bev.f_vx)
            resid = self._solve_roll(alphas, coef)
            phi_bev = phi - resid
            vp, lines_img = self._vp_image_lines(bev, lines)
            psi, theta = yaw_pitch_from_r3(r3_from_vp(cam.K, vp))
            phi = roll_xyz_from_zyx(phi_bev, theta, psi) if o.eq21 else phi_bev
            if dbg is not None:
                dbg.cross_rows_v = vs
                dbg.image_lines = lines_img
            H, x0 = self.surface_of(phi, theta, psi)
            model = self._model(edges, _R_o_from_cp(phi, theta, psi), H, shape_deg, bev.grid)
            x_rows = self._cross_x(model)
            if x_rows is None:
                return VisionEstimate.invalid("the lines do not overlap along the road", o.method, debug=dbg)
        else:
            step = math.inf
            for it in range(o.refine_iterations + extra_passes):
                if it >= o.refine_iterations and not held_last:
                    break
                iterations = it + 1
                H, x0 = self.surface_of(phi, theta, psi)
                R = _R_o_from_cp(phi, theta, psi)
                sag = zeta if use_sag else None
                tw = self.twist_map.profile(axis) if use_twist and axis is not None else None
                model = self._model(edges, R, H, shape_deg, bev.grid, select=it == 0, zeta=sag, x0=x0,
                                    zeta_prior=zeta0, twist=tw)
                shape_deg = model.c.size + 1       # the degree chosen in the first pass is kept
                if use_twist:
                    axis = _centre_axis(model)
                dmodel = model if o.vp == "tangent" else self._model(edges, R, H, 1, bev.grid, zeta=sag, x0=x0,
                                                                                  zeta_prior=zeta0, twist=tw)
                if use_sag and model.dzeta != 0.0 and step > _ZETA_POSE_STEP_RAD:
                    # Far from the pose, a pitch error bends the projected lines in ways the
                    # polynomials do not follow (a 1/x term), which zeta would take up: where
                    # the step with zeta held is large, zeta stays where it is. (After a step
                    # under that size the pose is near: the check is skipped, 0.7 ms a frame.)
                    held = model.held_at(0.0)
                    dheld = held if o.vp == "tangent" else dmodel.held_at(0.0)
                    upd = self._pose_update(held, dheld, R, H, x0, zeta, use_eq10, ratio)
                    held_last = not (isinstance(upd, str) or max(abs(upd[0]), abs(upd[1] - psi),
                                                                 abs(upd[2] - theta)) <= _ZETA_POSE_STEP_RAD)
                    if held_last:
                        model, dmodel = held, dheld
                    else:
                        upd = self._pose_update(model, dmodel, R, H, x0, zeta, use_eq10, ratio)
                else:
                    held_last = False
                    upd = self._pose_update(model, dmodel, R, H, x0, zeta, use_eq10, ratio)
                if isinstance(upd, str):
                    return VisionEstimate.invalid(upd, o.method, debug=dbg)
                delta, psi_new, theta_new, zeta_new, x_rows = upd
                step = max(abs(delta), abs(psi_new - psi), abs(theta_new - theta),
                           abs(zeta_new - zeta) * _ZETA_LEVER_M)
                phi, theta, psi, zeta = phi - delta, theta_new, psi_new, zeta_new
                if step < _CONVERGED_RAD:
                    break
            if step >= _REUSE_RAD:
                # The last pass moved the pose: describe the lanes in the final frame.
                H, x0 = self.surface_of(phi, theta, psi)
                sag = zeta if use_sag else None
                tw = self.twist_map.profile(axis) if use_twist and axis is not None else None
                model = self._model(edges, _R_o_from_cp(phi, theta, psi), H, shape_deg, bev.grid, select=False,
                                    zeta=sag, x0=x0, zeta_prior=zeta0, twist=tw)
                if use_twist:
                    axis = _centre_axis(model)
            x_rows = self._cross_x(model)
            if x_rows is None:
                return VisionEstimate.invalid("the lines do not overlap along the road", o.method, debug=dbg)
            vp = vp_from_r3(cam.K, r3_from_yaw_pitch(psi, theta))
            if dbg is not None:
                dbg.cross_rows_v = bev.grid.row_of_x(x_rows)

        # ---- outputs ----
        # vehicle_from_camera_xyz: R_o_from_v as height_of has it (the same product, often made already)
        _, R_o_from_v = self.height_of(phi, theta, psi)
        roll, pitch, yaw = (float(a) for a in rpy_from_R(R_o_from_v))
        cam_off = _camera_offset(R_o_from_v, self.mount)
        H = float(cam_off[2])
        x_c = -float(cam_off[0])
        heights = _heights(x_rows, H, x_c, zeta)
        # Uncertainty: the lane model's covariance through the roll equation and the lane
        # direction (first order), plus the painted widths' tolerance for eq. (8).
        sig_f = 0.0
        if not use_eq10 and o.marker_width_tolerance_m > 0:
            sig_f = o.marker_width_tolerance_m / H * math.hypot(1.0, ratio)
        # first-order rows shared by the covariance, the road twist and the twist response
        roll_rows = _roll_rows(model, x_rows, use_eq10, ratio, heights, x_c)
        R_cp = _R_o_from_cp(phi, theta, psi)
        dir_rows = _direction_rows(model, H, x_c, R_cp)
        J_vehicle = _vehicle_jacobian(float(phi), float(theta), float(psi), self.mount.tilt_rad)
        cov_cam = self._camera_covariance(model, roll_rows, dir_rows, sig_f)
        if held_last and model.zeta_hold is None and model.i_dzeta >= 0 and model.dzeta != 0.0:
            # The pose was solved with zeta held (far from it), the lanes refitted with it free:
            # the step that fit would still take is an error of the pose the fit's covariance
            # does not hold.
            upd = self._pose_update(model, model, R_cp, H, x_c, zeta, use_eq10, ratio)
            if not isinstance(upd, str):
                d = np.array([-upd[0], upd[2] - theta, upd[1] - psi])
                cov_cam = cov_cam + np.outer(d, d)
        s_roll, s_pitch, s_yaw = _vehicle_sigmas(J_vehicle, cov_cam)
        s_roll, s_pitch, s_yaw = (math.hypot(s, m) for s, m in zip((s_roll, s_pitch, s_yaw), _ANGLE_MODEL_SIGMA_RAD))
        # Curvature, lateral offset, spacing at the contact point, from the outermost lines used.
        shape_c = model._shape(x_c)            # the lines' common shape term at x_c, once for all edges
        all_centres = [0.5 * float(model.y(2 * j, x_c, shape_c) + model.y(2 * j + 1, x_c, shape_c))
                       for j in range(n_lines)]
        centres = [all_centres[0], all_centres[-1]]
        offsets = tuple(c + float(cam_off[1]) for c in all_centres)
        # the outer lines' curvature and its first-order row (for its sigma and the twist response)
        curv = [model.curvature_and_row(j, x_c) for j in (0, n_lines - 1)] if model.c.size else None
        curvature = float(_mean_rows([k for k, _ in curv])) if curv else 0.0
        curvature_row = _mean_rows([r for _, r in curv]) if curv else None
        curvature_sigma = self._curvature_sigma(model, curvature, curvature_row)
        # the vehicle's pitch and yaw as first-order rows in the lane model's parameters, for the
        # gains below (the yaw's coupling to the curvature, the twist and vertical-curve responses)
        py_rows = _pitch_yaw_rows(J_vehicle, dir_rows)
        yaw_per_curvature = self._yaw_per_curvature(model, py_rows[1], curvature_row)
        x_mean = float(_mean(x_rows))
        lookahead = x_mean - x_c
        span = (float(x_rows.min()) - x_c, float(x_rows.max()) - x_c)
        twisted = tw is not None if o.refine_iterations > 0 else False
        # in a frame projected onto the twisted road: what the cross-sections see beyond the map's
        twist, twist_sigma = _road_twist(model, x_rows, roll_rows, use_eq10)
        bank_change_L = 0.0
        if twisted:
            # The projection had the road's twist (the map's, from the frames before): pitch,
            # yaw and curvature are the road's under the vehicle, no road-in-view terms are left
            # for the fusion but the map's own uncertainty near the vehicle, which the uniform-
            # twist gains carry into pitch and yaw. The roll stays the one relative to the road
            # at the cross-sections, which the map does not touch (their own rolls are measured
            # against the mapped surface there, whose tilt the pose takes up), and the twist
            # there is the map's plus what the cross-sections still see.
            mapped, span_sigma = self.twist_map.mean_twist(*span)
            twist += mapped
            response = np.zeros((3, 2))
            _, near_sigma = self.twist_map.mean_twist(0.0, lookahead)
            # the map's uncertainty through the outputs' response to a twist here and ahead
            k = _TWIST_MAP_SIGMA_SCALE
            if model.linear is not None:
                sens = np.abs(self._twist_response(model, H, x_c, zeta, x_mean, py_rows, curvature_row))
                curvature_sigma = math.hypot(curvature_sigma, k * (sens[0, 0] * near_sigma + sens[0, 1] * span_sigma))
                s_pitch = math.hypot(s_pitch, k * (sens[1, 0] * near_sigma + sens[1, 1] * span_sigma))
                s_yaw = math.hypot(s_yaw, k * (sens[2, 0] * near_sigma + sens[2, 1] * span_sigma))
            else:                     # the uniform twist's gains
                s_pitch = math.hypot(s_pitch, k * abs(centres[0] + centres[1]) * near_sigma)
                s_yaw = math.hypot(s_yaw, k * abs(centres[0] * centres[1] / H) * near_sigma)
            bank_change_L = float(tw.bank_change(lookahead)[0])
            roll = roll - bank_change_L
        else:
            response = np.full((3, 2), math.nan)
            if o.refine_iterations > 0 and model.linear is not None:
                response = self._twist_response(model, H, x_c, zeta, x_mean, py_rows, curvature_row)
        per_zeta = math.nan
        # only where the pose was solved with zeta free: held (far from the pose: single frames
        # seeded from elsewhere, large steps) the pitch took up the curvature the fit left out
        if o.refine_iterations > 0 and model.linear is not None and model.i_dzeta >= 0 \
                and not math.isfinite(model.zeta_free_sigma) and not held_last:
            per_zeta = self._sag_change_response(model, py_rows[0])
        zeta_sigma = model.zeta_free_sigma if math.isfinite(model.zeta_free_sigma) else model.sigma_dzeta
        lateral = -float(cam_off[1]) - 0.5 * (centres[0] + centres[1])
        spacing = abs(centres[0] - centres[1]) / (n_lines - 1)
        # Eq. (14) as printed, with the fit residual as dp (BEV px) and the width tolerance as dw.
        g = bev.grid
        bound = roll_bound_eq14(g.width, g.y_max_m - g.y_min_m, self.mount.height_m,
                                o.marker_width_tolerance_m, rms_px)
        if dbg is not None:
            dbg.vp_px = (float(vp[0]), float(vp[1]))
            dbg.R_o_from_cp = R_cp
            dbg.height_m = H
            dbg.model = model
        reason = ""
        valid = True
        if not all(math.isfinite(v) for v in (roll, pitch, yaw, s_roll, s_pitch, s_yaw)):
            valid, reason = False, "non-finite result"
        elif abs(roll) > math.radians(65) or abs(pitch) > math.radians(25) or abs(yaw) > math.radians(45):
            valid, reason = False, "attitude out of range (roll 65, pitch 25, yaw 45 deg)"
        else:
            reason = self._implausible(model, n_lines, spacing)
            valid = not reason
        return VisionEstimate(
            roll, pitch, yaw, s_roll, s_pitch, s_yaw, valid,
            curvature_1_m=curvature, curvature_sigma_1_m=curvature_sigma,
            vertical_curvature_1_m=zeta, vertical_curvature_sigma_1_m=zeta_sigma,
            roll_lookahead_m=lookahead, lateral_offset_m=lateral,
            pitch_per_twist_m=0.0 if twisted else centres[0] + centres[1],
            yaw_per_twist_m=0.0 if twisted else centres[0] * centres[1] / H,
            road_twist_rad_m=twist, road_twist_sigma_rad_m=twist_sigma,
            twist_response=tuple(map(float, response.ravel())),
            pitch_per_vertical_curvature_m=per_zeta, yaw_per_curvature_m=yaw_per_curvature,
            road_twist_span_m=span if use_eq10 else (),
            road_axis=tuple(map(float, _centre_axis(model))) if n_lines == 3 else (),
            road_twist_used=bank_change_L,
            line_spacing_m=spacing, line_offsets_m=offsets,
            camera_xyz_rad=(float(phi), float(theta), float(psi)), vp_px=(float(vp[0]), float(vp[1])),
            n_lines=n_lines, roll_equation="eq10" if use_eq10 else "eq8", edge_rms_px=rms_px,
            n_edge_points=n_points, iterations=iterations, warps=warps, roll_bound_eq14_rad=bound,
            method=o.method, reason=reason, debug=dbg)

    # ---- pieces ----

    def _pose_update(self, model: LaneModel, dmodel: LaneModel, R, H: float, x0: float, zeta: float,
                     use_eq10: bool, ratio: float):
        """One refinement step from a lane model fitted at pose ``R``: ``(delta_roll, psi1, theta1,
        zeta, cross-sections)``, or the reason why not (a string)."""
        # The two outer lines, as the paper (section V.B): the dashed centre line, seen in
        # pieces, adds more error than information to the direction.
        d = lane_direction(dmodel, H, lines=[0, dmodel.n_lines - 1], x0_m=x0)
        if d is None:
            return "no lane direction (vanishing point)"
        psi_new, theta_new = yaw_pitch_from_r3(R.T @ d)
        x_rows = self._cross_x(model)
        if x_rows is None:
            return "the lines do not overlap along the road"
        zeta_new = float(min(max(zeta + model.dzeta, -_ZETA_MAX), _ZETA_MAX))      # np.clip of a number
        alphas, coef = self._model_alphas(model, x_rows, use_eq10, ratio, _heights(x_rows, H, x0, zeta_new))
        delta = self._solve_roll(alphas, coef)
        return delta, psi_new, theta_new, zeta_new, x_rows

    def _implausible(self, model: LaneModel, n_lines: int, spacing: float) -> str:
        """Why the lines found do not look like the road's markings at this pose ("" if they do):
        each marker's width on the road within half to twice the configured one, and the lines
        0.5 to 3 lane widths apart. A curb or a rail taken for a line, or eq. (8) balancing two
        markers of different widths at an absurd roll, shows up here."""
        road = self.road
        expected = [road.marker_widths_m[0], road.marker_widths_m[1], road.marker_widths_m[2]]
        which = [0, 2] if n_lines == 2 else [0, 1, 2]
        for j, k in enumerate(which):
            w = float(model.a[2 * j] - model.a[2 * j + 1])
            if not 0.5 * expected[k] <= w <= 2.0 * expected[k]:
                return (f"line {j + 1} of {n_lines} is {100 * w:.0f} cm wide on the road, "
                        f"expected {100 * expected[k]:.0f} cm")
        if not 0.5 * road.lane_width_m <= spacing <= 3.0 * road.lane_width_m:
            return f"lines {spacing:.2f} m apart, expected 0.5 to 3 lane widths ({road.lane_width_m:g} m)"
        return ""

    def _solve_roll(self, alphas: np.ndarray, coef: np.ndarray, seed: float = 0.0) -> float:
        if self.options.solver == "numeric":
            return solve_numeric(alphas, coef, seed)
        a = np.atleast_2d(alphas)
        return float(np.mean([solve_pade(row, coef, seed) for row in a]))

    def _bev_cross_rows(self, lines: list[Marker]):
        """BEV rows of the cross-sections: one at the farthest of the edges' near ends (the
        paper, section IV.E), or several over the rows all lines cover."""
        v_hi = min(m.v_near for m in lines)
        v_lo = max(m.v_far for m in lines)
        if v_hi <= v_lo:
            return None
        n = self.options.cross_sections
        if n == 1:
            return np.array([v_hi])
        return np.linspace(v_hi, v_lo, n + 2)[1:-1]

    def _bev_alphas(self, bev, lines, vs, use_eq10, ratio, f_vx):
        """Eq. (9): ``alpha = atan2(p, f_vx)``, ``p`` the BEV column from the nadir, positive left."""
        cols = [m.u_at(vs) for m in lines]
        if use_eq10:
            p = np.stack([bev.u0 - 0.5 * (ul + ur) for ul, ur in cols], axis=-1)
            return np.arctan2(p, f_vx), coefficients_eq10()
        (al, ar), (bl, br) = cols[0], cols[-1]
        p = np.stack([bev.u0 - al, bev.u0 - ar, bev.u0 - bl, bev.u0 - br], axis=-1)
        return np.arctan2(p, f_vx), coefficients_eq8(ratio)

    def _model(self, edges: list[_Edge], R, H, deg, grid: BevGrid, select: bool = True, zeta: float | None = None,
               x0: float = 0.0, zeta_prior: tuple[float, float] = (0.0, math.inf),
               twist: RoadTwist | None = None) -> LaneModel:
        """Lane model of the edges projected onto the road at pose ``R``, height ``H``; with
        ``zeta`` (not None), onto the surface of that vertical curvature, fitting its correction
        with the prior ``zeta_prior = (mean, sigma)`` (1/m); with ``twist``, onto the road turning
        about its centre line (:mod:`vision.twistmap`)."""
        rays, bounds, steps, edge_lines, edge_sides = _stack_edges(edges)
        z = 0.0 if zeta is None else zeta
        x, y = ground_from_rays(rays, R, H, z, x0, twist)
        from_image = edges[0].from_image
        if from_image:
            # Metres of lateral position per pixel along each cut (the measurement's direction).
            _, y2 = ground_from_rays(rays + steps, R, H, z, x0, twist)
            q_all = np.abs(y2 - y)
        reach = self.options.fit_range_m if twist is None else min(self.options.fit_range_m,
                                                                    self.options.road_twist_fit_range_m)
        ok, counts = _in_range(x, bounds, 0.5, reach)   # NaN (above the horizon) is out
        if counts.min() < 3:
            raise VisionError("an edge lies above the horizon at this pose")
        # BEV rows far away re-sample image rows (f_y H / x^2 rows per metre against 1 / dx);
        # cuts in the image are one per image row or column.
        independent = math.inf if from_image else self.camera.fy * H * grid.dx_m
        model = fit_lane_model_points(x[ok], y[ok], counts, edge_lines, edge_sides, deg,
                                      independent, q=q_all[ok] if from_image else None, select=select,
                                      sag=None if zeta is None else (H, x0, z))
        if zeta is not None:
            model = model.with_dzeta_prior(zeta_prior[0] - z, zeta_prior[1])
            t = self.options.vertical_curvature_t_min
            if abs(z + model.dzeta) < t * model.sigma_dzeta:
                # Not significant: the road is taken as its tangent plane (the fit conditioned on
                # zeta = 0); a free zeta would only add its noise to pitch and yaw.
                model = model.held_at(-z)
                model.zeta_free_sigma = model.zeta_hold[1]
        return model

    @staticmethod
    def _twist_response(model: LaneModel, H: float, x0: float, zeta: float, x_ahead_m: float, py_rows,
                        curvature_row) -> np.ndarray:
        """How the outputs respond to the road twisting in view: ``(3, 2)``, rows curvature
        (1/m per rad/m), pitch and yaw (rad per rad/m), columns the twist at the contact point
        and at ``x_ahead_m`` (the cross-sections), the twist ``tau(x) = d bank / dx`` linear
        between them and constant beyond. In a superelevation runoff ahead the twist changes
        across the view, and a lane model fitted on a single surface reads that change as
        curvature and the lines' tangents (a uniform twist only moves the tangents,
        ``pitch_per_twist_m``, ``yaw_per_twist_m``).

        The road turns about its centre (the middle line of three, else midway between two).
        With ``b(x)`` the bank change ahead of the contact point ``x0`` (``u = x - x0``), a
        point at lateral position ``y`` lies ``dz = (y - y_c(x)) b(x) + y_c(x0) tau(x0) u`` above
        the tangent plane (the last term keeps the plane tangent at the vehicle); projected
        onto the estimator's surface it appears displaced by ``(y - x y') dz / D``, the
        vertical-curvature column's lever (:mod:`vision.lanemodel`). The lane model's linear
        response to its points so displaced (:meth:`vision.lanemodel.LaneModel.linear_response`,
        the fit's weights held), through the outputs' first-order rows, gives the response for
        the two profiles ``tau = 1 - u / u_L`` and ``tau = u / u_L`` up to ``u_L`` (0 and 1
        beyond). On the simulator's runoffs, with the true
        twists, it takes the curvature error near runoffs from 1.90 / 3.36 / 0.59 to 1.35 / 1.36 /
        0.33e-3 1/m, the yaw error from 1.07 / 1.16 / 0.81 to 0.52 / 0.46 / 0.16 deg and the pitch
        error from 0.40 / 0.35 / 0.38 to 0.14 / 0.11 / 0.09 deg RMS on the three HD drives (the
        uniform model: yaw 0.53 / 0.87 / 0.28, pitch 0.15 / 0.13 / 0.13; the same with the
        vision's own twist ahead). About 0.35 ms a frame; refitting the lane model to displaced
        points instead (which also re-derives the lines' concentric scale) gave the same gains
        within 1-3 % (median, up to 15 % on single frames in curves) at 0.85 ms."""
        x, y, k_of = model.linear[0], model.linear[1], model.linear[2]
        J = model.n_lines
        j_of = model.edge_line[k_of]
        if model.c.size <= 2:
            slope = _line_slopes(x, j_of, model.b, model.line_scale, model.c)
        else:
            slope = np.empty_like(x)
            for j in range(J):
                sel = j_of == j
                slope[sel] = model.slope(j, x[sel])
        # the road turns about its centre: the middle line of three, else midway between two
        mid = [1] if J == 3 else [0, J - 1]
        shape, shape0 = model._shape(x), model._shape(x0)        # common to the lines' edges
        pivot = _mean_rows([0.5 * (model.y(2 * j, x, shape) + model.y(2 * j + 1, x, shape)) for j in mid])
        pivot0 = float(_mean_rows([0.5 * (model.y(2 * j, x0, shape0) + model.y(2 * j + 1, x0, shape0)) for j in mid]))
        xl = max(x_ahead_m - x0, 1.0)
        # the points' lateral moves per rad/m of the two twist profiles (:func:`_twist_moves`)
        moves = _twist_moves(x, y, slope, pivot, float(pivot0), float(x0), float(H), float(zeta), float(xl))
        # first-order rows of the outputs in the lane model's parameters (``py_rows``: the
        # vehicle's pitch and yaw, :func:`_pitch_yaw_rows`)
        rows = np.zeros((3, model.cov.shape[0]))
        if model.c.size:
            rows[0] = curvature_row       # the outer lines' mean, as the curvature's sigma takes it
        rows[1], rows[2] = py_rows
        out = np.zeros((3, 2))
        for col in range(2):
            out[:, col] = rows @ model.linear_response(moves[col])
        return out

    @staticmethod
    def _sag_change_response(model: LaneModel, pitch_row) -> float:
        """How the pitch errs where the road's vertical curvature changes across the view: rad
        per 1/m of the fitted ``zeta`` beyond the vertical curvature at the vehicle, i.e. metres
        (``pitch_per_vertical_curvature_m``). A single quadratic surface fitted to a view whose
        curvature changes reads the change as pitch. The profile: a height ``zeta' u^3 / 6``
        over the estimator's surface (``u = x - x0``: the curvature grows linearly ahead from 0
        at the vehicle), which moves each point laterally by ``u / 3`` times the fit's own
        vertical-curvature column (``u^2 / (2 D) (y - x y')`` per unit of ``zeta``,
        :mod:`vision.lanemodel`; the height ``u^3 / 6`` is ``u / 3`` times ``u^2 / 2``), the fit's linear response without the prior from the
        previous frame: the ratio of the free fit's pitch and ``zeta`` responses (the prior
        holds ``zeta`` where the frames before saw it, which on a steady change is where a free
        fit puts it). On the HD hill drive it is -5.1 to -6.6 m (median -5.3); against the
        truth, the vision's pitch error regresses on the fitted ``zeta`` minus the vehicle's
        with -5.9 m, and the correction takes it from 0.045 to 0.022 deg RMS (notes, ninth
        session). The yaw's response from the same profile (+4 m in the first sag, +1 m in the
        median over the drive) is not reported: modelled like the pitch it made the fused yaw
        worse on every benchmark drive (notes)."""
        u = model.linear[0] - model.sag[1]
        dp = model.linear_response(np.where(u > 0, u / 3.0 * model.linear[4], 0.0), priors=False)
        r_zeta = float(dp[model.i_dzeta])
        if not abs(r_zeta) > 0:
            return math.nan
        return float(pitch_row @ dp) / r_zeta

    def _cross_x(self, model: LaneModel):
        """Cross-sections along the road: one at the farthest of the edges' near ends (the
        paper, section IV.E), or several over the range every edge covers."""
        n = self.options.cross_sections
        x_lo = float(model.x_min.max())
        x_hi = float(model.x_max.min())
        if x_hi <= x_lo:
            if n == 1 or self.options.refine_iterations == 0:
                return None
            # No range where every line was seen (a dash far ahead, a line close by): the
            # lines share the road's shape in the model, so cross the gap between them.
            x_lo, x_hi = x_hi, x_lo
        if n == 1:
            return np.array([x_lo])
        return np.arange(1, n + 1) * ((x_hi - x_lo) / (n + 1)) + x_lo     # linspace's interior, as it computes it

    def _model_alphas(self, model: LaneModel, xs, use_eq10, ratio, heights):
        """Angles of the edges (eq. (8)) or line centres (eq. (10)) from the nadir at the
        cross-sections ``xs``: ``atan(y / H(x))``, ``H(x)`` the camera's height above the road
        there (:func:`_heights`; the angle of a ray does not depend on the surface it meets,
        only the cross-section does)."""
        J = model.n_lines
        h = np.asarray(heights, float).reshape(-1, 1)
        if use_eq10:
            Y = model.y_edges(np.arange(6), xs)
            p = 0.5 * (Y[0::2] + Y[1::2])
            return np.arctan(p.T / h), coefficients_eq10()
        j1 = J - 1
        Y = model.y_edges([0, 1, 2 * j1, 2 * j1 + 1], xs)
        return np.arctan(Y.T / h), coefficients_eq8(ratio)

    @staticmethod
    def _camera_covariance(model: LaneModel, roll_rows, dir_rows, sig_f):
        """3x3 covariance of the camera's XYZ ``(phi1, theta1, psi1)`` from the lane model's
        covariance, first order: the root of eqs. (8)/(10) at the cross-sections (implicit
        function: ``d phi = -sum c_k sec^2(alpha_k) d alpha_k / sum c_k sec^2(alpha_k)``, all rows
        and their correlations through the model), and the lane direction of the two outer lines
        (central differences of :func:`lane_direction` in ``y_j(x0)``, ``y_j'(x0)``).
        ``roll_rows``: :func:`_roll_rows` at the cross-sections; ``dir_rows``:
        :func:`_direction_rows`; ``sig_f``: the painted widths' tolerance as an error of eq. (8),
        rad."""
        P = model.cov.shape[0]
        alphas, coef, d_alpha = roll_rows
        q = 1.0 / np.cos(alphas) ** 2
        cq = coef[None, :] * q
        total = cq.sum()
        row_phi = -np.einsum("rg,rgp->p", cq, d_alpha) / total if total != 0 else np.full(P, np.inf)
        # ---- pitch and yaw: the lane direction of the outer lines (dir_rows: psi, theta) ----
        Jc = np.stack([row_phi, dir_rows[1], dir_rows[0]])       # phi, theta, psi
        cov = Jc @ model.cov @ Jc.T
        cov[0, 0] += sig_f**2
        held = model.zeta_consider_cov()
        if held is not None:
            # zeta held: the error that leaves in it moves the pose as it moves the parameters
            cov += Jc @ held @ Jc.T
        return cov

    @staticmethod
    def _yaw_per_curvature(model: LaneModel, yaw_row, curvature_row) -> float:
        """The yaw's error per 1/m of the curvature's, as the lane fit couples them:
        ``cov(yaw, kappa) / var(kappa)`` from the lane model's covariance (m; NaN where the fit
        has no curvature). ``yaw_row``, ``curvature_row``: their first-order rows."""
        if curvature_row is None or not model.c.size:
            return math.nan
        ck = model.cov @ curvature_row
        var = float(curvature_row @ ck)
        if not var > 0.0:
            return math.nan
        return float(yaw_row @ ck) / var

    def _curvature_sigma(self, model: LaneModel, curvature: float, row) -> float:
        """1-sigma of the reported curvature: the lane model's covariance (vertical curvature
        included; ``row``: the curvature's first-order row in the model's parameters, the mean
        of the outer lines' rows of :meth:`LaneModel.curvature_and_row`) and the model terms of
        :data:`CURVATURE_MODEL_SIGMA`.

        Where the fit chose straight lines (no shape term significant) this is 0 +- 0: the sigma
        given that choice, not the curvature's (the fusion floors it at 3e-4 1/m). Tried
        (2026-11-26, docs/fusion-notes.md): 0 with the full shape's sigma, and the full shape's
        curvature with its sigma. Both moved the right-hand 7 deg drive's fused yaw from 0.089
        to 0.125 deg (over issue 5's 0.1): at its curve entry the straight frames' curvature
        and yaw errors cancel in the filter, and a different curvature there breaks that."""
        if not model.c.size:
            fit = 0.0
        else:
            fit = float(row @ model.cov @ row)
        floor, rel = CURVATURE_MODEL_SIGMA
        return math.sqrt(max(fit, 0.0) + floor**2 + (rel * curvature) ** 2)

    def _vp_image_lines(self, bev: Bev, lines: list[Marker]):
        """The paper's vanishing point: a straight line through each marker's centre in the
        image (total least squares), intersected."""
        homs = []
        segs = []
        for m in lines:
            k = m.inliers
            uc = 0.5 * (m.u_left[k] + m.u_right[k])
            pts = np.stack([uc, m.v[k], np.ones(uc.size)], axis=-1) @ bev.image_from_bev.T
            xy = pts[:, :2] / pts[:, 2:3]
            c = xy.mean(axis=0)
            _, _, vt = np.linalg.svd(xy - c, full_matrices=False)
            d = vt[0]
            n = np.array([-d[1], d[0]])
            homs.append(np.array([n[0], n[1], -n @ c]))
            t = (xy - c) @ d
            segs.append((c + t.min() * d, c + t.max() * d))
        p = intersect_lines(np.asarray(homs))
        if abs(p[2]) < 1e-12:
            raise VisionError("lane lines parallel in the image: no vanishing point")
        return p[:2] / p[2], segs


def _mean(a: np.ndarray):
    """``np.mean`` of a float array without its dispatch: the same sum (``np.add.reduce``) over
    the same count (8 us a call less; called a dozen times a frame)."""
    return np.add.reduce(a) / a.size


def _mean_rows(rows: list):
    """``np.mean(rows, axis=0)`` of one or two arrays (or numbers) of one shape: the first plus
    the second, over their number, as numpy's reduction adds them (without building the array)."""
    if len(rows) == 1:
        return rows[0] / 1
    if len(rows) == 2:
        return (rows[0] + rows[1]) / 2
    return np.mean(rows, axis=0)


_STACK_CACHE: dict = {}


def _stack_edges(edges: list[_Edge], rays: np.ndarray | None = None):
    """All edges' rays in one array, the bounds of each, the cut steps, and each edge's line and
    side (cached per list). ``rays``: the edges' rays already in one array, edge after edge (the
    caller's, when it sliced the edges from it: no copy)."""
    key = id(edges)
    hit = _STACK_CACHE.get(key)
    if hit is not None and hit[0] is edges:
        return hit[1]
    if rays is None:
        rays = np.concatenate([e.rays for e in edges])
    bounds = np.cumsum([0] + [e.rays.shape[0] for e in edges])
    steps = np.concatenate([e.cut_step for e in edges]) if edges[0].from_image else None
    lines = np.array([e.line for e in edges], np.int64)
    sides = np.array([e.side for e in edges], np.int64)
    _STACK_CACHE.clear()
    _STACK_CACHE[key] = (edges, (rays, bounds, steps, lines, sides))
    return rays, bounds, steps, lines, sides


@nb.njit(cache=True)
def _in_range(x, bounds, lo, hi):  # pragma: no cover (numba)
    """Points with ``lo < x < hi`` (False for NaN), and how many of each edge's (``bounds``)."""
    ok = np.empty(x.size, np.bool_)
    counts = np.zeros(bounds.size - 1, np.int64)
    for k in range(bounds.size - 1):
        for i in range(bounds[k], bounds[k + 1]):
            ok[i] = x[i] > lo and x[i] < hi
            counts[k] += ok[i]
    return ok, counts


def _vehicle_sigmas(J_vehicle: np.ndarray, cov_cam: np.ndarray) -> tuple[float, float, float]:
    """The 1-sigma of the vehicle's ZYX angles from the covariance of the camera's XYZ angles,
    through :func:`_vehicle_jacobian` (eq. (22), first order)."""
    cov = J_vehicle @ cov_cam @ J_vehicle.T
    return tuple(math.sqrt(max(float(cov[i, i]), 0.0)) for i in range(3))


@nb.njit(cache=True)
def _line_slopes(x, j_of, b, line_scale, c):  # pragma: no cover (numba)
    """``model.slope(j_of[i], x[i])`` of each point (:meth:`LaneModel.slope`, up to two shape
    terms), with numpy's operations in numpy's order (``x ** 1`` is ``x``, ``x ** 2`` is
    ``x * x`` for arrays): one call instead of a mask and four array operations per line."""
    out = np.empty(x.size)
    for i in range(x.size):
        t = x[i] / 10.0
        d = 0.0
        for k in range(c.size):
            p = k + 2
            d = d + c[k] * p * (t if p == 2 else t * t) / 10.0
        j = j_of[i]
        out[i] = b[j] + line_scale[j] * d
    return out


@nb.njit(cache=True)
def _twist_moves(x, y, slope, pivot, pivot0, x0, H, zeta, xl):  # pragma: no cover (numba)
    """The lateral moves ``(2, n)`` of the lane fit's points per rad/m of the two twist profiles
    of :meth:`Estimator._twist_response` (the twist at the vehicle, ``tau = 1 - u / u_L``, and
    at the cross-sections, ``tau = u / u_L``): the heights over the tangent plane
    ``dz = (y - pivot) b(u) + pivot0 tau(0) u`` times the lever ``(y - x y') / D``. Each
    point's numbers as numpy computed them array by array (twenty operations of ~1000 points)."""
    n = x.size
    out = np.empty((2, n))
    for i in range(n):
        u = x[i] - x0
        lever = (y[i] - x[i] * slope[i]) / (H - 0.5 * zeta * u * u + zeta * u * x[i])    # d y_projected / d height
        if u < xl:
            db1 = u - u * u / (2 * xl)
            db2 = u * u / (2 * xl)
        else:
            db1 = 0.5 * xl
            db2 = u - 0.5 * xl
        dz1 = (y[i] - pivot[i]) * db1 + pivot0 * u           # heights over the tangent plane per rad/m
        dz2 = (y[i] - pivot[i]) * db2 + pivot0 * (0.0 * u)
        out[0, i] = dz1 * lever
        out[1, i] = dz2 * lever
    return out


def _pitch_yaw_rows(J_vehicle, dir_rows):
    """First-order rows of the vehicle's pitch and yaw in the lane model's parameters, from the
    camera's ``(psi1, theta1)`` rows (:func:`_direction_rows`) through :func:`_vehicle_jacobian`."""
    return (J_vehicle[1, 1] * dir_rows[1] + J_vehicle[1, 2] * dir_rows[0],
            J_vehicle[2, 1] * dir_rows[1] + J_vehicle[2, 2] * dir_rows[0])


@nb.njit(cache=True)
def _vehicle_jacobian(phi, theta, psi, tilt):  # pragma: no cover (numba)
    """``d(vehicle roll, pitch, yaw) / d(camera phi, theta, psi)`` (central differences of eq. (22))."""
    e = 1e-6
    J = np.empty((3, 3))
    for k in range(3):
        ang = np.array([phi, theta, psi])
        ang[k] += e
        rp = rpy_from_camera_xyz_scalar(ang[0], ang[1], ang[2], tilt)
        ang[k] -= 2.0 * e
        rm = rpy_from_camera_xyz_scalar(ang[0], ang[1], ang[2], tilt)
        for i in range(3):
            J[i, k] = (rp[i] - rm[i]) / (2.0 * e)
    return J


@nb.njit(cache=True)
def _yaw_pitch_two_lines(D, H, x0, R_o_from_cp):  # pragma: no cover (numba)
    """``(psi1, theta1)`` rows for rows ``(y_L, b_L, y_R, b_R)`` of ``D`` (n, 4): :func:`lane_direction`
    of two lines, for each row (for the covariance). Compiled: it runs once a frame."""
    out = np.empty((D.shape[0], 2))
    for i in range(D.shape[0]):
        a0, a1, a2 = H * D[i, 1], -H, x0 * D[i, 1] - D[i, 0]
        b0, b1, b2 = H * D[i, 3], -H, x0 * D[i, 3] - D[i, 2]
        d0, d1, d2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
        s = (-1.0 if d0 < 0 else 1.0) / math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        d0, d1, d2 = d0 * s, d1 * s, d2 * s
        r0 = d0 * R_o_from_cp[0, 0] + d1 * R_o_from_cp[1, 0] + d2 * R_o_from_cp[2, 0]    # R^T d
        r1 = d0 * R_o_from_cp[0, 1] + d1 * R_o_from_cp[1, 1] + d2 * R_o_from_cp[2, 1]
        r2 = d0 * R_o_from_cp[0, 2] + d1 * R_o_from_cp[1, 2] + d2 * R_o_from_cp[2, 2]
        out[i, 0] = math.atan2(r0, r2)
        out[i, 1] = -math.asin(min(1.0, max(-1.0, r1)))
    return out


def _heights(xs, H: float, x0: float, zeta: float) -> np.ndarray:
    """Camera height above the road at ``xs`` (m ahead of the nadir): ``H - zeta (x - x0)^2 / 2``."""
    xs = np.asarray(xs, float)
    return H - 0.5 * zeta * (xs - x0) ** 2


def _direction_rows(model: LaneModel, H: float, x0: float, R) -> np.ndarray:
    """First-order rows ``(2, P)`` of the camera's ``(psi1, theta1)`` from the lane direction of
    the outer lines at ``x0`` (:func:`vision.lanemodel.lane_direction`), in the lane model's
    parameters (central differences of :func:`_yaw_pitch_two_lines` in ``y_j(x0)``, ``y_j'(x0)``)."""
    J = model.n_lines
    M = np.zeros((4, model.cov.shape[0]))
    vals = np.zeros(4)
    for n, j in enumerate((0, J - 1)):
        ks = np.flatnonzero(model.edge_line == j)
        y_j, rows_j = model.mean_y_and_rows(ks, x0)
        M[2 * n], vals[2 * n] = rows_j[0], y_j[0]
        M[2 * n + 1] = model.slope_row(j, x0)
        vals[2 * n + 1] = float(model.slope(j, x0))
    D = _DIR_STEPS + vals                                     # (8, 4)
    yp = _yaw_pitch_two_lines(D, H, x0, R)                   # (8, 2): psi, theta
    J_yp = ((yp[:4] - yp[4:]) / _DIR_SPANS).T                # (2, 4)
    return J_yp @ M


#: :func:`_direction_rows`' steps in ``(y_L, b_L, y_R, b_R)`` (m, rad): the rows of ``+e`` then
#: ``-e``, and the central differences' spans ``2 e`` (constants, made once).
_DIR_STEP = np.array([1e-4, 1e-6, 1e-4, 1e-6])
_DIR_STEPS = np.concatenate([np.diag(_DIR_STEP), -np.diag(_DIR_STEP)])
_DIR_SPANS = 2.0 * _DIR_STEP[:, None]


def _roll_rows(model: LaneModel, xs, use_eq10: bool, ratio: float, heights, x0: float):
    """The roll equation's angles at the cross-sections ``xs`` (eq. (8): the outer lines'
    edges; eq. (10): the three lines' centres), ``(n_x, G)``, its coefficients and the angles'
    derivatives with respect to the lane model's parameters ``(n_x, G, P)``."""
    J = model.n_lines
    P = model.cov.shape[0]
    xs = np.asarray(xs, float)
    h = np.asarray(heights, float)
    if use_eq10:
        groups = [(2 * j, 2 * j + 1) for j in range(3)]
        coef = coefficients_eq10()
    else:
        j1 = J - 1
        groups = [(0,), (1,), (2 * j1,), (2 * j1 + 1,)]
        coef = coefficients_eq8(ratio)
    u2 = (xs - x0) ** 2 / 2.0
    d_alpha = np.zeros((xs.size, len(groups), P))
    alphas = np.zeros((xs.size, len(groups)))
    for g, ks in enumerate(groups):
        y, rows = model.mean_y_and_rows(ks, xs)                        # (n_x,), (n_x, P)
        den = h * h + y * y
        d_alpha[:, g, :] = rows * (h / den)[:, None]
        if model.has_sag:
            d_alpha[:, g, model.i_dzeta] += y * u2 / den              # through H(x)
        alphas[:, g] = np.arctan(y / h)
    return alphas, coef, d_alpha


def _road_twist(model: LaneModel, xs, roll_rows, use_eq10: bool) -> tuple[float, float]:
    """The road's twist over the cross-sections ``xs``, rad/m, and its 1-sigma (``roll_rows``:
    :func:`_roll_rows` there).

    Three lines (eq. (10)): each cross-section's roll equation, solved on its own, gives the
    camera's roll relative to the road there, ``phi - b(x)`` (``b(x)`` the bank change ahead, :mod:`vision.roll`):
    one Newton step from the current pose, ``delta(x) = sum c tan(alpha) / sum c sec^2(alpha)``
    (the pose has converged on their mean, so each ``delta`` is small). Its least-squares slope
    over ``x`` is ``db/dx``; the 1-sigma is the lane model's covariance through the same
    implicit-function rows as the roll's (:meth:`Estimator._camera_covariance`). The rows share
    the lane model, so neighbouring cross-sections are not independent: only the slope over
    their span is used, not the scatter about it. What it reads is the lanes' widths changing
    unequally along the road, in the model the part of the three lines' slopes that grows with
    the square of their lateral position (a twist lifts the outer lane's far side by its
    distance from the pivot, and the projection moves it out by its lateral position times
    the height over ``H``). With two lines (eq. (8)) the model keeps each marker's width
    constant along the road and the equation has no twist in it: NaN.

    Sign: the bank here is that of :mod:`vision.frames` (the left edge raised), so that on the
    simulator's runoffs ``delta(x)`` grows with ``x`` exactly as the true ``b(x)`` does
    (measured on the right-hand 7 deg drive: 0.17 deg/m against a true 0.17 where the runoff
    fills the view, 0.004 deg/m RMS on steady road)."""
    xs = np.asarray(xs, float)
    if not use_eq10 or xs.size < 2 or float(xs.max() - xs.min()) < TWIST_MIN_SPAN_M:
        return math.nan, math.nan
    if xs.min() < model.x_min.max() - 1e-6 or xs.max() > model.x_max.min() + 1e-6:
        return math.nan, math.nan       # cross-sections across a gap: some line only extrapolated
    alphas, coef, d_alpha = roll_rows
    cq = coef[None, :] * (1.0 / np.cos(alphas) ** 2)
    den = cq.sum(axis=1)                                             # (n_x,)
    if np.any(den == 0):
        return math.nan, math.nan
    delta = (coef[None, :] * np.tan(alphas)).sum(axis=1) / den
    rows = np.einsum("rg,rgp->rp", cq, d_alpha) / den[:, None]       # d delta_r / d p
    w = xs - _mean(xs)
    w = w / float(w @ w)
    row = w @ rows
    return float(w @ delta), float(math.sqrt(max(float(row @ model.cov @ row), 0.0)))


def _centre_axis(model: LaneModel) -> np.ndarray:
    """The middle line of three as :class:`vision.ipm.RoadTwist` takes it: ``(a, b, s, c2, c3)``."""
    a = float(_mean(model.a[model.edge_line == 1]))
    c = np.zeros(2)
    c[:model.c.size] = model.c[:2]
    return np.array([a, float(model.b[1]), float(model.line_scale[1]), c[0], c[1]])


def _seed_rpy(seed):
    if seed is None:
        return None
    if isinstance(seed, VisionEstimate):
        if not seed.valid:
            return None
        if seed.road_twist_used:
            # the pose the frame's projection had: relative to the road under the vehicle (its
            # reported roll is the one at the cross-sections)
            return seed.rpy_rad[0] + seed.road_twist_used, seed.rpy_rad[1], seed.rpy_rad[2]
        return seed.rpy_rad
    try:
        r, p, y = (float(v) for v in seed)
    except (TypeError, ValueError):
        raise VisionError(f"seed must be a VisionEstimate or (roll, pitch, yaw) in rad, got {seed!r}") from None
    if not all(math.isfinite(v) for v in (r, p, y)):
        return None
    return r, p, y


def _sanitise(est: VisionEstimate) -> VisionEstimate:
    """A valid estimate never carries a non-finite number."""
    if est.valid:
        vals = (est.roll_rad, est.pitch_rad, est.yaw_rad, est.roll_sigma_rad, est.pitch_sigma_rad,
                est.yaw_sigma_rad, est.curvature_1_m, est.lateral_offset_m)
        if not all(math.isfinite(v) for v in vals):
            return replace(est, valid=False, reason="non-finite result",
                           roll_rad=math.nan, pitch_rad=math.nan, yaw_rad=math.nan)
    return est


def estimate(image, camera: Camera, mount: Mount, seed=None, *, road: RoadMarkings = RoadMarkings(),
             options: EstimatorOptions = EstimatorOptions()) -> VisionEstimate:
    """The vehicle's roll, pitch and yaw relative to the road from one frame.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The camera's picture (BGR as OpenCV reads it, or grey), ``uint8`` (or ``uint16``,
        float in [0, 1] or [0, 255]).
    camera : Camera
    mount : Mount
    seed : VisionEstimate or (roll, pitch, yaw) in rad, optional
        A previous estimate: only where the search starts, not needed for correctness.
    road : RoadMarkings
        Marker widths and whether a centre line is painted (three lines: eq. (10)).
    options : EstimatorOptions

    Returns
    -------
    VisionEstimate
        ``valid=False`` (with a ``reason``) for pictures without usable lane lines, of the wrong
        size, empty or with non-finite pixels; never raises for them.
    """
    return Estimator(camera, mount, road, options).estimate(image, seed)
