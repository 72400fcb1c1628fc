"""The golden engine's SPI slave against the firmware's own link master: ID word, status
word with its CRC-8, register writes read back and refused, packets equal to the golden
detector's through the codec, flush, soft reset, underruns, the queue of two packets."""

import numpy as np

from lodestar import contract as C
from lodestar.firmware import link as _link
from lodestar.fly import golden_top
from lodestar.golden import Detector
from lodestar.ground import codec


class _Clock:
    def __init__(self):
        self.now = 0

    def ticks_ms(self):
        return self.now

    def ticks_diff(self, a, b):
        return a - b

    def sleep_ms(self, n):
        self.now += n


class _Bus:
    """``machine.SPI`` and pins straight onto a GoldenTop."""

    def __init__(self, top):
        self.top = top
        self.cs = _Pin(lambda v: top.cs(v))
        self.irq = _Pin(None, top.irq)

    def write_readinto(self, out, into):
        into[:len(out)] = self.top.xfer(bytes(out))

    def write(self, out):
        self.top.xfer(bytes(out))

    def readinto(self, into, write=0):
        into[:] = self.top.xfer(bytes((write,)) * len(into))


class _Pin:
    def __init__(self, write, read=None):
        self._write, self._read = write, read

    def value(self, v=None):
        if v is None:
            return int(self._read())
        self._write(v)


def _frame(seed=0, w=64, h=32):
    rng = np.random.default_rng(seed)
    f = rng.integers(0, 40, (h, w)).astype(np.uint16)
    for k in range(12):
        y, x = 2 + (k % 4) * 7, 4 + (k // 4) * 20
        f[y:y + 2, x:x + 3] = 200 + 150 * k
    return f


def setup(cap=20):
    top = golden_top.GoldenTop(64, 32, 12, cap, build_id=0x33)
    bus = _Bus(top)
    return top, _link.Link(bus, bus.cs, bus.irq, _Clock(), capacity=cap)


def test_id_status_and_registers():
    top, link = setup()
    assert link.read_id() == _link.OK and link.ident == (C.LINK_VERSION, 0x33)
    assert link.read_status() == _link.OK and link.frame_counter == 0
    assert link.write_reg("threshold", 100) == _link.OK
    assert top.bank[C.REGISTER_BY_NAME["threshold"].address] == 100
    # above the 12-bit full scale: refused, read back differs, the status word says so
    assert link.write_reg("threshold", 5000) == _link.VERIFY_FAILED
    assert link.read_status() == _link.OK and link.overflow & (1 << C.OVF_REG_REFUSED)


def test_packets_are_the_golden_detectors_and_the_queue_holds_two():
    top, link = setup()
    for reg, value in (("threshold", 100), ("background", 30)):
        assert link.write_reg(reg, value) == _link.OK
    frames = [_frame(k) for k in range(3)]
    for f in frames:
        top.frame(f)
    ref = Detector(golden_top.config_of(top.bank, 64, 32, 12, 20, None))
    expect = [codec.encode(ref.process(f)) for f in frames]
    assert link.wait_irq(10) and link.read_status() == _link.OK
    assert link.overflow & (1 << C.OVF_TRAILER_LOST)        # the third found two queued
    for k in range(2):
        code, n = link.read_packet()
        assert code == _link.OK and bytes(link.packet(n)) == expect[k]
    assert not link.wait_irq(5)


def test_min_sum_cuts_the_next_packet_and_flush_and_soft_reset():
    top, link = setup()
    for reg, value in (("threshold", 100), ("background", 30)):
        link.write_reg(reg, value)
    top.frame(_frame())
    code, n_all = link.read_packet()
    assert code == _link.OK and n_all == 12
    assert link.write_reg("min_sum", 6 * (1700 - 30)) == _link.OK
    top.frame(_frame())
    code, n = link.read_packet()
    assert code == _link.OK and 0 < n < n_all
    top.frame(_frame())
    assert link.resync() == _link.OK and not top.irq()       # FLUSH emptied the queue
    assert link.read_status() == _link.OK and link.frame_counter == 3
    assert link.soft_reset() == _link.OK
    assert link.read_status() == _link.OK and link.frame_counter == 0


def test_reading_past_the_stream_counts_underruns():
    top, link = setup()
    code, _n = link.read_packet()
    assert code == _link.HEADER_BAD
    top.cs(0)
    top.xfer(bytes((C.OP_READ_STREAM, 0, 0, 0)))
    top.cs(1)
    assert top.underruns == 2
