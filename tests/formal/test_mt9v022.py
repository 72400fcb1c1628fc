"""Formal: the MT9V022 front end (``hdl.mt9v022.MT9V022Frontend``): its word aligner relocks,
and no pixel is delivered while unlocked.

The link is driven by a packet generator: 12-bit packets back to back, ``lanes`` bits per
clock (12: one packet per clock, the shortest trace; 6: the DE2-115 build's; 4, opt-in) at a
free bit offset chosen once, each packet's 10-bit word free and, on a free ``corrupt``
input, its start bit flipped (a framing error when locked); reset may rise on any clock.
BMC from reset proves (``docs/formal.md``):

* **relock**: once the aligner has locked on the packets' alignment and lost lock, it
  locks again within ``relock_bound(lanes)`` clocks of the last corrupted packet (tight),
  whatever the words (the blanking word 4, whose pattern also passes at a false
  alignment, included);
* **no pixel while unlocked**: a pixel is handed to the clock-domain crossing only while
  locked, and the first one after a loss of lock carries ``sof``, so a frame is never
  resumed in the middle.

The depth (``bmc_depth``) covers a lock from reset, a framing error and a full relock
window.  Mutants (12 lanes): an aligner that does not prefer its previous alignment when
relocking (relock fails with the blanking word) and one whose decoder keeps its frame across
a framing error (delivers pixels after the loss without a new frame start).

Phase training (``PhaseTrainer``, ``framed`` free, k-induction): while trained, the
``eye_width`` phases centred on ``tap`` were all error-free in the last sweep.  Mutant: the
phase set on the far side of the best run's end (BMC through a whole sweep).
"""

import gc
import warnings

import pytest
from amaranth import Cat, Elaboratable, Module, Mux, Signal
from amaranth.hdl import Assert, Assume, UnusedElaboratable

from lodestar.hdl.mt9v022 import (
    LOCK_PACKETS,
    PACKET_BITS,
    PIXEL_BITS,
    MT9V022Frontend,
    PhaseTrainer,
)

from .sby import (
    available,
    elaborate,
    elaborate_submodule,
    fsm_states,
    internals,
    prove,
    submodule,
)

pytestmark = pytest.mark.skipif(not available(), reason="yowasp-sby or yices-smt2 missing")


def elaborated(module, name, platform):
    """The named submodule of an elaborated ``Module`` as a ``Module``, elaborated in place
    unless a mutant already did."""
    sub = submodule(module, name)
    return sub if isinstance(sub, Module) else elaborate_submodule(module, name, platform)



