"""Report of a run: time plots of every estimate (against truth when there is one), a summary
table, PNG files and one self-contained HTML page (images embedded)."""

from __future__ import annotations

import base64
import contextlib
import gc
import html
import io
import json
import math
import multiprocessing
import os
import signal
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .calibration import calibration_table
from .files import write_bytes_atomically
from .metrics import ANGLES, consistency, interp_truth, rmse_table, wrap_deg

__all__ = ["ReportInputs", "write_report", "summarise", "source_name"]

CONVERGENCE_S = 2.0
#: Scored time after the convergence below which the report gives no RMSE (a 2 s drive left one sample).
MIN_SCORED_S = 1.0


@dataclass
class ReportInputs:
    fused: pd.DataFrame
    vision: pd.DataFrame | None = None
    imu_only: pd.DataFrame | None = None
    plain_bank: pd.DataFrame | None = None
    truth: pd.DataFrame | None = None
    imu_truth: pd.DataFrame | None = None
    cov: np.ndarray | None = None
    counts: dict = field(default_factory=dict)
    timings_s: dict = field(default_factory=dict)
    time_offset: dict | None = None
    warnings: list[str] = field(default_factory=list)
    title: str = "vifusion run"
    smoothed: bool = False
    camera_time_offset_s: float = 0.0
    #: What calibration.toml holds (None: from ``fused``'s last sample, when it has one).
    imu_calibration: dict | None = None
    #: The calibration file the run started from (``--calibration``; a campaign's carried one).
    calibration_from: str | None = None
    #: The run's input files by kind (video, frames, can_log, dbc, config, truth), as given.
    inputs: dict | None = None


def source_name(src: str, smoothed: bool) -> str:
    """An estimate's name where it is shown (legends, the page's and the printed RMSE rows): the
    filter's says whether it was smoothed; the baselines are forward filters either way."""
    return "fused (smoothed)" if src == "fused" and smoothed else src


def _truth_covers_s(fused: pd.DataFrame, tr: pd.DataFrame, t0: float, angles, every: bool = False) -> float:
    """Seconds of the fused samples from ``t0`` on at which the truth (``tr``: interpolated at
    their times) has a value of one of ``angles`` estimated (``every``: of all of them): the
    samples' count times their median interval."""
    t = fused["t_s"].to_numpy(dtype=float)
    cols = [f"{a}_deg" for a in angles if f"{a}_deg" in tr and f"{a}_deg" in fused]
    if not cols or len(t) < 2:
        return 0.0
    has = np.isfinite(tr[cols].to_numpy(dtype=float))
    ok = (has.all(axis=1) if every else has.any(axis=1)) & (t >= t0)
    return float(np.sum(ok) * np.median(np.diff(t)))


#: Share of samples whose NEES should lie inside its 95 % band (issue 5's bar): below it the
#: report warns that the fused sigma does not describe the errors against the truth.
CONSISTENT_SHARE = 0.9


