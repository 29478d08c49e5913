"""The simulator's truth is self-consistent: pictures, attitude and IMU agree exactly.

These tests are what every estimator's accuracy figures rest on.
"""

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from drivesim.render import Look, Markings, Renderer
from drivesim.road import Road, Segment
from drivesim.trajectory import GRAVITY_M_S2, Manoeuvre, Motion, Trajectory
from vision.camera import Camera, Mount
from vision.frames import rpy_from_R, so3_exp, so3_log

# A road with everything at once: straight, clothoid into a banked, graded left curve,
# reverse clothoid into a right curve banked the other way.
ROAD = Road([
    Segment(120.0),
    Segment(60.0, 1 / 250, -5.0, 2.0),
    Segment(120.0, 1 / 250, -5.0, 2.0),
    Segment(80.0, -1 / 300, 4.0, -1.0),
    Segment(600.0, -1 / 300, 4.0, -1.0),
])

FLAT = Look(blur_sigma_px=0.0, read_noise_dn=0.0, shot_noise_gain=0.0, texture_fine=0.0, texture_coarse=0.0)


def motorcycle(**kw):
    base = dict(vehicle="motorcycle", speed_kmh=90.0, start_station_m=30.0,
                manoeuvres=(Manoeuvre("double_lane_change", 50.0, 70.0, 3.5, 20.0),))
    base.update(kw)
    return Trajectory(ROAD, Motion(**base))


def project(camera, R_w_from_cp, o_w, X_w):
    return camera.project((np.asarray(X_w) - o_w) @ R_w_from_cp)


@pytest.mark.parametrize("t_s, distortion", [(0.0, False), (2.6, False), (7.0, True)])
def test_rendered_marking_edges_match_projected_truth(t_s, distortion):
    """Known road points (marking edges) projected with the truth pose land on the rendered
    edges to within 0.1 px, measured across the edge (the contract of issue 2).

    The rendered edge is measured from area coverage: along one image row, the coverage of the
    paint summed over a window that holds one edge equals the distance from the window's end
    to the edge (exact for a straight edge across the row band). 8x8 sub-pixel rays keep the
    coverage quantisation under 1/16 px.
    """
    dist = (-0.12, 0.03, 0.0005, -0.0003, 0.0) if distortion else (0.0,) * 5
    camera = Camera.from_fov(960, 540, 80.0, distortion=dist)
    mount = Mount(1.1, math.radians(15.0))
    markings = Markings(lane_width_m=3.5, widths_m=(0.25, 0.15, 0.15))
    traj = motorcycle()
    pose = traj.pose(np.array([t_s]))
    R_w_from_v, P = pose["R_w_from_v"][0], pose["P_w"][0]
    R_w_from_cp = R_w_from_v @ mount.R_v_from_cp
    o = P + R_w_from_v @ mount.position_v
    ren = Renderer(ROAD, camera, markings, FLAT, supersample=8)
    img = ren.radiance(R_w_from_cp, o, pose["s"][0], pose["d"][0], pose["R_w_from_o"][0], P)[..., 0]
    A, Pt = FLAT.asphalt[0], FLAT.paint[0]

    s_v = pose["s"][0]
    errors = []
    lw = markings.lane_width_m
    for line_d, w in ((lw, markings.widths_m[0]), (-lw, markings.widths_m[2])):
        for edge_d in (line_d - w / 2, line_d + w / 2):
            for dist_m in (8.0, 12.0, 18.0, 25.0):
                # Truth: the edge point whose image row is an integer row near dist_m ahead.
                X = ROAD.surface(np.array(s_v + dist_m), np.array(edge_d))
                uv = project(camera, R_w_from_cp, o, X)
                row = int(round(float(uv[1])))
                if not 40 <= row < camera.height - 40:
                    continue

                def v_of(s):
                    return project(camera, R_w_from_cp, o, ROAD.surface(np.array(s), np.array(edge_d)))[1] - row

                grid = s_v + np.linspace(2.0, 60.0, 300)
                vals = np.array([v_of(x) for x in grid])
                k = np.flatnonzero(np.sign(vals[:-1]) != np.sign(vals[1:]))
                if not len(k):
                    continue
                k = k[np.argmin(np.abs(grid[k] - s_v - dist_m))]
                s_row = brentq(v_of, grid[k], grid[k + 1], xtol=1e-12)
                u_true = float(project(camera, R_w_from_cp, o, ROAD.surface(np.array(s_row), np.array(edge_d)))[0])
                # Window of pixels around the edge: the coverage left of the edge is 1 on the
                # paint side. Which side is paint: the marking's centre projects to that side.
                uc = float(project(camera, R_w_from_cp, o, ROAD.surface(np.array(s_row), np.array(line_d)))[0])
                # Window from the last fully painted pixel to the first bare one (or the
                # reverse): the edge's whole transition, and nothing of the other edge.
                paint_right = uc > u_true
                row_cov = (img[row] - A) / (Pt - A)
                lo = hi = int(math.floor(u_true))
                want_lo, want_hi = (0.0, 1.0) if paint_right else (1.0, 0.0)
                while lo > 0 and abs(row_cov[lo] - want_lo) > 1e-9 and u_true - lo < 12:
                    lo -= 1
                while hi < camera.width - 1 and abs(row_cov[hi] - want_hi) > 1e-9 and hi - u_true < 12:
                    hi += 1
                if abs(row_cov[lo] - want_lo) > 1e-9 or abs(row_cov[hi] - want_hi) > 1e-9:
                    continue  # the transitions of the two edges overlap (far away): no clean window
                cov = row_cov[lo:hi + 1]
                if paint_right:  # coverage sum = (hi + 0.5) - u_edge
                    u_meas = hi + 0.5 - cov.sum()
                else:  # coverage sum = u_edge - (lo - 0.5)
                    u_meas = lo - 0.5 + cov.sum()
                # Distance across the edge (what "lands on" means for a slanted edge): the
                # horizontal offset times the sine of the edge's angle to the row.
                a, b = (project(camera, R_w_from_cp, o, ROAD.surface(np.array(s_row + e), np.array(edge_d)))
                        for e in (-0.05, 0.05))
                sin_angle = abs(b[1] - a[1]) / math.hypot(*(b - a))
                errors.append((u_meas - u_true) * sin_angle)
    errors = np.asarray(errors)
    assert len(errors) >= 8, "too few edges measured: the test lost its subject"
    assert np.abs(errors).max() < 0.1, f"edge errors px: {np.round(errors, 3)}"


