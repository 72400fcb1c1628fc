"""cocotb test module of ``lodestar.cosim``: clock the harness and let it play its stimulus.

The harness (``harness.sv``) runs its own clock, reads the stimulus and writes the output
itself; this test only raises ``start`` and waits for ``done``. It polls ``done`` every
``POLL_NS`` of simulated time instead of awaiting its edge: a value-change callback is
compared by Verilator's VPI after every time step (~5 % of the playback in ``perf``). The
harness stops at the end of the stimulus file, so the wait is bounded; the poll adds at most
``POLL_NS`` (100 time steps of 1000 clocks: 0.1 Mclk) of the detector held in reset.
"""

import cocotb
from cocotb.triggers import Timer

POLL_NS = 1_000


@cocotb.test()
async def play(dut):
    dut.start.value = 1
    while not dut.done.value:
        await Timer(POLL_NS, "ns")
