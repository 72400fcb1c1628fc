"""SPI slave for the MCU link: a byte layer (:class:`SPIByteSlave`) and the command layer on top
(:class:`SPISlave`), both in the ``sync`` domain.

SPI mode 0 (CPOL = 0, CPHA = 0), MSB first, CS active low; SCK, MOSI and CS_N pass through
2-flop synchronizers, so the system clock must be at least 4x SCK plus the I/O margin
(:func:`max_sck_hz`; SCK high and low each >= 2 clocks, CS_N setup >= 4, hold >= 2, high >= 3
clocks).  ``miso_oe`` is high only while CS is low (the board tri-states MISO otherwise).
One command per transaction: byte 0 is the opcode (``OP_WRITE_REG``, ``OP_READ_STATUS``,
``OP_READ_STREAM``, ``OP_READ_REG``, ``OP_READ_ID``, ``OP_SOFT_RESET``, ``OP_FLUSH``), every
read has one turnaround byte, MISO carries ``FILLER`` where no reply byte is defined.  The
status reply ends with its CRC-8 (``contract.crc8``) of the captured word.
``READ_REG`` shows its address on ``reg_addr`` from the clock after the address byte until
CS rises and sends ``reg_rdata`` (the register bank's word at that address; it may lag
``reg_addr`` by up to 8 clocks) from byte 3 on.  ``soft_reset`` and ``flush`` pulse for one
clock when a keyed command's key byte (``contract.command_key``) completes.  ``errors``
(unknown opcode or register, value too wide, aborted write, wrong or missing key) and
``underruns`` saturate and restart at each status read.  Protocol table, byte layer and
timing derivation: ``docs/sensors_and_link.md`` (SPI slave).
"""

from amaranth import Cat, Const, Module, Mux, Signal
from amaranth.lib import stream, wiring
from amaranth.lib.cdc import FFSynchronizer
from amaranth.lib.wiring import In, Out

from lodestar import contract as C

MISO_TCO_NS = 6.0
"""Estimate, not measured: MISO's clock-to-pin from the I/O element's output register
(``FAST_OUTPUT_REGISTER``, clock insertion included) on a slow Cyclone IV corner.  The board
SDC bounds it (``set_max_delay`` to the MISO pin), so the Timing Analyzer checks it."""
MISO_BOARD_NS = 1.0
"""Estimate: MISO's trace from the FPGA to the MCU."""
MISO_OUT_NS = MISO_TCO_NS + MISO_BOARD_NS + C.MCU_MISO_SETUP_NS
"""``t_out`` of the slave's rule: the FPGA's clock-to-pin, the board and the master's MISO
setup tsu(MI) (``contract.MCU_MISO_SETUP_NS``): 12 ns."""


def max_sck_hz(sync_hz, t_out_ns=MISO_OUT_NS):
    """Highest SCK the slave's own rule allows: ``T_sck >= 4 T + t_out`` (an SCK edge is acted
    on 2 to 4 ``T`` after it happens, then MISO must settle before the master's next rising
    edge; ``docs/sensors_and_link.md``).  100 MHz: 19.2 MHz; 50 MHz: 10.9 MHz."""
    return 1e9 / (4e9 / sync_hz + t_out_ns)


SPI_PINS = {"sck": In(1), "mosi": In(1), "cs_n": In(1, init=1), "miso": Out(1),
            "miso_oe": Out(1)}
"""The SPI pins of a slave's signature: clock, data in, chip select (idle high), data out
and its output enable."""


