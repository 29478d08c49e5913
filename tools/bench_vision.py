"""Benchmark of the vision estimator on the simulated drives of Alrazouk et al. 2024, Table I.

    .venv/bin/python tools/bench_vision.py            # everything (renders what is not cached)
    .venv/bin/python tools/bench_vision.py --quick    # smoke run: every 4th frame, two configs
                                                      # (frames 4x further apart need more second
                                                      # warps: its timings are not the benchmark's)

Prints, for each Table I scenario, the RMSE of roll, pitch and yaw of the vehicle relative to
the road against the simulator's exact truth, next to the paper's figures; then the same for
the paper's plain method and each improvement switched on alone (side by side); then the speed
on one core at 1280x720 against the roll loop of Damon et al. 2018 (delta-phi = 0.1 deg) on
the same frames, both timed from the grey frame as vifusion hands it over (the decoded video's
luma plane; the cached PNG frames are converted with ``cv2.cvtColor`` first, and that conversion
is printed on its own).

Rendered drives are cached under ``.cache/drives/<scenario name>-<key>/`` (gitignored):

* ``frames/000000.png`` ...: the uint8 BGR frames as the simulated camera delivers them
  (:func:`drivesim.drive.render_frames`: optics and sensor noise, no video codec), PNG;
* ``truth_frames.csv``: ``frame, t_s`` and the truth of :func:`drivesim.drive.truth_frame`
  (degrees, relative to the road, ZYX, INTERFACE conventions);
* ``done``: written last, so an interrupted render is never taken for a whole one.

The key hashes the scenario file and the simulator modules that decide what a frame looks
like (road, trajectory, render), so editing either renders again.
"""

from __future__ import annotations

import os

# One core: set before numpy, OpenCV and numba start their thread pools.
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / ".cache" / "drives"
SCENARIOS = ROOT / "configs" / "scenarios"
_SIM_FILES = ("road.py", "trajectory.py", "render.py")

#: Table I of Alrazouk et al. 2024: (scenario file, label, RMSE roll, pitch, yaw in deg).
TABLE_I = [
    ("alrazouk_s1_hd_center", "1 at 30FPS HD with center line", 0.1905, 0.0563, 0.0124),
    ("alrazouk_s2_hd_center", "2 at 30FPS HD with center line", 0.194, 0.0897, 0.0532),
    ("alrazouk_s3_hd_center", "3 at 30FPS HD with center line", 0.2189, 0.0522, 0.005),
    ("alrazouk_s1_fhd", "1 at 24FPS FHD", 0.5159, 0.0557, 0.03),
    ("alrazouk_s2_fhd", "2 at 24FPS FHD", 0.314, 0.0949, 0.0591),
    ("alrazouk_s3_fhd", "3 at 24FPS FHD", 0.4324, 0.0517, 0.0107),
    ("alrazouk_s1_hd", "1 at 30FPS HD", 0.9361, 0.0555, 0.0347),
    ("alrazouk_s2_hd", "2 at 30FPS HD", 0.6114, 0.0893, 0.0568),
    ("alrazouk_s3_hd", "3 at 30FPS HD", 0.7928, 0.0515, 0.0173),
]


# ---------------------------------------------------------------------------------------------
# Cache of rendered drives


@dataclass(frozen=True)
class CachedDrive:
    name: str
    folder: Path
    n_frames: int

    def truth(self):
        import pandas as pd

        return pd.read_csv(self.folder / "truth_frames.csv")

    def frame(self, i: int) -> np.ndarray:
        import cv2

        path = self.folder / "frames" / f"{i:06d}.png"
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise FileNotFoundError(path)
        return img


def cache_key(scenario_path: str | Path) -> str:
    """Cache key of a scenario's frames: its bytes and the code of the simulator modules that
    decide them (:func:`drivesim.code_key.drive_key`: their docstrings apart)."""
    from drivesim.code_key import drive_key

    return drive_key(Path(scenario_path).read_bytes(), (ROOT / "tools" / "drivesim" / name for name in _SIM_FILES))


