"""MT9V022 stand-alone LVDS front end: the serial bit stream in, the detector's pixel stream
``pixel_layout(10)`` out in ``sync`` (same stream contract as :mod:`lodestar.hdl.mt9p031`).

Serial format (MT9V022 datasheet, "LVDS Output Format", stand-alone mode, 10-bit pixels)
-------------------------------------------------------------------------------------
* One 12-bit packet per pixel clock: start bit ``1``, the 10 data bits LSB first, stop bit
  ``0``; so the bit rate is 12 x the pixel clock (320 Mbit/s at the 26.67 MHz master clock).
* LINE_VALID and FRAME_VALID are not transmitted; they are embedded as reserved words.  Raw
  pixel values 0, 1, 2 and 3 are replaced by 4 on the link, and a raw sequence 1023, 0, 1023
  by 1023, 4, 1023, so the following can never be pixel data.  Decoded here:

  ==============================  ==================================================
  frame start                     the sequence 1023, 0, 1023 (FRAME_VALID rises after it)
  line start (word ``1``)         precedes LINE_VALID assertion: the next word is the
                                  line's first pixel
  line end (word ``2``)           succeeds LINE_VALID de-assertion: the previous word was
                                  the line's last pixel
  frame end (word ``3``)          succeeds FRAME_VALID de-assertion
  ==============================  ==================================================

  Verified against datasheet text (MT9V022 Rev. H, "LVDS Output Format" and the notes of its
  figure "Serial Output Format for a 6x2 Frame"; the MT9V024's table "Reserved words in the
  pixel data stream"): the packet format, the substitution of 0-3 by 4 and of 1023, 0, 1023
  by 1023, 4, 1023, word 0 "precedes frame valid assertion", word 1 "precedes line valid
  assertion".  **Not verified** (from memory of the same table, which the excerpts cut off):
  word 2 "succeeds line valid de-assertion", word 3 "succeeds frame valid de-assertion";
  whether word 3 replaces the last line's word 2 or follows it; what the words between lines
  carry (the tests use 4, a raw 0).  The decoder accepts both frame-end orders and ignores
  every non-reserved word outside a line.

Decoding rules (robust to the unverified points): in a line, a word >= 4 is a pixel; any
reserved word (0-3) ends an open line (the pixel before it gets ``eol``); word 1 opens a line
only inside a frame; word 3 ends the frame; 1023, 0, 1023 starts a frame (the next line's first
pixel gets ``sof``).  Lines of the wrong length and frames with the wrong number of lines pass
through as they come (the detector flags them); ``width``/``height`` are only checked against
the contract and handed to the top level.

Receiver (what a Cyclone IV can do) and the ``bits`` input
---------------------------------------------------------
Cyclone IV has true LVDS input buffers but no hard SERDES and no dynamic phase alignment:
ALTLVDS_RX is built from the DDIO input registers, logic shift registers and a PLL (fast clock
at half the bit rate, static phase), with deserialization factors up to 10, so 12 bits per
word cannot be deserialized in one step and 320 Mbit/s is far above the fabric's clock rate.
The front end therefore takes ``lanes`` bits per clock of the ``ser`` domain (default 6:
ALTLVDS_RX with J = 6, ``ser`` = 2 x the pixel clock = 53.3 MHz, its PLL locked to the
sensor's shift clock or to the SYSCLK the FPGA drives) and finds the word boundary itself.
``lanes`` may be any divisor of 12 (1 is the plain one-bit-per-clock model the tests also
use).  Bit order: ``bits[lanes-1]`` is the earliest bit, the ALTLVDS_RX ``rx_out`` order
(**to verify** against the megafunction's documentation for the Quartus version used; a
receiver with the opposite order is wired with its bits reversed).  [The deserialization
factor range and the LVDS rates are from memory of the Cyclone IV handbook.]

Word alignment and lock
-----------------------
Every packet has a ``0`` -> ``1`` transition (stop bit, next start bit) at its boundary.  All
12 candidate alignments are checked in parallel: each keeps a count of consecutive packets
with a correct start and stop bit, saturating at ``LOCK_PACKETS``.  The front end locks when
exactly one candidate is saturated and no other has a run of ``LOCK_PACKETS - 1`` (the
candidates are checked one after the other within a packet period, so a rival that passes as
long is at most one packet behind).  (A constant word such as the blanking value 4 repeats a
12-bit pattern with a second internal 0 -> 1 transition, so two candidates pass for as long as
it lasts; the 1023, 0, 1023 of a frame start, whose 1023 has a single 0, leaves only the
true one.)  While locked, each packet of the locked alignment must have correct framing bits;
a packet that has not is a **framing error**: it is counted (``framing_errors``, saturating),
lock is dropped and the partial frame is abandoned (the pixel held for its ``eol`` is dropped
and nothing more is delivered until the next frame start, so the detector sees a truncated
frame followed by the next ``sof``) and every candidate's count restarts from zero.  Lock is
re-acquired on the previous alignment as soon as it is saturated again, even if another
candidate is too (a corrupted bit does not move the boundary), or else on a unique saturated
candidate as at power-up.  So a corrupted bit costs ``LOCK_PACKETS`` packets and the rest
of its frame, and the next frame is exact.  At power-up
a frame is delivered only if lock comes before the last word of its start sequence; with
blanking words of value 4 the first 1023 of the sequence rules out the false alignment before
its own last bit, so the first frame is delivered (the tests show it).

Clock-domain crossing: :class:`lodestar.hdl.mt9p031.PixelCrossing` (AsyncFIFO, sticky
``overflow`` with ``overflow_clear``, frame broken until the next ``sof`` on overflow).  A word
is written at most once per ``12 / lanes`` ``ser`` clocks, so the sync clock must be at least
the pixel clock.  ``locked`` and ``framing_errors`` are synchronized into ``sync`` (the count
crosses Gray-coded, one bit changing per increment; errors are at least ``LOCK_PACKETS``
packets apart, since lock must be regained before the next one can be counted).
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
    See the module docstring."""

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
