"""What the streaming filter does with the inputs a live bus and camera give besides the
expected ones: a gap in the IMU samples, a sample with a NaN, the same vision result twice, a
result dated far ahead of the IMU, results from before the IMU started. Synthetic drive,
vision from the truth plus known noise (:mod:`fusion_support`)."""

import math

import numpy as np
import pytest

from fusion.ekf import NoiseModel
from fusion.engine import FusionOptions, FusionStream
from fusion.pipeline import fuse

from fusion_support import SIM_NOISE, rmse_deg, synth_drive

OPTIONS = FusionOptions(noise=NoiseModel(**SIM_NOISE))


@pytest.fixture(scope="module")
def drive():
    return synth_drive("banked_curves_60s.toml", vision_sigma_deg=0.3)


def _abs_error(f, truth, col):
    return np.abs(f[col].to_numpy() - np.interp(f["t_s"], truth["t_s"], truth[col]))


@pytest.mark.parametrize("smooth", [False, True])
def test_a_gap_in_the_imu_samples_restarts_the_filter(drive, smooth):
    """No IMU sample for 1 s (30-31 s, in the 7 deg curve at 14 deg of lean): integrated
    across with the mean of the two gyro readings, the bank was 11.5 deg off 5 s later with a
    sigma of 0.4 deg (a review's measurement on a rendered drive). The filter now starts again
    from the sample after the gap, keeping the IMU biases, and says so: measured, roll at most
    0.43 deg off in the 3 s after (forward; 0.19 smoothed, each side of the gap smoothed on its
    own), and from then on the RMSE of the run without the gap (0.178 / 0.098 deg). Bars: the
    issue's 1 deg of lane loss for the first 3 s, within 0.02 deg of the gapless run after."""
    keep = ~((drive.imu["t_s"] > 30.0) & (drive.imu["t_s"] < 31.0)).to_numpy()
    run = fuse(drive.imu[keep], drive.vision, lever_arm_m=drive.lever_arm_m, options=OPTIONS, smooth=smooth)
    base = fuse(drive.imu, drive.vision, lever_arm_m=drive.lever_arm_m, options=OPTIONS, smooth=smooth)
    assert run.counts["imu_gaps"] == 1 and base.counts["imu_gaps"] == 0
    assert any("gap" in w and "started again" in w for w in run.warnings), run.warnings
    # the frames inside the gap are said as not used (they were counted only as ahead of the
    # filter or too old for it): those stamped strictly between the samples on either side
    t_imu = drive.imu["t_s"][keep].to_numpy()
    k = int(np.flatnonzero(np.diff(t_imu) > OPTIONS.max_imu_gap_s)[0])
    vt = drive.vision["t_s"].to_numpy()
    reach = min(OPTIONS.max_imu_gap_s, OPTIONS.history_s)     # those applied at the sample after it
    inside = int(np.sum(drive.vision["valid"].to_numpy(dtype=bool) & (vt > t_imu[k]) & (vt < t_imu[k + 1] - reach)))
    assert inside >= 20     # 1 s at 30 fps, less the 0.2 s applied after the gap
    assert any(f"; {inside} vision result(s) inside them were not used" in w for w in run.warnings), run.warnings
    f, t = run.fused, run.fused["t_s"].to_numpy()
    assert np.all(np.isfinite(f[["roll_deg", "bank_deg", "roll_sigma_deg"]].to_numpy()))
    assert _abs_error(f, drive.truth, "roll_deg")[(t >= 31.0) & (t < 34.0)].max() < 1.0
    tb = base.fused["t_s"].to_numpy()
    for col in ("roll_deg", "pitch_deg", "yaw_deg", "bank_deg"):
        after, ref = rmse_deg(f, drive.truth, col, mask=t >= 34.0), rmse_deg(base.fused, drive.truth, col, mask=tb >= 34.0)
        assert after < ref + 0.02, (col, after, ref)


