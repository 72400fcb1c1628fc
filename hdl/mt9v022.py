"""MT9V022 stand-alone LVDS front end: the serial bit stream in, the detector's pixel stream
``pixel_layout(10)`` out in ``sync`` (the stream contract of :mod:`lodestar.hdl.frontend`).

The link carries one 12-bit packet per pixel clock (start bit ``1``, 10 data bits LSB first,
stop bit ``0``) with LINE_VALID/FRAME_VALID embedded as reserved words (0-3, and 1023, 0, 1023
for a frame start).  A Cyclone IV has no hard SERDES, so the front end takes ``lanes`` bits
per ``ser`` clock (``bits[lanes-1]`` earliest), finds the word boundary itself (lock on a
unique alignment; a framing error drops lock and the rest of its frame: :class:`WordAligner`),
decodes the reserved words (:class:`WordDecoder`) and crosses into ``sync`` through
:class:`lodestar.hdl.frontend.PixelCrossing` (sync clock >= pixel clock).  On a board, an
ALTLVDS_RX deserializes the link and clocks ``ser`` (:meth:`MT9V022Frontend.board_clocks`).
Datasheet sources, the points not yet verified, decoding and lock rules:
``docs/sensors_and_link.md`` (MT9V022).
"""

from amaranth import Array, Cat, ClockDomain, ClockSignal, Const, Instance, Module, Mux, Signal
from amaranth.lib import stream, wiring
from amaranth.lib.cdc import FFSynchronizer
from amaranth.lib.wiring import In, Out

from lodestar import contract as C
from lodestar.hdl.frontend import (
    FIFO_DEPTH,
    SensorFrontend,
    clock_output,
    crossing_constraints,
    gray_skew_constraints,
    input_buffer,
)
from lodestar.hdl.threshold import pixel_layout

PIXEL_BITS = C.SENSOR_PIXEL_BITS["mt9v022"]
"""MT9V022 pixel width (the contract's ``SENSOR_PIXEL_BITS``)."""
PACKET_BITS = PIXEL_BITS + 2
"""Start bit, the pixel's bits LSB first, stop bit."""
FULL = C.full_scale(PIXEL_BITS)
"""1023: first and last word of the frame-start sequence."""
FRAME_START_MIDDLE = 0
LINE_START = 1
LINE_END = 2
FRAME_END = 3
RESERVED_WORDS = 4
"""Words 0 .. 3 are reserved (control); pixel data on the link is always >= 4."""

LOCK_PACKETS = 8
"""Consecutive well-framed packets an alignment needs before it may be locked on."""
ERROR_COUNT_BITS = 16
"""Width of the saturating framing-error counter."""
ACTIVE_CLOCKS = 64
"""Oscillator clocks within which the returned LVDS clock must show an edge (seen through a
toggle flip-flop it clocks) to count as running (:class:`ReceiverPllReset`)."""
LOCK_TIMEOUT_CLOCKS = 1 << 17
"""Oscillator clocks the receiver's PLL gets to lock after its reset is released (2.6 ms at
50 MHz, over twice the Cyclone IV PLL's 1 ms lock time) before it is reset and retried."""
LVDS_LANES = 6
"""Bits per ``ser`` clock from the board's LVDS deserializer (ALTLVDS_RX, factor 6)."""


def packet_bits(word):
    """The 12 bits of one packet in transmission order (start, LSB .. MSB, stop)."""
    return [1] + [(word >> i) & 1 for i in range(PIXEL_BITS)] + [0]



