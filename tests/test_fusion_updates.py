"""How vision results enter the filter: the chi-square gate before the update, angle wrapping
in the residual, results that arrive out of order. Synthetic drive, vision from the truth plus
known noise (:mod:`fusion_support`)."""

import math

import numpy as np
import pytest

from fusion.ekf import AttitudeEKF, S, VisionMeasurement
from fusion.engine import FusionOptions, FusionStream
from fusion.pipeline import fuse

from fusion_support import synth_drive


@pytest.fixture(scope="module")
def drive():
    return synth_drive("banked_curves_60s.toml", duration_s=15.0, vision_sigma_deg=0.1)


def test_an_outlier_frame_is_gated_out_before_the_update(drive):
    """One frame whose roll is 5 deg off while it claims 0.1 deg (a kerb taken for a line): the
    gate (chi-square of the innovation, computed before the update) rejects it, and the fused
    roll at that frame stays within 0.01 deg of the run without it (the filter's roll sigma
    there is 0.074 deg against the frame's 0.14 with the floor: applied, it would have pulled
    the roll by about 1 deg)."""
    v = drive.vision.copy()
    k = int(np.searchsorted(v["t_s"], 10.0))
    v.loc[k, "roll_deg"] += 5.0
    clean = fuse(drive.imu, drive.vision, lever_arm_m=drive.lever_arm_m)
    hit = fuse(drive.imu, v, lever_arm_m=drive.lever_arm_m)
    assert hit.counts["vision_rejected"] == clean.counts["vision_rejected"] + 1
    t = hit.fused["t_s"].to_numpy()
    i = int(np.searchsorted(t, v.loc[k, "t_s"])) + 1
    assert abs(hit.fused["roll_deg"].iloc[i] - clean.fused["roll_deg"].iloc[i]) < 0.01


def test_the_yaw_residual_is_wrapped():
    """A heading of 179.9 deg measured as -179.9 deg is 0.2 deg off, not 359.8: the update
    moves the yaw by a fraction of 0.2 deg towards 180 (unwrapped, the gate would reject it or
    the yaw would swing by half a turn)."""
    f = AttitudeEKF()
    f.x[S.YAW_REL] = math.radians(179.9)
    m = VisionMeasurement(0.0, np.radians([0.0, 0.0, -179.9]), np.radians([0.1, 0.1, 0.1]))
    assert f.update_vision(m)
    yaw = math.degrees(f.x[S.YAW_REL]) % 360.0
    assert 179.9 < yaw <= 180.1, yaw


def test_without_a_speed_the_roll_of_the_road_ahead_carries_its_twist_in_the_sigma():
    """Before the first wheel speed a frame's roll, measured ``roll_lookahead_m`` ahead, can be
    neither deferred nor modelled as the bank ahead (both need the speed), and was taken as the
    roll here at the frame's own sigma: in a runoff 1.8-2.2 deg off at a sigma of 0.09-0.12 (a
    review, LiveFusion with the speed message withheld). The measured twist times the lookahead,
    the bank change it can hold, is now in the roll's variance (here 0.003 rad/m over 10 m:
    1.7 deg); without a measured twist the variance is as before (not covered: notes)."""
    inn = []
    for twist in (math.nan, 0.003):
        f = AttitudeEKF()
        f.x[S.SPEED] = 0.0
        m = VisionMeasurement(0.0, np.radians([1.0, 0.0, 0.0]), np.radians([0.05, 0.05, 0.05]),
                              roll_lookahead_m=10.0, road_twist_rad_m=twist)
        assert f.update_vision(m)
        inn.append(f.S[0, 0])
    assert inn[1] - inn[0] == pytest.approx((0.003 * 10.0) ** 2, rel=1e-9)
    f = AttitudeEKF()                        # moving: the bank ahead is modelled, not this term
    f.x[S.SPEED] = 20.0
    f.update_vision(VisionMeasurement(0.0, np.radians([1.0, 0.0, 0.0]), np.radians([0.05, 0.05, 0.05]),
                                      roll_lookahead_m=10.0, road_twist_rad_m=0.003))
    assert f.S[0, 0] < inn[0] + 0.5 * (0.003 * 10.0) ** 2


def _delivered(drive, imu, vis, delay_s, history_s: float, lookahead_m: float = 0.0) -> FusionStream:
    """A stream fed ``imu`` in order and each vision row ``delay_s`` after its capture (0.1 deg
    sigmas; the roll of the road ``lookahead_m`` ahead)."""
    s = FusionStream(drive.lever_arm_m, options=FusionOptions(history_s=history_s))
    arrive = vis["t_s"].to_numpy() + delay_s
    order = np.argsort(arrive, kind="stable")
    j = 0
    for row in imu.itertuples():
        while j < len(order) and arrive[order[j]] <= row.t_s:
            p = vis.iloc[order[j]]
            s.add_vision(p.t_s, np.radians([p.roll_deg, p.pitch_deg, p.yaw_deg]), np.radians([0.1] * 3),
                         True, p.curvature_1_m, p.lateral_offset_m, lookahead_m=lookahead_m)
            j += 1
        s.add_imu(row.t_s, [row.gyro_x_rad_s, row.gyro_y_rad_s, row.gyro_z_rad_s],
                  [row.accel_x_m_s2, row.accel_y_m_s2, row.accel_z_m_s2], row.speed_m_s, row.fresh_speed)
    return s


