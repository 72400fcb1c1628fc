"""Board top levels: every board elaborates into a Quartus project with its pins, I/O
standards, clocks and constraints; bad names are refused.  (The top level's behaviour is
checked on Verilator in ``cocotb_tests/test_board_top.py``.)"""

import copy
import re

import pytest

from lodestar import contract as C
from lodestar.hdl.boards import (
    BOARDS,
    BoardTop,
    GatewareTop,
    board_platform,
    sdc_constraints,
)


@pytest.fixture(scope="module")
def projects(tmp_path_factory):
    """Quartus projects of every board, small frames (the pins and clocks do not depend on
    the frame), as ``{board: {file name: text}}``."""
    out = {}
    for name, board in BOARDS.items():
        small = copy.copy(board)
        small.width, small.height, small.record_capacity, small.record_depth = 16, 8, 4, 4
        top = BoardTop(small)
        plan = board_platform(name).prepare(top, name="lodestar",
                                            add_constraints=sdc_constraints(board))
        folder = tmp_path_factory.mktemp(name)
        plan.extract(str(folder))
        out[name] = {p.name: p.read_text() for p in folder.iterdir()}
    return out


@pytest.mark.parametrize("name", sorted(BOARDS))
def test_project_files_pins_and_clocks(projects, name):
    board, files = BOARDS[name], projects[name]
    assert {"lodestar.v", "lodestar.qsf", "lodestar.sdc", "build_lodestar.sh"} <= set(files)
    qsf, sdc = files["lodestar.qsf"], files["lodestar.sdc"]
    assert f"set_global_assignment -name DEVICE {board.part}" in qsf
    located = dict(re.findall(r'set_location_assignment -to "([^"]+)" PIN_(\w+)', qsf))
    assert located.pop("clk_osc_0__io") == board.osc_pin
    expected = set()
    for signals in board.pins.values():
        for pins, _direction, _assumed in signals.values():
            expected.update(pins.split())
    assert set(located.values()) == expected       # every board pin, nothing else
    assert qsf.count("io_standard") >= len(located)
    period = 1e9 / board.osc_hz
    assert f'create_clock -name "clk_osc_0__io" -period {period}' in sdc
    assert "derive_pll_clocks" in sdc and "set_clock_groups -asynchronous" in sdc
    verilog = files["lodestar.v"]
    assert "altpll" in verilog
    assert ("altlvds_rx" in verilog) == (board.sensor == "mt9v022")


def test_boards_are_the_issue_targets():
    assert BOARDS["de2-115"].part == "EP4CE115F29C7" and BOARDS["de2-115"].sensor == "mt9v022"
    assert BOARDS["de0-nano"].part == "EP4CE22F17C6" and BOARDS["de0-nano"].sensor == "mt9p031"
    assert BOARDS["estcube2"].device == "EP4CE22"
    for board in BOARDS.values():
        assert board.pixel_bits in C.SENSOR_PIXEL_BITS.values()
        assert board.sync_hz >= board.pixel_hz     # the pixel crossing's requirement


def test_bad_names_are_refused():
    with pytest.raises(ValueError, match="unknown board 'de1'.*de2-115"):
        board_platform("de1")
    with pytest.raises(ValueError, match="unknown board"):
        BoardTop("de1")
    with pytest.raises(ValueError, match="unknown sensor 'ov7670'"):
        GatewareTop("ov7670", 16, 8)
