"""The SPI slave in the Amaranth simulator, driven by an SPI master model (mode 0, MSB first)
whose SCK is asynchronous to the system clock, at several SCK/sysclk ratios down to the
documented 4x: register writes and read-back, status reads (CRC-8 checked), the ID word,
the keyed soft-reset and flush strobes, packet streaming with underruns and partial reads,
bad commands, and CS/SCK glitches that must not wedge the slave."""

from collections import deque

import numpy as np
import pytest
from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.contract import (
    FILLER,
    OP_FLUSH,
    OP_READ_ID,
    OP_READ_REG,
    OP_READ_STATUS,
    OP_READ_STREAM,
    OP_SOFT_RESET,
    OP_WRITE_REG,
    OVERFLOW_BITS,
    STATUS_BYTES,
    TURNAROUND_BYTES,
    command_key,
    decode_id,
    decode_status,
)
from lodestar.hdl.spi_slave import SPISlave

NS = 1e-9
REPLY = 1 + TURNAROUND_BYTES        # MISO bytes before a read's first reply byte


class Master:
    """SPI mode 0 master on the simulator's time line: ``T`` the sys clock period; CS lead,
    lag and high time just above the documented minimums (4 T, 2 T, 3 T)."""

    def __init__(self, ctx, dut, T, sck_period):
        self.ctx, self.dut, self.T, self.half = ctx, dut, T, sck_period / 2

    async def transfer(self, out, bits=None):
        """Send the bytes ``out`` (stop after ``bits`` bits if given); return MISO bytes."""
        ctx, dut = self.ctx, self.dut
        ctx.set(dut.cs_n, 0)
        await ctx.delay(4.1 * self.T)
        got = []
        n = 8 * len(out) if bits is None else bits
        for k in range(n):
            byte, bit = divmod(k, 8)
            ctx.set(dut.mosi, (out[byte] >> (7 - bit)) & 1)
            await ctx.delay(self.half)
            if bit == 0:
                got.append(0)
            got[-1] |= ctx.get(dut.miso) << (7 - bit)   # sampled on the rising edge
            ctx.set(dut.sck, 1)
            await ctx.delay(self.half)
            ctx.set(dut.sck, 0)
        await ctx.delay(max(2.1 * self.T - self.half, 0))
        ctx.set(dut.cs_n, 1)
        await ctx.delay(3.1 * self.T)
        return got

    async def write_reg(self, address, value):
        await self.transfer([OP_WRITE_REG, address] + list(value.to_bytes(4, "big")))

    async def read_status(self):
        got = await self.transfer([OP_READ_STATUS] + [0] * (TURNAROUND_BYTES + STATUS_BYTES))
        assert got[:REPLY] == [FILLER] * REPLY
        return decode_status(got[REPLY:])

    async def read_reg(self, address):
        got = await self.transfer([OP_READ_REG, address] + [0] * (TURNAROUND_BYTES + 4))
        assert got[:C.READ_REG_FIRST_REPLY] == [FILLER] * C.READ_REG_FIRST_REPLY
        return int.from_bytes(bytes(got[C.READ_REG_FIRST_REPLY:]), "big")

    async def read_id(self):
        got = await self.transfer([OP_READ_ID] + [0] * (TURNAROUND_BYTES + C.ID_BYTES))
        assert got[:C.ID_FIRST_REPLY] == [FILLER] * C.ID_FIRST_REPLY
        return decode_id(bytes(got[C.ID_FIRST_REPLY:]))

    async def read_stream(self, n):
        got = await self.transfer([OP_READ_STREAM] + [0xFF] * (TURNAROUND_BYTES + n))
        assert got[:REPLY] == [FILLER] * REPLY
        return got[REPLY:]


