"""The board top level (sensor front end, detector, packetizer, SPI slave), Verilated, against
the golden model: a parallel sensor model in, an SPI master model out (one small build of the
same ``GatewareTop`` class the boards use); also a PLL lock loss inside a frame, after which
the first frame is golden again."""

from simulator import run

from lodestar.hdl.boards import GatewareTop


def test_board_top_packets_equal_golden(tmp_path):
    width, height, cap = 16, 16, 16
    env = {"TB_WIDTH": width, "TB_HEIGHT": height, "TB_SEED": 11, "TB_RECORD_CAPACITY": cap}
    top = GatewareTop("mt9p031", width, height, record_capacity=cap, record_depth=4 * cap)
    assert run(top, "board_top", "board_top_tb", tmp_path / "build", env) == 2