def _feed(stream, imu, vision=None, vision_sigma_deg=0.3):
    """IMU rows in order, each vision row (capture time, angles) handed in at the first IMU
    sample at or after its time."""
    j = 0
    vt = vision["t_s"].to_numpy() if vision is not None else np.zeros(0)
    for row in imu.itertuples():
        while j < len(vt) and vt[j] <= row.t_s:
            p = vision.iloc[j]
            stream.add_vision(p.t_s, np.radians([p.roll_deg, p.pitch_deg, p.yaw_deg]),
                              np.radians([vision_sigma_deg] * 3), True, p.curvature_1_m, p.lateral_offset_m)
            j += 1
        stream.add_imu(row.t_s, [row.gyro_x_rad_s, row.gyro_y_rad_s, row.gyro_z_rad_s],
                       [row.accel_x_m_s2, row.accel_y_m_s2, row.accel_z_m_s2], row.speed_m_s, row.fresh_speed)


def test_an_hour_without_imu_samples(drive):
    """The bus quiet for an hour (the vehicle parked with the logger on), then the drive goes
    on: the bank was 27,000 deg off before the restart existed; now within 0.5 deg of the truth
    2 s after the bus returns, the biases carried."""
    s = FusionStream(drive.lever_arm_m, options=OPTIONS)
    first, second = drive.imu[drive.imu["t_s"] < 20.0], drive.imu[drive.imu["t_s"] >= 20.0]
    _feed(s, first, drive.vision[drive.vision["t_s"] < 20.0])
    bias = s.ekf.x[5:8].copy()
    shifted = second.assign(t_s=second["t_s"] + 3600.0)
    _feed(s, shifted[shifted["t_s"] < 3600.0 + 25.0], drive.vision[drive.vision["t_s"] >= 20.0].assign(
        t_s=lambda v: v["t_s"] + 3600.0).query("t_s < 3625.0"))
    assert s.counts["imu_gaps"] == 1
    est = s.estimate()
    truth_bank = np.interp(25.0 - 0.01, drive.truth["t_s"], drive.truth["bank_deg"])
    assert abs(math.degrees(est.bank_rad) - truth_bank) < 0.5, (math.degrees(est.bank_rad), truth_bank)
    np.testing.assert_allclose(s.ekf.x[5:8], bias, atol=math.radians(0.05))   # not re-learnt from zero


def test_a_sample_with_a_nan_is_skipped_and_counted(drive):
    """One gyro reading NaN (a decode that failed): skipped and counted, the state stays finite
    and equal to the run that never had the sample; a NaN time too."""
    imu = drive.imu[drive.imu["t_s"] < 5.0]
    clean = FusionStream(drive.lever_arm_m, options=OPTIONS)
    _feed(clean, imu.drop(index=imu.index[200]))
    hit = FusionStream(drive.lever_arm_m, options=OPTIONS)
    bad = imu.copy()
    bad.loc[bad.index[200], "gyro_x_rad_s"] = np.nan
    _feed(hit, bad)
    hit.add_imu(math.nan, [0.0] * 3, [0.0, 0.0, 9.8])
    assert hit.counts["imu_invalid"] == 2 and hit.counts["imu"] == clean.counts["imu"]
    np.testing.assert_allclose(hit.ekf.x, clean.ekf.x, atol=1e-12)
    with pytest.raises(ValueError, match="not after the previous"):
        hit.add_imu(imu["t_s"].iloc[-1], [0.0] * 3, [0.0, 0.0, 9.8])
    assert hit.counts["imu"] == clean.counts["imu"]   # the refused sample is not counted


def test_the_same_result_twice_counts_once(drive):
    """Every vision result handed in twice (a camera thread that repeats its last result): the
    second is counted as a duplicate and not applied, which would halve its variance: the
    state equals the single run's."""
    imu, vis = drive.imu[drive.imu["t_s"] < 6.0], drive.vision[drive.vision["t_s"] < 6.0]
    once, twice = FusionStream(drive.lever_arm_m, options=OPTIONS), FusionStream(drive.lever_arm_m, options=OPTIONS)
    _feed(once, imu, vis)
    _feed(twice, imu, vis.loc[vis.index.repeat(2)])
    assert twice.counts["vision_duplicate"] == len(vis)
    assert twice.counts["vision_used"] == once.counts["vision_used"]
    np.testing.assert_allclose(twice.ekf.P, once.ekf.P, atol=1e-15)