def simulate(script, T, sck_period, packet=(), build=0):
    """Run ``script(master, state)`` against a fresh slave with a packet-byte source holding
    ``packet`` and a register bank (``reg_rdata`` the word at ``reg_addr`` one clock later, as
    a registered read mux gives it; writes land in it); ``state`` has ``writes`` [(addr,
    data)], ``bank``, ``queue`` (bytes not yet consumed, the script may append),
    ``status_reads``, ``resets`` and ``flushes`` (strobe clocks) and ``set(name, value)``."""
    dut = SPISlave(build=build)
    state = {"writes": [], "queue": deque(packet), "status_reads": 0, "bank": {},
             "resets": 0, "flushes": 0}

    async def bench(ctx):
        state["set"] = lambda name, value: ctx.set(getattr(dut, name), value)
        await script(Master(ctx, dut, T, sck_period), state)

    async def monitor(ctx):
        while True:
            _, _, strobe, addr, data, read, reset, flush = await ctx.tick().sample(
                dut.reg_strobe, dut.reg_addr, dut.reg_data, dut.status_read, dut.soft_reset,
                dut.flush)
            if strobe:
                state["writes"].append((addr, data))
                state["bank"][addr] = data
            ctx.set(dut.reg_rdata, state["bank"].get(ctx.get(dut.reg_addr), 0))
            state["status_reads"] += read
            state["resets"] += reset
            state["flushes"] += flush

    async def source(ctx):
        q = state["queue"]
        while True:
            ctx.set(dut.packet.valid, bool(q))
            if q:
                ctx.set(dut.packet.payload, q[0])
            _, _, valid, ready = await ctx.tick().sample(dut.packet.valid, dut.packet.ready)
            if valid and ready:
                q.popleft()

    sim = Simulator(dut)
    sim.add_clock(T, phase=0.43 * T)
    sim.add_testbench(bench)
    sim.add_testbench(monitor, background=True)
    sim.add_testbench(source, background=True)
    sim.run()
    return state


RATIOS = [(10, 40), (10, 53.7), (10, 97), (7, 160)]
"""(sys clock period, SCK period) in ns: 4x (the documented minimum) up to 23x."""


@pytest.mark.parametrize("T,sck", RATIOS)
def test_registers_status_and_stream(T, sck):
    rng = np.random.default_rng(int(sck))
    values = {r.address: int(rng.integers(0, 1 << r.bits)) for r in C.REGISTERS}
    packet = [int(b) for b in rng.integers(0, 256, 60)]
    chunks = [7, 1, 13, 0, 19, 20]
    result = {}

    async def script(master, state):
        for r in C.REGISTERS:
            await master.write_reg(r.address, values[r.address])
        state["set"]("busy", 1)
        state["set"]("overflow", 0b1010011)
        state["set"]("frame_counter", 0xDEADBEEF)
        state["set"]("trained", 1)
        state["set"]("eye_width", 11)
        result["status"] = await master.read_status()
        result["stream"] = [await master.read_stream(n) for n in chunks]
        result["status2"] = await master.read_status()

    state = simulate(script, T * NS, sck * NS, packet)
    assert state["writes"] == [(r.address, values[r.address]) for r in C.REGISTERS]
    assert result["status"] == {"frame_counter": 0xDEADBEEF, "errors": 0, "underruns": 0,
                                "overflow": 0b1010011, "busy": 1, "trained": 1,
                                "eye_width": 11}
    assert sum(result["stream"], []) == packet     # in order, nothing lost or repeated
    assert list(state["queue"]) == []
    assert result["status2"]["underruns"] == 0
    assert state["status_reads"] == 2


def test_underruns_and_partial_reads():
    """Reads past the end of the available bytes get FILLER and count underruns; bytes that
    arrive later, and bytes a read did not clock, come out in order on the next read."""
    result = {}

    async def script(master, state):
        q = state["queue"]
        result["a"] = await master.read_stream(5)          # 3 available: 2 underruns
        q.extend([0x10, 0x11, 0x12, 0x13])
        result["b"] = await master.read_stream(2)          # leaves 0x12, 0x13
        # a read cut after the turnaround byte clocks no packet bit: nothing consumed
        await master.transfer([OP_READ_STREAM, 0, 0], bits=8 * REPLY)
        result["c"] = await master.read_stream(3)          # 0x12 0x13 + 1 underrun
        result["status"] = await master.read_status()
        result["status2"] = await master.read_status()

    state = simulate(script, 10 * NS, 53 * NS, packet=[0xA0, 0xA1, 0xA2])
    assert result["a"] == [0xA0, 0xA1, 0xA2, FILLER, FILLER]
    assert result["b"] == [0x10, 0x11]
    assert result["c"] == [0x12, 0x13, FILLER]
    assert result["status"]["underruns"] == 3
    assert result["status2"]["underruns"] == 0      # counts since the previous status read
    assert list(state["queue"]) == []


