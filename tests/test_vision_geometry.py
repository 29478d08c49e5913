"""Geometry of the estimator without pictures: the vanishing point (eqs. (17), (20)), the BEV's
residual rotation, and the whole solve (eqs. (8)/(10), (20)-(22)) on exact edges.

The edges are the exact BEV images of road lines seen from a known pose, so every tolerance here
is numerical (nothing is measured); the rendered round trips are in test_vision_estimator.py.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vision.camera import Camera, Mount, RoadMarkings
from vision.estimator import Estimator, _R_o_from_cp, camera_xyz_from_vehicle, vehicle_from_camera_xyz
from vision.frames import R_CS_FROM_CP, Rx, Ry, matrix_from_euler, roll_xyz_from_zyx
from vision.ipm import Bev, BevGrid, RoadTwist, ground_from_rays, pixels_from_rays
from vision.lanes import Marker, _robust_fit_pair
from vision.options import EstimatorOptions
from vision.vanishing import r3_from_vp, r3_from_yaw_pitch, vp_bounds, vp_from_r3, yaw_pitch_from_r3

CAMERA = Camera.from_fov(1280, 720, 80.0)
MOUNT = Mount(1.1, math.radians(15.0))
TWO = RoadMarkings(3.5, 0.15, False)
THREE = RoadMarkings(3.5, 0.15, True)


@settings(max_examples=200, deadline=None)
@given(psi=st.floats(-0.5, 0.5), theta=st.floats(-0.5, 0.5))
def test_vanishing_point_round_trip(psi, theta):
    """Eq. (20) and its inverse: (yaw, pitch) -> r3 -> pixel -> r3 (eq. (17)) -> (yaw, pitch)."""
    r3 = r3_from_yaw_pitch(psi, theta)
    back = yaw_pitch_from_r3(r3_from_vp(CAMERA.K, vp_from_r3(CAMERA.K, r3)))
    assert back == pytest.approx((psi, theta), abs=1e-12)


@settings(max_examples=200, deadline=None)
@given(phi=st.floats(-1.0, 1.0), theta=st.floats(-0.6, 0.6), psi=st.floats(-0.6, 0.6))
def test_lane_direction_is_r3_and_independent_of_roll(phi, theta, psi):
    """With R_o_from_cs = Rx(phi1) Ry(theta1) Rz(psi1), the road's x axis seen in cp is eq. (20)'s
    r3 = (sin psi cos theta, -sin theta, cos psi cos theta), whatever the roll phi1."""
    R_o_from_cp = matrix_from_euler("xyz", phi, theta, psi) @ R_CS_FROM_CP
    d_cp = R_o_from_cp.T @ np.array([1.0, 0.0, 0.0])
    assert d_cp == pytest.approx(r3_from_yaw_pitch(psi, theta), abs=1e-12)


def test_pitched_down_camera_sees_the_vanishing_point_above_the_centre():
    """theta = -asin(r3[1]): a camera tilted down by 15 deg has its vanishing point above the
    principal point (image y down); the error analysis' arcsin(r3(2)) would say pitched up."""
    vp = vp_from_r3(CAMERA.K, r3_from_yaw_pitch(0.0, math.radians(15.0)))
    assert vp[1] < CAMERA.cy
    assert yaw_pitch_from_r3(r3_from_vp(CAMERA.K, vp))[1] == pytest.approx(math.radians(15.0))


@settings(max_examples=100, deadline=None)
@given(phi0=st.floats(-0.6, 0.6), phi1=st.floats(-0.6, 0.6), theta=st.floats(-0.4, 0.4), psi=st.floats(-0.4, 0.4))
def test_bev_residual_is_a_roll_about_the_lane(phi0, phi1, theta, psi):
    """A BEV with the vanishing point's pitch and yaw differs from the truth by
    Q = R_assumed R_true^T = Rx(phi0 - phi1): a rotation about the lane direction."""
    Ra = matrix_from_euler("xyz", phi0, theta, psi)
    Rt = matrix_from_euler("xyz", phi1, theta, psi)
    assert Ra @ Rt.T == pytest.approx(Rx(phi0 - phi1), abs=1e-12)