def test_results_whose_numbers_are_no_measurement_are_refused_and_said(drive):
    """Every tenth result in degrees where radians are due (a roll of 8 deg handed in as 8 rad:
    a review took the bank to -462 deg through 11 re-acquisitions, without a word), and one with
    a sigma of 0 and one with a negative sigma: refused, counted as invalid and as implausible,
    said once in the offline run's warnings; the state equals the run without them."""
    imu, vis = drive.imu[drive.imu["t_s"] < 6.0], drive.vision[drive.vision["t_s"] < 6.0]
    clean = vis.iloc[[k for k in range(len(vis)) if k % 10]]
    bad = vis.copy()
    bad.iloc[::10, bad.columns.get_loc("roll_deg")] += 458.0     # 8 deg read as 8 rad, roughly
    ref, got = FusionStream(drive.lever_arm_m, options=OPTIONS), FusionStream(drive.lever_arm_m, options=OPTIONS)
    _feed(ref, imu, clean)
    _feed(got, imu, bad)
    n = len(vis[::10])
    assert got.counts["vision_implausible"] == n and got.counts["vision_invalid"] == n
    np.testing.assert_allclose(got.ekf.x, ref.ekf.x, atol=1e-12)
    for sig in (0.0, -0.1):
        s = FusionStream(drive.lever_arm_m, options=OPTIONS)
        s.add_vision(1.0, np.radians([1.0, 0.0, 0.0]), np.radians([sig, 0.1, 0.1]))
        assert s.counts["vision_implausible"] == 1 and not s._pending
    v = vis.copy()
    v.iloc[::10, v.columns.get_loc("roll_deg")] += 458.0
    run = fuse(imu, v, lever_arm_m=drive.lever_arm_m, options=OPTIONS)
    said = [w for w in run.warnings if "refused: an angle beyond +-90 deg" in w]
    assert len(said) == 1 and said[0].startswith(f"{n} vision result(s)"), run.warnings


def test_results_far_ahead_or_from_before_the_imu_are_not_applied(drive):
    """A result dated more than ``history_s`` after the newest IMU sample (frame times in ms
    instead of s) is counted and dropped instead of waiting in the queue for good; results
    from more than ``max_imu_gap_s`` (0.2 s) before the first IMU sample (the camera started
    earlier, the side stand's 20 deg of roll) are dropped as too old, not applied at the first
    sample (up to ``history_s``, 1 s, were); those within it are applied there."""
    s = FusionStream(drive.lever_arm_m, options=OPTIONS)
    imu = drive.imu[drive.imu["t_s"] < 3.0]
    t0 = float(imu["t_s"].iloc[0])
    frames = t0 - 0.199 - np.arange(294)[::-1] / 30     # 9.8 s of frames, the last 0.199 s before
    assert t0 - frames[-1] < 0.2 < t0 - frames[-2]
    for t in frames:
        s.add_vision(t, np.radians([20.0, 0.0, 0.0]), np.radians([0.1] * 3))
    _feed(s, imu.iloc[:10])
    assert s.counts["vision_too_old"] == 293 and s.counts["vision_used"] + s.counts["vision_rejected"] == 1
    s.add_vision(1000.0 * imu["t_s"].iloc[9], np.radians([0.0, 0.0, 0.0]), np.radians([0.1] * 3))
    assert s.counts["vision_future"] == 1 and not s._pending