def test_bad_commands_are_ignored_and_counted():
    mode = C.REGISTER_BY_NAME["mode"]
    thr = C.REGISTER_BY_NAME["threshold"]
    unknown = max(r.address for r in C.REGISTERS) + 1
    result = {}

    async def script(master, state):
        await master.write_reg(unknown, 5)                          # unknown address
        await master.write_reg(mode.address, 1 << mode.bits)        # wider than the field
        await master.transfer([OP_WRITE_REG, thr.address, 0, 0])    # aborted write
        await master.transfer([0x00, 1, 2])                         # unknown opcode
        await master.transfer([OP_WRITE_REG, thr.address, 0, 0, 0, 77, 99, 98])  # extra bytes
        result["status"] = await master.read_status()
        result["status2"] = await master.read_status()

    state = simulate(script, 10 * NS, 41 * NS)
    assert state["writes"] == [(thr.address, 77)]
    assert result["status"]["errors"] == 4
    assert result["status2"]["errors"] == 0


def test_glitches_do_not_wedge():
    """CS pulses too short to see, CS low without clocks, SCK toggling while deselected and a
    transaction aborted mid-byte: afterwards writes, status and stream work normally."""
    thr = C.REGISTER_BY_NAME["threshold"]
    result = {}

    async def script(master, state):
        ctx, dut, T = master.ctx, master.dut, master.T
        ctx.set(dut.cs_n, 0)                       # shorter than a sys clock
        await ctx.delay(0.4 * T)
        ctx.set(dut.cs_n, 1)
        await ctx.delay(5 * T)
        await master.transfer([], bits=0)          # CS low and high, no clocks
        for _ in range(11):                        # SCK on the bus for another slave
            ctx.set(dut.sck, 1)
            ctx.set(dut.mosi, 1)
            await ctx.delay(2.5 * T)
            ctx.set(dut.sck, 0)
            await ctx.delay(2.5 * T)
        await master.transfer([OP_WRITE_REG, thr.address, 0, 0, 1, 2], bits=8 * 5 + 3)
        await master.transfer([OP_READ_STREAM, 0, 0], bits=8 * REPLY + 5)   # byte 0 clocked
        ctx.set(dut.cs_n, 0)                       # a transaction of three clocks only
        await ctx.delay(4.1 * T)
        for _ in range(3):
            ctx.set(dut.sck, 1)
            await ctx.delay(2.5 * T)
            ctx.set(dut.sck, 0)
            await ctx.delay(2.5 * T)
        ctx.set(dut.cs_n, 1)
        await ctx.delay(3.1 * T)
        await master.write_reg(thr.address, 300)
        result["status"] = await master.read_status()
        result["stream"] = await master.read_stream(2)

    state = simulate(script, 10 * NS, 45 * NS, packet=[1, 2, 3])
    assert state["writes"] == [(thr.address, 300)]
    assert result["status"]["errors"] == 1                      # the aborted write
    assert result["stream"] == [2, 3]       # byte 1 went with the read cut inside it


def test_status_layout_and_decode():
    assert STATUS_BYTES * 8 == 32 + 8 + 8 + OVERFLOW_BITS + 1 + 1 + C.EYE_WIDTH_BITS + 8
    word = bytes([0x12, 0x34, 0x56, 0x78, 0x05, 0x06, 0x83, 0x8A])
    word += bytes([C.crc8(word)])
    assert decode_status(word) == {"frame_counter": 0x12345678, "errors": 5, "underruns": 6,
                                   "overflow": 0x41, "busy": 1, "trained": 1,
                                   "eye_width": 10}
    with pytest.raises(ValueError, match="status word"):
        decode_status(word[:-1])
    with pytest.raises(ValueError, match="CRC"):
        decode_status(word[:-1] + bytes([word[-1] ^ 1]))


