"""Benchmark of the vision estimator on banked curves, where the road is not a plane.

    .venv/bin/python tools/bench_vision_banked.py                 # the three banked drives, PNG
    .venv/bin/python tools/bench_vision_banked.py --source mp4    # the fusion benchmark's videos
    .venv/bin/python tools/bench_vision_banked.py --stride 3 --scenarios banked_curve_left_5deg

On a curve of curvature ``kappa`` banked by ``b`` the road ahead leaves the tangent plane at
the vehicle by ``-sin(b) kappa x^2 / 2`` (:mod:`vision.lanemodel`). This prints, side by side,
the estimator with the vertical curvature (``default``) and with a planar road
(``planar``: ``vertical_curvature=False``):

* bias (mean error) and RMSE of roll, pitch and yaw against the simulator's truth (relative to
  the road's tangent plane at the contact point), over all valid frames and over the frames in
  steady curves (the curvature and bank the same from the vehicle to 40 m ahead);
* the lane curvature at the vehicle against the truth: mean relative error in steady curves,
  RMSE over all frames;
* the vertical curvature against ``-kappa sin(bank)`` in steady curves;
* calibration of the reported 1-sigma: RMS(error / sigma) of each angle and of the curvature
  (1 = calibrated).

Frames: ``--source png`` renders the scenario into ``.cache/drives/<name>-<key>/`` like
``tools/bench_vision.py`` (no codec); ``--source mp4`` reads the ``video.mp4`` and
``truth_frames.csv`` of the fusion benchmark's drive ``.cache/drives/full-<name>-*/``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_vision import CACHE, SCENARIOS, cached_drive, fmt, scenario_setup  # noqa: E402

BANKED = ("banked_curve_left_5deg", "banked_curve_right_7deg", "banked_curves_60s")
#: Steady curve: curvature and bank at the vehicle and this far ahead agree (m).
STEADY_AHEAD_M = 40.0


@dataclass
class BankedRun:
    err_deg: np.ndarray        # (n, 3) roll pitch yaw, estimate - truth; NaN where invalid
    sigma_deg: np.ndarray      # (n, 3)
    curv: np.ndarray           # (n,) estimate, 1/m
    curv_sigma: np.ndarray
    curv_true: np.ndarray
    zeta: np.ndarray           # (n,) vertical curvature, 1/m
    zeta_true: np.ndarray
    valid: np.ndarray
    steady: np.ndarray
    ms: np.ndarray
    frames: np.ndarray


def steady_mask(truth) -> np.ndarray:
    """Frames whose curvature (non-zero) and bank hold from the vehicle to STEADY_AHEAD_M ahead."""
    s = truth["station_m"].to_numpy()
    k = truth["curvature_1_m"].to_numpy()
    b = truth["bank_deg"].to_numpy()
    k_ahead = np.interp(s + STEADY_AHEAD_M, s, k, right=np.nan)
    b_ahead = np.interp(s + STEADY_AHEAD_M, s, b, right=np.nan)
    return (np.abs(k) > 1e-3) & (np.abs(k_ahead - k) < 0.01 * np.abs(k)) & (np.abs(b_ahead - b) < 0.05)


def frames_of(name: str, source: str):
    """(frame getter, truth table, n frames)."""
    import pandas as pd

    if source == "png":
        d = cached_drive(SCENARIOS / f"{name}.toml")
        return d.frame, d.truth(), d.n_frames
    folders = sorted(CACHE.glob(f"full-{name}-*[0-9a-f]"))
    folders = [f for f in folders if (f / "video.mp4").is_file()]
    if not folders:
        raise SystemExit(f"no .cache/drives/full-{name}-*/video.mp4: run tools/bench_fusion.py first")
    import cv2

    cap = cv2.VideoCapture(str(folders[-1] / "video.mp4"))
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(img)
    cap.release()
    truth = pd.read_csv(folders[-1] / "truth_frames.csv")
    return frames.__getitem__, truth, min(len(frames), len(truth))


def run(name: str, options, get, truth, frames) -> BankedRun:
    from fusion.metrics import truth_lane_plane_curvature
    from vision.estimator import Estimator

    sc, road = scenario_setup(name)
    est = Estimator(sc.camera, sc.mount, road, options)
    n = len(frames)
    out = BankedRun(*(np.full((n, 3), np.nan) for _ in range(2)), *(np.full(n, np.nan) for _ in range(5)),
                    np.zeros(n, bool), np.zeros(n, bool), np.zeros(n), np.asarray(frames))
    steady = steady_mask(truth)
    # what the lane fit measures: the road plane's curvature (fusion.ekf._lane_plane_curvature)
    plane_curvature = truth_lane_plane_curvature(truth)
    for i, f in enumerate(frames):
        img = get(f)
        t0 = time.perf_counter()
        e = est.estimate(img)
        out.ms[i] = (time.perf_counter() - t0) * 1e3
        tr = truth.iloc[f]
        out.curv_true[i] = plane_curvature[f]
        out.zeta_true[i] = -tr.curvature_1_m * math.sin(math.radians(tr.bank_deg))
        out.steady[i] = steady[f]
        out.valid[i] = e.valid
        if not e.valid:
            continue
        out.err_deg[i] = np.degrees(e.rpy_rad) - [tr.roll_deg, tr.pitch_deg, tr.yaw_deg]
        out.sigma_deg[i] = np.degrees([e.roll_sigma_rad, e.pitch_sigma_rad, e.yaw_sigma_rad])
        out.curv[i], out.curv_sigma[i] = e.curvature_1_m, e.curvature_sigma_1_m
        out.zeta[i] = e.vertical_curvature_1_m
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Banked-curve benchmark of the vision estimator (module docstring).")
    p.add_argument("--scenarios", default=",".join(BANKED), help="comma-separated scenario names")
    p.add_argument("--source", choices=("png", "mp4"), default="png")
    p.add_argument("--stride", type=int, default=1, help="use every n-th frame")
    p.add_argument("--configs", default="default,planar", help="default and/or planar")
    p.add_argument("--csv", default=None, help="write per-frame results to this CSV")
    args = p.parse_args(argv)
    if args.stride < 1:
        p.error(f"--stride must be at least 1, got {args.stride}")
    if set(args.configs.split(",")) - {"default", "planar"}:
        p.error(f"--configs takes default and/or planar, got {args.configs}")
    missing = [n for n in args.scenarios.split(",") if not (SCENARIOS / f"{n}.toml").is_file()]
    if missing:
        p.error(f"--scenarios: no {', '.join(missing)} in {SCENARIOS}")

    import cv2

    cv2.setNumThreads(1)
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):
        pass
    from vision.options import EstimatorOptions

    cfgs = {"default": EstimatorOptions(), "planar": EstimatorOptions(vertical_curvature=False)}
    cfgs = {k: cfgs[k] for k in args.configs.split(",")}
    cmd = "python tools/bench_vision_banked.py " + " ".join(argv if argv is not None else sys.argv[1:])
    print(f"$ {cmd.strip()}")
    print(f"frames: every {args.stride}, source {args.source}; one core")
    results = {}
    for name in args.scenarios.split(","):
        get, truth, n = frames_of(name, args.source)
        frames = list(range(0, n, args.stride))
        for cname, opt in cfgs.items():
            results[(name, cname)] = r = run(name, opt, get, truth, frames)
            v, s = r.valid, r.valid & r.steady
            print(f"  {name:24s} {cname:8s} valid {v.mean():5.1%}, steady {s.sum():4d} frames, "
                  f"median {np.median(r.ms):5.2f} ms", flush=True)
        del get

    print()
    print("Attitude error (deg), estimate - truth relative to the tangent plane: bias (mean) and RMSE")
    print(f"{'scenario':24s} {'config':8s} {'frames':6s} {'roll bias':>9s} {'rmse':>6s} {'pitch bias':>10s} {'rmse':>6s} "
          f"{'yaw bias':>8s} {'rmse':>6s}")
    for (name, cname), r in results.items():
        for label, m in (("all", r.valid), ("steady", r.valid & r.steady)):
            e = r.err_deg[m]
            if not len(e):
                continue
            b, q = e.mean(0), np.sqrt((e**2).mean(0))
            print(f"{name:24s} {cname:8s} {label:6s} {fmt(b[0], 9, 3)} {fmt(q[0], 6, 3)} {fmt(b[1], 10, 3)} "
                  f"{fmt(q[1], 6, 3)} {fmt(b[2], 8, 3)} {fmt(q[2], 6, 3)}")

    print()
    print("Lane curvature (1/m) in steady curves: mean truth, mean estimate, mean and RMS of the relative")
    print("error per frame; RMSE over all frames. Vertical curvature zeta = -kappa sin(bank) (1/m), steady curves")
    print(f"{'scenario':24s} {'config':8s} {'truth':>8s} {'estimate':>9s} {'rel bias':>8s} {'rel rms':>7s} "
          f"{'all rmse':>9s} {'zeta truth':>10s} {'zeta est':>9s} {'zeta std':>9s}")
    for (name, cname), r in results.items():
        s = r.valid & r.steady
        v = r.valid
        rm = float(np.sqrt(np.mean((r.curv[v] - r.curv_true[v]) ** 2)))
        if s.any():
            rel = (r.curv[s] - r.curv_true[s]) / r.curv_true[s]
            cells = (f"{r.curv_true[s].mean():8.5f} {r.curv[s].mean():9.5f} {100 * rel.mean():7.1f}% "
                     f"{100 * np.sqrt(np.mean(rel**2)):6.1f}% {rm:9.2e} {r.zeta_true[s].mean():10.2e} "
                     f"{np.mean(r.zeta[s]):9.2e} {np.std(r.zeta[s]):9.2e}")
        else:
            cells = f"{'n/a':>8s} {'':9s} {'':8s} {'':7s} {rm:9.2e}"
        print(f"{name:24s} {cname:8s} {cells}")

    print()
    print("Reported 1-sigma against the actual error: RMS(error / sigma), all valid frames (1 = calibrated)")
    for (name, cname), r in results.items():
        v = r.valid
        z = np.sqrt(np.mean((r.err_deg[v] / r.sigma_deg[v]) ** 2, axis=0))
        zk = float(np.sqrt(np.nanmean(((r.curv[v] - r.curv_true[v]) / r.curv_sigma[v]) ** 2)))
        print(f"  {name:24s} {cname:8s} roll {z[0]:5.2f}  pitch {z[1]:5.2f}  yaw {z[2]:5.2f}  curvature {zk:5.2f}")
    if args.csv:
        import pandas as pd

        tables = []
        for (name, cname), r in results.items():
            t = pd.DataFrame({"scenario": name, "config": cname, "frame": r.frames, "valid": r.valid,
                              "steady": r.steady, "ms": r.ms})
            for i, a in enumerate(("roll", "pitch", "yaw")):
                t[f"{a}_err_deg"] = r.err_deg[:, i]
                t[f"{a}_sigma_deg"] = r.sigma_deg[:, i]
            t["curvature_1_m"], t["curvature_sigma_1_m"], t["curvature_true_1_m"] = r.curv, r.curv_sigma, r.curv_true
            t["zeta_1_m"], t["zeta_true_1_m"] = r.zeta, r.zeta_true
            tables.append(t)
        pd.concat(tables).to_csv(args.csv, index=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
