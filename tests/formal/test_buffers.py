"""Formal: the record buffer (``hdl.buffers.HalfWordFIFO``) accounts for every record.

Record accounting, k-induction: an observer counts the items taken in (``w_en & w_rdy``)
and out (``r_en & r_rdy``); for any write and read pattern and resets at any time, the
items held never exceed ``depth``, ``r_rdy`` never offers an item that is not held,
``w_rdy`` refuses only in the clock after an item was taken or when ``depth`` items are
held, and an item held is offered at most two clocks after the reader became free
(``docs/formal.md``).  Mutation: a buffer whose ``w_rdy`` ignores fullness fails.

Order, BMC: with each item's value its number (modulo ``2**width``), every item offered is
the next one in write order, so items are neither lost, repeated nor reordered, nor torn
between their two half-words (the output stage's proof, ``test_output.py``, counts on it).
Mutation: a buffer that writes a stale high half fails.
"""

import pytest
from amaranth import Elaboratable, Module, Signal
from amaranth.hdl import Assert, Assume

from lodestar.hdl.buffers import HalfWordFIFO

from .sby import available, elaborate, internals, prove

pytestmark = pytest.mark.skipif(not available(), reason="yowasp-sby or yices-smt2 missing")

ORDER_DEPTH = 16
"""BMC depth of the order proof: 8 items in and out (numbers wrap at 4, the buffer fills
and empties)."""


class AccountedFIFO(Elaboratable):
    """``fifo`` (a ``HalfWordFIFO`` or a mutant) under the accounting properties."""

    def __init__(self, fifo):
        self.fifo = fifo

    def elaborate(self, platform):
        m = Module()
        f = self.fifo
        m.submodules.fifo = unit = elaborate(f, platform)
        s = internals(unit)
        count, second, fetch = s["count"], s["second"], s["fetch"]
        w_item, r_item = s["w_item"], s["r_item"]
        depth = f.depth
        took = f.w_en & f.w_rdy
        popped = f.r_en & f.r_rdy
        held = Signal(range(2 * depth + 2))             # items taken in, not yet out
        took_last = Signal()
        waited = Signal(range(4))                       # clocks an item has waited, reader free
        m.d.sync += [held.eq(held + took - popped), took_last.eq(took)]
        with m.If((held - took_last != 0) & ~f.r_rdy):
            m.d.sync += waited.eq(waited + (waited != 3))
        with m.Else():
            m.d.sync += waited.eq(0)

        # ---- the properties (ports and the observer only) -------------------------------
        m.d.comb += [
            Assert(held <= depth),
            Assert(~f.r_rdy | (held != 0)),
            Assert(f.w_rdy == (~took_last & (held != depth))),
            Assert(waited <= 2),
        ]
        # ---- helper invariants on the buffer's state, for the induction ------------------
        items = (w_item - r_item) % depth if depth & (depth - 1) else (w_item - r_item)
        m.d.comb += [
            Assert(held == count + second),
            Assert(second == took_last),
            Assert(w_item < depth), Assert(r_item < depth),
            Assert(items[:len(w_item)] == count % depth),
            Assert(~f.r_rdy | (count != 0)),
            Assert(~fetch | ~f.r_rdy),
            Assert(~fetch | (count != 0)),
        ]
        m.d.comb += Assume(held <= 2 * depth)             # the observer's own range
        return m


class OrderedFIFO(Elaboratable):
    """``fifo`` fed its items' numbers: each item offered is the next in write order."""

    def __init__(self, fifo):
        self.fifo = fifo

    def elaborate(self, platform):
        m = Module()
        f = self.fifo
        m.submodules.fifo = f
        written = Signal(f.width)
        read = Signal(f.width)
        m.d.sync += [written.eq(written + (f.w_en & f.w_rdy)),
                     read.eq(read + (f.r_en & f.r_rdy))]
        m.d.comb += [Assume(f.w_data == written), Assert(~f.r_rdy | (f.r_data == read))]
        return m


class UnboundedFIFO(HalfWordFIFO):
    """Mutant: ``w_rdy`` ignores fullness."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        m.d.comb += self.w_rdy.eq(~internals(m)["second"])
        return m


def inputs(fifo):
    return [fifo.w_en, fifo.w_data, fifo.r_en]


@pytest.mark.parametrize("depth", [3, 4])
def test_record_accounting(tmp_path, depth):
    fifo = HalfWordFIFO(5, depth)
    result = prove(AccountedFIFO(fifo), "prove", 10, tmp_path, ports=inputs(fifo))
    assert result.passed, result.log


class StaleFIFO(HalfWordFIFO):
    """Mutant: the high half is never taken from the item (it stays at its reset value)."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        hi_hold = internals(m)["hi_hold"]
        m.d.sync += hi_hold.eq(hi_hold)
        return m


@pytest.mark.parametrize("depth", [3, 4])
def test_order(tmp_path, depth):
    fifo = HalfWordFIFO(2, depth)
    result = prove(OrderedFIFO(fifo), "bmc", ORDER_DEPTH, tmp_path, ports=inputs(fifo))
    assert result.passed, result.log


def test_order_mutant_fails(tmp_path):
    fifo = StaleFIFO(2, 3)
    result = prove(OrderedFIFO(fifo), "bmc", ORDER_DEPTH, tmp_path, ports=inputs(fifo))
    assert result.failed, result.log


def test_record_accounting_mutant_fails(tmp_path):
    fifo = UnboundedFIFO(5, 3)
    result = prove(AccountedFIFO(fifo), "prove", 10, tmp_path, ports=inputs(fifo))
    assert result.failed, result.log
