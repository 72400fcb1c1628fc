"""The board top level with the MT9V022 LVDS front end (front end with phase training,
detector, packetizer, SPI slave), Verilated, against the golden model: an LVDS sensor model
in, an SPI master model out (one small build of the same ``GatewareTop`` class the DE2-115
uses, ``TAPS`` sample phases); also a link that dies inside a frame (timed out, flagged,
bit-exact) and a skewed link whose eye the trainer finds."""

from simulator import run

from lodestar.hdl.boards import GatewareTop


def test_board_lvds_packets_equal_golden(tmp_path):
    width, height, cap = 24, 16, 16
    taps = 8
    env = {"TB_WIDTH": width, "TB_HEIGHT": height, "TB_SEED": 7, "TB_RECORD_CAPACITY": cap,
           "TB_TAPS": taps}
    # a short stall timeout (above a row's blanking, about 70 sync clocks) for the cut link
    top = GatewareTop("mt9v022", width, height, record_capacity=cap, record_depth=4 * cap,
                      stall_timeout=4000, taps=taps)
    assert run(top, "board_lvds", "board_lvds_tb", tmp_path / "build", env) == 3
