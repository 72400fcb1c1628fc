"""Resource estimation: M9K counting rules, multiplier elements, the memory inventory of a
design, netlist analysis (units, carry-chain LEs, logic depth) on a hand-made netlist, and
one real Yosys run on a small build."""

import json

import pytest

from lodestar.hdl.boards import BOARDS, GatewareTop
from lodestar.hdl.estimate import (
    BLOCK_RAM_CLK_TO_Q_NS,
    ROUTING_NS_PER_HOP,
    analyse,
    board_report,
    format_report,
    m9k_blocks,
    memories,
    multiplier_elements,
    multiplier_les,
)
from lodestar.hdl.layouts import record_layout


@pytest.mark.parametrize("depth,width,r,w,blocks", [
    (8192, 1, 1, 1, 1), (8193, 1, 1, 1, 2), (256, 36, 1, 1, 1), (256, 37, 1, 1, 2),
    (256, 345, 1, 1, 10), (1296, 9, 1, 2, 2), (512, 36, 1, 2, 2), (512, 36, 1, 1, 2),
    (2592, 1, 2, 1, 2), (3, 224, 1, 1, 7), (256, 173, 1, 1, 5), (0, 8, 1, 1, 0)])
def test_m9k_blocks(depth, width, r, w, blocks):
    assert m9k_blocks(depth, width, r, w) == blocks


def test_multiplier_elements():
    assert multiplier_elements(9, 9) == (1, 0)
    assert multiplier_elements(12, 4) == (0, 1)
    assert multiplier_elements(24, 12) == (0, 2)


def test_multiplier_les_count_the_adders_around_the_elements():
    assert multiplier_les({"A_WIDTH": "1100", "B_WIDTH": "100"}, 16) == 0     # 12 x 4
    assert multiplier_les({"A_WIDTH": "11000", "B_WIDTH": "1100"}, 36) == 36  # 24 x 12: 2
    # s + p * p (Yosys' $macc_v2: one 12 x 12 product and one addend) into 47 bits
    macc = {"NPRODUCTS": "1", "NADDENDS": "1", "A_WIDTHS": format(12, "016b"),
            "B_WIDTHS": format(12, "016b")}
    assert multiplier_les(macc, 47) == 47
    two = {"NPRODUCTS": "10", "NADDENDS": "0", "A_WIDTHS": format(20, "016b") * 2,
           "B_WIDTHS": format(8, "016b") * 2}                               # a*b + c*d
    assert multiplier_les(two, 30) == 2 * 28 + 30


