"""Formal: the SPI command layer (``hdl.spi_slave.SPISlave``) writes registers and reads the
packet stream only as the protocol says, for any pin activity.

SCK, MOSI and CS_N are free inputs (no timing assumed) and reset may rise on any clock.  An
observer collects the bytes of each transaction from the byte layer (``rx``, ``selected``);
k-induction proves (``docs/formal.md``):

* a register write strobes exactly when a transaction's 6th byte completes a WRITE_REG of
  a known register with a value that fits, one clock later, with the address and value of
  those bytes (so at most one strobe per transaction: the observer's byte count only
  grows until CS_N rises);
* ``packet.ready`` (a packet byte consumed) only in a READ_STREAM transaction, from its
  first reply byte on.

Mutations (BMC finds their counterexample, so the properties are not vacuous): a slave that
consumes packet bytes during the turnaround byte (24 clocks), and one that shows a wrong
address (100 clocks, the length of a write: opt-in, ``--runslow``).
"""

import pytest
from amaranth import Const, Elaboratable, Module, Mux, Signal
from amaranth.hdl import Assert

from lodestar import contract as C
from lodestar.hdl.spi_slave import SPISlave

from .sby import available, internals, prove, submodule, unnamed

pytestmark = pytest.mark.skipif(not available(), reason="yowasp-sby or yices-smt2 missing")

FIRST_REPLY = 1 + C.TURNAROUND_BYTES           # byte number of the first reply byte
ADDR_BITS = 8 * C.ADDRESS_BYTES


def known(address, value):
    """The register at ``address`` exists and ``value`` fits it."""
    ok = Const(0, 1)
    for r in C.REGISTERS:
        fits = 1 if r.bits >= C.REGISTER_WORD_BITS else value[r.bits:] == 0
        ok = ok | ((address == r.address) & fits)
    return ok


class CheckedSPI(Elaboratable):
    def __init__(self, spi):
        self.spi = spi

    def elaborate(self, platform):
        m = Module()
        spi = self.spi
        m.submodules.spi = unit = spi.elaborate(platform)
        byte = submodule(unit, "byte")
        rx, sel = byte.rx, byte.selected

        # ---- observer: this transaction's bytes --------------------------------------
        count = Signal(4)                               # bytes received, saturating at 15
        count_max = 15
        opcode = Signal(8)
        address = Signal(ADDR_BITS)
        value = Signal(C.REGISTER_WORD_BITS)            # the last 4 bytes after the address
        value_now = Signal(C.REGISTER_WORD_BITS)
        m.d.comb += value_now.eq((value << 8) | rx.payload)
        expect = Signal()                               # a write completed in the last clock
        with m.If(rx.valid):
            m.d.sync += count.eq(Mux(count == count_max, count, count + 1))
            with m.If(count == 0):
                m.d.sync += opcode.eq(rx.payload)
            with m.Elif(count <= C.ADDRESS_BYTES):
                m.d.sync += address.eq((address << 8) | rx.payload)
            with m.Else():
                m.d.sync += value.eq(value_now)
        with m.If(~sel):
            m.d.sync += [count.eq(0), opcode.eq(0)]
        m.d.sync += expect.eq(rx.valid & (count == C.WRITE_REG_BYTES - 1)
                              & (opcode == C.OP_WRITE_REG) & known(address, value_now))

        # ---- the properties ---------------------------------------------------------
        m.d.comb += [
            Assert(spi.reg_strobe == expect),
            Assert(~spi.reg_strobe | ((spi.reg_addr == address) & (spi.reg_data == value))),
            Assert(~spi.packet.ready | ((opcode == C.OP_READ_STREAM) & (count >= FIRST_REPLY)
                                        & sel)),
        ]
        # ---- helper invariants on the slave's state, for the induction ----------------
        st = internals(unit)
        # ``is_write, is_status, is_stream = Signal(), Signal(), Signal()``: only the last
        # has a name; the others are the first unnamed signals the slave assigns
        st["is_write"], st["is_status"] = unnamed(unit)[:2]
        index = st["index"]
        active = count != 0
        m.d.comb += [
            # the slave's byte index saturates past the write's last byte, at most at the
            # longest fixed-length transaction
            Assert((index == count) | ((count > index) & (index >= C.WRITE_REG_BYTES))),
            Assert(index <= max(C.WRITE_REG_BYTES, FIRST_REPLY + C.STATUS_BYTES)),
            Assert(st["is_write"] == (active & (opcode == C.OP_WRITE_REG))),
            Assert(st["is_status"] == (active & (opcode == C.OP_READ_STATUS))),
            Assert(st["is_stream"] == (active & (opcode == C.OP_READ_STREAM))),
            Assert((count <= C.ADDRESS_BYTES) | (st["address"][:ADDR_BITS] == address)),
            *[Assert((count < C.ADDRESS_BYTES + 1 + k)
                     | (st["value"][:8 * k] == value[:8 * k]))
              for k in range(1, C.REGISTER_WORD_BITS // 8 + 1)],
            Assert(~expect | (count == C.WRITE_REG_BYTES)),
        ]
        return m


class WrongAddressSPI(SPISlave):
    """Mutant: the write port shows the address with its low bit flipped."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        m.d.comb += self.reg_addr.eq(internals(m)["address"] ^ 1)
        return m


class EarlyStreamSPI(SPISlave):
    """Mutant: packet bytes are consumed from the turnaround byte on."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        st = internals(m)
        tx = submodule(m, "byte").tx
        with m.If(st["is_stream"] & (st["index"] >= FIRST_REPLY - 1)):
            m.d.comb += self.packet.ready.eq(tx.ready)
        return m


def inputs(spi):
    return [spi.sck, spi.mosi, spi.cs_n, spi.busy, spi.overflow, spi.frame_counter,
            spi.packet.valid, spi.packet.payload]


DEPTH = 12


def test_command_layer(tmp_path):
    spi = SPISlave()
    result = prove(CheckedSPI(spi), "prove", DEPTH, tmp_path, ports=inputs(spi))
    assert result.passed, result.log


def test_stream_mutant_fails(tmp_path):
    spi = EarlyStreamSPI()
    result = prove(CheckedSPI(spi), "bmc", 24, tmp_path, ports=inputs(spi))
    assert result.failed, result.log


@pytest.mark.slow
def test_write_mutant_fails(tmp_path):
    """A write needs 6 bytes of 8 SCK periods of at least 2 clocks: BMC to 100 clocks
    (30-90 s)."""
    spi = WrongAddressSPI()
    result = prove(CheckedSPI(spi), "bmc", 100, tmp_path, ports=inputs(spi))
    assert result.failed, result.log