def test_vp_bounds_contain_the_intersection():
    A, B, C, D = np.array([900.0, 700.0]), np.array([700.0, 300.0]), np.array([300.0, 700.0]), np.array([600.0, 300.0])
    dx, dy, vp = vp_bounds(A, B, C, D, 0.0)
    assert dx == pytest.approx(0.0, abs=1e-9) and dy == pytest.approx(0.0, abs=1e-9)
    dx1, dy1, _ = vp_bounds(A, B, C, D, 1.0)
    assert dx1 > 0 and dy1 > 0


# ---------------------------------------------------------------------------------------------
# Exact edges through the whole solve


def exact_markers(bev: Bev, R_true_o_from_cp, H_true, edges_Y, v_range=(5, 330)):
    """Markers whose edges are the exact BEV images of the road lines ``y = Y`` (m, from the
    true camera nadir) seen from the true pose. BEV pixel -> ray (assumed pose) -> true road
    point is a homography G; the line (0, 1, -Y) maps to G^T (0, 1, -Y) in the BEV."""
    G = np.diag([1.0, 1.0, -1.0 / H_true]) @ R_true_o_from_cp @ bev.R_o_from_cp.T @ bev.grid.M_h(bev.height_m)
    v = np.arange(*v_range, dtype=float)
    out = []
    for Yl, Yr in edges_Y:
        us = []
        for Y in (Yl, Yr):
            l = G.T @ np.array([0.0, 1.0, -Y])
            us.append(-(l[1] * v + l[2]) / l[0])
        m = Marker(v.copy(), us[0], us[1], 100.0)
        m.v0 = float(v.mean())
        m.fit_left, m.rms_left, kl, m.fit_right, m.rms_right, kr = _robust_fit_pair(v, us[0], us[1], 2, m.v0)
        m.inliers = kl & kr
        out.append(m)
    return out


def solve_exact(options, road, roll, pitch, yaw, bev_rpy, lines_Y):
    """Solve the exact edges of ``lines_Y`` (line centres from the contact point, m) seen with the
    vehicle attitude (roll, pitch, yaw), in a BEV built at ``bev_rpy``."""
    est = Estimator(CAMERA, MOUNT, road, options)
    true = camera_xyz_from_vehicle(roll, pitch, yaw, MOUNT.tilt_rad)
    H_t, R_o_from_v = est.height_of(*true)
    cam_y = float((R_o_from_v @ MOUNT.position_v)[1])
    w = road.marker_width_m
    edges = [(Y - cam_y + w / 2, Y - cam_y - w / 2) for Y in lines_Y]
    pose0 = camera_xyz_from_vehicle(*bev_rpy, MOUNT.tilt_rad)
    H0, _ = est.height_of(*pose0)
    grid = BevGrid(2.0, 36.0, -9.0, 9.0, 0.1, 0.02)
    bev = Bev(grid, CAMERA, _R_o_from_cp(*pose0), H0)
    markers = exact_markers(bev, _R_o_from_cp(*true), H_t, edges, (5, 330))
    return est._solve(bev, markers, pose0, H0, None, 1)