def _gyro_integration_error_deg(traj, t):
    """The largest angle between the truth attitude and the simulated body rates integrated
    (trapezoid) over the uniform times ``t`` from the truth's first attitude, deg."""
    dt = t[1] - t[0]
    w = traj.body_rate_rad_s(t)
    R_true = traj.R_w_from_v(t)
    R = R_true[0]
    worst = 0.0
    for k in range(len(t) - 1):
        R = R @ so3_exp((w[k] + w[k + 1]) / 2 * dt)
        worst = max(worst, np.linalg.norm(so3_log(R.T @ R_true[k + 1])))
    return math.degrees(worst)


def test_gyro_integration_reproduces_attitude():
    """Integrating the simulated body rates (noise- and bias-free, 200 Hz, trapezoid) over 10 s
    reproduces the truth attitude to within 0.05 deg, through a double lane change and a
    banked curve entry: the rates are the derivative of the same rotation the truth reports."""
    traj = motorcycle(speed_kmh=80.0)
    dt = 1 / 200
    t = np.arange(0.0, 10.0 + dt / 2, dt)
    w = traj.body_rate_rad_s(t)
    assert _gyro_integration_error_deg(traj, t) < 0.05
    # and the drive did something: lean beyond 15 deg, roll rate beyond 20 deg/s
    assert np.degrees(np.abs(traj.pose(t)["roll"])).max() > 15.0
    assert np.degrees(np.abs(w[:, 0])).max() > 20.0


def test_bank_is_world_roll_minus_roll_with_zero_yaw_and_pitch():
    """With no manoeuvre and no pitch motion, yaw and pitch relative to the road are zero, and
    bank = roll_world - roll exactly (INTERFACE.md), through curves, bank runoffs and grade."""
    traj = motorcycle(manoeuvres=(), pitch_amplitude_deg=0.0, pitch_per_decel_deg=0.0)
    t = np.linspace(0.0, 25.0, 501)
    tr = traj.truth(t)
    assert np.abs(tr["yaw"]).max() < 1e-6 and np.abs(tr["pitch"]).max() < 1e-12
    np.testing.assert_allclose(tr["roll_world"] - tr["roll"], tr["bank"], atol=1e-6)
    assert np.degrees(np.abs(tr["bank"])).max() > 3.9  # the banked curves were reached