def test_results_out_of_order_give_the_in_order_estimate(drive):
    """Vision results delayed by 0 to 150 ms each (random: they arrive out of order), within
    the 0.5 s history: rolled back and re-propagated, the final state equals the in-time run's
    to rounding."""
    imu, vis = drive.imu.iloc[:1000], drive.vision[drive.vision["t_s"] < 9.9]
    delays = np.random.default_rng(4).uniform(0.0, 0.15, len(vis))

    on_time, shuffled = (_delivered(drive, imu, vis, d, history_s=0.5) for d in (np.zeros(len(vis)), delays))
    arrive = vis["t_s"].to_numpy() + delays
    assert np.any(np.diff(arrive[np.argsort(arrive)]) >= 0) and np.any(np.diff(arrive) < 0)   # really out of order
    assert shuffled.counts["vision_late"] > 100
    np.testing.assert_allclose(shuffled.ekf.x, on_time.ekf.x, atol=1e-9)
    np.testing.assert_allclose(shuffled.ekf.P, on_time.ekf.P, atol=1e-12)


def test_results_later_than_their_deferred_roll_give_the_in_order_estimate(drive):
    """Results 0.5-0.9 s late (within a 1 s history) whose rolls, of the road 12 m ahead, fall
    due 0.5 s after capture, inside the span the late result replays: the replay applies them at
    their due time. Before, they waited for the next sample and went in at its interval's start:
    the final roll and bank 0.22 deg off the in-time run's (a review: LiveFusion's roll 0.21 /
    0.37 deg RMS off at 0.7 / 0.9 s late, 14 / 27 sigma at worst; now 0.11 / 0.22 as reported,
    2.2 / 2.0 sigma). Now 0.002 deg: not to rounding, as results in time order are, since one
    frame's gate decides otherwise on the way (1 rejected against 0); the bar, 0.01 deg."""
    imu, vis = drive.imu.iloc[:1000], drive.vision[drive.vision["t_s"] < 9.0]
    delays = np.random.default_rng(5).uniform(0.5, 0.9, len(vis))

    on_time, late = (_delivered(drive, imu, vis, d, history_s=1.0, lookahead_m=12.0)
                     for d in (np.zeros(len(vis)), delays))
    assert late.counts["vision_late"] > 100 and late.counts["roll_ahead_used"] > 100
    a, b = on_time.estimate(), late.estimate()
    assert abs(math.degrees(b.roll_rad - a.roll_rad)) < 0.01 and abs(math.degrees(b.bank_rad - a.bank_rad)) < 0.01


def test_a_result_stamped_at_the_newest_sample_equals_the_in_time_run(drive):
    """A vision result whose capture time is exactly the newest IMU sample's, handed in after
    that sample (the camera and the IMU share a trigger): applied at that sample as if it had
    come before it; the state equals the run where it came first, to rounding (its snapshot
    was the one before the sample, a whole interval early, until a fix of 2026-11-25)."""
    imu = drive.imu.iloc[:400]
    t = imu["t_s"].to_numpy()
    vis = drive.vision[drive.vision["t_s"] < t[-1]]
    # the frames moved onto IMU sample times
    k = np.searchsorted(t, vis["t_s"].to_numpy())
    stamps = t[np.clip(k, 0, len(t) - 1)]

    def run(after: bool):
        s = FusionStream(drive.lever_arm_m, options=FusionOptions())
        j = 0
        for i, row in enumerate(imu.itertuples()):
            def hand_in(limit):
                nonlocal j
                while j < len(stamps) and stamps[j] <= limit:
                    p = vis.iloc[j]
                    s.add_vision(stamps[j], np.radians([p.roll_deg, p.pitch_deg, p.yaw_deg]), np.radians([0.1] * 3),
                                 True, p.curvature_1_m, p.lateral_offset_m)
                    j += 1
            if not after:
                hand_in(row.t_s)
            s.add_imu(row.t_s, [row.gyro_x_rad_s, row.gyro_y_rad_s, row.gyro_z_rad_s],
                      [row.accel_x_m_s2, row.accel_y_m_s2, row.accel_z_m_s2], row.speed_m_s, row.fresh_speed)
            if after:
                hand_in(row.t_s)
        return s

    before, after = run(False), run(True)
    assert after.counts["vision_late"] >= 100 and before.counts["vision_late"] == 0
    assert after.counts["vision_used"] == before.counts["vision_used"] > 100
    np.testing.assert_allclose(after.ekf.x, before.ekf.x, atol=1e-9)
    np.testing.assert_allclose(after.ekf.P, before.ekf.P, atol=1e-12)
