"""MT9P031 parallel front end: PIXCLK, LINE_VALID, FRAME_VALID and D[11:0] in, the detector's
pixel stream out in ``sync``.

Stream contract (what the detector consumes): ``out`` is an always-ready ``lib.stream`` in the
``sync`` domain whose payload is ``threshold.pixel_layout(12)``: ``data`` the pixel, ``sof`` on
the first pixel of a frame, ``eol`` on the last pixel of each line, one pixel per beat, raster
order.  ``valid`` is low between pixels (the sync clock is faster than the pixel rate).

Capture (pixel clock domain, default ``"pix"``; the board top level defines it from PIXCLK)
-------------------------------------------------------------------------------------------
* Edge: the MT9P031 launches D, LINE_VALID and FRAME_VALID on the *falling* edge of PIXCLK by
  default (register R0x0A[15] "invert pixel clock" = 0) so that a receiver samples them on the
  *rising* edge, half a period (5.2 ns at 96 MHz) after they change.  The front end samples on
  the active edge of its domain, so the board top level defines that domain on PIXCLK's rising
  edge (``ClockDomain("pix")``); a board that sets R0x0A[15] = 1 defines it with
  ``clk_edge="neg"``.  The edge is a property of the clock domain, not of this logic, which is
  why it is not a parameter here.
* The pins go through one register stage (the I/O cells' input registers).  A pixel is valid
  when LINE_VALID and FRAME_VALID are both high.
* ``sof`` marks the first valid pixel after FRAME_VALID was seen low; ``eol`` the last valid
  pixel before LINE_VALID (or FRAME_VALID) falls.  ``eol`` needs the next sample, so pixels
  leave the capture one PIXCLK later (latency 2 PIXCLK to the FIFO).
* Geometry: ``width`` and ``height`` describe the frames the sensor is programmed for; they
  are checked against the contract and handed to the top level (``self.width``,
  ``self.height``) but not enforced: lines of the wrong length and frames with the wrong number
  of lines pass through as they come, with their markers, and the detector flags them
  (``FRAME_LINE_ERROR``, ``FRAME_TRUNCATED``).

Clock-domain crossing (:class:`PixelCrossing`, shared with the MT9V022 front end)
--------------------------------------------------------------------------------
Pixels cross into ``sync`` through an ``amaranth.lib.fifo.AsyncFIFO``.  The sync clock must be
at least the pixel rate; then the FIFO never holds more than the pointer-synchronizer round
trip: an entry written on a pixel clock edge is visible to the read side after at most 2 sync
clocks (synchronizer), is read on the next, and the write side learns that 2 pixel clocks
later (synchronizer).  So the write side counts an entry for at most ``3 T_sync + 2 T_pix``,
during which at most ``3 + 3 f_pix / f_sync <= 6`` pixels arrive.  ``FIFO_DEPTH = 8`` covers
that (the tests measure the write side's peak occupancy, ``fifo_level``: 5 at equal clocks).

If a pixel finds the FIFO full (the sync clock is too slow), the pixel is dropped, the sticky
``overflow`` flag rises in ``sync`` (it stays up until an ``overflow_clear`` strobe; a new
overflow in the same clock wins) and every further pixel is suppressed until the next ``sof``:
the detector sees a truncated frame followed by the next frame's ``sof`` and flags it
``FRAME_TRUNCATED``; the frame is never delivered shifted.  After a reset of the capture
domain the crossing likewise waits for a frame start, so a frame already under way is never
delivered without its beginning.
"""

from amaranth import Module, Signal
from amaranth.lib import stream, wiring
from amaranth.lib.cdc import PulseSynchronizer
from amaranth.lib.fifo import AsyncFIFO
from amaranth.lib.wiring import In, Out

from lodestar import contract as C
from lodestar.hdl.threshold import pixel_layout

PIXEL_BITS = C.SENSOR_PIXEL_BITS["mt9p031"]
"""MT9P031 pixel width (the contract's ``SENSOR_PIXEL_BITS``)."""

FIFO_DEPTH = 8
"""Entries of the pixel-clock -> sync FIFO when the sync clock is at least the pixel rate
(module docstring: at most 6 are ever counted by the write side)."""


def check_geometry(width, height):
    """Raise ``ValueError`` unless a ``width x height`` frame is within the contract."""
    if not (1 <= width <= C.MAX_WIDTH and 1 <= height <= C.MAX_HEIGHT):
        raise ValueError(f"frame {width}x{height} is outside the contract's "
                         f"1..{C.MAX_WIDTH} x 1..{C.MAX_HEIGHT}")


