"""Every memory in the generated Verilog is read synchronously, the pattern Quartus infers as
M9K block RAM: a read of a memory array only inside a clocked ``always`` block.  An
asynchronous read (``assign q = mem[addr]``, or a read in a combinational block) is what
Amaranth emits for a transparent read port, and Quartus builds such a memory from logic
("uninferred due to asynchronous read logic"), which the feature table cannot afford."""

import copy
import re

import pytest

from lodestar.hdl.boards import BOARDS, BoardTop, board_platform, sdc_constraints
from lodestar.hdl.detector import Detector
from lodestar.hdl.export import to_verilog

_MEMORY = re.compile(r"^\s*reg\s+(?:\[[^\]]*\]\s*)?(\\\S+|[A-Za-z_]\w*)\s*\[[^\]]*\]\s*;",
                     re.MULTILINE)


def asynchronous_reads(verilog):
    """``[(memory, line)]`` for every read of a memory array outside a clocked ``always``
    block.  Module items are the lines at the module's indentation (Yosys' ``write_verilog``
    layout); a deeper line belongs to the item above it.  Writes (``mem[a] <=``, and the
    ``initial`` block's ``mem[a] =``) are not reads."""
    names = set(_MEMORY.findall(verilog))
    if not names:
        return []
    uses = re.compile(r"(" + "|".join(re.escape(n) for n in names) + r")\s*\[")
    found, clocked, indent = [], False, None
    for line in verilog.splitlines():
        stripped = line.lstrip()
        if not stripped:
            continue
        depth = len(line) - len(stripped)
        if stripped.startswith("module "):
            indent = None
            continue
        if indent is None:
            indent = depth
        if _MEMORY.match(line):
            continue                                   # the declaration
        if depth <= indent:
            clocked = re.match(r"always\s*@\s*\(\s*(posedge|negedge)\b", stripped) is not None
        for match in uses.finditer(line):
            rest = line[match.end():]
            close = rest.find("]")
            after = rest[close + 1:].lstrip() if close >= 0 else ""
            if after.startswith("<=") or (after.startswith("=") and
                                          not after.startswith("==")):
                continue                               # a write
            if not clocked:
                found.append((match.group(1), stripped))
    return found


def test_the_check_finds_an_asynchronous_read():
    async_read = """module m(clk, a, q);
  reg [3:0] mem [7:0];
  always @(posedge clk) begin
    mem[a] <= 4'h1;
  end
  reg [2:0] a_q;
  always @(posedge clk) begin
    a_q <= a;
  end
  assign q = mem[a_q];
endmodule
"""
    sync_read = async_read.replace("a_q <= a;", "q_r <= mem[a];").replace(
        "assign q = mem[a_q];", "assign q = q_r;")
    assert asynchronous_reads(async_read) == [("mem", "assign q = mem[a_q];")]
    assert asynchronous_reads(sync_read) == []


def test_detector_memories_read_synchronously():
    """The detector alone (every unit's memories; the patterns do not depend on the
    frame size)."""
    verilog = to_verilog(Detector(64, 16, 12, 8, 8, 4), "detector")
    assert _MEMORY.search(verilog), "no memory found: the check would be vacuous"
    assert asynchronous_reads(verilog) == []


@pytest.mark.parametrize("name", sorted(BOARDS))
def test_board_memories_read_synchronously(tmp_path, name):
    """The board's Quartus Verilog (small frames: the memories' patterns do not depend
    on the frame), the sensor front end's clock-crossing FIFO included."""
    small = copy.copy(BOARDS[name])
    small.width, small.height, small.record_capacity, small.record_depth = 16, 8, 4, 4
    plan = board_platform(name).prepare(BoardTop(small), name="lodestar",
                                        add_constraints=sdc_constraints(small))
    plan.extract(str(tmp_path))
    verilog = (tmp_path / "lodestar.v").read_text()
    assert len(_MEMORY.findall(verilog)) >= 8
    assert asynchronous_reads(verilog) == []