def summarise(r: ReportInputs) -> dict:
    """Numbers of the report: RMSE per source against truth, consistency, counts, timings."""
    out: dict = {"title": r.title, "smoothed": r.smoothed, "counts": r.counts, "timings_s": r.timings_s,
                 "time_offset": r.time_offset, "warnings": r.warnings,
                 "camera_time_offset_s": r.camera_time_offset_s, "calibration_from": r.calibration_from,
                 "inputs": r.inputs,
                 # present in every summary, null where there is none (no truth, too short a truth,
                 # biases that ended non-finite): a reader need not tell a missing key from a null
                 "imu_calibration": None, "rmse_deg": None, "consistency": None}
    f = r.fused
    out["samples"] = int(len(f))
    if r.imu_calibration is not None:
        out["imu_calibration"] = r.imu_calibration
    elif len(f) and "gyro_bias_x_sigma_deg_s" in f:
        with contextlib.suppress(ValueError):   # none when the biases ended non-finite (a warning of the run)
            out["imu_calibration"] = calibration_table(f)   # what calibration.toml holds
    out["duration_s"] = float(f["t_s"].iloc[-1] - f["t_s"].iloc[0]) if len(f) else 0.0
    t0 = float(f["t_s"].iloc[0]) + CONVERGENCE_S if len(f) else math.nan
    tr = interp_truth(r.truth, f["t_s"].to_numpy()) if r.truth is not None and len(f) else None
    if r.truth is not None and len(f) and not f["t_s"].iloc[-1] - t0 >= MIN_SCORED_S:
        out["warnings"] = [*r.warnings, f"no RMSE against truth: the drive has under {MIN_SCORED_S:g} s after the "
                                        f"first {CONVERGENCE_S:g} s of convergence"]
    elif r.truth is not None and len(f) and (covered := _truth_covers_s(f, tr, t0, ANGLES)) < MIN_SCORED_S:
        # a truth cut short or empty where the run is scored: said, not a table of nulls (a review)
        out["warnings"] = [*r.warnings, f"no RMSE against truth: it has values for {covered:.1f} s of the drive "
                                        f"after the first {CONVERGENCE_S:g} s of convergence, under {MIN_SCORED_S:g} s"]
    elif r.truth is not None and len(f):
        acc = {"fused": rmse_table(f, r.truth, t0)}
        empty = [a for a, v in acc["fused"].items() if not math.isfinite(v)]
        if empty:   # a truth column without values where the run is scored: its RMSE is null, said why
            out["warnings"] = [*out["warnings"], f"no RMSE of {', '.join(empty)} against truth: the truth has no "
                               f"values of {'it' if len(empty) == 1 else 'them'} after the first {CONVERGENCE_S:g} s"]
        if r.vision is not None and len(r.vision):
            v = r.vision.assign(t_s=r.vision["t_s"] + r.camera_time_offset_s)
            acc["vision"] = rmse_table(v, r.truth, t0, angles=("roll", "pitch", "yaw"),
                                       valid=v["valid"].to_numpy(dtype=bool))
            # over the whole drive (what the run's vision gave), where the RMSE is from t0 on
            acc["vision"]["valid_fraction"] = float(np.mean(v["valid"].astype(bool)))
        if r.plain_bank is not None and len(r.plain_bank):
            pb = r.plain_bank.rename(columns={"bank_plain_deg": "bank_deg"})
            acc["imu_minus_vision"] = rmse_table(pb, r.truth, t0, angles=("bank",))
        if r.imu_only is not None:
            acc["imu_only"] = rmse_table(r.imu_only, r.truth, t0, angles=("roll_world", "pitch_world"))
        # every source's key there, null where it has no value (no vision, a truth without the
        # column): the keys had changed from run to run (a review); the vision's share of valid
        # frames is kept beside angles that are null
        for src in ("vision", "imu_minus_vision", "imu_only"):
            vals = acc.get(src) or {}
            if "valid_fraction" not in vals and not any(math.isfinite(v) for v in vals.values()):
                acc[src] = None
        # and every source's angle keys, null where it has none (the vision has no bank, a truth
        # of roll_world and pitch_world alone scores no roll): keys left out had made
        # ``s["rmse_deg"]["fused"]["bank"]`` a KeyError where the README promises a null (a review)
        out["rmse_deg"] = {src: None if vals is None else {**{a: vals.get(a, math.nan) for a in ANGLES},
                                                           **{k: v for k, v in vals.items() if k not in ANGLES}}
                           for src, vals in acc.items()}
        nees_angles = ("roll", "pitch", "yaw", "bank")
        if all(f"{a}_deg" in r.truth for a in nees_angles) and \
                _truth_covers_s(f, tr, t0, nees_angles, every=True) < MIN_SCORED_S:
            out["warnings"] = [*out["warnings"], f"no NEES against the truth: it has roll, pitch, yaw and bank together "
                               f"for under {MIN_SCORED_S:g} s of the scored drive"]
        elif all(f"{a}_deg" in r.truth for a in nees_angles):
            c = consistency(f, r.truth, r.cov, t0)
            out["consistency"] = asdict(c)
            if c.fraction_inside < CONSISTENT_SHARE:
                # the sigmas do not describe the errors against this truth: say which way
                worse = ("overconfident: the errors exceed their sigmas" if c.fraction_above >= c.fraction_below
                         else "overcautious: the sigmas exceed the errors")
                out["warnings"] = [*out["warnings"], f"fused sigma against the truth: NEES inside its 95 % band on "
                                   f"{100 * c.fraction_inside:.0f} % of samples ({100 * c.fraction_above:.0f} % above, "
                                   f"{100 * c.fraction_below:.0f} % below), {worse}"]
    return out


