"""Formal: the detector's output stage (``hdl.output.OutputStage``) keeps every frame's
records and its trailer in step, and returns to idle.

The feature engine's side is free: records offered on any clock (taken when the buffer is
ready), ``done`` on any clock with any trailer, reset on any clock.  The environment's
contract is assumed: a trailer's ``n_records`` counts the records taken since the previous
``done`` (not in a ``done`` clock: such a record, of a frame cut short, is nobody's) and
never exceeds ``record_capacity`` (= the buffer's depth, the detector's default).  The reader
follows the packetizer's discipline: it takes a trailer only when it owes no record, then
exactly that trailer's ``n_records`` records, at any pace.  An observer numbers the records
taken in (``wcount``) and out of the buffer (``pops``; the buffer keeps their order,
``test_buffers.py``) and remembers the trailer owed to the reader.  k-induction proves, with
helper invariants on the stage's sequence numbers and the buffer's state
(``docs/formal.md``):

* **sequencing**: a ``done`` either loses its trailer (``trailer_lost`` + 1, only while an
  earlier trailer is still owed) or owes exactly that trailer, which the reader then takes
  once, unchanged; the records the reader takes after it are exactly the ``n_records``
  taken in before that ``done``, in order (orphans of lost frames are never delivered);
* **bounded response**: while a trailer or a record is owed, the reader waits at most
  ``response_bound(record_depth)`` consecutive clocks for it, whatever the inputs;
* **return to idle**: with a reader that takes what it is owed at once, once
  ``idle_bound(record_depth)`` clocks have passed without a ``done`` or an offered record,
  nothing is owed and no trailer is held, after any frame, a truncated one included.

Both bounds are tight: one clock less fails (BMC).

Mutants: an output stage that forgets the orphans (its held trailer's records start right
after the last claimed one) breaks sequencing; one that never discards orphans breaks
bounded response and return to idle.
"""

from types import SimpleNamespace

import pytest
from amaranth import Elaboratable, Module, Mux, Signal, Value
from amaranth.hdl import Assert, Assume

from lodestar.hdl.layouts import trailer_layout
from lodestar.hdl.output import OutputStage, idle_bound

from .sby import available, elaborate, elaborate_submodule, internals, prove, submodule

pytestmark = pytest.mark.skipif(not available(), reason="yowasp-sby or yices-smt2 missing")

RECORD_BITS = 2


def response_bound(depth):
    """Consecutive clocks a reader may wait for an owed trailer or record: at most
    ``depth - 1`` orphans ahead of it read out and discarded (three clocks each,
    ``HalfWordFIFO``), then one clock.  Tight: the proof fails for one clock less."""
    return 3 * depth - 2


