"""Packetizer: a frame's trailer and records out as the contract's packet bytes.

Input: the detector's ``records`` and ``trailer`` streams (a frame's records are the
``n_records`` before its trailer).  Output: ``packet``, a valid/ready byte stream
(``lib.stream``) for the SPI slave's ``READ_STREAM``, byte-exact with
``lodestar.ground.codec.encode`` (layout and CRC: ``docs/contract.md``).  At most one byte per
clock, from a register (no path from the record buffer's memory or the CRC reaches the
reader); ``valid`` falls for one clock before each record (it is copied from the record
stream and taken) and one before the CRC (the last byte is folded into it), which the SPI
reader never sees; ``busy`` is high from the trailer's acceptance until the CRC's last byte
is taken (``docs/gateware.md``, Packetizer).
"""

from amaranth import Cat, Const, Module, Signal, Value
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from lodestar import contract as C

from .layouts import TRAILER_NAMES, record_fields, record_layout, trailer_layout

BUILD_FIELDS = ("magic", "version", "width", "height", "pixel_bits")
"""Header fields that are constants of the build (the others come from the trailer)."""


def crc32_byte(crc, byte):
    """Amaranth expression: the CRC-32 register ``crc`` after the byte ``byte`` (reflected,
    LSB first: the same step as ``zlib.crc32``'s inner loop)."""
    bits = [crc[i] for i in range(C.CRC_BITS)]
    for k in range(8):
        feedback = bits[0] ^ byte[k]
        bits = bits[1:] + [Const(0, 1)]
        bits = [b ^ feedback if (C.CRC_POLY >> i) & 1 else b for i, b in enumerate(bits)]
    return Cat(*bits)


def _msb_first(parts):
    """``Cat`` of ``(value, bits)`` pairs with the first pair in the most significant bits,
    each value zero-extended to ``bits``."""
    out = []
    for value, bits in reversed(parts):
        if len(value) > bits:
            raise ValueError(f"a {len(value)}-bit value does not fit its {bits}-bit field")
        out.append(value)
        if len(value) < bits:
            out.append(Const(0, bits - len(value)))
    return Cat(*out)


class Packetizer(wiring.Component):
    """Trailer + records of ``width x height x pixel_bits`` frames in, packet bytes out."""

    def __init__(self, width, height, pixel_bits):
        missing = set(C.HEADER_NAMES) - set(TRAILER_NAMES) - set(BUILD_FIELDS)
        if missing:
            raise ValueError(f"header fields {sorted(missing)} come neither from the trailer "
                             f"nor from the build")
        self.width, self.height, self.pixel_bits = width, height, pixel_bits
        self.constants = {"magic": C.PACKET_MAGIC, "version": C.PACKET_VERSION,
                          "width": width, "height": height, "pixel_bits": pixel_bits}
        header = dict(C.HEADER_FIELDS)
        for name, value in self.constants.items():
            if value >> header[name]:
                raise ValueError(f"{name}={value} does not fit the {header[name]}-bit header "
                                 f"field")
        super().__init__({
            "records": In(stream.Signature(record_layout(width, height, pixel_bits))),
            "trailer": In(stream.Signature(trailer_layout())),
            "packet": Out(stream.Signature(8)),
            "busy": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        # the trailer of the packet being sent (the header's source); its ``n_records``
        # counts the records not yet copied once the header is out
        tr = Signal(trailer_layout(), reset_less=True)
        crc = Signal(C.CRC_BITS, reset_less=True)           # loaded with C.CRC_INIT per packet
        rec = Signal(record_layout(self.width, self.height, self.pixel_bits), reset_less=True)

        values = dict(self.constants)
        values.update({name: Value.cast(tr[name]) for name in TRAILER_NAMES})
        header = _msb_first([(Const(values[n], b) if isinstance(values[n], int) else values[n],
                              b) for n, b in C.HEADER_FIELDS])
        compact = dict(record_fields(self.width, self.height, self.pixel_bits))
        record = _msb_first([(Value.cast(rec[n]) if n in compact else Const(0, b), b)
                             for n, b in C.RECORD_FIELDS])
        sections = [header, record, crc ^ C.CRC_INIT]
        # every byte of the packet's sections in sending order; ``pos`` is the next byte
        in_order = Cat(*[v.word_select(len(v) // 8 - 1 - k, 8)
                         for v in sections for k in range(len(v) // 8)])
        first_record = C.HEADER_BYTES
        first_crc = first_record + C.RECORD_BYTES
        end = first_crc + C.CRC_BYTES
        pos = Signal(range(end), reset_less=True)

        # the output register: ``load`` puts byte ``pos`` into it when it is empty or taken;
        # a header or record byte is folded into the CRC in the clock after its load, from
        # the register
        out = self.packet
        load = Signal()
        fold = Signal()
        with m.If(out.valid & out.ready):
            m.d.sync += out.valid.eq(0)
        with m.If(load):
            m.d.sync += [out.payload.eq(in_order.word_select(pos, 8)), out.valid.eq(1),
                         pos.eq(pos + 1)]
        with m.If(fold):
            m.d.sync += crc.eq(crc32_byte(crc, out.payload))
        room = ~out.valid | out.ready
        self._sequence(m, tr, rec, crc, pos, (load, fold, room), (first_record, first_crc, end))
        return m

    def _sequence(self, m, tr, rec, crc, pos, strobes, marks):
        """The header, then each record (copied from the record stream, which is taken in
        that clock), one clock to fold the last byte, then the CRC."""
        first_record, first_crc, end = marks
        load, fold, room = strobes
        busy = Signal()
        m.d.comb += self.busy.eq(busy | self.packet.valid)
        with m.FSM():
            with m.State("IDLE"):
                m.d.comb += self.trailer.ready.eq(1)
                with m.If(self.trailer.valid):
                    m.d.sync += [tr.eq(self.trailer.payload), pos.eq(0), crc.eq(C.CRC_INIT)]
                    m.next = "BODY"
            with m.State("BODY"):              # header and record bytes: into the CRC
                m.d.comb += [load.eq(room), busy.eq(1)]
                m.d.sync += fold.eq(room)
                with m.If(room & ((pos == first_record - 1) | (pos == first_crc - 1))):
                    with m.If(tr.n_records == 0):
                        m.d.sync += pos.eq(first_crc)
                        m.next = "SEAL"
                    with m.Else():
                        m.d.sync += pos.eq(first_record)
                        m.next = "FETCH"
            with m.State("FETCH"):             # the next record: copied and taken
                m.d.comb += [self.records.ready.eq(1), busy.eq(1)]
                m.d.sync += fold.eq(0)
                with m.If(self.records.valid):
                    m.d.sync += [rec.eq(self.records.payload),
                                 tr.n_records.eq(tr.n_records - 1)]
                    m.next = "BODY"
            with m.State("SEAL"):              # the last byte is folded into the CRC now
                m.d.comb += busy.eq(1)
                m.d.sync += fold.eq(0)
                m.next = "CRC"
            with m.State("CRC"):
                m.d.comb += [load.eq(room), busy.eq(1)]
                with m.If(room & (pos == end - 1)):
                    m.next = "IDLE"