def test_steady_turn_lean_and_specific_force():
    """Steady banked turn: the motorcycle's lean is atan(v^2 k / g) relative to gravity, and the
    specific force at the IMU has no lateral component (it stays in the plane of symmetry)."""
    traj = motorcycle(manoeuvres=(), pitch_amplitude_deg=0.0, lateral_offset_m=0.0)
    t = np.array([8.4])  # station 240 m: on the 1/250 arc, bank -5 deg, grade 2 %
    pose = traj.pose(t)
    assert ROAD.curvature_1_m(pose["s"])[0] == pytest.approx(1 / 250)
    v, k = pose["speed_m_s"][0], 1 / 250
    roll_world = rpy_from_R(pose["R_w_from_v"])[0][0]
    # On a 2 % grade the horizontal speed is v / sqrt(1 + 0.02^2); lean uses the horizontal turn.
    v_h = v / math.sqrt(1 + 0.02**2)
    assert math.degrees(roll_world) == pytest.approx(-math.degrees(math.atan(v_h**2 * k / GRAVITY_M_S2)), abs=0.02)
    f = traj.specific_force_m_s2(t, [0.0, 0.0, 0.0])[0]
    assert abs(f[1]) < 1e-3  # m/s^2: the lean definition
    assert f[2] == pytest.approx(math.hypot(GRAVITY_M_S2, v_h**2 * k), rel=1e-3)


def test_side_grip_is_the_turn_less_the_bank_and_the_motorcycles_lean():
    """The side force the tyres take (the simulator's limits rest on it, ``drivesim.drive``): in
    a steady left turn banked 5 deg into it, ``atan(grip)`` is the level lean ``atan(v^2 k / g)``
    less the bank (0.02 deg: the 2 % grade, as above), and the motorcycle, with no pitch or yaw,
    leans to the road by exactly ``atan(grip)`` (to the left: negative roll)."""
    traj = motorcycle(manoeuvres=(), pitch_amplitude_deg=0.0, lateral_offset_m=0.0)
    t = np.array([8.4])  # station 240 m: on the 1/250 arc, bank -5 deg, grade 2 %
    pose, grip = traj.pose(t), traj.side_grip(t)[0]
    v_h = pose["speed_m_s"][0] / math.sqrt(1 + 0.02**2)
    level_deg = math.degrees(math.atan(v_h**2 / 250 / GRAVITY_M_S2))
    assert math.degrees(math.atan(grip)) == pytest.approx(level_deg - 5.0, abs=0.02)
    assert math.tan(-pose["roll"][0]) == pytest.approx(grip, rel=1e-9)


def test_curvature_is_smooth_across_clothoid_joints():
    """The road's curvature is the derivative of its heading, and its slope has no corner where
    transitions meet arcs and straights (:func:`drivesim.road.ease`): a plain clothoid's has one,
    which the vehicle turns into a step of its roll rate."""
    s = np.linspace(100.0, 400.0, 300001)   # the clothoid joints at 120, 180, 300 and 380 m
    h = s[1] - s[0]
    k = ROAD.curvature_1_m(s)
    np.testing.assert_allclose(np.gradient(ROAD.heading_rad(s), h)[1:-1], k[1:-1], atol=1e-9)
    slope = np.gradient(k, h)
    # per 1 mm: the plain clothoid's corners (1/250 over 60 m, -7.3e-3 over 80 m) showed 3.3e-5
    # and 4.6e-5 1/m^2 here (half a corner: the difference of a central gradient); now 4.3e-8
    assert np.abs(np.diff(slope)).max() < 1e-7
    assert ROAD.curvature_1_m(np.array([150.0]))[0] == pytest.approx(1 / 500, rel=1e-9)  # mid-transition


