"""Output stage of the detector: a frame's records and its trailer, in step, to one reader.

``OutputStage(record_shape, record_depth)`` takes the feature engine's records
(``records_in``, valid/ready, into a ``HalfWordFIFO`` of ``record_depth``) and, on ``done``,
the frame's completed trailer (``trailer_in``, sampled in that clock; its ``n_records`` are
the records taken before that clock since the previous ``done``).  It holds one trailer
and offers it on ``trailer`` once the records between the last claimed one and the held
trailer's first (orphans: a lost frame's, or one taken in a ``done`` clock) are discarded,
so a reader that takes a trailer and then its ``n_records`` records (the packetizer) stays
in step.  A ``done`` while the held trailer is not taken loses the new trailer and counts
it in ``trailer_lost`` (wrapping).  Sequence numbers and proofs: ``docs/gateware.md`` (output
buffers), ``docs/formal.md``.
"""

from amaranth import Module, Signal, Value
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from lodestar import contract as C

from .buffers import HalfWordFIFO
from .layouts import trailer_layout

TRAILER_LOST_BITS = 8
"""Width of the wrapping count of lost trailers (the board compares it with its value at
the last status read, so any width that cannot wrap between two reads will do)."""


def idle_bound(record_depth):
    """Clocks after the last ``done`` or offered record within which the stage is idle (no
    trailer held, none owed to the reader) if the reader takes what it is owed at once: the
    buffer's at most ``record_depth`` records, orphans and the held trailer's, go out at one
    per three clocks (``HalfWordFIFO``), the trailer's take overlapping the buffer's fetch.
    Proved tight (``docs/formal.md``, return to idle)."""
    return 3 * record_depth - 1


class OutputStage(wiring.Component):
    """Record buffer, held trailer and orphan discarding for records of ``record_shape``."""

    def __init__(self, record_shape, record_depth):
        self.record_shape, self.record_depth = record_shape, record_depth
        super().__init__({
            "records_in": In(stream.Signature(record_shape)),
            "done": In(1),
            "trailer_in": In(trailer_layout()),
            "records": Out(stream.Signature(record_shape)),
            "trailer": Out(stream.Signature(trailer_layout())),
            "trailer_lost": Out(TRAILER_LOST_BITS),
        })

    def elaborate(self, platform):
        m = Module()
        width = len(Value.cast(self.records_in.payload))
        m.submodules.record_fifo = rfifo = HalfWordFIFO(width, self.record_depth)
        m.d.comb += [rfifo.w_data.eq(self.records_in.payload), rfifo.w_en.eq(self.records_in.valid),
                     self.records_in.ready.eq(rfifo.w_rdy),
                     self.records.payload.eq(rfifo.r_data)]
        self.sequence(m, rfifo)
        return m

    def sequence(self, m, rfifo):
        """Hold the trailer; discard orphans.  Record sequence numbers (modulo
        ``2**seq > 2 x record_depth``): ``wseq`` counts records into the buffer, ``rseq``
        records out of it (delivered or discarded); ``claimed`` is the number after the last
        record claimed by a taken trailer (or discarded).  The held trailer's records start
        at ``held_first``; records between ``claimed`` and ``held_first`` are orphans
        (``same``: there are none, a register)."""
        seq = C.bits_for(self.record_depth) + 1
        wseq, rseq, claimed = (Signal(seq, name=n) for n in ("wseq", "rseq", "claimed"))
        held_first = Signal(seq, reset_less=True)
        held = Signal(trailer_layout(), reset_less=True)
        held_valid = Signal()
        # claimed == held_first, registered from both registers' next values: the trailer's
        # valid (and the reader's take of its payload) starts at a flip-flop, not a compare
        same = Signal(name="same")
        claimed_next, first_next = Signal(seq), Signal(seq)
        taken = self.trailer.valid & self.trailer.ready
        m.d.comb += [claimed_next.eq(claimed), first_next.eq(held_first)]
        with m.If(self.done & (~held_valid | taken)):
            m.d.comb += first_next.eq(wseq - self.trailer_in.n_records[:seq])
            m.d.sync += [held.eq(self.trailer_in), held_valid.eq(1)]
        with m.Elif(taken):
            m.d.sync += held_valid.eq(0)
        with m.If(self.done & held_valid & ~taken):
            m.d.sync += self.trailer_lost.eq(self.trailer_lost + 1)

        orphans = held_valid & ~same
        at_claimed = rseq == claimed
        behind = (rseq - claimed)[seq - 1]        # the reader still owes claimed records
        discard = orphans & at_claimed & rfifo.r_rdy
        rseq_next = rseq + 1
        with m.If(taken):
            m.d.comb += claimed_next.eq(held_first + held.n_records[:seq])
        with m.Elif(discard):
            m.d.comb += claimed_next.eq(rseq_next)       # claimed == rseq here
        with m.Elif(orphans & ~at_claimed & ~behind):   # the reader took them already
            m.d.comb += claimed_next.eq(held_first)
        m.d.sync += [claimed.eq(claimed_next), held_first.eq(first_next),
                     same.eq(claimed_next == first_next)]
        m.d.comb += [self.records.valid.eq(rfifo.r_rdy & ~(orphans & at_claimed)),
                     rfifo.r_en.eq(self.records.valid & self.records.ready | discard),
                     self.trailer.payload.eq(held), self.trailer.valid.eq(held_valid & ~orphans)]
        with m.If(rfifo.w_en & rfifo.w_rdy):
            m.d.sync += wseq.eq(wseq + 1)
        with m.If(rfifo.r_en & rfifo.r_rdy):
            m.d.sync += rseq.eq(rseq_next)