def test_speed_is_nan_until_the_first_wheel_speed(drive):
    """The speed state starts at 0 as a placeholder; until the first wheel speed arrives the
    outputs say NaN (0 m/s would read as standing still), after it the wheel speed within the
    speed noise (5 cm/s, the simulator's wheel speed is exact)."""
    imu = drive.imu[drive.imu["t_s"] < 3.0].copy()
    first = imu.index[100]
    imu.loc[imu.index < first, "speed_m_s"] = np.nan
    imu.loc[imu.index < first, "fresh_speed"] = False
    run = fuse(imu, None, lever_arm_m=drive.lever_arm_m, options=OPTIONS)
    before = run.fused["t_s"] < imu.loc[first, "t_s"]
    assert run.fused.loc[before, "speed_m_s"].isna().all() and before.sum() == 100
    after = run.fused.loc[~before, "speed_m_s"].to_numpy()
    truth = np.interp(run.fused.loc[~before, "t_s"], drive.truth["t_s"], drive.truth["speed_m_s"])
    assert np.isfinite(after).all() and np.max(np.abs(after - truth)) < 0.05
    stream = FusionStream(drive.lever_arm_m, options=OPTIONS)
    _feed(stream, imu.iloc[:50])
    assert math.isnan(stream.estimate().speed_m_s)
    _feed(stream, imu.iloc[50:150])
    assert abs(stream.estimate().speed_m_s - truth[49]) < 0.05


def test_a_replay_keeps_each_results_roll_deferral(drive, monkeypatch):
    """Rolls measured 12 m ahead wait for the vehicle to get there (deferred), except the first
    frame after a gap in the vision, whose roll is applied at capture. The lanes gone for 1 s,
    then a frame back on time (its roll applied at capture), then a frame from just before it
    arriving late (out of order): the replay that applies the late one used to decide again,
    see no gap, defer the first frame's roll, and lose it (its deferred roll is queued only by
    the first pass). Every result's roll must be applied exactly once: at capture, or when the
    vehicle reaches it."""
    from fusion.ekf import AttitudeEKF

    calls = []   # ("vision", t_s, deferred) and ("ahead", roll_rad) in the order applied
    update_vision, update_roll_ahead = AttitudeEKF.update_vision, AttitudeEKF.update_roll_ahead

    def spy_vision(self, m, defer_roll=False, bank_rate_ahead=0.0):
        calls.append(("vision", m.t_s, defer_roll))
        return update_vision(self, m, defer_roll, bank_rate_ahead)

    def spy_ahead(self, r, turned):
        calls.append(("ahead", r.roll_rad))
        return update_roll_ahead(self, r, turned)

    monkeypatch.setattr(AttitudeEKF, "update_vision", spy_vision)
    monkeypatch.setattr(AttitudeEKF, "update_roll_ahead", spy_ahead)
    imu = drive.imu[drive.imu["t_s"] < 9.0]
    vis = drive.vision[(drive.vision["t_s"] < 8.5) & ((drive.vision["t_s"] < 5.0) | (drive.vision["t_s"] >= 6.0))]
    back = vis[vis["t_s"] >= 6.0].index
    late, first_back = back[0], back[1]      # handed in after the frame that follows it
    s = FusionStream(drive.lever_arm_m, options=OPTIONS)
    # handed in when the IMU reaches its time; the late one 30 ms after the frame after it
    hand_in = {i: vis.loc[i, "t_s"] for i in vis.index}
    hand_in[late] = vis.loc[first_back, "t_s"] + 0.03
    pending = sorted(vis.index, key=hand_in.get)
    for row in imu.itertuples():
        while pending and hand_in[pending[0]] <= row.t_s:
            p = vis.loc[pending.pop(0)]
            # each roll made unique, so that its deferred application can be told apart
            roll = p.roll_deg + 1e-6 * p.name
            s.add_vision(p.t_s, np.radians([roll, p.pitch_deg, p.yaw_deg]), np.radians([0.3] * 3), True,
                         p.curvature_1_m, p.lateral_offset_m, lookahead_m=12.0)
        s.add_imu(row.t_s, [row.gyro_x_rad_s, row.gyro_y_rad_s, row.gyro_z_rad_s],
                  [row.accel_x_m_s2, row.accel_y_m_s2, row.accel_z_m_s2], row.speed_m_s, row.fresh_speed)
    assert s.counts["vision_late"] == 1
    # the last pass over each result decides (a replay rolls the state back before it)
    last = {}
    for k, c in enumerate(calls):
        if c[0] == "vision":
            last[c[1]] = (k, c[2])
    rolls_ahead = [(k, c[1]) for k, c in enumerate(calls) if c[0] == "ahead"]
    t_of = {round(math.radians(vis.loc[i, "roll_deg"] + 1e-6 * i), 12): vis.loc[i, "t_s"] for i in vis.index}
    for i in (late, first_back):
        t = vis.loc[i, "t_s"]
        k, deferred = last[t]
        applied_ahead = [kk for kk, r in rolls_ahead if kk > k and t_of.get(round(r, 12)) == t]
        assert (not deferred and not applied_ahead) or (deferred and len(applied_ahead) == 1), \
            (i, t, deferred, applied_ahead)


