"""Record buffer: a FIFO of wide items stored as two half-width memory words.

A memory ``depth x width`` with ``width`` above the M9K's widest port (36 bits) costs
``ceil(width / 36)`` blocks however shallow it is: 128 or 255 records of 345 bits both need
10.  Stored as two words of ``ceil(width / 2)`` bits, ``depth`` items fill ``2 x depth``
words, so 128 records of 345 bits need 5 blocks (256 x 173).

``HalfWordFIFO(width, depth)`` has the ports of Amaranth's FIFOs (``w_data``, ``w_en``,
``w_rdy``, ``r_data``, ``r_rdy``, ``r_en``) and holds exactly ``depth`` items:

* write: an item is taken when ``w_en & w_rdy``; its low half is written in that clock, its
  high half (held in a register) in the next, during which ``w_rdy`` is low.  So the buffer
  takes at most one item per two clocks, as fast as the detector's records come
  (``docs/gateware.md``, output buffers).
* read: the head item's low half is read into a register, then its high half is read and
  held on the memory's read port; ``r_data`` is the two together and ``r_rdy`` rises two
  clocks after an item became available or three after the previous one was taken, so a
  reader that is always ready takes one item per three clocks.  The next read starts in
  the clock after a take, from registers only (no path from the reader's ``r_en`` to the
  memory's address).  An item is readable from the clock after its high half was written.
"""

from amaranth import Cat, Module, Mux, Signal
from amaranth.lib import wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out


class HalfWordFIFO(wiring.Component):
    """FIFO of ``depth`` items of ``width`` bits in a ``2 depth x ceil(width / 2)`` memory."""

    def __init__(self, width, depth):
        if width < 2 or depth < 1:
            raise ValueError(f"HalfWordFIFO needs width >= 2 and depth >= 1, got {width}, "
                             f"{depth}")
        self.width, self.depth = width, depth
        self.lo_bits = (width + 1) // 2
        super().__init__({
            "w_data": In(width), "w_en": In(1), "w_rdy": Out(1),
            "r_data": Out(width), "r_rdy": Out(1), "r_en": In(1),
        })

    def elaborate(self, platform):
        m = Module()
        lo = self.lo_bits
        m.submodules.storage = mem = Memory(shape=lo, depth=2 * self.depth, init=[])
        wp = mem.write_port()
        rp = mem.read_port()

        count = Signal(range(self.depth + 1))       # items written whole, not yet taken
        w_item = Signal(range(self.depth))
        r_item = Signal(range(self.depth))
        second = Signal()                           # the high half is written this clock
        hi_hold = Signal(self.width - lo, reset_less=True)

        def advance(ptr):
            if self.depth & (self.depth - 1) == 0:
                return ptr + 1                      # wraps by itself
            return Mux(ptr == self.depth - 1, 0, ptr + 1)

        # ---- write: low half now, high half next clock ---------------------------------
        take_in = self.w_en & self.w_rdy
        m.d.comb += [self.w_rdy.eq(~second & (count != self.depth)),
                     wp.addr.eq(Cat(second, w_item)),
                     wp.data.eq(Mux(second, hi_hold, self.w_data[:lo])),
                     wp.en.eq(take_in | second)]
        m.d.sync += [second.eq(take_in), hi_hold.eq(self.w_data[lo:])]
        with m.If(second):
            m.d.sync += w_item.eq(advance(w_item))

        # ---- read: low half into a register, high half held on the read port ------------
        lo_reg = Signal(lo, reset_less=True)
        fetch = Signal()                            # the low half arrives this clock
        pop = self.r_en & self.r_rdy
        m.d.comb += self.r_data.eq(Cat(lo_reg, rp.data[:self.width - lo]))
        start = ~fetch & ~self.r_rdy & (count != 0)
        m.d.comb += [rp.addr.eq(Cat(fetch, r_item)), rp.en.eq(start | fetch)]
        m.d.sync += fetch.eq(start)
        with m.If(fetch):
            m.d.sync += [lo_reg.eq(rp.data), self.r_rdy.eq(1)]
        with m.Elif(pop):
            m.d.sync += self.r_rdy.eq(0)
        with m.If(pop):
            m.d.sync += r_item.eq(advance(r_item))
        with m.If(second ^ pop):
            m.d.sync += count.eq(count + Mux(pop, -1, 1))
        return m
