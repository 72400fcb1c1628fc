"""cocotb test module of ``lodestar.cosim``: clock the harness and let it play its stimulus.

The harness (``harness.sv``) runs its own clock, reads the stimulus and writes the
output itself; this test only raises ``start`` and waits for ``done``.  The harness stops at
the end of the stimulus file, so the wait is bounded.
"""

import cocotb
from cocotb.triggers import RisingEdge


@cocotb.test()
async def play(dut):
    dut.start.value = 1
    await RisingEdge(dut.done)
