"""Formal: the packetizer's bytes are the codec's for one record.

The packetizer is fed one trailer (``n_records`` assumed 1) and one record, both free
values, offered from the first clock after reset, and read by a reader that takes every
byte at once.  The expected bytes are not restated here but read off
``lodestar.ground.codec.encode``: the body (header and record) is a fixed placement of the
field bits, so encoding the all-zero frame and each frame with one field bit set gives every
body bit as a constant or one field bit (checked: each field bit moves exactly one body bit).
BMC proves:

* **bytes**: the ``k``-th byte the reader takes is the codec's byte ``k`` of the trailer
  and record the packetizer took, for the 40 header bytes (default run, depth
  ``HEADER_DEPTH``) and the 48 record bytes too (``--runslow``, depth ``PACKET_DEPTH``);
* **length**: at most ``packet_bytes(1)`` bytes are taken, and once the trailer is taken
  ``busy`` falls only after all of them are (``--runslow``);
* **CRC** (k-induction, ``CheckedCrc``): the 4 CRC bytes taken are ``zlib.crc32`` of the
  body bytes taken, big-endian, folded by an observer with ``crc32_byte`` (zlib's step on
  every input: ``tests/hdl/test_packetizer.py``).  A BMC of the 88-byte fold against an
  affine formula gets no answer from yices in 10 minutes; with a helper tying the
  packetizer's ``crc`` to the observer's the induction step is one local fold (9 s).

Mutants (the real packetizer elaborated under a contract table with one change, so that they
stay valid however the packetizer is pipelined): two 8-bit header fields swapped
(``pixel_bits`` and ``flags``: a swapped byte; default run), a record field one bit wider and
its neighbour one narrower (``xmin``/``xmax``: an off-by-one field; ``--runslow``), a CRC
polynomial with one more bit (``--runslow``).
"""

from unittest import mock

import pytest
from amaranth import Cat, Const, Elaboratable, Module, ResetSignal, Signal, Value
from amaranth.hdl import Assert, Assume
from amaranth.lib import data

from lodestar import contract as C
from lodestar.contract import BlobRecord, DetectionResult
from lodestar.ground import codec
from lodestar.hdl.layouts import TRAILER_NAMES, record_fields, trailer_fields, trailer_layout
from lodestar.hdl.packetizer import Packetizer, crc32_byte

from .sby import available, elaborate, fsm_states, internals, prove

pytestmark = pytest.mark.skipif(not available(), reason="yowasp-sby or yices-smt2 missing")

GEOMETRY = (4, 4, 8)
"""The proof's frame size: the compact record's widths (243 bits) are its; the header and
the packet's record are the contract's whatever the frame."""

PACKET_BYTES = C.packet_bytes(1)
BODY_BYTES = PACKET_BYTES - C.CRC_BYTES


def _encode(geometry, trailer, record):
    """The body (header and record, an int, big-endian) of ``codec.encode`` of one record;
    ``trailer`` and ``record`` map field names to ints (missing: 0)."""
    width, height, pixel_bits = geometry
    blob = BlobRecord(**{name: record.get(name, 0) for name in C.RECORD_NAMES})
    frame = {name: trailer.get(name, 0) for name in TRAILER_NAMES if name != "n_records"}
    packet = codec.encode(DetectionResult(blobs=[blob], width=width, height=height,
                                          pixel_bits=pixel_bits, **frame))
    return int.from_bytes(packet[:BODY_BYTES], "big")


def codec_body(geometry):
    """The codec's body of one record as a placement of the field bits: ``(base, places)``,
    ``base`` the body (an int, big-endian) of all-zero fields and ``places[(section, name,
    bit)]`` the body bit that field bit sets."""
    sections = {"trailer": [f for f in trailer_fields() if f[0] != "n_records"],
                "record": record_fields(*geometry)}
    base = _encode(geometry, {}, {})
    places = {}
    for section, fields in sections.items():
        for name, bits in fields:
            for bit in range(bits):
                values = {"trailer": {}, "record": {}, section: {name: 1 << bit}}
                flips = base ^ _encode(geometry, values["trailer"], values["record"])
                if flips & (flips - 1) or not flips:
                    raise AssertionError(f"{section}.{name}[{bit}] is not one body bit")
                places[(section, name, bit)] = flips.bit_length() - 1
    return base, places


def expected_body(geometry, trailer, record):
    """The codec's body bytes (first byte first) as Amaranth expressions of the ``trailer``
    and ``record`` views."""
    base, places = codec_body(geometry)
    views = {"trailer": trailer, "record": record}
    bits = [Const(base >> q & 1, 1) for q in range(8 * BODY_BYTES)]
    for (section, name, bit), q in places.items():
        bits[q] = Value.cast(views[section][name])[bit]
    return [Cat(*bits[8 * (BODY_BYTES - 1 - k):8 * (BODY_BYTES - k)])
            for k in range(BODY_BYTES)]


