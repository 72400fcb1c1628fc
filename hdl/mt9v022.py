"""MT9V022 stand-alone LVDS front end: the serial bit stream in, the detector's pixel stream
``pixel_layout(10)`` out in ``sync`` (same stream contract as :mod:`lodestar.hdl.mt9p031`).

The link carries one 12-bit packet per pixel clock (start bit ``1``, 10 data bits LSB first,
stop bit ``0``) with LINE_VALID/FRAME_VALID embedded as reserved words (0-3, and 1023, 0, 1023
for a frame start).  A Cyclone IV has no hard SERDES, so the front end takes ``lanes`` bits
per ``ser`` clock (``bits[lanes-1]`` earliest), finds the word boundary itself (lock on a
unique alignment; a framing error drops lock and the rest of its frame) and crosses into
``sync`` through :class:`lodestar.hdl.mt9p031.PixelCrossing` (sync clock >= pixel clock).
Datasheet sources, the points not yet verified, decoding and lock rules:
``docs/sensors_and_link.md`` (MT9V022).
"""

from amaranth import Array, Cat, Module, Mux, Signal
from amaranth.lib import stream, wiring
from amaranth.lib.cdc import FFSynchronizer
from amaranth.lib.wiring import In, Out

from lodestar import contract as C
from lodestar.hdl.mt9p031 import FIFO_DEPTH, PixelCrossing, check_geometry
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


def packet_bits(word):
    """The 12 bits of one packet in transmission order (start, LSB .. MSB, stop)."""
    return [1] + [(word >> i) & 1 for i in range(PIXEL_BITS)] + [0]


class MT9V022Frontend(wiring.Component):
    """MT9V022 LVDS bits (``bits``, ``lanes`` per ``domain`` clock) to the detector's pixel
    stream ``out`` in ``sync``; ``overflow``/``overflow_clear``, ``locked`` and
    ``framing_errors`` in ``sync``; ``fifo_level`` in ``domain`` (see ``PixelCrossing``).
    See ``docs/sensors_and_link.md`` (MT9V022)."""

    def __init__(self, width, height, *, lanes=6, domain="ser", fifo_depth=FIFO_DEPTH):
        check_geometry(width, height)
        if lanes < 1 or PACKET_BITS % lanes:
            raise ValueError(f"lanes must divide the {PACKET_BITS}-bit packet, got {lanes}")
        self.width, self.height = width, height
        self.lanes, self.domain, self.fifo_depth = lanes, domain, fifo_depth
        super().__init__({
            "bits": In(lanes),
            "out": Out(stream.Signature(pixel_layout(PIXEL_BITS), always_ready=True)),
            "overflow": Out(1),
            "overflow_clear": In(1),
            "fifo_level": Out(range(fifo_depth + 1)),
            "locked": Out(1),
            "framing_errors": Out(ERROR_COUNT_BITS),
        })

    def elaborate(self, platform):
        m = Module()
        ser = self.domain
        L = self.lanes
        P = PACKET_BITS // L           # ser clocks per packet
        m.submodules.crossing = cross = PixelCrossing(PIXEL_BITS, ser, self.fifo_depth)
        wiring.connect(m, wiring.flipped(self.out), cross.out)
        m.d.comb += [cross.overflow_clear.eq(self.overflow_clear),
                     self.overflow.eq(cross.overflow), self.fifo_level.eq(cross.fifo_level)]

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
        # Runs grow in step (each candidate is checked once per packet period), so a rival
        # that passed as long as the first saturated candidate has at least LOCK_PACKETS - 1.
        near = Cat(*[n >= LOCK_PACKETS - 1 for n in nexts])
        unique = (sat == near) & (sat != 0) & ((sat & (sat - 1)) == 0)
        which = Signal(range(PACKET_BITS))
        for a in range(PACKET_BITS):
            with m.If(sat[a]):
                m.d.comb += which.eq(a)

        locked = Signal()
        relock = Signal()              # lock_a was locked before: preferred when it qualifies
        lock_a = Signal(range(PACKET_BITS))
        lock_p = Array([a // L for a in range(PACKET_BITS)])[lock_a]
        lock_s = Array([a % L for a in range(PACKET_BITS)])[lock_a]
        at_word = locked & (ph == lock_p)
        word_good = Array(good)[lock_s]
        word = Array(words)[lock_s]
        word_valid = at_word & word_good
        framing_error = at_word & ~word_good
        with m.If(~locked):
            with m.If(relock & sat.bit_select(lock_a, 1)):
                m.d[ser] += locked.eq(1)
            with m.Elif(unique):
                m.d[ser] += [locked.eq(1), relock.eq(1), lock_a.eq(which)]
        with m.If(framing_error):
            # Lose lock and restart every candidate, so that the locked alignment competes
            # again on equal terms with alignments that only pass on the blanking pattern.
            m.d[ser] += [locked.eq(0)] + [r.eq(0) for r in runs]
        with m.Else():
            m.d[ser] += [r.eq(n) for r, n in zip(runs, nexts)]

        errors = Signal(ERROR_COUNT_BITS)
        errors_gray = Signal(ERROR_COUNT_BITS)
        errors_next = Mux(framing_error & (errors != (1 << ERROR_COUNT_BITS) - 1),
                          errors + 1, errors)
        m.d[ser] += [errors.eq(errors_next), errors_gray.eq(errors_next ^ (errors_next >> 1))]

        # ---- reserved-word decoder --------------------------------------------------------
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
            cross.pixels.valid.eq(word_valid & held_valid),
            cross.pixels.payload.data.eq(held),
            cross.pixels.payload.sof.eq(held_sof),
            cross.pixels.payload.eol.eq(reserved),
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
        with m.Elif(framing_error):    # abandon the frame; wait for the next frame start
            m.d[ser] += [in_frame.eq(0), in_line.eq(0), held_valid.eq(0),
                         prev1.eq(0), prev2.eq(0)]

        # ---- status into sync -------------------------------------------------------------
        m.submodules.locked_cdc = FFSynchronizer(locked, self.locked, o_domain="sync")
        gray = Signal(ERROR_COUNT_BITS)
        m.submodules.errors_cdc = FFSynchronizer(errors_gray, gray, o_domain="sync")
        binary = [gray[-1]]
        for i in reversed(range(ERROR_COUNT_BITS - 1)):
            binary.insert(0, binary[0] ^ gray[i])
        m.d.sync += self.framing_errors.eq(Cat(*binary))
        return m