def test_vehicle_accelerations_are_finite_at_clothoid_joints():
    """Sampled every 10 ms through the road's clothoid joints and bank runoffs at 90 km/h, 1.75 m
    off the centre line, the specific force 0.5 m above the contact point (where an IMU sits)
    moves by under 0.5 m/s^2 and the body rates by under 1.5 deg/s from one sample to the next,
    for the motorcycle and the car: a rider builds the lean rate up, and no body's roll or pitch
    rate steps. With plain clothoids the motorcycle's lateral specific force jumped 12.2 m/s^2
    in one sample (the roll rate stepping at the joint, the lever arm turning it into a velocity
    impulse) and the pitch rate 6.4 deg/s (the longitudinal acceleration off the centre line
    stepping); now 0.14 m/s^2 and 0.23 deg/s, and the largest change is the roll rate's 0.9
    deg/s (92 deg/s^2 of roll acceleration entering the 250 m curve). (A manoeuvre's septic
    smoothstep is C3: its roll acceleration starts with a finite step, as a rider's push on the
    bar does, 280 deg/s^2 for this file's 70 m double lane change.)"""
    t = np.arange(0.0, 30.0, 0.01)
    for vehicle in ("motorcycle", "car"):
        traj = motorcycle(vehicle=vehicle, manoeuvres=())
        f = traj.specific_force_m_s2(t, [0.0, 0.0, 0.5])
        w = np.degrees(traj.body_rate_rad_s(t))
        assert np.abs(np.diff(f, axis=0)).max() < 0.5, vehicle
        assert np.abs(np.diff(w, axis=0)).max() < 1.5, vehicle
        if vehicle == "motorcycle":
            assert np.abs(w[:, 0]).max() > 5.0   # and it did lean into the curves (9.5 deg/s)


def test_renderer_taylor_surface_matches_exact_surface():
    """The renderer's node Taylor series and the truth's exact surface agree to 10 um."""
    s = np.linspace(0.0, ROAD.length_m - 1, 4001)
    d = np.linspace(-5.0, 5.0, s.size)
    assert np.abs(ROAD.surface(s, d) - ROAD.surface_taylor(s, d)).max() < 1e-5


def test_drive_config_allows_for_what_the_simulated_gyros_leave_out():
    """The attitude allowance a simulated drive's config gives the filter
    (``attitude_walk_deg_sqrt_s``, :data:`drivesim.drive.SIM_ATTITUDE_WALK_DEG_SQRT_S`) covers what
    its gyros leave out: on the bundled sample drive, the decoded rates less the true bias,
    integrated the filter's way over 1 s and 4 s windows from the truth, drift by no more than
    the filter's process noise for them, ``sqrt(gyro_noise^2 dt + walk^2)`` per sqrt(s) (measured
    0.003-0.006 deg/sqrt(s) in roll and yaw, 0.007-0.009 in pitch, against 0.011; before the
    clothoid joints were eased, 0.012-0.015 in pitch: the 100 Hz integration across the two joints
    where the simulated roll rate stepped). The check has power: a 1 % scale-factor error, which
    real gyros have and the simulator's do not, drifts 0.055 deg/sqrt(s) in yaw through the curve
    (0.025 in roll), about 5 times the allowance."""
    import pandas as pd

    from drivesim.drive import SIM_ATTITUDE_WALK_DEG_SQRT_S
    from fusion.config import load_config
    from fusion.drive import SAMPLE_DRIVE
    from fusion.metrics import gyro_attitude_drift
    from imu import read_log

    cfg = load_config(SAMPLE_DRIVE / "config.toml")
    fusion = cfg.extra["fusion"]
    assert fusion["attitude_walk_deg_sqrt_s"] == SIM_ATTITUDE_WALK_DEG_SQRT_S
    imu, _ = read_log(next(SAMPLE_DRIVE.glob("can.*")), cfg.can, cfg.imu)
    imu = imu.dropna(subset=["gyro_x_rad_s"])
    t = imu["t_s"].to_numpy()
    bias = pd.read_csv(SAMPLE_DRIVE / "imu_truth.csv")
    w = imu[["gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"]].to_numpy() - np.stack(
        [np.interp(t, bias["t_s"], bias[f"gyro_bias_{a}_rad_s"]) for a in "xyz"], axis=1)
    truth = pd.read_csv(SAMPLE_DRIVE / "truth.csv")
    allowed = math.hypot(fusion["gyro_noise_deg_s"] * math.sqrt(float(np.median(np.diff(t)))),
                         fusion["attitude_walk_deg_sqrt_s"])
    for window_s in (1.0, 4.0):
        drift = gyro_attitude_drift(t, w, truth, window_s)
        assert np.all(drift <= allowed), (window_s, drift, allowed)
    # a truth without a heading (comma2k19's) gives the same roll and pitch: a rotation about
    # the vertical does not change them
    no_heading = gyro_attitude_drift(t, w, truth.drop(columns="yaw_world_deg"), 1.0)
    np.testing.assert_allclose(no_heading[:2], gyro_attitude_drift(t, w, truth, 1.0)[:2], rtol=1e-9)
    assert np.isnan(no_heading[2])
    assert np.max(gyro_attitude_drift(t, 1.01 * w, truth, 1.0)) > 2 * allowed