def test_the_plain_bank_has_no_value_inside_an_imu_gap(drive):
    """Damon et al.'s IMU-minus-vision bank needs the IMU's roll at the frame: inside a gap in
    the IMU samples (the filter restarts there) there is none. It was interpolated across the
    gap: a review measured 7.7 deg of error at the 53 frames of a 1.8 s gap in a weave, scored
    in the report (0.85 against 0.36 deg RMSE). Now NaN there, finite elsewhere."""
    from fusion.pipeline import plain_bank

    imu = drive.imu[drive.imu["t_s"] < 40.0]
    keep = ~((imu["t_s"] > 30.0) & (imu["t_s"] < 31.0)).to_numpy()
    imu_only = fuse(imu[keep], None, lever_arm_m=drive.lever_arm_m, options=OPTIONS).fused
    pb = plain_bank(imu_only, drive.vision[drive.vision["t_s"] < 40.0])
    t, bank = pb["t_s"].to_numpy(), pb["bank_plain_deg"].to_numpy()
    inside = (t > 30.0) & (t < 31.0)
    assert inside.sum() >= 25 and np.all(np.isnan(bank[inside]))
    assert np.all(np.isfinite(bank[~inside & (t > imu_only["t_s"].iloc[0]) & (t < imu_only["t_s"].iloc[-1])]))


def test_a_10_fps_camera_keeps_its_plain_bank_between_frames():
    """Frames 0.1 s apart (KITTI's 10 fps) against the 0.1 s lane-loss limit: 40 % of the
    intervals come out a rounding step longer and were taken for lost lanes (NaN). The limit
    is now at least 1.5 frame periods of all the frames (not of the valid ones: with lanes
    found on one frame in three the limit grew to 0.3 s, a review found, and interpolated
    across the lost ones)."""
    from fusion.pipeline import frame_gap_limit_s, frames_to_samples

    frames = np.arange(200) / 10.0 + 1234.5
    t = np.arange(frames[0], frames[-1], 0.01)
    limit = frame_gap_limit_s(frames)
    assert limit == pytest.approx(0.15)
    assert np.all(np.isfinite(frames_to_samples(t, frames, np.sin(frames), limit)))
    valid = frames[::3]                                # lanes on one frame in three
    v = frames_to_samples(t, valid, np.sin(valid), limit)
    inside = (t > valid[0]) & (t < valid[-1]) & ~np.isin(t, valid)
    assert np.all(np.isnan(v[inside]))


def test_a_gap_at_the_limit_is_bridged_whichever_way_its_epoch_time_rounds():
    """Three 30 fps frames apart is 0.1 s, the limit, as written; the epoch times' float64
    rounding made some such gaps 0.10000014 s and others 0.09999990 s, and the first were left
    NaN (the sample drive: 26 empty samples where 17 were expected, a review)."""
    from fusion.pipeline import PLAIN_BANK_MAX_FRAME_GAP_S, frames_to_samples

    frames = np.array([1700000005.6, 1700000005.7 + 1.4e-7, 1700000005.8 - 1.0e-7])
    assert frames[1] - frames[0] > PLAIN_BANK_MAX_FRAME_GAP_S > frames[2] - frames[1]
    t = np.linspace(frames[0], frames[-1], 41)
    assert np.all(np.isfinite(frames_to_samples(t, frames, np.array([1.0, 2.0, 3.0]))))
    # a gap a frame longer is still a loss
    late = frames + np.array([0.0, 1.0 / 30.0, 1.0 / 30.0])
    v = frames_to_samples(t, late, np.array([1.0, 2.0, 3.0]))
    assert np.all(np.isnan(v[(t > late[0]) & (t < late[1])]))