class SPIByteSlave(wiring.Component):
    """SPI mode 0 byte layer: pins (asynchronous) in, ``rx``/``tx`` byte streams, ``selected``
    (synchronized CS) and ``underrun`` pulses in ``sync``.  See ``docs/sensors_and_link.md``."""

    def __init__(self):
        super().__init__({
            **SPI_PINS,
            "rx": Out(stream.Signature(8, always_ready=True)),
            "tx": In(stream.Signature(8)),
            "selected": Out(1),
            "underrun": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        sck = Signal()
        mosi = Signal()
        cs_n = Signal(init=1)
        m.submodules.sck_cdc = FFSynchronizer(self.sck, sck)
        m.submodules.mosi_cdc = FFSynchronizer(self.mosi, mosi)
        m.submodules.cs_cdc = FFSynchronizer(self.cs_n, cs_n, init=1)
        sck_prev = Signal()
        sel_prev = Signal()
        sel = ~cs_n
        m.d.sync += [sck_prev.eq(sck), sel_prev.eq(sel)]
        start = sel & ~sel_prev
        rise = sel & ~start & sck & ~sck_prev

        count = Signal(range(8))     # bits of the current byte already sampled
        rx_bits = Signal(7, reset_less=True)   # data registers: read only under count/first
        tx_bits = Signal(8, reset_less=True)
        first = Signal()             # the next rising edge is the byte's first
        peeked = Signal()            # tx_bits came from the tx stream (not C.FILLER)
        last = rise & (count == 7)
        m.d.comb += [
            self.selected.eq(sel),
            self.miso.eq(tx_bits[7]),
            self.miso_oe.eq(sel),
            self.rx.valid.eq(last),
            self.rx.payload.eq(Cat(mosi, rx_bits)),
            self.tx.ready.eq(rise & first & peeked),
            self.underrun.eq(rise & first & ~peeked),
        ]
        with m.If(rise):
            m.d.sync += [rx_bits.eq(Cat(mosi, rx_bits[:6])), count.eq(count + 1),
                         tx_bits.eq(tx_bits << 1), first.eq(0)]
        with m.If(start | last):
            m.d.sync += [tx_bits.eq(Mux(self.tx.valid, self.tx.payload, C.FILLER)),
                         peeked.eq(self.tx.valid), first.eq(1), count.eq(0)]
        with m.If(~sel):
            m.d.sync += count.eq(0)
        return m


def crc8_matrix():
    """``(columns, constant)`` of the status CRC as an affine map of the data word: the CRC of
    a ``STATUS_DATA_BITS``-bit word ``w`` is ``constant`` XOR the ``columns[i]`` of every set
    bit ``i`` of ``w`` (CRC-8 is linear in the data for a fixed initial value)."""
    n = C.STATUS_DATA_BYTES
    constant = C.crc8(bytes(n))
    columns = [C.crc8((1 << i).to_bytes(n, "big")) ^ constant for i in range(8 * n)]
    return columns, constant


def crc8_of(word):
    """Amaranth expression: the CRC-8 of the ``STATUS_DATA_BITS``-bit value ``word``."""
    columns, constant = crc8_matrix()
    bits = []
    for b in range(8):
        taps = [word[i] for i in range(len(columns)) if (columns[i] >> b) & 1]
        bit = Const((constant >> b) & 1, 1)
        for t in taps:
            bit = bit ^ t
        bits.append(bit)
    return Cat(*bits)


class SPISlave(wiring.Component):
    """SPI command slave: pins, the register write and read ports, the status inputs, the
    ``soft_reset`` and ``flush`` strobes and the packet byte stream; ``build`` (0 .. 255) is
    the ID word's build byte.  Protocol and timing requirements: ``docs/sensors_and_link.md``.

    ``soft_reset``: the top level returns the detector datapath (front end, detector,
    packetizer) to its power-up state and keeps the register bank; ``flush``: it drops every
    packet byte queued for the MCU, so the next ``READ_STREAM`` starts at the next packet's
    magic.  The reset acts within a few clocks, before the master's next transaction can
    start; the flush drains for up to ``GatewareTop.flush_clocks()`` with ``irq`` low and
    the stream closed to ``READ_STREAM`` (:class:`lodestar.hdl.boards.GatewareTop`)."""

    def __init__(self, build=0):
        self.build = build
        super().__init__({
            **SPI_PINS,
            "reg_addr": Out(C.REG_ADDR_BITS),
            "reg_data": Out(C.REGISTER_WORD_BITS),
            "reg_strobe": Out(1),
            "reg_rdata": In(C.REGISTER_WORD_BITS),
            "busy": In(1),
            "overflow": In(C.OVERFLOW_BITS),
            "frame_counter": In(C.FRAME_COUNTER_BITS),
            "trained": In(1),
            "eye_width": In(C.EYE_WIDTH_BITS),
            "status_read": Out(1),
            "soft_reset": Out(1),
            "flush": Out(1),
            "packet": In(stream.Signature(8)),
        })

    def elaborate(self, platform):
        m = Module()
        m.submodules.byte = byte = SPIByteSlave()
        m.d.comb += [byte.sck.eq(self.sck), byte.mosi.eq(self.mosi), byte.cs_n.eq(self.cs_n),
                     self.miso.eq(byte.miso), self.miso_oe.eq(byte.miso_oe)]
        tr = _transaction(m, byte)
        errors = Signal(C.LINK_COUNT_BITS)
        underruns = Signal(C.LINK_COUNT_BITS)
        snapshot, reply = self._status(m, tr, errors, underruns)

        def count(counter, event):
            base = Mux(snapshot, 0, counter)
            full = base == (1 << C.LINK_COUNT_BITS) - 1
            m.d.sync += counter.eq(Mux(event & ~full, base + 1, base))

        # the cycle's link-error event (a wide decode of the byte) is registered before its
        # count: an error comes 8 SCK periods or a deselect before the next READ_STATUS
        # opening, so the snapshot still counts it
        error = Signal(name="link_error")
        m.d.sync += error.eq(self._commands(m, byte, tr))
        count(errors, error)
        count(underruns, byte.underrun)
        self._replies(m, byte.tx, tr, reply)
        return m

    def _status(self, m, tr, errors, underruns):
        """The status word captured at a ``READ_STATUS`` opcode: ``(snapshot, reply)``, the
        capture strobe (it also clears the counts) and the word with its CRC-8."""
        status = Signal(C.STATUS_DATA_BITS, reset_less=True)
        snapshot = tr.opening & (tr.rx.payload == C.OP_READ_STATUS)
        fields = {"frame_counter": self.frame_counter, "errors": errors,
                  "underruns": underruns, "overflow": self.overflow, "busy": self.busy,
                  "trained": self.trained, "eye_width": self.eye_width}
        live = Cat(*[fields[name] for name, _ in reversed(C.STATUS_FIELDS)])
        m.d.comb += self.status_read.eq(snapshot)
        with m.If(snapshot):
            m.d.sync += status.eq(live)
        # the reply: the captured word and its CRC-8 (an XOR tree of the captured bits)
        reply = Signal(C.STATUS_BITS)
        m.d.comb += reply.eq(Cat(crc8_of(status), status))
        return snapshot, reply

    def _commands(self, m, byte, tr):
        """Register writes and the keyed strobes; returns the link-error event of this
        cycle (unknown opcode or address, aborted write, bad or missing key)."""
        rx, index, is_ = tr.rx, tr.index, tr.flags
        # ``value`` shifts in every byte after the address; after the 6th byte of a write it
        # is the register word, and the write port shows it with ``address`` while
        # ``reg_strobe`` is high (the next byte, if any, comes 8 SCK periods later).
        known = Const(0, 1)
        for r in C.REGISTERS:
            fits = 1 if r.bits >= C.REGISTER_WORD_BITS else tr.word[r.bits:] == 0
            known = known | ((tr.address == r.address) & fits)
        write = is_[C.OP_WRITE_REG]
        write_done = rx.valid & write & (index == C.WRITE_REG_BYTES - 1)
        unknown_op = tr.opening & ~Cat(*[rx.payload == op for op in C.OPCODES]).any()
        aborted = ~byte.selected & write & (index < C.WRITE_REG_BYTES)
        # keyed commands: the key is byte 1
        key_byte = rx.valid & (index == C.KEYED_BYTES - 1)
        keyed = {C.OP_SOFT_RESET: self.soft_reset, C.OP_FLUSH: self.flush}
        bad_key = Const(0, 1)
        key_missing = Const(0, 1)
        for op, strobe in keyed.items():
            flag = is_[op]
            m.d.sync += strobe.eq(key_byte & flag & (rx.payload == C.command_key(op)))
            bad_key = bad_key | (key_byte & flag & (rx.payload != C.command_key(op)))
            key_missing = key_missing | (~byte.selected & flag & (index < C.KEYED_BYTES))
        readable = Const(0, 1)
        for r in C.REGISTERS:
            readable = readable | (rx.payload == r.address)
        bad_read = rx.valid & is_[C.OP_READ_REG] & (index == C.ADDRESS_BYTES) & ~readable
        m.d.comb += [self.reg_addr.eq(tr.address), self.reg_data.eq(tr.value)]
        m.d.sync += self.reg_strobe.eq(write_done & known)
        return unknown_op | (write_done & ~known) | aborted | bad_key | key_missing | bad_read

    def _replies(self, m, tx, tr, reply):
        """The MISO bytes: packet bytes under ``READ_STREAM``, the status, register or ID
        reply bytes at their places, else the filler.  The byte being loaded at a boundary is
        number index + 1; a reply byte loaded with index == first - 1 + k is reply byte k,
        and has index == first + k when the master clocks its first bit (that is when a
        packet byte is consumed)."""
        first_reply = 1 + C.TURNAROUND_BYTES
        ident = C.gateware_id(self.build)
        replies = [
            (C.OP_READ_STATUS, first_reply, C.STATUS_BYTES, lambda k: reply.word_select(
                C.STATUS_BYTES - 1 - k, 8)),
            (C.OP_READ_REG, C.READ_REG_FIRST_REPLY, C.VALUE_BYTES,
             lambda k: self.reg_rdata.word_select(C.VALUE_BYTES - 1 - k, 8)),
            (C.OP_READ_ID, C.ID_FIRST_REPLY, C.ID_BYTES, lambda k: Const(
                (ident >> (8 * (C.ID_BYTES - 1 - k))) & 0xFF, 8)),
        ]
        with m.If(tr.flags[C.OP_READ_STREAM] & (tr.index >= first_reply - 1)):
            m.d.comb += [tx.valid.eq(self.packet.valid), tx.payload.eq(self.packet.payload),
                         self.packet.ready.eq(tx.ready & (tr.index >= first_reply))]
        with m.Else():
            m.d.comb += [tx.valid.eq(1), tx.payload.eq(C.FILLER)]
            for op, first, n, byte_k in replies:
                with m.If(tr.flags[op]):
                    with m.Switch(tr.index):
                        for k in range(n):
                            with m.Case(first - 1 + k):
                                m.d.comb += tx.payload.eq(byte_k(k))


_FLAG_NAMES = {C.OP_WRITE_REG: "write", C.OP_READ_STATUS: "status", C.OP_READ_STREAM: "stream",
               C.OP_READ_REG: "read", C.OP_READ_ID: "id", C.OP_SOFT_RESET: "reset",
               C.OP_FLUSH: "flush"}
"""The decoded-opcode flags' signal names (``is_<name>``), for waveforms and proofs."""
if set(_FLAG_NAMES) != set(C.OPCODES):
    raise ValueError("every opcode of the contract needs a flag name")


class _Transaction:
    """One chip-select's decoded state: ``rx`` (the byte stream in), ``index`` (bytes
    received, saturating past the longest fixed-length reply), ``flags`` (opcode -> its
    decoded flag; all 0: none yet, or unknown), ``opening`` (the opcode byte is arriving),
    ``address`` and ``value`` (shifted in after the opcode; without reset, meaningful only
    under the flags and counts) and ``word`` (``value`` with the arriving byte)."""

    def __init__(self, rx, index, flags, address, value):
        self.rx, self.index, self.flags = rx, index, flags
        self.address, self.value = address, value
        self.opening = rx.valid & (index == 0)
        self.word = Cat(rx.payload, value[:C.REGISTER_WORD_BITS - 8])


def _transaction(m, byte):
    """The :class:`_Transaction` of ``byte``'s stream, with its updates."""
    rx = byte.rx
    index_max = max(C.WRITE_REG_BYTES, 1 + C.TURNAROUND_BYTES + C.STATUS_BYTES,
                    C.READ_REG_BYTES, C.ID_FIRST_REPLY + C.ID_BYTES, C.KEYED_BYTES)
    tr = _Transaction(rx, Signal(range(index_max + 1), name="index"),
                      {op: Signal(name="is_" + name) for op, name in _FLAG_NAMES.items()},
                      Signal(8 * C.ADDRESS_BYTES, reset_less=True, name="address"),
                      Signal(C.REGISTER_WORD_BITS, reset_less=True, name="value"))
    with m.If(rx.valid):
        m.d.sync += tr.index.eq(Mux(tr.index == index_max, tr.index, tr.index + 1))
        with m.If(tr.index == 0):
            m.d.sync += [flag.eq(rx.payload == op) for op, flag in tr.flags.items()]
        with m.Elif(tr.index <= C.ADDRESS_BYTES):
            m.d.sync += tr.address.eq(Cat(rx.payload, tr.address[:-8]))
        with m.Else():
            m.d.sync += tr.value.eq(tr.word)
    with m.If(~byte.selected):
        m.d.sync += [tr.index.eq(0)] + [flag.eq(0) for flag in tr.flags.values()]
    return tr
