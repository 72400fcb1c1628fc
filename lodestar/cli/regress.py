"""``lodestar regress``: replay the recorded FPGA packets through the firmware on CPython and
MicroPython and diff against the recorded outputs; ``--record`` regenerates the set
(:mod:`lodestar.regress`)."""

import argparse
import sys
from pathlib import Path

from lodestar.regress import micropython, qemu, record
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
                                   "the flight API on CPython, on the flight MCU's build (the "
                                   "Cortex-M4F image under QEMU) and on MicroPython "
                                   "(WebAssembly) and compare with the recorded outputs (exit "
                                   "status 1 on any difference).")
    p.add_argument("--set", dest="set_dir", default=str(DEFAULT_SET), metavar="DIR",
                   help="the regression set (default: lodestar/regress/data/regression)")
    p.add_argument("--micropython", action=argparse.BooleanOptionalAction, default=True,
                   help="also replay on MicroPython (Node.js and `npm ci --prefix "
                        "tools/micropython`; default: yes)")
    p.add_argument("--float32", action=argparse.BooleanOptionalAction, default=True,
                   help="also replay on the flight MCU's build, MicroPython for a Cortex-M4F "
                        "(float32, floats in the object word, firmware and set frozen) on "
                        "QEMU, against its recorded float32 outputs (built with "
                        "build-qemu.sh beside $LODESTAR_MICROPYTHON_BUILD or in "
                        "../shared/micropython, into the cache; needs arm-none-eabi-gcc and "
                        "qemu-system-arm; default: yes)")
    p.add_argument("--record", action="store_true",
                   help="(re)generate the set in --set instead of replaying it")
    p.add_argument("--record-float32", action="store_true",
                   help="record only the float32 expectations of the set in --set again, on "
                        "the flight build (after a change of its arithmetic; the packets "
                        "and double expectations stay)")
    p.set_defaults(func=run)


def run(args):
    """The ``regress`` command: 0 when every replay agrees, 1 when any differs, the set is
    unusable or a MicroPython run fails, 2 for a folder with no set or a missing MicroPython
    or Cortex-M4F build (recording always needs the Cortex-M4F build)."""
    missing = not (Path(args.set_dir) / "manifest.json").is_file()
    if missing and not args.record:
        print(f"lodestar regress: error: no regression set in {args.set_dir} (no "
              "manifest.json; `lodestar regress --record --set DIR` makes one)",
              file=sys.stderr)
        return 2
    if args.record or args.record_float32:
        try:
            if args.record_float32:
                manifest = record.record_float32(args.set_dir)
            else:
                manifest = record.record(args.set_dir, log=sys.stderr)
        except qemu.Unavailable as exc:
            print(f"lodestar regress: {exc}; nothing recorded", file=sys.stderr)
            return 2
        except (RegressionError, micropython.MicroPythonError) as exc:
            print(f"lodestar regress: {exc}", file=sys.stderr)
            return 1
        print(f"recorded {len(manifest['cases'])} packets x {len(manifest['methods'])} "
              f"methods in {args.set_dir}")
        return 0
    try:
        rows, mp = regress(args.set_dir, args.micropython, float32=args.float32)
    except RegressionError as exc:
        print(f"lodestar regress: {exc}", file=sys.stderr)
        return 1
    except qemu.Unavailable as exc:
        print(f"lodestar regress: {exc}", file=sys.stderr)
        return 2
    except micropython.MicroPythonError as exc:
        print(f"lodestar regress: {exc}", file=sys.stderr)
        missing = args.micropython and micropython.unavailable_reason() is not None
        return 2 if missing else 1
    print(format_table(rows, mp, args.float32))
    if mp is not None:
        print(format_resident(mp))
    return 1 if any(r["problems"] for r in rows) else 0
