"""Threshold unit: pixel stream in, lit flag and weight out, one pixel per clock.

Implements the ``fixed``, ``global`` and ``local`` modes of ``lodestar.contract`` bit-exactly
(``docs/gateware.md`` describes how, with each mode's latency and blanking).
:class:`ThresholdUnit` wires :class:`GlobalLevels` (global mode's levels, searched after each
complete frame) and :class:`LocalWindow` (local mode's delay line and window mean) to the
frame's position count, statistics and output register.  A frame that cannot use its mode's
levels uses the fixed registers and says so.
"""

from collections import namedtuple

from amaranth import Cat, Const, Module, Mux, Signal
from amaranth.lib import stream, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

from lodestar import contract as C

from .layouts import (
    ThresholdMode,
    check_frame,
    delay_entry_layout,
    lit_layout,
    local_mean_layout,
    local_pixel_layout,
    pixel_layout,
)


def _pass_bits(width, height, pixel_bits):
    """Clocks of one trial of ``B`` and of ``D`` (bits of the numbers the trial compares)."""
    nfs = width * height * C.full_scale(pixel_bits)
    kmax = (1 << C.KSIGMA_BITS) - 1
    # B: S1 against N*c (c <= fs), and one clock more so that S1, which rotates while it
    # is streamed, is in place in a trial's last clock (where the D search copies it).
    # D: K*K*V (V <= (N fs)**2 / 4, Popoviciu) against 256*N*N*c*c; every partial product
    # of the chain is below these bounds too.  One clock more: the chain is cut by a
    # register on each side (V's bit, 256*N*N*c*c's bit) for timing, so both reach the
    # final subtraction a clock late.
    return (C.bits_for(nfs) + 1,
            C.bits_for(max(kmax * kmax * nfs * nfs // 4, (nfs << C.KSIGMA_FRAC_BITS) ** 2))
            + 1)


def ksigma_cycles(width, height, pixel_bits):
    """Clocks from a ``ksigma`` write to levels computed with it: the ``D`` search (one
    trial per bit of ``D``), the rest of the trial under way when it was written, and the
    clock of the registered compare that notices the write."""
    _, ld = _pass_bits(width, height, pixel_bits)
    return (pixel_bits + 1) * ld + 1


def global_cycles(width, height, pixel_bits):
    """Clocks the global-mode computation needs after a frame's last pixel: the ``B``
    search (a flush trial and one per bit), the ``D`` search and the clock that starts
    it."""
    lb, ld = _pass_bits(width, height, pixel_bits)
    return (pixel_bits + 1) * lb + pixel_bits * ld + 1


def _serial_mul(m, bit, multiplicand):
    """One bit of a serial (LSB first) product ``multiplicand * stream``: returns the output
    bit of the clock in which the stream's bit is ``bit``.

    The register ``h`` holds the partial product's bits above the output: each clock
    ``h + bit * multiplicand`` gives the output bit (its LSB) and the new ``h`` (the rest).
    Streaming more clocks than the product has bits (with zero stream bits) leaves ``h``
    at 0, so nothing needs clearing between products; the adder is one bit wider than the
    multiplicand.
    """
    h = Signal(len(multiplicand), reset_less=True)
    total = h + Mux(bit, multiplicand, 0)
    m.d.sync += h.eq(total[1:])
    return h[0] ^ (bit & multiplicand[0])


def _below_const(value, bound):
    """``value < bound`` for a constant ``bound``, as logic rather than a carry chain."""
    if bound >> len(value):
        return Const(1)
    result = Const(0)
    for i, bit in enumerate(value):              # decided by the highest differing bit
        result = (~bit | result) if (bound >> i) & 1 else (~bit & result)
    return result


def _serial_sub(m, a, b, keep):
    """One bit of a serial (LSB first) difference ``a - b``: returns the difference bit and
    the borrow out; the borrow is kept for the next clock while ``keep``, else cleared."""
    borrow = Signal(reset_less=True)
    out = (~a & b) | (~a & borrow) | (b & borrow)
    m.d.sync += borrow.eq(out & keep)
    return a ^ b ^ borrow, out


LOCAL_LATENCY = 8
"""Local mode: clocks from the input pixel that makes a pixel ready to that pixel's beat."""


def local_log2_window_max(width):
    """Largest ``local_log2_window`` a frame ``width`` pixels wide admits (window narrower
    than the frame), or ``None`` if none does."""
    usable = [lg for lg in range(C.LOCAL_LOG2_WINDOW_MIN, C.LOCAL_LOG2_WINDOW_MAX + 1)
              if (1 << lg) < width]
    return max(usable) if usable else None


def _log2_windows(width):
    """The ``local_log2_window`` values a frame ``width`` pixels wide admits."""
    return range(C.LOCAL_LOG2_WINDOW_MIN,
                 (local_log2_window_max(width) or C.LOCAL_LOG2_WINDOW_MIN - 1) + 1)


def local_depth(width):
    """Entries of the local-mode circular buffer for frames ``width`` pixels wide.

    A pixel is read while at most ``L + 1`` pixels of the frame are unread (itself included)
    and its window reads reach back ``L/2 + 1`` further, so ``3L/2 + 3`` entries suffice;
    rounded up to a power of two (256 for ``L = 128``).
    """
    lg = local_log2_window_max(width) or C.LOCAL_LOG2_WINDOW_MIN
    return 1 << C.bits_for(3 * (1 << lg) // 2 + 2)


def local_blanking(log2_window):
    """Idle clocks a local-mode frame needs between its last pixel and the next ``sof`` for
    all its pixels to leave: the up to ``L + 1`` pixels unread after the last pixel are read
    one per clock, the last of them ``LOCAL_LATENCY - 1`` clocks before its beat."""
    return (1 << log2_window) + LOCAL_LATENCY - 1


def local_sum_bits(width, pixel_bits):
    """Width of the running ``S1`` copies the local delay line keeps: a window's sum of
    ``L + 1`` pixels, for the widest ``L`` a frame ``width`` pixels wide admits (the window
    sums are differences of the copies, exact modulo this width)."""
    window_max = 1 << (local_log2_window_max(width) or C.LOCAL_LOG2_WINDOW_MIN)
    return C.bits_for((window_max + 1) * C.full_scale(pixel_bits))


def _sum_widths(width, height, pixel_bits):
    """Widths of a frame's ``S1 = sum(p)`` and ``S2 = sum(p*p)``."""
    nfs = width * height * C.full_scale(pixel_bits)
    return C.bits_for(nfs), C.bits_for(nfs * C.full_scale(pixel_bits))


_Position = namedtuple("_Position", [
    "sof", "sof_valid", "pixel", "x", "y", "last_col", "eol", "frame_end", "in_frame",
    "complete"])
_Position.__doc__ = """The input pixel's position and the frame's integrity, as the input counts
them: ``x``/``y`` (0 at a ``sof``), ``last_col`` (``x == W - 1``), ``frame_end`` (a valid
pixel at ``(W - 1, H - 1)`` of a started frame), ``in_frame`` (a frame started and has not
ended), ``complete`` (``frame_end`` of a frame whose every line was ``W`` long)."""

_Sums = namedtuple("_Sums", ["s1", "s2", "s1_before", "s1_after"])
_Sums.__doc__ = """The frame's ``S1`` and ``S2`` registers, and ``S1`` before and after the
input pixel (local mode's running sum)."""


class _PixelLevels(namedtuple("_PixelLevels", [
        "sof_valid", "local_new", "use_global", "local", "global_", "fixed", "frame"])):
    """The candidate ``(T, B)`` pairs of the input pixel: at a ``sof`` the new frame's
    (``local``: the offset and 0, ``global_``: the search's, ``fixed``: the registers,
    chosen by ``local_new`` and ``use_global``), else the frame's latched ``frame``."""

    def apply(self, f):
        """``f(T, B)`` of this pixel's levels, computed for each candidate and selected
        after (the sof's mode decision runs beside ``f``'s arithmetic: timing)."""
        new = Mux(self.local_new, f(*self.local),
                  Mux(self.use_global, f(*self.global_), f(*self.fixed)))
        return Mux(self.sof_valid, new, f(*self.frame))


_FrameMode = namedtuple("_FrameMode", [
    "threshold", "levels", "use_global", "window_ok", "local_new", "local"])
_FrameMode.__doc__ = """The mode of the frame the input pixel belongs to: ``threshold`` (its T,
the offset in local mode), ``levels`` (a ``_PixelLevels``), ``use_global`` and ``local_new``
(a frame starting now uses the search's levels, local mode), ``window_ok`` (the window
register admits local mode), ``local`` (the pixel's frame is in local mode)."""


class ThresholdUnit(wiring.Component):
    """Fixed, global and local thresholds for ``width x height`` frames of ``pixel_bits``
    pixels, bit-exact against ``lodestar.contract`` (``docs/gateware.md``: each mode's latency
    and blanking).  Composes the global-levels search (:class:`GlobalLevels`) and the local
    delay line (:class:`LocalWindow`) with the position count, the statistics and the
    output register.

    Parameters
    ----------
    width, height : int
        Frame size in pixels.
    pixel_bits : int
        Bits per pixel (``contract.PIXEL_BITS``).

    Members
    -------
    pixels : ``In(stream.Signature(pixel_layout(pixel_bits), always_ready=True))``
        One pixel per clock while ``valid`` (no backpressure), ``sof`` on a frame's first
        pixel, ``eol`` on each line's last.
    out : ``Out(stream.Signature(lit_layout(width, height, pixel_bits), always_ready=True))``
        One beat per pixel in raster order: ``lit = p > T``, ``weight = max(p - B, 0)``,
        ``eof`` on the frame's last.  Fixed and global mode: a clock after the pixel; local
        mode: ``LOCAL_LATENCY`` clocks after the pixel that made the beat ready.
    mode, threshold, background, ksigma, local_log2_window, local_offset : ``In``
        The registers of the same names (``contract.REGISTERS``), latched on the ``sof``
        pixel (``ksigma`` also when the global search starts its ``D`` pass).
    frame_threshold, frame_background : ``Out(pixel_bits)``
        The frame's T and B (local mode: the offset and 0), from the clock after its
        ``sof``.
    frame_fallback, frame_local_fallback : ``Out(1)``
        Latched at each ``sof``: the frame asked for global (local) mode and uses the fixed
        registers (no levels for ``ksigma`` yet; a window not narrower than the frame).
    frame_tail_dropped : ``Out(1)``
        Latched at each ``sof``: it discarded pixels of the previous local-mode frame that
        were still in the delay line.
    stats_busy : ``Out(1)``
        The global levels are being computed.
    """

    def __init__(self, width, height, pixel_bits):
        check_frame(width, height, pixel_bits)
        self.width, self.height, self.pixel_bits = width, height, pixel_bits
        reg = C.REGISTER_BY_NAME
        super().__init__({
            "pixels": In(stream.Signature(pixel_layout(pixel_bits), always_ready=True)),
            "out": Out(stream.Signature(lit_layout(width, height, pixel_bits),
                                        always_ready=True)),
            "mode": In(ThresholdMode),
            "threshold": In(pixel_bits),
            "background": In(pixel_bits),
            "ksigma": In(reg["ksigma"].bits),
            "local_log2_window": In(reg["local_log2_window"].bits),
            "local_offset": In(reg["local_offset"].bits),
            "frame_threshold": Out(pixel_bits),
            "frame_background": Out(pixel_bits),
            "frame_fallback": Out(1),
            "frame_local_fallback": Out(1),
            "frame_tail_dropped": Out(1),
            "stats_busy": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        W, H, pb = self.width, self.height, self.pixel_bits
        m.submodules.levels = levels = GlobalLevels(W, H, pb)
        m.submodules.window = window = LocalWindow(W, H, pb)
        pos = self._position(m)
        mode = self._frame_mode(m, pos, levels)
        sums = self._statistics(m, pos, levels.rotate_s1, levels.rotate_s2)
        self._window_input(m, pos, mode, sums, window)
        self._frame_status(m, pos, mode, window.pending)
        self._output(m, pos, mode, window.out)
        m.d.comb += [levels.s1.eq(sums.s1), levels.s2.eq(sums.s2), levels.ksigma.eq(self.ksigma),
                     levels.start.eq(pos.sof_valid), levels.frame_end.eq(pos.frame_end),
                     levels.complete.eq(pos.complete), levels.in_frame.eq(pos.in_frame),
                     self.stats_busy.eq(levels.busy)]
        return m

    def _position(self, m):
        """Position of the input pixel and frame integrity, as the input counts them
        (a ``_Position``)."""
        W, H, inp = self.width, self.height, self.pixels
        sof = inp.payload.sof
        sof_valid = inp.valid & sof
        x = Signal(range(W), reset_less=True)
        y = Signal(range(H), reset_less=True)
        in_frame = Signal()
        frame_ok = Signal()          # every line so far was exactly W long
        # x == W - 1 and y == H - 1, kept in registers beside x and y
        x_last = Signal(reset_less=True, init=W == 1)
        y_last = Signal(reset_less=True, init=H == 1)
        cur_x = Mux(sof, 0, x)
        cur_y = Mux(sof, 0, y)
        last_col = Mux(sof, W == 1, x_last)
        last_row = Mux(sof, H == 1, y_last)
        before_last_col = (cur_x == W - 2) if W >= 2 else Const(0)
        before_last_row = (cur_y == H - 2) if H >= 2 else Const(0)
        line_error = inp.payload.eol != last_col
        frame_end = inp.valid & last_col & last_row & (in_frame | sof)
        with m.If(inp.valid):
            with m.If(last_col | inp.payload.eol):
                m.d.sync += [x.eq(0), y.eq(Mux(last_row, 0, cur_y + 1)), x_last.eq(W == 1),
                             y_last.eq(Mux(last_row, H == 1, before_last_row))]
            with m.Else():
                m.d.sync += [x.eq(cur_x + 1), y.eq(cur_y), x_last.eq(before_last_col),
                             y_last.eq(last_row)]
            m.d.sync += frame_ok.eq(Mux(sof, 1, frame_ok) & ~line_error)
        with m.If(sof_valid):
            m.d.sync += in_frame.eq(1)
        with m.If(frame_end):
            m.d.sync += in_frame.eq(0)
        return _Position(
            sof=sof, sof_valid=sof_valid, pixel=inp.payload.data, x=cur_x, y=cur_y,
            last_col=last_col, eol=inp.payload.eol, frame_end=frame_end, in_frame=in_frame,
            complete=frame_end & Mux(sof, 1, frame_ok) & ~line_error)

    def _frame_mode(self, m, pos, levels):
        """The mode a frame starting now uses and its T and B (local mode: the offset and
        0), latched on the ``sof`` pixel (a ``_FrameMode``); ``levels``: the search's."""
        pb, fs = self.pixel_bits, C.full_scale(self.pixel_bits)
        # a sof while in_frame: the previous frame never ended, so its statistics are
        # missing and this frame falls back, as after an incomplete frame.  (levels.valid
        # is 0 while the levels are being computed.)
        use_global = ((self.mode == ThresholdMode.GLOBAL) & levels.valid &
                      (levels.valid_ksigma == self.ksigma) & ~pos.in_frame)
        window_ok = Const(0)         # a window narrower than the frame
        for k in _log2_windows(self.width):
            window_ok |= self.local_log2_window == k
        local_new = (self.mode == ThresholdMode.LOCAL) & window_ok
        offset_sat = Mux(self.local_offset[pb:].any(), fs, self.local_offset[:pb])
        local_frame = Signal()                     # the current frame is in local mode
        t_frame = Signal(pb, reset_less=True)
        b_frame = Signal(pb, reset_less=True)
        t_new = Mux(use_global, levels.threshold, self.threshold)
        b_new = Mux(use_global, levels.background, self.background)
        threshold = Mux(pos.sof_valid, Mux(local_new, offset_sat, t_new), t_frame)
        background = Mux(pos.sof_valid, Mux(local_new, 0, b_new), b_frame)
        m.d.sync += [t_frame.eq(threshold), b_frame.eq(background)]
        with m.If(pos.sof_valid):
            m.d.sync += local_frame.eq(local_new)
        m.d.comb += [self.frame_threshold.eq(t_frame), self.frame_background.eq(b_frame)]
        pixel_levels = _PixelLevels(
            sof_valid=pos.sof_valid, local_new=local_new, use_global=use_global,
            local=(offset_sat, Const(0, pb)), global_=(levels.threshold, levels.background),
            fixed=(self.threshold, self.background), frame=(t_frame, b_frame))
        return _FrameMode(threshold=threshold, levels=pixel_levels, use_global=use_global,
                          window_ok=window_ok, local_new=local_new,
                          local=Mux(pos.sof, local_new, local_frame))

    def _statistics(self, m, pos, rotate_s1, rotate_s2):
        """``S1 = sum(p)`` and ``S2 = sum(p*p)`` of the frame's pixels (a stray pixel
        between frames leaves them alone; a sof restarts them), as ``_Sums``.  The
        global-levels search reads them in place by rotating them right (``rotate_s1``/
        ``rotate_s2``, exactly once per trial).  S1 after each pixel is also local mode's
        running sum."""
        inp = self.pixels
        s1_bits, s2_bits = _sum_widths(self.width, self.height, self.pixel_bits)
        s1 = Signal(s1_bits, reset_less=True)
        s2 = Signal(s2_bits, reset_less=True)
        p_frame = Mux(inp.valid & (pos.sof | pos.in_frame), pos.pixel, 0)
        s1_before = Mux(pos.sof_valid, 0, Mux(rotate_s1, s1.rotate_right(1), s1))
        s1_after = s1_before + p_frame
        # S2 takes each p*p two clocks late, through a register before the multiplier and
        # one after it (the search first reads S2 long after the frame's last pixel)
        p_square = Signal.like(pos.pixel, reset_less=True, name="p_square")
        square = Signal(2 * len(p_frame), reset_less=True)
        restart = Signal(reset_less=True, name="restart_square")
        restart_s2 = Signal(reset_less=True)
        m.d.sync += [
            s1.eq(s1_after), p_square.eq(p_frame), square.eq(p_square * p_square),
            restart.eq(pos.sof_valid), restart_s2.eq(restart),
            s2.eq(Mux(restart_s2, 0, Mux(rotate_s2, s2.rotate_right(1), s2)) + square),
        ]
        return _Sums(s1=s1, s2=s2, s1_before=s1_before, s1_after=s1_after)

    def _window_input(self, m, pos, mode, sums, window):
        """The local delay line's input: each pixel of a local-mode frame, with the
        running S1 after it and before it; a ``sof`` of any mode restarts it."""
        inp, beat = self.pixels, window.pixels.payload
        m.d.comb += [
            window.pixels.valid.eq(inp.valid & mode.local & (pos.sof | pos.in_frame)),
            beat.data.eq(pos.pixel), beat.x.eq(pos.x), beat.y.eq(pos.y), beat.sof.eq(pos.sof),
            beat.eof.eq(pos.frame_end), beat.row_end.eq(pos.last_col | pos.eol),
            beat.sum_after.eq(sums.s1_after), beat.sum_before.eq(sums.s1_before),
            window.start.eq(pos.sof_valid), window.log2_window.eq(self.local_log2_window),
        ]

    def _frame_status(self, m, pos, mode, tail_pending):
        """Latched on each sof: the frame's fallbacks, and whether it dropped the delay
        line's ``tail_pending`` pixels."""
        with m.If(pos.sof_valid):
            m.d.sync += [
                self.frame_fallback.eq((self.mode == ThresholdMode.GLOBAL) & ~mode.use_global),
                self.frame_local_fallback.eq((self.mode == ThresholdMode.LOCAL) &
                                             ~mode.window_ok),
                self.frame_tail_dropped.eq(tail_pending),
            ]

    def _output(self, m, pos, mode, local):
        """Output register: the input pixel (fixed, global) or the delay line's ``local``
        beat.  ``p > min(M + offset, fs)`` is ``p - M > offset`` for ``p <= fs``;
        ``mode.threshold`` is the offset in a local frame."""
        pb, out, lp = self.pixel_bits, self.out, local.payload
        fixed_valid = self.pixels.valid & ~mode.local
        beat = Signal.like(out.payload, reset_less=True)
        m.d.comb += out.payload.eq(beat)
        value = Mux(local.valid, lp.data, pos.pixel)
        above_local = lp.data - lp.mean
        above = Mux(local.valid, above_local,                    # weight if >= 0
                    mode.levels.apply(lambda t, b: pos.pixel - b))
        below = Mux(local.valid, mode.threshold - above_local,   # < 0: lit
                    mode.levels.apply(lambda t, b: t - pos.pixel))
        m.d.sync += [
            out.valid.eq(fixed_valid | local.valid),
            beat.data.eq(value),
            beat.x.eq(Mux(local.valid, lp.x, pos.x)),
            beat.y.eq(Mux(local.valid, lp.y, pos.y)),
            beat.lit.eq(below[-1]),
            beat.weight.eq(Mux(above[-1], 0, above[:pb])),
            beat.eof.eq(Mux(local.valid, lp.eof, pos.frame_end)),
        ]


class LocalWindow(wiring.Component):
    """Local mode's delay line and window mean for ``width x height`` frames of
    ``pixel_bits`` pixels.  Each pixel is stored with its position, eof and window flags
    and with two copies of the frame's running S1 (after it and before it), read back once
    its window's last pixel is in, and goes through six stages: read data registered,
    window addresses, window sums registered, window sum less the pixel, mean, output
    register.  Every memory's read data goes straight into a register and every read
    address comes from registers through one adder (post-route timing,
    ``docs/synthesis.md``).

    Parameters
    ----------
    width, height : int
        Frame size in pixels.
    pixel_bits : int
        Bits per pixel.

    Members
    -------
    pixels : ``In(stream.Signature(local_pixel_layout(...), always_ready=True))``
        The pixels of local-mode frames, in raster order, at most one per clock: position,
        ``sof``, ``eof``, ``row_end`` (the line's last pixel) and the frame's running S1
        after and before the pixel (``local_sum_bits`` wide).
    start : ``In(1)``
        A frame starts (a ``sof`` pixel of any mode): the pixels left in the line are
        discarded and ``log2_window`` is latched.
    log2_window : ``In(C.REGISTER_BY_NAME["local_log2_window"].bits)``
        ``log2 L`` of the frame that starts (its pixels come only if the window is
        narrower than the frame: ``local_log2_window_max``).
    out : ``Out(stream.Signature(local_mean_layout(width, height, pixel_bits), always_ready=True))``
        Each pixel with ``mean``, the mean of the ``L`` other pixels of its window (its
        row's columns ``contract.local_window_start`` to that ``+ L``), ``LOCAL_LATENCY - 1``
        clocks after the input pixel that made it ready: the ``L``-th after it, or its
        row's last (one per clock while more are ready).
    pending : ``Out(1)``
        Pixels are in the line (a ``start`` now would discard them).
    """

    def __init__(self, width, height, pixel_bits):
        self.width, self.height, self.pixel_bits = width, height, pixel_bits
        self.depth = local_depth(width)
        super().__init__({
            "pixels": In(stream.Signature(
                local_pixel_layout(width, height, pixel_bits,
                                   local_sum_bits(width, pixel_bits)), always_ready=True)),
            "start": In(1),
            "log2_window": In(C.REGISTER_BY_NAME["local_log2_window"].bits),
            "out": Out(stream.Signature(local_mean_layout(width, height, pixel_bits),
                                        always_ready=True)),
            "pending": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        log2_window = Signal.like(self.log2_window, reset_less=True,
                                  name="log2_window")   # of the current frame
        with m.If(self.start):
            m.d.sync += log2_window.eq(self.log2_window)
        window = Const(1, 1) << log2_window      # L of the current frame
        px_read, end_read, start_read, write_addr = self._write(m, log2_window)
        read, read_addr, unread = self._read(m, write_addr, window)
        stages = self._stages(m, px_read, end_read, start_read, read, read_addr, window,
                              log2_window)
        m.d.comb += self.pending.eq((unread != 0) | Cat(*stages).any())
        return m

    def _write(self, m, log2_window):
        """The delay line's memories, written with each input pixel (its entry, the S1
        copies); returns their read ports and the write address."""
        W, H, pb, depth = self.width, self.height, self.pixel_bits, self.depth
        inp = self.pixels.payload
        sum_bits = len(inp.sum_after)
        entry = delay_entry_layout(W, H, pb)
        m.submodules.px_mem = px_mem = Memory(shape=entry, depth=depth, init=[])
        m.submodules.end_mem = end_mem = Memory(shape=sum_bits, depth=depth, init=[])
        m.submodules.start_mem = start_mem = Memory(shape=sum_bits, depth=depth, init=[])
        write_addr = Signal(range(depth), reset_less=True)
        px_write, end_write, start_write = (px_mem.write_port(), end_mem.write_port(),
                                            start_mem.write_port())
        for port in (px_write, end_write, start_write):
            m.d.comb += [port.addr.eq(write_addr), port.en.eq(self.pixels.valid)]
        # the window of the pixel in column x: its last pixel s + L (an address of the end
        # copy) and its first s (of the start copy).  The window moves (s advances by one)
        # at each x with half < x <= W - 1 - half; elsewhere the start copy's read port
        # keeps its last word, so no read reaches back more than half pixels.  The flags
        # are those of the window the pixel's frame uses (latched at its sof).
        frame_window = Mux(inp.sof, self.log2_window, log2_window)
        move_first = Const(0, range(W + 1))   # the window moves from x = half + 1 up to,
        move_end = Const(0, range(W + 1))     # not including, x = W - half
        for k in _log2_windows(W):
            move_first = Mux(frame_window == k, (1 << (k - 1)) + 1, move_first)
            move_end = Mux(frame_window == k, W - (1 << (k - 1)), move_end)
        written = Signal(entry)
        m.d.comb += [written.data.eq(inp.data), written.x.eq(inp.x), written.y.eq(inp.y),
                     written.eof.eq(inp.eof), written.row_start.eq(inp.x == 0),
                     written.move_first.eq(inp.x == move_first),
                     written.move_end.eq(inp.x == move_end)]
        m.d.comb += [px_write.data.eq(written), end_write.data.eq(inp.sum_after),
                     start_write.data.eq(inp.sum_before)]
        with m.If(self.pixels.valid):
            m.d.sync += write_addr.eq(write_addr + 1)
        return px_mem.read_port(), end_mem.read_port(), start_mem.read_port(), write_addr

    def _read(self, m, write_addr, window):
        """One ready pixel read per clock: while more than ``window`` are unread, or a row
        end is among them.  Returns ``read``, its address and the count unread."""
        depth, write, drop = self.depth, self.pixels.valid, self.start
        unread = Signal(range(depth))         # pixels written and not yet read
        row_ended = Signal(range(depth))      # of them, those up to the last row end written
        read_addr = Signal(range(depth), reset_less=True)    # the oldest unread pixel
        # unread > window and row_ended != 0, registered from their next values: the read
        # decision starts at two flip-flops (after a drop unread <= 1 < 2 <= window)
        over, ended = Signal(name="read_over"), Signal(name="read_ended")
        read = (over | ended) & ~drop
        unread_next = (unread + Cat(write ^ read,
                                    (read & ~write).replicate(len(unread) - 1)))[:len(unread)]
        row_end = write & self.pixels.payload.row_end
        ended_next = Mux(row_end, unread_next, row_ended - (read & ended))[:len(row_ended)]
        with m.If(drop):
            m.d.sync += [read_addr.eq(write_addr), unread.eq(write), row_ended.eq(row_end),
                         over.eq(0), ended.eq(row_end)]
        with m.Else():
            m.d.sync += [read_addr.eq(read_addr + read), unread.eq(unread_next),
                         row_ended.eq(ended_next), over.eq(unread_next > window),
                         ended.eq(ended_next != 0)]
        return read, read_addr, unread

    def _stages(self, m, px_read, end_read, start_read, read, read_addr, window,
                log2_window):
        """The six stages from a read to ``out``; returns their valid flags."""
        depth, pb, drop = self.depth, self.pixel_bits, self.start
        entry = delay_entry_layout(self.width, self.height, pb)
        sum_bits = len(end_read.data)
        m.d.comb += px_read.addr.eq(read_addr)
        # stage 0: the pixel's entry on the read port, registered
        stage0_valid = Signal()
        stage0_addr = Signal(range(depth), reset_less=True)
        stage1 = Signal(entry, reset_less=True)
        stage1_valid = Signal()
        stage1_addr = Signal(range(depth), reset_less=True)
        stage1_end = Signal(range(depth), reset_less=True)   # stage1_addr + L
        m.d.sync += [stage0_valid.eq(read), stage0_addr.eq(read_addr),
                     stage1_valid.eq(stage0_valid & ~drop), stage1.eq(px_read.data),
                     stage1_addr.eq(stage0_addr), stage1_end.eq(stage0_addr + window)]

        # stage 1: the window's addresses; the start address is kept beside the end one
        # (start = end - L) so that each is one adder away from registers
        last_end = Signal(range(depth), reset_less=True)    # window end of the last pixel
        last_start = Signal(range(depth), reset_less=True)  # and its start
        moving = Signal(reset_less=True)  # the window moved at the row's previous pixel
        row_start = stage1.row_start
        step = (stage1.move_first | moving) & ~stage1.move_end & ~row_start
        end_addr = Mux(row_start, stage1_end, last_end + step)
        start_addr = Mux(row_start, stage1_addr, last_start + step)
        m.d.comb += [end_read.addr.eq(end_addr), start_read.addr.eq(start_addr),
                     start_read.en.eq(row_start | step)]
        stage2 = Signal(entry, reset_less=True)
        stage2_valid = Signal()
        m.d.sync += [stage2_valid.eq(stage1_valid & ~drop), stage2.eq(stage1)]
        with m.If(stage1_valid):
            m.d.sync += [last_end.eq(end_addr), last_start.eq(start_addr), moving.eq(step)]

        # stage 2: the window's sums on the read ports, registered
        stage3 = Signal(entry, reset_less=True)
        stage3_valid = Signal()
        end_sum = Signal(sum_bits, reset_less=True)
        start_sum = Signal(sum_bits, reset_less=True)
        m.d.sync += [end_sum.eq(end_read.data), start_sum.eq(start_read.data),
                     stage3_valid.eq(stage2_valid & ~drop), stage3.eq(stage2)]

        # stage 3: the sum of the window's other L pixels
        stage4 = Signal(entry, reset_less=True)
        stage4_valid = Signal()
        others = Signal(sum_bits, reset_less=True)
        m.d.sync += [others.eq(end_sum - start_sum - stage3.data),
                     stage4_valid.eq(stage3_valid & ~drop), stage4.eq(stage3)]
        # stage 4: the window mean M; others >> log2(L) as a product (an embedded
        # multiplier instead of a shifter)
        stage5 = Signal(entry, reset_less=True)
        stage5_valid = Signal()
        mean = Signal(pb, reset_less=True)
        # (the scale in a register: the window is latched at a sof, and no pixel of the
        # new frame reaches this stage within a clock of it)
        scale = Signal(1 << C.LOCAL_LOG2_WINDOW_MAX, reset_less=True)
        scale_now = Const(0, 1 << C.LOCAL_LOG2_WINDOW_MAX)
        for k in _log2_windows(self.width):
            scale_now = Mux(log2_window == k, 1 << (C.LOCAL_LOG2_WINDOW_MAX - k), scale_now)
        m.d.sync += scale.eq(scale_now)
        mean_now = (others * scale)[C.LOCAL_LOG2_WINDOW_MAX:][:pb]
        m.d.sync += [stage5_valid.eq(stage4_valid & ~drop), stage5.eq(stage4),
                     mean.eq(mean_now)]
        # stage 5 is the output register
        out = self.out.payload
        m.d.comb += [self.out.valid.eq(stage5_valid & ~drop), out.data.eq(stage5.data),
                     out.x.eq(stage5.x), out.y.eq(stage5.y), out.eof.eq(stage5.eof),
                     out.mean.eq(mean)]
        return [stage0_valid, stage1_valid, stage2_valid, stage3_valid, stage4_valid,
                stage5_valid]


class GlobalLevels(wiring.Component):
    """Global mode's levels for ``width x height`` frames of ``pixel_bits`` pixels: after
    each complete frame a sequential search finds ``B`` then ``D``, bit by bit, MSB first
    (``c``: the bits found so far with the trial bit set): ``B``: ``N*c <= S1``; ``D``:
    ``256*N*N*c*c <= K*K*(N*S2 - S1*S1)``; then ``T = min(B + D, fs)``.  Each trial streams
    both sides LSB first through serial multipliers into a serial subtraction whose last
    borrow decides it.  B's first trial only flushes what an abandoned computation left in
    the multipliers of ``c``.  It takes ``global_cycles`` clocks, and ``ksigma_cycles`` after
    a ``ksigma`` write.

    Parameters
    ----------
    width, height : int
        Frame size in pixels (``N = width * height``).
    pixel_bits : int
        Bits per pixel.

    Members
    -------
    s1, s2 : ``In``
        The frame's ``S1 = sum(p)`` and ``S2 = sum(p*p)`` registers, read in place: while
        ``rotate_s1`` (``rotate_s2``) is high their owner rotates them right by one bit a
        clock, exactly once per trial, and bit 0 is the bit streamed.
    rotate_s1, rotate_s2 : ``Out(1)``
        Rotate ``s1`` (``s2``) this clock.
    start : ``In(1)``
        A ``sof`` pixel: the sums restart (a search under way is abandoned).
    frame_end : ``In(1)``
        A frame's last pixel; ``complete`` with it when every line of the frame was
        ``width`` long: the search starts on its sums.
    complete : ``In(1)``
        See ``frame_end``.
    in_frame : ``In(1)``
        A frame started and has not ended (the levels of a frame cut short are invalid).
    ksigma : ``In(C.KSIGMA_BITS)``
        The ``ksigma`` register: read as the ``D`` search starts; a value that differs from
        ``valid_ksigma`` restarts the ``D`` search.
    threshold, background : ``Out(pixel_bits)``
        The levels ``T`` and ``B`` found, for ``valid_ksigma`` while ``valid``.
    valid : ``Out(1)``
        ``threshold`` and ``background`` hold the last complete frame's levels.
    valid_ksigma : ``Out(C.KSIGMA_BITS)``
        The ``ksigma`` of the levels.
    busy : ``Out(1)``
        A trial is under way.
    """

    def __init__(self, width, height, pixel_bits):
        self.width, self.height, self.pixel_bits = width, height, pixel_bits
        s1_bits, s2_bits = _sum_widths(width, height, pixel_bits)
        super().__init__({
            "s1": In(s1_bits), "s2": In(s2_bits),
            "rotate_s1": Out(1), "rotate_s2": Out(1),
            "start": In(1), "frame_end": In(1), "complete": In(1), "in_frame": In(1),
            "ksigma": In(C.KSIGMA_BITS),
            "threshold": Out(pixel_bits), "background": Out(pixel_bits), "valid": Out(1),
            "valid_ksigma": Out(C.KSIGMA_BITS),
            "busy": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        W, H, pb = self.width, self.height, self.pixel_bits
        N, fs = W * H, C.full_scale(pb)
        s1, s2 = self.s1, self.s2
        threshold = Signal(pb, reset_less=True, name="next_threshold")
        background = Signal(pb, reset_less=True, name="next_background")
        valid = Signal(name="levels_valid")   # they hold the levels for ``ksigma``
        ksigma = Signal(C.KSIGMA_BITS, reset_less=True, name="levels_ksigma")
        have_sums = Signal()   # S1, S2 hold a complete frame and ``background`` its B
        m.d.comb += [self.threshold.eq(threshold), self.background.eq(background),
                     self.valid.eq(valid), self.valid_ksigma.eq(ksigma)]
        # the compare registered (a timing cut between the ksigma registers and the
        # search's control): a write is noticed a clock late; the search reads it only at
        # a trial's last clock or while idle, never the clock after loading ``ksigma``
        ksigma_same = Signal(name="ksigma_same")
        m.d.sync += ksigma_same.eq(ksigma == self.ksigma)
        b_bits, d_bits = _pass_bits(W, H, pb)
        run = Signal(name="search_run")      # a trial is under way
        searching_d = Signal()               # else B
        trial_clock = Signal(range(max(b_bits, d_bits)), reset_less=True)  # bit streamed
        trial = Signal(pb + 1, reset_less=True)  # the trial bit, one-hot (pb: B's flush)
        found = Signal(pb, reset_less=True)  # the bits of B or D found so far
        last = trial_clock == Mux(searching_d, d_bits - 1, b_bits - 1)
        c = found | trial[:pb]
        # the reference constant of a trial (N for B, (N << 8)**2 for D), streamed LSB
        # first from a shift register loaded when the trial starts (no lookup by clock)
        ref_b, ref_d = Const(N), Const((N << C.KSIGMA_FRAC_BITS) ** 2)
        ref = Signal(max(len(ref_b), len(ref_d)), reset_less=True)

        # the multiplicand of S1*S1 (s1 rotates)
        s1_copy = Signal(len(s1), reset_less=True, name="s1_copy")
        m.d.comb += [self.rotate_s1.eq(run & _below_const(trial_clock, len(s1))),
                     self.rotate_s2.eq(run & searching_d & _below_const(trial_clock, len(s2)))]
        s1_bit = s1[0] & self.rotate_s1
        variance_bit, _ = _serial_sub(
            m, _serial_mul(m, s2[0] & self.rotate_s2, Const(N)),
            _serial_mul(m, s1_bit & searching_d, s1_copy), run & ~last)
        # D's two sides each delayed a clock by a register (the chain's timing cut)
        variance = Signal(reset_less=True, name="variance_bit")
        m.d.sync += variance.eq(variance_bit)
        lhs_d = _serial_mul(m, _serial_mul(m, variance, ksigma), ksigma)
        reference = ref[0] & run
        rhs_b = _serial_mul(m, reference, c)
        rhs_d = Signal(reset_less=True, name="rhs_d_bit")
        m.d.sync += rhs_d.eq(_serial_mul(m, rhs_b & searching_d, c))
        _, borrow = _serial_sub(m, Mux(searching_d, lhs_d, s1_bit),
                                Mux(searching_d, rhs_d, rhs_b), run & ~last)
        passed = ~borrow             # at the trial's last bit

        start_d = [searching_d.eq(1), ksigma.eq(self.ksigma), trial.eq(1 << (pb - 1)),
                   found.eq(0), trial_clock.eq(0), s1_copy.eq(s1), ref.eq(ref_d)]
        m.d.comb += self.busy.eq(run)
        found_now = Mux(passed, c, found)    # at a trial's last bit

        def saturated(d):
            """T = min(B + d, fs), from registers only."""
            level = background + d
            return Mux(level[pb], fs, level[:pb])
        # both outcomes of the last trial precomputed, so ``passed`` only selects
        threshold_now = Mux(passed, saturated(c), saturated(found))
        with m.If(self.complete):
            m.d.sync += [valid.eq(0), have_sums.eq(0), run.eq(1), searching_d.eq(0),
                         trial.eq(1 << pb), found.eq(0), trial_clock.eq(0), ref.eq(ref_b)]
        with m.Elif(self.frame_end | self.start):   # S1, S2 restart, or a broken frame
            m.d.sync += [have_sums.eq(0), run.eq(0)]
            with m.If(self.frame_end | self.in_frame | run):
                m.d.sync += valid.eq(0)
        with m.Elif(~run):
            with m.If(have_sums & ~ksigma_same):   # ksigma rewritten: search D anew
                m.d.sync += [valid.eq(0), run.eq(1)] + start_d
        with m.Else():
            m.d.sync += [trial_clock.eq(trial_clock + 1), ref.eq(ref >> 1)]
            with m.If(last):
                m.d.sync += [trial_clock.eq(0), trial.eq(trial >> 1), found.eq(found_now),
                             ref.eq(Mux(searching_d, ref_d, ref_b))]
                with m.If(searching_d & ~ksigma_same):
                    m.d.sync += start_d                   # rewritten meanwhile: restart
                with m.Elif(trial[0] & ~searching_d):
                    m.d.sync += [have_sums.eq(1), background.eq(found_now)] + start_d
                with m.Elif(trial[0]):                    # T = min(B + D', fs)
                    m.d.sync += [run.eq(0), valid.eq(1), threshold.eq(threshold_now)]
        return m
