"""Formal: the threshold unit (``hdl.threshold.ThresholdUnit``) passes every pixel beat on
or says it dropped it, and a frame's last position is followed by ``(0, 0)``.

Part of "every pixel beat taken or flagged" (``docs/formal.md``), both by k-induction with
pixels, ``sof``, ``eol``, every register and reset free:

* Fixed and global mode (3 x 2; ``mode`` never local): every input beat comes out one
  clock later and no other beat comes out, at a position inside the frame; the beat after
  one at ``(W - 1, H - 1)`` is at ``(0, 0)`` (``test_labeller.py`` assumes exactly this).
  Mutants: a unit whose column count runs on past the frame's last pixel, and one that
  drops ``sof`` beats.
* Local mode (any mode, frames from 3 x 2 to 2592 x 1944): every beat of a frame comes out
  (no beat comes out that did not go in), or the next ``sof`` discards it and
  ``frame_tail_dropped`` is high the clock after that ``sof`` (and low if nothing was
  discarded); after a local frame's last pixel every beat is out once
  ``local_blanking(log2 L)`` idle clocks have passed, and that bound is tight (one less
  fails, BMC).  Mutant: a unit that counts only the read stages, not the unread pixels, in
  ``frame_tail_dropped``.
* Local mode's output order (BMC, ``ORDER_DEPTH``, ``--runslow``, ~7 min): in any mode the
  output keeps the fixed/global guarantee above (positions inside the frame, ``(0, 0)``
  after ``(W - 1, H - 1)``), which ``test_labeller.py`` assumes.  Mutant: a ``sof`` that
  leaves a stale pixel in the delay line's stage 2.
"""

import pytest
from amaranth import Cat, Elaboratable, Module, Mux, Signal
from amaranth.hdl import Assert, Assume

from lodestar import contract as C
from lodestar.hdl.layouts import ThresholdMode
from lodestar.hdl.threshold import (
    ThresholdUnit,
    local_blanking,
    local_depth,
    local_log2_window_max,
)

