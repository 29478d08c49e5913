"""``vifusion campaign DRIVE... --out DIR``: a bank campaign, drive after drive with one IMU.

Each drive is a ``vifusion run --drive`` into ``DIR/<drive name>/`` (drives of one name:
``DIR/day1/drive/``, as many parent folders as tell them apart), started from the IMU biases
the previous good drive ended with (its ``calibration.toml``, :mod:`fusion.calibration`): at
constant speed one curve cannot tell the lateral accelerometer bias from bank, a campaign's
drives together can. A drive whose run warned of its vision (lanes on under half the frames,
or the gate refusing over 15 % of the results: :func:`_vision_doubt`) runs, but does not hand
its biases on (``calibration_carried`` in the table, a line on stderr). ``DIR/campaign.csv`` (and ``.parquet``) has one row per drive: status,
where its calibration came from, the fused bank's statistics, the RMSE against truth when the
drive has one, and the biases it ended with. A drive that fails (missing files, bad config) is
skipped with its one-line reason in the table and on stderr, and the next drive starts from
the last good calibration; the exit status is 2 when no drive succeeded. A drive whose run
fails with an internal error (a bug) is ``failed: internal error ...`` in the table, its
traceback on stderr, and the campaign goes on; the exit status is then 1 (``--debug`` stops at it).

A campaign into a folder an earlier campaign wrote replaces it: the old table and the old output
folders of this campaign's drives are removed before the first drive (a folder holding anything
a run did not write, or a ``campaign.csv`` / ``.parquet`` that is not a campaign's table, is
refused first; ``--calibration`` is read first, so it may lie in one of them), so that no drive
folder outlives the row that describes it. The table is written after every drive, the drives
not yet run listed as ``not run``; an interrupt (Ctrl-C) leaves it so, with the interrupted
drive and the rest ``not run: interrupted``. A run's warnings on stderr name their drive.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import shutil
import sys
import time
import traceback
from pathlib import Path

from . import workers_arg, write_tables

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser(
        "campaign",
        help="run several drives of one vehicle in order, carrying the IMU calibration",
        description="Run drives (folders as 'vifusion simulate' writes them) one after the other, each "
        "started from the IMU biases the previous one ended with; a table of all drives.",
    )
    p.add_argument("drives", nargs="+", type=Path, help="drive folders, in the order to run them")
    p.add_argument("--out", type=Path, required=True, help="output folder: one sub-folder per drive, campaign.csv")
    p.add_argument("--calibration", type=Path, help="calibration.toml to start the first drive from")
    p.add_argument("--no-carry", action="store_true", help="run every drive on its own (no calibration carried)")
    p.add_argument("--smooth", action="store_true", help="forward filter plus RTS smoother (offline)")
    p.add_argument("--no-report", action="store_true", help="skip the per-drive plots and HTML")
    p.add_argument("--workers", type=workers_arg, default=None,
                   help="vision processes (default: the cores available; the tables do not depend on it)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..calibration import read_calibration
    from ..errors import InputError
    from . import run as run_cmd

    names = output_names(args.drives)
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        twice = next(d for d, n in zip(args.drives, names) if n == dup[0])
        raise InputError(f"the drive {twice} is given twice: both runs would write {args.out / dup[0]}")
    nested = [(a, b) for a in names for b in names if Path(a) in Path(b).parents]
    if nested:    # a drive's output folder would hold another's
        raise InputError(f"the output folder of drive {nested[0][1]} would lie in drive {nested[0][0]}'s "
                         f"({args.out / nested[0][0]}): run them in two campaigns")
    partial = [n for n in names if n.endswith(".partial") and n[: -len(".partial")] in names]
    if partial:   # the run of drive X writes into OUT/X.partial first
        raise InputError(f"a drive named {partial[0]} beside one named {partial[0][:-len('.partial')]}: the second's "
                         "run writes into the first's output folder first")
    clash = [n for n in names if Path(n).parts[0] in ("campaign.csv", "campaign.parquet")]
    if clash:   # said now, not after every drive
        raise InputError(f"a drive named {clash[0]}: its output folder would be the campaign's table")
    out_dir = args.out.resolve()
    if not out_dir.name:
        raise InputError(f"--out {args.out}: the root is not an output folder")
    drives = [Path(d).resolve() for d in args.drives]
    inside = [d for d, r in zip(args.drives, drives) if out_dir == r or r in out_dir.parents]
    if inside:   # the campaign's folders and tables would be mixed into a drive's own files
        raise InputError(f"--out {args.out} is inside the drive {inside[0]}: give the campaign a folder of its own")
    for name in names:   # a drive's output folder may not be, hold or lie in a drive (found out on its turn)
        target = out_dir / name
        clash = [d for d, r in zip(args.drives, drives) if r == target or r in target.parents or target in r.parents]
        if clash:
            raise InputError(f"--out {args.out}: the output folder {target} of drive {name} would replace the drive "
                             f"{clash[0]}: give the campaign a folder of its own")
    for name in names:      # refused before any work, not on the drive's turn
        run_cmd.check_out(args.out / name)
    for table in ("campaign.csv", "campaign.parquet"):
        _check_old_table(args.out / table)
    # read before anything is replaced: a bad file is the campaign's error, not every drive's,
    # and it may lie in an earlier campaign's drive folder, removed below
    cal = read_calibration(args.calibration) if args.calibration is not None else None
    args.out.mkdir(parents=True, exist_ok=True)
    for stale in [args.out / "campaign.csv", args.out / "campaign.parquet",
                  *(args.out / n for n in names), *(args.out / (n + ".partial") for n in names)]:
        if stale.is_dir():
            shutil.rmtree(stale)
        elif stale.exists():
            stale.unlink()
    calibration = (args.calibration, cal) if cal is not None else None
    rows = []
    i = 0
    try:
        for i, (drive, name) in enumerate(zip(args.drives, names)):
            calibration = _one_drive(args, drive, name, calibration, rows)
            write_tables(_table(rows, args.drives, "not run"), args.out / "campaign")
    except KeyboardInterrupt:
        # a drive interrupted while it ran (no row yet) keeps the calibration it started from:
        # the interrupt left ``calibration`` as it was passed in
        write_tables(_table(rows, args.drives, "not run: interrupted", calibration if len(rows) == i else None),
                     args.out / "campaign")
        raise
    table = _table(rows, args.drives, "not run")
    ok = int((table["status"] == "ok").sum())
    print(f"wrote {args.out}/campaign.csv and campaign.parquet: {ok} of {len(table)} drives done")
    if table["status"].str.startswith("failed: ").any():
        print("error: a drive of the campaign failed with an internal error (its row and traceback)", file=sys.stderr)
        return 1
    if ok == 0:
        print("error: no drive of the campaign could be run", file=sys.stderr)
        return 2
    return 0


def output_names(drives: list[Path]) -> list[str]:
    """Each drive's output folder under ``--out``: the drive folder's name ('.' names its
    folder; a link keeps its own name), and where drives share a name, as many of their parent
    folders as tell them apart (``day1/drive`` and ``day2/drive``; they were refused before, a
    campaign's usual layout). The same folder given twice keeps one name for both."""
    paths = [Path(os.path.abspath(d)) for d in drives]
    names = [p.name for p in paths]
    for name in set(names):
        group = [i for i, n in enumerate(names) if n == name]
        if len(group) < 2:
            continue
        parts = [paths[i].parts[1:] for i in group]      # without the root: a name under --out
        k = next((k for k in range(2, max(map(len, parts)) + 1) if len({q[-k:] for q in parts}) == len(parts)),
                 1)    # none: the same folder twice, one name (refused as such)
        for i, q in zip(group, parts):
            names[i] = "/".join(q[-k:])
    return names


def _check_old_table(path: Path) -> None:
    """A ``campaign.csv`` or ``.parquet`` already in ``--out`` is replaced only if it is a
    campaign's table (a review found a user's file, and a folder of that name, deleted)."""
    from ..errors import InputError

    if not path.exists():
        return
    ours = False
    if path.is_file():
        with contextlib.suppress(OSError, ValueError, ImportError):
            if path.suffix == ".csv":
                with open(path, encoding="utf-8", errors="replace") as f:
                    ours = f.readline().startswith("drive,calibration_from,status")
            else:
                import pyarrow.parquet as pq

                ours = {"drive", "calibration_from", "status"} <= set(pq.read_schema(path).names)
    if not ours:
        raise InputError(f"--out {path.parent} holds {path.name}, which is not a campaign's table: "
                         "give a new or empty folder")


def _table(rows: list[dict], drives: list[Path], pending: str, calibration=None):
    """The campaign's table: the rows of the drives run so far, then the rest as ``pending``,
    the first of them with ``calibration`` (the one it started from, when it was running)."""
    import pandas as pd

    rest = [{"drive": str(d), "calibration_from": "", "status": pending} for d in drives[len(rows):]]
    if rest and calibration:
        rest[0]["calibration_from"] = str(calibration[0])
    return pd.DataFrame(rows + rest)


def _one_drive(args: argparse.Namespace, drive: Path, name: str, calibration, rows: list[dict]):
    """Run one drive into ``args.out / name``, append its row; the calibration the next drive
    starts from. A calibration is ``(path, its [fusion] keys)``: read once, when it is made."""
    import pandas as pd

    from ..calibration import read_calibration
    from . import USER_ERRORS, _one_line, interrupt_seen
    from . import run as run_cmd

    out = args.out / name
    run_args = argparse.Namespace(
        drive=drive, video=None, frames=None, can=None, dbc=None, config=None, truth=None, out=out,
        smooth=args.smooth, calibration=calibration[0] if calibration else None,
        calibration_table=calibration[1] if calibration else None, estimate_time_offset=False, debug_video=None,
        no_report=args.no_report, workers=args.workers, quiet=args.quiet, debug=False,
        started_s=time.perf_counter(), warning_prefix=f"{name}: ")
    row = {"drive": str(drive), "calibration_from": str(calibration[0]) if calibration else ""}
    print(f"== {drive}" + (f" (from {calibration[0]})" if calibration else ""))
    try:
        log = io.StringIO()
        with contextlib.redirect_stdout(log):
            run_cmd.run(run_args)
    except Exception as e:
        if interrupt_seen():   # Ctrl-C or SIGTERM that surfaced as an error (numba's SystemError
            raise KeyboardInterrupt from None   # too): the campaign ends, no drive skipped
        if not isinstance(e, USER_ERRORS):
            if args.debug:
                raise
            # A bug, not the drive's fault: said with its traceback, and the campaign goes on
            # (a division by zero in one drive's filter ended a campaign, the drives after it
            # never run: a review); the exit status says it (1)
            traceback.print_exc(file=sys.stderr)
            reason = f"internal error (a bug, the traceback on stderr): {type(e).__name__}: {_one_line(e)}"
            print(f"error: {drive} failed: {reason}", file=sys.stderr)
            rows.append({**row, "status": f"failed: {reason}"})
            return calibration
        reason = _one_line(e)
        print(f"warning: {drive} skipped: {reason}", file=sys.stderr)
        rows.append({**row, "status": f"skipped: {reason}"})
        return calibration
    try:
        fused = pd.read_csv(out / "fused.csv")
        summary = _read_summary(out)
        row.update(status="ok", **_drive_row(fused, summary))
    except KeyboardInterrupt:   # the drive's folder is complete: its row says so
        rows.append({**row, "status": "ok (interrupted before its figures were read)"})
        raise
    rows.append(row)
    line = (f"   bank mean {row['bank_mean_deg']:+.2f} deg, |max| {row['bank_abs_max_deg']:.2f} deg"
            + (f", RMSE vs truth {row['bank_rmse_deg']:.3f} deg" if "bank_rmse_deg" in row else ""))
    row["calibration_carried"] = False
    if (out / "calibration.toml").is_file():
        cal = read_calibration(out / "calibration.toml")
        line += (f"; lateral accelerometer bias {cal['accel_bias_m_s2'][1]:+.4f} "
                 f"+- {cal['accel_bias_sigma_m_s2'][1]:.4f} m/s^2")
        doubt = _vision_doubt(out, summary)
        if doubt and not args.no_carry:
            print(f"warning: {drive}: its calibration is not carried ({doubt}: the biases rest on the vision): "
                  f"the next drive starts from {calibration[0] if calibration else 'the config'}", file=sys.stderr)
        elif not args.no_carry:
            calibration = (out / "calibration.toml", cal)
            row["calibration_carried"] = True
    else:
        print(f"warning: {drive} wrote no calibration.toml: the next drive starts from "
              f"{calibration[0] if calibration else 'the config'}", file=sys.stderr)
    print(line)
    return calibration


def _read_summary(out: Path) -> dict:
    """A drive's ``report/summary.json`` ({} when the run wrote no report)."""
    summary = out / "report" / "summary.json"
    return json.loads(summary.read_text()) if summary.is_file() else {}


def _vision_doubt(out: Path, summary: dict) -> str:
    """Why a drive's calibration is not handed on, or "": its run warned of its vision (valid on
    too few frames, :func:`fusion.drive.too_few_valid`, or more than
    :data:`fusion.pipeline.VISION_REFUSED_WARN` of the results refused by the gate). The biases
    are learnt against the vision; a review carried a 2 s drive's with lanes on 11 of 30 frames,
    whose yaw-rate bias ended 1.56 +- 0.30 deg/s against a truth of -0.30, and the next drive's
    bank RMSE went 0.368 -> 0.837 deg."""
    import pandas as pd

    from ..drive import too_few_valid
    from ..pipeline import vision_refused_warning

    valid = pd.read_csv(out / "vision.csv", usecols=["valid"])["valid"].astype(bool)
    if too_few_valid(int(valid.sum()), len(valid)):
        return f"vision valid on {int(valid.sum())} of {len(valid)} frames"
    counts = summary.get("counts", {})
    refused, used = counts.get("vision_rejected", 0), counts.get("vision_used", 0)
    if vision_refused_warning(refused, refused + used):
        return f"the gate refused {refused} of {refused + used} vision results"
    return ""


def _drive_row(fused, summary: dict) -> dict:
    """Bank statistics, the RMSE against truth when the run had one (its ``summary``), the final
    biases."""
    import numpy as np

    bank = fused["bank_deg"].to_numpy()
    known = np.isfinite(bank)        # none before the first wheel speed
    row = {"duration_s": float(fused["t_s"].iloc[-1] - fused["t_s"].iloc[0]),
           "bank_mean_deg": float(np.mean(bank[known])) if known.any() else math.nan,
           "bank_abs_max_deg": float(np.max(np.abs(bank[known]))) if known.any() else math.nan,
           "bank_sigma_median_deg": float(np.median(fused["bank_sigma_deg"].to_numpy()[known])) if known.any() else math.nan}
    if summary:
        # the run's own warnings (no valid vision, an incomplete log, gaps...): 'ok' means it ran
        row["warnings"] = " | ".join(summary.get("warnings") or [])
        fusedrmse = (summary.get("rmse_deg") or {}).get("fused") or {}
        for a in ("roll", "pitch", "yaw", "bank"):
            if isinstance(fusedrmse.get(a), (int, float)) and math.isfinite(fusedrmse[a]):   # null: none
                row[f"{a}_rmse_deg"] = fusedrmse[a]
    last = fused.iloc[-1]
    for c in fused.columns:
        if c.startswith(("gyro_bias_", "accel_bias_")):
            row[c] = float(last[c])
    return row
