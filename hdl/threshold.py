"""Threshold unit: pixel stream in, lit flag and weight out, at one pixel per clock.

Implements the ``fixed``, ``global`` and ``local`` modes of ``lodestar.contract``
bit-exactly.

Stream conventions: ``pixels`` carries one pixel per clock while ``valid`` (no backpressure,
a sensor cannot be stalled) with ``sof`` on the first pixel of a frame and ``eol`` on the
last pixel of each line.  Positions count as the input arrives: ``sof`` is at (0, 0), ``x``
returns to 0 after column ``W - 1`` or an ``eol`` and ``y`` advances with it; a frame ends on
the pixel at ``(W - 1, H - 1)`` and is *complete* (for the statistics) if every line was
``W`` long.  The runtime registers are latched on the ``sof`` pixel.  ``out`` carries one
beat per pixel in raster order with the pixel, its position, ``lit = p > T`` and
``weight = max(p - B, 0)``, and ``eof`` on the frame's last pixel.  The ``frame_*`` outputs
are latched on each ``sof`` and describe that frame.

Fixed and global mode: ``out`` follows the input one clock later.

Global mode: the unit accumulates ``S1 = sum(p)`` and ``S2 = sum(p*p)`` over every frame
(in every mode).  When a frame completes a sequential unit computes the next frame's
levels exactly as ``contract.global_levels``::

    B = S1 // N;  V = N*S2 - S1**2;  r = isqrt(K*K*V);  T = min(B + r // (16 N), full_scale)

in shift registers, one bit per clock and no variable shift: shift-add multipliers (a
product register shifting right, its LSB the next multiplier bit), restoring dividers (the
dividend shifting into the remainder) and a digit-by-digit square root (the operand shifting
out two bits a clock); ``B``, ``S1**2`` and ``N*S2`` are computed side by side.  The levels
are ready ``global_cycles(width, height, pixel_bits)`` clocks after the frame's last pixel
(188 for 2592 x 1944 x 12 bits).
The ``ksigma`` register is read when the k-dependent part starts; if the MCU rewrites it
between frames, that part (``ksigma_cycles(...)`` clocks) is redone.  So the levels are
those of the ksigma in effect at the next frame's start provided the register was written
at least ``ksigma_cycles`` clocks before it (and the frame's last pixel came at least
``global_cycles`` before).  A frame that starts earlier, or after an incomplete frame, uses
the fixed registers and raises ``frame_fallback`` (``FRAME_GLOBAL_FALLBACK``).

Local mode (``L = 2**local_log2_window``, ``half = L/2``): per pixel ``x`` of a row, with
``s = contract.local_window_start(x, W, log2 L)``::

    M = (sum(p[s .. s+L]) - p[x]) >> log2(L);   T = min(M + local_offset, full_scale);   B = M

The window reaches up to ``L`` columns ahead of ``x``, so local-mode pixels go through a
circular buffer of ``local_depth(W)`` entries (256 for ``L`` up to 128), in three copies in
synchronous-read memories (one M9K each): one read at ``x``, with the pixel's ``eol`` bit,
one at ``x + half`` and one at ``x - half - 1``.  The window sum is kept running: at
``x = 0`` it is the row's first window ``p[0] + .. + p[L]``, added up on the input side as
the row arrives and handed over in a register; at each ``x`` with
``half < x <= W - 1 - half`` (where ``s`` advances by one) it gains ``p[x + half]`` and
loses ``p[x - half - 1]``; elsewhere ``s`` is clamped and the sum stays.  A pixel is
*ready* once ``L`` more pixels of the frame have come after it, or its row's last pixel has
come; ready pixels are read one per clock, in order (every address read was written on an
earlier clock: no read-during-write), and a pixel's beat follows its read 4 clocks later
(window sum, ``M``, output register).

* Latency: a pixel's beat comes ``LOCAL_LATENCY`` (5) clocks after the input pixel that
  made it ready, or one clock after the previous beat if that is later; within a row
  streaming without gaps, ``L + 5`` clocks after the pixel itself (fixed mode: 1).  The
  last ``L`` pixels of a row follow the row's last pixel one per clock, during the
  horizontal blanking or the next row's first pixels: any horizontal blanking, none
  included, works.  After a frame's last pixel its remaining pixels drain by themselves;
  the ``eof`` beat comes at most ``L + 5`` clocks after it.
* Vertical blanking: after a local-mode frame, ``local_blanking(log2 L)`` = ``L + 4`` idle
  clocks between its last pixel and the next ``sof`` (132 for ``L = 128``; a sensor's
  vertical blanking, rows long, is more).  Before a local-mode frame none.  One frame at a
  time is in the buffer: a ``sof`` that comes earlier, or that cuts a local-mode frame
  short, discards the delayed pixels not yet out and raises ``frame_tail_dropped`` for the
  new frame, which is processed normally (its pixels never mix with the previous frame's).
  The pixels of a frame that stops mid-row wait in the buffer for the next ``sof``, which
  discards them.
* Frame geometry: the window must be narrower than the frame.  A frame started in local mode
  with ``2**local_log2_window >= W`` (or ``local_log2_window`` outside
  ``LOCAL_LOG2_WINDOW_MIN .. LOCAL_LOG2_WINDOW_MAX``) is processed with the fixed
  registers, one clock later, and raises ``frame_local_fallback``.
* Broken lines: in a local-mode frame with lines of the wrong length, positions are counted
  as above and the levels come from whatever pixels the buffer holds at the window's
  positions; every pixel still leaves once its row has ended.  Pixels that come after a
  local-mode frame ended and before the next ``sof`` belong to no frame and are not output.
* ``frame_threshold`` carries ``local_offset`` saturated to full scale (which leaves every
  ``T`` unchanged) and ``frame_background`` 0, as ``golden.frame.frame_levels`` reports them.
"""