class PixelCrossing(wiring.Component):
    """Pixel stream from a sensor clock domain into ``sync``; frames broken on overflow.

    ``pixels`` (in ``domain``) and ``out`` (in ``sync``) are always-ready streams of
    ``pixel_layout(pixel_bits)``.  ``overflow`` (sync) is sticky until ``overflow_clear``
    (sync).  ``fifo_level`` (in ``domain``) is the FIFO occupancy as the write side sees it
    (entries written and not yet known to be read: the quantity that overflows).  See the
    module docstring for the depth and the broken-frame rule.
    """

    def __init__(self, pixel_bits, domain, depth=FIFO_DEPTH):
        if depth < 2:
            raise ValueError(f"FIFO depth must be at least 2, got {depth}")
        self.pixel_bits, self.domain, self.depth = pixel_bits, domain, depth
        layout = pixel_layout(pixel_bits)
        super().__init__({
            "pixels": In(stream.Signature(layout, always_ready=True)),
            "out": Out(stream.Signature(layout, always_ready=True)),
            "overflow": Out(1),
            "overflow_clear": In(1),
            "fifo_level": Out(range(depth + 1)),
        })

    def elaborate(self, platform):
        m = Module()
        w = self.domain
        m.submodules.fifo = fifo = AsyncFIFO(width=pixel_layout(self.pixel_bits).size,
                                             depth=self.depth, r_domain="sync", w_domain=w)
        m.submodules.lost_cdc = lost_cdc = PulseSynchronizer(i_domain=w, o_domain="sync")
        p = self.pixels

        # ---- write side: drop the rest of a frame once a pixel is lost ------------------
        broken = Signal(init=1)      # wait for a frame start (also after reset)
        take = p.valid & (p.payload.sof | ~broken)
        lost = take & ~fifo.w_rdy
        m.d.comb += [fifo.w_en.eq(take), fifo.w_data.eq(p.payload), lost_cdc.i.eq(lost)]
        with m.If(lost):
            m.d[w] += broken.eq(1)
        with m.Elif(take & p.payload.sof):
            m.d[w] += broken.eq(0)
        # ``lost`` pulses at most once per frame (later pixels are not taken until the next
        # sof), so the toggle synchronizer never merges two of them.

        # ---- read side: always ready -----------------------------------------------------
        m.d.comb += [
            fifo.r_en.eq(1),
            self.out.valid.eq(fifo.r_rdy),
            self.out.payload.eq(fifo.r_data),
            self.fifo_level.eq(fifo.w_level),
        ]
        with m.If(lost_cdc.o):
            m.d.sync += self.overflow.eq(1)
        with m.Elif(self.overflow_clear):
            m.d.sync += self.overflow.eq(0)
        return m


class MT9P031Frontend(wiring.Component):
    """MT9P031 parallel bus (``d``, ``line_valid``, ``frame_valid`` sampled in ``domain``) to
    the detector's pixel stream ``out`` in ``sync``; sticky ``overflow``/``overflow_clear`` in
    ``sync``; ``fifo_level`` in ``domain`` (see :class:`PixelCrossing`).  ``width x height``:
    the programmed frame, not enforced (module docstring)."""

    def __init__(self, width, height, *, domain="pix", fifo_depth=FIFO_DEPTH):
        check_geometry(width, height)
        self.width, self.height, self.domain, self.fifo_depth = width, height, domain, fifo_depth
        super().__init__({
            "d": In(PIXEL_BITS),
            "line_valid": In(1),
            "frame_valid": In(1),
            "out": Out(stream.Signature(pixel_layout(PIXEL_BITS), always_ready=True)),
            "overflow": Out(1),
            "overflow_clear": In(1),
            "fifo_level": Out(range(fifo_depth + 1)),
        })

    def elaborate(self, platform):
        m = Module()
        pix = self.domain
        m.submodules.crossing = cross = PixelCrossing(PIXEL_BITS, pix, self.fifo_depth)
        wiring.connect(m, wiring.flipped(self.out), cross.out)
        m.d.comb += [cross.overflow_clear.eq(self.overflow_clear),
                     self.overflow.eq(cross.overflow), self.fifo_level.eq(cross.fifo_level)]

        # ---- input registers (I/O cells) ----------------------------------------------
        d = Signal(PIXEL_BITS)
        lv = Signal()
        fv = Signal(init=1)          # after reset, assume a frame is under way
        m.d[pix] += [d.eq(self.d), lv.eq(self.line_valid), fv.eq(self.frame_valid)]
        valid = lv & fv

        # ---- one-pixel delay: the held pixel learns eol from the next sample ------------
        held = Signal(PIXEL_BITS)
        held_valid = Signal()
        held_sof = Signal()
        armed = Signal()             # FRAME_VALID was low since the last frame's first pixel
        m.d[pix] += held_valid.eq(valid)
        with m.If(valid):
            m.d[pix] += [held.eq(d), held_sof.eq(armed), armed.eq(0)]
        with m.Elif(~fv):
            m.d[pix] += armed.eq(1)
        m.d.comb += [
            cross.pixels.valid.eq(held_valid),
            cross.pixels.payload.data.eq(held),
            cross.pixels.payload.sof.eq(held_sof),
            cross.pixels.payload.eol.eq(~valid),
        ]
        return m