@pytest.mark.parametrize("lines_Y, road", [((5.25, -1.75), TWO), ((1.75, -1.75), TWO), ((5.25, 1.75, -1.75), THREE)])
@pytest.mark.parametrize("roll_deg, pitch_deg, yaw_deg", [(0.0, 0.0, 0.0), (12.0, 0.3, 3.0), (-25.0, -0.4, -5.0)])
def test_refinement_recovers_the_pose_from_exact_edges(lines_Y, road, roll_deg, pitch_deg, yaw_deg):
    """Default options, BEV at a seed 2 deg of roll, 0.5 deg of pitch and yaw off: the vehicle's
    roll, pitch and yaw come back to 1e-4 deg (two passes of re-projection converge; eq. (22)
    and the ZYX extraction close the loop)."""
    rpy = np.radians([roll_deg, pitch_deg, yaw_deg])
    seed = rpy + np.radians([2.0, 0.5, -0.5])
    opts = EstimatorOptions(refine_iterations=6, fit_degree=2)
    est = solve_exact(opts, road, *rpy, seed, lines_Y)
    assert est.valid, est.reason
    assert np.degrees(est.rpy_rad) == pytest.approx(np.degrees(rpy), abs=1e-4)
    assert est.roll_equation == ("eq10" if len(lines_Y) == 3 else "eq8")


def test_bev_measures_the_xyz_roll_and_eq21_is_a_slip():
    """The paper's single pass: BEV at the fixed mount (roll 0, pitch mu), vehicle leaning 20 deg
    with no pitch or yaw, so the camera's XYZ pitch is mu and its yaw 0. Eq. (8) on the BEV
    gives the XYZ roll exactly; converting it with eq. (21) as the paper does is off by
    0.63 deg (cos(mu) tan(phi) against tan(phi))."""
    roll = math.radians(20.0)
    plain = EstimatorOptions.paper(edges="area")
    no21 = solve_exact(plain.__class__(**{**plain.__dict__, "eq21": False}), TWO, roll, 0.0, 0.0, (0, 0, 0), (5.25, -1.75))
    with21 = solve_exact(plain, TWO, roll, 0.0, 0.0, (0, 0, 0), (5.25, -1.75))
    assert math.degrees(no21.roll_rad) == pytest.approx(20.0, abs=1e-3)
    slip = math.degrees(roll_xyz_from_zyx(roll, MOUNT.tilt_rad, 0.0)) - 20.0
    assert slip == pytest.approx(-0.63, abs=0.01)
    assert math.degrees(with21.roll_rad) - 20.0 == pytest.approx(slip, abs=0.01)


def test_vehicle_from_camera_is_eq22():
    """R_o_from_v = R_o_from_cs Ry(mu)^T and back."""
    rpy = np.radians([14.0, -0.7, 4.0])
    cam = camera_xyz_from_vehicle(*rpy, MOUNT.tilt_rad)
    back, R = vehicle_from_camera_xyz(*cam, MOUNT.tilt_rad)
    assert np.array(back) == pytest.approx(rpy, abs=1e-12)
    assert matrix_from_euler("xyz", *cam) @ Ry(MOUNT.tilt_rad).T == pytest.approx(R, abs=1e-12)


# ---------------------------------------------------------------------------------------------
# The road turning about its centre line (vision.ipm.RoadTwist)


def runoff_twist(axis=(1.75, 0.01, 1.0, 0.05, -0.01)):
    """A runoff ahead: no twist for 5 m, then 0.2 deg/m (a 7 deg runoff over 35 m), about a
    centre line 1.75 m to the left, slightly curved."""
    u = np.arange(0.0, 60.5, 0.5)
    b = np.radians(0.2) * np.clip(u - 5.0, 0.0, None)
    return RoadTwist(u, b, np.array(axis))


def twisted_height(tw: RoadTwist, x, y, x0):
    """The surface of the RoadTwist docstring written out here, independently of vision.ipm:
    ``h = (y - y_c(x)) tan b(x - x0) + y_c(x0) b'(0) (x - x0)``."""
    a, b1, s, c2, c3 = tw.axis
    yc = lambda X: a + b1 * X + s * (c2 * (X / 10) ** 2 + c3 * (X / 10) ** 3)  # noqa: E731
    tau0 = (tw.bank_change_rad[1] - tw.bank_change_rad[0]) / (tw.u_m[1] - tw.u_m[0])
    return (y - yc(x)) * np.tan(np.interp(x - x0, tw.u_m, tw.bank_change_rad)) + yc(x0) * tau0 * (x - x0)