def test_memories_of_a_design():
    mems = {m["name"]: m for m in memories(GatewareTop("mt9p031", 64, 16, record_capacity=8))}
    bitmap = mems["detector.labeller.bitmap"]
    assert (bitmap["depth"], bitmap["width"], bitmap["bits"]) == (64, 1, 64)
    rec = mems["detector.output.record_fifo.storage"]        # 8 records as 16 half-words
    assert (rec["depth"], rec["width"]) == (16, (record_layout(64, 16, 12).size + 1) // 2)
    assert mems["detector.labeller.flags0"]["write_ports"] == 2
    assert "frontend.crossing.fifo.storage" in mems


def _cell(kind, conns, **params):
    return {"type": kind, "connections": conns, "parameters": params}


def test_analyse_counts_and_depth():
    """ff -> lut -> 16-bit adder -> lut -> ff: depth 1 + (1 + 2) + 1 = 5; the adder is 16 LEs,
    the multiplier is counted, memories and multipliers end paths."""
    cells = {
        "a.r1_dffeas": _cell("dffeas", {"d": [9], "q": [2]}),
        "a.x_$lut": _cell("cycloneive_lcell_comb", {"dataa": [2], "combout": [3]}),
        "$flatten\\a.b.$add$f.py:1$7": _cell("lodestar_arith",
                                             {"A": [3], "B": [2], "Y": list(range(10, 26))}),
        "a.b.y_$lut": _cell("cycloneive_lcell_comb", {"dataa": [25], "combout": [4]}),
        "a.b.r2_dffeas": _cell("dffeas", {"d": [4], "q": [5]}),
        "c.mul": _cell("lodestar_mul", {"A": [5], "B": [5], "Y": [6]},
                       A_WIDTH="1100", B_WIDTH="100"),
        "c.m_$lut": _cell("cycloneive_lcell_comb", {"dataa": [6], "combout": [9]}),
    }
    out = analyse({"modules": {"t": {"cells": cells}}}, "t")
    assert (out["luts"], out["ffs"], out["arith_les"], out["les"]) == (3, 2, 16, 19)
    assert out["multipliers"] == [(12, 4)]
    assert out["depth"] == 5 and out["critical_unit"] == "a.b"
    assert out["depth_by_unit"] == {"a": 1, "a.b": 5, "c": 1}
    path = out["paths"]["a.b"]
    assert path["cells"][0] == "a.x_$lut" and path["cells"][-1] == "a.b.y_$lut"
    assert path["cells"][1] == "a.b.$add$f.py:1$7 (carry chain, 16 bits)"
    assert path["ns"] == pytest.approx(0.6 + 3 * 0.5 + 16 * 0.06 + 4 * ROUTING_NS_PER_HOP)
    assert not path["from_memory"]
    assert out["by_unit"]["a.b"]["les"] == 17


def test_a_path_out_of_a_memory_outweighs_a_deeper_one():
    """A memory's read data through one LUT costs the block RAM's clock-to-output: it is
    the unit's slowest path although another one is three LUTs deep."""
    cells = {
        "u.r_dffeas": _cell("dffeas", {"d": [9], "q": [2]}),
        "u.l1_$lut": _cell("cycloneive_lcell_comb", {"dataa": [2], "combout": [3]}),
        "u.l2_$lut": _cell("cycloneive_lcell_comb", {"dataa": [3], "combout": [4]}),
        "u.l3_$lut": _cell("cycloneive_lcell_comb", {"dataa": [4], "combout": [9]}),
        "u.mem": _cell("lodestar_mem", {"RD_ADDR": [2], "RD_DATA": [5]}),
        "u.m_$lut": _cell("cycloneive_lcell_comb", {"dataa": [5], "combout": [6]}),
    }
    out = analyse({"modules": {"t": {"cells": cells}}}, "t")
    assert out["depth"] == 3
    path = out["paths"]["u"]
    assert path["cells"] == ["u.m_$lut"] and path["from_memory"]
    assert path["ns"] == pytest.approx(0.6 + BLOCK_RAM_CLK_TO_Q_NS + 0.5 +
                                       2 * ROUTING_NS_PER_HOP)


@pytest.fixture(scope="module")
def small_build(tmp_path_factory):
    """One real Yosys run of a small board top (32 x 8): its report and its work folder."""
    workdir = tmp_path_factory.mktemp("small_build")
    top = GatewareTop("mt9p031", 32, 8, label_capacity=4, record_capacity=4)
    return board_report(BOARDS["de0-nano"], top, workdir=workdir), workdir


def test_board_report_of_a_small_build(small_build):
    """A real Yosys run (small frame): logic, multipliers and depth are present and sane."""
    report, _workdir = small_build
    logic = report["logic"]
    assert logic["les"] == logic["luts"] + logic["arith_les"] > 500
    assert logic["ffs"] > 300
    assert {"detector.features", "detector.labeller", "packetizer", "spi"} <= set(logic["by_unit"])
    assert report["multipliers"]["18x18"] >= 1
    assert 3 <= report["depth"]["levels"] < 100
    assert report["m9k"]["used"] == sum(m["m9k"] for m in report["memories"])
    assert "estimate" in format_report(report).lower()


def test_boxed_cells_keep_their_outputs(small_build):
    """Memories, multipliers and adders are boxed out of Yosys' mapping; their outputs must
    stay driven (undeclared box ports were once tied to 0 and all logic behind them
    optimised away, halving the LE estimate)."""
    netlist = json.loads((small_build[1] / "star_tracker.json").read_text())
    cells = netlist["modules"]["star_tracker"]["cells"]
    boxes = [c for c in cells.values() if c["type"].startswith("lodestar_")]
    assert len(boxes) > 20
    for cell in boxes:
        for port in ("Y", "RD_DATA"):
            bits = cell["connections"].get(port, [])
            assert not bits or not all(isinstance(b, str) for b in bits), cell["type"]


def test_frame_beyond_the_part_is_refused():
    board = BOARDS["de0-nano"]
    top = GatewareTop("mt9p031", 4096, 4096, label_capacity=2049, record_capacity=4096)
    with pytest.raises(ValueError, match=r"needs \d+ M9K blocks, the part has 66.*--width"):
        board_report(board, top, yosys=False)


def test_estcube2_memory_budget():
    """The issue's goal: at most half of the EP4CE22's 66 M9K for 2592 x 1944 x 12."""
    from lodestar.hdl.estimate import memory_budget

    mems, m9k, _ = memory_budget(BOARDS["estcube2"].gateware_top())
    assert m9k <= 33
    by_name = {m["name"]: m for m in mems}
    assert by_name["detector.output.record_fifo.storage"]["m9k"] == 5
    assert not any("trailer" in name for name in by_name)      # the trailer is in registers
