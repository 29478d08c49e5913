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
from vision.ipm import Bev, BevGrid
from vision.lanes import Marker, _robust_fit
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
        m.fit_left, m.rms_left, kl = _robust_fit(v, us[0], 2, m.v0)
        m.fit_right, m.rms_right, kr = _robust_fit(v, us[1], 2, m.v0)
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