#: The PNGs' resolution [dots per inch]: the 11-inch wide figures are 1210 pixels before their crop.
DPI = 110


def _fig_to_png(fig) -> bytes:
    """``fig`` as a PNG cropped to what is drawn (and 0.1 inch around it), as
    ``savefig(bbox_inches="tight")`` crops it, to the same pixels: its crop measured by
    ``get_tightbbox`` without the draw that "tight" makes before the one that saves (the 5
    figures of the 60 s drive in one process: 1.48 s with "tight", 1.31 s without; median of 5)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches=fig.get_tightbbox().padded(0.1))
    return buf.getvalue()


def _panels(n: int, height_in: float):
    """A figure 11 inches wide of ``n`` panels over one time axis, and its axes. A figure of its
    own (not pyplot's: nothing global to close, no backend to choose) drawn by Agg."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, height_in), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]


@contextlib.contextmanager
def _gc_paused():
    """No garbage collection while the figures are drawn: their many short-lived artists, kept
    while a figure is drawn, set off full collections of the whole heap (0.15-0.2 s each in a
    process that has reported before, as a campaign's). The 60 s drive's plots: 1.00 s with
    collections, 0.97 s paused in ``vifusion run`` (median of 5 runs); in a process reporting
    again and again 1.33 and 1.19 s in one process, 0.87 and 0.72 s in two (median of 15).
    What the figures leave is collected after."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


#: The report's figures, in the page's order (errors.png where there is a truth to take them from).
FIGURES = ("attitude.png", "world.png", "errors.png", "road.png", "biases.png")
#: The figures a second process draws (:func:`_plots`): those every run has, half the time.
FORKED = ("attitude.png", "world.png", "road.png")


def _plots(r: ReportInputs, processes: int = 2) -> dict[str, bytes]:
    """The figures of ``r`` as PNGs, in the page's order: with ``processes`` 2, those of
    :data:`FORKED` drawn by a forked process (it inherits the imported matplotlib) while this
    one draws the others, where there are fork and a second core; else all here. The child's
    error is raised here, its death as BrokenProcessPool. ``vifusion run`` of the 60 s drive,
    the plots' time (summary.json, matplotlib's import of 0.3 s in it): 1.70 s before, 1.44 s
    in one process, 0.97 s in two (median of 5 runs each)."""
    import matplotlib.backends.backend_agg  # noqa: F401  (once, before the fork)

    if processes < 2 or not _can_fork():
        return _draw(r, FIGURES)
    fork = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(1, mp_context=fork, initializer=_child_signals) as pool:
        # the child is forked in submit: a Ctrl-C or SIGTERM between its fork and its handlers
        # (a review) waits, blocked, until each process has its own
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, _STOPS)
        try:
            theirs = pool.submit(_draw, r, FORKED)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        figs = _draw(r, [name for name in FIGURES if name not in FORKED])
        figs.update(theirs.result())
    return {name: figs[name] for name in FIGURES if name in figs}


def _can_fork() -> bool:
    """Whether a forked process can draw beside this one: fork there (as the vision's workers
    are), more than one core to draw on, and this process allowed children (not a daemon's)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return (cores > 1 and "fork" in multiprocessing.get_all_start_methods()
            and not multiprocessing.current_process().daemon)


#: The signals that stop ``vifusion run`` (fusion.cli), blocked while the report's child is forked.
_STOPS = {signal.SIGINT, signal.SIGTERM}


