"""Formal: the SPI command layer (``hdl.spi_slave.SPISlave``) writes registers, strobes its
soft reset and flush, reads the packet stream and sends its replies only as the protocol
says, for any pin activity.

SCK, MOSI and CS_N are free inputs (no timing assumed) and reset may rise on any clock; the
register bank's read data is a fixed function of ``reg_addr`` (:func:`bank`), whose four
bytes differ for every address.  An observer collects the bytes of each transaction from
the byte layer (``rx``, ``selected``); k-induction proves (``docs/formal.md``):

* a register write strobes exactly when a transaction's 6th byte completes a WRITE_REG of
  a known register with a value that fits, one clock later, with the address and value of
  those bytes (so at most one strobe per transaction: the observer's byte count only
  grows until CS_N rises);
* ``soft_reset`` (``flush``) strobes exactly when a transaction's 2nd byte completes a
  SOFT_RESET (FLUSH) whose 2nd byte is its key, one clock later;
* ``packet.ready`` (a packet byte consumed) only in a READ_STREAM transaction, from its
  first reply byte on;
* a READ_STATUS's reply bytes are the status word captured at its opcode and the CRC-8 of
  that word (the contract's ``crc8``), in order;
* a READ_REG's reply bytes are the register bank's word at the transaction's address, big
  endian, after a FILLER turnaround; a READ_ID's are the ID word of the slave's ``build``.

Mutations (BMC finds their counterexample, so the properties are not vacuous): a slave that
consumes packet bytes during the turnaround byte (24 clocks), one that resets without
checking the key (40), one whose status CRC has another initial value (2), one that sends
the ID's first byte wrong (40), one that sends a READ_REG's value little endian (60), and
one that shows a wrong address (100 clocks, the length of a write: opt-in, ``--runslow``).
"""

import pytest
from amaranth import Cat, Const, Elaboratable, Module, Mux, ResetSignal, Signal
from amaranth.hdl import Assert, Assume

from lodestar import contract as C
from lodestar.hdl import spi_slave
from lodestar.hdl.spi_slave import SPISlave

from .sby import available, elaborate, internals, prove, submodule

pytestmark = pytest.mark.skipif(not available(), reason="yowasp-sby or yices-smt2 missing")

FIRST_REPLY = 1 + C.TURNAROUND_BYTES           # byte number of the first reply byte
ADDR_BITS = 8 * C.ADDRESS_BYTES
BUILD = 0x5C
INDEX_MAX = max(C.WRITE_REG_BYTES, FIRST_REPLY + C.STATUS_BYTES, C.READ_REG_BYTES,
                C.ID_FIRST_REPLY + C.ID_BYTES, C.KEYED_BYTES)
FLAGS = {"is_write": C.OP_WRITE_REG, "is_status": C.OP_READ_STATUS,
         "is_stream": C.OP_READ_STREAM, "is_read": C.OP_READ_REG, "is_id": C.OP_READ_ID,
         "is_reset": C.OP_SOFT_RESET, "is_flush": C.OP_FLUSH}


def known(address, value):
    """The register at ``address`` exists and ``value`` fits it."""
    ok = Const(0, 1)
    for r in C.REGISTERS:
        fits = 1 if r.bits >= C.REGISTER_WORD_BITS else value[r.bits:] == 0
        ok = ok | ((address == r.address) & fits)
    return ok


def bank(addr):
    """The register bank's word at ``addr``: four different bytes for every address."""
    a = Cat(addr, Const(0, 8 - len(addr)))
    return Cat(a ^ 0x88, a ^ 0x44, a ^ 0x22, a ^ 0x11)


def contract_crc8(word, nbits):
    """The contract's CRC-8 of the ``nbits``-bit big-endian ``word`` as an expression: CRC-8
    is affine in the data, so each CRC bit is a constant XOR the data bits whose unit word's
    CRC (``contract.crc8``) differs from the zero word's in that bit.  (Taken from the
    contract's function here, not the slave's matrix; a bit-serial LFSR would state the same
    but its equivalence with any XOR matrix is a hard SAT problem for the solver.)"""
    n = nbits // 8
    zero = C.crc8(bytes(n))
    columns = [C.crc8((1 << i).to_bytes(n, "big")) ^ zero for i in range(nbits)]
    out = []
    for b in range(8):
        bit = Const((zero >> b) & 1, 1)
        for i in range(nbits):
            if (columns[i] >> b) & 1:
                bit = bit ^ word[i]
        out.append(bit)
    return Cat(*out)