from amaranth import Cat, Const, Module, Mux, Signal
from amaranth.lib import data, stream, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

from lodestar import contract as C


def pixel_layout(pixel_bits):
    """Input payload: the pixel and its frame/line markers."""
    return data.StructLayout({"data": pixel_bits, "sof": 1, "eol": 1})


def lit_layout(width, height, pixel_bits):
    """Output payload: pixel, position, lit flag, weight and the end-of-frame marker."""
    return data.StructLayout({
        "data": pixel_bits, "x": C.bits_for(width - 1), "y": C.bits_for(height - 1),
        "lit": 1, "weight": pixel_bits, "eof": 1,
    })


def _widths(width, height, pixel_bits):
    """Bit widths and clock counts of the global-mode arithmetic, from the contract's bounds."""
    n = width * height
    fs = C.full_scale(pixel_bits)
    kmax = (1 << C.KSIGMA_BITS) - 1
    w = {"n": C.bits_for(n), "s1": C.bits_for(n * fs), "s2": C.bits_for(n * fs * fs)}
    w["sq"] = 2 * w["s1"]                               # S1**2
    w["v"] = C.bits_for(n * n * fs * fs)                # N*S2 - S1**2 <= N**2 fs**2
    w["x"] = C.bits_for(kmax * kmax * n * n * fs * fs)  # K**2 V
    w["x"] += w["x"] & 1                                # even, for the square root
    w["r"] = w["x"] // 2
    w["k2"] = 2 * C.KSIGMA_BITS
    w["b"] = w["s1"] - w["n"] + 1                       # quotient bits of S1 // N
    w["d"] = w["r"] - C.bits_for(n << C.KSIGMA_FRAC_BITS) + 1   # of isqrt(K**2 V) // (16 N)
    w["rem"] = max(w["r"] + 1, C.bits_for(n << C.KSIGMA_FRAC_BITS))  # root / D remainder
    w["p"] = max(w["n"] + w["s2"], w["k2"] + w["v"], w["x"])  # product register
    return w