from .sby import available, elaborate, elaborate_submodule, internals, prove

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
        m.submodules.unit = mod = elaborate(th, platform)
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
            delay = internals(elaborate_submodule(mod, "window", platform))
            m.d.comb += self.invariants(internals(mod), delay, valid_d, last, after_last)
        return m

    def invariants(self, s, delay, valid_d, last, after_last):
        """The position counters and an idle delay line (no local-mode frame)."""
        x, y = s["x"], s["y"]
        ended = Mux(valid_d, last, after_last)     # the latest input beat was the last
        return [Assert(x < W), Assert(y < H),
                Assert(s["x_last"] == (x == W - 1)), Assert(s["y_last"] == (y == H - 1)),
                Assert(~s["local_frame"]), Assert(delay["unread"] == 0),
                *[Assert(~delay[f"stage{k}_valid"]) for k in range(6)],
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


# ---- local mode: every beat of a frame comes out or its frame's tail is flagged ----------

class LocalCheckedThreshold(Elaboratable):
    """``unit`` in any mode, a local-mode frame's beats through the delay line.  An observer
    counts the beats owed (taken in, not yet out): in a local frame its beats from its
    ``sof`` through its last position (as the input counts positions: ``W`` per line or an
    ``eol``), in a fixed or global frame every beat.  Asserted: no beat comes out that is
    not owed; the clock after a ``sof``, ``frame_tail_dropped`` is high exactly if beats of
    the previous frames were still owed (not out by the ``sof``'s clock: the ``sof``
    discards them); after a local frame's last pixel, none is owed once
    ``local_blanking(log2 L)`` idle clocks have passed (its beats all come out by
    themselves, in the documented blanking)."""

    def __init__(self, unit, helpers=True, blanking=None):
        self.unit, self.helpers = unit, helpers
        lg_max = local_log2_window_max(unit.width)
        self.blanking = local_blanking(lg_max) if blanking is None else blanking

    def elaborate(self, platform):
        m = Module()
        th = self.unit
        W, H = th.width, th.height
        m.submodules.unit = mod = elaborate(th, platform)
        inp, out = th.pixels, th.out
        sof, eol = inp.payload.sof, inp.payload.eol
        sof_valid = inp.valid & sof
        # the input's positions and frames, as the contract counts them
        # (x, y like the unit's: not reset, the count runs on through a detector reset)
        x, y = Signal(range(W), reset_less=True), Signal(range(H), reset_less=True)
        in_frame = Signal()
        cur_x, cur_y = Mux(sof, 0, x), Mux(sof, 0, y)
        frame_end = inp.valid & (sof | in_frame) & (cur_x == W - 1) & (cur_y == H - 1)
        with m.If(inp.valid):
            with m.If((cur_x == W - 1) | eol):
                m.d.sync += [x.eq(0), y.eq(Mux(cur_y == H - 1, 0, cur_y + 1))]
            with m.Else():
                m.d.sync += [x.eq(cur_x + 1), y.eq(cur_y)]
        with m.If(sof_valid):
            m.d.sync += in_frame.eq(1)
        with m.Elif(frame_end):
            m.d.sync += in_frame.eq(0)
        # a frame is local if at its sof the mode is local and the window narrower than W
        lg_max = local_log2_window_max(W)
        window_ok = (th.local_log2_window >= C.LOCAL_LOG2_WINDOW_MIN) & \
            (th.local_log2_window <= lg_max)
        local = Signal()
        log2_window = Signal.like(th.local_log2_window, reset_less=True)
        with m.If(sof_valid):
            m.d.sync += [local.eq((th.mode == ThresholdMode.LOCAL) & window_ok),
                         log2_window.eq(th.local_log2_window)]
        local_now = Mux(sof, (th.mode == ThresholdMode.LOCAL) & window_ok, local)
        taken = inp.valid & (~local_now | sof | in_frame)
        owed = Signal(range(local_depth(W) + 8))     # at most the buffer and 7 stages
        left = owed - out.valid          # owed beats that did not come out by this clock
        m.d.sync += owed.eq(Mux(sof_valid, 0, left) + taken)
        after_sof, dropped = Signal(), Signal()
        m.d.sync += [after_sof.eq(sof_valid), dropped.eq(left != 0)]
        # clocks since a local frame's last pixel, no sof since (0: none or a sof since);
        # the bound is the widest window's (the narrower ones' are proved by the helpers)
        blanking = self.blanking
        since = Signal(range(blanking + 2))
        with m.If(sof_valid):
            m.d.sync += since.eq(0)
        with m.Elif(frame_end & local_now):
            m.d.sync += since.eq(1)
        with m.Elif((since != 0) & (since <= blanking)):
            m.d.sync += since.eq(since + 1)
        m.d.comb += [
            Assert(~out.valid | (owed != 0)),
            Assert(~after_sof | (th.frame_tail_dropped == dropped)),
            Assert((since <= blanking) | (left == 0)),
        ]
        if self.helpers:
            delay = internals(elaborate_submodule(mod, "window", platform))
            m.d.comb += self.invariants(internals(mod), delay, x, y, in_frame, local,
                                        log2_window, owed, since, out.valid)
        return m

    def invariants(self, s, delay, x, y, in_frame, local, log2_window, owed, since,
                   out_valid):
        """The observer's copies are the unit's; the beats owed are those unread and in
        the six stages; the delay line is idle outside a local frame, holds at most
        ``L + 1`` unread pixels, and after the frame's last pixel drains one per clock."""
        W, H = self.unit.width, self.unit.height
        stages = [delay[f"stage{k}_valid"] for k in range(6)]
        unread, row_ended = delay["unread"], delay["row_ended"]
        window = 1 << log2_window
        lg_max = local_log2_window_max(W)
        ended = since != 0
        return [
            Assert(s["x"] == x), Assert(s["y"] == y), Assert(s["in_frame"] == in_frame),
            Assert(s["x_last"] == (x == W - 1)), Assert(s["y_last"] == (y == H - 1)),
            Assert(s["local_frame"] == local), Assert(delay["log2_window"] == log2_window),
            Assert(owed == unread + sum(stages) + out_valid),
            Assert(local | ((unread == 0) & ~Cat(*stages).any())),
            Assert(~local | ((log2_window >= C.LOCAL_LOG2_WINDOW_MIN) &
                             (log2_window <= lg_max))),
            Assert(~local | (unread <= window + 1)), Assert(row_ended <= unread),
            Assert(delay["read_over"] == (unread > (1 << delay["log2_window"]))),
            Assert(delay["read_ended"] == (row_ended != 0)),
            Assert(~ended | (local & ~in_frame & (row_ended == unread))),
            Assert(~ended | (unread == 0) | (unread + since <= window + 2)),
            *[Assert(~ended | ~stage | (since <= window + k + 2))
              for k, stage in enumerate(stages)],
            Assert(~ended | ~out_valid | (since <= window + 8)),
        ]


class TailForgettingUnit(ThresholdUnit):
    """Mutant: a ``sof`` discards the delay line's unread pixels without saying so
    (``frame_tail_dropped`` counts only the pixels already in the read stages)."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        window = internals(elaborate_submodule(m, "window", platform))
        in_stages = Cat(*(window[f"stage{k}_valid"] for k in range(6))).any()
        with m.If(self.pixels.valid & self.pixels.payload.sof):
            m.d.sync += self.frame_tail_dropped.eq(in_stages)
        return m


@pytest.mark.parametrize("size", [(W, H, BITS), (5, 3, BITS), (9, 2, BITS), (752, 480, 10),
                                  (2592, 1944, 12)],
                         ids=lambda size: "{}x{}".format(*size[:2]))
def test_local_every_beat_out_or_tail_flagged(tmp_path, size):
    """Windows up to 2, 4, 8 and 128 pixels (the sensors' sizes): k-induction does not
    unroll frames."""
    th = ThresholdUnit(*size)
    result = prove(LocalCheckedThreshold(th), "prove", 6, tmp_path, ports=inputs(th))
    assert result.passed, result.log


def test_local_mutant_fails(tmp_path):
    th = TailForgettingUnit(W, H, BITS)
    result = prove(LocalCheckedThreshold(th, helpers=False), "bmc", 12, tmp_path,
                   ports=inputs(th))
    assert result.failed, result.log


def test_local_blanking_is_tight(tmp_path):
    th = ThresholdUnit(W, H, BITS)
    tight = local_blanking(local_log2_window_max(W)) - 1
    result = prove(LocalCheckedThreshold(th, helpers=False, blanking=tight), "bmc", 20,
                   tmp_path, ports=inputs(th))
    assert result.failed, result.log


# ---- local mode: the labeller's assumption on the output order (bounded) ---------------

ORDER_DEPTH = 30
"""A 3 x 2 local frame, its drain, the next frame's first beat out after the delay line."""


class OrderedThreshold(Elaboratable):
    """``unit`` in any mode (local included) under the fixed/global proof's output
    guarantee, which ``test_labeller.py`` assumes: positions inside the frame, and the beat
    after one at ``(W - 1, H - 1)`` at ``(0, 0)``.  Pixel values and every register but
    ``mode`` and ``local_log2_window`` are 0: they do not steer positions."""

    def __init__(self, unit):
        self.unit = unit

    def elaborate(self, platform):
        m = Module()
        th = self.unit
        W, H = th.width, th.height
        m.submodules.unit = elaborate(th, platform)
        out = th.out
        after_last = Signal()
        with m.If(out.valid):
            m.d.sync += after_last.eq((out.payload.x == W - 1) & (out.payload.y == H - 1))
        origin = (out.payload.x == 0) & (out.payload.y == 0)
        m.d.comb += [Assume(th.pixels.payload.data == 0), Assume(th.threshold == 0),
                     Assume(th.background == 0), Assume(th.ksigma == 0),
                     Assume(th.local_offset == 0),
                     Assert(~out.valid | ((out.payload.x < W) & (out.payload.y < H))),
                     Assert(~(out.valid & after_last) | origin)]
        return m


class StaleStageUnit(ThresholdUnit):
    """Mutant: a ``sof`` does not discard the pixel in the delay line's stage 2."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        window = elaborate_submodule(m, "window", platform)
        s = internals(window)
        window.d.sync += s["stage3_valid"].eq(s["stage2_valid"])
        return m


@pytest.mark.slow
def test_local_output_order(tmp_path):
    th = ThresholdUnit(W, H, BITS)
    result = prove(OrderedThreshold(th), "bmc", ORDER_DEPTH, tmp_path, ports=inputs(th),
                   timeout=1800)
    assert result.passed, result.log


def test_local_output_order_mutant_fails(tmp_path):
    th = StaleStageUnit(W, H, BITS)
    result = prove(OrderedThreshold(th), "bmc", ORDER_DEPTH, tmp_path, ports=inputs(th))
    assert result.failed, result.log