def byte_of(word, k, n):
    """Byte ``k`` (0: most significant) of the ``n``-byte ``word``."""
    return word.word_select(n - 1 - k, 8)


class CheckedSPI(Elaboratable):
    def __init__(self, spi):
        self.spi = spi

    def elaborate(self, platform):
        m = Module()
        spi = self.spi
        m.submodules.spi = unit = elaborate(spi, platform)
        byte = submodule(unit, "byte")
        rx, sel, tx = byte.rx, byte.selected, byte.tx
        m.d.comb += spi.reg_rdata.eq(bank(spi.reg_addr))

        # ---- observer: this transaction's bytes --------------------------------------
        count = Signal(4)                               # bytes received, saturating at 15
        count_max = 15
        opcode = Signal(8)
        address = Signal(ADDR_BITS)
        value = Signal(C.REGISTER_WORD_BITS)            # the last 4 bytes after the address
        value_now = Signal(C.REGISTER_WORD_BITS)
        m.d.comb += value_now.eq((value << 8) | rx.payload)
        expect = Signal()                               # a write completed in the last clock
        expect_keyed = {op: Signal(name="expect_{:02x}".format(op)) for op in C.KEYED_OPCODES}
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
        for op, sig in expect_keyed.items():
            m.d.sync += sig.eq(rx.valid & (count == C.KEYED_BYTES - 1) & (opcode == op)
                               & (rx.payload == C.command_key(op)))

        # ---- the properties ---------------------------------------------------------
        st = internals(unit)
        status = st["status"]
        reply = Cat(contract_crc8(status, C.STATUS_DATA_BITS), status)
        ident = C.gateware_id(BUILD)

        def loads(op, k):
            """The byte layer loads byte ``k + 1`` of an ``op`` transaction."""
            return rx.valid & (opcode == op) & (count == k)

        m.d.comb += [
            Assert(spi.reg_strobe == expect),
            Assert(~spi.reg_strobe | ((spi.reg_addr == address) & (spi.reg_data == value))),
            Assert(spi.soft_reset == expect_keyed[C.OP_SOFT_RESET]),
            Assert(spi.flush == expect_keyed[C.OP_FLUSH]),
            Assert(~spi.packet.ready | ((opcode == C.OP_READ_STREAM) & (count >= FIRST_REPLY)
                                        & sel)),
            Assert(st["reply"] == reply),
            *[Assert(~loads(C.OP_READ_STATUS, FIRST_REPLY - 1 + k)
                     | (tx.payload == byte_of(st["reply"], k, C.STATUS_BYTES)))
              for k in range(C.STATUS_BYTES)],
            Assert(~loads(C.OP_READ_REG, C.READ_REG_FIRST_REPLY - 2) | (tx.payload == C.FILLER)),
            *[Assert(~loads(C.OP_READ_REG, C.READ_REG_FIRST_REPLY - 1 + k)
                     | (tx.payload == byte_of(bank(address[:C.REG_ADDR_BITS]), k, 4)))
              for k in range(C.VALUE_BYTES)],
            *[Assert(~loads(C.OP_READ_ID, C.ID_FIRST_REPLY - 1 + k)
                     | (tx.payload == (ident >> (8 * (C.ID_BYTES - 1 - k))) & 0xFF))
              for k in range(C.ID_BYTES)],
        ]
        # ---- helper invariants on the slave's state, for the induction ----------------
        index = st["index"]
        active = count != 0
        m.d.comb += [
            # the slave's byte index is the observer's count, saturating past the longest
            # fixed-length transaction
            Assert(index == Mux(count > INDEX_MAX, INDEX_MAX, count)),
            *[Assert(st[flag] == (active & (opcode == op))) for flag, op in FLAGS.items()],
            Assert((count <= C.ADDRESS_BYTES) | (st["address"][:ADDR_BITS] == address)),
            *[Assert((count < C.ADDRESS_BYTES + 1 + k)
                     | (st["value"][:8 * k] == value[:8 * k]))
              for k in range(1, C.REGISTER_WORD_BITS // 8 + 1)],
            Assert(~expect | (count == C.WRITE_REG_BYTES)),
            *[Assert(~sig | (count == C.KEYED_BYTES)) for sig in expect_keyed.values()],
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


class KeylessResetSPI(SPISlave):
    """Mutant: the soft reset strobes whatever the second byte is."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        st = internals(m)
        rx = submodule(m, "byte").rx
        m.d.sync += self.soft_reset.eq(rx.valid & st["is_reset"] & (st["index"] == 1))
        return m


class WrongCRCSPI(SPISlave):
    """Mutant: the status CRC starts from another initial value (its constant term off)."""

    def elaborate(self, platform):
        real = spi_slave.crc8_matrix

        def wrong():
            columns, constant = real()
            return columns, constant ^ 0x01
        spi_slave.crc8_matrix = wrong
        try:
            return super().elaborate(platform)
        finally:
            spi_slave.crc8_matrix = real


class WrongIDSPI(SPISlave):
    """Mutant: the ID word's first byte has its low bit flipped."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        st = internals(m)
        tx = submodule(m, "byte").tx
        with m.If(st["is_id"] & (st["index"] == C.ID_FIRST_REPLY - 1)):
            m.d.comb += tx.payload.eq((C.ID_MAGIC >> 8) ^ 1)
        return m


class LittleEndianReadSPI(SPISlave):
    """Mutant: a READ_REG's value goes out least significant byte first."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        st = internals(m)
        tx = submodule(m, "byte").tx
        for k in range(C.VALUE_BYTES):
            with m.If(st["is_read"] & (st["index"] == C.READ_REG_FIRST_REPLY - 1 + k)):
                m.d.comb += tx.payload.eq(self.reg_rdata.word_select(k, 8))
        return m


def inputs(spi):
    return [spi.sck, spi.mosi, spi.cs_n, spi.busy, spi.overflow, spi.frame_counter,
            spi.packet.valid, spi.packet.payload]


DEPTH = 12


def test_command_layer(tmp_path):
    spi = SPISlave(build=BUILD)
    result = prove(CheckedSPI(spi), "prove", DEPTH, tmp_path, ports=inputs(spi))
    assert result.passed, result.log


@pytest.mark.parametrize("mutant,depth", [(EarlyStreamSPI, 24), (KeylessResetSPI, 40),
                                          (WrongCRCSPI, 4), (WrongIDSPI, 40)])
def test_mutant_fails(tmp_path, mutant, depth):
    spi = mutant(build=BUILD)
    result = prove(CheckedSPI(spi), "bmc", depth, tmp_path, ports=inputs(spi))
    assert result.failed, result.log


@pytest.mark.slow
@pytest.mark.parametrize("mutant,depth", [(WrongAddressSPI, 100), (LittleEndianReadSPI, 60)])
def test_long_mutant_fails(tmp_path, mutant, depth):
    """A write needs 6 bytes of 8 SCK periods of at least 2 clocks (BMC to 100 clocks, 30-90
    s); a read's value starts at byte 3 (60 clocks)."""
    spi = mutant(build=BUILD)
    result = prove(CheckedSPI(spi), "bmc", depth, tmp_path, ports=inputs(spi))
    assert result.failed, result.log


# ---- the byte layer at the pins ---------------------------------------------------------

class PinsSPI(Elaboratable):
    """The byte layer (``SPIByteSlave``) seen from its pins by an SPI mode 0 master that
    keeps the slave's documented timing (assumed on the free pins, one step = one ``sync``
    clock: SCK high and low at least 2 clocks, the first rising edge at least 4 clocks
    after CS_N falls, CS_N rising at least 2 clocks after the last rising edge and with SCK
    low, CS_N high at least 3 clocks).  The master samples MISO at each SCK rising edge at
    the pin and raises CS_N only between bytes.  The byte stream ``tx`` offers, whenever its
    free ``valid`` is high, the number of bytes consumed so far (mod 256) XOR 0xA5.  Asserted: each
    byte the master completes (8 rising edges in one chip-select) whose first edge consumed
    a stream byte is that byte, MSB first; a byte consumes at most one stream byte; and no
    consumed byte is left incomplete when CS_N rises, so a byte offered but not yet clocked
    when a chip-select ends is the next one sent (none dropped or repeated across CS
    edges)."""

    def __init__(self, byte):
        self.byte = byte

    def elaborate(self, platform):
        m = Module()
        m.submodules.byte = byte = self.byte
        tx = byte.tx
        sent = Signal(8)                                # stream bytes consumed
        with m.If(tx.valid & tx.ready):
            m.d.sync += sent.eq(sent + 1)
        m.d.comb += tx.payload.eq(sent ^ 0xA5)          # no byte is all zeros or ones

        # ---- the master's timing, assumed -------------------------------------------------
        sck_prev, cs_prev = Signal(), Signal(init=1)
        sck_age, cs_age, rise_age = Signal(range(8)), Signal(range(8)), Signal(range(8))
        m.d.sync += [sck_prev.eq(byte.sck), cs_prev.eq(byte.cs_n),
                     sck_age.eq(Mux(byte.sck != sck_prev, 0, Mux(sck_age == 7, 7, sck_age + 1))),
                     cs_age.eq(Mux(byte.cs_n != cs_prev, 0, Mux(cs_age == 7, 7, cs_age + 1)))]
        pin_rise = byte.sck & ~sck_prev
        with m.If(pin_rise):
            m.d.sync += rise_age.eq(0)
        with m.Elif(rise_age != 7):
            m.d.sync += rise_age.eq(rise_age + 1)
        first_edge = Signal()                           # no rising edge yet in this select
        with m.If(byte.cs_n):
            m.d.sync += first_edge.eq(1)
        with m.Elif(pin_rise):
            m.d.sync += first_edge.eq(0)
        m.d.comb += [
            Assume(~ResetSignal()),
            Assume((byte.sck == sck_prev) | (sck_age >= 1)),      # levels >= 2 clocks
            Assume(~byte.cs_n | ~cs_prev | ~byte.sck),            # SCK low at CS fall
            Assume(~pin_rise | ~first_edge | (cs_age >= 3)),     # CS setup >= 4 clocks
            Assume(byte.cs_n | ~pin_rise | ~cs_prev),
            Assume(~byte.cs_n | cs_prev | (~byte.sck & (rise_age >= 1))),   # CS hold
            Assume(~byte.cs_n | ~byte.sck),                       # SCK idles low
            Assume(byte.cs_n | ~cs_prev | (cs_age >= 2)),        # CS high >= 3 clocks
        ]

        # ---- the master's bytes against the consumed ones ---------------------------------
        bits = Signal(range(9))                         # bits of this byte sampled
        got = Signal(8)
        pending = Signal()                              # this byte's first edge consumed one
        value = Signal(8)                               # the consumed byte
        with m.If(tx.valid & tx.ready):
            m.d.sync += [pending.eq(1), value.eq(tx.payload)]
        with m.If(byte.cs_n):
            m.d.sync += [bits.eq(0), pending.eq(0)]
        with m.Elif(pin_rise):
            m.d.sync += [got.eq(Cat(byte.miso, got[:7])), bits.eq(Mux(bits == 8, 1, bits + 1))]
        complete = pin_rise & (bits == 7) & ~byte.cs_n
        with m.If(complete):
            m.d.sync += pending.eq(0)
        m.d.comb += [
            Assume(~byte.cs_n | cs_prev | (bits == 0) | (bits == 8)),   # whole bytes only
            Assert(~complete | ~pending | (Cat(byte.miso, got[:7]) == value)),
            Assert(~(tx.valid & tx.ready) | ~pending),   # one consumption per byte
            Assert(~byte.cs_n | cs_prev | ~pending),     # none left incomplete at CS rise
        ]
        return m


class LoadConsumesByteSlave(spi_slave.SPIByteSlave):
    """Mutant: a byte counts as consumed when it is loaded into the shift register, so a
    chip-select that ends before its first SCK edge drops it."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        start = self.selected & ~internals(m)["sel_prev"]
        m.d.comb += self.tx.ready.eq(start | self.rx.valid)
        return m


class ShortByteSlave(spi_slave.SPIByteSlave):
    """Mutant: MISO shows the shift register's bit 6, so every bit leaves one edge early
    (a whole byte must be clocked to see it)."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        m.d.comb += self.miso.eq(internals(m)["tx_bits"][6])
        return m


PINS_DEPTH = 44
"""BMC steps: a chip-select with one whole byte (8 SCK periods of at least 4 clocks) and a
second chip-select opening."""


def pins_inputs(byte):
    return [byte.sck, byte.mosi, byte.cs_n, byte.tx.valid]


def test_byte_layer_at_the_pins(tmp_path):
    byte = spi_slave.SPIByteSlave()
    result = prove(PinsSPI(byte), "bmc", PINS_DEPTH, tmp_path, ports=pins_inputs(byte))
    assert result.passed, result.log


@pytest.mark.parametrize("mutant", [LoadConsumesByteSlave, ShortByteSlave])
def test_byte_layer_at_the_pins_mutant_fails(tmp_path, mutant):
    byte = mutant()
    result = prove(PinsSPI(byte), "bmc", PINS_DEPTH, tmp_path, ports=pins_inputs(byte))
    assert result.failed, result.log