class CheckedPacketizer(Elaboratable):
    """``unit`` (a ``Packetizer`` or a mutant) fed one trailer and one record, its bytes
    checked against the codec's."""

    def __init__(self, unit):
        self.unit = unit

    def elaborate(self, platform):
        m = Module()
        unit = self.unit
        m.submodules.unit = elaborate(unit, platform)

        # the environment: reset only at power-up, the trailer offered until taken (once),
        # the record always offered, a reader that takes every byte at once
        got_trailer = Signal()
        m.d.comb += [Assume(~ResetSignal()), Assume(unit.packet.ready),
                     Assume(unit.records.valid), Assume(unit.trailer.valid == ~got_trailer),
                     Assume(unit.trailer.payload.n_records == 1)]
        # the observer: the trailer and record taken, the bytes taken since
        trailer = Signal.like(unit.trailer.payload)
        record = Signal.like(unit.records.payload)
        count = Signal(range(PACKET_BYTES + 2))
        take = unit.packet.valid & unit.packet.ready
        with m.If(unit.trailer.valid & unit.trailer.ready):
            m.d.sync += [got_trailer.eq(1), trailer.eq(unit.trailer.payload)]
        with m.If(unit.records.valid & unit.records.ready):
            m.d.sync += record.eq(unit.records.payload)
        with m.If(take):
            m.d.sync += count.eq(count + (count <= PACKET_BYTES))

        expected = expected_body((unit.width, unit.height, unit.pixel_bits), trailer, record)
        for k, value in enumerate(expected):
            m.d.comb += Assert(~take | (count != k) | (unit.packet.payload == value))
        m.d.comb += [Assert(~take | (count < PACKET_BYTES)),
                     Assert(~got_trailer | unit.busy | (count == PACKET_BYTES))]
        return m


class CheckedCrc(Elaboratable):
    """``unit`` (a ``Packetizer`` or a mutant) in the environment of ``CheckedPacketizer``,
    its CRC bytes checked: the ``k``-th of them is byte ``k`` (big-endian) of
    ``zlib.crc32`` of the body bytes the reader took, folded by an observer register from
    ``CRC_INIT`` with ``crc32_byte`` (zlib's step on every input:
    ``tests/hdl/test_packetizer.py``).  ``helpers``: the induction's invariants on the
    unit's state (off for the mutant's BMC)."""

    def __init__(self, unit, helpers=True):
        self.unit, self.helpers = unit, helpers

    def elaborate(self, platform):
        m = Module()
        unit = self.unit
        m.submodules.unit = elaborated = elaborate(unit, platform)
        got_trailer = Signal()
        m.d.comb += [Assume(~ResetSignal()), Assume(unit.packet.ready),
                     Assume(unit.records.valid), Assume(unit.trailer.valid == ~got_trailer),
                     Assume(unit.trailer.payload.n_records == 1)]
        with m.If(unit.trailer.valid & unit.trailer.ready):
            m.d.sync += got_trailer.eq(1)
        count = Signal(range(PACKET_BYTES + 2))
        crc = Signal(C.CRC_BITS, init=C.CRC_INIT)
        take = unit.packet.valid & unit.packet.ready
        with m.If(take):
            m.d.sync += count.eq(count + (count <= PACKET_BYTES))
        with m.If(take & (count < BODY_BYTES)):
            m.d.sync += crc.eq(crc32_byte(crc, unit.packet.payload))
        sent = crc ^ C.CRC_INIT
        for j in range(C.CRC_BYTES):
            m.d.comb += Assert(~take | (count != BODY_BYTES + j) |
                               (unit.packet.payload == sent.word_select(C.CRC_BYTES - 1 - j, 8)))
        if self.helpers:
            m.d.comb += self.invariants(elaborated, got_trailer, count, crc)
        return m

    def invariants(self, elaborated, got_trailer, count, crc):
        """Before the trailer nothing is sent; after it ``count`` is the bytes loaded
        (``pos``) less the one in the output register, a byte is folded exactly when a body
        byte is taken, so the unit's CRC is the observer's, and a CRC byte in the output
        register is the unit's CRC's."""
        unit = self.unit
        s = internals(elaborated)
        _, st = fsm_states(elaborated)
        pos, fold = s["pos"], s["fold"]
        n_left = data.View(trailer_layout(), s["tr"]).n_records
        out = unit.packet
        first_record, first_crc = C.HEADER_BYTES, BODY_BYTES
        loaded = pos - out.valid                      # bytes taken before the one held
        which = (first_crc + C.CRC_BYTES - 1 - loaded).as_unsigned()[:2]   # big-endian
        crc_byte = (s["crc"] ^ C.CRC_INIT).word_select(which, 8)
        return [
            Assert(st["IDLE"] | st["BODY"] | st["FETCH"] | st["SEAL"] | st["CRC"]),
            Assert(got_trailer | (st["IDLE"] & (count == 0) & ~out.valid)),
            Assert(~got_trailer | ((count == loaded) & (pos <= PACKET_BYTES))),
            Assert(~(got_trailer & st["IDLE"]) | (pos == PACKET_BYTES)),
            Assert(fold == (got_trailer & out.valid & (loaded < first_crc))),
            Assert(~got_trailer | (s["crc"] == crc)),
            Assert(~st["BODY"] | (pos < first_crc)),
            Assert(~st["BODY"] | (n_left == (pos < first_record))),
            Assert(~st["FETCH"] | (n_left == 1)),
            Assert(~st["FETCH"] | ((pos == first_record) & out.valid)),
            Assert(~(st["SEAL"] | st["CRC"]) | (pos >= first_crc)),
            Assert(~st["SEAL"] | ((pos == first_crc) & out.valid)),
            Assert(~(got_trailer & out.valid & (loaded >= first_crc)) | (out.payload == crc_byte)),
        ]


