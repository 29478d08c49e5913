"""``vifusion vision`` and the frame sources: files in, vision.csv out, one-line errors."""

import shutil
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from drivesim.drive import build_road, render_frames, truth_frame
from drivesim.scenario import parse_scenario
from drivesim.trajectory import Trajectory
from fusion.cli import main
from vision.errors import VisionError
from vision.video import VISION_COLUMNS, FrameSource, count_frames

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    """Five 640x360 frames of Table I scenario 1 as PNGs, frames.csv, a config, the truth."""
    root = tmp_path_factory.mktemp("drive")
    data = tomllib.loads((ROOT / "configs" / "scenarios" / "alrazouk_s1_hd.toml").read_text())
    data["camera"]["width"], data["camera"]["height"] = 640, 360
    sc = parse_scenario(data, "s1_small")
    road = build_road(sc)
    traj = Trajectory(road, sc.motion)
    t = 2.0 + np.arange(5) / 30.0
    (root / "frames").mkdir()
    for i, img in enumerate(render_frames(sc, t, road=road, traj=traj)):
        cv2.imwrite(str(root / "frames" / f"{i:04d}.png"), img)
    pd.DataFrame({"frame": np.arange(5), "t_s": 100.0 + t}).to_csv(root / "frames.csv", index=False)
    c = sc.camera
    (root / "config.toml").write_text(
        f"[camera]\nwidth = {c.width}\nheight = {c.height}\nfx = {c.fx}\nfy = {c.fy}\ncx = {c.cx}\ncy = {c.cy}\n"
        f"[mount]\nheight_m = 1.1\ntilt_deg = 15.0\n"
        f"[road]\nlane_width_m = 3.5\nmarker_width_m = 0.15\ncenter_line = false\n"
        f"[video]\nfps = 30.0\nstart_s = 5.0\n")
    truth = truth_frame(traj, t, t)
    return root, truth


def test_vision_command_writes_the_table(drive, tmp_path):
    root, truth = drive
    out = tmp_path / "vision.csv"
    dbg = tmp_path / "new" / "debug.avi"     # its folder made, as --out's is (it was refused, a review)
    rc = main(["vision", "--video", str(root / "frames"), "--frames", str(root / "frames.csv"),
               "--config", str(root / "config.toml"), "--out", str(out), "--debug-video", str(dbg), "--quiet"])
    assert rc == 0
    v = pd.read_csv(out)
    assert tuple(v.columns) == VISION_COLUMNS
    assert list(v.columns[:6]) == ["t_s", "frame", "roll_deg", "pitch_deg", "yaw_deg", "valid"]
    assert len(v) == 5 and v["valid"].all()
    assert v["t_s"].to_numpy() == pytest.approx(100.0 + 2.0 + np.arange(5) / 30.0)
    # The same tolerances as the rendered tests (640x360): roll 0.6 deg, pitch 0.05 deg.
    assert np.abs(v["roll_deg"] - truth["roll_deg"]).max() < 0.6
    assert np.abs(v["pitch_deg"] - truth["pitch_deg"]).max() < 0.05
    assert not (tmp_path / "vision.csv.partial").exists()
    cap = cv2.VideoCapture(str(dbg))
    ok, pic = cap.read()
    cap.release()
    assert ok and pic.shape[0] > 360 and pic.shape[1] == 640 + 320    # frame, BEV; text strip under them
    grey = cv2.imread(str(root / "frames" / "0000.png"))
    # no text box over the frame: its top-left corner is the frame's (the codec's loss aside)
    assert np.abs(pic[:40, :200].astype(int) - grey[:40, :200].astype(int)).mean() < 6


def test_frame_times_from_the_config_without_frames_csv(drive, tmp_path):
    root, _ = drive
    out = tmp_path / "v.csv"
    assert main(["vision", "--video", str(root / "frames"), "--config", str(root / "config.toml"),
                 "--out", str(out), "--quiet", "--method", "alrazouk"]) == 0
    assert pd.read_csv(out)["t_s"].to_numpy() == pytest.approx(5.0 + np.arange(5) / 30.0)