def test_an_imu_table_with_a_nan_time_is_refused(drive):
    """A NaN sample time passed the 'strictly increasing' check (a comparison with NaN is
    false): the forward table got a row with t_s NaN and the smoother a length error."""
    from fusion.errors import InputError

    imu = drive.imu.iloc[:300].copy()
    imu.loc[imu.index[100], "t_s"] = np.nan
    with pytest.raises(InputError, match="not finite"):
        fuse(imu, None, lever_arm_m=drive.lever_arm_m, options=OPTIONS, smooth=True)


#: What a zeroed CAN frame of the review's IMU decodes to (the DBC's offsets): -163.84 deg/s on
#: each gyro axis, -4.18 g on each accelerometer axis (7.2 g in all, in the vehicle frame
#: rotated by the mount's axes: the signs differ).
_ZEROED_GYRO_RAD_S = math.radians(-163.84)
_ZEROED_ACCEL_M_S2 = (-40.96, 40.96, 40.96)


def test_a_zeroed_first_accelerometer_frame_starts_the_filter_level(drive):
    """An IMU that sends a zeroed frame at power-up: the first sample's specific force is 7.2 g,
    which no attitude explains. Levelled from it, the start's pitch was 90 deg (``asin`` of
    -4.18 clipped to 1) and the first gravity update divided by zero: a traceback from
    ``vifusion run``, ``campaign`` and ``LiveFusion`` (a review). Now the start is level with
    the roll's and pitch's sigma at 25 deg, the sample is counted and the run says so; the
    drive is then as good as without the frame: the world roll after 2 s within 0.05 deg RMS
    of the clean run's (measured 0.000: the gravity reference brings the start in long before
    2 s), and every angle inside the bars of the clean run plus that."""
    imu = drive.imu[drive.imu["t_s"] < 20.0].copy()
    vision = drive.vision[drive.vision["t_s"] < 20.0]
    clean = fuse(imu, vision, lever_arm_m=drive.lever_arm_m, options=OPTIONS)
    imu.loc[imu.index[0], ["accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]] = _ZEROED_ACCEL_M_S2
    run = fuse(imu, vision, lever_arm_m=drive.lever_arm_m, options=OPTIONS)
    assert run.counts["level_skipped"] == 1 and clean.counts["level_skipped"] == 0
    assert any("could not level the filter" in w for w in run.warnings)
    for col in ("roll_world_deg", "bank_deg", "roll_deg"):
        assert abs(rmse_deg(run.fused, drive.truth, col) - rmse_deg(clean.fused, drive.truth, col)) < 0.05, col


def test_a_gyro_glitch_is_recovered_from(drive):
    """Ten zeroed gyro frames (0.1 s at -164 deg/s on every axis) in the middle of a drive turn
    the attitude 16 deg: every gravity update after them was refused by the gate, and the
    bank stayed 20 deg off with a sigma of 0.3 for the rest of the drive, without a warning
    (a review). After ``gravity_reacquire_after_s`` (1 s) of refusals the world roll and pitch
    are taken again from the accelerometer, the heading relative to the road reopened and the
    road's states set again by the next frame. From 1.5 s after the glitch every angle's RMSE
    is within 0.05 deg of the run without it (measured: at most +0.037, the world roll; the
    vision's 0.3 deg noise sets the rest), and the bank inside the issue's 0.3 deg bar; the run
    warns."""
    imu = drive.imu[drive.imu["t_s"] < 20.0].copy()
    vision = drive.vision[drive.vision["t_s"] < 20.0]
    clean = fuse(imu, vision, lever_arm_m=drive.lever_arm_m, options=OPTIONS)
    glitch = (imu["t_s"] >= 10.0) & (imu["t_s"] < 10.1)
    imu.loc[glitch, ["gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"]] = _ZEROED_GYRO_RAD_S
    run = fuse(imu, vision, lever_arm_m=drive.lever_arm_m, options=OPTIONS)
    assert run.counts["gravity_reacquired"] == 1 and clean.counts["gravity_reacquired"] == 0
    assert any("gravity reference was refused" in w for w in run.warnings)
    for col in ("bank_deg", "roll_world_deg", "roll_deg", "pitch_deg", "yaw_deg"):
        err, ref = (rmse_deg(f.fused, drive.truth, col, t_min=11.5) for f in (run, clean))
        assert err < ref + 0.05, (col, err, ref)
    assert rmse_deg(run.fused, drive.truth, "bank_deg", t_min=11.5) < 0.3
    # and right after the glitch it was off: the test has a glitch to recover from
    during = (run.fused["t_s"] > 10.2) & (run.fused["t_s"] < 10.9)
    assert np.max(_abs_error(run.fused[during], drive.truth, "roll_world_deg")) > 5.0


@pytest.mark.parametrize("stuck_m_s", [0.0, 83.3])
def test_a_wheel_speed_sensor_stuck_at_a_value_is_refused(drive, stuck_m_s):
    """A wheel-speed sensor that reads 0 (a locked or lifted wheel, a dead sensor) or 300 km/h
    (a spinning wheel) for 6 s while the motorcycle rides on at about 80 km/h: the re-acquisition
    for a drifted speed state took it after 0.2 s of refusals, and the speed into the gravity
    reference's centripetal term with it (a review: the bank 13 deg off, 42 sigma, on the sample
    drive). Now it is refused as the sensor's fault, the speed carried on by the acceleration
    state: every angle's RMSE within 0.05 deg of the clean run's (measured: bank +0.011, world
    roll +0.022; before, the bank's was 6.4 and 13.2 deg), the speed within 0.3 m/s of the truth
    during the fault (measured 0.08; the accelerometer carried it within 0.33 m/s over 40 s on
    the 60 s drive), the run warns and no re-acquisition took it."""
    imu = drive.imu[drive.imu["t_s"] < 20.0].copy()
    vision = drive.vision[drive.vision["t_s"] < 20.0]
    clean = fuse(imu, vision, lever_arm_m=drive.lever_arm_m, options=OPTIONS)
    stuck = (imu["t_s"] >= 8.0) & (imu["t_s"] < 14.0)
    imu.loc[stuck, "speed_m_s"] = stuck_m_s
    run = fuse(imu, vision, lever_arm_m=drive.lever_arm_m, options=OPTIONS)
    assert run.counts["speed_reacquired"] == 0 and run.counts["speed_implausible"] > 0
    assert clean.counts["speed_implausible"] == 0
    assert any("refused as a sensor fault" in w for w in run.warnings)
    for col in ("bank_deg", "roll_world_deg", "roll_deg", "pitch_deg", "yaw_deg"):
        err, ref = (rmse_deg(f.fused, drive.truth, col, t_min=2.0) for f in (run, clean))
        assert err < ref + 0.05, (col, err, ref)
    during = run.fused[(run.fused["t_s"] >= 8.0) & (run.fused["t_s"] < 14.0)]
    assert np.max(_abs_error(during, drive.truth, "speed_m_s")) < 0.3


def test_a_wheel_speed_within_reach_of_the_carried_speed_is_re_acquired(drive):
    """The other side of the bound: a wheel speed that steps 1.5 m/s (more than the gate lets
    through, less than :data:`fusion.engine.SPEED_REACQUIRE_M_S`) and stays there is taken again
    after ``reacquire_after_rejections`` refusals: the speed state follows the wheel, which the
    filter cannot tell from a speed state that drifted. Within 0.1 m/s of the stepped wheel speed
    0.5 s after the step (the re-acquisition sets it to the reading, 0.05 m/s its sigma)."""
    from fusion.engine import SPEED_REACQUIRE_M_S

    imu = drive.imu[drive.imu["t_s"] < 12.0].copy()
    vision = drive.vision[drive.vision["t_s"] < 12.0]
    step = 1.5
    assert step < SPEED_REACQUIRE_M_S
    after = imu["t_s"] >= 8.0
    imu.loc[after, "speed_m_s"] += step
    run = fuse(imu, vision, lever_arm_m=drive.lever_arm_m, options=OPTIONS)
    assert run.counts["speed_reacquired"] == 1 and run.counts["speed_implausible"] == 0
    late = run.fused[run.fused["t_s"] >= 8.5]
    wheel = np.interp(late["t_s"], imu["t_s"], imu["speed_m_s"])
    assert np.max(np.abs(late["speed_m_s"].to_numpy() - wheel)) < 0.1


def test_a_drive_that_starts_in_a_turn_without_a_calibration_is_warned(drive):
    """In a turn the yaw-rate bias and the world roll trade in the centripetal term; a drive cut
    to start at its first curve's roll-in had the bank 0.4 deg RMS off for 15 s (the bench's 60 s
    drive from 5 s: 0.39 / 0.42 over 2-6 / 6-15 s; 0.02 / 0.04 with a calibration). The run
    says so when the first 2 s turn at over 1.5 deg/s and the yaw-rate gyro's prior is the
    uncalibrated one; not for the drive from its straight start, nor with a calibration."""
    import dataclasses

    def said(run):
        return any("starts in a turn" in w for w in run.warnings)

    imu, vision = drive.imu[drive.imu["t_s"] < 20.0], drive.vision[drive.vision["t_s"] < 20.0]
    assert not said(fuse(imu, vision, lever_arm_m=drive.lever_arm_m, options=OPTIONS))
    cut = imu[imu["t_s"] >= 5.0]
    r = cut["gyro_z_rad_s"][cut["t_s"] < 7.0]
    assert np.degrees(np.abs(r).mean()) > 1.5       # the roll-in: the drive does turn there
    assert said(fuse(cut, vision[vision["t_s"] >= 5.0], lever_arm_m=drive.lever_arm_m, options=OPTIONS))
    calibrated = dataclasses.replace(OPTIONS, noise=dataclasses.replace(OPTIONS.noise, init_gyro_bias_rad_s=math.radians(0.02)))
    assert not said(fuse(cut, vision[vision["t_s"] >= 5.0], lever_arm_m=drive.lever_arm_m, options=calibrated))


def test_a_bad_first_wheel_speed_is_still_re_acquired(drive):
    """A wheel speed of 0 for the first 0.3 s of a drive at 80 km/h (a sensor that starts late):
    the speed state, set from it, is taken again from the wheel after 10 refusals, as before the
    sensor-fault bound, which holds only once the wheel has confirmed the state for 2 s (the
    bound had held that state at 0 against the right readings for seconds, a review). The
    speed within 0.1 m/s of the truth from 1 s on (the re-acquisition sets it to the reading,
    0.05 m/s its sigma)."""
    from fusion.engine import SPEED_CONFIRMED_S

    imu = drive.imu[drive.imu["t_s"] < 6.0].copy()
    imu.loc[imu["t_s"] < 0.3, "speed_m_s"] = 0.0
    assert 0.3 < SPEED_CONFIRMED_S
    run = fuse(imu, drive.vision[drive.vision["t_s"] < 6.0], lever_arm_m=drive.lever_arm_m, options=OPTIONS)
    assert run.counts["speed_reacquired"] == 1 and run.counts["speed_implausible"] == 0
    late = run.fused[run.fused["t_s"] >= 1.0]
    assert np.max(_abs_error(late, drive.truth, "speed_m_s")) < 0.1
