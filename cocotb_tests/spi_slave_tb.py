"""cocotb testbench of the SPI slave (Verilator): an SPI master model (mode 0, MSB first) on
its own time base writes every register, reads the status word, streams packet bytes in
chunks (with underruns and a read cut short) and sends bad and aborted commands, at two SCK
rates asynchronous to the 100 MHz system clock (4.5x and 9.73x).  The packet source and the
write-port monitor act on the falling edge of the system clock.

Parameters from the environment: ``TB_SEED``.
"""

import os
from collections import deque

import cocotb
import numpy as np
from cocotb.clock import Clock
from cocotb.triggers import FallingEdge, Timer

from lodestar import contract as C
from lodestar.contract import (
    FILLER,
    OP_READ_STATUS,
    OP_READ_STREAM,
    OP_WRITE_REG,
    STATUS_BYTES,
    TURNAROUND_BYTES,
    decode_status,
)

T_NS = 10
REPLY = 1 + TURNAROUND_BYTES


class Master:
    """SPI mode 0 master; CS lead/lag/high just above the documented 4 T / 2 T / 3 T."""

    def __init__(self, dut, sck_ns):
        self.dut, self.half = dut, sck_ns / 2

    async def transfer(self, out, bits=None):
        dut = self.dut
        dut.cs_n.value = 0
        await Timer(4.1 * T_NS, unit="ns")
        got = []
        n = 8 * len(out) if bits is None else bits
        for k in range(n):
            byte, bit = divmod(k, 8)
            dut.mosi.value = (out[byte] >> (7 - bit)) & 1
            await Timer(self.half, unit="ns")
            if bit == 0:
                got.append(0)
            got[-1] |= int(dut.miso.value) << (7 - bit)
            dut.sck.value = 1
            await Timer(self.half, unit="ns")
            dut.sck.value = 0
        await Timer(max(2.1 * T_NS - self.half, 0.1), unit="ns")
        dut.cs_n.value = 1
        await Timer(3.1 * T_NS, unit="ns")
        return got

    async def write_reg(self, address, value):
        await self.transfer([OP_WRITE_REG, address] + list(value.to_bytes(4, "big")))

    async def read_status(self):
        got = await self.transfer([OP_READ_STATUS] + [0] * (TURNAROUND_BYTES + STATUS_BYTES))
        assert got[:REPLY] == [FILLER] * REPLY, got
        return decode_status(got[REPLY:])

    async def read_stream(self, n):
        got = await self.transfer([OP_READ_STREAM] + [0] * (TURNAROUND_BYTES + n))
        assert got[:REPLY] == [FILLER] * REPLY, got
        return got[REPLY:]


@cocotb.test()
async def spi_transactions(dut):
    rng = np.random.default_rng(int(os.environ["TB_SEED"]))
    cocotb.start_soon(Clock(dut.clk, T_NS, unit="ns").start())
    dut.rst.value = 1
    dut.cs_n.value = 1
    dut.sck.value = 0
    dut.mosi.value = 0
    dut.packet__valid.value = 0
    dut.busy.value = 0
    dut.overflow.value = 0
    dut.frame_counter.value = 0
    for _ in range(3):
        await FallingEdge(dut.clk)
    dut.rst.value = 0

    queue, writes = deque(), []

    async def source():                   # the packetizer's byte stream (valid/ready)
        while True:
            await FallingEdge(dut.clk)
            dut.packet__valid.value = int(bool(queue))
            if queue:
                dut.packet__payload.value = queue[0]
                if int(dut.packet__ready.value):   # transfer at the next rising edge
                    queue.popleft()

    async def monitor():
        while True:
            await FallingEdge(dut.clk)
            if int(dut.reg_strobe.value):
                writes.append((int(dut.reg_addr.value), int(dut.reg_data.value)))

    cocotb.start_soon(source())
    cocotb.start_soon(monitor())
    thr = C.REGISTER_BY_NAME["threshold"]
    for sck_ns in (45, 97.3):
        m = Master(dut, sck_ns)
        writes.clear()
        values = {r.address: int(rng.integers(0, 1 << r.bits)) for r in C.REGISTERS}
        for r in C.REGISTERS:
            await m.write_reg(r.address, values[r.address])
        assert writes == [(r.address, values[r.address]) for r in C.REGISTERS], writes

        counter = int(rng.integers(0, 1 << 32))
        dut.busy.value, dut.overflow.value, dut.frame_counter.value = 1, 0b0000101, counter
        status = await m.read_status()
        assert status == {"frame_counter": counter, "errors": 0, "underruns": 0,
                          "overflow": 0b0000101, "busy": 1, "trained": 0,
                          "eye_width": 0}, status
        dut.busy.value = 0

        packet = [int(b) for b in rng.integers(0, 256, 48)]
        queue.extend(packet)
        got = []
        for n in (5, 17, 1, 25):                        # 48 bytes, then 0 left
            got += await m.read_stream(n)
        assert got == packet, (got, packet)
        assert await m.read_stream(2) == [FILLER, FILLER]
        queue.extend([0x5A, 0xC3])
        await m.transfer([OP_READ_STREAM, 0, 0], bits=8 * REPLY)   # clocks no packet bit
        assert await m.read_stream(2) == [0x5A, 0xC3]

        await m.write_reg(max(r.address for r in C.REGISTERS) + 1, 1)    # unknown address
        await m.transfer([OP_WRITE_REG, thr.address, 0], bits=19)        # aborted mid-byte
        dut.cs_n.value = 0                                               # glitch
        await Timer(3, unit="ns")
        dut.cs_n.value = 1
        await Timer(5 * T_NS, unit="ns")
        await m.write_reg(thr.address, 123)
        assert writes[-1] == (thr.address, 123) and len(writes) == len(C.REGISTERS) + 1
        status = await m.read_status()
        assert (status["errors"], status["underruns"]) == (2, 2), status
    dut._log.info("SPI slave: writes, status, %d streamed bytes per rate, errors as expected",
                  48)
