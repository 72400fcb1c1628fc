"""Formal: the threshold unit (``hdl.threshold.ThresholdUnit``) passes every pixel beat on,
and a frame's last position is followed by ``(0, 0)``.

Part of "every pixel beat taken or flagged" (``docs/formal.md``): the labeller ignores a beat
without a flag only outside a frame at a position other than ``(0, 0)``, and it leaves a
frame only after holding ``(W - 1, H - 1)``.  k-induction on a 3 x 2 unit, pixels, ``sof``,
``eol``, every register but ``mode`` and reset free (``mode`` is fixed or global: a local
frame's beats come through the delay line, not covered): every input beat comes out one
clock later and no other beat comes out, at a position inside the frame; the beat after
one at ``(W - 1, H - 1)`` is at ``(0, 0)`` (``test_labeller.py`` assumes exactly this).
Mutants: a unit whose column count runs on past the frame's last pixel, and one that drops
``sof`` beats.
"""

import pytest
from amaranth import Elaboratable, Module, Mux, Signal
from amaranth.hdl import Assert, Assume

from lodestar.hdl.layouts import ThresholdMode
from lodestar.hdl.threshold import ThresholdUnit

from .sby import available, internals, prove

pytestmark = pytest.mark.skipif(not available(), reason="yowasp-sby or yices-smt2 missing")

W, H, BITS = 3, 2, 8


class CheckedThreshold(Elaboratable):
    """``unit`` (a ``ThresholdUnit`` or a mutant) under the properties; ``helpers``: the
    induction's invariants (off for the mutants' BMC, so that a property fails)."""

    def __init__(self, unit, helpers=True):
        self.unit, self.helpers = unit, helpers

    def elaborate(self, platform):
        m = Module()
        th = self.unit
        m.submodules.unit = mod = th.elaborate(platform)
        out = th.out
        valid_d = Signal()
        after_last = Signal()            # the last beat out was at (W - 1, H - 1)
        m.d.sync += valid_d.eq(th.pixels.valid)
        last = (out.payload.x == W - 1) & (out.payload.y == H - 1)
        with m.If(out.valid):
            m.d.sync += after_last.eq(last)
        origin = (out.payload.x == 0) & (out.payload.y == 0)
        m.d.comb += Assume(th.mode != ThresholdMode.LOCAL)
        m.d.comb += [
            Assert(out.valid == valid_d),
            Assert(~out.valid | ((out.payload.x < W) & (out.payload.y < H))),
            Assert(~(out.valid & after_last) | origin),
        ]
        if self.helpers:
            m.d.comb += self.invariants(internals(mod), valid_d, last, after_last)
        return m

    def invariants(self, s, valid_d, last, after_last):
        """The position counters and an idle delay line (no local-mode frame)."""
        x, y = s["x"], s["y"]
        ended = Mux(valid_d, last, after_last)     # the latest input beat was the last
        return [Assert(x < W), Assert(y < H),
                Assert(s["x_last"] == (x == W - 1)), Assert(s["y_last"] == (y == H - 1)),
                Assert(~s["local_frame"]), Assert(s["unread"] == 0),
                *[Assert(~s[f"stage{k}_valid"]) for k in range(6)],
                Assert(~ended | ((x == 0) & (y == 0)))]


class RunOnUnit(ThresholdUnit):
    """Mutant: the column count runs on past the frame's last pixel."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        s, p = internals(m), self.pixels
        with m.If(p.valid & ~p.payload.sof & s["x_last"] & s["y_last"]):
            m.d.sync += s["x"].eq(s["x"] + 1)
        return m


class SofDroppingUnit(ThresholdUnit):
    """Mutant: a frame's first beat does not come out."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        with m.If(self.pixels.valid & self.pixels.payload.sof):
            m.d.sync += self.out.valid.eq(0)
        return m


def inputs(th):
    return [th.pixels.valid, th.pixels.payload.as_value(), th.mode.as_value(), th.threshold,
            th.background, th.ksigma, th.local_log2_window, th.local_offset]


def test_every_beat_out_and_wrap(tmp_path):
    th = ThresholdUnit(W, H, BITS)
    result = prove(CheckedThreshold(th), "prove", 4, tmp_path, ports=inputs(th))
    assert result.passed, result.log


@pytest.mark.parametrize("mutant", [RunOnUnit, SofDroppingUnit])
def test_mutant_fails(tmp_path, mutant):
    th = mutant(W, H, BITS)
    result = prove(CheckedThreshold(th, helpers=False), "bmc", 8, tmp_path, ports=inputs(th))
    assert result.failed, result.log
