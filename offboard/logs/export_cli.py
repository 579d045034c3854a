"""``slung export --csv RUN``: a run folder's time series (``*.slts``, ``offboard.logs.timeseries_file``) as CSV,
for spreadsheets and tools that do not read the compact format. One ``<name>.csv`` per ``<name>.slts``, header of
column names, full precision (``%.17g``), beside the original or in ``--out``; a tick log cut short by a killed
flight is exported up to its last whole block (and says so)."""

from __future__ import annotations

import argparse
from pathlib import Path

from estimators.errors import UserError
from offboard.logs.timeseries_file import SUFFIX, read_table, write_csv
from offboard.outputs import prepare_output_dir


def configure(p: argparse.ArgumentParser) -> None:
    """Arguments of ``slung export``."""
    p.add_argument("run", metavar="RUN", help="a run folder (or one .slts file) written by slung")
    p.add_argument("--csv", action="store_true", required=True, help="write CSV (the one export format)")
    p.add_argument("--out", default=None, help="folder for the CSV files (default: beside the originals)")


def run(args: argparse.Namespace) -> int:
    """Export every time series of ``args.run``; prints one line per file written."""
    src = Path(args.run)
    if src.is_dir():
        files = sorted(src.glob("*" + SUFFIX))
    elif src.is_file():
        files = [src]
    else:
        raise UserError(f"{src}: no such run folder or file")
    if not files:
        raise UserError(f"{src}: no time series ({SUFFIX}) in it: is it a slung run folder?")
    out = prepare_output_dir(args.out) if args.out else None
    for f in files:
        table = read_table(f)
        target = (out or f.parent) / (f.stem + ".csv")
        write_csv(table, target)
        note = "" if table.complete else " (the file ends early: its last whole block; the run was cut short)"
        print(f"{target}: {len(table)} rows, {len(table.columns)} columns{note}", flush=True)
    return 0
