"""Real frames recorded by others (../shared/data, see its README): KITTI with OXTS truth and the
Udacity highway frames. The estimator finds the lanes or says why not, never raises; on KITTI
its pitch, brought into the IMU frame with the calibration files, agrees with OXTS."""

import math

import cv2
import numpy as np
import pytest

from conftest import shared_data_dir

from vision import Camera, Mount, RoadMarkings
from vision.estimator import Estimator, _R_o_from_cp
from vision.frames import rpy_from_R
from vision.options import EstimatorOptions

DATA = shared_data_dir()
KITTI = DATA / "kitti_2011_09_26_drive_0001"
UDACITY = DATA / "udacity_advanced_lane_lines"

needs_kitti = pytest.mark.skipif(not KITTI.is_dir(), reason=f"{KITTI} not present")
needs_udacity = pytest.mark.skipif(not UDACITY.is_dir(), reason=f"{UDACITY} not present")


def _calib(name: str) -> dict:
    out = {}
    for line in (KITTI / name).read_text().splitlines():
        key, _, value = line.partition(":")
        try:
            out[key.strip()] = np.array([float(x) for x in value.split()])
        except ValueError:
            pass
    return out


def kitti_setup():
    """Camera 02 (rectified, P_rect_02), the rotation from the OXTS IMU frame (x forward, y left,
    z up) to the rectified camera frame (R_rect_00 R_velo_to_cam R_imu_to_velo), and a mount
    1.65 m high (KITTI setup) tilted as the calibration says."""
    c2c, i2v, v2c = _calib("calib_cam_to_cam.txt"), _calib("calib_imu_to_velo.txt"), _calib("calib_velo_to_cam.txt")
    R_cp_from_imu = c2c["R_rect_00"].reshape(3, 3) @ v2c["R"].reshape(3, 3) @ i2v["R"].reshape(3, 3)
    P = c2c["P_rect_02"].reshape(3, 4)
    camera = Camera(1242, 375, P[0, 0], P[1, 1], P[0, 2], P[1, 2])
    axis = R_cp_from_imu.T @ np.array([0.0, 0.0, 1.0])
    mount = Mount(1.65, math.atan2(-axis[2], axis[0]))
    return camera, mount, R_cp_from_imu


def kitti_results():
    camera, mount, R_cp_from_imu = kitti_setup()
    est = Estimator(camera, mount, RoadMarkings(3.5, 0.12, False), EstimatorOptions())
    rows = []
    for f in sorted((KITTI / "2011_09_26_drive_0001_sync" / "image_02" / "data").glob("*.png")):
        i = int(f.stem)
        oxts = np.array([float(x) for x in (KITTI / "2011_09_26_drive_0001_sync" / "oxts" / "data" /
                                            f"{i:010d}.txt").read_text().split()])
        e = est.estimate(cv2.imread(str(f)))
        if e.valid:
            # The IMU's attitude relative to the road: R_o_from_imu = R_o_from_cp R_cp_from_imu;
            # ZYX roll (left side up positive) and pitch (front down positive): KITTI's convention.
            roll, pitch, _ = rpy_from_R(_R_o_from_cp(*e.camera_xyz_rad) @ R_cp_from_imu)
            rows.append((i, True, math.degrees(roll), math.degrees(pitch), math.degrees(oxts[3]), math.degrees(oxts[4])))
        else:
            rows.append((i, False, e.reason, None, math.degrees(oxts[3]), math.degrees(oxts[4])))
    return rows


@pytest.fixture(scope="module")
def kitti():
    return kitti_results()


@needs_kitti
def test_kitti_runs_and_finds_lanes(kitti):
    """Ten real frames: lanes or a reason, no exception; lanes on some frames (2 of 10 pass the
    plausibility checks today: 1 and 25; 2 and 3 did too before `01f8844`, whose extra refinement
    passes leave them one line, bisected by a review of the fifteenth session). No painted line
    bounds the lane on the right (a kerb, then tram tracks), so the right "line" is the kerb (25)
    or a rail (1, 4.8 m right); the others see one line, lines too close, or fail."""
    assert len(kitti) == 10
    assert all(r[1] or r[2] for r in kitti)
    assert sum(r[1] for r in kitti) >= 2


@needs_kitti
def test_kitti_pitch_agrees_with_oxts(kitti):
    """Pitch relative to the road against OXTS pitch relative to level: within 0.3 deg, measured
    -0.11 deg on frame 1 and -0.01 on frame 25 (OXTS gives its pitch to 0.03 deg; the camera to
    IMU calibration and the city street's grade, a few tenths, make the rest). OXTS pitch is 0.46
    and 0.65 deg on these frames, so a pitch of 0 or of the wrong sign fails (the 2 deg allowed
    before let both pass, a review). The lane direction needs only parallel lines: a kerb serves."""
    checked = 0
    for i, valid, roll, pitch, oxts_roll, oxts_pitch in kitti:
        if valid:
            assert abs(pitch - oxts_pitch) < 0.3, (i, pitch, oxts_pitch)
            checked += 1
    assert checked >= 2