class CheckedOutput(Elaboratable):
    """``stage`` (an ``OutputStage`` or a mutant) under one ``check``: ``"sequencing"``,
    ``"response"`` or ``"idle"`` (whose reader takes what it is owed at once); ``helpers``:
    the induction's invariants (off for the mutants' BMC, so that a property fails, not a
    helper); ``slack``: clocks added to the bounds (the tightness checks)."""

    def __init__(self, stage, check, helpers=True, slack=0):
        self.stage, self.check, self.helpers, self.slack = stage, check, helpers, slack
        self.eager = check == "idle"

    def elaborate(self, platform):
        m = Module()
        st = self.stage
        depth = st.record_depth
        m.submodules.stage = unit = elaborate(st, platform)
        rfifo = submodule(unit, "record_fifo")
        fifo = elaborate_submodule(unit, "record_fifo", platform)
        seq = len(internals(unit)["wseq"])

        # ---- environment: the feature engine's contract, a packetizer-like reader ----------
        took = st.records_in.valid & st.records_in.ready
        popped = rfifo.r_en & rfifo.r_rdy
        wcount = Signal(seq)                  # records taken in so far (mod 2**seq)
        pops = Signal(seq)                    # records out of the buffer (delivered/dropped)
        idx = Signal(range(2 * depth + 2))    # records taken in since the last done
        m.d.sync += [wcount.eq(wcount + took), pops.eq(pops + popped)]
        with m.If(st.done):
            m.d.sync += idx.eq(0)
        with m.Else():
            m.d.sync += idx.eq(idx + took)
        m.d.comb += [Assume(~st.done | (st.trailer_in.n_records == idx)),
                     Assume(idx <= depth)]
        remaining = Signal(range(depth + 1))  # records the reader owes for its last trailer
        next_rec = Signal(seq)                # the record number it takes next
        tr_take = st.trailer.valid & st.trailer.ready
        rec_take = st.records.valid & st.records.ready
        m.d.comb += [Assume(~st.trailer.ready | (remaining == 0)),
                     Assume(~st.records.ready | (remaining != 0))]
        if self.eager:
            m.d.comb += [Assume(st.trailer.ready == (remaining == 0)),
                         Assume(st.records.ready == (remaining != 0))]

        # ---- observer: the trailer owed to the reader ------------------------------------
        lost_prev = Signal.like(st.trailer_lost)
        done_d = Signal()
        tr_d = Signal(trailer_layout())
        first_d = Signal(seq)
        m.d.sync += [lost_prev.eq(st.trailer_lost), done_d.eq(st.done), tr_d.eq(st.trailer_in),
                     first_d.eq(wcount - st.trailer_in.n_records[:seq])]
        lost_now = st.trailer_lost != lost_prev
        kept = done_d & ~lost_now
        owed = Signal()
        owed_tr = Signal(trailer_layout())
        owed_first = Signal(seq)
        owed_now = owed | kept                # a trailer is owed in this clock
        owed_tr_now = Signal(trailer_layout())
        owed_first_now = Signal(seq)
        m.d.comb += [owed_tr_now.eq(owed_tr), owed_first_now.eq(owed_first)]
        with m.If(kept):
            m.d.comb += [owed_tr_now.eq(tr_d), owed_first_now.eq(first_d)]
        m.d.sync += [owed.eq(owed_now & ~tr_take), owed_tr.eq(owed_tr_now),
                     owed_first.eq(owed_first_now)]
        with m.If(tr_take):
            m.d.sync += [remaining.eq(st.trailer.payload.n_records), next_rec.eq(owed_first_now)]
        with m.Elif(rec_take):
            m.d.sync += [remaining.eq(remaining - 1), next_rec.eq(next_rec + 1)]

        # ---- sequencing ------------------------------------------------------------------
        def sequencing():
            return [
                Assert((st.trailer_lost - lost_prev)[:len(lost_prev)] <= 1),
                Assert(~done_d | (lost_now == owed)),       # lost only while one is owed
                Assert(~lost_now | done_d),
                Assert(~tr_take | owed_now),
                Assert(~tr_take | (Value.cast(st.trailer.payload) == Value.cast(owed_tr_now))),
                Assert(~rec_take | (pops == next_rec)),
            ]

        # ---- bounded response: clocks the reader has waited for what it is owed -----------
        response = response_bound(depth) + self.slack
        waited = Signal(range(response + 2))
        starved = (((remaining == 0) & owed_now & ~st.trailer.valid)
                   | ((remaining != 0) & ~st.records.valid))
        m.d.sync += waited.eq(0)
        with m.If(starved):
            m.d.sync += waited.eq(waited + (waited <= response))

        # ---- return to idle (eager reader) -----------------------------------------------
        bound = idle_bound(depth) + self.slack
        quiet = Signal(range(bound + 1))      # clocks since the last done or record offered
        with m.If(st.done | st.records_in.valid):
            m.d.sync += quiet.eq(0)
        with m.Elif(quiet != bound):
            m.d.sync += quiet.eq(quiet + 1)

        # only the checked properties are built (a property built and not added warns
        # UnusedProperty); the observers of all three stay in the design
        checks = {
            "sequencing": sequencing,
            "response": lambda: [Assert(waited <= response)],
            "idle": lambda: [Assert((quiet != bound)
                                    | (~owed_now & (remaining == 0) & ~st.trailer.valid))],
        }
        m.d.comb += checks[self.check]()

        if self.helpers:
            obs = SimpleNamespace(owed=owed_now, first=owed_first_now, trailer=owed_tr_now,
                                  wcount=wcount, pops=pops, idx=idx, remaining=remaining,
                                  next_rec=next_rec)
            m.d.comb += self.invariants(internals(unit), rfifo, internals(fifo), obs)
        return m

    def invariants(self, s, rfifo, f, obs):
        """Helper invariants for the induction: the stage's (``s``) and its buffer's (``f``)
        internal state in terms of the observer's (``obs``)."""
        depth = self.stage.record_depth
        owed_now, owed_first_now, owed_tr_now = obs.owed, obs.first, obs.trailer
        wcount, pops, idx = obs.wcount, obs.pops, obs.idx
        remaining, next_rec = obs.remaining, obs.next_rec
        count, second, fetch = f["count"], f["second"], f["fetch"]
        held_valid, held_first, held = s["held_valid"], s["held_first"], s["held"]
        held_trailer = owed_tr_now              # == held (below), as a view
        wseq, rseq, claimed = s["wseq"], s["rseq"], s["claimed"]
        seq = len(wseq)

        def ahead(a, b):
            """Records from number ``a`` to number ``b`` (modulo ``2**seq``)."""
            return (b - a)[:seq]

        items = ahead(rseq, wseq)
        n_held = held_trailer.n_records[:seq]
        boundary = Mux(held_valid, held_first + n_held, claimed)[:seq]  # the last claim's end
        return [
            Assert(wseq == wcount), Assert(rseq == pops),
            Assert(items == count + second), Assert(count <= depth),
            Assert(~rfifo.r_rdy | (count != 0)), Assert(~fetch | ~rfifo.r_rdy),
            Assert(~fetch | (count != 0)),
            Assert(held_valid == owed_now),
            Assert(~held_valid | (held_first == owed_first_now)),
            Assert(~held_valid | (s["same"] == (claimed == held_first))),
            Assert(~held_valid | (held == Value.cast(owed_tr_now))),
            Assert((remaining == 0) | ((rseq == next_rec)
                                       & (claimed == (next_rec + remaining)[:seq]))),
            Assert((remaining != 0) | (rseq == claimed)),
            Assert(ahead(rseq, claimed) <= items),
            Assert(~held_valid | (held_trailer.n_records <= depth)),
            Assert(~held_valid | (ahead(rseq, held_first) >= ahead(rseq, claimed))),
            Assert(~held_valid | (ahead(rseq, held_first) <= items)),
            Assert(ahead(rseq, boundary) <= items),
            Assert(ahead(rseq, boundary) <= ahead(rseq, (wseq - idx)[:seq])),
            Assert(ahead(rseq, (wseq - idx)[:seq]) <= items),
        ]


