"""Formal: ``hdl.frontend.PixelCrossing`` never delivers a frame shifted, and never loses a
pixel while ``sync`` ticks at least as often as ``pix`` (multiclock BMC).

The sensor side (``pix``) and ``sync`` have independent free clocks (SBY ``multiclock on``:
either may tick at any step, so either may be much faster), and any stream of beats is
offered.  The sensor side's reset is free as the board makes it: a request at any step
(``down``, inside a frame: the board resets the capture domain on a PLL lock loss, the
DE2-115 also on the LVDS receiver's) held for at least ``HOLD`` ``sync`` clocks (the board
holds it for the PLL's qualification, 65,536 oscillator clocks), through a
``ResetSynchronizer`` (asserted at once, released on the ``pix`` clock two edges after the
request ends).  Shorter requests are outside the AsyncFIFO's reset contract: its read side
copies the write pointer while the reset is synchronized, and a pulse that releases before
the pointer's reset has crossed leaves a stale entry (found by this proof with no hold);
``sync`` is not reset after the start (the board resets it only at power-up, with every
domain; Amaranth's AsyncFIFO does not support a read-side reset on its own).  Each pixel's
value is assumed to be its position in its frame (0 at ``sof``,
then +1 per beat, wrapping): then a pixel lost to an overflow and a frame delivered
without it would show on ``out`` as a value that is not the position there.  Proved for
``DEPTH`` = 16 steps (5 s; an overflow is first reachable at step 14) and, opt-in
(``--runslow``), 24 steps (~2-3 min; the time per step grows fast): every pixel on
``out`` is either a ``sof`` or follows a ``sof`` and carries its position, i.e. after an
overflow nothing reaches ``out`` before the next ``sof``.  Mutation: a crossing that keeps
writing after a lost pixel fails.  Overflow-freedom (:class:`NoLoss`, the design's 8-entry
FIFO, BMC ``NO_LOSS_DEPTH`` steps by default, 36 opt-in): a 4-entry FIFO fails.
"""

import pytest
from amaranth import ClockDomain, ClockSignal, Elaboratable, Module, Mux, ResetSignal, Signal
from amaranth.hdl import Assert, Assume
from amaranth.lib.cdc import ResetSynchronizer

from lodestar.hdl.frontend import FIFO_DEPTH, PixelCrossing

from .sby import available, elaborate, prove, submodule

pytestmark = pytest.mark.skipif(not available(), reason="yowasp-sby or yices-smt2 missing")

BITS, FIFO, DEPTH = 4, 4, 16
MUTANT_DEPTH = 20
"""BMC steps for the shifting mutant (the capture domain leaves its power-up reset first)."""
NO_LOSS_DEPTH = 28
"""BMC steps of the overflow-freedom proof (14 pix ticks at most: the 8-entry FIFO twice
over)."""


HOLD = 3
"""``sync`` clocks a reset request of the capture domain lasts at least."""


def pix_domain(m, down):
    """The ``pix`` domain of a wrapper, reset by the board's synchronizer of a request that
    the free input ``down`` raises at any step and that lasts at least ``HOLD`` ``sync``
    clocks."""
    m.domains.pix = ClockDomain()
    request = Signal()
    held = Signal(range(HOLD + 1))
    with m.If(down):
        m.d.sync += [request.eq(1), held.eq(0)]
    with m.Elif(held == HOLD):
        m.d.sync += request.eq(0)
    with m.Elif(request):
        m.d.sync += held.eq(held + 1)
    m.submodules.pix_reset = ResetSynchronizer(request, domain="pix")


class UnshiftedCrossing(Elaboratable):
    def __init__(self, crossing):
        self.crossing = crossing
        self.down = Signal()

    def elaborate(self, platform):
        m = Module()
        pix_domain(m, self.down)
        m.submodules.crossing = x = self.crossing
        p, out = x.pixels, x.out
        pos = Signal(BITS)                    # position of the next beat in its frame (pix)
        with m.If(p.valid):
            m.d.pix += pos.eq(Mux(p.payload.sof, 1, pos + 1))
        opos = Signal(BITS)                   # the same on ``out`` (sync)
        seen = Signal()                       # a sof was delivered since reset
        with m.If(out.valid):
            m.d.sync += [opos.eq(Mux(out.payload.sof, 1, opos + 1)),
                         seen.eq(seen | out.payload.sof)]
        m.d.comb += [
            Assume(~ResetSignal("sync")),
            Assume(~p.valid | (p.payload.data == Mux(p.payload.sof, 0, pos))),
            Assert(~out.valid | out.payload.sof | (seen & (out.payload.data == opos))),
            Assert(~out.valid | ~out.payload.sof | (out.payload.data == 0)),
        ]
        return m