def test_a_docstring_edit_keeps_the_drive_cache_key(tmp_path):
    """The benchmarks cache rendered drives under a key of the scenario and the simulator's
    code (``drivesim.code_key``): a docstring, comment or blank line renders the same drive and
    keeps the key; a changed number, a changed statement does not."""
    from drivesim.code_key import drive_key

    base = '"""Module doc."""\nEASE_M = 5.0\n\n\ndef f(x):\n    """Doc."""\n    return x * EASE_M  # why\n'
    variants = {
        "same": '"""Another doc."""\n# a comment\nEASE_M = 5.0\n\ndef f(x):\n    """Other."""\n\n    return x * EASE_M\n',
        "number": base.replace("5.0", "5.5"),
        "statement": base.replace("x * EASE_M", "x / EASE_M"),
    }
    key = {}
    for name, text in {"base": base, **variants}.items():
        (tmp_path / f"{name}.py").write_text(text)
        key[name] = drive_key(b"scenario", [tmp_path / f"{name}.py"])
    assert key["same"] == key["base"]
    assert key["number"] != key["base"] and key["statement"] != key["base"]
    assert drive_key(b"other scenario", [tmp_path / "base.py"]) != key["base"]


def test_a_speed_profile_brakes_without_a_spike_at_its_knots():
    """Braking from 72 to 36 km/h between 0.5 and 2.5 s (a speed profile's knots), the pitch
    following the deceleration (0.3 deg per m/s^2): the specific force at a 0.5 m lever arm is
    smooth through the knots. With the cubic smoothstep the jerk stepped at each knot, the pitch
    rate with it, and the IMU read a one-sample spike of 6.7 m/s^2 (a review); the septic one is
    C3. Bars: the sample-to-sample second difference of the longitudinal specific force at 100
    Hz under 0.05 m/s^2 (the septic profile's own is 0.006; the spike's was 14), and the station
    the closed-form integral of the speed (1 mm over the drive)."""
    traj = Trajectory(Road([Segment(400.0)]), Motion(speed_profile=((0.0, 72.0), (0.5, 72.0), (2.5, 36.0), (4.0, 36.0)),
                                                   pitch_amplitude_deg=0.0, pitch_per_decel_deg=0.3, manoeuvres=()))
    t = np.arange(0.0, 4.0, 0.01)
    f = traj.specific_force_m_s2(t, np.array([0.0, 0.0, -0.5]))[:, 0]
    assert f.max() - f.min() > 4.0                        # it braked (5 m/s^2 at the middle)
    assert np.abs(np.diff(f, 2)).max() < 0.05, np.abs(np.diff(f, 2)).max()
    fine = np.linspace(0.0, 4.0, 40001)
    s_num = traj.station_m(0.0) + np.concatenate([[0.0], np.cumsum(np.diff(fine) * 0.5 * (
        traj.speed_m_s(fine)[1:] + traj.speed_m_s(fine)[:-1]))])
    np.testing.assert_allclose(traj.station_m(fine), s_num, atol=1e-3)