def test_missing_video_is_a_one_line_error(drive, tmp_path, capsys):
    root, _ = drive
    rc = main(["vision", "--video", str(tmp_path / "nope.mp4"), "--config", str(root / "config.toml"),
               "--out", str(tmp_path / "v.csv")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith("error: ") and "nope.mp4" in err and "\n" not in err


def _copy_frames(root: Path, to: Path, ext: str = ".png") -> list[Path]:
    """The drive's five pictures copied to ``to`` (re-encoded by OpenCV for another ``ext``)."""
    to.mkdir()
    out = []
    for f in sorted((root / "frames").iterdir()):
        out.append(to / (f.stem + ext))
        cv2.imwrite(str(out[-1]), cv2.imread(str(f)))
    return out


def _vision_of_folder(root: Path, tmp_path: Path, capfd):
    """``vifusion vision`` of ``tmp_path / "frames"`` with the drive's frames.csv and config: the
    table written and what was printed (exit 0 checked)."""
    out = tmp_path / "v.csv"
    rc = main(["vision", "--video", str(tmp_path / "frames"), "--frames", str(root / "frames.csv"),
               "--config", str(root / "config.toml"), "--out", str(out), "--quiet", "--workers", "1"])
    said = capfd.readouterr()
    assert rc == 0, said.err
    return pd.read_csv(out), said


@pytest.mark.parametrize("bad", ["text", "cut", "empty", "dangling"])
def test_an_unreadable_picture_is_a_frame_skipped_and_said(drive, tmp_path, capfd, bad):
    """Picture 0002 of five is text, a PNG cut to 500 bytes, an empty file or a link to nothing:
    its frame is skipped, its row invalid with the reason, counted on the summary line and
    warned with the picture's name; the other frames are estimated. It had ended the run with
    exit 2 and nothing written (a review: after 12 s of a 4000-picture folder), and libpng's
    own "Read Error" line came raw on stderr."""
    root, _ = drive
    pictures = _copy_frames(root, tmp_path / "frames")
    if bad == "text":
        pictures[2].write_bytes(b"not a png")
    elif bad == "cut":
        pictures[2].write_bytes(pictures[2].read_bytes()[:500])
    elif bad == "empty":
        pictures[2].write_bytes(b"")
    else:
        pictures[2].unlink()
        pictures[2].symlink_to(tmp_path / "nowhere.png")
    v, said = _vision_of_folder(root, tmp_path, capfd)
    assert list(v["frame"]) == [0, 1, 2, 3, 4] and list(v["valid"]) == [1, 1, 0, 1, 1]
    assert v["reason"][2].startswith("unreadable picture") and np.isnan(v["roll_deg"][2])
    assert "1 unreadable picture(s) skipped" in said.out
    warned = [line for line in said.err.splitlines() if "0002.png" in line]
    assert len(warned) == 1 and warned[0].startswith("warning: ") and "1 of the 5 frames" in warned[0], said.err
    assert all(line.startswith("warning: ") for line in said.err.splitlines()), said.err   # nothing raw


def test_a_folder_of_unreadable_pictures_is_a_one_line_error(drive, tmp_path, capsys):
    """None of the pictures readable: an error before any frame is estimated, nothing written."""
    (tmp_path / "frames").mkdir()
    for k in range(3):
        (tmp_path / "frames" / f"{k:04d}.png").write_bytes(b"not a png")
    out = tmp_path / "v.csv"
    rc = main(["vision", "--video", str(tmp_path / "frames"), "--config", str(drive[0] / "config.toml"),
               "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith("error: ") and "\n" not in err
    assert "none of the 3 pictures" in err and "0000.png" in err
    assert not list(tmp_path.glob("v.csv*"))


def test_a_damaged_jpeg_is_an_unreadable_picture(drive, tmp_path, capfd):
    """JPEG 0002's entropy-coded data from its middle on overwritten (its end marker kept), as a
    review did: OpenCV returns a picture, grey or garbled below the damage, and libjpeg prints
    "Corrupt JPEG data: premature end of data segment" naming no file; 8 of 11 such frames had
    stayed valid, roll up to 0.24 deg off. Now it is an unreadable picture (F1's skip), the
    libjpeg line in its reason and the warning, not raw on stderr."""
    root, _ = drive
    pictures = _copy_frames(root, tmp_path / "frames", ".jpg")
    data = bytearray(pictures[2].read_bytes())
    data[len(data) // 2:-2] = b"\x55" * (len(data) - 2 - len(data) // 2)
    pictures[2].write_bytes(bytes(data))
    assert cv2.imread(str(pictures[2])) is not None     # OpenCV alone takes it for a picture
    capfd.readouterr()
    v, said = _vision_of_folder(root, tmp_path, capfd)
    assert list(v["valid"]) == [1, 1, 0, 1, 1]
    assert v["reason"][2].startswith("unreadable picture: damaged JPEG data (libjpeg: Corrupt JPEG data")
    assert any("0002.jpg" in line and "damaged JPEG data" in line for line in said.err.splitlines()), said.err
    assert all(line.startswith("warning: ") for line in said.err.splitlines()), said.err


def test_which_libjpeg_lines_are_damage(tmp_path, capfd):
    """libjpeg's "N extraneous bytes before marker" for a few bytes (an encoder's padding: the
    picture decodes whole) is not damage; thousands of them, left by junk in the data (100 zero
    bytes in the middle of a picture: 1619 here), and its other "Corrupt JPEG data" and
    "Premature end" lines are."""
    from vision.video import _damage, _decode_picture

    assert not _damage("Corrupt JPEG data: 1 extraneous bytes before marker 0xd9")
    assert _damage("Corrupt JPEG data: 1619 extraneous bytes before marker 0xd9")
    assert _damage("Corrupt JPEG data: premature end of data segment")
    assert _damage("Corrupt JPEG data: bad Huffman code")
    assert _damage("Premature end of JPEG file")
    assert not _damage("libpng warning: iCCP: known incorrect sRGB profile")
    img = (np.random.default_rng(0).random((180, 320, 3)) * 255).astype(np.uint8)
    data = cv2.imencode(".jpg", img)[1].tobytes()
    mid = len(data) // 2
    (tmp_path / "junk.jpg").write_bytes(data[:mid] + bytes(100) + data[mid + 100:])
    got, why = _decode_picture(tmp_path / "junk.jpg")
    assert got is None and "extraneous bytes" in why and capfd.readouterr().err == ""


def test_frame_source_order_and_errors(tmp_path):
    for name in ("b.png", "a.jpg", "c.txt"):
        img = np.full((4, 6, 3), 7 if name.startswith("a") else 9, np.uint8)
        if name.endswith("txt"):
            (tmp_path / name).write_text("x")
        else:
            cv2.imwrite(str(tmp_path / name), img)
    src = FrameSource(tmp_path)
    assert [p.name for p in src.files] == ["a.jpg", "b.png"] and len(src) == 2 and count_frames(tmp_path) == 2
    with pytest.raises(VisionError, match="no such"):
        FrameSource(tmp_path / "missing")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(VisionError, match="no .png"):
        FrameSource(empty)
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"\x00" * 100)
    with pytest.raises(VisionError, match="cannot open"):
        FrameSource(junk)


def test_the_table_does_not_depend_on_the_number_of_workers(tmp_path):
    """The sample drive's mp4 (12 s: two pieces, the second seeking to its start and warming up
    on the 3 s before it, vision.video.WARM_UP_S) gives the same table, bit for bit, with one,
    two and three workers, and with one worker writing the debug video (one frame per row).
    Where the video is cut depends on the video alone: the rows after a cut differ from those
    of a run through it (the estimator's state carried in differs by little, and on some runoff
    frames the lines found and the twist map's decisions turn that into other angles: with the
    cut where the number of workers put it, the 60 s HD drive's vision yaw differed by up to 1.9
    deg on 47 frames of a runoff between one worker and two, the fused roll 0.101 against 0.082
    deg). The accuracy against truth: the roll within 1 deg RMS (the sample drive's vision roll
    RMSE is 0.61 deg, its bank runoffs)."""
    from fusion.config import load_config
    from fusion.drive import SAMPLE_DRIVE
    from vision.video import estimate_video

    cfg = load_config(SAMPLE_DRIVE / "config.toml")
    frames = pd.read_csv(SAMPLE_DRIVE / "frames.csv")
    # Two frames past the end of the video: counted as missing by every run.
    frames = pd.concat([frames, pd.DataFrame({"frame": [10_000, 10_001], "t_s": [99.0, 99.1]})], ignore_index=True)
    truth = pd.read_csv(SAMPLE_DRIVE / "truth_frames.csv").set_index("frame")
    dbg = tmp_path / "dbg.mp4"
    runs = {w: estimate_video(SAMPLE_DRIVE / "video.mp4", frames, cfg.camera, cfg.mount, cfg.road,
                              progress=False, workers=w) for w in (1, 2, 3)}
    runs["debug"] = estimate_video(SAMPLE_DRIVE / "video.mp4", frames, cfg.camera, cfg.mount, cfg.road,
                                   progress=False, workers=2, debug_video=dbg)
    one, s1 = runs[1]
    assert s1["pieces"] == 2 and s1["workers"] == 1
    assert [runs[k][1]["workers"] for k in (2, 3, "debug")] == [2, 2, 1]   # no more workers than pieces
    for key, (tab, stats) in runs.items():
        assert stats["pieces"] == 2
        assert stats["frames_missing"] == 2 and stats["frames_read"] == len(frames) - 2
        pd.testing.assert_frame_equal(tab.drop(columns="estimator_ms"), one.drop(columns="estimator_ms"), obj=str(key))
    cap = cv2.VideoCapture(str(dbg))
    n_debug = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    assert n_debug == len(one)
    ok = one[one["valid"] == 1]
    rmse = float(np.sqrt(np.mean((ok["roll_deg"].to_numpy() - truth.loc[ok["frame"], "roll_deg"].to_numpy()) ** 2)))
    assert rmse < 1.0


def test_where_the_video_is_cut_depends_on_the_video_alone():
    """Two pieces per started minute of video, one where a piece would be shorter than its
    warm-up and 60 frames: the cut does not move with the number of processes."""
    from vision.video import PIECES_PER_MINUTE, piece_count

    assert PIECES_PER_MINUTE == 2
    assert piece_count(1800, 30.0, 90) == 2          # the 60 s HD drive
    assert piece_count(1801, 30.0, 90) == 4
    assert piece_count(600, 30.0, 90) == 2           # 20 s
    assert piece_count(360, 30.0, 90) == 2           # the 12 s sample drive
    assert piece_count(299, 30.0, 90) == 1           # shorter than two warm-ups and minimum pieces
    assert piece_count(18_000, 30.0, 90) == 20       # ten minutes
    assert piece_count(0, 30.0, 90) == 1


def test_pieces_give_every_worker_the_same_frames_to_estimate():
    """The pieces cover the frames once, in order, and every piece costs the same number of
    frames counting the warm-up before it (within one): the run's wall time is the slowest
    worker's, and equal pieces left the last ones longer by the warm-up (30 frames, 0.2 s on
    the HD drive)."""
    from vision.video import _piece_starts

    for n, pieces, warm in ((1800, 2, 30), (1800, 3, 30), (601, 2, 30), (5000, 8, 30)):
        starts = _piece_starts(n, pieces, warm)
        ends = starts[1:] + [n]
        assert starts[0] == 0 and len(starts) == pieces
        assert all(a < b for a, b in zip(starts, ends))
        work = [(e - s) + (warm if s > 0 else 0) for s, e in zip(starts, ends)]
        assert max(work) - min(work) <= 1, (n, pieces, work)
    # too few frames for the warm-up to be evened out: plain equal pieces
    assert _piece_starts(120, 4, 30) == [0, 30, 60, 90]


def test_grey_frames_come_from_the_luma_plane(tmp_path):
    """The estimator reads a video's grey straight from the decoded luma plane. Flat grey
    frames written by OpenCV come back within 1 level of what was written (through BGR and
    BGR2GRAY they come back 1 to 2 levels darker), and a seek gives the frames, numbered, that
    decoding from the start gives, bit for bit."""
    from fusion.drive import SAMPLE_DRIVE
    from vision.video import _frames_from

    levels = (20, 60, 100, 140, 180, 220, 250)
    path = tmp_path / "grey.mp4"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (320, 240))
    for v in levels:
        w.write(np.full((240, 320, 3), v, np.uint8))
    w.release()
    got = [(i, img) for i, img in _frames_from(FrameSource(path), 0, luma=True)]
    assert [i for i, _ in got] == list(range(len(levels)))
    assert all(img.ndim == 2 and img.dtype == np.uint8 for _, img in got)
    assert max(abs(float(img.mean()) - v) for (_, img), v in zip(got, levels)) <= 1.0

    src = FrameSource(SAMPLE_DRIVE / "video.mp4")
    from_start = {i: img for i, img in _frames_from(src, 0, luma=True) if 150 <= i < 160}
    seeked = []
    for i, img in _frames_from(src, 150, luma=True):
        if i >= 160:
            break
        seeked.append((i, img))
    assert [i for i, _ in seeked] == list(range(150, 160))
    assert all(np.array_equal(img, from_start[i]) for i, img in seeked)
    # and they are the pictures OpenCV decodes (up to its colour round trip)
    bgr = {i: img for _, (i, img) in zip(range(10), _frames_from(src, 150))}
    assert max(np.abs(cv2.cvtColor(bgr[i], cv2.COLOR_BGR2GRAY).astype(int) - img).max() for i, img in seeked) <= 3


def test_a_corrupt_video_is_read_up_to_the_damage(tmp_path):
    """30 kB of noise in the middle of the sample drive's mp4: the grey frames stop where
    OpenCV's reader stops (the frames after it count as missing), without an exception."""
    from fusion.drive import SAMPLE_DRIVE
    from vision.video import _frames_from

    path = tmp_path / "corrupt.mp4"
    data = bytearray((SAMPLE_DRIVE / "video.mp4").read_bytes())
    mid = len(data) // 2
    data[mid:mid + 30_000] = np.random.default_rng(0).integers(0, 256, 30_000, dtype=np.uint8).tobytes()
    path.write_bytes(bytes(data))
    src = FrameSource(path)
    n_bgr = sum(1 for _ in _frames_from(src, 0))
    n_grey = sum(1 for _ in _frames_from(src, 0, luma=True))
    assert 0 < n_grey == n_bgr < len(FrameSource(SAMPLE_DRIVE / "video.mp4"))


def test_a_numbered_picture_missing_is_a_missing_frame(tmp_path):
    """Pictures named by number (000000.png ...) are frames at their number less the first's:
    with 000002.png missing, 000003.png is frame 3, timed by frames.csv's row for frame 3, and
    frame 2 is missing. Before, name order made it frame 2: every picture after a gap took the
    time of the one before it (a review). Numbers of different widths sort by value; numbers that
    skip more values than there are pictures are times, taken in name order."""
    from vision.video import _frames_from

    for n in (0, 1, 3, 4, 5):
        cv2.imwrite(str(tmp_path / (f"{n:06d}.png" if n < 5 else f"{n}.png")), np.full((4, 6, 3), n, np.uint8))
    src = FrameSource(tmp_path)
    assert len(src) == 6 and src.files[2] is None
    got = {i: int(img[0, 0, 0]) for i, img in _frames_from(src, 0)}
    assert got == {0: 0, 1: 1, 3: 3, 4: 4, 5: 5}
    # names that are nanosecond times (a review: 100,000,001 slots, 877 MB) stay in name order
    stamps = tmp_path / "stamps"
    stamps.mkdir()
    for k in range(3):
        cv2.imwrite(str(stamps / f"{1403636579763555584 + k * 50_000_000}.png"), np.full((4, 6, 3), k, np.uint8))
    assert len(FrameSource(stamps)) == 3
    # a stray copy among numbered pictures: the whole folder went to name order and every frame
    # after it took the picture before its own, without a word (a review); now an error
    cv2.imwrite(str(tmp_path / "000003 - Copy.png"), np.full((4, 6, 3), 9, np.uint8))
    with pytest.raises(VisionError, match="5 numbered pictures and 1 other names .000003 - Copy.png"):
        FrameSource(tmp_path)


def test_a_folder_of_every_third_frame_named_by_number(tmp_path):
    """Every third frame kept, each picture named by its original number (000000, 000003, ...),
    with the frames.csv that lists 0, 3, 6, ...: picture 000009.png is frame 9. Before, numbers
    that skip more values than there are pictures were taken in name order, so that picture k
    became frame k, stamped with another frame's time (a review: vision roll 4.3 deg RMS
    against 0.85 on the whole folder, one warning about 'missing' frames). The listed frames
    decide: listing positions 0..n-1 instead keeps name order; without a listing the old rule."""
    from vision.video import _frames_from

    for n in range(0, 30, 3):
        cv2.imwrite(str(tmp_path / f"{n:06d}.png"), np.full((4, 6, 3), n, np.uint8))
    src = FrameSource(tmp_path, range(0, 30, 3))
    got = {i: int(img[0, 0, 0]) for i, img in _frames_from(src, 0)}
    assert got == {n: n for n in range(0, 30, 3)}
    src = FrameSource(tmp_path, range(10))          # frames.csv by position
    assert {i: int(img[0, 0, 0]) for i, img in _frames_from(src, 0)} == {k: 3 * k for k in range(10)}
    assert len(FrameSource(tmp_path)) == 10        # no listing: name order, as before


def test_numbered_names_not_taken_as_frame_numbers_are_said(drive, tmp_path, capsys):
    """The drive's five pictures named 0, 1, 2, 25, 45 (numbers that skip more values than there
    are pictures): they are frames 0-4 in name order, as the README's rule says, and the run now
    says so with how to give their times; listed by number in a frames.csv they are frames 0, 1,
    2, 25, 45 and nothing is said. A review found picture 25 of KITTI's folder at 0.6 s for 2.5 s
    without a word."""
    root, _ = drive
    (tmp_path / "frames").mkdir()
    for f, n in zip(sorted((root / "frames").iterdir()), (0, 1, 2, 25, 45)):
        shutil.copy(f, tmp_path / "frames" / f"{n:06d}.png")
    out = tmp_path / "v.csv"
    assert main(["vision", "--video", str(tmp_path / "frames"), "--config", str(root / "config.toml"),
                 "--out", str(out), "--quiet", "--workers", "1"]) == 0
    err = capsys.readouterr().err
    said = [line for line in err.splitlines() if "not taken as frame numbers" in line]
    assert len(said) == 1 and said[0].startswith("warning: ") and "(0 to 45)" in said[0], err
    assert "frames 0 to 4 in name order" in said[0] and "frames.csv" in said[0]
    assert list(pd.read_csv(out)["frame"]) == [0, 1, 2, 3, 4]
    listed = tmp_path / "frames.csv"
    pd.DataFrame({"frame": [0, 1, 2, 25, 45], "t_s": [0.0, 0.1, 0.2, 2.5, 4.5]}).to_csv(listed, index=False)
    assert main(["vision", "--video", str(tmp_path / "frames"), "--frames", str(listed), "--config",
                 str(root / "config.toml"), "--out", str(out), "--quiet", "--workers", "1"]) == 0
    assert "not taken as frame numbers" not in capsys.readouterr().err
    assert list(pd.read_csv(out)["t_s"]) == [0.0, 0.1, 0.2, 2.5, 4.5]


def test_kittis_folder_in_name_order_is_said():
    """The shared KITTI folder (pictures 0-5, 25, 45, 65, 85), read only: without frames.csv a
    warning says its names are not taken as frame numbers; a frames.csv listing 0-9 (by
    position) decides it, and nothing is said."""
    from conftest import shared_data_dir

    from fusion.drive import frames_warnings, read_frame_times
    from fusion.config import VideoTiming

    folder = shared_data_dir() / "kitti_2011_09_26_drive_0001" / "2011_09_26_drive_0001_sync" / "image_02" / "data"
    if not folder.is_dir():
        pytest.skip(f"{folder} not present")
    frames = read_frame_times(None, VideoTiming(10.0, 0.0), count_frames(folder))
    said = [w for w in frames_warnings(folder, frames, None, 10.0) if "not taken as frame numbers" in w]
    assert len(said) == 1 and "(0 to 85)" in said[0] and "[video] start_s + frame / fps" in said[0], said
    assert not [w for w in frames_warnings(folder, frames, Path("frames.csv"), 10.0) if "frame numbers" in w]


def _video_and_pictures(tmp_path: Path, fps: float = 15.0, n: int = 10) -> tuple[Path, Path]:
    """The same ``n`` small frames as an AVI whose container says ``fps`` and as a folder of PNGs."""
    video, folder = tmp_path / "v.avi", tmp_path / "pictures"
    folder.mkdir()
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), fps, (64, 48))
    for k in range(n):
        img = np.full((48, 64, 3), 10 * k, np.uint8)
        writer.write(img)
        cv2.imwrite(str(folder / f"{k:06d}.png"), img)
    writer.release()
    return video, folder


def test_a_config_fps_that_is_not_the_containers_is_said(tmp_path):
    """A video whose container says 15 fps, timed without frames.csv by ``[video] fps = 30``:
    every time was halved without a word, while the same mismatch through a frames.csv was
    said (a review). Now the warning names both rates and which one times the frames; a config
    that agrees says nothing, nor does 29.97 against 30 on a few frames (a thirtieth of a frame)."""
    from fusion.config import VideoTiming
    from fusion.drive import frames_warnings, read_frame_times

    video, _ = _video_and_pictures(tmp_path)

    def warned(fps):
        frames = read_frame_times(None, VideoTiming(fps, 0.0), count_frames(video))
        return [w for w in frames_warnings(video, frames, None, fps) if "[video] fps" in w]

    said = warned(30.0)
    assert len(said) == 1 and "[video] fps = 30 is not its container's 15 fps" in said[0], said
    assert "timed at 30 fps" in said[0] and "0.3 s off" in said[0] and "frames.csv" in said[0]
    assert warned(15.0) == []
    (tmp_path / "ntsc").mkdir()
    video, _ = _video_and_pictures(tmp_path / "ntsc", 29.97)
    assert warned(30.0) == []


def test_frame_times_in_ns_are_said_for_a_video_and_a_folder(tmp_path):
    """frames.csv with times in nanoseconds read as seconds (t_s about 1.7e18): said for a
    video only, by its container's rate; a folder of the same pictures took them silently (a
    review). One check of the median period, for both, says it now."""
    from fusion.drive import frames_warnings

    video, folder = _video_and_pictures(tmp_path)
    ns = pd.DataFrame({"frame": np.arange(10), "t_s": 1.7e18 + np.arange(10) * 1e9 / 15})
    seconds = ns.assign(t_s=1.7e9 + np.arange(10) / 15)
    for source in (video, folder):
        said = [w for w in frames_warnings(source, ns, Path("frames.csv"), 30.0) if "no camera's" in w]
        assert len(said) == 1 and "6.67e+07 s a frame" in said[0] and "ns given as seconds" in said[0], said
        assert frames_warnings(source, seconds, Path("frames.csv"), 30.0) == []


def test_the_debug_video_is_the_tables_run(tmp_path):
    """With ``--debug-video`` the estimator gets the same grey as without (a video's luma
    plane): it had got OpenCV's colour frames' grey, a few levels off, and the table of a run
    with a debug video was another run's (a review: 7 of 10 KITTI frames valid against 2). The
    debug video's frames all have one size, the BEV panel fitted into half the frame's width
    (the whole picture had been scaled to the first frame's size, stretching the camera half)."""
    from fusion.cli import main as cli_main

    d = Path(__file__).resolve().parents[1] / "fusion" / "data" / "sample_drive"
    frames = pd.read_csv(d / "frames.csv").iloc[:20]
    frames.to_csv(tmp_path / "frames.csv", index=False, float_format="%.9f")
    common = ["vision", "--video", str(d / "video.mp4"), "--frames", str(tmp_path / "frames.csv"),
              "--config", str(d / "config.toml"), "--quiet", "--workers", "1"]
    assert cli_main([*common, "--out", str(tmp_path / "plain.csv")]) == 0
    assert cli_main([*common, "--out", str(tmp_path / "dbg.csv"), "--debug-video", str(tmp_path / "dbg.mp4")]) == 0
    a, b = pd.read_csv(tmp_path / "plain.csv"), pd.read_csv(tmp_path / "dbg.csv")
    pd.testing.assert_frame_equal(a.drop(columns="estimator_ms"), b.drop(columns="estimator_ms"))
    cap = cv2.VideoCapture(str(tmp_path / "dbg.mp4"))
    sizes = set()
    while True:
        ok, pic = cap.read()
        if not ok:
            break
        sizes.add(pic.shape[:2])
    cap.release()
    (h, w), = sizes                               # one size, whatever each frame says
    assert w == 640 + 320 and 360 < h < 360 + 80    # frame and BEV; the text strip under them


def test_the_debug_horizon_stays_where_the_distortion_is_one_to_one():
    """A lens whose radial polynomial folds back inside the ±60 deg of road directions drawn
    (Udacity's k1 = -0.27, k3 = -0.24): the horizon is drawn only where the distorted radius
    still grows, so that it does not cross itself (u had run -9569, -1052, 937, ..., -94, 2402)."""
    from vision.camera import Camera
    from vision.debug import _monotonic_radius

    cam = Camera(1280, 720, 1156.9, 1152.1, 665.9, 388.0, (-0.2416, -0.0527, -0.0012, 0.0002, 0.0))
    folding = Camera(1280, 720, 1156.9, 1152.1, 665.9, 388.0, (-0.27, 0.0, 0.0, 0.0, -0.24))
    r = _monotonic_radius(folding)
    assert 0.5 < r < 1.5
    x = np.linspace(0.0, r * 0.999, 200)
    xd, _ = folding.distort_normalized(x, np.zeros_like(x))
    assert np.all(np.diff(xd) > 0)
    assert _monotonic_radius(cam) > 1.0


def test_what_the_vision_command_says_of_bad_input(drive, tmp_path, capsys):
    """Found by a review, each said now: a camera whose size is not the video's gave exit 0 and
    a table of invalid frames with the reason only in its rows (then a warning with it, as
    `vifusion run` gives; now, as no frame can be of the camera's size, a one-line error before
    any frame is estimated, nothing written; a folder with some pictures of another size goes
    on, each of those refused with the reason in its row); a frames.csv none of whose frames is in the video wrote an empty
    table (now an error); a video cut short was read as whole when it came without frames.csv
    (now a warning: the frames its container announces that could not be read); an output under a
    file was said after the whole video, a debug video left behind (now before any work); a
    focal length of 0.001 px was taken."""
    root, _ = drive
    cfg = (root / "config.toml").read_text()
    wide = tmp_path / "wide.toml"
    wide.write_text(cfg.replace("width = 640", "width = 1280"))
    out = tmp_path / "v.csv"
    assert main(["vision", "--video", str(root / "frames"), "--config", str(wide), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"error: {root / 'frames'}: the pictures are 640x360, but [camera] width x height is 1280x360: "
                   "set [camera] width = 640, height = 360 and the intrinsics (fx, fy, cx, cy) in pixels of that "
                   "size, or give this camera's config"), err
    assert not out.exists()
    mixed = tmp_path / "mixed"
    shutil.copytree(root / "frames", mixed)
    small = mixed / "0002.png"
    cv2.imwrite(str(small), cv2.resize(cv2.imread(str(small)), (320, 180)))
    assert main(["vision", "--video", str(mixed), "--frames", str(root / "frames.csv"), "--config",
                 str(root / "config.toml"), "--out", str(out), "--quiet"]) == 0
    capsys.readouterr()
    rows = pd.read_csv(out)
    assert rows.loc[rows["frame"] == 2, "reason"].item() == "image is 320x180, the camera is 640x360"
    assert rows.loc[rows["frame"] != 2, "valid"].all()

    beyond = tmp_path / "beyond.csv"
    pd.DataFrame({"frame": [100, 101], "t_s": [1.0, 1.1]}).to_csv(beyond, index=False)
    assert main(["vision", "--video", str(root / "frames"), "--frames", str(beyond), "--config",
                 str(root / "config.toml"), "--out", str(tmp_path / "none.csv"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "none of the 2 frames that frames.csv lists" in err and "\n" not in err
    assert not (tmp_path / "none.csv").exists()

    avi = tmp_path / "cut.avi"
    w = cv2.VideoWriter(str(avi), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (640, 360))
    for p in sorted((root / "frames").glob("*.png")) * 6:
        w.write(cv2.imread(str(p)))
    w.release()
    raw = avi.read_bytes()
    avi.write_bytes(raw[: len(raw) // 2])
    n = count_frames(avi)                 # decoded; the container still announces 30
    assert 0 < n < 30
    assert main(["vision", "--video", str(avi), "--config", str(root / "config.toml"), "--out", str(out),
                 "--quiet"]) == 0
    err = capsys.readouterr().err
    assert len(pd.read_csv(out)) == n and f"its container announces 30 frames, {n} could be read" in err, err

    a_file = tmp_path / "a_file"
    a_file.write_text("")
    dbg = tmp_path / "dbg.avi"
    assert main(["vision", "--video", str(root / "frames"), "--config", str(root / "config.toml"),
                 "--out", str(a_file / "v.csv"), "--debug-video", str(dbg), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "is a file, not a folder" in err and "\n" not in err and not dbg.exists()

    tiny_f = tmp_path / "tiny_f.toml"
    tiny_f.write_text(cfg.replace("fx = ", "fx = 0.001\nfx_was = ").replace("fx_was", "#"))
    assert main(["vision", "--video", str(root / "frames"), "--config", str(tiny_f), "--out", str(out),
                 "--quiet"]) == 2
    assert "the focal length is in pixels" in capsys.readouterr().err


def test_a_frame_left_out_of_frames_csv_is_said(drive, tmp_path, capsys):
    """A frames.csv with a frame left out mid-listing: that video frame is not processed, and
    now said (a review found it skipped without a word); a listing of every other frame is
    regular and not said."""
    root, _ = drive
    frames = pd.read_csv(root / "frames.csv")
    for rows, said in (([0, 1, 3, 4], "skip 1 of the video's frames beyond its usual step of 1 (first after frame 1, "
                                      "next listed 3)"), ([0, 2, 4], None)):
        listing = tmp_path / "listing.csv"
        frames.iloc[rows].to_csv(listing, index=False)
        assert main(["vision", "--video", str(root / "frames"), "--frames", str(listing), "--config",
                     str(root / "config.toml"), "--out", str(tmp_path / "v.csv"), "--quiet"]) == 0
        err = capsys.readouterr().err
        assert (said in err) if said else ("skip" not in err), err


def test_the_debug_strip_tells_the_can_clock_with_the_configured_offset(tmp_path, monkeypatch):
    """The debug video's strip says each frame's time on the CAN clock where the fusion places
    it, ``frames.csv``'s time plus ``[fusion] camera_time_offset_s``, and the camera's own under
    it: with an offset of 0.2 s it said 4.000 where the fusion had the frame at 4.200 (a review).
    Through ``vifusion run`` and ``vifusion vision`` alike; without an offset, the strip of three
    lines as before."""
    from fusion.cli import main as cli_main
    from fusion.drive import SAMPLE_DRIVE
    from vision import debug
    from vision.estimator import VisionEstimate

    est = VisionEstimate.invalid("test")
    assert debug.strip_text(est, 1004.0, 1000.0, 0.2) == [
        "invalid: test", "t 4.000 s (CAN clock 1004.200)", "camera clock 1004.000 (-0.200 s from the CAN clock)"]
    assert debug.strip_text(est, 1004.0, 1000.0) == ["invalid: test", "t 4.000 s (CAN clock 1004.000)"]

    told = []
    real = debug.strip_text
    monkeypatch.setattr(debug, "strip_text", lambda *a: told.append(a[1:]) or real(*a))
    frames = pd.read_csv(SAMPLE_DRIVE / "frames.csv").iloc[:3]
    frames.to_csv(tmp_path / "frames.csv", index=False, float_format="%.9f")
    cfg = tmp_path / "config.toml"
    cfg.write_text((SAMPLE_DRIVE / "config.toml").read_text().replace("[fusion]", "[fusion]\ncamera_time_offset_s = 0.2"))
    shutil.copy(SAMPLE_DRIVE / "vifusion_imu.dbc", tmp_path)
    common = ["--video", str(SAMPLE_DRIVE / "video.mp4"), "--frames", str(tmp_path / "frames.csv"),
              "--config", str(cfg), "--quiet"]
    assert cli_main(["vision", *common, "--out", str(tmp_path / "v.csv"), "--debug-video", str(tmp_path / "v.mp4")]) == 0
    assert cli_main(["run", *common, "--can", str(SAMPLE_DRIVE / "can.blf"), "--out", str(tmp_path / "run"),
                     "--no-report", "--debug-video", str(tmp_path / "r.mp4")]) == 0
    want = [(t, frames["t_s"].iloc[0], 0.2) for t in frames["t_s"]]
    assert [told[:3], told[3:]] == [want, want], told
    for name in ("v.mp4", "r.mp4"):   # the strip has room for the fourth line (19 px a line at 360 rows)
        cap = cv2.VideoCapture(str(tmp_path / name))
        h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        cap.release()
        assert h == 360 + 4 * 19 + 8, (name, h)
