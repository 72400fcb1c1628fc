"""The firmware's SPI master (``firmware/link.py``) against the Amaranth simulation of the
gateware's ``SPISlave`` (``tests/firmware/amaranth_bus.py``): every opcode, packets read whole,
packets longer than the buffer, corrupt and short reads, a stream entered mid-packet, a
floating MISO, a dead IRQ and a failing bus, each followed by a clean read (the link
resynchronised), with the counters of each error kind."""

import numpy as np
import pytest

from lodestar import contract as C
from lodestar.firmware import link as _link
from lodestar.golden import Detector, DetectorConfig
from lodestar.golden.starfield import star_frame
from lodestar.ground import codec
from tests.firmware.amaranth_bus import AmaranthBus, GatewareTopBus, SimClock


def make_packet(seed, n_stars=6, capacity=64, frame_counter=None, timestamp=None):
    frame, _ = star_frame(width=64, height=48, pixel_bits=12, n_stars=n_stars, seed=seed,
                          sigma=1.2)
    cfg = DetectorConfig(width=64, height=48, pixel_bits=12, threshold=80, background=40,
                         min_pixels=2, record_capacity=capacity)
    res = Detector(cfg).process(frame)
    if frame_counter is not None:
        res.frame_counter = frame_counter
    if timestamp is not None:
        res.timestamp = timestamp
    return codec.encode(res)


def records(packet):
    return int.from_bytes(packet[C.HEADER_BYTES - 2:C.HEADER_BYTES], "big")


@pytest.fixture(scope="module")
def packets():
    out = [make_packet(seed, frame_counter=seed) for seed in range(1, 5)]
    assert all(0 < records(p) <= 8 for p in out)
    return out


def new_link(capacity=8, **kw):
    bus = AmaranthBus(**kw)
    clock = SimClock()
    return bus, _link.Link(bus.spi, bus.cs, bus.irq, clock, capacity=capacity), clock


def counters(link):
    return {name: link.counters[i] for i, name in enumerate(_link.COUNTER_NAMES)
            if link.counters[i]}


def test_status_id_registers_and_keyed_commands():
    bus, link, _ = new_link()
    bus.status_in.update(frame_counter=0xDEADBEEF, overflow=1 << C.OVF_CLOCK_LOST, busy=1,
                         trained=1, eye_width=(1 << C.EYE_WIDTH_BITS) - 2)
    assert link.read_status() == _link.OK
    assert (link.frame_counter, link.errors, link.underruns, link.overflow, link.busy,
            link.trained, link.eye_width) == \
        (0xDEADBEEF, 0, 0, 1 << C.OVF_CLOCK_LOST, 1, 1, (1 << C.EYE_WIDTH_BITS) - 2)
    assert link.clock_lost()
    bus.status_in["overflow"] = 0
    assert link.read_id() == _link.OK and link.ident == (C.LINK_VERSION, 0x21)
    rng = np.random.default_rng(3)
    for reg in C.REGISTERS:
        value = int(rng.integers(0, 1 << reg.bits))
        assert link.write_reg(reg.name, value) == _link.OK
        assert bus.bank[reg.address] == value
        assert link.read_reg(reg.address) == (_link.OK, value)
    assert link.write_reg("nonsense", 1) == _link.BAD_ARGUMENT
    assert link.write_reg("mode", 1 << 8) == _link.BAD_ARGUMENT
    assert link.command(C.OP_SOFT_RESET) == _link.OK and bus.resets == 1
    assert link.command(C.OP_FLUSH) == _link.OK and bus.flushes == 1
    assert link.command(C.OP_READ_STREAM) == _link.BAD_ARGUMENT
    assert link.read_status() == _link.OK and link.errors == 0
    assert counters(link) == {"status": 2, "overflow": 1, "clock_lost": 1}