def test_a_car_on_a_banked_straight_rolls_down_the_bank():
    """A car at constant speed along a straight banked 5 deg (no turn): its springs take
    gravity's part across the road, ``g sin(bank)``, and the body rolls towards the low side by
    the roll gain times it: 0.5 deg per m/s^2 gives 0.43 deg, positive (leaning right) for a
    positive bank (left edge raised, INTERFACE.md). With the turn's acceleration alone it did not
    roll at all (a review). The world roll is then the bank plus that."""
    traj = Trajectory(Road([Segment(100.0), Segment(50.0, 0.0, 5.0, 0.0), Segment(400.0, 0.0, 5.0, 0.0)]),
                      Motion(vehicle="car", speed_kmh=72.0, pitch_amplitude_deg=0.0, manoeuvres=(),
                             car_roll_gain_deg=0.5))
    t = np.array([15.0])                                  # station 320 m: the steady bank
    tr = traj.truth(t)
    assert math.degrees(tr["bank"][0]) == pytest.approx(5.0, abs=1e-6)
    expected = 0.5 * GRAVITY_M_S2 * math.sin(math.radians(5.0))
    assert math.degrees(tr["roll"][0]) == pytest.approx(expected, abs=0.005)
    assert math.degrees(tr["roll_world"][0] - tr["bank"][0]) == pytest.approx(expected, abs=0.005)


@pytest.mark.parametrize("deg", [15.0, 12.5, 7.3, -4.0, 0.1, 100.0 / 3.0])
def test_config_angles_read_back_to_the_rendered_radians(deg):
    """A drive's config.toml gives the mount tilt the drive was rendered with, to the bit, in its
    shortest decimal (15.0, not math.degrees' 14.999999999999998)."""
    from drivesim.drive import _degrees_text

    rad = math.radians(deg)
    text = _degrees_text(rad)
    assert math.radians(float(text)) == rad
    assert len(text) <= len(repr(deg))


def _rear_slip_deg(traj, t, wheelbase_m, h=1e-3):
    """Side slip of the rear contact point (the front one less the wheelbase along the body's x
    axis in the road plane): the angle between its velocity and that axis, deg."""
    def rear(tt):
        p = traj.pose(tt)
        x, z = p["R_w_from_v"][..., 0], p["R_w_from_o"][..., 2]
        xg = x - np.sum(x * z, -1)[..., None] * z
        xg /= np.linalg.norm(xg, axis=-1)[..., None]
        return p["P_w"] - wheelbase_m * xg, xg, z

    (a, _, _), (b, _, _), (_, xg, z) = rear(t - h), rear(t + h), rear(t)
    v = (b - a) / (2 * h)
    return np.degrees(np.arcsin(np.sum(np.cross(xg, v) * z, -1) / np.linalg.norm(v, axis=-1)))


def test_a_wheelbase_points_the_body_along_the_rear_wheel():
    """With a wheelbase the body points along the chord from the rear contact to the front one
    (the contact point followed, the contract's origin of v): in a steady left turn of 250 m the
    yaw relative to the road is -asin(L k), -0.332 deg for 1.45 m (nose right of the tangent; the
    tolerance of 0.003 deg is the curvature in the 5 deg banked, 2 % graded road plane against
    the horizontal one, 0.4 %), and the rear wheel rolls without side slip: 0.012 deg at most in
    the clothoids (the quasi-static chord), 0.07 deg through a double lane change, where the body
    along the velocity has 0.77 deg. Without a wheelbase (every bench drive) the yaw stays 0:
    test_bank_is_world_roll_minus_roll_with_zero_yaw_and_pitch."""
    L = 1.45
    traj = motorcycle(manoeuvres=(), pitch_amplitude_deg=0.0, lateral_offset_m=0.0, wheelbase_m=L)
    t = np.array([8.4])   # on the 1/250 arc (test_steady_turn_lean_and_specific_force)
    assert math.degrees(traj.pose(t)["yaw"][0]) == pytest.approx(-math.degrees(math.asin(L / 250)), abs=0.003)
    tt = np.linspace(0.0, 25.0, 1251)
    assert np.abs(_rear_slip_deg(traj, tt, L)).max() < 0.02
    assert np.abs(_rear_slip_deg(motorcycle(wheelbase_m=L), tt, L)).max() < 0.1
    assert np.abs(_rear_slip_deg(motorcycle(), tt, L)).max() > 0.5   # the check sees a slipping rear wheel
    # the gyros see the same rotation the truth reports (test_gyro_integration_reproduces_attitude)
    assert _gyro_integration_error_deg(traj, tt) < 0.05