def test_rays_meet_the_twisted_road_where_it_is():
    """Road points on the twisted surface (with a vertical curvature as well), seen from a
    leaning, pitched camera: the rays through them come back onto them to 1 mm, 5-40 m ahead
    and across the lanes (Newton from the plane's root; the surface there is up to 0.6 m above
    the plane, so a plane would put them metres off)."""
    tw = runoff_twist()
    R = _R_o_from_cp(*camera_xyz_from_vehicle(*np.radians([15.0, 0.4, 1.0]), MOUNT.tilt_rad))
    H, zeta, x0 = 1.2, 2e-4, 1.5
    X, Y = np.meshgrid(np.linspace(5.0, 40.0, 15), np.linspace(-5.0, 8.0, 9))
    Z = -H + 0.5 * zeta * (X - x0) ** 2 + twisted_height(tw, X, Y, x0)
    assert np.abs(Z + H).max() > 0.5
    rays = np.stack([X, Y, Z], axis=-1) @ R        # cp = R^T o, row-wise
    x, y = ground_from_rays(rays, R, H, zeta, x0, tw)
    assert x == pytest.approx(X, abs=1e-3) and y == pytest.approx(Y, abs=1e-3)
    flat_x, _ = ground_from_rays(rays, R, H, zeta, x0)
    assert np.abs(flat_x - X).max() > 1.0


def test_the_twisted_road_near_the_vehicle_turns_about_the_vehicle():
    """The tangent plane at the contact point is the road under the vehicle, whatever the axis:
    with a uniform twist tau from the contact point on, h ~ tau u y to first order, so the road
    rises by 0 under the vehicle (y = 0) and by tau u y beside it (to third order in tau u: the
    axis 1.75 m off leaves 1.75 (tan(tau u) - tau u), 3e-9 m here)."""
    tau = math.radians(0.2)
    u = np.arange(0.0, 60.5, 0.5)
    tw = RoadTwist(u, tau * u, np.array([1.75, 0.0, 0.0, 0.0, 0.0]))
    x0, du = 2.0, 0.5
    assert tw.height(x0 + du, 0.0, x0) == pytest.approx(0.0, abs=1e-8)
    assert tw.height(x0 + du, 3.0, x0) == pytest.approx(tau * du * 3.0, rel=1e-3)
    assert tw.bank_change(du)[0] == pytest.approx(tau * du, rel=1e-12)


def test_the_twisted_birds_eye_view_samples_the_surface():
    """The bird's-eye view onto the twisted surface (a per-pixel remap) takes every BEV pixel
    from the image pixel of its road point: an image whose grey value is its own column shows,
    at each BEV pixel, the column that the ray through that pixel (``rays_of_bev``) projects to,
    to 0.05 px (bilinear interpolation of a linear ramp is exact up to float32)."""
    tw = runoff_twist()
    grid = BevGrid(3.0, 36.0, -6.0, 6.0, 0.25, 0.05)     # the lanes and a margin
    R = _R_o_from_cp(*camera_xyz_from_vehicle(*np.radians([10.0, 0.3, 0.5]), MOUNT.tilt_rad))
    H, zeta, x0 = 1.1, 1e-4, 1.5
    bev = Bev(grid, CAMERA, R, H, (zeta, x0, tw))
    ramp = np.tile(np.arange(CAMERA.width, dtype=np.float32), (CAMERA.height, 1))
    img = bev.warp(ramp)
    v, u = np.mgrid[0:grid.height:7, 0:grid.width:11]
    px = pixels_from_rays(CAMERA, bev.rays_of_bev(u, v))
    inside = (px[..., 0] > 1) & (px[..., 0] < CAMERA.width - 2) & (px[..., 1] > 1) & (px[..., 1] < CAMERA.height - 2)
    assert inside.sum() > 100
    assert img[v, u][inside] == pytest.approx(px[..., 0][inside], abs=0.05)
    # and the rays of the BEV pixels meet the surface at the pixels' road points
    x, y = ground_from_rays(bev.rays_of_bev(u, v), R, H, zeta, x0, tw)
    assert x == pytest.approx(grid.x_of_row(v), abs=1e-3) and y == pytest.approx(grid.y_of_col(u), abs=1e-3)