def test_uncommanded_counter_restart_is_counted():
    """The frame counter going back is a detector reset; counted unless the MCU commanded
    it (soft reset) or the PLL's loss explains it (``OVF_CLOCK_LOST``)."""
    bus, link, _ = new_link()

    def status(counter, overflow=0):
        bus.status_in.update(frame_counter=counter, overflow=overflow)
        assert link.read_status() == _link.OK
    status(10)
    status(11)
    status(0)
    assert link.restarted and counters(link)["restarts"] == 1
    link.restarted = False
    status(5)
    bus.status_in["frame_counter"] = 0
    assert link.soft_reset() == _link.OK                # its resync reads the status
    status(3)
    status(0, overflow=1 << C.OVF_CLOCK_LOST)
    assert not link.restarted and counters(link)["restarts"] == 1


def test_packets_read_whole_and_frames_skipped(packets):
    bus, link, _ = new_link()
    bus.packets.extend(packets[:2])
    for p in packets[:2]:
        assert link.wait_irq(10)
        code, n = link.read_packet()
        assert (code, n) == (_link.OK, records(p))
        assert bytes(link.packet(n)) == p
    assert not bus.irq.value()
    bus.status_in["frame_counter"] = 5
    assert link.read_status() == _link.OK
    bus.status_in["frame_counter"] = 9
    assert link.read_status() == _link.OK
    assert counters(link) == {"packets": 2, "status": 2, "frames_skipped": 3}
    assert link.last_frame_counter == 2


def test_timestamps_come_as_small_ints_of_30_and_2_bits():
    """A header timestamp above 2**30 (after 17.9 min of the gateware's clock) is given as its
    low 30 bits and its top 2, both small ints on the MCU; ``timestamp()`` joins them.  The
    link reads the field as 32 bits on a byte boundary: the contract's header must keep it
    there."""
    (at, bits), = [(a, b) for name, a, b in C.field_offsets(C.HEADER_FIELDS)
                   if name == "timestamp"]
    assert bits == 32 and at % 8 == 0
    bus, link, _ = new_link()
    assert link.timestamp() is None
    for stamp in (0xC0000123, 0x3FFFFFFF, 0x40000000, 5):
        bus.packets.append(make_packet(1, timestamp=stamp))
        assert link.read_packet()[0] == _link.OK
        assert link.last_stamp == stamp & 0x3FFFFFFF and link.last_stamp_top == stamp >> 30
        assert link.timestamp() == stamp


def test_packet_longer_than_the_buffer_is_refused_and_flushed(packets):
    big = make_packet(9, n_stars=12)
    assert records(big) > 8
    bus, link, _ = new_link()
    bus.packets.extend([big, packets[0]])
    assert link.read_packet() == (_link.LENGTH_BAD, 0)
    assert bus.flushes == 1 and not bus.irq.value()     # the flush dropped both
    bus.packets.append(packets[1])
    assert link.read_packet() == (_link.OK, records(packets[1]))
    assert counters(link) == {"length_bad": 1, "resync": 1, "status": 1, "packets": 1}


def no_flush(link):
    """Make ``link`` talk to a gateware whose FLUSH does nothing (link version 1)."""
    real = link.command
    link.command = lambda op: _link.OK if op == C.OP_FLUSH else real(op)


@pytest.mark.parametrize("flush_works", [True, False])
def test_corrupt_byte_resynchronises(packets, flush_works):
    """A bit flipped on MISO inside a packet: CRC-32 refused, then the stream is flushed
    (or, with a gateware whose flush does nothing, drained until irq falls) and the next
    packet reads clean; the drain's underruns are not counted as errors."""
    bus, link, _ = new_link()
    if not flush_works:
        no_flush(link)
    bus.packets.extend(packets[:1])
    bus.miso_hook = lambda i, b: b ^ 0x01 if i == 2 + 5 else b
    assert link.read_packet() == (_link.PACKET_CRC, 0)
    bus.miso_hook = None
    assert not bus.irq.value()
    bus.packets.append(packets[1])
    assert link.read_packet() == (_link.OK, records(packets[1]))
    c = counters(link)
    assert c["packet_crc"] == 1 and c["resync"] == 1 and "underruns" not in c
    assert bus.flushes == (1 if flush_works else 0)


