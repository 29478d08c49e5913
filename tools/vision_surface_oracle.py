"""How much of the vision's error in superelevation runoffs is the road surface it assumes.

Usage::

    .venv/bin/python tools/vision_surface_oracle.py [drive names ...] [--stride N]

For each simulated drive (cached as ``tools/bench_fusion.py`` caches it) the estimator runs over
the frames once per mode, each time projecting the image rays onto a different road:

* ``assumed``: the estimator as it is, a plane with a vertical curvature (``vision.ipm``);
* ``exact``: the simulator's own road surface (``drivesim.road``), met by each ray at the
  estimator's current pose (vertical curvature off: the surface has it);
* ``profiles``: a road described by two profiles along it, both from the simulator's truth:
  the centre line's height above the vehicle's tangent plane and the bank change ahead, the
  road turning about its centre line, ``h(x, y) = z_c(x) + (y - y_c(x)) tan(b(x) - b(0))``;
* ``polynomials``: the same with ``z_c`` reduced to its least-squares linear + quadratic and
  ``b(x) - b(0)`` to its cubic over 5-40 m (the few parameters an estimator could carry).

It prints the RMS error of roll, pitch, yaw (deg) and lane curvature (1e-3 1/m) against the
truth, on steady road and near runoffs (``bench_fusion.near_runoffs``: a bank change within
1.5 s). How good must an estimate of
the profiles be: ``--profile-scale K`` scales the bank change (a relative error), ``--known-to
M`` keeps it only to ``M`` m ahead and holds its last twist beyond (what a map of the
cross-sections' twists from the frames before could know), ``--fit-range M`` limits the lane
fit (:attr:`vision.options.EstimatorOptions.fit_range_m`) for the true-surface modes. The
detection of the markers (in a planar bird's-eye view) is the same in every mode; only the
geometry differs.
The ``exact`` rows are the ceiling of a single-frame estimator that knew the surface; the
``profiles`` rows show that a surface of two profiles along the road reaches it, and the
``polynomials`` rows that five numbers per frame do (`docs/fusion-notes.md`, 2026-11-25).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

import numba as nb
import numpy as np
import pandas as pd

from drivesim.road import intersect_ray

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

DRIVES = ("banked_curves_60s", "banked_curve_right_7deg", "banked_curve_left_5deg")
MODES = ("assumed", "exact", "profiles", "polynomials")


@nb.njit(cache=True)
def _exact_hits(tab, rays_o, Rw, origin_w, s0, d0, H, out):  # pragma: no cover (numba)
    """Rays (estimator frame: o's axes, origin at the camera) met with the simulator's road:
    ``out`` gets each hit's ``(x, y)`` relative to the camera's nadir in ``o`` (NaN: no hit)."""
    for i in range(rays_o.shape[0]):
        rx, ry, rz = rays_o[i, 0], rays_o[i, 1], rays_o[i, 2]
        out[i, 0] = np.nan
        out[i, 1] = np.nan
        if rz > -1e-9:
            continue
        lam = H / -rz
        wx = Rw[0, 0] * rx + Rw[0, 1] * ry + Rw[0, 2] * rz
        wy = Rw[1, 0] * rx + Rw[1, 1] * ry + Rw[1, 2] * rz
        wz = Rw[2, 0] * rx + Rw[2, 1] * ry + Rw[2, 2] * rz
        s, d, lam, ok = intersect_ray(tab, origin_w[0], origin_w[1], origin_w[2], wx, wy, wz,
                                      s0 + lam * rx, d0 + lam * ry, lam)
        if ok:
            out[i, 0] = lam * rx
            out[i, 1] = lam * ry


class TrueSurface:
    """The road around one frame's vehicle, in the estimator's frame (``o``'s axes, origin at
    the camera), from the simulator."""

    def __init__(self, road, s_m: float, d_m: float, R_o_from_v: np.ndarray, camera_v: np.ndarray,
                 profile_scale: float = 1.0, known_to_m: float | None = None) -> None:
        self.road = road
        self.s, self.d = s_m, d_m
        self.Rw = road.frame(np.array(s_m), np.array(d_m))                # R_w_from_o
        self.P0 = road.surface(np.array(s_m), np.array(d_m))              # contact point, world
        self.cam_o = R_o_from_v @ camera_v                                 # camera in o, from the contact point
        self.origin_w = self.P0 + self.Rw @ self.cam_o
        # the centre line and the bank change ahead, for the two-profile surface
        u = np.arange(-5.0, 90.0, 0.5)
        C = (road.surface(s_m + u, np.zeros_like(u)) - self.P0) @ self.Rw
        self.cx, self.cy, self.cz = C[:, 0] - self.cam_o[0], C[:, 1] - self.cam_o[1], C[:, 2]
        self.db = profile_scale * (road.bank_rad(s_m + u) - road.bank_rad(np.array(s_m)))
        if known_to_m is not None:              # known to there, its last twist beyond
            k = int(np.searchsorted(u, known_to_m))
            twist = (self.db[k] - self.db[k - 4]) / (u[k] - u[k - 4])
            self.db = np.where(u <= known_to_m, self.db, self.db[k] + twist * (u - u[k]))
        fit = (self.cx > 5.0) & (self.cx < 40.0)
        # the same surface with each profile reduced to a polynomial fitted to it over the view
        x = self.cx[fit]
        B = np.stack([x, x ** 2, x ** 3], 1)                               # b(x) - b(0): cubic
        self.db_cubic = np.stack([self.cx, self.cx ** 2, self.cx ** 3], 1) @ np.linalg.lstsq(B, self.db[fit], rcond=None)[0]
        Q = np.stack([self.cx[fit], self.cx[fit] ** 2], 1)
        self.zq = np.linalg.lstsq(Q, self.cz[fit], rcond=None)[0]      # z_c(x): linear + quadratic

    def exact(self, rays_cp, R_o_from_cp, H):
        rays = np.ascontiguousarray(np.asarray(rays_cp, float).reshape(-1, 3) @ np.asarray(R_o_from_cp).T)
        out = np.empty((rays.shape[0], 2))
        _exact_hits(self.road.table, rays, self.Rw, self.origin_w, self.s, self.d, float(H), out)
        return out[:, 0], out[:, 1]

    def polynomials(self, rays_cp, R_o_from_cp, H):
        return self.profiles(rays_cp, R_o_from_cp, H, polynomials=True)

    def profiles(self, rays_cp, R_o_from_cp, H, polynomials=False):
        r = np.asarray(rays_cp, float).reshape(-1, 3) @ np.asarray(R_o_from_cp).T
        down = -r[:, 2] > 1e-9
        t = np.where(down, H / np.where(down, -r[:, 2], 1.0), np.nan)
        for _ in range(8):       # fixed point: t r_z = -H_cam + h(t r_x, t r_y)
            x, y = t * r[:, 0], t * r[:, 1]
            zc = (self.zq[0] * x + self.zq[1] * x * x) if polynomials else np.interp(x, self.cx, self.cz)
            yc = np.interp(x, self.cx, self.cy)
            h = zc + (y - yc) * np.tan(np.interp(x, self.cx, self.db_cubic if polynomials else self.db))
            t = np.where(down, (self.cam_o[2] - h) / np.where(down, -r[:, 2], 1.0), np.nan)
        t = np.where(t > 0, t, np.nan)
        return t * r[:, 0], t * r[:, 1]


def estimates(images, truth: pd.DataFrame, road, camera, mount, markings, mode: str, *,
              fit_range_m: float | None = None, profile_scale: float = 1.0,
              known_to_m: float | None = None) -> pd.DataFrame:
    """The estimator over ``images`` (in order: it seeds each frame from the last) with the rays
    met on the road ``mode`` (:data:`MODES`), and its errors against ``truth`` (one row of
    :func:`drivesim.drive.truth_frame` per image): ``t_s, bank_deg, roll, pitch, yaw`` (deg),
    ``curvature`` (1e-3 1/m), valid frames only."""
    import vision.estimator as est_mod
    from vision.frames import R_from_rpy
    from vision.options import EstimatorOptions

    opts = EstimatorOptions()
    if mode != "assumed":
        opts = replace(opts, vertical_curvature=False)
        if fit_range_m is not None:
            opts = replace(opts, fit_range_m=fit_range_m)
    assumed = est_mod.ground_from_rays
    here: dict = {}

    def on_true_road(rays, R, H, zeta=0.0, x0=0.0, twist=None):  # the signature of vision.ipm.ground_from_rays
        shape = np.asarray(rays).shape[:-1]
        x, y = getattr(here["surface"], mode)(rays, R, H)
        return x.reshape(shape), y.reshape(shape)

    rows = []
    try:
        if mode != "assumed":
            est_mod.ground_from_rays = on_true_road
        est = est_mod.Estimator(camera, mount, markings, opts)
        for (_, tr), img in zip(truth.iterrows(), images):
            if mode != "assumed":
                R_ov = R_from_rpy(*np.radians([tr.roll_deg, tr.pitch_deg, tr.yaw_deg]))
                here["surface"] = TrueSurface(road, float(tr.station_m), float(tr.lateral_offset_m), R_ov,
                                              mount.position_v, profile_scale, known_to_m)
            e = est.estimate(img)
            if not e.valid:
                continue
            rows.append({"t_s": tr.t_s - truth.t_s.iloc[0], "bank_deg": tr.bank_deg,
                         "roll": math.degrees(e.roll_rad) - tr.roll_deg,
                         "pitch": math.degrees(e.pitch_rad) - tr.pitch_deg,
                         "yaw": math.degrees(e.yaw_rad) - tr.yaw_deg,
                         "curvature": 1e3 * (e.curvature_1_m - tr.curvature_1_m)})
    finally:
        est_mod.ground_from_rays = assumed
    return pd.DataFrame(rows)


def run(name: str, mode: str, stride: int, **kw) -> pd.DataFrame:
    """:func:`estimates` over a drive as ``tools/bench_fusion.py`` caches it, every ``stride``-th
    frame scored (all estimated)."""
    from bench_fusion import cached_full_drive
    from drivesim.drive import build_road
    from drivesim.scenario import load_scenario
    from fusion.config import load_config
    from vision.video import FrameSource, _frames_from

    drive = cached_full_drive(name)
    cfg = load_config(drive / "config.toml")
    truth = pd.read_csv(drive / "truth_frames.csv")
    road = build_road(load_scenario(drive / "scenario.toml"))
    video = FrameSource(next(p for p in drive.iterdir() if p.name.startswith("video")))
    images = (img for _, img in _frames_from(video, 0, luma=True))
    df = estimates(images, truth, road, cfg.camera, cfg.mount, cfg.road, mode, **kw)
    frame = np.rint(df["t_s"].to_numpy() * float(1.0 / np.median(np.diff(truth.t_s)))).astype(int)
    return df[frame % stride == 0]


def main(argv=None) -> int:
    from bench_fusion import near_runoffs

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", default=DRIVES)
    ap.add_argument("--stride", type=int, default=1, help="score every N-th frame (all are estimated)")
    ap.add_argument("--modes", nargs="+", default=MODES, choices=MODES)
    ap.add_argument("--fit-range", type=float, help="lane fit range of the true-surface modes, m")
    ap.add_argument("--profile-scale", type=float, default=1.0, help="scale the true bank change ahead")
    ap.add_argument("--known-to", type=float, help="the bank change known to this far ahead, m; its last twist beyond")
    args = ap.parse_args(argv)
    print("RMS error against truth: roll, pitch, yaw [deg], lane curvature [1e-3 1/m]; steady road | near runoffs")
    print(f"{'drive':<26} {'surface':<11} {'roll':>6} {'pitch':>6} {'yaw':>6} {'kappa':>6} | "
          f"{'roll':>6} {'pitch':>6} {'yaw':>6} {'kappa':>6}   frames")
    for name in args.names:
        for mode in args.modes:
            df = run(name, mode, args.stride, fit_range_m=args.fit_range, profile_scale=args.profile_scale,
                     known_to_m=args.known_to)
            near = near_runoffs(df["t_s"].to_numpy(), df["bank_deg"].to_numpy())
            cells = []
            for part in (~near, near):
                q = df[part]
                cells.append(" ".join(f"{math.sqrt(float(np.mean(q[c] ** 2))) if len(q) else math.nan:6.3f}"
                                      for c in ("roll", "pitch", "yaw", "curvature")))
            print(f"{name:<26} {mode:<11} {cells[0]} | {cells[1]}   {len(df)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