def ksigma_cycles(width, height, pixel_bits):
    """Clocks of the k-dependent part: K*K, K*K*V, square root, division, done."""
    w = _widths(width, height, pixel_bits)
    return C.KSIGMA_BITS + w["v"] + w["r"] + w["d"] + 2


def global_cycles(width, height, pixel_bits):
    """Clocks the global-mode computation needs after a frame's last pixel."""
    w = _widths(width, height, pixel_bits)
    # LOAD, then S1 // N, S1*S1 and N*S2 side by side, SUB, then the k-dependent part
    return 1 + w["s2"] + 1 + ksigma_cycles(width, height, pixel_bits)


def _mul_step(prod, multiplier_bits, multiplicand):
    """One clock of a shift-add multiplier: the new value of the product register ``prod``.

    The low ``multiplier_bits`` bits of ``prod`` hold the multiplier bits not used yet, LSB
    first, and the bits above them the partial product: ``multiplicand`` (a fixed value) is
    added above them if the LSB is set, then the register shifts right one bit.  Loaded with
    the multiplier (upper bits 0), ``prod`` holds the product after ``multiplier_bits``
    clocks; the adder is one bit wider than ``multiplicand``.
    """
    high = prod[multiplier_bits:multiplier_bits + len(multiplicand)]
    return Cat(prod[1:multiplier_bits], high + Mux(prod[0], multiplicand, 0))


def _div_step(rem, quo, divisor):
    """One clock of a restoring divider: the new values of ``(rem, quo)``.

    ``rem`` (the partial remainder, below ``divisor``) takes in the top bit of ``quo`` (the
    dividend bits not used yet, MSB first); ``divisor`` is subtracted if it fits and the
    quotient bit enters ``quo`` at the bottom.  Loaded with a dividend's top bits in ``rem``
    (below ``divisor``) and the rest in ``quo``, ``quo`` holds the quotient and ``rem`` the
    remainder after ``len(quo)`` clocks.
    """
    trial = Cat(quo[-1], rem)
    diff = trial - divisor
    fits = ~diff[-1]
    return Mux(fits, diff, trial)[:len(rem)], Cat(fits, quo[:-1])