# Roll, measured on the ten frames (2011_09_26_drive_0001, Karlsruhe, city; see the images):
# * The ego lane has ONE painted line, the dashed lane line on its left (Leitlinie, RMS narrow
#   line 0.12 m). On its right there is no marking: a concrete kerb, then the tram tracks. The
#   second marking is the solid line 3.1 to 3.5 m further left (centre to centre, BEV at the OXTS
#   pose), bounding the parking strip: in town RMS allows a broad line there (0.25 m), and the
#   estimator's area widths make it 22 to 29 cm on 9 of 10 frames (frame 25, in shadow: 14 cm).
# * Default options (the fixture): the pair is the dashed line with the kerb or a rail, neither
#   a flat marking of any width, so eq. (8) has no true width ratio to use. Roll minus OXTS roll:
#   frame 1 -2.7, 25 -5.9 deg (fifteenth session; before `01f8844`: 1 -2.3, 2 +7.8, 3 -1.1, 25 -4.5).
# * The rule widths on the two painted lines (RoadMarkings(3.25, 0.12, False, marker_widths_m=
#   (0.25, 0.12, 0.12)), BEV limited to y in [-0.6, 8] m so the kerb is out of view; lane width
#   3.25 m, RASt 06, the BEV's 3.1 to 3.5 m agreeing): with the default re-warps no frame is valid
#   (the solve moves the roll by 3 to 10 deg and a line is lost in the BEV warped there); with one
#   warp (rewarp_deg=inf) 8 frames are valid and roll minus OXTS roll is frame
#   0 +1.7, 1 +4.9, 2 +4.2, 3 +4.0, 25 +10.7, 45 +5.7, 65 +2.6, 85 +3.2 deg (line spacing then
#   3.6 to 7.8 m: the roll that balances the rule widths is not the road's).
# * Why: on this pair (1.2 m and 4.5 m left, camera 1.65 m up) the width ratio changes by about
#   7 % per degree of roll, so 2 deg needs the ratio to 14 %. At the OXTS pose (no bank) the
#   measured ratio dashed/solid is 0.57 to 0.66 with the default area edges, 0.66 to 0.91 with
#   half-level ("subpixel") edges and 1.2 to 1.6 with binary edges (frame 25 left out: 1.05, 1.14,
#   1.22), against the rule's 0.48: the paint here is not at the nominal widths, or the edges do
#   not measure them, to 14 %.
# * OXTS roll is relative to gravity, the estimate relative to the road surface: a 2.5 % crossfall
#   (RASt 06 minimum) is 1.4 deg of the 2 deg allowed, and it is not known here.
@needs_kitti
@pytest.mark.xfail(strict=True, reason=(
    "eq. (8) needs the two markers' widths known to about 14 % on this road; the ego lane has one "
    "painted line (the kerb or a rail is taken as the other: roll off by -2.7 and -5.9 deg on the two valid frames), and "
    "with the RMS widths (broad 0.25 m solid, narrow 0.12 m dashed) on the two painted lines the "
    "measured width ratio is 0.57 to 0.66, not 0.48: roll off by +1.7 to +10.7 deg (see above)"))
def test_kitti_roll_agrees_with_oxts(kitti):
    for i, valid, roll, pitch, oxts_roll, oxts_pitch in kitti:
        if valid:
            assert abs(roll - oxts_roll) < 2.0, (i, roll, oxts_roll)


def udacity_camera() -> Camera:
    """Calibrated from the 9x6 chessboards of the same camera (OpenCV, 17 of 20 boards found)."""
    objp = np.zeros((54, 3), np.float32)
    objp[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2)
    obj, pts = [], []
    for f in sorted((UDACITY / "camera_cal").glob("*.jpg")):
        g = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        ok, corners = cv2.findChessboardCorners(g, (9, 6), flags=cv2.CALIB_CB_FAST_CHECK | cv2.CALIB_CB_ADAPTIVE_THRESH)
        if ok:
            obj.append(objp)
            pts.append(corners)
    _, K, dist, _, _ = cv2.calibrateCamera(obj, pts, (1280, 720), None, None)
    return Camera(1280, 720, K[0, 0], K[1, 1], K[0, 2], K[1, 2], tuple(float(x) for x in dist.ravel()[:5]))


@needs_udacity
def test_udacity_frames_give_lanes_or_reasons():
    """Eight highway frames, lens distortion folded into the BEV warp. Mounting height and tilt
    are not known (1.5 m, level assumed): lanes on most frames, plausible geometry where found
    (lines 2.5 to 6 m apart, a near-level camera), a reason otherwise, no exception."""
    camera = udacity_camera()
    est = Estimator(camera, Mount(1.5, 0.0), RoadMarkings(3.7, 0.15, False), EstimatorOptions())
    valid = 0
    for f in sorted((UDACITY / "test_images").glob("*.jpg")):
        e = est.estimate(cv2.imread(str(f)), seed=(0.0, 0.0, 0.0))
        if e.valid:
            valid += 1
            assert 2.5 < e.line_spacing_m < 6.0
            assert abs(math.degrees(e.pitch_rad)) < 5.0
        else:
            assert e.reason
    assert valid >= 4