def test_mid_packet_start_and_short_packet(packets):
    bus, link, _ = new_link()
    bus.packets.append(packets[0][10:])                   # entered mid-packet
    assert link.read_packet() == (_link.HEADER_BAD, 0)
    bus.packets.append(packets[1][:-3])                   # the last 3 bytes never come
    assert link.read_packet() == (_link.PACKET_CRC, 0)
    bus.packets.append(packets[2])
    assert link.read_packet() == (_link.OK, records(packets[2]))
    c = counters(link)
    assert c["header_bad"] == 1 and c["packet_crc"] == 1 and c["resync"] == 2
    # the short packet's 3 bytes read past the end were underruns, seen by the status read
    # of the resync and not counted as an error
    assert "underruns" not in c


def test_drain_without_flush_stops_at_the_packet_end(packets):
    bus, link, _ = new_link()
    no_flush(link)
    bus.packets.extend([packets[0][5:]])
    assert link.read_packet() == (_link.HEADER_BAD, 0)
    assert not bus.irq.value() and bus.flushes == 0
    bus.packets.append(packets[1])
    assert link.read_packet() == (_link.OK, records(packets[1]))


@pytest.mark.parametrize("level", [0x00, 0xFF])
def test_floating_miso_is_never_a_status_or_an_id(level):
    bus, link, _ = new_link()
    bus.miso_hook = lambda i, b: level
    assert link.read_status() == _link.STATUS_BAD
    assert link.frame_counter is None
    assert link.read_id() == _link.ID_BAD
    assert link.write_reg("min_sum", 1234) == _link.VERIFY_FAILED
    assert link.read_packet() == (_link.HEADER_BAD, 0)
    c = counters(link)
    assert c["status_bad"] >= 1 and c["verify"] == 3 and c["header_bad"] == 1


def test_dead_irq_times_out_in_bounded_time():
    bus, link, clock = new_link()
    assert not link.wait_irq(120)
    assert 120 <= clock.now <= 121
    assert counters(link) == {"irq_timeout": 1}


def test_stuck_irq_resync_fails_in_bounded_time(packets):
    bus, link, clock = new_link()
    bus.irq = type(bus.irq)(read=lambda: 1)
    link.irq = bus.irq
    bus.packets.append(packets[0][3:])
    clock.on_sleep = None
    start = clock.now

    def tick(*_):
        clock.now += 1
    bus.miso_hook = lambda i, b: (tick(), b)[1]
    assert link.read_packet() == (_link.HEADER_BAD, 0)
    assert counters(link)["resync_failed"] == 1
    # the header, the flush, then chunks until the drain time is up
    assert clock.now - start <= C.HEADER_BYTES + 2 + 2 + _link.DRAIN_MS + _link.DRAIN_CHUNK + 2


class FailingSPI:
    def write_readinto(self, out, into):
        raise OSError(5)

    def write(self, out):
        raise OSError(5)

    def readinto(self, into, write=0):
        raise OSError(5)


def test_bus_errors_are_codes_not_exceptions():
    bus, _, clock = new_link()
    link = _link.Link(FailingSPI(), bus.cs, bus.irq, clock, capacity=8)
    assert link.read_status() == _link.BUS_ERROR
    assert link.read_id() == _link.BUS_ERROR
    assert link.write_reg("min_sum", 3) == _link.BUS_ERROR
    assert link.read_packet() == (_link.BUS_ERROR, 0)
    assert link.command(C.OP_FLUSH) == _link.BUS_ERROR
    assert counters(link)["bus"] >= 5
    assert bus.cs.value() == 1                          # CS released after each failure


