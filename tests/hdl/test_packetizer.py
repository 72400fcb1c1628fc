"""The packetizer in the Amaranth simulator: bytes equal ``lodestar.ground.codec.encode`` of the
same
trailer and records (random values at every compact width, a slow reader), and the detector
followed by the packetizer produces packets that decode to the golden result."""

import zlib

import numpy as np
import pytest
from amaranth import Module, Signal
from amaranth.lib import wiring
from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.contract import DetectionResult
from lodestar.golden import DetectorConfig, detect_frame
from lodestar.ground import codec
from lodestar.hdl.detector import Detector
from lodestar.hdl.labeller import vblank_cycles
from lodestar.hdl.layouts import TRAILER_NAMES, record_fields, trailer_fields
from lodestar.hdl.packetizer import Packetizer, crc32_byte
from tests.hdl.bench import to_record
from tests.hdl.streams import stream_idle, stream_put


def pack(values, fields):
    """Integer of a struct value (first field in the low bits)."""
    out, shift = 0, 0
    for name, bits in fields:
        out |= values[name] << shift
        shift += bits
    return out


def split_packets(data):
    """Packets of a byte string holding whole packets back to back (length from the header)."""
    out = []
    while data:
        n = int.from_bytes(data[C.HEADER_BYTES - 2:C.HEADER_BYTES], "big")
        size = C.packet_bytes(n)
        out.append(bytes(data[:size]))
        data = data[size:]
    return out


def collect(sim, dut, ready):
    """Background testbench reading ``dut.packet`` with ``ready(cycle)``; returns the list."""
    got = []

    async def reader(ctx):
        cycle = 0
        while True:
            r = ready(cycle)
            ctx.set(dut.packet.ready, r)
            if r and ctx.get(dut.packet.valid):
                got.append(ctx.get(dut.packet.payload))
            await ctx.tick()
            cycle += 1
    sim.add_testbench(reader, background=True)
    return got


def test_crc_step_is_zlibs_on_every_input():
    """``crc32_byte`` is zlib's CRC-32 step for every register and byte: both are linear over
    GF(2) in the 40 bits of (register, byte) (``crc32_byte`` is XORs of input bits only;
    zlib's step without its pre- and post-inversion is the reflected CRC's shift-and-XOR), so
    equal on the 40 unit vectors they are equal on all 2**40 inputs; a 64-byte fold from
    ``CRC_INIT`` matches ``zlib.crc32`` too (the formal packetizer proof folds with it)."""
    crc, byte, nxt = Signal(32), Signal(8), Signal(32)
    m = Module()
    m.d.comb += nxt.eq(crc32_byte(crc, byte))
    sim = Simulator(m)
    rng = np.random.default_rng(1)
    data = bytes(rng.integers(0, 256, 64, dtype=np.uint8))
    inv = 0xFFFFFFFF
    basis = [(1 << i, 0) for i in range(32)] + [(0, 1 << i) for i in range(8)] + [(0, 0)]
    got, want, out = [], [zlib.crc32(bytes([b]), c ^ inv) ^ inv for c, b in basis], {}

    async def tb(ctx):
        for c, b in basis:
            ctx.set(crc, c)
            ctx.set(byte, b)
            got.append(ctx.get(nxt))
        value = C.CRC_INIT
        for b in data:
            ctx.set(crc, value)
            ctx.set(byte, b)
            value = ctx.get(nxt)
        out["crc"] = value ^ inv
    sim.add_testbench(tb)
    sim.run()
    assert got == want
    assert out["crc"] == zlib.crc32(data)


@pytest.mark.parametrize("geometry", [(5, 3, 10), (2592, 1944, 12), (4096, 4096, 16)])
def test_bytes_equal_encode(geometry):
    """Random values filling every compact field (all-ones included), frames of 0..3 records,
    a reader that stalls at random: the bytes are ``codec.encode``'s."""
    w, h, pb = geometry
    rng = np.random.default_rng(w)
    rec_f = record_fields(w, h, pb)
    tr_f = trailer_fields()
    frames = []
    for k in range(6):
        n = [0, 1, 3, 2, 0, 1][k]
        recs = []
        for _ in range(n):
            if k == 5:
                recs.append({name: (1 << bits) - 1 for name, bits in rec_f})
            else:
                recs.append({name: int(rng.integers(0, 1 << bits)) for name, bits in rec_f})
        tr = {name: int(rng.integers(0, 1 << bits)) for name, bits in tr_f}
        if k == 5:
            tr = {name: (1 << bits) - 1 for name, bits in tr_f}
        tr["n_records"] = n
        frames.append((recs, tr))
    dut = Packetizer(w, h, pb)
    sim = Simulator(dut)
    sim.add_clock(1e-6)

    records = [pack(r, rec_f) for recs, _ in frames for r in recs]
    trailers = [pack(tr, tr_f) for _, tr in frames]

    def server(port, queue):
        """Background testbench: ``port`` offers ``queue``'s items, like a FIFO's read side
        (every record is buffered before its trailer: the packetizer fetches after it)."""
        async def serve(ctx):
            while True:
                if queue:
                    await stream_put(ctx, port, queue[0])
                    queue.pop(0)
                else:
                    await stream_idle(ctx, port, 1)
        return serve

    async def wait(ctx):
        await ctx.tick().repeat(200 * (len(records) + len(trailers)))

    sim.add_testbench(server(dut.records, records), background=True)
    sim.add_testbench(server(dut.trailer, trailers), background=True)
    sim.add_testbench(wait)
    got = collect(sim, dut, lambda c: bool(rng.random() < 0.6))
    sim.run()
    expected = b""
    for recs, tr in frames:
        res = DetectionResult(blobs=[to_record(r) for r in recs], width=w, height=h,
                              pixel_bits=pb, **{n: tr[n] for n in TRAILER_NAMES
                                                if n != "n_records"})
        expected += codec.encode(res)
    assert bytes(got) == expected