class ForgetfulOutput(OutputStage):
    """Mutant: the held trailer's records start right after the last claimed one, so
    orphans are delivered as its records."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        s = internals(m)
        with m.If(self.done & ~s["held_valid"]):
            m.d.sync += [s["held_first"].eq(s["claimed"]), s["same"].eq(1)]
        return m


class HoardingOutput(OutputStage):
    """Mutant: orphans are never discarded."""

    def elaborate(self, platform):
        m = super().elaborate(platform)
        m.d.comb += submodule(m, "record_fifo").r_en.eq(self.records.valid & self.records.ready)
        return m


def inputs(stage):
    return [stage.records_in.valid, stage.records_in.payload, stage.done,
            stage.trailer_in.as_value(),
            stage.records.ready, stage.trailer.ready]


def run(tmp_path, stage, check, mode, depth, **options):
    wrapper = CheckedOutput(stage, check, helpers=mode == "prove", **options)
    return prove(wrapper, mode, depth, tmp_path, ports=inputs(stage))


@pytest.mark.parametrize("depth", [3, 4])
def test_sequencing(tmp_path, depth):
    result = run(tmp_path, OutputStage(RECORD_BITS, depth), "sequencing", "prove", 3)
    assert result.passed, result.log


def test_sequencing_mutant_fails(tmp_path):
    result = run(tmp_path, ForgetfulOutput(RECORD_BITS, 3), "sequencing", "bmc", 12)
    assert result.failed, result.log


# k-induction needs a trace as long as the bound and a little more
@pytest.mark.parametrize("depth, k", [(3, 11), pytest.param(4, 14, marks=pytest.mark.slow)])
@pytest.mark.parametrize("check", ["response", "idle"])
def test_bounded(tmp_path, check, depth, k):
    result = run(tmp_path, OutputStage(RECORD_BITS, depth), check, "prove", k)
    assert result.passed, result.log


@pytest.mark.parametrize("check", ["response", "idle"])
def test_bounded_mutant_fails(tmp_path, check):
    result = run(tmp_path, HoardingOutput(RECORD_BITS, 3), check, "bmc", 16)
    assert result.failed, result.log


@pytest.mark.parametrize("check", ["response", "idle"])
def test_bounds_are_tight(tmp_path, check):
    """One clock less than the stated bound is not enough."""
    result = run(tmp_path, OutputStage(RECORD_BITS, 3), check, "bmc", 16, slack=-1)
    assert result.failed, result.log
