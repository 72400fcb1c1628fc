"""Formal: ``hdl.frontend.FrameWatchdog`` is safe and responds in bounded time.

A small frame (``W x H``, a short ``TIMEOUT``) and any pixel stream, the reset free
(k-induction, ``docs/formal.md``):

* safety: the watchdog pads (sends its own pixels) only inside a frame, and every pixel it
  pads is dark (0: never lit, ``lit = p > T``), a ``sof`` only from the sensor;
* bounded response: inside a frame, at most ``BOUND`` = ``TIMEOUT`` + ``W * H`` +
  ``H * MIN_HBLANK`` clocks pass without a sensor pixel before the frame ends (the watchdog
  times out and pads the rest).

Mutations: a watchdog built with a longer timeout than the bound assumes (the response
fails), and one that pads with lit pixels (safety fails).
"""

import pytest
from amaranth import Elaboratable, Module, Signal
from amaranth.hdl import Assert

from lodestar.hdl.frontend import FrameWatchdog
from lodestar.hdl.labeller import MIN_HBLANK

from .sby import available, elaborate, internals, prove

pytestmark = pytest.mark.skipif(not available(), reason="yowasp-sby or yices-smt2 missing")

W, H, BITS, TIMEOUT = 4, 2, 8, 3
BOUND = TIMEOUT + W * H + H * MIN_HBLANK
DEPTH = BOUND + 4


class CheckedWatchdog(Elaboratable):
    def __init__(self, watchdog):
        self.watchdog = watchdog

    def elaborate(self, platform):
        m = Module()
        wd = self.watchdog
        m.submodules.watchdog = unit = elaborate(wd, platform)
        st = internals(unit)
        in_frame, send, sof, data = st["in_frame"], st["send"], st["sof"], st["data"]
        p = wd.pixels
        quiet = Signal(range(BOUND + 2))         # clocks in a frame since the last pixel
        with m.If(p.valid | ~in_frame):
            m.d.sync += quiet.eq(0)
        with m.Elif(quiet <= BOUND):
            m.d.sync += quiet.eq(quiet + 1)
        own = send & wd.padding & ~(p.valid & p.payload.sof)   # a pixel the watchdog made
        m.d.comb += [
            Assert(~wd.padding | in_frame),
            Assert(~own | ((data == 0) & ~sof)),
            Assert(~in_frame | (quiet <= BOUND)),
        ]
        return m


class LitPaddingWatchdog(FrameWatchdog):
    """Mutant: pads with a lit pixel."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        with m.If(self.padding):
            m.d.comb += internals(m)["data"].eq(1)
        return m


def inputs(wd):
    return [wd.pixels.valid, wd.pixels.payload.as_value()]


def test_watchdog_safe_and_bounded(tmp_path):
    wd = FrameWatchdog(W, H, BITS, TIMEOUT)
    result = prove(CheckedWatchdog(wd), "prove", DEPTH, tmp_path, ports=inputs(wd))
    assert result.passed, result.log


@pytest.mark.parametrize("make", [lambda: FrameWatchdog(W, H, BITS, TIMEOUT + 4),
                                  lambda: LitPaddingWatchdog(W, H, BITS, TIMEOUT)],
                         ids=["late", "lit"])
def test_watchdog_mutant_fails(tmp_path, make):
    wd = make()
    result = prove(CheckedWatchdog(wd), "bmc", DEPTH, tmp_path, ports=inputs(wd))
    assert result.failed, result.log
