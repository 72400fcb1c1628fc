"""Formal: ``hdl.frontend.PixelCrossing`` never delivers a frame shifted (multiclock BMC).

The sensor side (``pix``) and ``sync`` have independent free clocks (SBY ``multiclock on``:
either may tick at any step, so either may be much faster), and any stream of beats is
offered.  Each pixel's value is assumed to be its position in its frame (0 at ``sof``,
then +1 per beat, wrapping): then a pixel lost to an overflow and a frame delivered
without it would show on ``out`` as a value that is not the position there.  Proved for
``DEPTH`` = 16 steps (5 s; an overflow is first reachable at step 14) and, opt-in
(``--runslow``), 24 steps (~2-3 min; the time per step grows fast): every pixel on
``out`` is either a ``sof`` or follows a ``sof`` and carries its position, i.e. after an
overflow nothing reaches ``out`` before the next ``sof``.  Mutation: a crossing that keeps
writing after a lost pixel fails.
"""

import pytest
from amaranth import ClockDomain, ClockSignal, Elaboratable, Module, Mux, ResetSignal, Signal
from amaranth.hdl import Assert, Assume

from lodestar.hdl.frontend import PixelCrossing

from .sby import available, prove, submodule

pytestmark = pytest.mark.skipif(not available(), reason="yowasp-sby or yices-smt2 missing")

BITS, FIFO, DEPTH = 4, 4, 16


class UnshiftedCrossing(Elaboratable):
    def __init__(self, crossing):
        self.crossing = crossing

    def elaborate(self, platform):
        m = Module()
        m.domains.pix = ClockDomain()
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
            Assume(~ResetSignal("pix")), Assume(~ResetSignal("sync")),
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


def inputs(x):
    """The free inputs; ``pix`` is declared by the wrapper, so its clock and reset must be
    named here (``sync``, created by Amaranth, brings its own)."""
    return [x.pixels.valid, x.pixels.payload.as_value(), x.overflow_clear,
            ClockSignal("pix"), ResetSignal("pix")]


@pytest.mark.parametrize("depth", [DEPTH, pytest.param(24, marks=pytest.mark.slow)])
def test_no_shifted_frame(tmp_path, depth):
    x = PixelCrossing(BITS, "pix", FIFO)
    result = prove(UnshiftedCrossing(x), "bmc", depth, tmp_path, ports=inputs(x),
                   multiclock=True)
    assert result.passed, result.log


def test_no_shifted_frame_mutant_fails(tmp_path):
    x = ShiftingCrossing(BITS, "pix", FIFO)
    result = prove(UnshiftedCrossing(x), "bmc", DEPTH, tmp_path, ports=inputs(x),
                   multiclock=True)
    assert result.failed, result.log