def _child_signals() -> None:
    """The forked child leaves Ctrl-C to this process, which waits for it (its figures' time),
    and a SIGTERM ends it as it ends a process: it keeps the command's handlers otherwise
    (fusion.cli), which raise in it. It is forked with both blocked (:func:`_plots`): they are
    taken once its own handlers are set."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOPS)


def _draw(r: ReportInputs, names) -> dict[str, bytes]:
    """The PNGs of the figures ``names`` (of :data:`FIGURES`) that ``r`` has something to draw in."""
    with _gc_paused():
        return _draw_figures(r, names)


def _draw_figures(r: ReportInputs, names) -> dict[str, bytes]:
    f = r.fused
    t0 = float(f["t_s"].iloc[0])
    tf = f["t_s"].to_numpy() - t0
    truth = interp_truth(r.truth, f["t_s"].to_numpy()) if r.truth is not None else None
    vis = r.vision[r.vision["valid"].astype(bool)] if r.vision is not None else None
    figs: dict[str, bytes] = {}

    #: the filter's estimate: forward, or smoothed (RTS) with --smooth, whose samples each saw the
    #: whole drive (the IMU-only and IMU-minus-vision baselines stay forward filters)
    fused = source_name("fused", r.smoothed)
    smoothed = " (RTS smoothed)" if r.smoothed else ""     # the figures' titles
    settled = tf >= CONVERGENCE_S
    if not settled.any():   # a drive shorter than the convergence: its panels scaled to all of it (they had
        settled[:] = True   # been scaled to the truth alone, the estimates off the panel, a review)

    def band(ax, col, label, color, unit="deg") -> list:
        """The estimate and its 2-sigma band; returns what the panel's scale is set to show
        (the band from the end of the convergence: the start's sigmas of degrees would squash
        the rest, a bank of a few degrees drawn on a scale of +-50)."""
        y = f[f"{col}_{unit}"].to_numpy()
        s = f[f"{col}_sigma_{unit}"].to_numpy() if f"{col}_sigma_{unit}" in f else None
        ax.plot(tf, y, color=color, lw=1.2, label=label)
        if s is None:
            return [y]
        ax.fill_between(tf, y - 2 * s, y + 2 * s, color=color, alpha=0.2, lw=0, label=f"{label} 2-sigma")
        return [y, (y - 2 * s)[settled], (y + 2 * s)[settled]]

    if "attitude.png" in names:
        # 1. attitude relative to the road
        fig, axes = _panels(4, 11)
        for ax, a in zip(axes, ("roll", "pitch", "yaw", "bank")):
            shown = []
            if a != "bank" and vis is not None and len(vis):
                # with its own 2-sigma (the estimator's, before the filter's floor) as bars, where
                # the vision table has it (they were points alone, a review)
                sig = vis.get(f"{a}_sigma_deg")
                bars = ax.errorbar(vis["t_s"] + r.camera_time_offset_s - t0, vis[f"{a}_deg"],
                                   yerr=None if sig is None else 2.0 * sig.to_numpy(dtype=float), fmt=".", ms=2.5,
                                   color="tab:orange", elinewidth=0.5, alpha=0.7,
                                   label="vision" if sig is None else "vision, its own 2-sigma")
                for lines in bars[2]:
                    lines.set_alpha(0.3)    # the bars behind the points (two-line frames' reach off the panel)
                shown.append(vis[f"{a}_deg"].to_numpy())
            if a == "bank" and r.plain_bank is not None and len(r.plain_bank):
                ax.plot(r.plain_bank["t_s"] - t0, r.plain_bank["bank_plain_deg"], ".", ms=2.5, color="tab:purple",
                        alpha=0.6, label="IMU roll - vision roll (Damon 2018)")
                shown.append(r.plain_bank["bank_plain_deg"].to_numpy())
            shown += band(ax, a, fused, "tab:blue")
            if truth is not None and f"{a}_deg" in truth:
                ax.plot(tf, truth[f"{a}_deg"], "k--", lw=1.0, label="truth")
                shown.append(truth[f"{a}_deg"].to_numpy())
            _scale_to(ax, shown)
        _finish(figs, "attitude.png", fig, axes, [f"{a} [deg]" for a in ("roll", "pitch", "yaw", "bank")],
                f"{r.title}: attitude relative to the road and road bank{smoothed}", ncol=4)

    if "world.png" in names:
        # 2. relative to gravity: the vehicle's attitude and the road's grade (the grade had been
        # in fused.csv only, neither drawn nor scored against the truth)
        fig, axes = _panels(3, 8.5)
        for ax, a in zip(axes, ("roll_world", "pitch_world", "grade")):
            shown = band(ax, a, fused, "tab:blue")
            if r.imu_only is not None and a != "grade":
                ax.plot(r.imu_only["t_s"] - t0, r.imu_only[f"{a}_deg"], color="tab:green", lw=1.0, label="IMU only")
                shown.append(r.imu_only[f"{a}_deg"].to_numpy())
            if truth is not None and f"{a}_deg" in truth:
                ax.plot(tf, truth[f"{a}_deg"], "k--", lw=1.0, label="truth")
                shown.append(truth[f"{a}_deg"].to_numpy())
            _scale_to(ax, shown)
        _finish(figs, "world.png", fig, axes, ("roll_world [deg]", "pitch_world [deg]", "grade [deg], + downhill"),
                f"attitude relative to gravity and the road's grade{smoothed}", ncol=4)

    if "errors.png" in names:
        # 3. errors against truth with the 2-sigma envelope: every angle the truth has (a real
        # recording's reference may have the world angles only)
        scored = [a for a in ANGLES if truth is not None and f"{a}_deg" in truth and f"{a}_deg" in f
                  and np.isfinite(truth[f"{a}_deg"].to_numpy(dtype=float)).any()]
        if scored:
            fig, axes = _panels(len(scored), 2.25 * len(scored))
            # the truth at the vision's and the IMU-only run's times, once for every angle
            tv = vis["t_s"].to_numpy() + r.camera_time_offset_s if vis is not None and len(vis) else None
            truth_v = interp_truth(r.truth, tv) if tv is not None else None
            truth_i = interp_truth(r.truth, r.imu_only["t_s"].to_numpy()) if r.imu_only is not None else None
            for ax, a in zip(axes, scored):
                e = wrap_deg(f[f"{a}_deg"].to_numpy() - truth[f"{a}_deg"].to_numpy())
                s = f[f"{a}_sigma_deg"].to_numpy()
                ax.plot(tf, e, color="tab:blue", lw=1.0, label=f"{fused} - truth")
                ax.fill_between(tf, -2 * s, 2 * s, color="tab:blue", alpha=0.15, lw=0, label="+-2 sigma")
                # the scale of the fused error once converged (as the RMSE is taken) and of most of its
                # band: the start's sigmas, the band's peaks in runoffs (4.5 deg of bank for an error
                # of 1.3 on the 60 s drive) and the vision's larger errors go off it
                es, band2 = e[settled], 2 * s[settled]
                band2 = band2[np.isfinite(band2)]
                wide = float(np.percentile(band2, 95)) if band2.size else math.nan
                _scale_to(ax, [es, -es, [wide, -wide]])
                if a in ("roll", "pitch", "yaw") and truth_v is not None:
                    ev = wrap_deg(vis[f"{a}_deg"].to_numpy() - truth_v[f"{a}_deg"].to_numpy())
                    lo, hi = ax.get_ylim()
                    off = (ev < lo) | (ev > hi)
                    label = "vision - truth"
                    if off.any():   # drawn at the edge they went over, and said (a review: 12 % of the
                        # roll's points, the largest 2.5 deg, went off the panel without a mark)
                        label += (f" ({int(off.sum())} beyond the panel, up to {np.nanmax(np.abs(ev[off])):.2f}: "
                                  "at its edge)")
                        ax.plot(tv[off] - t0, np.clip(ev[off], lo, hi), "^", ms=3, color="tab:orange", alpha=0.8)
                        ax.set_ylim(lo, hi)
                    ax.plot(tv[~off] - t0, ev[~off], ".", ms=2, color="tab:orange", alpha=0.5, label=label)
                if a.endswith("_world") and truth_i is not None:
                    ei = wrap_deg(r.imu_only[f"{a}_deg"].to_numpy() - truth_i[f"{a}_deg"].to_numpy())
                    ax.plot(r.imu_only["t_s"] - t0, ei, color="tab:green", lw=0.8, label="IMU only - truth")
                ax.set_ylabel(f"{a} error [deg]")
                ax.grid(alpha=0.3)
                ax.legend(loc="upper right", fontsize=8, ncol=3)
            axes[0].set_title("errors against truth" + (" (the fused estimate RTS smoothed)" if r.smoothed else ""))
            axes[-1].set_xlabel("time [s]")
            figs["errors.png"] = _fig_to_png(fig)

    if "road.png" in names:
        # 4. the road: curvature and bank rate (the vision's twist at the road it was measured on)
        fig, axes = _panels(2, 6)
        k, ks = f["curvature_1_m"].to_numpy(), f["curvature_sigma_1_m"].to_numpy()
        axes[0].plot(tf, k, color="tab:blue", lw=1.2, label=fused)
        axes[0].fill_between(tf, k - 2 * ks, k + 2 * ks, color="tab:blue", alpha=0.2, lw=0, label=f"{fused} 2-sigma")
        shown_rate = band(axes[1], "bank_rate", fused, "tab:blue", unit="deg_s")
        if vis is not None and len(vis):
            tv = vis["t_s"].to_numpy() + r.camera_time_offset_s
            axes[0].plot(tv - t0, vis["curvature_1_m"], ".", ms=2.5, color="tab:orange", alpha=0.7, label="vision")
            if "road_twist_deg_per_m" in vis and np.isfinite(vis["road_twist_deg_per_m"].to_numpy()).any():
                v = np.interp(tv, f["t_s"], f["speed_m_s"])
                ahead = np.nan_to_num(vis["roll_lookahead_m"].to_numpy()) / np.maximum(v, 1.0)
                there = tv + ahead <= f["t_s"].iloc[-1]     # the road the drive got to
                rate_seen = (v * vis["road_twist_deg_per_m"].to_numpy())[there]
                axes[1].plot((tv + ahead - t0)[there], rate_seen, ".", ms=2.5,
                             color="tab:orange", alpha=0.7, label="vision twist x speed, where measured")
                shown_rate.append(rate_seen)
        if truth is not None and "curvature_1_m" in truth:
            axes[0].plot(tf, truth["curvature_1_m"], "k--", lw=1.0, label="truth")
        if r.truth is not None and "bank_deg" in r.truth:
            tt = r.truth["t_s"].to_numpy()
            rate_true = np.gradient(r.truth["bank_deg"].to_numpy(), tt)
            axes[1].plot(tt - t0, rate_true, "k--", lw=1.0, label="truth")
            shown_rate.append(rate_true)
        _scale_to(axes[1], shown_rate, min_span=0.5)
        _finish(figs, "road.png", fig, axes, ("curvature [1/m]", "bank rate [deg/s]"),
                "the road: lane curvature and bank rate", ncol=4)

    if "biases.png" in names:
        # 5. sensor biases
        fig, axes = _panels(2, 5.5)
        shown: list[list] = [[], []]
        for i, ax_name in enumerate("xyz"):
            for k, (kind, unit) in enumerate((("gyro", "deg_s"), ("accel", "m_s2"))):
                y = f[f"{kind}_bias_{ax_name}_{unit}"].to_numpy()
                axes[k].plot(tf, y, lw=1.0, label=f"{kind} {ax_name}", color=f"C{i}")
                shown[k].append(y[settled])
                sig = f.get(f"{kind}_bias_{ax_name}_sigma_{unit}")
                if sig is not None:   # the lateral accelerometer's: what bounds the bank (README)
                    sig = sig.to_numpy()
                    axes[k].fill_between(tf, y - 2 * sig, y + 2 * sig, color=f"C{i}", alpha=0.12, lw=0)
                    shown[k] += [(y - 2 * sig)[settled], (y + 2 * sig)[settled]]
            if r.imu_truth is not None and f"gyro_bias_{ax_name}_rad_s" in r.imu_truth:
                tb = (np.degrees(r.imu_truth[f"gyro_bias_{ax_name}_rad_s"]), r.imu_truth[f"accel_bias_{ax_name}_m_s2"])
                for k in (0, 1):
                    axes[k].plot(r.imu_truth["t_s"] - t0, tb[k], "--", color=f"C{i}", lw=0.8)
                    shown[k].append(tb[k].to_numpy())
        for ax, arrays in zip(axes, shown):
            _scale_to(ax, arrays, min_span=1e-3)
        _finish(figs, "biases.png", fig, axes, ("gyro bias [deg/s]", "accel bias [m/s^2]"),
                "sensor bias estimates and their 2-sigma bands (dashed: truth)", ncol=3)
    return figs


def _scale_to(ax, arrays, pad: float = 0.08, min_span: float = 0.02) -> None:
    """The panel's y-limits around the finite values of ``arrays`` (what it is meant to show),
    padded; those of nothing finite leave matplotlib's own."""
    vals = [np.asarray(a, dtype=float).ravel() for a in arrays]
    vals = np.concatenate(vals) if vals else np.empty(0)
    vals = vals[np.isfinite(vals)]
    if not vals.size:
        return
    lo, hi = float(vals.min()), float(vals.max())
    span = max(hi - lo, min_span)
    mid = 0.5 * (lo + hi)
    ax.set_ylim(mid - (0.5 + pad) * span, mid + (0.5 + pad) * span)