def cached_drive(scenario_path: str | Path, *, progress: bool = True, cache_root: Path = CACHE) -> CachedDrive:
    """The cached drive of a scenario file, rendered first if needed."""
    from drivesim.scenario import load_scenario

    scenario_path = Path(scenario_path)
    sc = load_scenario(scenario_path)
    folder = cache_root / f"{sc.name}-{cache_key(scenario_path)}"
    if not (folder / "done").is_file():
        _render(sc, folder, progress)
    return CachedDrive(sc.name, folder, sc.n_frames)


def _render(sc, folder: Path, progress: bool) -> None:
    import shutil

    import cv2
    from tqdm import tqdm

    from drivesim.drive import build_road, render_frames, truth_frame
    from drivesim.trajectory import Trajectory

    tmp = folder.with_name(folder.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    (tmp / "frames").mkdir(parents=True)
    road = build_road(sc)
    traj = Trajectory(road, sc.motion)
    n = sc.n_frames
    t = sc.video.start_s + np.arange(n) / sc.video.fps
    tf = truth_frame(traj, t, t)
    tf.insert(0, "frame", np.arange(n))
    tf.to_csv(tmp / "truth_frames.csv", index=False, float_format="%.10g")
    frames = render_frames(sc, t, road=road, traj=traj)
    for i, img in enumerate(tqdm(frames, total=n, desc=f"render {sc.name}", unit="frame", disable=not progress)):
        cv2.imwrite(str(tmp / "frames" / f"{i:06d}.png"), img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    (tmp / "done").write_text("ok\n")
    if folder.exists():
        shutil.rmtree(folder)
    tmp.rename(folder)


# ---------------------------------------------------------------------------------------------
# Running the estimator on a drive


@dataclass
class Run:
    scenario: str
    config: str
    err_deg: np.ndarray        # (n, 3) estimate - truth, roll pitch yaw; NaN where invalid
    sigma_deg: np.ndarray      # (n, 3)
    valid: np.ndarray
    ms: np.ndarray             # per-frame time of estimate(), ms
    frames: np.ndarray

    def rmse(self) -> np.ndarray:
        e = self.err_deg[self.valid]
        return np.sqrt(np.mean(e**2, axis=0)) if e.size else np.full(3, np.nan)

    def z_rms(self) -> np.ndarray:
        """RMS of error / sigma (1 for a calibrated sigma)."""
        v = self.valid
        return np.sqrt(np.mean((self.err_deg[v] / self.sigma_deg[v]) ** 2, axis=0)) if v.any() else np.full(3, np.nan)


def scenario_setup(name: str):
    from drivesim.scenario import load_scenario
    from vision.camera import RoadMarkings

    sc = load_scenario(SCENARIOS / f"{name}.toml")
    mk = sc.markings
    road = RoadMarkings(mk.lane_width_m, mk.widths_m[2], mk.center_line, mk.widths_m)
    return sc, road


def run_drive(drive: CachedDrive, name: str, config: str, options, frames, images=None) -> Run:
    from vision.estimator import Estimator

    sc, road = scenario_setup(name)
    truth = drive.truth()
    est = Estimator(sc.camera, sc.mount, road, options)
    n = len(frames)
    err = np.full((n, 3), np.nan)
    sig = np.full((n, 3), np.nan)
    valid = np.zeros(n, bool)
    ms = np.zeros(n)
    for k, f in enumerate(frames):
        img = images[f] if images is not None else drive.frame(f)
        t0 = time.perf_counter()
        e = est.estimate(img)
        ms[k] = (time.perf_counter() - t0) * 1e3
        valid[k] = e.valid
        if e.valid:
            tr = truth.iloc[f]
            err[k] = np.degrees([e.roll_rad, e.pitch_rad, e.yaw_rad]) - [tr.roll_deg, tr.pitch_deg, tr.yaw_deg]
            sig[k] = np.degrees([e.roll_sigma_rad, e.pitch_sigma_rad, e.yaw_sigma_rad])
    return Run(name, config, err, sig, valid, ms, np.asarray(frames))


# ---------------------------------------------------------------------------------------------
# Configurations compared side by side


def configs(quick: bool):
    from vision.options import EstimatorOptions

    paper = EstimatorOptions.paper()
    out = {
        # this estimator, and the paper's plain method
        "default": EstimatorOptions(),
        "paper": paper,
        # the paper's method with one improvement switched on
        "paper+area-edges": replace(paper, edges="area"),
        "paper+subpixel-edges": replace(paper, edges="subpixel"),
        "paper+no-eq21": replace(paper, eq21=False),
        "paper+9-sections": replace(paper, cross_sections=9, solver="numeric"),
        "paper+known-widths": replace(paper, known_widths=True),
        "paper+refine": replace(paper, refine_iterations=2, eq21=False, ipm_pose="seed", rewarp_deg=2.0,
                                max_warps=3, fit_range_m=100.0),
        # this estimator with one improvement switched off (or changed)
        "default-pade": EstimatorOptions(solver="pade"),
        "default-1-section": EstimatorOptions(cross_sections=1),
        "default-subpixel": EstimatorOptions(edges="subpixel"),
        "default-binary": EstimatorOptions(edges="binary"),
        "default-lines-vp": EstimatorOptions(vp="lines"),
        "default-quadratic": EstimatorOptions(fit_degree=2),
        "default-no-refine": EstimatorOptions(refine_iterations=0),
        "default-1-iteration": EstimatorOptions(refine_iterations=1),
        "default-image-edges": EstimatorOptions(edge_domain="image"),
    }
    if quick:
        out = {k: out[k] for k in ("default", "paper")}
    return out


def fmt(x: float, w: int = 7, p: int = 3) -> str:
    return f"{x:{w}.{p}f}" if math.isfinite(x) else " " * (w - 3) + "n/a"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Table I benchmark of the vision estimator (see the module docstring).")
    p.add_argument("--quick", action="store_true", help="smoke run: every 4th frame, default and paper only")
    p.add_argument("--stride", type=int, default=None, help="use every n-th frame (default 1, quick 4)")
    p.add_argument("--scenarios", default=None, help="comma-separated scenario names (default: all of Table I)")
    p.add_argument("--configs", default=None, help="comma-separated configurations (default: all)")
    p.add_argument("--no-damon", action="store_true", help="skip the 2018 roll loop")
    p.add_argument("--damon-frames", type=int, default=None,
                   help="frames per scenario for the roll loop (default: all used frames)")
    p.add_argument("--csv", default=None, help="write per-frame errors to this CSV")
    p.add_argument("--render-only", action="store_true", help="render the scenarios into the cache and stop")
    args = p.parse_args(argv)
    if args.stride is not None and args.stride < 1:
        p.error(f"--stride must be at least 1, got {args.stride}")
    if args.damon_frames is not None and args.damon_frames < 1:
        p.error(f"--damon-frames must be at least 1, got {args.damon_frames}")
    known = configs(False)
    if args.configs and set(args.configs.split(",")) - set(known):
        p.error(f"--configs: unknown {sorted(set(args.configs.split(',')) - set(known))}; known: {', '.join(known)}")

    stride = args.stride or (4 if args.quick else 1)
    table = TABLE_I
    if args.scenarios:
        want = args.scenarios.split(",")
        table = [r for r in TABLE_I if r[0] in want or r[0].replace("alrazouk_", "") in want]
        if not table:
            p.error(f"no Table I scenario among {args.scenarios}")
    drives = {}
    for name, *_ in table:
        drives[name] = cached_drive(SCENARIOS / f"{name}.toml")
    if args.render_only:
        for name, d in drives.items():
            print(f"{name}: {d.folder} ({d.n_frames} frames)")
        return 0

    import cv2

    cv2.setNumThreads(1)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):  # numba absent, or its pool already smaller
        pass

    cfgs = configs(args.quick)
    if args.configs:
        cfgs = {k: v for k, v in cfgs.items() if k in args.configs.split(",")}
    cmd = "python tools/bench_vision.py " + " ".join(argv if argv is not None else sys.argv[1:])
    print(f"$ {cmd.strip()}")
    print(f"frames: every {stride} of each drive; one core (cv2.setNumThreads(1), numba 1 thread)")

    runs: dict[tuple[str, str], Run] = {}
    grey_ms: dict[str, list[float]] = {}
    images_cache: dict[str, dict[int, np.ndarray]] = {}
    for name, *_ in table:
        d = drives[name]
        frames = list(range(0, d.n_frames, stride))
        # The estimator (and the loop) are timed from the grey frame, as vifusion hands it over
        # (the luma plane of the decoded video, vision.video.FrameSource.grey_frames); the PNG
        # frames are BGR, and their conversion is timed on its own.
        images_cache = {name: {}}
        for f in frames:
            bgr = d.frame(f)
            t0 = time.perf_counter()
            images_cache[name][f] = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
            grey_ms.setdefault(name, []).append((time.perf_counter() - t0) * 1e3)
        for cname, opt in cfgs.items():
            runs[(name, cname)] = run_drive(d, name, cname, opt, frames, images_cache[name])
            r = runs[(name, cname)]
            print(f"  {name:24s} {cname:22s} roll {fmt(r.rmse()[0])} pitch {fmt(r.rmse()[1], p=4)} "
                  f"yaw {fmt(r.rmse()[2], p=4)} valid {r.valid.mean():5.1%} median {np.median(r.ms):6.2f} ms",
                  flush=True)
        if not args.no_damon and name.endswith("_center"):
            from vision.options import EstimatorOptions

            dfr = frames if args.damon_frames is None else frames[: args.damon_frames]
            runs[(name, "damon2018")] = run_drive(d, name, "damon2018", EstimatorOptions.damon2018(), dfr,
                                                  images_cache[name])
            r = runs[(name, "damon2018")]
            print(f"  {name:24s} {'damon2018':22s} roll {fmt(r.rmse()[0])} valid {r.valid.mean():5.1%} "
                  f"median {np.median(r.ms):6.2f} ms", flush=True)
            if "default" in cfgs:
                # The default method on exactly the loop's frames, for the ratio.
                runs[(name, "default@damon")] = run_drive(d, name, "default", cfgs["default"], dfr, images_cache[name])

    # ---- Table I ----
    if "default" in cfgs:
        print()
        print("Table I layout: RMSE (deg) of the vehicle's attitude relative to the road, this estimator (default")
        print("options) against the simulator's truth | Alrazouk et al. 2024, Table I")
        print(f"{'Scenario':34s} {'Roll':>15s} {'Pitch':>17s} {'Yaw':>17s}  valid  beats")
        for name, label, pr, pp, py in table:
            r = runs[(name, "default")]
            e = r.rmse()
            beats = all(e[i] <= ref for i, ref in enumerate((pr, pp, py)))
            print(f"{label:34s} {fmt(e[0])} |{pr:6.4f} {fmt(e[1], 8, 4)} |{pp:6.4f} {fmt(e[2], 8, 4)} |{py:6.4f}"
                  f"  {r.valid.mean():5.1%}  {'yes' if beats else 'NO'}")

    # ---- side by side ----
    if len(cfgs) > 1:
        print()
        print("Side by side: RMSE roll / pitch / yaw (deg) per configuration and scenario (valid share)")
        short = [n.replace("alrazouk_", "") for n, *_ in table]
        print(f"{'configuration':22s} " + " ".join(f"{s:>22s}" for s in short))
        for cname in cfgs:
            cells = []
            for name, *_ in table:
                r = runs[(name, cname)]
                e = r.rmse()
                cells.append(f"{fmt(e[0], 6, 3)}/{fmt(e[1], 5, 3)}/{fmt(e[2], 5, 3)}{'' if r.valid.all() else '*'}")
            print(f"{cname:22s} " + " ".join(f"{c:>22s}" for c in cells))
        print("(* some frames invalid; RMSE over the valid ones)")

    # ---- uncertainty calibration ----
    if "default" in cfgs:
        print()
        print("Reported 1-sigma against the actual error, default options: RMS(error / sigma) per angle (1 = calibrated)")
        for name, label, *_ in table:
            z = runs[(name, "default")].z_rms()
            print(f"  {label:34s} roll {z[0]:6.2f}  pitch {z[1]:6.2f}  yaw {z[2]:6.2f}")

    # ---- speed ----
    print()
    hd = [n for n, *_ in table if n.endswith("_hd") or n.endswith("_hd_center")]
    if "default" in cfgs and hd:
        ms = np.concatenate([runs[(n, "default")].ms for n in hd])
        med = float(np.median(ms))
        print(f"Speed, default options, 1280x720, one core, from the grey frame: median {med:.2f} ms/frame "
              f"({1000 / med:.0f} frames/s), 95th percentile {np.percentile(ms, 95):.2f} ms, over {ms.size} frames of "
              f"{len(hd)} HD drives")
        g = float(np.median(np.concatenate([grey_ms[n] for n in hd])))
        print(f"  (from BGR frames add the conversion to grey, cv2.cvtColor: median {g:.2f} ms/frame, "
              f"{1000 / (med + g):.0f} frames/s in all; vifusion reads the grey straight from the video)")
    centers = [n for n in hd if n.endswith("_center") and (n, "damon2018") in runs]
    if centers:
        print("Against the roll loop of Damon et al. 2018 (delta-phi 0.1 deg, range 6 deg), same frames:")
        print("  (roll RMSE of both on the frames where both are valid; the loop's valid share in brackets)")
        for n in centers:
            rd, ro = runs[(n, "damon2018")], runs[(n, "default@damon")]
            md, mo = float(np.median(rd.ms)), float(np.median(ro.ms))
            both = rd.valid & ro.valid
            e_d = float(np.sqrt(np.mean(rd.err_deg[both, 0] ** 2))) if both.any() else math.nan
            e_o = float(np.sqrt(np.mean(ro.err_deg[both, 0] ** 2))) if both.any() else math.nan
            print(f"  {n:24s} loop {md:7.1f} ms/frame, roll RMSE {fmt(e_d)} deg [{rd.valid.mean():4.0%} valid] | "
                  f"this {mo:5.2f} ms/frame, roll RMSE {fmt(e_o)} deg [{ro.valid.mean():4.0%}] | {md / mo:5.1f}x faster")
        md = float(np.median(np.concatenate([runs[(n, 'damon2018')].ms for n in centers])))
        mo = float(np.median(np.concatenate([runs[(n, 'default@damon')].ms for n in centers])))
        print(f"  all: loop {md:.1f} ms/frame, this {mo:.2f} ms/frame: {md / mo:.1f}x faster")

    if args.csv:
        import pandas as pd

        rows = []
        for (name, cname), r in runs.items():
            for k, f in enumerate(r.frames):
                rows.append(dict(scenario=name, config=cname, frame=int(f), valid=bool(r.valid[k]), ms=r.ms[k],
                                 roll_err_deg=r.err_deg[k, 0], pitch_err_deg=r.err_deg[k, 1],
                                 yaw_err_deg=r.err_deg[k, 2], roll_sigma_deg=r.sigma_deg[k, 0],
                                 pitch_sigma_deg=r.sigma_deg[k, 1], yaw_sigma_deg=r.sigma_deg[k, 2]))
        pd.DataFrame(rows).to_csv(args.csv, index=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