def relock_bound(lanes=PACKET_BITS):
    """Clocks from the last corrupted packet until lock is regained: ``LOCK_PACKETS`` good
    packets at the previous alignment, a packet period that shifts the corrupted packet out
    of the bit window and one for the lock, ``12 / lanes`` clocks per packet period."""
    return (LOCK_PACKETS + 2) * (PACKET_BITS // lanes)


def bmc_depth(lanes):
    """BMC depth: a lock from reset (about ``relock_bound`` clocks), an error, the relock
    window and a few clocks to spare (26 clocks for 12 lanes)."""
    return 2 * relock_bound(lanes) + 6


class CheckedAligner(Elaboratable):
    """``frontend`` (``domain="sync"``) fed by the packet generator, under
    ``check``: ``"relock"`` or ``"pixels"``; ``slack``: clocks added to the relock bound."""

    def __init__(self, frontend, check, slack=0):
        self.frontend, self.check, self.slack = frontend, check, slack
        self.word = Signal(PIXEL_BITS)
        self.corrupt = Signal()
        self.offset = Signal(range(PACKET_BITS))

    def elaborate(self, platform):
        m = Module()
        fe = self.frontend
        m.submodules.frontend = unit = fe.elaborate(platform)
        cross = submodule(unit, "crossing")
        unit._named_submodules["crossing"] = (Module(), None)     # only its input is observed
        s = internals(elaborated(unit, "aligner", platform))
        locked = s["locked"]

        # ---- packet generator: packets back to back at a constant bit offset -------------
        lanes = fe.lanes
        period = PACKET_BITS // lanes                              # clocks per packet
        phase = Signal(range(period))
        m.d.sync += phase.eq(Mux(phase == period - 1, 0, phase + 1))
        load = phase == 0                                          # a new packet starts
        packet = Cat(~self.corrupt, self.word, 0)                  # start, LSB .. MSB, stop
        current, previous = Signal(PACKET_BITS), Signal(PACKET_BITS)
        with m.If(load):
            m.d.sync += [current.eq(packet), previous.eq(current)]
        first = Signal(init=1)
        offset_d = Signal.like(self.offset)
        m.d.sync += [first.eq(0), offset_d.eq(self.offset)]
        m.d.comb += [Assume(self.offset < PACKET_BITS), Assume(first | (self.offset == offset_d))]
        stream = Cat(Mux(load, current, previous), Mux(load, packet, current))  # earliest first
        chunk = Signal(lanes)
        with m.Switch(Cat(self.offset, phase)):
            for g in range(period):
                for r in range(PACKET_BITS):
                    with m.Case(r | (g << len(self.offset))):
                        start = PACKET_BITS + g * lanes - r
                        m.d.comb += chunk.eq(stream[start:start + lanes])
        m.d.comb += fe.bits.eq(Cat(*[chunk[lanes - 1 - j] for j in range(lanes)]))
        corrupted = load & self.corrupt

        # ---- relock: clocks without lock since the last corrupted packet, after a loss -----
        # of a lock on the packets' own alignment, ``offset + 11 + lanes`` modulo 12 (the
        # aligner's and the generator's phase counters both start at reset; crafted words
        # can also make a false alignment lock, which is not what relocking is about)
        had_lock = Signal()
        m.d.sync += had_lock.eq(had_lock | locked)
        true = Signal(range(PACKET_BITS))
        m.d.comb += true.eq((self.offset + (PACKET_BITS - 1 + lanes) % PACKET_BITS)
                            % PACKET_BITS)
        bound = relock_bound(lanes) + self.slack
        waiting = Signal(range(bound + 2))
        with m.If(corrupted | locked | ~had_lock | (s["lock_a"] != true)):
            m.d.sync += waiting.eq(0)
        with m.Elif(waiting <= bound):
            m.d.sync += waiting.eq(waiting + 1)

        # ---- pixels: none while unlocked; after a loss, the first one starts a frame -----
        pixels = cross.pixels
        delivered = pixels.valid
        was_locked = Signal()
        resumed = Signal()                # a pixel was delivered since the last loss of lock
        m.d.sync += was_locked.eq(locked)
        with m.If(was_locked & ~locked):
            m.d.sync += resumed.eq(0)
        with m.Elif(delivered):
            m.d.sync += resumed.eq(1)
        if self.check == "relock":
            m.d.comb += Assert(waiting <= bound)
        else:
            m.d.comb += [Assert(~delivered | locked),
                         Assert(~delivered | resumed | ~had_lock | pixels.payload.sof)]
        return m


class FickleAligner(MT9V022Frontend):
    """Mutant: relocking does not prefer the previous alignment (as at power-up)."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        aligner = elaborated(m, "aligner", platform)
        aligner.d.sync += internals(aligner)["relock"].eq(0)
        return m


class ResumingAligner(MT9V022Frontend):
    """Mutant: the decoder keeps its line (and held pixel) across a framing error."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        framing_error = submodule(m, "decoder").framing_error
        decoder = elaborated(m, "decoder", platform)
        s = internals(decoder)
        with decoder.If(framing_error):
            decoder.d.sync += [s["in_frame"].eq(s["in_frame"]), s["in_line"].eq(s["in_line"]),
                               s["held_valid"].eq(s["held_valid"])]
        return m


def frontend(cls=MT9V022Frontend, lanes=PACKET_BITS):
    return cls(4, 2, lanes=lanes, domain="sync")


def run(tmp_path, fe, check, **options):
    wrapper = CheckedAligner(fe, check, **options)
    with warnings.catch_warnings():
        # The front end, its aligner and decoder are elaborated by hand to reach their
        # internal signals, and the crossing is replaced: Amaranth cannot see them used.
        warnings.simplefilter("ignore", UnusedElaboratable)
        result = prove(wrapper, "bmc", bmc_depth(fe.lanes), tmp_path,
                       ports=[wrapper.word, wrapper.corrupt, wrapper.offset])
        del wrapper, fe
        gc.collect()
    return result


LANES = [12, 6, pytest.param(4, marks=pytest.mark.slow)]
"""12: one packet per clock; 6: the DE2-115 build's; 4: 68 clocks, opt-in."""


@pytest.mark.parametrize("lanes", LANES)
@pytest.mark.parametrize("check", ["relock", "pixels"])
def test_aligner(tmp_path, check, lanes):
    result = run(tmp_path, frontend(lanes=lanes), check)
    assert result.passed, result.log


def test_relock_mutant_fails(tmp_path):
    result = run(tmp_path, frontend(FickleAligner), "relock")
    assert result.failed, result.log


def test_pixels_mutant_fails(tmp_path):
    result = run(tmp_path, frontend(ResumingAligner), "pixels")
    assert result.failed, result.log


@pytest.mark.parametrize("lanes", LANES)
def test_relock_bound_is_tight(tmp_path, lanes):
    """One clock less than ``relock_bound(lanes)`` is not enough."""
    result = run(tmp_path, frontend(lanes=lanes), "relock", slack=-1)
    assert result.failed, result.log


# ---- phase training: the chosen phase is the centre of an error-free run ---------------------
TRAIN_TAPS = 4
"""Phases of the trainer's proof (4: a run of 3 has a centre other than its ends)."""


def all_good(good, phases):
    """``good`` has every phase of ``phases``."""
    ok = 1
    for p in phases:
        ok = ok & good[p]
    return ok


class CheckedTrainer(Elaboratable):
    """``trainer`` (``domain="sync"``, a ``PhaseTrainer`` or a mutant) with ``framed`` free:
    while ``trained``, the ``eye_width`` phases centred on ``tap`` (its upper middle) are
    all error-free in ``good``.  ``helpers``: the induction's invariants (off for the
    mutant's BMC)."""

    def __init__(self, trainer, helpers=True):
        self.trainer, self.helpers = trainer, helpers

    def elaborate(self, platform):
        m = Module()
        t = self.trainer
        T = t.taps
        m.submodules.trainer = unit = elaborate(t, platform)

        def centred(tap, width):
            return [(tap - width // 2 + k) % T for k in range(width)]
        for tap in range(T):
            for width in range(1, T + 1):
                at = t.trained & (t.tap == tap) & (t.eye_width == width)
                m.d.comb += Assert(~at | all_good(t.good, centred(tap, width)))
        m.d.comb += Assert(~t.trained | (t.eye_width != 0))
        if self.helpers:
            m.d.comb += self.invariants(unit, t)
        return m

    @staticmethod
    def invariants(unit, t):
        """The scan's run and best run are error-free phases ending before ``pos`` and at
        ``best_end``; in ``TRACK`` the phase is the best run's centre."""
        T = t.taps
        s = internals(unit)
        _, ongoing = fsm_states(unit)
        run, best, pos, best_end = s["run"], s["best"], s["pos"], s["best_end"]
        after = ongoing["SCAN"] | ongoing["CENTRE"] | ongoing["TRACK"]
        out = [Assert(run <= T), Assert(best <= T), Assert(pos < T), Assert(best_end < T),
               Assert(t.trained == ongoing["TRACK"]),
               Assert(~ongoing["TRACK"] | ((t.eye_width == best) & (best != 0)))]
        for end in range(T):
            for n in range(1, T + 1):
                ending = [(end - k) % T for k in range(n)]
                out.append(Assert(~(after & (best_end == end) & (best == n))
                                  | all_good(t.good, ending)))
                out.append(Assert(~(ongoing["SCAN"] & (pos == (end + 1) % T) & (run == n))
                                  | all_good(t.good, ending)))
                out.append(Assert(~(ongoing["TRACK"] & (best_end == end) & (best == n))
                                  | (t.tap == (end - (n - 1) // 2) % T)))
        return out


class OffCentreTrainer(PhaseTrainer):
    """Mutant: the phase goes the other way from the best run's end (past it)."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        s = internals(m)
        _, ongoing = fsm_states(m)
        best, best_end = s["best"], s["best_end"]
        back = (best - 1) >> 1
        with m.If(ongoing["CENTRE"] & (best != 0)):
            m.d.sync += self.tap.eq((best_end + back) % self.taps)
        return m


def trainer(cls=PhaseTrainer):
    """A small trainer: ``TRAIN_TAPS`` phases, one clock per packet, no settling, two
    packets checked per phase (a sweep of 44 clocks)."""
    return cls(TRAIN_TAPS, 1, "sync", settle=0, dwell_packets=2)


def test_trained_phase_is_the_centre_of_an_error_free_run(tmp_path):
    t = trainer()
    result = prove(CheckedTrainer(t), "prove", 3, tmp_path, ports=[t.framed])
    assert result.passed, result.log


def test_trained_phase_mutant_fails(tmp_path):
    t = trainer(OffCentreTrainer)
    result = prove(CheckedTrainer(t, helpers=False), "bmc", 60, tmp_path, ports=[t.framed])
    assert result.failed, result.log