def _finish(figs: dict, name: str, fig, axes, ylabels, title: str, ncol: int) -> None:
    """Labels, grid and legends of a stack of time plots, then the PNG into ``figs[name]``."""
    for ax, label in zip(axes, ylabels):
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8, ncol=ncol)
    axes[0].set_title(title)
    axes[-1].set_xlabel("time [s]")
    figs[name] = _fig_to_png(fig)


def _table_html(summary: dict) -> str:
    rows = []
    acc = summary.get("rmse_deg")
    if acc:
        cols = list(ANGLES)
        head = "".join(f"<th>{c}</th>" for c in cols)
        rows.append(f"<h2>RMSE against truth [deg] (after {CONVERGENCE_S:g} s)</h2><table><tr><th>source</th>{head}</tr>")
        # a source without a value is said under the table, not shown as a row of blanks
        # (a value is NaN here, null in a summary read back from summary.json)
        def score(vals, c):
            v = (vals or {}).get(c)
            return v if isinstance(v, (int, float)) and math.isfinite(v) else None

        none = [src for src, vals in acc.items() if all(score(vals, c) is None for c in cols)]
        for src, vals in acc.items():
            if src in none:
                continue
            cells = "".join("<td></td>" if score(vals, c) is None else f"<td>{vals[c]:.3f}</td>" for c in cols)
            rows.append(f"<tr><td>{html.escape(source_name(src, summary.get('smoothed')))}</td>{cells}</tr>")
        rows.append("</table>")
        if none:
            rows.append(f"<p>No RMSE of {html.escape(', '.join(none))}: no value to score (no valid vision frame, "
                        "or the truth has none of its angles).</p>")
    c = summary.get("consistency")
    if c:
        rows.append("<h2>Consistency of the fused sigma</h2><p>NEES of (roll, pitch, yaw, bank): "
                    f"{100 * c['fraction_inside']:.1f} % of samples inside the 95 % chi-square band "
                    f"[{c['band'][0]:.2f}, {c['band'][1]:.2f}] ({100 * c['fraction_above']:.1f} % above, "
                    f"{100 * c['fraction_below']:.1f} % below); mean NEES {c['mean_nees']:.2f} "
                    f"(expected {c['dof']}).</p>")
    cal = summary.get("imu_calibration")
    if cal:
        rows.append("<h2>IMU biases at the end (calibration.toml), vehicle frame, 1-sigma</h2><table>"
                    "<tr><th></th><th>x</th><th>y</th><th>z</th></tr>")
        for label, key, unit in (("gyro", "gyro_bias_deg_s", "deg/s"), ("accelerometer", "accel_bias_m_s2", "m/s^2")):
            sig = cal[key.replace("_bias_", "_bias_sigma_")]
            cells = "".join(f"<td>{v:+.4f} &plusmn; {s:.4f}</td>" for v, s in zip(cal[key], sig))
            rows.append(f"<tr><td>{label} [{unit}]</td>{cells}</tr>")
        rows.append("</table>")
    rows.append("<h2>Run</h2><table>")
    rows.append("<tr><td>estimate</td><td>" + ("forward filter and RTS smoother (offline)" if summary.get("smoothed")
                                             else "forward filter") + "</td></tr>")
    for kind, path in (summary.get("inputs") or {}).items():
        if path:
            rows.append(f"<tr><td>{html.escape(kind.replace('_', ' '))}</td><td>{html.escape(str(path))}</td></tr>")
    rows.append(f"<tr><td>IMU samples fused</td><td>{summary.get('samples', 0)}</td></tr>"
                f"<tr><td>duration [s]</td><td>{summary.get('duration_s', 0.0):.2f}</td></tr>"
                f"<tr><td>camera time offset applied [s] (added to frames.csv's times)</td>"
                f"<td>{summary.get('camera_time_offset_s', 0.0):+.4f}</td></tr>"
                f"<tr><td>IMU biases started from</td><td>"
                f"{html.escape(summary.get('calibration_from') or 'the config')}</td></tr>")
    acc = summary.get("rmse_deg") or {}
    if (acc.get("vision") or {}).get("valid_fraction") is not None:
        rows.append(f"<tr><td>vision valid</td><td>{100 * acc['vision']['valid_fraction']:.1f} % of the drive's "
                    "frames</td></tr>")
    for k, v in summary.get("counts", {}).items():
        rows.append(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(str(v))}</td></tr>")
    for k, v in summary.get("timings_s", {}).items():
        rows.append(f"<tr><td>time: {html.escape(k)}</td><td>{v:.2f} s</td></tr>")
    to = summary.get("time_offset")
    if to:
        rows.append(f"<tr><td>camera-to-CAN offset estimate</td><td>{html.escape(json.dumps(to))}</td></tr>")
    rows.append("</table>")
    if summary.get("warnings"):
        rows.append("<h2>Warnings</h2><ul>" + "".join(f"<li>{html.escape(w)}</li>" for w in summary["warnings"]) + "</ul>")
    return "\n".join(rows)