class ShiftingCrossing(PixelCrossing):
    """Mutant: waits for the first ``sof`` after reset, but keeps writing the rest of a
    frame after a lost pixel."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        p = self.pixels
        started = Signal()
        with m.If(p.valid & p.payload.sof):
            m.d[self.domain] += started.eq(1)
        m.d.comb += submodule(m, "fifo").w_en.eq(p.valid & (p.payload.sof | started))
        return m


def inputs(wrapper, x):
    """The free inputs; ``pix`` is declared by the wrapper, so its clock must be named here
    (its reset is the wrapper's synchronizer of the free ``down``; ``sync``, created by
    Amaranth, brings its own clock and reset)."""
    return [x.pixels.valid, x.pixels.payload.as_value(), x.overflow_clear,
            ClockSignal("pix"), wrapper.down]


@pytest.mark.parametrize("depth", [DEPTH, pytest.param(24, marks=pytest.mark.slow)])
def test_no_shifted_frame(tmp_path, depth):
    x = PixelCrossing(BITS, "pix", FIFO)
    wrapper = UnshiftedCrossing(x)
    result = prove(wrapper, "bmc", depth, tmp_path, ports=inputs(wrapper, x), multiclock=True)
    assert result.passed, result.log


def test_no_shifted_frame_mutant_fails(tmp_path):
    x = ShiftingCrossing(BITS, "pix", FIFO)
    wrapper = UnshiftedCrossing(x)
    result = prove(wrapper, "bmc", MUTANT_DEPTH, tmp_path, ports=inputs(wrapper, x),
                   multiclock=True)
    assert result.failed, result.log


class NoLoss(Elaboratable):
    """Overflow-freedom: ``sync`` ticks at least once between two ``pix`` ticks (assumed
    with two tick counters: ``sync``'s catches up with ``pix``'s at each of its ticks, and
    ``pix``'s may lead by at most one), any beats, the power-up reset only; no pixel is
    ever offered to a full FIFO (``w_en`` with ``w_rdy`` low), i.e. ``overflow`` never
    rises.  (Right after a later capture-domain reset the AsyncFIFO's write side may see
    the read pointer's old value for a few clocks, so a frame start arriving then can be
    lost: flagged, and never delivered shifted, :class:`UnshiftedCrossing`.)"""

    def __init__(self, crossing):
        self.crossing = crossing
        self.down = Signal()

    def elaborate(self, platform):
        m = Module()
        pix_domain(m, self.down)
        x = self.crossing
        m.submodules.crossing = xm = elaborate(x, platform)
        fifo = submodule(xm, "fifo")
        pix_ticks = Signal(4, reset_less=True)
        sync_ticks = Signal(4, reset_less=True)
        m.d.pix += pix_ticks.eq(pix_ticks + 1)
        with m.If(sync_ticks != pix_ticks):
            m.d.sync += sync_ticks.eq(sync_ticks + 1)
        m.d.comb += [
            Assume(~ResetSignal("sync")), Assume(~self.down),
            Assume((pix_ticks - sync_ticks)[:4] <= 1),
            Assert(~(fifo.w_en & ~fifo.w_rdy)),
        ]
        return m


@pytest.mark.parametrize("depth", [NO_LOSS_DEPTH, pytest.param(36, marks=pytest.mark.slow)])
def test_no_loss_when_sync_keeps_up(tmp_path, depth):
    x = PixelCrossing(BITS, "pix")               # the design's FIFO_DEPTH (8)
    assert x.depth == FIFO_DEPTH
    wrapper = NoLoss(x)
    result = prove(wrapper, "bmc", depth, tmp_path, ports=inputs(wrapper, x), multiclock=True)
    assert result.passed, result.log


def test_no_loss_mutant_fails(tmp_path):
    """A 4-entry FIFO overflows under the same clocks: the write side counts pixels whose
    read it has not yet seen through the pointer synchronizers (up to 6)."""
    x = PixelCrossing(BITS, "pix", 4)
    wrapper = NoLoss(x)
    result = prove(wrapper, "bmc", NO_LOSS_DEPTH, tmp_path, ports=inputs(wrapper, x),
                   multiclock=True)
    assert result.failed, result.log