def _swapped(fields, a, b, widen=0):
    """``fields`` (``(name, bits)`` pairs) with the fields ``a`` and ``b`` swapped, or, with
    ``widen``, ``a`` that many bits wider and ``b`` that many narrower in place."""
    out = list(fields)
    i, j = (next(k for k, f in enumerate(out) if f[0] == n) for n in (a, b))
    if widen:
        out[i], out[j] = (a, out[i][1] + widen), (b, out[j][1] - widen)
    else:
        out[i], out[j] = out[j], out[i]
    return tuple(out)


class MutantPacketizer(Packetizer):
    """Mutant: the packetizer built and elaborated under the contract table ``name`` replaced
    by ``fields`` (the packetizer reads the layout from the contract, so one wrong table row
    is one wrong field in its bytes)."""

    def __init__(self, name, fields):
        self.patch = (name, fields)
        with mock.patch.object(C, name, fields):
            super().__init__(*GEOMETRY)

    def elaborate(self, platform):
        with mock.patch.object(C, *self.patch):
            return super().elaborate(platform)


def inputs(unit):
    return [unit.trailer.valid, unit.trailer.payload.as_value(), unit.records.valid,
            unit.records.payload.as_value(), unit.packet.ready]


def run(tmp_path, unit, depth):
    return prove(CheckedPacketizer(unit), "bmc", depth, tmp_path, ports=inputs(unit))


HEADER_DEPTH = C.HEADER_BYTES + 4
"""Clocks to the last header byte's take: the trailer, the first load, one byte per clock."""
PACKET_DEPTH = PACKET_BYTES + 6
"""Clocks to the CRC's last byte and ``busy``'s fall: two clocks more per record (its fetch
and the gap before the CRC)."""


@pytest.mark.parametrize("depth", [HEADER_DEPTH,
                                   pytest.param(PACKET_DEPTH, marks=pytest.mark.slow)])
def test_bytes_equal_codec(tmp_path, depth):
    result = run(tmp_path, Packetizer(*GEOMETRY), depth)
    assert result.passed, result.log


@pytest.mark.parametrize("table, a, b, widen", [
    ("HEADER_FIELDS", "pixel_bits", "flags", 0),
    pytest.param("RECORD_FIELDS", "xmin", "xmax", 1, marks=pytest.mark.slow),
])
def test_mutant_fails(tmp_path, table, a, b, widen):
    unit = MutantPacketizer(table, _swapped(getattr(C, table), a, b, widen))
    result = run(tmp_path, unit, PACKET_DEPTH)
    assert result.failed, result.log


def test_crc_bytes_are_zlibs_of_the_body(tmp_path):
    unit = Packetizer(*GEOMETRY)
    result = prove(CheckedCrc(unit), "prove", 3, tmp_path, ports=inputs(unit))
    assert result.passed, result.log


@pytest.mark.slow
def test_crc_mutant_fails(tmp_path):
    """A packetizer whose CRC polynomial has one more bit (the contract's ``CRC_POLY``
    patched while it is built) sends other CRC bytes."""
    unit = MutantPacketizer("CRC_POLY", C.CRC_POLY ^ 0x20)
    result = prove(CheckedCrc(unit, helpers=False), "bmc", PACKET_DEPTH, tmp_path,
                   ports=inputs(unit))
    assert result.failed, result.log
