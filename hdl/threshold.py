"""Threshold unit: pixel stream in, lit flag and weight out, one pixel per clock.

Implements the ``fixed``, ``global`` and ``local`` modes of ``lodestar.contract`` bit-exactly
(``docs/gateware.md`` describes how, with each mode's latency and blanking).  ``pixels``: one
pixel per clock while ``valid`` (no backpressure), ``sof`` on a frame's first pixel, ``eol``
on each line's last; registers are latched on the ``sof`` pixel.  ``out``: one beat per pixel
in raster order, ``lit = p > T``, ``weight = max(p - B, 0)``, ``eof`` on the frame's last.
Fixed and global mode answer one clock later, local mode ``LOCAL_LATENCY`` clocks after the
pixel that made a beat ready.  A frame that cannot use its mode's levels uses the fixed
registers and says so (``frame_fallback``, ``frame_local_fallback``, ``frame_tail_dropped``).
"""

from types import SimpleNamespace

from amaranth import Cat, Const, Module, Mux, Signal
from amaranth.lib import stream, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

from lodestar import contract as C

from .layouts import ThresholdMode, check_frame, delay_entry_layout, lit_layout, pixel_layout


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
    trial per bit of ``D``) and the rest of the trial under way when it was written."""
    _, ld = _pass_bits(width, height, pixel_bits)
    return (pixel_bits + 1) * ld


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



class ThresholdUnit(wiring.Component):
    """Fixed, global and local thresholds for ``width x height`` frames of ``pixel_bits``
    pixels.  Status outputs, latched on each ``sof``: ``frame_threshold``/
    ``frame_background`` (the frame's T and B), ``frame_fallback``,
    ``frame_local_fallback``, ``frame_tail_dropped`` (``docs/gateware.md``).  ``stats_busy`` is
    high while the global levels are being computed."""

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
        pos = self._position(m)
        levels = self._global_levels_state()
        mode = self._frame_mode(m, pos, levels)
        sums = self._statistics(m, pos)
        local = self._local_mode(m, pos, mode, sums)
        self._frame_status(m, pos, mode, levels, local)
        self._output(m, pos, mode, local)
        self._global_mode(m, pos, levels, sums)
        return m

    # ---- shared: positions, frame mode and levels, statistics, output -------------------
    def _position(self, m):
        """Position of the input pixel and frame integrity, as the input counts them."""
        W, H, inp = self.width, self.height, self.pixels
        sof = inp.payload.sof
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
        return SimpleNamespace(
            sof=sof, sof_valid=inp.valid & sof, pixel=inp.payload.data, x=cur_x, y=cur_y,
            last_col=last_col, line_error=line_error, frame_end=frame_end, in_frame=in_frame,
            # a frame that ends here with every line W long
            complete=frame_end & Mux(sof, 1, frame_ok) & ~line_error)

    def _global_levels_state(self):
        """Registers the global-levels search fills and the frame start reads."""
        pb = self.pixel_bits
        return SimpleNamespace(
            threshold=Signal(pb, reset_less=True, name="next_threshold"),
            background=Signal(pb, reset_less=True, name="next_background"),
            valid=Signal(name="levels_valid"),   # they hold the levels for ``ksigma``
            ksigma=Signal(C.KSIGMA_BITS, reset_less=True, name="levels_ksigma"),
            have_sums=Signal(),   # S1, S2 hold a complete frame and ``background`` its B
        )

    def _frame_mode(self, m, pos, levels):
        """The mode a frame starting now uses and its T and B (local mode: the offset and
        0), latched on the ``sof`` pixel."""
        W, pb, fs = self.width, self.pixel_bits, C.full_scale(self.pixel_bits)
        # a sof while in_frame: the previous frame never ended, so its statistics are
        # missing and this frame falls back, as after an incomplete frame.  (levels.valid
        # is 0 while the levels are being computed.)
        use_global = ((self.mode == ThresholdMode.GLOBAL) & levels.valid &
                      (levels.ksigma == self.ksigma) & ~pos.in_frame)
        log2_window_max = local_log2_window_max(W)    # window narrower than the frame
        log2_windows = range(C.LOCAL_LOG2_WINDOW_MIN,
                             (log2_window_max or C.LOCAL_LOG2_WINDOW_MIN - 1) + 1)
        window_ok = Const(0)
        for k in log2_windows:
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
        m.d.comb += [self.frame_threshold.eq(t_frame), self.frame_background.eq(b_frame)]

        def apply(f):
            """``f(T, B)`` of this pixel's levels, computed for each candidate and selected
            after (the sof's mode decision runs beside ``f``'s arithmetic: timing)."""
            new = Mux(local_new, f(offset_sat, Const(0, pb)),
                      Mux(use_global, f(levels.threshold, levels.background),
                          f(self.threshold, self.background)))
            return Mux(pos.sof_valid, new, f(t_frame, b_frame))
        return SimpleNamespace(
            threshold=threshold, use_global=use_global, apply=apply,
            window_ok=window_ok, local_new=local_new,
            local_frame=local_frame, local=Mux(pos.sof, local_new, local_frame),
            log2_window=Signal.like(self.local_log2_window, reset_less=True,
                                    name="log2_window"),   # of the current frame
            log2_windows=log2_windows, log2_window_max=log2_window_max)

    def _statistics(self, m, pos):
        """``S1 = sum(p)`` and ``S2 = sum(p*p)`` of the frame's pixels (a stray pixel
        between frames leaves them alone; a sof restarts them).  The global-levels search
        reads them in place by rotating them right (``rotate_s1``/``rotate_s2``, exactly
        once per trial).  S1 after each pixel is also local mode's running sum."""
        N, fs, inp = self.width * self.height, C.full_scale(self.pixel_bits), self.pixels
        s1 = Signal(C.bits_for(N * fs), reset_less=True)
        s2 = Signal(C.bits_for(N * fs * fs), reset_less=True)
        p_frame = Mux(inp.valid & (pos.sof | pos.in_frame), pos.pixel, 0)
        rotate_s1, rotate_s2 = Signal(), Signal()
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
        return SimpleNamespace(s1=s1, s2=s2, rotate_s1=rotate_s1, rotate_s2=rotate_s2,
                               s1_before=s1_before, s1_after=s1_after)

    def _frame_status(self, m, pos, mode, levels, local):
        """Latched on each sof: the frame's mode, its fallbacks and dropped tail."""
        with m.If(pos.sof_valid):
            m.d.sync += [
                self.frame_fallback.eq((self.mode == ThresholdMode.GLOBAL) & ~mode.use_global),
                self.frame_local_fallback.eq((self.mode == ThresholdMode.LOCAL) &
                                             ~mode.window_ok),
                self.frame_tail_dropped.eq(local.pending),
                mode.local_frame.eq(mode.local_new), mode.log2_window.eq(self.local_log2_window),
                pos.in_frame.eq(1),
            ]
        with m.If(pos.frame_end):
            m.d.sync += pos.in_frame.eq(0)

    def _output(self, m, pos, mode, local):
        """Output register: the input pixel (fixed, global) or the delay line's (local).
        ``p > min(M + offset, fs)`` is ``p - M > offset`` for ``p <= fs``; ``mode.threshold``
        is the offset in a local frame."""
        pb, out = self.pixel_bits, self.out
        fixed_valid = self.pixels.valid & ~mode.local
        beat = Signal.like(out.payload, reset_less=True)
        m.d.comb += out.payload.eq(beat)
        value = Mux(local.valid, local.data, pos.pixel)
        above_local = local.data - local.mean
        above = Mux(local.valid, above_local,                    # weight if >= 0
                    mode.apply(lambda t, b: pos.pixel - b))
        below = Mux(local.valid, mode.threshold - above_local,   # < 0: lit
                    mode.apply(lambda t, b: t - pos.pixel))
        m.d.sync += [
            out.valid.eq(fixed_valid | local.valid),
            beat.data.eq(value),
            beat.x.eq(Mux(local.valid, local.x, pos.x)),
            beat.y.eq(Mux(local.valid, local.y, pos.y)),
            beat.lit.eq(below[-1]),
            beat.weight.eq(Mux(above[-1], 0, above[:pb])),
            beat.eof.eq(Mux(local.valid, local.eof, pos.frame_end)),
        ]

    # ---- local mode ---------------------------------------------------------------------
    def _local_mode(self, m, pos, mode, sums):
        """Delay line and window mean.  Each pixel of a local-mode frame is stored with its
        position, eof and window flags and with two copies of the frame's running S1 (after
        it and before it), read back once ready, and goes through six stages: read data
        registered, window addresses, window sums registered, window sum less the pixel,
        mean, output register.  Every memory's read data goes straight into a register and
        every read address comes from registers through one adder (post-route timing,
        ``docs/synthesis.md``)."""
        W, H, pb = self.width, self.height, self.pixel_bits
        fs, inp = C.full_scale(pb), self.pixels
        depth = local_depth(W)
        window_max = 1 << (mode.log2_window_max or C.LOCAL_LOG2_WINDOW_MIN)
        sum_bits = C.bits_for((window_max + 1) * fs)
        entry = delay_entry_layout(W, H, pb)
        m.submodules.px_mem = px_mem = Memory(shape=entry, depth=depth, init=[])
        m.submodules.end_mem = end_mem = Memory(shape=sum_bits, depth=depth, init=[])
        m.submodules.start_mem = start_mem = Memory(shape=sum_bits, depth=depth, init=[])
        px_read, end_read, start_read = (px_mem.read_port(), end_mem.read_port(),
                                         start_mem.read_port())
        write = inp.valid & mode.local & (pos.sof | pos.in_frame)  # a local-mode frame's pixel
        drop = pos.sof_valid        # a new frame: discard what is left of the last one
        write_addr = Signal(range(depth), reset_less=True)
        px_write, end_write, start_write = (px_mem.write_port(), end_mem.write_port(),
                                            start_mem.write_port())
        for port in (px_write, end_write, start_write):
            m.d.comb += [port.addr.eq(write_addr), port.en.eq(write)]
        # the window of the pixel in column x: its last pixel s + L (an address of the end
        # copy) and its first s (of the start copy).  The window moves (s advances by one)
        # at each x with half < x <= W - 1 - half; elsewhere the start copy's read port
        # keeps its last word, so no read reaches back more than half pixels.  The flags
        # are those of the window the pixel's frame uses (latched at its sof).
        log2_window = Mux(pos.sof, self.local_log2_window, mode.log2_window)
        move_first = Const(0, range(W + 1))   # the window moves from x = half + 1 up to,
        move_end = Const(0, range(W + 1))     # not including, x = W - half
        for k in mode.log2_windows:
            move_first = Mux(log2_window == k, (1 << (k - 1)) + 1, move_first)
            move_end = Mux(log2_window == k, W - (1 << (k - 1)), move_end)
        written = Signal(entry)
        m.d.comb += [written.data.eq(pos.pixel), written.x.eq(pos.x), written.y.eq(pos.y),
                     written.eof.eq(pos.frame_end), written.row_start.eq(pos.x == 0),
                     written.move_first.eq(pos.x == move_first),
                     written.move_end.eq(pos.x == move_end)]
        m.d.comb += [px_write.data.eq(written),
                     end_write.data.eq(sums.s1_after[:sum_bits]),
                     start_write.data.eq(sums.s1_before[:sum_bits])]
        window = Const(1, 1) << mode.log2_window      # L of the current frame
        with m.If(write):
            m.d.sync += write_addr.eq(write_addr + 1)

        # reads, one ready pixel per clock
        unread = Signal(range(depth))         # pixels written and not yet read
        row_ended = Signal(range(depth))      # of them, those up to the last row end written
        read_addr = Signal(range(depth), reset_less=True)    # the oldest unread pixel
        read = ((unread > window) | (row_ended != 0)) & ~drop
        unread_next = unread + Cat(write ^ read, (read & ~write).replicate(len(unread) - 1))
        row_end = write & (pos.last_col | inp.payload.eol)
        m.d.comb += px_read.addr.eq(read_addr)
        with m.If(drop):
            m.d.sync += [read_addr.eq(write_addr), unread.eq(write), row_ended.eq(row_end)]
        with m.Else():
            m.d.sync += [read_addr.eq(read_addr + read), unread.eq(unread_next),
                         row_ended.eq(Mux(row_end, unread_next,
                                          row_ended - (read & (row_ended != 0))))]

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
        for k in mode.log2_windows:
            scale_now = Mux(mode.log2_window == k, 1 << (C.LOCAL_LOG2_WINDOW_MAX - k),
                            scale_now)
        m.d.sync += scale.eq(scale_now)
        mean_now = (others * scale)[C.LOCAL_LOG2_WINDOW_MAX:][:pb]
        m.d.sync += [stage5_valid.eq(stage4_valid & ~drop), stage5.eq(stage4),
                     mean.eq(mean_now)]
        # stage 5 is the output register
        return SimpleNamespace(
            valid=stage5_valid & ~drop, data=stage5.data, x=stage5.x, y=stage5.y,
            eof=stage5.eof, mean=mean,
            pending=(unread != 0) | stage0_valid | stage1_valid | stage2_valid |
            stage3_valid | stage4_valid | stage5_valid)

    # ---- global mode --------------------------------------------------------------------
    def _global_mode(self, m, pos, levels, sums):
        """Sequential global-levels search after each complete frame: ``B`` then ``D``,
        bit by bit, MSB first (``c``: the bits found so far with the trial bit set):
        ``B``: ``N*c <= S1``; ``D``: ``256*N*N*c*c <= K*K*(N*S2 - S1*S1)``.  Each trial
        streams both sides LSB first through serial multipliers into a serial subtraction
        whose last borrow decides it.  B's first trial only flushes what an abandoned
        computation left in the multipliers of ``c``."""
        W, H, pb = self.width, self.height, self.pixel_bits
        N, fs = W * H, C.full_scale(pb)
        s1, s2 = sums.s1, sums.s2
        ksigma_same = levels.ksigma == self.ksigma
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

        s1_copy = Signal.like(s1, name="s1_copy")  # the multiplicand of S1*S1 (s1 rotates)
        m.d.comb += [sums.rotate_s1.eq(run & _below_const(trial_clock, len(s1))),
                     sums.rotate_s2.eq(run & searching_d & _below_const(trial_clock, len(s2)))]
        s1_bit = s1[0] & sums.rotate_s1
        variance_bit, _ = _serial_sub(
            m, _serial_mul(m, s2[0] & sums.rotate_s2, Const(N)),
            _serial_mul(m, s1_bit & searching_d, s1_copy), run & ~last)
        # D's two sides each delayed a clock by a register (the chain's timing cut)
        variance = Signal(reset_less=True, name="variance_bit")
        m.d.sync += variance.eq(variance_bit)
        lhs_d = _serial_mul(m, _serial_mul(m, variance, levels.ksigma), levels.ksigma)
        reference = ref[0] & run
        rhs_b = _serial_mul(m, reference, c)
        rhs_d = Signal(reset_less=True, name="rhs_d_bit")
        m.d.sync += rhs_d.eq(_serial_mul(m, rhs_b & searching_d, c))
        _, borrow = _serial_sub(m, Mux(searching_d, lhs_d, s1_bit),
                                Mux(searching_d, rhs_d, rhs_b), run & ~last)
        passed = ~borrow             # at the trial's last bit

        def start_d():
            return [searching_d.eq(1), levels.ksigma.eq(self.ksigma),
                    trial.eq(1 << (pb - 1)), found.eq(0), trial_clock.eq(0), s1_copy.eq(s1),
                    ref.eq(ref_d)]

        m.d.comb += self.stats_busy.eq(run)
        found_now = Mux(passed, c, found)    # at a trial's last bit

        def threshold(d):
            """T = min(B + d, fs), from registers only."""
            level = levels.background + d
            return Mux(level[pb], fs, level[:pb])
        # both outcomes of the last trial precomputed, so ``passed`` only selects
        threshold_now = Mux(passed, threshold(c), threshold(found))
        with m.If(pos.complete):
            m.d.sync += [levels.valid.eq(0), levels.have_sums.eq(0), run.eq(1),
                         searching_d.eq(0), trial.eq(1 << pb), found.eq(0), trial_clock.eq(0),
                         ref.eq(ref_b)]
        with m.Elif(pos.frame_end | pos.sof_valid):   # S1, S2 restart, or a broken frame
            m.d.sync += [levels.have_sums.eq(0), run.eq(0)]
            with m.If(pos.frame_end | pos.in_frame | run):
                m.d.sync += levels.valid.eq(0)
        with m.Elif(~run):
            with m.If(levels.have_sums & ~ksigma_same):   # ksigma rewritten: search D anew
                m.d.sync += [levels.valid.eq(0), run.eq(1)] + start_d()
        with m.Else():
            m.d.sync += [trial_clock.eq(trial_clock + 1), ref.eq(ref >> 1)]
            with m.If(last):
                m.d.sync += [trial_clock.eq(0), trial.eq(trial >> 1), found.eq(found_now),
                             ref.eq(Mux(searching_d, ref_d, ref_b))]
                with m.If(searching_d & ~ksigma_same):
                    m.d.sync += start_d()                 # rewritten meanwhile: restart
                with m.Elif(trial[0] & ~searching_d):
                    m.d.sync += [levels.have_sums.eq(1),
                                 levels.background.eq(found_now)] + start_d()
                with m.Elif(trial[0]):                    # T = min(B + D', fs)
                    m.d.sync += [run.eq(0), levels.valid.eq(1),
                                 levels.threshold.eq(threshold_now)]
