"""``vifusion can LOG --config C --out imu.parquet|imu.csv``: decode the IMU channels of a CAN log.

Reads ``[imu]`` and ``[can]`` (with ``[can.signals]``, optional ``[can.units]``) from the config,
decodes the log with :func:`imu.read_log` and writes the IMU table (vehicle frame, SI units,
``fresh_*`` flags). The output is written under a temporary name and renamed when complete. A log
whose reading stopped early (truncated or corrupt binary file) is an error unless ``--partial``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from imu import read_log
from imu.samples import never_seen

from ..config import parse_tables, read_toml
from ..errors import ConfigError, InputError
from . import check_output_file, refuse_inputs_as_outputs, settle_heap, write_table

OUT_SUFFIXES = (".parquet", ".csv")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "can",
        help="decode IMU rates, accelerations and speed from a CAN log into a table",
        description="Decode the IMU channels of a CAN log (.asc .blf .log .trc .csv .mf4) with the DBC "
        "and [can.signals] of a config, into a parquet or CSV table in the vehicle frame.",
    )
    p.add_argument("log", help="CAN log file")
    p.add_argument("--config", required=True, help="config TOML with [imu], [can] and [can.signals]")
    p.add_argument("--out", required=True, help="output table: .parquet or .csv")
    p.add_argument("--dbc", default=None, help="DBC to use instead of [can] dbc")
    p.add_argument("--partial", action="store_true",
                   help="write the table even if the log breaks off (truncated file); it is marked incomplete "
                        "(.parquet only: the mark is in its metadata)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def load_can_config(path: str | Path):
    """``[imu]`` and ``[can]`` of a config file; its other tables are not needed here (nor
    ``[camera]`` and ``[mount]`` required), but checked as every command checks them."""
    path = Path(path)
    data = read_toml(path)
    if "can" not in data:
        raise ConfigError(f"{path}: [can] is missing (vifusion can needs [can] dbc and [can.signals])")
    tables = parse_tables(data, str(path), path.parent, required=())
    return tables["imu"], tables["can"]


def run(args: argparse.Namespace) -> int:
    settle_heap()
    out = Path(args.out)
    if out.suffix.lower() not in OUT_SUFFIXES:
        raise InputError(f"{out}: output must end in {' or '.join(OUT_SUFFIXES)}")
    check_output_file(out)   # said now, not after the log
    if args.partial and out.suffix.lower() != ".parquet":
        raise InputError(f"{out}: --partial needs a .parquet output, which keeps complete=false with the table "
                         "(a CSV of a log that broke off would look complete)")
    mount, mapping = load_can_config(args.config)
    if args.dbc is not None:
        mapping = dataclasses.replace(mapping, dbc_path=Path(args.dbc))
    refuse_inputs_as_outputs([out], [args.log, args.config, mapping.dbc_path])
    t0 = time.perf_counter()
    table, summary = read_log(args.log, mapping, mount, progress=not args.quiet)
    elapsed = time.perf_counter() - t0
    for line in summary.lines():
        print(line)
    print(f"decoded in {elapsed:.2f} s ({summary.frames_read / max(elapsed, 1e-9):,.0f} frames/s)")
    if not summary.complete and not args.partial:
        why = summary.stop_reason or "reading stopped early"
        raise InputError(f"{args.log}: {why}; nothing written (--partial writes the {summary.samples} samples read)")
    if not summary.complete:
        print(f"warning: {args.log}: reading stopped early; {out} holds the first {summary.samples} samples "
              f"and is marked complete=false", file=sys.stderr)
    for line in summary.range_lines():
        print(f"warning: {args.log}: {line}", file=sys.stderr)
    for col in never_seen(table):
        print(f"warning: {args.log}: {col} never seen (all NaN in {out.name})", file=sys.stderr)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_table(table, out)
    print(f"wrote {out} ({len(table)} rows)")
    return 0

