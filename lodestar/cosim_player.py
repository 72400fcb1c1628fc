"""cocotb test module of ``lodestar.cosim``: clock the harness and let it play its stimulus.

The harness (``cosim_harness.sv``) reads the stimulus and writes the output itself; this
test only starts the clock, raises ``start`` and waits for ``done``.  The harness stops at
the end of the stimulus file, so the wait is bounded.
"""

import cocotb
from cocotb.clock import Clock
from cocotb.triggers import RisingEdge


@cocotb.test()
async def play(dut):
    cocotb.start_soon(Clock(dut.clk, 10, unit="ns").start())
    dut.start.value = 1
    await RisingEdge(dut.done)