LOCAL_LATENCY = 5
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
    pixels (module docstring).  Status outputs, latched on each ``sof``:
    ``frame_threshold``/``frame_background`` (the frame's T and B; in local mode the offset
    and 0), ``frame_fallback`` (global mode without levels: fixed registers used),
    ``frame_local_fallback`` (local mode with a window not narrower than the frame: fixed
    registers used), ``frame_tail_dropped`` (this ``sof`` discarded local-mode pixels of the
    previous frame that were not out yet).  ``stats_busy`` is high while the global levels
    are being computed."""

    def __init__(self, width, height, pixel_bits):
        if pixel_bits not in C.PIXEL_BITS:
            raise ValueError(f"pixel_bits={pixel_bits} is not one of {C.PIXEL_BITS}")
        if not (1 <= width <= C.MAX_WIDTH and 1 <= height <= C.MAX_HEIGHT):
            raise ValueError(f"frame {width}x{height} exceeds the contract's "
                             f"{C.MAX_WIDTH}x{C.MAX_HEIGHT}")
        self.width, self.height, self.pixel_bits = width, height, pixel_bits
        reg = C.REGISTER_BY_NAME
        super().__init__({
            "pixels": In(stream.Signature(pixel_layout(pixel_bits), always_ready=True)),
            "out": Out(stream.Signature(lit_layout(width, height, pixel_bits),
                                        always_ready=True)),
            "mode": In(reg["mode"].bits),
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
        N = W * H
        fs = C.full_scale(pb)
        wd = _widths(W, H, pb)
        inp, out = self.pixels, self.out
        p = inp.payload.data
        sof = inp.payload.sof

        # ---- position and frame integrity -------------------------------------------
        x = Signal(range(W))
        y = Signal(range(H))
        in_frame = Signal()
        frame_ok = Signal()          # every line so far was exactly W long
        cur_x = Mux(sof, 0, x)
        cur_y = Mux(sof, 0, y)
        last_col = cur_x == W - 1
        line_error = inp.payload.eol != last_col
        frame_end = inp.valid & last_col & (cur_y == H - 1) & (in_frame | sof)

        # ---- levels latched at the start of each frame -------------------------------
        next_t = Signal(pb)
        next_b = Signal(pb)
        stats_valid = Signal()       # next_t/next_b hold the levels for ksigma == kreg
        kreg = Signal(C.KSIGMA_BITS)  # the ksigma the levels are computed for
        have_v = Signal()            # the last frame was complete and V is computed
        t_frame = Signal(pb)
        b_frame = Signal(pb)
        # a sof while in_frame: the previous frame never ended, so its statistics are
        # missing and this frame falls back, as after an incomplete frame
        use_global = (self.mode == C.MODE_GLOBAL) & stats_valid & ~self.stats_busy & \
            (kreg == self.ksigma) & ~in_frame
        t_new = Mux(use_global, next_t, self.threshold)
        b_new = Mux(use_global, next_b, self.background)
        t_eff = Mux(sof, t_new, t_frame)
        b_eff = Mux(sof, b_new, b_frame)

        lg_reg = self.local_log2_window
        window_ok = ((lg_reg >= C.LOCAL_LOG2_WINDOW_MIN) & (lg_reg <= C.LOCAL_LOG2_WINDOW_MAX)
                     & ((Const(1, 1) << lg_reg) < W))
        local_new = (self.mode == C.MODE_LOCAL) & window_ok
        offset_sat = Mux(self.local_offset > fs, fs, self.local_offset)[:pb]
        local_frame = Signal()       # the current frame is processed in local mode
        lg = Signal.like(lg_reg)     # its log2(L) and offset
        offset = Signal(pb)
        local_pix = Mux(sof, local_new, local_frame)

        # ---- local mode: input side --------------------------------------------------
        depth = local_depth(W)
        win_max = 1 << (local_log2_window_max(W) or C.LOCAL_LOG2_WINDOW_MIN)
        sum_bits = C.bits_for((win_max + 1) * fs)
        entry = data.StructLayout({"data": pb, "eol": 1})
        m.submodules.px_mem = px_mem = Memory(shape=entry, depth=depth, init=[])
        m.submodules.add_mem = add_mem = Memory(shape=pb, depth=depth, init=[])
        m.submodules.sub_mem = sub_mem = Memory(shape=pb, depth=depth, init=[])
        px_rd, add_rd, sub_rd = px_mem.read_port(), add_mem.read_port(), sub_mem.read_port()
        wr = inp.valid & local_pix & (sof | in_frame)    # a pixel of a local-mode frame
        drop = inp.valid & sof       # a new frame: discard what is left of the last one
        wp = Signal(range(depth))    # buffer address of the next pixel written
        for mem in (px_mem, add_mem, sub_mem):
            port = mem.write_port()
            m.d.comb += [port.addr.eq(wp), port.en.eq(wr)]
            m.d.comb += port.data.eq(Cat(p, inp.payload.eol) if mem is px_mem else p)
        row_sum = Signal(sum_bits)   # p[0] + .. + p[x] (wraps after column L, unused then)
        first_sum = Signal(sum_bits)  # the row's first window p[0] + .. + p[L]
        row_sum_new = Mux(cur_x == 0, 0, row_sum) + p
        win = Const(1, 1) << lg      # L of the current frame
        half = win >> 1
        step_last = Signal(range(W))  # W - 1 - half of the current frame (latched with lg)
        with m.If(wr):
            m.d.sync += [wp.eq(wp + 1), row_sum.eq(row_sum_new)]
            with m.If(cur_x == win):
                m.d.sync += first_sum.eq(row_sum_new)

        # ---- local mode: reads, one ready pixel per clock ----------------------------
        lag = Signal(range(depth))   # pixels written and not yet read
        since_end = Signal(range(depth), init=depth - 1)  # written since a row's last pixel
        ra = Signal(range(depth))    # buffer address of the oldest unread pixel
        ready = (lag > win) | (since_end < lag)
        rd = ready & ~drop
        m.d.comb += [px_rd.addr.eq(ra), add_rd.addr.eq(ra + half),
                     sub_rd.addr.eq(ra - half - 1)]
        with m.If(drop):
            m.d.sync += [ra.eq(wp), lag.eq(wr)]
        with m.Else():
            m.d.sync += [ra.eq(ra + rd), lag.eq(lag + wr - rd)]
        since_base = Mux(drop, depth - 1, since_end)
        with m.If(wr):
            m.d.sync += since_end.eq(Mux(last_col | inp.payload.eol, 0,
                                         Mux(since_base == depth - 1, since_base,
                                             since_base + 1)))
        with m.Elif(drop):
            m.d.sync += since_end.eq(depth - 1)

        # stage 1: position (counted as on the input side) and running window sum
        st1_valid = Signal()
        xo = Signal(range(W))
        yo = Signal(range(H))
        acc = Signal(sum_bits)       # sum(p[s .. s+L]) of the pixel in stage 2
        step = (xo > half) & (xo <= step_last)
        beat = data.StructLayout({"data": pb, "x": range(W), "y": range(H), "eof": 1})
        st2 = Signal(beat)
        st2_valid = Signal()
        m.d.sync += [st1_valid.eq(rd), st2_valid.eq(st1_valid & ~drop),
                     st2.data.eq(px_rd.data.data), st2.x.eq(xo), st2.y.eq(yo),
                     st2.eof.eq((xo == W - 1) & (yo == H - 1))]
        with m.If(drop):
            m.d.sync += [xo.eq(0), yo.eq(0)]
        with m.Elif(st1_valid):
            with m.If((xo == W - 1) | px_rd.data.eol):
                m.d.sync += [xo.eq(0), yo.eq(Mux(yo == H - 1, 0, yo + 1))]
            with m.Else():
                m.d.sync += xo.eq(xo + 1)
            m.d.sync += acc.eq(Mux(xo == 0, first_sum, acc)
                               + Mux(step, add_rd.data, 0) - Mux(step, sub_rd.data, 0))

        # stage 2: the window mean M
        st3 = Signal(beat)
        mean = Signal(pb)            # M of the pixel in stage 3 (<= full scale)
        st3_valid = Signal()
        m.d.sync += [st3_valid.eq(st2_valid & ~drop), st3.eq(st2),
                     mean.eq((acc - st2.data)[:sum_bits] >> lg)]
        # stage 3 (into the output register): T, lit and weight
        level = mean + offset
        t_local = Mux(level > fs, fs, level)
        local_valid = st3_valid & ~drop
        fixed_valid = inp.valid & ~local_pix

        with m.If(inp.valid):
            with m.If(sof):
                m.d.sync += [
                    t_frame.eq(t_new), b_frame.eq(b_new),
                    self.frame_threshold.eq(Mux(local_new, offset_sat, t_new)),
                    self.frame_background.eq(Mux(local_new, 0, b_new)),
                    self.frame_fallback.eq((self.mode == C.MODE_GLOBAL) & ~use_global),
                    self.frame_local_fallback.eq((self.mode == C.MODE_LOCAL) & ~window_ok),
                    self.frame_tail_dropped.eq((lag != 0) | st1_valid | st2_valid | st3_valid),
                    local_frame.eq(local_new), lg.eq(lg_reg), offset.eq(offset_sat),
                    step_last.eq(W - 1 - ((Const(1, 1) << lg_reg) >> 1)),
                    in_frame.eq(1),
                ]
            with m.If(last_col | inp.payload.eol):
                m.d.sync += [x.eq(0), y.eq(Mux(cur_y == H - 1, 0, cur_y + 1))]
            with m.Else():
                m.d.sync += [x.eq(cur_x + 1), y.eq(cur_y)]
            m.d.sync += frame_ok.eq(Mux(sof, 1, frame_ok) & ~line_error)
            with m.If(frame_end):
                m.d.sync += in_frame.eq(0)

        # ---- output register: the input pixel (fixed, global) or stage 3 (local) ------
        m.d.sync += out.valid.eq(fixed_valid | local_valid)
        with m.If(local_valid):
            m.d.sync += [
                out.payload.data.eq(st3.data),
                out.payload.x.eq(st3.x),
                out.payload.y.eq(st3.y),
                out.payload.lit.eq(st3.data > t_local),
                out.payload.weight.eq(Mux(st3.data > mean, st3.data - mean, 0)),
                out.payload.eof.eq(st3.eof),
            ]
        with m.Else():
            m.d.sync += [
                out.payload.data.eq(p),
                out.payload.x.eq(cur_x),
                out.payload.y.eq(cur_y),
                out.payload.lit.eq(p > t_eff),
                out.payload.weight.eq(Mux(p > b_eff, p - b_eff, 0)),
                out.payload.eof.eq(frame_end),
            ]

        # ---- statistics of the frame -------------------------------------------------
        s1 = Signal(wd["s1"])
        s2 = Signal(wd["s2"])
        with m.If(inp.valid):
            m.d.sync += [s1.eq(Mux(sof, 0, s1) + p),
                         s2.eq(Mux(sof, 0, s2) + p * p)]
        complete = frame_end & Mux(sof, 1, frame_ok) & ~line_error

        # ---- sequential global-levels unit -------------------------------------------
        # Shift registers only: every step is a fixed-width add or subtract (_mul_step,
        # _div_step, the root step); no variable shift and no variable bit select.
        a1 = Signal(wd["s1"])        # S1: the multiplicand of S1*S1
        sq = Signal(wd["sq"])        # S1*S1 product register (multiplier: a copy of S1)
        bq = Signal(wd["b"])         # S1 // N: dividend bits, then B
        rem_b = Signal(wd["n"])      # its remainder
        prod = Signal(wd["p"])       # N*S2, then K*K*V product register; root operand
        vreg = Signal(wd["v"])       # N*S2 - S1**2 of the last complete frame
        k2 = Signal(wd["k2"])        # K*K product register (multiplier: a copy of K)
        root = Signal(wd["r"])       # isqrt(K*K*V), then its dividend bits and D
        rem = Signal(wd["rem"])      # root remainder, then D remainder
        i = Signal(range(max(wd["s2"], C.KSIGMA_BITS, wd["v"], wd["r"], wd["d"])))  # clocks left
        divisor = N << C.KSIGMA_FRAC_BITS
        m.d.comb += self.stats_busy.eq(0)

        with m.FSM():
            with m.State("IDLE"):
                with m.If(complete):
                    m.d.sync += stats_valid.eq(0)
                    m.next = "LOAD"
                with m.Elif(frame_end | (inp.valid & sof & in_frame)):
                    m.d.sync += [stats_valid.eq(0), have_v.eq(0)]   # incomplete frame
                with m.Elif(have_v & (self.ksigma != kreg)):
                    # ksigma was rewritten between frames: redo the k-dependent part
                    m.d.sync += [stats_valid.eq(0), kreg.eq(self.ksigma), k2.eq(self.ksigma),
                                 i.eq(C.KSIGMA_BITS - 1)]
                    m.next = "K2"
            with m.State("LOAD"):             # s1, s2 now hold the complete frame's sums
                m.d.comb += self.stats_busy.eq(1)
                m.d.sync += [a1.eq(s1), sq.eq(s1), bq.eq(s1[:wd["b"]]), rem_b.eq(s1[wd["b"]:]),
                             prod.eq(s2), i.eq(wd["s2"] - 1)]
                m.next = "STATS"
            with m.State("STATS"):            # bq = S1 // N, sq = S1*S1, prod = N*S2
                m.d.comb += self.stats_busy.eq(1)
                with m.If(i >= wd["s2"] - wd["b"]):
                    new_rem, new_quo = _div_step(rem_b, bq, N)
                    m.d.sync += [rem_b.eq(new_rem), bq.eq(new_quo)]
                with m.If(i >= wd["s2"] - wd["s1"]):
                    m.d.sync += sq.eq(_mul_step(sq, wd["s1"], a1))
                m.d.sync += [prod.eq(_mul_step(prod, wd["s2"], Const(N, wd["n"]))),
                             i.eq(i - 1)]
                with m.If(i == 0):
                    m.next = "SUB"
            with m.State("SUB"):              # vreg = V = N*S2 - S1**2 (>= 0)
                m.d.comb += self.stats_busy.eq(1)
                m.d.sync += [vreg.eq(prod[:wd["v"]] - sq[:wd["v"]]), have_v.eq(1),
                             kreg.eq(self.ksigma), k2.eq(self.ksigma),
                             i.eq(C.KSIGMA_BITS - 1)]
                m.next = "K2"
            with m.State("K2"):               # k2 = K*K, K = kreg (the ksigma register)
                m.d.comb += self.stats_busy.eq(1)
                m.d.sync += [k2.eq(_mul_step(k2, C.KSIGMA_BITS, kreg)), i.eq(i - 1)]
                with m.If(i == 0):
                    m.d.sync += [prod.eq(vreg), i.eq(wd["v"] - 1)]
                    m.next = "K2V"
            with m.State("K2V"):              # prod = V * k2
                m.d.comb += self.stats_busy.eq(1)
                m.d.sync += [prod.eq(_mul_step(prod, wd["v"], k2)), i.eq(i - 1)]
                with m.If(i == 0):
                    m.d.sync += [root.eq(0), rem.eq(0), i.eq(wd["r"] - 1)]
                    m.next = "SQRT"
            with m.State("SQRT"):             # root = isqrt(prod), two operand bits a clock
                m.d.comb += self.stats_busy.eq(1)
                trial = Cat(prod[wd["x"] - 2:wd["x"]], rem[:wd["r"] + 1])
                diff = trial - Cat(Const(1, 2), root)    # 4 * root + 1
                fits = ~diff[-1]
                new_root = Cat(fits, root[:-1])
                m.d.sync += [prod.eq(Cat(Const(0, 2), prod[:wd["x"] - 2])), i.eq(i - 1)]
                with m.If(i == 0):
                    # D = root // (16 N): the top bits (below the divisor) go to rem
                    m.d.sync += [root.eq(new_root[:wd["d"]]), rem.eq(new_root[wd["d"]:]),
                                 i.eq(wd["d"] - 1)]
                    m.next = "DIV_D"
                with m.Else():
                    m.d.sync += [root.eq(new_root),
                                 rem.eq(Mux(fits, diff, trial)[:wd["r"] + 1])]
            with m.State("DIV_D"):            # root[:d] = D = isqrt(K*K*V) // (16 N)
                m.d.comb += self.stats_busy.eq(1)
                rem_d = rem[:C.bits_for(divisor)]
                new_rem, new_quo = _div_step(rem_d, root[:wd["d"]], divisor)
                m.d.sync += [rem.eq(new_rem), root.eq(new_quo), i.eq(i - 1)]
                with m.If(i == 0):
                    m.next = "DONE"
            with m.State("DONE"):             # T = min(B + D, fs); B <= fs fits pb bits
                m.d.comb += self.stats_busy.eq(1)
                level = bq[:pb] + root[:pb]
                big = root[pb:wd["d"]].any() | level[pb]
                m.d.sync += [next_b.eq(bq), next_t.eq(Mux(big, fs, level[:pb])),
                             stats_valid.eq(kreg == self.ksigma)]
                m.next = "IDLE"
        return m
