"""Formal: the labeller (``hdl.labeller.Labeller``) on small frames.

**Every beat taken or flagged** (``docs/formal.md``), k-induction: the input beats follow the
guarantee ``test_threshold.py`` proves for the threshold unit's output in fixed and global
mode (assumed here, with reset free as there): a beat's position is inside the frame, and
the beat after one at ``(W - 1, H - 1)`` is at ``(0, 0)``.  Then every beat is held (the
next clock the held pixel is that beat: it reaches the feature engine's ops) or, at the
clock it is decided or the next, the labeller ends a frame with ``FRAME_TRUNCATED`` (with
or without ``FRAME_LINE_ERROR``), or ``fault`` is up.  Exempt by design: beats while a frame
already ended that way is skipped (until its next ``(0, 0)``), and after a reset until the
first ``(0, 0)`` (the rest of a frame cut by the reset).  So ``IDLE``, ``GAP``, ``VROW`` and
``DRAIN`` never ignore a beat silently.  Pixel values and weights are 0 (they only ride
along).  Mutants: the successor check's row count wraps (for a power-of-two height the
next frame's ``(0, 0)`` right after the last pixel was held while the labeller went on to
its virtual row, and that frame's beats were then ignored: the bug this proof found), and
``DRAIN`` ignoring the next frame's ``(0, 0)``.

**Internal bounds** (BMC, ``--runslow``): ``fault`` (a slot, stack spill or non-empty stack
at a row end) never rises for any beat stream (any coordinates, ``lit``, ``eof``, valid
pattern, feature engine busy, resets) for ``DEPTH`` clocks: a whole 3x2 frame, its
blanking and the next frame's start (~2.5 min); mutant: a push stage that never pushes.
"""

import pytest
from amaranth import Const, Elaboratable, Module, Mux, Signal
from amaranth.hdl import Assert, Assume
from amaranth.lib import data

from lodestar import contract as C
from lodestar.hdl.labeller import Labeller
from lodestar.hdl.layouts import held_layout

from .sby import available, elaborate, fsm_states, internals, prove

pytestmark = pytest.mark.skipif(not available(), reason="yowasp-sby or yices-smt2 missing")

W, H, CAPACITY, DEPTH = 3, 2, 2, 22


class TakenOrFlagged(Elaboratable):
    """``lab`` (a ``Labeller`` or a mutant) under "every beat taken or flagged";
    ``helpers``: the induction's invariants (off for the mutants' BMC)."""

    def __init__(self, lab, helpers=True):
        self.lab, self.helpers = lab, helpers

    def elaborate(self, platform):
        m = Module()
        lab = self.lab
        W, H = lab.width, lab.height
        m.submodules.labeller = mod = elaborate(lab, platform)
        p, valid = lab.pixels.payload, lab.pixels.valid
        origin = (p.x == 0) & (p.y == 0)
        # the threshold unit's guarantee (test_threshold.py)
        after_last = Signal()             # the latest valid beat was at (W - 1, H - 1)
        with m.If(valid):
            m.d.sync += after_last.eq((p.x == W - 1) & (p.y == H - 1))
        m.d.comb += [Assume(~valid | ((p.x < W) & (p.y < H))),
                     Assume(~(valid & after_last) | origin),
                     Assume(p.data == 0), Assume(p.weight == 0)]
        # exemptions: after a reset until a (0, 0); a frame flagged and being skipped
        after_reset = Signal(init=1)
        with m.If(valid & origin):
            m.d.sync += after_reset.eq(0)
        flag = lab.done & ((lab.done_flags & C.FRAME_TRUNCATED) != 0)
        skipping = Signal()
        with m.If(lab.frame_start):
            m.d.sync += skipping.eq(0)
        with m.Elif(flag):
            m.d.sync += skipping.eq(1)
        # the beat in the labeller's input register (decided now), and a clock later
        beat = Signal.like(p)
        beat_valid, beat_origin, beat_exempt = Signal(), Signal(), Signal()
        m.d.sync += [beat.eq(p), beat_valid.eq(valid), beat_origin.eq(origin),
                     beat_exempt.eq(after_reset & ~origin)]
        last_x, last_y, last_valid, last_ok = (Signal.like(p.x), Signal.like(p.y), Signal(),
                                               Signal())
        m.d.sync += [last_x.eq(beat.x), last_y.eq(beat.y), last_valid.eq(beat_valid),
                     last_ok.eq(flag | lab.fault | beat_exempt | (skipping & ~beat_origin))]
        s = internals(mod)
        held = data.View(held_layout(C.bits_for(W - 1), C.bits_for(H), lab.pixel_bits),
                         s["held"])
        m.d.comb += Assert(~last_valid | last_ok | flag |
                           (held.valid & (held.x == last_x) & (held.y == last_y)))
        if self.helpers:
            m.d.comb += self.invariants(mod, s, held, beat, beat_valid, beat_origin,
                                        after_last, after_reset, skipping)
        return m

    def invariants(self, mod, s, held, beat, beat_valid, beat_origin, after_last, after_reset,
                   skipping):
        """The input register is the observer's copy; the FSM in a defined state; once a
        frame is over (a state between frames, or ``(W - 1, H - 1)`` just held) the beat
        in the input register, if any, is at ``(0, 0)``, and else the latest beat was the
        frame's last; ``SKIP`` exactly while a flagged frame is skipped; after a reset,
        ``IDLE``."""
        W, H = self.lab.width, self.lab.height
        state, st = fsm_states(mod)
        hv, hl = held.valid, held.last_col
        over = (st["IDLE"] | st["GAP"] | st["VROW"] | st["DRAIN"] |
                (st["RUN"] & hv & hl & (held.y == H - 1)))
        return [Assert(s["in_valid"] == beat_valid), Assert(s["in_beat"] == beat.as_value()),
                Assert(s["in_origin"] == beat_origin), Assert(state < len(st)),
                Assert(~hv | (hl == (held.x == W - 1))),
                Assert(~over | after_reset | Mux(beat_valid, beat_origin, after_last)),
                Assert(~after_reset | st["IDLE"]), Assert(skipping == st["SKIP"])]