class WordAligner(wiring.Component):
    """Finds the packets' word boundary in the bit stream and hands over their words.

    All candidate alignments are checked in parallel; lock is taken on a unique one after
    ``LOCK_PACKETS`` well-framed packets (the previous alignment preferred when relocking),
    and a framing error at the locked alignment drops it.  Everything is in ``domain``.

    Parameters
    ----------
    lanes : int
        Bits per clock; divides ``PACKET_BITS``.
    domain : str
        The bit clock domain.

    Members
    -------
    bits : ``In(lanes)``
        The link's bits, ``bits[lanes-1]`` earliest.
    words : ``Out(stream.Signature(PIXEL_BITS, always_ready=True))``
        A well-framed packet's word at the locked alignment (combinational).
    framing_error : ``Out(1)``
        The packet at the locked alignment is badly framed (lock is lost).
    locked : ``Out(1)``
        Locked on an alignment.
    framed : ``Out(1)``
        Some alignment has passed its last ``LOCK_PACKETS`` framing checks, lock or not
        (on the blanking stream alone two alignments may: :class:`PhaseTrainer` needs no
        lock).
    forget : ``In(1)``
        Drop lock and the preferred alignment (a lock taken while the sample phase was
        being swept may be a false one); the next lock needs a unique alignment.
    """

    def __init__(self, lanes, domain):
        self.lanes, self.domain = lanes, domain
        super().__init__({
            "bits": In(lanes),
            "words": Out(stream.Signature(PIXEL_BITS, always_ready=True)),
            "framing_error": Out(1),
            "locked": Out(1),
            "framed": Out(1),
            "forget": In(1),
        })

    def elaborate(self, platform):
        m = Module()
        ser = self.domain
        L = self.lanes
        P = PACKET_BITS // L           # ser clocks per packet

        # ---- bit window: sr[0] is the oldest bit, sr[-1] the newest ----------------------
        sr = Signal(PACKET_BITS + L - 1)
        m.d[ser] += sr.eq(Cat(sr[L:], *[self.bits[L - 1 - j] for j in range(L)]))
        # A packet ending at any of the L newest bits starts at s = 0 .. L-1.
        good = [sr[s] & ~sr[s + PACKET_BITS - 1] for s in range(L)]
        words = [sr[s + 1:s + 1 + PIXEL_BITS] for s in range(L)]
        ph = Signal(range(P))          # which of the P clocks of a packet period this is
        m.d[ser] += ph.eq(Mux(ph == P - 1, 0, ph + 1))

        # ---- candidate alignments a = phase * L + s, checked in parallel -----------------
        runs = [Signal(range(LOCK_PACKETS + 1), name=f"run{a}") for a in range(PACKET_BITS)]
        nexts = [Signal.like(r, name=f"run{a}_next") for a, r in enumerate(runs)]
        for r, n in zip(runs, nexts):
            m.d.comb += n.eq(r)
        with m.Switch(ph):
            for p in range(P):
                with m.Case(p):
                    for s in range(L):
                        r, n = runs[p * L + s], nexts[p * L + s]
                        m.d.comb += n.eq(Mux(good[s], Mux(r == LOCK_PACKETS, r, r + 1), 0))
        # The lock decision looks at the updated runs, so a lock taken on this clock's checks
        # is in force for the next clock's packet.
        sat = Cat(*[n == LOCK_PACKETS for n in nexts])
        m.d.comb += self.framed.eq(sat != 0)
        # Runs grow in step (each candidate is checked once per packet period), so a rival
        # that passed as long as the first saturated candidate has at least LOCK_PACKETS - 1.
        near = Cat(*[n >= LOCK_PACKETS - 1 for n in nexts])
        unique = (sat == near) & (sat != 0) & ((sat & (sat - 1)) == 0)
        which = Signal(range(PACKET_BITS))
        for a in range(PACKET_BITS):
            with m.If(sat[a]):
                m.d.comb += which.eq(a)

        locked = self.locked
        relock = Signal()              # lock_a was locked before: preferred when it qualifies
        lock_a = Signal(range(PACKET_BITS))
        lock_p = Array([a // L for a in range(PACKET_BITS)])[lock_a]
        lock_s = Array([a % L for a in range(PACKET_BITS)])[lock_a]
        at_word = locked & (ph == lock_p)
        word_good = Array(good)[lock_s]
        m.d.comb += [self.words.valid.eq(at_word & word_good),
                     self.words.payload.eq(Array(words)[lock_s]),
                     self.framing_error.eq(at_word & ~word_good)]
        with m.If(~locked):
            with m.If(relock & sat.bit_select(lock_a, 1)):
                m.d[ser] += locked.eq(1)
            with m.Elif(unique):
                m.d[ser] += [locked.eq(1), relock.eq(1), lock_a.eq(which)]
        with m.If(self.framing_error):
            # Lose lock and restart every candidate, so that the locked alignment competes
            # again on equal terms with alignments that only pass on the blanking pattern.
            m.d[ser] += [locked.eq(0)] + [r.eq(0) for r in runs]
        with m.Else():
            m.d[ser] += [r.eq(n) for r, n in zip(runs, nexts)]
        with m.If(self.forget):
            m.d[ser] += [locked.eq(0), relock.eq(0)]
        return m


class PhaseTrainer(wiring.Component):
    """Sample-phase training for a receiver without DPA (Cyclone IV): steps the sample
    point through ``taps`` phases of a bit, counts per phase the clocks at which no
    alignment is well framed (:class:`WordAligner`'s ``framed``, which the blanking
    stream's fixed words keep high at a phase inside the eye), centres the sample point in
    the widest error-free run of phases (circular: the eye may straddle the bit clock's
    edge) and retrains when ``framed`` stays low for ``dwell`` clocks.  On the board a
    phase is one dynamic phase step of the receiver PLL's sampling clock (ALTPLL
    ``phasestep``; ``docs/gateware.md``, MT9V022); in simulation it selects a tap of an
    oversampled stream.  Everything in ``domain``.

    Parameters
    ----------
    taps : int
        Sample phases per bit (>= 2).
    packet_clocks : int
        Clocks per packet (``PACKET_BITS // lanes``).
    domain : str
        The bit clock domain.
    settle : int
        Clocks from a ``tap`` change to its first sample at the aligner.
    dwell_packets : int
        Packets each phase is checked for (and without a framed alignment before a
        retraining).

    Members
    -------
    framed : ``In(1)``
        The aligner's ``framed``.
    tap : ``Out(range(taps))``
        The sample phase.
    trained : ``Out(1)``
        ``tap`` is the centre of an error-free run of ``eye_width`` phases.
    forget : ``Out(1)``
        A training ends: the aligner's lock and preferred alignment are dropped (its
        ``forget``).
    eye_width : ``Out(range(taps + 1))``
        Error-free phases found by the last training (held while retraining).
    good : ``Out(taps)``
        The last sweep's error-free phases.
    """

    def __init__(self, taps, packet_clocks, domain, settle=4, dwell_packets=4 * LOCK_PACKETS):
        if taps < 2 or packet_clocks < 1 or dwell_packets < 1:
            raise ValueError(f"PhaseTrainer needs taps >= 2, packet_clocks >= 1 and "
                             f"dwell_packets >= 1, got {taps}, {packet_clocks}, "
                             f"{dwell_packets}")
        self.taps, self.domain = taps, domain
        self.warmup, self.dwell = self.timing(packet_clocks, settle, dwell_packets)
        super().__init__({"framed": In(1), "tap": Out(range(taps)), "trained": Out(1),
                          "forget": Out(1), "eye_width": Out(range(taps + 1)),
                          "good": Out(taps)})

    @staticmethod
    def timing(packet_clocks, settle=4, dwell_packets=4 * LOCK_PACKETS):
        """``(warmup, dwell)``: clocks at a new phase before its check (the receiver's
        ``settle`` and the aligner's runs rebuilt), and clocks checked (``dwell_packets``;
        also the clocks without a framed alignment that start a retraining).  A training
        takes ``taps (warmup + dwell) + 2 taps + 1`` clocks."""
        return settle + (LOCK_PACKETS + 1) * packet_clocks, dwell_packets * packet_clocks

    def elaborate(self, platform):
        m = Module()
        d, T = m.d[self.domain], self.taps
        count = Signal(range(max(self.warmup, self.dwell) + 1), name="count")
        bad = Signal(name="bad")              # the phase under test failed a check
        scan = Signal(range(2 * T), name="scan")  # phases scanned twice (the run may wrap)
        pos = Signal(range(T), name="pos")    # scan mod T
        run = Signal(range(T + 1), name="run")    # error-free phases ending before pos
        best = Signal(range(T + 1), name="best")
        best_end = Signal(range(T), name="best_end")  # the widest run's last phase
        with m.FSM(domain=self.domain):
            with m.State("WARMUP"):
                d += count.eq(count + 1)
                with m.If(count == self.warmup - 1):
                    d += [count.eq(0), bad.eq(0)]
                    m.next = "DWELL"
            with m.State("DWELL"):
                d += [count.eq(count + 1), bad.eq(bad | ~self.framed)]
                with m.If(count == self.dwell - 1):
                    d += [count.eq(0), self.good.bit_select(self.tap, 1).eq(~bad & self.framed)]
                    with m.If(self.tap == T - 1):
                        d += [scan.eq(0), pos.eq(0), run.eq(0), best.eq(0)]
                        m.next = "SCAN"
                    with m.Else():
                        d += self.tap.eq(self.tap + 1)
                        m.next = "WARMUP"
            with m.State("SCAN"):
                run_next = Mux(self.good.bit_select(pos, 1), Mux(run == T, T, run + 1), 0)
                d += [run.eq(run_next), scan.eq(scan + 1), pos.eq(Mux(pos == T - 1, 0, pos + 1))]
                with m.If(run_next > best):
                    d += [best.eq(run_next), best_end.eq(pos)]
                with m.If(scan == 2 * T - 1):
                    m.next = "CENTRE"
            with m.State("CENTRE"):
                back = (best - 1) >> 1            # the run's centre, best_end - back (mod T)
                with m.If(best == 0):             # no eye: sweep again
                    d += self.tap.eq(0)
                    m.next = "WARMUP"
                with m.Else():
                    d += [self.tap.eq(Mux(best_end >= back, best_end - back,
                                          best_end + T - back)),
                          self.eye_width.eq(best), self.trained.eq(1)]
                    m.d.comb += self.forget.eq(1)
                    m.next = "TRACK"
            with m.State("TRACK"):                # lost: no alignment framed for dwell
                d += count.eq(Mux(self.framed, 0, count + 1))
                with m.If(count == self.dwell - 1):
                    d += [count.eq(0), self.tap.eq(0), self.trained.eq(0)]
                    m.next = "WARMUP"
        return m


class WordDecoder(wiring.Component):
    """The link's words to pixels: the reserved words (0-3, and 1023, 0, 1023 for a frame
    start) mark lines and frames; a pixel is held until the next word tells whether it ends
    its line.  A framing error abandons the frame until the next frame start.  Everything is
    in ``domain``.

    Parameters
    ----------
    domain : str
        The bit clock domain.

    Members
    -------
    words : ``In(stream.Signature(PIXEL_BITS, always_ready=True))``
        The aligned words (:class:`WordAligner`).
    framing_error : ``In(1)``
        The aligner's framing error.
    pixels : ``Out(stream.Signature(pixel_layout(PIXEL_BITS), always_ready=True))``
        The frame's pixels, raster order, ``sof`` and ``eol`` marked.
    """

    def __init__(self, domain):
        self.domain = domain
        super().__init__({
            "words": In(stream.Signature(PIXEL_BITS, always_ready=True)),
            "framing_error": In(1),
            "pixels": Out(stream.Signature(pixel_layout(PIXEL_BITS), always_ready=True)),
        })

    def elaborate(self, platform):
        m = Module()
        ser = self.domain
        word, word_valid = self.words.payload, self.words.valid
        prev1 = Signal(PIXEL_BITS)
        prev2 = Signal(PIXEL_BITS)
        in_frame = Signal()
        in_line = Signal()
        sof_next = Signal()            # the next pixel is the frame's first
        held = Signal(PIXEL_BITS)
        held_valid = Signal()
        held_sof = Signal()
        reserved = word < RESERVED_WORDS
        frame_start = (prev2 == FULL) & (prev1 == FRAME_START_MIDDLE) & (word == FULL)
        m.d.comb += [
            self.pixels.valid.eq(word_valid & held_valid),
            self.pixels.payload.data.eq(held),
            self.pixels.payload.sof.eq(held_sof),
            self.pixels.payload.eol.eq(reserved),
        ]
        with m.If(word_valid):
            m.d[ser] += [prev1.eq(word), prev2.eq(prev1), held_valid.eq(0)]
            with m.If(reserved):
                m.d[ser] += in_line.eq(in_frame & (word == LINE_START))
                with m.If(word == FRAME_END):
                    m.d[ser] += in_frame.eq(0)
            with m.Elif(frame_start):
                m.d[ser] += [in_frame.eq(1), sof_next.eq(1)]
            with m.Elif(in_line):
                m.d[ser] += [held.eq(word), held_valid.eq(1), held_sof.eq(sof_next),
                             sof_next.eq(0)]
        with m.Elif(self.framing_error):    # abandon the frame; wait for the next frame start
            m.d[ser] += [in_frame.eq(0), in_line.eq(0), held_valid.eq(0),
                         prev1.eq(0), prev2.eq(0)]
        return m


class ReceiverPllReset(wiring.Component):
    """``pll_areset`` of the LVDS receiver's PLL, whose input clock (the sensor's returned
    LVDS clock) only starts once the MCU enables the sensor's LVDS: held in reset while that
    clock is not running, released once it has run for ``active_clocks``, and reset again
    (a retry) if the PLL has not locked ``lock_timeout`` clocks later or whenever the clock
    stops.  Everything in the always-running ``osc`` domain.

    Parameters
    ----------
    active_clocks : int
        Clocks within which a running clock shows an edge of ``toggle``.
    lock_timeout : int
        Clocks the PLL gets to lock after each release.

    Members
    -------
    toggle : ``In(1)``
        A flip-flop the returned clock toggles, synchronized into ``osc``.
    locked : ``In(1)``
        The receiver PLL's ``rx_locked``, synchronized into ``osc``.
    areset : ``Out(1, init=1)``
        The PLL's ``pll_areset``.
    retries : ``Out(8)``
        Releases that timed out (saturating), for bring-up.
    """

    def __init__(self, active_clocks=ACTIVE_CLOCKS, lock_timeout=LOCK_TIMEOUT_CLOCKS):
        if active_clocks < 2 or lock_timeout < 1:
            raise ValueError("active_clocks must be >= 2 and lock_timeout >= 1")
        self.active_clocks, self.lock_timeout = active_clocks, lock_timeout
        super().__init__({"toggle": In(1), "locked": In(1), "areset": Out(1, init=1),
                          "retries": Out(8)})

    def elaborate(self, platform):
        m = Module()
        last = Signal()
        quiet = Signal(range(self.active_clocks + 1))     # clocks since the last edge
        running = Signal(range(self.active_clocks + 1))   # clocks the clock has run
        m.d.osc += last.eq(self.toggle)
        edge = self.toggle != last
        active = quiet < self.active_clocks
        with m.If(edge):
            m.d.osc += quiet.eq(0)
        with m.Elif(active):
            m.d.osc += quiet.eq(quiet + 1)
        with m.If(~active):
            m.d.osc += running.eq(0)
        with m.Elif(running != self.active_clocks):
            m.d.osc += running.eq(running + 1)
        waited = Signal(range(self.lock_timeout + 1))
        with m.If(~active):
            m.d.osc += [self.areset.eq(1), waited.eq(0)]
        with m.Elif(self.areset):
            with m.If(running == self.active_clocks):
                m.d.osc += [self.areset.eq(0), waited.eq(0)]
        with m.Elif(~self.locked):
            with m.If(waited == self.lock_timeout - 1):
                m.d.osc += [self.areset.eq(1), waited.eq(0),
                            self.retries.eq(Mux(self.retries == 0xFF, 0xFF, self.retries + 1))]
            with m.Else():
                m.d.osc += waited.eq(waited + 1)
        with m.Else():
            m.d.osc += waited.eq(0)
        return m


PHASE_STEP_TIMEOUT = 32
"""Scan clocks a dynamic phase step waits for each edge of the PLL's ``phasedone`` (low once
the step is taken, high once it is applied) before it is given up (:class:`PhaseStepper`)."""
PHASE_COUNTER_ALL = 0b000
"""ALTPLL ``phasecounterselect`` of Cyclone IV selecting all output counters (the fast,
slow and enable clocks of the receiver move together)."""


class PhaseStepper(wiring.Component):
    """The receiver PLL's sampling phase moved to :class:`PhaseTrainer`'s ``tap`` through the
    Cyclone IV ALTPLL dynamic phase shift (``phasestep``, ``phaseupdown``,
    ``phasecounterselect``, ``phasedone``; one step is 1/8 of the VCO period, so a bit is
    ``taps = 8 f_vco / bit rate`` steps).  It keeps ``phase``, the taps stepped since the
    PLL's reset, and steps up (``(tap - phase) mod taps`` steps) until it equals ``tap``.
    One step (Cyclone IV PLL handbook, "Dynamic Phase Shifting"): ``phaseupdown`` and
    ``phasecounterselect`` held, ``phasestep`` high for at least two scan clocks and until
    ``phasedone`` is seen low, then ``phasedone`` high.  Each wait is bounded by ``timeout``
    clocks; a step whose edge never comes is counted in ``timeouts`` and taken as done (the
    trainer's sweep then finds no eye or an offset one, and retrains).  Everything in
    ``domain`` (the PLL's ``scanclk``, at most 100 MHz).

    ``tap`` comes from the trainer's clock domain through a synchronizer; a target is taken
    only when two successive samples agree (any number of its bits may change, the trainer
    holds a tap for :meth:`settle_clocks` and more).  ``phasedone`` rises asynchronously and
    is synchronized (two flip-flops): its low time must be at least a scan clock, or the
    step times out.

    Members
    -------
    tap : ``In(range(taps))``
        The trainer's tap (any domain).
    hold : ``In(1)``
        The PLL is in reset or not locked: it returns to its configured phase, ``phase`` to
        0, and no step is issued.
    phasedone : ``In(1)``
        The PLL's ``phasedone``.
    phasestep, phaseupdown : ``Out(1)``; phasecounterselect : ``Out(3)``
        To the PLL (``phaseupdown`` 1: up; all output counters).
    phase : ``Out(range(taps))``
        Taps stepped (modulo ``taps``).
    timeouts : ``Out(8)``
        Steps given up (saturating), for bring-up.
    """

    def __init__(self, taps, domain="osc", timeout=PHASE_STEP_TIMEOUT):
        if taps < 2 or timeout < 2:
            raise ValueError(f"PhaseStepper needs taps >= 2 and timeout >= 2, got {taps}, "
                             f"{timeout}")
        self.taps, self.domain, self.timeout = taps, domain, timeout
        super().__init__({"tap": In(range(taps)), "hold": In(1), "phasedone": In(1),
                          "phasestep": Out(1), "phaseupdown": Out(1), "phasecounterselect": Out(3),
                          "phase": Out(range(taps)), "timeouts": Out(8)})

    @staticmethod
    def settle_bound(taps, timeout=PHASE_STEP_TIMEOUT):
        """Most scan clocks from a ``tap`` change to ``phase`` equal to it: the synchronizer
        and the agreeing sample, then up to ``taps - 1`` steps of at most ``2 timeout + 1``
        clocks each (leaving idle to idle again)."""
        return 4 + (taps - 1) * (2 * timeout + 1)

    def settle_clocks(self):
        """:meth:`settle_bound` of this stepper."""
        return self.settle_bound(self.taps, self.timeout)

    def elaborate(self, platform):
        m = Module()
        d = m.d[self.domain]
        target, last, done = Signal.like(self.tap), Signal.like(self.tap), Signal(init=1)
        m.submodules.tap_cdc = FFSynchronizer(self.tap, target, o_domain=self.domain)
        m.submodules.done_cdc = FFSynchronizer(self.phasedone, done, o_domain=self.domain,
                                               init=1)
        d += last.eq(target)
        count = Signal(range(self.timeout), name="step_count")
        given_up = Mux(self.timeouts == 0xFF, 0xFF, self.timeouts + 1)
        m.d.comb += [self.phaseupdown.eq(1), self.phasecounterselect.eq(PHASE_COUNTER_ALL)]
        next_phase = Mux(self.phase == self.taps - 1, 0, self.phase + 1)
        with m.FSM(domain=self.domain):
            with m.State("IDLE"):
                with m.If(self.hold):
                    d += self.phase.eq(0)
                with m.Elif((target == last) & (target != self.phase)):
                    d += [self.phasestep.eq(1), count.eq(0)]
                    m.next = "STEP"
            with m.State("STEP"):             # phasestep high: until phasedone is seen low
                d += count.eq(count + 1)
                with m.If(self.hold | ((count != 0) & ~done) | (count == self.timeout - 1)):
                    d += [self.phasestep.eq(0), count.eq(0)]
                    with m.If(done & ~self.hold):
                        d += self.timeouts.eq(given_up)
                    m.next = "WAIT"
            with m.State("WAIT"):             # phasestep low: until phasedone is high again
                d += count.eq(count + 1)
                with m.If(self.hold):
                    d += self.phase.eq(0)
                    m.next = "IDLE"
                with m.Elif(done | (count == self.timeout - 1)):
                    d += self.phase.eq(next_phase)
                    with m.If(~done):
                        d += self.timeouts.eq(given_up)
                    m.next = "IDLE"
        return m


class MT9V022Frontend(SensorFrontend):
    """MT9V022 LVDS bits, ``lanes`` per ``domain`` clock, to the detector's pixel stream in
    ``sync``: :class:`WordAligner`, :class:`WordDecoder`, then the crossing.  See
    ``docs/sensors_and_link.md`` (MT9V022).

    Parameters
    ----------
    width, height : int
        The programmed frame, not enforced.
    lanes : int
        Bits per ``domain`` clock; divides ``PACKET_BITS``.
    domain : str
        The bit clock domain.
    fifo_depth : int
        Entries of the crossing's FIFO.
    taps : int
        Sample phases per bit the receiver can select (1: a fixed phase, no training).
    settle : int
        ``domain`` clocks from a ``tap`` change to its first sample (the board's
        :class:`PhaseStepper` moving the receiver's phase: :meth:`PhaseStepper.settle_bound`).

    Members
    -------
    bits : ``In(lanes)``
        The link's bits, ``bits[lanes-1]`` earliest, in ``domain``.
    locked : ``Out(1)``
        The aligner is locked (``sync``, synchronized).
    framing_errors : ``Out(ERROR_COUNT_BITS)``
        Saturating count of framing errors (``sync``, through a Gray code).
    tap, trained, eye_width : ``Out``, with ``taps`` > 1
        :class:`PhaseTrainer`'s: ``tap`` in ``domain`` (to the receiver's sampling phase);
        ``trained`` synchronized into ``sync``, ``eye_width`` too (it changes only while
        ``trained`` is low, so read it while ``trained``).  Words reach the decoder only
        while trained.
    out, overflow, overflow_clear, fifo_level
        As :class:`lodestar.hdl.frontend.SensorFrontend`.
    """

    SENSOR = "mt9v022"
    PIXEL_BITS = PIXEL_BITS
    IO_VOLTS = (3.0, 3.6)
    MASTER_CLOCK_MAX_HZ = 26.6e6
    """SYSCLK at most 26.6 MHz (datasheet; ``docs/sensors_and_link.md``, MT9V022)."""
    """VDD 3.3 V +- 0.3 V (datasheet)."""
    LVDS_PINS = ("ser_clk", "ser_data")
    PHASE_TRAINING = True
    CLOCK_PINS = ("ser_clk",)

    def __init__(self, width, height, *, lanes=LVDS_LANES, domain="ser",
                 fifo_depth=FIFO_DEPTH, taps=1, settle=4):
        if lanes < 1 or PACKET_BITS % lanes:
            raise ValueError(f"lanes must divide the {PACKET_BITS}-bit packet, got {lanes}")
        if taps < 1:
            raise ValueError(f"taps must be >= 1, got {taps}")
        self.lanes, self.taps, self.settle = lanes, taps, settle
        training = {"tap": Out(range(taps)), "trained": Out(1),
                    "eye_width": Out(range(taps + 1))} if taps > 1 else {}
        super().__init__(width, height, {
            "bits": In(lanes),
            "locked": Out(1),
            "framing_errors": Out(ERROR_COUNT_BITS),
            **training,
        }, domain=domain, fifo_depth=fifo_depth)

    @property
    def pins(self):
        """The top level's sensor ports: the deserializer's ``lvds_bits`` (``lanes`` bits,
        earliest first as ``bits``, in ``domain``) and its PLL's ``rx_locked``
        (synchronized into ``sync`` by the board); with ``taps`` > 1 also ``rx_tap``, the
        trainer's sample phase (in ``domain``) to the receiver."""
        members = {"lvds_bits": In(self.lanes), "rx_locked": In(1)}
        if self.taps > 1:
            members["rx_tap"] = Out(range(self.taps))
        return wiring.Signature(members)

    def connect_pins(self, m, top):
        """Drive the front end from the top level's ``pins`` (and ``rx_tap`` from it)."""
        m.d.comb += self.bits.eq(top.lvds_bits)
        if self.taps > 1:
            m.d.comb += top.rx_tap.eq(self.tap)

    def status(self, top, since_read):
        """``OVF_LINK_DOWN`` while the aligner or the receiver's PLL is unlocked;
        ``OVF_LINK_ERROR`` while the framing-error count differs from its last read."""
        return {C.OVF_LINK_DOWN: ~self.locked | ~top.rx_locked,
                C.OVF_LINK_ERROR: since_read(self.framing_errors, "framing_errors")}

    def board_clocks(self, m, board, ports, top):
        """An ALTLVDS_RX (factor ``lanes``) deserializes ``ser_data`` on the returned
        ``ser_clk`` and clocks ``domain``, its PLL reset by :class:`ReceiverPllReset` until
        ``ser_clk`` runs (and retried if it does not lock); the master clock is forwarded to
        SYSCLK through a DDR output; the capture clock runs while the receiver's PLL is locked
        (returned; also synchronized into ``top.rx_locked``)."""
        pins = {sub: input_buffer(m, f"pin_mt9v022_0__{sub}", getattr(ports, sub))
                for sub in self.LVDS_PINS}
        clock_output(m, "pin_mt9v022_0__sysclk", ports.sysclk)
        ser_clk = Signal()
        rx_locked = Signal()
        bit_ps = 1e12 / (board.pixel_hz * PACKET_BITS)
        # pll_areset: a flip-flop the returned clock toggles tells the oscillator domain
        # whether that clock runs (ReceiverPllReset)
        m.domains += ClockDomain("ser_probe", reset_less=True)
        m.d.comb += ClockSignal("ser_probe").eq(pins["ser_clk"].i)
        probe = Signal()
        m.d.ser_probe += probe.eq(~probe)
        m.submodules.rx_pll_reset = pll_reset = ReceiverPllReset()
        m.submodules.rx_probe_cdc = FFSynchronizer(probe, pll_reset.toggle, o_domain="osc")
        m.submodules.rx_locked_osc_cdc = FFSynchronizer(rx_locked, pll_reset.locked,
                                                        o_domain="osc")
        if self.taps > 1:
            self._stepped_receiver(m, board, pins, top, pll_reset, ser_clk, rx_locked, bit_ps)
            m.d.comb += ClockSignal(self.domain).eq(ser_clk)
            m.submodules.rx_locked_cdc = FFSynchronizer(rx_locked, top.rx_locked)
            return rx_locked
        m.submodules.lvds_rx = Instance(
            "altlvds_rx",
            p_intended_device_family="Cyclone IV E", p_lpm_type="altlvds_rx",
            p_number_of_channels=1, p_deserialization_factor=self.lanes,
            p_data_rate=f"{1e6 / bit_ps:.1f} Mbps",
            p_input_data_rate=round(1e6 / bit_ps),
            p_inclock_period=round(1e12 / board.pixel_hz), p_implement_in_les="ON",
            # no DPA on Cyclone IV: shift the sampling clock by half a bit so that a
            # clock edge-aligned with the data samples each bit in its middle
            p_inclock_phase_shift=round(bit_ps / 2),
            p_registered_output="ON", p_use_external_pll="OFF",
            i_rx_in=pins["ser_data"].i, i_rx_inclock=pins["ser_clk"].i,
            i_pll_areset=pll_reset.areset,
            o_rx_out=top.lvds_bits, o_rx_outclock=ser_clk, o_rx_locked=rx_locked)
        m.d.comb += ClockSignal(self.domain).eq(ser_clk)
        m.submodules.rx_locked_cdc = FFSynchronizer(rx_locked, top.rx_locked)
        return rx_locked

    def _stepped_receiver(self, m, board, pins, top, pll_reset, ser_clk, rx_locked, bit_ps):
        """The receiver with a trained phase: an ALTPLL on the returned clock makes the bit
        clock (``c0``), the load enable (``c1``) and the word clock (``c2``, clocking
        ``domain``) with dynamic phase shift (``vco_phase_shift_step`` = a bit / ``taps``);
        a :class:`PhaseStepper` in ``osc`` (the PLL's ``scanclk``) moves all three to the
        trainer's ``rx_tap``; an ALTLVDS_RX in external-PLL mode deserializes on them.  The
        parameters follow the ALTPLL and ALTLVDS_RX user guides and must be checked in the
        Quartus MegaWizard (``docs/gateware.md``, MT9V022)."""
        clk = Signal(5, name="rx_pll_clk")
        phasedone = Signal()
        m.submodules.rx_stepper = stepper = PhaseStepper(self.taps, domain="osc")
        m.d.comb += [stepper.tap.eq(top.rx_tap),
                     stepper.hold.eq(pll_reset.areset | ~pll_reset.locked),
                     stepper.phasedone.eq(phasedone), ser_clk.eq(clk[2])]
        # (multiple of the returned pixel clock, phase in ps, duty %): the bit clock; the
        # load enable, one bit wide in the word's last bit; the word clock
        word = PACKET_BITS // self.lanes
        outputs = [(PACKET_BITS, 0, 50), (word, round((self.lanes - 1) * bit_ps),
                                          round(100 / self.lanes)), (word, 0, 50)]
        params = {"p_intended_device_family": "Cyclone IV E", "p_lpm_type": "altpll",
                  "p_operation_mode": "LVDS", "p_pll_type": "AUTO", "p_width_clock": 5,
                  "p_inclk0_input_frequency": round(1e12 / board.pixel_hz),
                  "p_vco_frequency_control": "MANUAL_PHASE",
                  "p_vco_phase_shift_step": round(bit_ps / self.taps),
                  "p_port_inclk0": "PORT_USED", "p_port_locked": "PORT_USED",
                  "p_port_areset": "PORT_USED", "p_port_scanclk": "PORT_USED",
                  "p_port_phasestep": "PORT_USED", "p_port_phaseupdown": "PORT_USED",
                  "p_port_phasecounterselect": "PORT_USED", "p_port_phasedone": "PORT_USED"}
        for k, (mul, phase_ps, duty) in enumerate(outputs):
            params.update({f"p_clk{k}_multiply_by": mul, f"p_clk{k}_divide_by": 1,
                           f"p_clk{k}_duty_cycle": duty, f"p_clk{k}_phase_shift": str(phase_ps),
                           f"p_port_clk{k}": "PORT_USED"})
        m.submodules.rx_pll = Instance(
            "altpll", **params, i_inclk=Cat(pins["ser_clk"].i, Const(0, 1)),
            i_areset=pll_reset.areset, i_scanclk=ClockSignal("osc"),
            i_phasestep=stepper.phasestep, i_phaseupdown=stepper.phaseupdown,
            i_phasecounterselect=stepper.phasecounterselect, o_phasedone=phasedone,
            o_clk=clk, o_locked=rx_locked)
        m.submodules.lvds_rx = Instance(
            "altlvds_rx",
            p_intended_device_family="Cyclone IV E", p_lpm_type="altlvds_rx",
            p_number_of_channels=1, p_deserialization_factor=self.lanes,
            p_data_rate=f"{1e6 / bit_ps:.1f} Mbps", p_input_data_rate=round(1e6 / bit_ps),
            p_inclock_period=round(bit_ps), p_implement_in_les="ON",
            p_registered_output="ON", p_use_external_pll="ON",
            i_rx_in=pins["ser_data"].i, i_rx_inclock=clk[0], i_rx_enable=clk[1],
            i_rx_syncclock=clk[2], o_rx_out=top.lvds_bits)

    @staticmethod
    def sdc_constraints(board):
        """The returned LVDS clock (created by the platform from the pin's ``Clock``, before
        ``derive_pll_clocks`` derives the receiver PLL's outputs from it) and those outputs,
        asynchronous to ``sync``."""
        ser_hz = board.pixel_hz * PACKET_BITS / LVDS_LANES
        return ["# the returned LVDS clock and the receiver PLL's outputs",
                "set_clock_groups -asynchronous -group [get_clocks {mt9v022_0__ser_clk__io "
                "*lvds_rx*}]",
                *crossing_constraints(board, ser_hz),
                *gray_skew_constraints("*|frontend|errors_gray*", "*|frontend|errors_cdc|*",
                                       0.8e9 / max(board.sync_hz, ser_hz)),
                "# ser_data: sampled by the receiver's PLL; the MT9V022 does not specify its "
                "LVDS clock-to-data relation,",
                "# so the sampling phase is set on the board (inclock_phase_shift), not timed "
                "against a datasheet window",
                "set_false_path -from [get_ports {mt9v022_0__ser_data__io}]",
                "# SYSCLK: the forwarded master clock (DDR output), no data relation",
                "set_false_path -to [get_ports {mt9v022_0__sysclk__io}]"]

    def elaborate(self, platform):
        m = Module()
        ser = self.domain
        cross = self.crossing(m)
        m.submodules.aligner = aligner = WordAligner(self.lanes, ser)
        m.submodules.decoder = decoder = WordDecoder(ser)
        m.d.comb += aligner.bits.eq(self.bits)
        if self.taps > 1:
            self._training(m, aligner, decoder)
        else:
            wiring.connect(m, aligner.words, decoder.words)
        m.d.comb += decoder.framing_error.eq(aligner.framing_error)
        wiring.connect(m, decoder.pixels, cross.pixels)

        # ---- status into sync -------------------------------------------------------------
        errors = Signal(ERROR_COUNT_BITS)
        errors_gray = Signal(ERROR_COUNT_BITS)
        errors_next = Mux(aligner.framing_error & (errors != (1 << ERROR_COUNT_BITS) - 1),
                          errors + 1, errors)
        m.d[ser] += [errors.eq(errors_next), errors_gray.eq(errors_next ^ (errors_next >> 1))]
        m.submodules.locked_cdc = FFSynchronizer(aligner.locked, self.locked, o_domain="sync")
        gray = Signal(ERROR_COUNT_BITS)
        m.submodules.errors_cdc = FFSynchronizer(errors_gray, gray, o_domain="sync")
        binary = [gray[-1]]
        for i in reversed(range(ERROR_COUNT_BITS - 1)):
            binary.insert(0, binary[0] ^ gray[i])
        m.d.sync += self.framing_errors.eq(Cat(*binary))
        return m

    def _training(self, m, aligner, decoder):
        """The :class:`PhaseTrainer` on the aligner's ``framed``; words reach the decoder
        only while trained; its status into ``sync``."""
        ser = self.domain
        m.submodules.trainer = trainer = PhaseTrainer(self.taps, PACKET_BITS // self.lanes,
                                                      ser, settle=self.settle)
        m.d.comb += [trainer.framed.eq(aligner.framed), self.tap.eq(trainer.tap),
                     aligner.forget.eq(trainer.forget),
                     decoder.words.payload.eq(aligner.words.payload),
                     decoder.words.valid.eq(aligner.words.valid & trainer.trained)]
        m.submodules.trained_cdc = FFSynchronizer(trainer.trained, self.trained,
                                                  o_domain="sync")
        m.submodules.eye_cdc = FFSynchronizer(trainer.eye_width, self.eye_width,
                                              o_domain="sync")
