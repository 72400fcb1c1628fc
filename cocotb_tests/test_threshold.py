"""The threshold unit, Verilated, against the golden model's levels (cocotb)."""

import pytest

from lodestar.hdl.threshold import ThresholdUnit, global_cycles

from simulator import run


@pytest.mark.parametrize("width,height,bits", [(13, 7, 12), (9, 5, 10)])
def test_threshold_unit_random_frames(tmp_path, width, height, bits):
    env = {"TB_WIDTH": width, "TB_HEIGHT": height, "TB_BITS": bits, "TB_FRAMES": 40,
           "TB_SEED": width * bits, "TB_GAP": global_cycles(width, height, bits)}
    assert run(ThresholdUnit(width, height, bits), "threshold_unit", "threshold_tb",
               tmp_path / "build", env) == 1
