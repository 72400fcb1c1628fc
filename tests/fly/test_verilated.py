"""The Verilated board top, pin by pin from Python (slow: a Verilator build, cached): the
firmware's link master reads its ID word and status, every packet byte it reads equals the
golden engine's for the same frames, instants and registers (the header's timestamp too:
the board's microsecond counter, set to each frame's instant before it in compressed time,
latched by the gateware at the first pixel), and ``min_sum`` written over SPI cuts the next
packet to the record budget."""

import pytest

from lodestar import contract as C
from lodestar.firmware import link as _link
from lodestar.fly import golden_top
from lodestar.ground import codec
from tests.fly.test_golden_top import _Bus, _Clock, _frame

pytestmark = pytest.mark.slow


class _PinBus(_Bus):
    def readinto(self, into, write=0):
        into[:] = self.top.xfer(bytes((write,)) * len(into))


def test_link_against_the_verilated_top_equals_golden():
    from lodestar.fly.verilated import VerilatedTop

    top = VerilatedTop.small(64, 32, 20)
    gold = golden_top.GoldenTop(64, 32, 12, 20, build_id=top.build_id)
    links = []
    for engine in (top, gold):
        b = _PinBus(engine)
        links.append(_link.Link(b, b.cs, b.irq, _Clock(), capacity=20))
    for link in links:
        assert link.read_id() == _link.OK and link.ident[1] == top.build_id
        for reg, value in (("threshold", 100), ("background", 30)):
            assert link.write_reg(reg, value) == _link.OK
    packets = [[], []]
    at = (100_000, 200_000, (1 << 32) - 50)      # us; the last one wraps within a frame
    for k in range(2):
        for engine in (top, gold):
            engine.frame(_frame(k), start_us=at[k])
        for i, link in enumerate(links):
            assert link.wait_irq(10) and link.read_status() == _link.OK
            code, n = link.read_packet()
            assert code == _link.OK
            packets[i].append(bytes(link.packet(n)))
    assert packets[0] == packets[1]
    assert [codec.decode(p).timestamp for p in packets[0]] == list(at[:2])
    n_all = C.packet_bytes(12)
    assert len(packets[0][0]) == n_all
    # min_sum: only the blobs with s0 >= 6 x (1700 - 30) come next
    for link in links:
        assert link.write_reg("min_sum", 6 * (1700 - 30)) == _link.OK
    for engine in (top, gold):
        engine.frame(_frame(2), start_us=at[2])
    got = []
    for link in links:
        assert link.wait_irq(10)
        code, n = link.read_packet()
        got.append(bytes(link.packet(n)))
        assert code == _link.OK and 0 < n < 12
    assert got[0] == got[1] and codec.decode(got[0]).timestamp == at[2]
    assert links[0].soft_reset() == _link.OK and links[0].read_status() == _link.OK
    assert links[0].frame_counter == 0


def test_a_frame_cut_short_ends_by_the_watchdog_before_the_next():
    """A frame whose FRAME_VALID falls after its first row: the board's frame watchdog
    completes it with dark rows after its stall timeout, long before the sensor's next frame,
    so its IRQ is high when the twin has played it and its packet is the golden engine's
    (``FRAME_TIMEOUT``; before, too few idle clocks were played for a 256-pixel row and the
    next frame's start ended it a period late, the twin's ``truncated`` time mismatches)."""
    from lodestar.fly.verilated import VerilatedTop

    top = VerilatedTop.small(256, 32, 20)
    gold = golden_top.GoldenTop(256, 32, 12, 20, build_id=top.build_id)
    got = []
    for engine in (top, gold):
        b = _PinBus(engine)
        link = _link.Link(b, b.cs, b.irq, _Clock(), capacity=20)
        assert link.write_reg("threshold", 100) == _link.OK
        engine.frame(_frame(0, w=256), rows=1, start_us=5000)
        assert engine.irq()
        assert link.read_status() == _link.OK and link.read_packet()[0] == _link.OK
        got.append(bytes(link.packet(link.n_records)))
    assert got[0] == got[1]
    assert codec.decode(got[0]).flags & C.FRAME_TIMEOUT
