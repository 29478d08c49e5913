"""Options of the vision estimator and the ``[vision]`` table of a config file.

Every option that departs from Alrazouk et al. 2024 is a switch here, so that the paper's
plain method (:meth:`EstimatorOptions.paper`) and each improvement can be measured side by
side (``tools/bench_vision.py``).
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, fields, replace
from typing import Any

from .errors import VisionError

__all__ = ["EstimatorOptions", "options_from_table", "PRESETS"]


@dataclass(frozen=True)
class EstimatorOptions:
    """How :func:`vision.estimator.estimate` works.

    Method
    ------
    method : {"alrazouk", "damon2018"}
        Alrazouk et al. 2024 (roll from marker widths, pitch and yaw from the vanishing point)
        or the roll loop of Damon et al. 2018 (:mod:`vision.baseline`; roll only, pitch and yaw
        from the vanishing point of its last BEV).

    BEV (:mod:`vision.ipm`)
    -----------------------
    ipm_pose : {"seed", "nominal"}
        Pose of the first BEV: the seed's (previous frame's) roll, pitch and yaw, or the paper's
        fixed mount (roll 0, pitch = tilt, yaw 0).
    half_width_m, x_min_m, x_max_m, dx_m, dy_m :
        Region of interest and pixel size; ``None`` picks them from the camera
        (:func:`vision.ipm.default_grid`): edges measured in the BEV need about the image's
        resolution at a third of the range (1 to 4 cm) and 0.1 m rows; a BEV that only finds the
        markers for the image measurement is twice as coarse with 0.2 m rows.
    narrow_bev : bool
        With a seed that knows its lines, warp only the part of the BEV around them (1.2 m
        beyond the outer lines plus the curvature's drift), and the whole width only if a line
        is lost there. Speed only: the lines and their measurement are the same.

    Lane markers (:mod:`vision.lanes`)
    ----------------------------------
    edges : {"area", "subpixel", "binary"}
        Centroid and area of each marker's profile on each cut (blur-proof widths),
        half-level crossings, or the thresholded BEV's edge pixels (paper; BEV only).
    edge_domain : {"image", "bev"}
        Where the edges are measured: on the camera image's rows or columns (:mod:`vision.edges`;
        the BEV only finds and tracks the markers, and can be coarse), or on the BEV's rows
        (the paper).
    fit_degree : int
        Degree of the edge polynomials (2 in the paper); in the refinement, of the road shape
        common to all lines (3 follows a clothoid's curvature change).
    fit_range_m : float
        Refinement: edge points farther than this are left out of the lane model, m (the
        road's shape beyond it biases the tangent at the vehicle more than it adds).

    Roll (:mod:`vision.roll`)
    -------------------------
    roll_equation : {"auto", "eq8", "eq10"}
        ``auto``: eq. (10) when the road has a centre line and three lines are found, else eq. (8).
    solver : {"numeric", "pade"}
        Bracketed root of eq. (8)/(10), or the real root of the Pade polynomial nearest the seed.
    cross_sections : int
        1: the paper's single cross-section at the farthest of the edges' near ends; more:
        evenly spaced over the range all edges cover, solved together.
    known_widths : bool
        Use the road's (possibly unequal) marker widths in eq. (8); False assumes equal widths.
    eq21 : bool
        Treat the BEV roll as the ZYX roll and convert it with eq. (21) (the paper). The round
        trip shows that the BEV measures the XYZ roll directly (rotation about the lane axis),
        so the default is False.

    Pitch and yaw (:mod:`vision.vanishing`)
    ---------------------------------------
    vp : {"tangent", "lines"}
        ``lines``: straight lines through the markers in the image, intersected (the paper).
        ``tangent``: the tangents of the fitted lane curves at the vehicle, so that curves do not
        bias yaw and pitch.

    Refinement (beyond the paper)
    -----------------------------
    refine_iterations : int
        0: one pass (the paper). n: re-project the detected edge points with the new roll, pitch
        and yaw and solve again, n times (the same as re-warping the image with the new pose
        and measuring again, without resampling).
    rewarp_deg : float
        Warp the image again at the new pose when it is farther than this from the BEV's pose
        (any angle), up to ``max_warps`` warps in all; ``inf`` never.
    max_warps : int
    vertical_curvature : bool
        Model the road as its tangent plane at the vehicle plus a height ``zeta x^2 / 2`` ahead
        and estimate ``zeta`` with the lanes (:mod:`vision.lanemodel`): on banked curves
        (``zeta = -kappa sin(bank)``) and over crests and sags a plane biases pitch, yaw and the
        curvature. Needs ``refine_iterations > 0``; False: the road is a plane (the paper).
    vertical_curvature_sigma_1_m : float
        Prior of ``zeta`` without a previous frame: ``N(0, sigma^2)``, 1/m. Roads' crests and
        sags have radii above 1000 m, and bank times curvature stays below 1e-3 1/m (7 deg at
        125 m radius), so 1e-3 only keeps a frame whose lines hardly see ``zeta`` (two lines
        close together, a short dash) from wandering off.
    vertical_curvature_walk_1_m : float
        Prior from the previous frame's estimate: its ``zeta`` with its 1-sigma grown by this
        (1/m per frame; ``inf``: no memory). The road's ``zeta`` changes over tens of metres
        (0 to 6e-4 1/m over a 70 m bank runoff, 1e-5 per frame at 80 km/h and 30 fps).
    vertical_curvature_t_min : float
        ``zeta`` within this many sigma of 0 is set to 0 (the fit conditioned on it): on a flat
        road a free ``zeta`` only adds noise to pitch (its errors, correlated over the 40 m of
        road in view, do not average out from frame to frame). 0: always free.
    road_twist : bool
        With three lines and the distance travelled per frame (``Estimator.estimate(travel_m=)``;
        ``vifusion run`` gives it from the wheel speed), project onto the road turning about its
        centre line ahead as the frames before measured its twist (:mod:`vision.twistmap`,
        :class:`vision.ipm.RoadTwist`): a plane (or a plane with a vertical curvature) reads a
        superelevation runoff in view as degrees of roll and yaw
        (``tools/vision_surface_oracle.py``).
    road_twist_min_deg : float
        The mapped bank change within ``road_twist_fit_range_m`` ahead from which a frame is
        projected onto the twisted road (below it, the plane): on straight road the map's own
        noise would add more than the twist it removes (0.3 deg over 20 m is 0.1 deg of yaw for a
        vehicle 1.75 m off the axis).
    road_twist_fit_range_m : float
        The lane fit's reach in frames projected onto the twisted road: the map knows the road
        as far as the cross-sections measured it, 20-22 m; beyond, its twist is extrapolated.

    Uncertainty
    -----------
    marker_width_tolerance_m : float
        1-sigma difference between the painted widths (first term of eq. (14)), m.

    Baseline (:mod:`vision.baseline`)
    ---------------------------------
    damon_step_deg, damon_range_deg : float
        Roll step ``delta_phi`` and search range ``Delta_phi`` of the 2018 loop.
    """

    method: str = "alrazouk"
    ipm_pose: str = "seed"
    half_width_m: float = 8.0
    narrow_bev: bool = True
    x_min_m: float | None = None
    x_max_m: float | None = None
    dx_m: float | None = None
    dy_m: float | None = None
    edges: str = "area"
    edge_domain: str = "bev"
    fit_degree: int = 3
    fit_range_m: float = 100.0
    roll_equation: str = "auto"
    solver: str = "numeric"
    cross_sections: int = 9
    known_widths: bool = True
    eq21: bool = False
    vp: str = "tangent"
    refine_iterations: int = 2
    rewarp_deg: float = 1.0
    max_warps: int = 3
    vertical_curvature: bool = True
    vertical_curvature_sigma_1_m: float = 1e-3
    vertical_curvature_walk_1_m: float = 3e-5
    vertical_curvature_t_min: float = 3.0
    road_twist: bool = True
    road_twist_min_deg: float = 0.3
    road_twist_fit_range_m: float = 22.0
    marker_width_tolerance_m: float = 0.003
    damon_step_deg: float = 0.1
    damon_range_deg: float = 6.0

    def __post_init__(self) -> None:
        _choice("method", self.method, ("alrazouk", "damon2018"))
        _choice("ipm_pose", self.ipm_pose, ("seed", "nominal"))
        _choice("edges", self.edges, ("area", "subpixel", "binary"))
        _choice("edge_domain", self.edge_domain, ("image", "bev"))
        if self.edge_domain == "image" and self.edges == "binary":
            raise VisionError('vision option edges = "binary" needs edge_domain = "bev"')
        _choice("roll_equation", self.roll_equation, ("auto", "eq8", "eq10"))
        _choice("solver", self.solver, ("numeric", "pade"))
        _choice("vp", self.vp, ("tangent", "lines"))
        _range("fit_degree", self.fit_degree, 1, 3)
        _range("fit_range_m", self.fit_range_m, 2.0, 500.0)
        _range("cross_sections", self.cross_sections, 1, 200)
        _range("refine_iterations", self.refine_iterations, 0, 20)
        _range("max_warps", self.max_warps, 1, 10)
        _range("half_width_m", self.half_width_m, 1.0, 30.0)
        if self.x_min_m is not None:
            _range("x_min_m", self.x_min_m, 0.1, 200.0)
        if self.x_max_m is not None:   # (beyond 200 m a marker is under a pixel at any resolution)
            _range("x_max_m", self.x_max_m, 1.0, 200.0)
        if self.x_min_m is not None and self.x_max_m is not None and not self.x_min_m < self.x_max_m:
            raise VisionError(f"vision option x_min_m ({self.x_min_m}) must be below x_max_m ({self.x_max_m})")
        if self.dx_m is not None:
            _range("dx_m", self.dx_m, 0.005, 1.0)
        if self.dy_m is not None:
            _range("dy_m", self.dy_m, 0.002, 0.5)
        if not self.rewarp_deg > 0:
            raise VisionError(f"vision option rewarp_deg must be > 0 (inf: never), got {self.rewarp_deg}")
        _range("marker_width_tolerance_m", self.marker_width_tolerance_m, 0.0, 0.2)
        _range("vertical_curvature_sigma_1_m", self.vertical_curvature_sigma_1_m, 1e-6, 0.1)
        _range("vertical_curvature_t_min", self.vertical_curvature_t_min, 0.0, 100.0)
        _range("road_twist_min_deg", self.road_twist_min_deg, 0.0, 90.0)
        _range("road_twist_fit_range_m", self.road_twist_fit_range_m, 5.0, 500.0)
        if not self.vertical_curvature_walk_1_m > 0:
            raise VisionError("vision option vertical_curvature_walk_1_m must be > 0 (inf: no memory), "
                              f"got {self.vertical_curvature_walk_1_m}")
        _range("damon_step_deg", self.damon_step_deg, 1e-3, 5.0)
        _range("damon_range_deg", self.damon_range_deg, 0.1, 120.0)

    @classmethod
    def paper(cls, **changes: Any) -> "EstimatorOptions":
        """Alrazouk et al. 2024 as written: BEV at the fixed mount pose, edges of the binary
        image, degree-2 fits, one cross-section, the Pade solver, eq. (21), straight-line
        vanishing point, one pass."""
        base = cls(ipm_pose="nominal", edges="binary", edge_domain="bev", fit_degree=2, fit_range_m=500.0, cross_sections=1, solver="pade",
                   eq21=True, vp="lines", refine_iterations=0, rewarp_deg=math.inf, max_warps=1,
                   known_widths=False, vertical_curvature=False)
        return replace(base, **changes)

    @classmethod
    def damon2018(cls, **changes: Any) -> "EstimatorOptions":
        """The 2018 roll loop with ``delta_phi = 0.1 deg`` and the paper's cubic fits."""
        base = cls(method="damon2018", fit_degree=3, edges="binary", edge_domain="bev", ipm_pose="seed")
        return replace(base, **changes)


#: Named presets for the command line and the benchmark.
PRESETS = {
    "default": EstimatorOptions,
    "paper": EstimatorOptions.paper,
    "damon2018": EstimatorOptions.damon2018,
}


def _choice(key: str, value: Any, choices: tuple) -> None:
    if value not in choices:
        raise VisionError(f"vision option {key} must be one of {', '.join(map(repr, choices))}, got {value!r}")


def _range(key: str, value: Any, lo: float, hi: float) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (lo <= value <= hi):
        raise VisionError(f"vision option {key} must be a number within [{lo}, {hi}], got {value!r}")


def options_from_table(table: dict | None, source: str = "config") -> EstimatorOptions:
    """Options from the ``[vision]`` table of a config file.

    ``preset = "paper"`` (or ``"damon2018"``, ``"default"``) starts from a preset; every other
    key overrides one field of :class:`EstimatorOptions`. Unknown keys and bad values raise
    :class:`VisionError` naming ``[vision] key``.
    """
    data = dict(table or {})
    preset = data.pop("preset", "default")
    if preset not in PRESETS:
        raise VisionError(f"{source}: [vision] preset must be one of {', '.join(map(repr, PRESETS))}, got {preset!r}")
    known = {f.name: f for f in fields(EstimatorOptions)}
    changes: dict[str, Any] = {}
    for key, value in data.items():
        if key not in known:
            close = difflib.get_close_matches(key, ["preset", *known], n=1)   # as fusion.config says a typo
            raise VisionError(f"{source}: [vision] {key} is not a known key ("
                              + (f"did you mean {close[0]}? " if close else "")
                              + f"known: preset, {', '.join(sorted(known))})")
        default = getattr(EstimatorOptions(), key)
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise VisionError(f"{source}: [vision] {key} must be true or false, got {value!r}")
        elif isinstance(default, str):
            if not isinstance(value, str):
                raise VisionError(f"{source}: [vision] {key} must be a string, got {value!r}")
        elif isinstance(default, int) and not isinstance(default, bool):
            if isinstance(value, bool) or not isinstance(value, int):
                raise VisionError(f"{source}: [vision] {key} must be an integer, got {value!r}")
        else:
            if isinstance(value, str) and value.lower() in ("inf", "infinity"):
                value = math.inf
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise VisionError(f"{source}: [vision] {key} must be a number, got {value!r}")
            value = float(value)
        changes[key] = value
    try:
        return PRESETS[preset](**changes)
    except VisionError as e:
        raise VisionError(f"{source}: [vision] {str(e).replace('vision option ', '')}") from None