class WrappingSuccessor(Labeller):
    """Mutant (the labeller before this proof): the successor check's ``y + 1`` wraps, so
    for a power-of-two height ``(0, 0)`` right after ``(W - 1, H - 1)`` is a successor."""

    def _input(self, m):
        out = super()._input(m)
        s, p = internals(m), self.pixels.payload
        wrapped = (s["prev_y"] + 1)[:len(p.y)]
        m.d.sync += s["in_successor"].eq(Mux(s["prev_last_col"], (p.x == 0) & (p.y == wrapped),
                                             (p.x == s["prev_next_x"]) & (p.y == s["prev_y"])))
        return out


class LateRestart(Labeller):
    """Mutant: ``DRAIN`` ignores the next frame's ``(0, 0)`` (waits to finish draining)."""

    def _frames(self, m, held, line_error):
        seq = super()._frames(m, held, line_error)
        s = internals(m)
        state, st = fsm_states(m)
        with m.If(st["DRAIN"] & s["in_valid"] & s["in_origin"]):
            m.d.comb += [seq.start.eq(0), s["take"].eq(0), s["abort"].eq(0)]
            m.d.sync += state.eq(state)
        return seq


class BoundedLabeller(Elaboratable):
    def __init__(self, labeller):
        self.labeller = labeller

    def elaborate(self, platform):
        m = Module()
        m.submodules.labeller = lab = self.labeller
        m.d.comb += [Assume(lab.pixels.payload.data == 0),
                     Assume(lab.pixels.payload.weight == 0),
                     Assert(~lab.fault)]
        return m


class ForgetfulLabeller(Labeller):
    """Mutant: the push stage never pushes a previous-row component on the stack."""

    def _push(self, m, above, parts):
        return super()._push(m, above, parts)._replace(push=Const(0))


def inputs(lab):
    return [lab.pixels.valid, lab.pixels.payload.as_value(), lab.feat_busy]


@pytest.mark.parametrize("size", [(W, H, CAPACITY), (4, 3, 2), (3, 4, 2), (752, 480, 8),
                                  (2592, 1944, 254)],
                         ids=lambda size: "{}x{}".format(*size[:2]))
def test_every_beat_taken_or_flagged(tmp_path, size):
    """Small frames, both parities of the height's power of two, and the sensors' sizes
    (the estcube2 build's label capacity at 2592): k-induction does not unroll frames."""
    w, h, capacity = size
    lab = Labeller(w, h, 12, capacity)
    result = prove(TakenOrFlagged(lab), "prove", 6, tmp_path, ports=inputs(lab))
    assert result.passed, result.log


@pytest.mark.parametrize("mutant", [WrappingSuccessor, LateRestart])
def test_every_beat_taken_or_flagged_mutant_fails(tmp_path, mutant):
    lab = mutant(W, H, 12, CAPACITY)
    result = prove(TakenOrFlagged(lab, helpers=False), "bmc", 24, tmp_path, ports=inputs(lab))
    assert result.failed, result.log


@pytest.mark.slow
def test_labeller_bounds(tmp_path):
    lab = Labeller(W, H, 12, CAPACITY)
    result = prove(BoundedLabeller(lab), "bmc", DEPTH, tmp_path, ports=inputs(lab))
    assert result.passed, result.log


@pytest.mark.slow
def test_labeller_bounds_mutant_fails(tmp_path):
    lab = ForgetfulLabeller(W, H, 12, CAPACITY)
    result = prove(BoundedLabeller(lab), "bmc", DEPTH, tmp_path, ports=inputs(lab))
    assert result.failed, result.log
