"""``lodestar regress``: replay the recorded FPGA packets through the firmware on CPython and
MicroPython and diff against the recorded outputs; ``--record`` regenerates the set
(:mod:`lodestar.regress`)."""

import argparse
import sys
from pathlib import Path

from lodestar.regress import micropython as regress_micropython
from lodestar.regress import record as regress_record
from lodestar.regress.replay import (
    DEFAULT_SET,
    RegressionError,
    format_resident,
    format_table,
    regress,
)


def add_parser(sub):
    """Register ``regress`` on an argparse subparsers object."""

    p = sub.add_parser("regress", help="replay the recorded FPGA packets on CPython and "
                                       "MicroPython and diff against the expected outputs",
                       description="Firmware regression: replay the recorded packets through "
                                   "the flight API on CPython and MicroPython and compare "
                                   "with the recorded outputs (exit status 1 on any "
                                   "difference).")
    p.add_argument("--set", dest="set_dir", default=str(DEFAULT_SET), metavar="DIR",
                   help="the regression set (default: lodestar/regress/data/regression)")
    p.add_argument("--micropython", action=argparse.BooleanOptionalAction, default=True,
                   help="also replay on MicroPython (Node.js and `npm ci --prefix "
                        "tools/micropython`; default: yes)")
    p.add_argument("--record", action="store_true",
                   help="(re)generate the set in --set instead of replaying it")
    p.set_defaults(func=run)


def run(args):
    """The ``regress`` command: 0 when every replay agrees, 1 when any differs or the set is
    unusable, 2 for a folder with no set or a missing MicroPython."""
    if args.record:

        try:
            manifest = regress_record.record(args.set_dir, log=sys.stderr)
        except RegressionError as exc:
            print(f"lodestar regress: {exc}", file=sys.stderr)
            return 1
        print(f"recorded {len(manifest['cases'])} packets x {len(manifest['methods'])} "
              f"methods in {args.set_dir}")
        return 0
    if not (Path(args.set_dir) / "manifest.json").is_file():
        print(f"lodestar regress: error: no regression set in {args.set_dir} (no "
              "manifest.json; `lodestar regress --record --set DIR` makes one)",
              file=sys.stderr)
        return 2
    try:
        rows, mp = regress(args.set_dir, args.micropython)
    except RegressionError as exc:
        print(f"lodestar regress: {exc}", file=sys.stderr)
        return 1
    except regress_micropython.MicroPythonError as exc:
        print(f"lodestar regress: {exc}", file=sys.stderr)
        return 1 if regress_micropython.unavailable_reason() is None else 2
    print(format_table(rows, mp))
    if mp is not None:
        print(format_resident(mp))
    return 1 if any(r["problems"] for r in rows) else 0
