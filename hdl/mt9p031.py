"""MT9P031 parallel front end: PIXCLK, LINE_VALID, FRAME_VALID and D[11:0] in, the detector's
pixel stream out in ``sync``.

``out`` is an always-ready ``lib.stream`` in ``sync`` of ``threshold.pixel_layout(12)``
(``data``, ``sof`` on a frame's first pixel, ``eol`` on each line's last, raster order).
Capture runs in the pixel clock domain (default ``"pix"``), whose edge the board top level
chooses (R0x0A[15]); ``width x height`` are checked, not enforced (the detector flags bad
frames).  :class:`PixelCrossing` (shared with the MT9V022) crosses into ``sync`` through an
AsyncFIFO: with the sync clock at least the pixel rate the write side never counts more than
6 entries (``FIFO_DEPTH = 8``); on overflow the sticky ``overflow`` rises and the frame is
cut until the next ``sof``, never delivered shifted.  Derivation: ``docs/sensors_and_link.md``.
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
    (entries written and not yet known to be read: the quantity that overflows).  See
    ``docs/sensors_and_link.md`` for the depth and the broken-frame rule.
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
