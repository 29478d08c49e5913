"""Frame conventions: every conversion round-trips, every matrix is a rotation, and the
signs of INTERFACE.md hold (checked against scipy's Rotation as an independent implementation)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from vision import frames as F

# Middle Euler angle kept 1e-3 rad away from the gimbal-lock pole, where the outer two are not unique.
outer = st.floats(-math.pi + 1e-6, math.pi - 1e-6)
middle = st.floats(-math.pi / 2 + 1e-3, math.pi / 2 - 1e-3)
ORDERS = ("zyx", "xyz", "yxz")


def assert_rotation(R):
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)


@settings(max_examples=300, deadline=None)
@given(a=outer, b=middle, c=outer, order=st.sampled_from(ORDERS))
def test_euler_round_trip_and_orthonormal(a, b, c, order):
    R = F.matrix_from_euler(order, a, b, c)
    assert_rotation(R)
    a2, b2, c2 = F.euler_from_matrix(order, R)
    # Angles back to 1e-9 rad; compare wrapped because +pi and -pi are the same angle.
    for x, y in ((a, a2), (b, b2), (c, c2)):
        assert abs(F.wrap_angle(x - y)) < 1e-9
    np.testing.assert_allclose(F.matrix_from_euler(order, a2, b2, c2), R, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(a=outer, b=middle, c=outer, order=st.sampled_from(ORDERS))
def test_euler_matches_scipy(a, b, c, order):
    # scipy's intrinsic upper-case sequence "ZYX" is Rz(a) @ Ry(b) @ Rx(c).
    R_ref = Rotation.from_euler(order.upper(), [a, b, c]).as_matrix()
    np.testing.assert_allclose(F.matrix_from_euler(order, a, b, c), R_ref, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(a=outer, b=middle, c=outer, src=st.sampled_from(ORDERS), dst=st.sampled_from(ORDERS))
def test_conversion_between_orders(a, b, c, src, dst):
    R = F.matrix_from_euler(src, a, b, c)
    x, y, z = F.euler_from_matrix(dst, R)
    if abs(y) < math.pi / 2 - 1e-3:  # away from the target order's own gimbal lock
        np.testing.assert_allclose(F.matrix_from_euler(dst, x, y, z), R, atol=1e-10)


@settings(max_examples=300, deadline=None)
@given(roll=st.floats(-1.2, 1.2), pitch=st.floats(-0.5, 0.5), yaw=st.floats(-0.5, 0.5))
def test_eq21_roll_zyx_to_xyz(roll, pitch, yaw):
    # Alrazouk et al. 2024, eq. (21) against the matrix route: same XYZ roll to 1e-10 rad.
    R = F.R_from_rpy(roll, pitch, yaw)
    roll1, pitch1, yaw1 = F.euler_from_matrix("xyz", R)
    assert abs(F.roll_xyz_from_zyx(roll, pitch1, yaw1) - roll1) < 1e-10


def test_sign_conventions():
    # Positive roll leans right: the vehicle's z (up) axis gets a negative y (right) component.
    z_up = F.R_from_rpy(0.1, 0, 0) @ [0, 0, 1]
    assert z_up[1] < 0
    # Positive pitch is nose down: x axis gets negative z.
    assert (F.R_from_rpy(0, 0.1, 0) @ [1, 0, 0])[2] < 0
    # Positive yaw is nose left: x axis gets positive y.
    assert (F.R_from_rpy(0, 0, 0.1) @ [1, 0, 0])[1] > 0
    # Positive bank raises the left edge: R_g_from_o = Rx(bank) lifts road y (left).
    assert (F.Rx(0.05) @ [0, 1, 0])[2] > 0
    # The camera looks down by the tilt: optical axis (cp z) has negative vehicle z.
    optical_axis_v = F.R_v_from_cp(math.radians(15)) @ [0, 0, 1]
    np.testing.assert_allclose(optical_axis_v, [math.cos(math.radians(15)), 0, -math.sin(math.radians(15))], atol=1e-15)
    # Image right (cp x) is vehicle right (-y); image down (cp y) is vehicle down-ish.
    np.testing.assert_allclose(F.R_CS_FROM_CP @ [1, 0, 0], [0, -1, 0])
    np.testing.assert_allclose(F.R_CS_FROM_CP @ [0, 1, 0], [0, 0, -1])
    assert_rotation(F.R_CS_FROM_CP)


@settings(max_examples=200, deadline=None)
@given(bank=st.floats(-0.3, 0.3), roll=st.floats(-1.0, 1.0), road_pitch=st.floats(-0.1, 0.1))
def test_bank_is_world_roll_minus_roll(bank, roll, road_pitch):
    # INTERFACE.md: with zero yaw and pitch relative to the road, roll_world = bank + roll exactly.
    R_g_from_v = F.Ry(road_pitch) @ F.Rx(bank) @ F.R_from_rpy(roll, 0.0, 0.0)
    roll_world, _, _ = F.rpy_from_R(R_g_from_v)
    assert abs(F.wrap_angle(roll_world - roll - bank)) < 1e-12


@settings(max_examples=200, deadline=None)
@given(w=st.lists(st.floats(-1.7, 1.7), min_size=3, max_size=3))
def test_so3_exp_log_round_trip(w):
    w = np.asarray(w)  # |w| <= 2.95 rad: the log is unique below pi
    R = F.so3_exp(w)
    assert_rotation(R)
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(F.so3_log(R), w, atol=1e-9)


def test_vectorised_shapes():
    a = np.linspace(-1, 1, 12).reshape(3, 4)
    R = F.R_from_rpy(a, 0.5 * a, -a)
    assert R.shape == (3, 4, 3, 3)
    assert_rotation(R)
    roll, pitch, yaw = F.rpy_from_R(R)
    np.testing.assert_allclose(roll, a, atol=1e-12)
    np.testing.assert_allclose(pitch, 0.5 * a, atol=1e-12)
    np.testing.assert_allclose(yaw, -a, atol=1e-12)


def test_bad_order_is_rejected():
    with pytest.raises(ValueError, match="Euler order"):
        F.matrix_from_euler("zzz", 0, 0, 0)


@settings(max_examples=200, deadline=None)
@given(roll=outer, pitch=middle, yaw=outer, w=st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3))
def test_scalar_fast_paths_match_vectorised(roll, pitch, yaw, w):
    np.testing.assert_allclose(F.R_from_rpy_scalar(roll, pitch, yaw), F.R_from_rpy(roll, pitch, yaw), atol=1e-14)
    R = F.R_from_rpy(roll, pitch, yaw)
    np.testing.assert_allclose(F.rpy_from_R_scalar(R), F.rpy_from_R(R), atol=1e-12)
    np.testing.assert_allclose(F.so3_exp_scalar(*w), F.so3_exp(np.array(w)), atol=1e-14)


def test_fusion_frames_is_the_same_module_of_conventions():
    """``vision/frames.py`` says ``fusion`` re-exports it as ``fusion.frames``; ``import
    fusion.frames`` was a ModuleNotFoundError (only the attribute of ``fusion`` existed, a
    review). Every name is the very object of ``vision.frames``, by either way of reaching it."""
    import subprocess
    import sys

    import fusion
    import fusion.frames
    from fusion.frames import R_from_rpy

    assert fusion.frames.__all__ == F.__all__ and R_from_rpy is F.R_from_rpy and fusion.frames is fusion.__getattr__("frames")
    for name in F.__all__:
        assert getattr(fusion.frames, name) is getattr(F, name), name
    # a fresh interpreter: the attribute before any import of the submodule
    code = "import fusion; import vision.frames as F; assert fusion.frames.Rx is F.Rx"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