_MP_LINK = r'''
from lodestar import contract as C
from lodestar.firmware import link as _link

class Clock:
    now = 0
    def ticks_ms(self):
        return self.now
    def ticks_diff(self, a, b):
        return a - b
    def sleep_ms(self, n):
        self.now += n

class FPGA:
    """The slave's replies as bytes: status (CRC-8 from the contract), READ_REG from a bank,
    READ_ID, the packet stream with irq high while bytes remain; ``flip`` corrupts a MISO byte
    of the stream."""
    def __init__(self, stream):
        self.stream = bytearray(stream)
        self.bank = {}
        self.flip = None
        self.sent = 0
        self.op = None
    def value(self, v=None):
        return 1 if self.stream else 0
    def write_readinto(self, out, into):
        op = out[0]
        for i in range(len(into)):
            into[i] = 0
        if op == C.OP_READ_STATUS:
            into[2:] = C.encode_status({"frame_counter": 9, "errors": 0, "underruns": 0,
                                        "overflow": 0, "busy": 0})
        elif op == C.OP_WRITE_REG:
            self.bank[out[1]] = bytes(out[2:6])
        elif op == C.OP_READ_REG:
            into[3:7] = self.bank.get(out[1], bytes(4))
        elif op == C.OP_READ_ID:
            into[2:6] = C.gateware_id(7).to_bytes(4, "big")
    def write(self, out):
        self.op = out[0]
        if out[0] == C.OP_FLUSH:
            self.stream = bytearray()
    def readinto(self, buf, write=0):
        n = len(buf)
        for i in range(n):
            if i < len(self.stream):
                b = self.stream[i]
                if self.flip == self.sent:
                    b ^= 1
                buf[i] = b
            else:
                buf[i] = C.FILLER
            self.sent += 1
        self.stream = self.stream[n:]

P = PACKETS
fpga = FPGA(P[0] + P[1] + P[2][:10])
lk = _link.Link(fpga, fpga, fpga, Clock(), capacity=8)
out = [lk.read_id(), lk.ident, lk.read_status(), lk.frame_counter]
out.append(lk.read_packet())
out.append(bytes(lk.packet(out[-1][1])) == P[0])
fpga.flip = fpga.sent + 40
out.append(lk.read_packet())                   # corrupt: flushed
fpga.stream = bytearray(P[2][5:] + P[1])      # mid-packet, then a good one
fpga.flip = None
out.append(lk.read_packet())
fpga.stream = bytearray(P[1])
out.append(lk.read_packet())
out.append(lk.write_reg("min_sum", 4321))
out.append(lk.write_reg("mode", 1 << 9))
out.append(list(lk.counters))
print(repr(out))
'''


def test_link_runs_unchanged_on_micropython(micropython, packets):
    """The master under MicroPython 1.27 against a byte-level fake FPGA gives CPython's
    codes, counters and bytes."""
    lit = [bytes(p) for p in packets[:3]]
    script = "PACKETS = " + repr(lit) + "\n" + _MP_LINK
    code, out = micropython(script)
    assert code == 0, out
    ns = {"PACKETS": lit}
    lines = []
    exec(compile(_MP_LINK.replace("print(repr(out))", "LINES.append(repr(out))"), "mp",
                 "exec"), dict(ns, LINES=lines))
    assert out.split("\n")[0] == lines[0]
    got = eval(lines[0])
    assert got[:4] == [_link.OK, (C.LINK_VERSION, 7), _link.OK, 9]
    assert got[4][0] == _link.OK and got[5] is True
    assert got[6] == (_link.PACKET_CRC, 0) and got[7] == (_link.HEADER_BAD, 0)
    assert got[8][0] == _link.OK and got[9] == _link.OK and got[10] == _link.BAD_ARGUMENT


def test_link_over_the_real_gateware_top():
    """The link master against the whole ``GatewareTop`` (its SPI slave, register bank
    mirror, soft reset and flush wired as on the boards): the ID word carries the build's
    ``contract.build_id``, every register is written and read back, a soft reset keeps them
    and resynchronises, and the status is clean."""
    bus = GatewareTopBus()
    link = _link.Link(bus.spi, bus.cs, bus.irq, SimClock(), capacity=4)
    assert link.read_status() == _link.OK and link.errors == 0
    assert link.read_id() == _link.OK and link.ident == (C.LINK_VERSION, bus.dut.build)
    rng = np.random.default_rng(4)
    values = {}
    for reg in C.REGISTERS:
        low, high = C.register_range(reg.name, 12)
        values[reg.name] = int(rng.integers(low, high + 1))
        assert link.write_reg(reg.name, values[reg.name]) == _link.OK, reg.name
    assert link.soft_reset() == _link.OK
    for reg in C.REGISTERS:
        assert link.read_reg(reg.address) == (_link.OK, values[reg.name])
    assert link.read_status() == _link.OK and (link.errors, link.overflow) == (0, 0)
    assert counters(link).get("verify_failed", 0) == 0