def write_report(r: ReportInputs, out_dir: str | Path, plots: bool = True) -> dict:
    """Write ``summary.json``, and with ``plots`` the PNG plots and ``report.html``, into
    ``out_dir``; returns the summary."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = summarise(r)
    if plots:
        t0 = time.perf_counter()
        figs = _plots(r) if len(r.fused) else {}
        # the plots' own time, in the page and summary.json alike (the run's clock stops before
        # the report: summary.json had every step's time but the report's, a review)
        summary["timings_s"] = {**summary.get("timings_s", {}), "report": time.perf_counter() - t0}
        _write_pages(r, summary, out_dir, figs)
    write_bytes_atomically(out_dir / "summary.json",
                           json.dumps(_finite_or_null(summary), indent=2, default=_json_default, allow_nan=False).encode())
    return summary


def _write_pages(r: ReportInputs, summary: dict, out_dir: Path, figs: dict) -> None:
    """The PNG plots ``figs`` and the self-contained ``report.html`` (the plots inlined)."""
    for name, png in figs.items():
        write_bytes_atomically(out_dir / name, png)
    body = [f"<h1>{html.escape(r.title)}</h1>", _table_html(summary)]
    for name, png in figs.items():
        body.append(f'<h2>{html.escape(name[:-4])}</h2><img src="data:image/png;base64,{base64.b64encode(png).decode()}"/>')
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>" + html.escape(r.title) + "</title>"
            "<style>body{font-family:sans-serif;max-width:1200px;margin:auto}table{border-collapse:collapse}"
            "td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}img{max-width:100%}</style></head><body>"
            + "\n".join(body) + "</body></html>")
    write_bytes_atomically(out_dir / "report.html", page.encode())


def _finite_or_null(o):
    """``summary`` with every non-finite number as None (JSON null): strict JSON has no NaN."""
    if isinstance(o, dict):
        return {k: _finite_or_null(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite_or_null(v) for v in o]
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    return o


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


