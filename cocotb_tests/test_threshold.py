"""The threshold unit, Verilated, against the golden model's levels (cocotb)."""

import pytest
from simulator import run

from lodestar.hdl.threshold import (
    ThresholdUnit,
    global_cycles,
    local_blanking,
    local_log2_window_max,
)


@pytest.mark.parametrize("width,height,bits,frames", [(13, 7, 12, 40), (131, 3, 10, 24)])
def test_threshold_unit_random_frames(tmp_path, width, height, bits, frames):
    """Fixed, global and local frames in random order; the wide frame admits L = 128."""
    lg_max = local_log2_window_max(width)
    env = {"TB_WIDTH": width, "TB_HEIGHT": height, "TB_BITS": bits, "TB_FRAMES": frames,
           "TB_SEED": width * bits, "TB_GAP": global_cycles(width, height, bits),
           "TB_LOG2_WINDOW_MAX": lg_max, "TB_DRAIN": local_blanking(lg_max) + 1}
    assert run(ThresholdUnit(width, height, bits), "threshold_unit", "threshold_tb",
               tmp_path / "build", env) == 1