class _DetectorPackets(wiring.Component):
    """Detector followed by the packetizer (what the board top level wires)."""

    def __init__(self, w, h, pb, record_capacity, record_depth):
        self.det = Detector(w, h, pb, record_capacity=record_capacity, record_depth=record_depth)
        self.pkt = Packetizer(w, h, pb)
        super().__init__({"pixels": self.det.signature.members["pixels"],
                          "packet": self.pkt.signature.members["packet"],
                          "reg_addr": wiring.In(self.det.reg_addr.shape()),
                          "reg_data": wiring.In(C.REGISTER_WORD_BITS),
                          "reg_en": wiring.In(1)})

    def elaborate(self, platform):
        m = Module()
        m.submodules.det, m.submodules.pkt = self.det, self.pkt
        wiring.connect(m, wiring.flipped(self.pixels), self.det.pixels)
        wiring.connect(m, self.det.records, self.pkt.records)
        wiring.connect(m, self.det.trailer, self.pkt.trailer)
        wiring.connect(m, self.pkt.packet, wiring.flipped(self.packet))
        m.d.comb += [self.det.reg_addr.eq(self.reg_addr), self.det.reg_data.eq(self.reg_data),
                     self.det.reg_en.eq(self.reg_en)]
        return m


def test_detector_packets_decode_to_golden():
    """Random frames (one with more blobs than the record capacity) through the detector and
    the packetizer, read by a slow reader while the next frames stream in (the record buffer
    holds every frame's records): frames 2 and 3 end while frame 1's trailer is still held
    and lose their trailers; every packet, frame 4's included, decodes (CRC and semantic
    checks) to the golden result of the frame its counter names: the lost frames' records
    shifted nothing."""
    rng = np.random.default_rng(5)
    w, h, cap = 12, 7, 6
    frames = []
    for density in (0.3, 0.0, 0.5, 0.25, 0.5):
        mask = rng.random((h, w)) < density
        frames.append(np.where(mask, rng.integers(51, 4096, (h, w)),
                               rng.integers(0, 51, (h, w))).astype(np.uint16))
    cfg = DetectorConfig(width=w, height=h, pixel_bits=12, threshold=50, background=40,
                         record_capacity=cap)
    dut = _DetectorPackets(w, h, 12, cap, len(frames) * cap)
    sim = Simulator(dut)
    sim.add_clock(1e-6)

    async def driver(ctx):
        for name, value in (("threshold", 50), ("background", 40)):
            ctx.set(dut.reg_addr, C.REGISTER_BY_NAME[name].address)
            ctx.set(dut.reg_data, value)
            ctx.set(dut.reg_en, 1)
            await ctx.tick()
        ctx.set(dut.reg_en, 0)
        for k, frame in enumerate(frames):
            if k == len(frames) - 1:
                await ctx.tick().repeat(6000)      # packets 0 and 1 are read by now
            for y in range(h):
                for x in range(w):
                    await stream_put(ctx, dut.pixels, {"data": int(frame[y, x]),
                                                       "sof": int(x == 0 and y == 0),
                                                       "eol": int(x == w - 1)})
                await stream_idle(ctx, dut.pixels, 1)
            await stream_idle(ctx, dut.pixels, vblank_cycles(w) + 2)
        await ctx.tick().repeat(6000)

    got = collect(sim, dut, lambda c: c % 7 == 0)
    sim.add_testbench(driver)
    sim.run()
    packets = split_packets(bytes(got))
    # one trailer is held while the packetizer sends a packet: frames that end meanwhile
    # lose theirs, and their records never reach a packet (hdl/detector.py)
    counters = [codec.decode(data).frame_counter for data in packets]
    assert counters == [0, 1, 4]
    for data in packets:
        decoded = codec.decode(data)
        expected = detect_frame(frames[decoded.frame_counter], cfg)
        expected.frame_counter = decoded.frame_counter
        assert decoded == expected
        assert (decoded.width, decoded.height, decoded.pixel_bits) == (w, h, 12)
    assert any(codec.decode(p).dropped_records for p in packets)