def _lane_fit_on_the_exact_road(bank_deg: float, t_s: float = 9.0, grade_pct: float | None = None):
    """The lane model fitted to the simulator's exact marker edges on the 250 m left-hand curve of
    ``banked_curve_left_5deg`` (bank replaced by ``bank_deg``), as the estimator sees them with
    an exact surface: the edges' coordinates in the road's tangent plane at the vehicle (frame
    ``o``), 2-28 m ahead (the HD drives' reach). ``grade_pct``: the curve goes into a vertical
    curve to that grade over 300 m from 230 m on. Returns the reported curvature (the outer
    lines' mean at the contact point), the truth's (horizontal) curvature, the road's bank, its
    grade rate (rad/s, the truth's road pitch's, numerically) and the speed."""
    import sys
    import tomllib
    from pathlib import Path

    tools = str(Path(__file__).resolve().parents[1] / "tools")
    if tools not in sys.path:
        sys.path.insert(0, tools)
    from drivesim.drive import build_road
    from drivesim.scenario import parse_scenario
    from drivesim.trajectory import Trajectory

    from vision.lanemodel import fit_lane_model_points

    root = Path(__file__).resolve().parents[1]
    data = tomllib.loads((root / "configs" / "scenarios" / "banked_curve_left_5deg.toml").read_text())
    segs = data["road"]["segment"]
    for seg in segs[1:]:
        seg["bank_deg"] = bank_deg
    if grade_pct is not None:
        segs[2]["length_m"] = 100.0
        segs += [dict(length_m=300.0, curvature_1_m=0.004, bank_deg=bank_deg, grade_pct=grade_pct),
                 dict(length_m=2000.0, curvature_1_m=0.004, bank_deg=bank_deg, grade_pct=grade_pct)]
    sc = parse_scenario(data, "banked_curve")
    road = build_road(sc)
    t = np.array([t_s])
    traj = Trajectory(road, sc.motion)
    pose, truth = traj.pose(t), traj.truth(t)
    h = 1e-3
    pitch = traj.truth(np.array([t_s - h, t_s + h]))["road_pitch"]
    s0, d0 = float(pose["s"][0]), float(pose["d"][0])
    R_w_o, P0 = road.frame(np.array(s0), np.array(d0)), road.surface(np.array(s0), np.array(d0))
    xs, ys, counts, lines, sides = [], [], [], [], []
    for j, d in enumerate((3.5, 0.0, -3.5)):
        for side, dd in ((0, d + 0.075), (1, d - 0.075)):
            u = np.arange(0.0, 32.0, 0.1)
            q = (road.surface(s0 + u, np.full_like(u, dd)) - P0) @ R_w_o        # in o, exact
            keep = (q[:, 0] > 2.0) & (q[:, 0] < 28.0)
            xs.append(q[keep, 0])
            ys.append(q[keep, 1])
            counts.append(int(keep.sum()))
            lines.append(j)
            sides.append(side)
    model = fit_lane_model_points(np.concatenate(xs), np.concatenate(ys), np.array(counts), np.array(lines),
                                  np.array(sides), 3, 99.0)
    kappa = float(np.mean([model.curvature_and_row(j, 0.0)[0] for j in (0, 2)]))
    return (kappa, float(truth["curvature_1_m"][0]), float(truth["bank"][0]), float(pitch[1] - pitch[0]) / (2 * h),
            float(truth["speed_m_s"][0]))


