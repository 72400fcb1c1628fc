"""The gateware side of the link that serves recorded packets to the firmware's ``Link`` on
the Cortex-M4F build (:mod:`lodestar.regress.linkmodel`), checked here on CPython against
the firmware's own link master."""

from lodestar import contract as C
from lodestar.firmware import link
from lodestar.regress import linkmodel, replay
from tests.firmware.fakes import Clock


def _link(model):
    return link.Link(model, model.cs, model.irq, Clock(), capacity=C.FLIGHT_RECORD_CAPACITY)


def test_the_firmware_link_reads_recorded_packets_from_the_model():
    """ID, a register written and read back, a status word with its CRC-8, and a packet whose
    header, length and CRC-32 pass: the packet's bytes in the link's buffer, irq low after."""
    model = linkmodel.LinkModel()
    lnk = _link(model)
    assert lnk.read_id() == link.OK and lnk.ident == (C.LINK_VERSION, 0)
    assert lnk.write_reg("min_sum", 1234) == link.OK
    data = (replay.DEFAULT_SET / "packets" / "estcube2_rest_s1.bin").read_bytes()
    model.load(memoryview(data))
    assert lnk.wait_irq(10) and lnk.read_status() == link.OK
    assert lnk.frame_counter == 1 and lnk.busy == 1
    code, n = lnk.read_packet()
    assert code == link.OK and bytes(lnk.packet(n)) == data
    assert model.irq.value() == 0 and not lnk.wait_irq(10)
    assert lnk.counter("packets") == 1 and lnk.counter("status_bad") == 0


def test_a_corrupt_packet_is_refused_and_the_stream_flushed():
    """A packet with a flipped bit fails its CRC-32; the link flushes the model's queue and
    the next packet reads whole."""
    model = linkmodel.LinkModel()
    lnk = _link(model)
    bad = (replay.DEFAULT_SET / "packets" / "corrupt_bit_flip.bin").read_bytes()
    good = (replay.DEFAULT_SET / "packets" / "estcube2_rest_s2.bin").read_bytes()
    model.load(bad)
    assert lnk.read_status() == link.OK
    assert lnk.read_packet() == (link.PACKET_CRC, 0)
    assert model.pending() == 0 and lnk.counter("resync") == 1
    model.load(good)
    code, n = lnk.read_packet()
    assert code == link.OK and bytes(lnk.packet(n)) == good