@pytest.mark.parametrize("T,sck", [(10, 40), (10, 97)])
def test_read_back_id_and_keyed_commands(T, sck):
    """Every register reads back what was written (an unknown address reads 0);
    the ID word carries the build byte; soft reset and flush strobe once each with the right
    key, never with a wrong or missing key (each counted as an error), and touch neither the
    registers nor the stream."""
    rng = np.random.default_rng(int(sck))
    values = {r.address: int(rng.integers(0, 1 << r.bits)) for r in C.REGISTERS}
    unknown = max(r.address for r in C.REGISTERS) + 1
    result = {}

    async def script(master, state):
        for r in C.REGISTERS:
            await master.write_reg(r.address, values[r.address])
        result["back"] = {r.address: await master.read_reg(r.address) for r in C.REGISTERS}
        result["unknown"] = await master.read_reg(unknown)                 # error 1
        result["id"] = await master.read_id()
        await master.transfer([OP_SOFT_RESET, command_key(OP_SOFT_RESET)])
        await master.transfer([OP_FLUSH, command_key(OP_FLUSH), 0, 0])     # extra bytes
        await master.transfer([OP_SOFT_RESET, command_key(OP_FLUSH)])      # error 2
        await master.transfer([OP_FLUSH, 0x00])                            # error 3
        await master.transfer([OP_SOFT_RESET])                             # error 4
        await master.transfer([OP_FLUSH, command_key(OP_FLUSH)], bits=12)  # error 5
        result["status"] = await master.read_status()
        result["stream"] = await master.read_stream(3)
        result["back2"] = await master.read_reg(C.REGISTER_BY_NAME["min_sum"].address)

    state = simulate(script, T * NS, sck * NS, packet=[5, 6, 7], build=0x2A)
    assert result["back"] == values
    assert result["unknown"] == 0
    assert result["id"] == {"magic": C.ID_MAGIC, "link_version": C.LINK_VERSION, "build": 0x2A}
    assert (state["resets"], state["flushes"]) == (1, 1)
    assert result["status"]["errors"] == 5
    assert result["stream"] == [5, 6, 7]
    assert result["back2"] == values[C.REGISTER_BY_NAME["min_sum"].address]


def test_miso_driven_only_while_selected():
    """``miso_oe`` (the board's MISO output enable) is high only while CS is low, give or take
    the CS synchronizer's 2-3 clocks, so MISO is tri-stated on a shared bus between
    transactions; it is high through every bit the master samples."""
    T = 10 * NS
    dut = SPISlave()
    trace = []                                 # per clock: (cs_n, miso_oe)
    sampled_oe = []

    async def bench(ctx):
        master = Master(ctx, dut, T, 40 * NS)
        await ctx.delay(5 * T)
        for _ in range(3):
            await master.read_status()
            await ctx.delay(7 * T)

    async def monitor(ctx):
        while True:
            _, _, cs_n, oe, sck = await ctx.tick().sample(dut.cs_n, dut.miso_oe, dut.sck)
            trace.append((cs_n, oe))
            if sck and not cs_n:
                sampled_oe.append(oe)

    sim = Simulator(dut)
    sim.add_clock(T, phase=0.43 * T)
    sim.add_testbench(bench)
    sim.add_testbench(monitor, background=True)
    sim.run()
    lag = 3
    for t in range(lag, len(trace)):
        window = [cs for cs, _ in trace[t - lag:t + 1]]
        if all(window):                      # CS high for the last `lag` clocks
            assert trace[t][1] == 0, t
    assert sampled_oe and all(sampled_oe)
    assert sum(oe for _, oe in trace) > 0 and trace[-1] == (1, 0)