def test_the_lane_fit_measures_the_curvature_in_the_road_plane():
    """On a banked curve the lines are circles on a cone; in the road's tangent plane, where the
    estimator fits them, their curvature is the geodesic one, ``kappa cos(bank)`` (the
    horizontal circle's curvature vector split into the plane's lateral axis and the normal, whose
    part is the vertical curvature ``-kappa sin(bank)``). The truth's ``curvature_1_m`` and the
    filter's curvature state are the horizontal curvature, so the filter models the lane fit
    with :func:`fusion.ekf._lane_plane_curvature`; taken as the horizontal one the fit read
    0.38 % low at 5 deg (1.5e-5 1/m here). The banked fit is compared with the same fit
    unbanked, which shares the polynomial's own error on an arc (its missing quartic,
    about -0.3 % at this reach): what is left is the geometry, to 1e-7 1/m (the fit's
    numerical floor on exact points is under 1e-8; 1e-7 is 0.0025 % of the curvature, a
    fifteenth of the 1.5e-5 the term is)."""
    from fusion.ekf import _lane_plane_curvature, curvature_from_lane_fit
    from fusion.noise import DIM_X, S

    flat, kappa, *_ = _lane_fit_on_the_exact_road(0.0)
    banked, kappa_b, bank, _, _ = _lane_fit_on_the_exact_road(-5.0)
    assert kappa_b == kappa == pytest.approx(0.004)
    assert bank == pytest.approx(math.radians(-5.0), abs=1e-9)
    x = np.zeros(DIM_X)
    x[S.CURVATURE], x[S.BANK], x[S.SPEED] = kappa, bank, 25.0
    predicted, per_kappa = _lane_plane_curvature(x, True)
    assert per_kappa == pytest.approx(math.cos(bank))
    # the fit's curvature as the filter predicts it (its own arc error, from the flat road, scaled)
    assert banked == pytest.approx(flat * predicted / kappa, abs=1e-7)
    # and not the horizontal curvature: the term is 15 times the tolerance
    assert abs(banked - flat) > 1.4e-5
    # the curvature state that the first frame and a re-acquisition take from the banked fit:
    # the unbanked fit's (the old code took the banked fit itself, 1.5e-5 lower)
    assert curvature_from_lane_fit(x, banked) == pytest.approx(flat, abs=1e-7)


@pytest.mark.parametrize("grade_pct", [8.0, -8.0])
def test_the_lane_plane_curvature_of_a_banked_curve_in_a_vertical_curve(grade_pct):
    """The vertical curve's part of the road plane's lane curvature, ``kv sin(bank)`` with ``kv =
    -grade_rate / v`` (:func:`fusion.ekf._lane_plane_curvature`): on the banked left-hand curve
    going into a vertical curve (8 % up or down over 300 m, 11 s in: inside it), the banked fit
    less the same fit unbanked equals the model's prediction less the curvature (-3.1e-5 1/m
    one way, +4e-7 the other, where the grade rate's sign decides; 2e-7 between fit and model
    measured, a review's script), to 1e-6 1/m: a tenth of the ``kv sin(bank)`` term (3e-5), so a
    sign slip in it fails."""
    from fusion.ekf import _lane_plane_curvature, curvature_from_lane_fit
    from fusion.noise import DIM_X, S

    flat, *_ = _lane_fit_on_the_exact_road(0.0, t_s=11.0, grade_pct=grade_pct)
    banked, kappa, bank, grade_rate, speed = _lane_fit_on_the_exact_road(-5.0, t_s=11.0, grade_pct=grade_pct)
    x = np.zeros(DIM_X)
    x[S.CURVATURE], x[S.BANK], x[S.SPEED], x[S.GRADE_RATE] = kappa, bank, speed, grade_rate
    predicted, _ = _lane_plane_curvature(x, True)
    kv_term = -grade_rate / speed * math.sin(bank)
    assert abs(kv_term) > 1e-5          # the vertical curve is there
    assert banked - flat == pytest.approx(predicted - kappa, abs=1e-6)
    # the curvature state taken from the banked fit (a first frame's) is the unbanked fit's
    assert curvature_from_lane_fit(x, banked) == pytest.approx(flat, abs=1e-6)
