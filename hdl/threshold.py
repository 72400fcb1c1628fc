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

Global mode: the unit accumulates ``S1 = sum(p)`` and ``S2 = sum(p*p)`` over the pixels of
every frame (in every mode; a ``sof`` restarts them).  When a frame completes a sequential
unit computes the next frame's levels exactly as ``contract.global_levels``::

    B = S1 // N;  V = N*S2 - S1**2;  D = isqrt(K*K*V) // (16 N);  T = min(B + D, full_scale)

by searching ``B`` and then ``D`` bit by bit, MSB first (``D`` below ``2**pixel_bits``:
``min(D, full_scale)`` gives the same ``T``): with ``c`` the bits found so far and the
trial bit, a trial tests ``N*c <= S1`` (``B``) or ``256*N*N*c*c <= K*K*(N*S2 - S1*S1)``
(``D``).  A trial streams both sides of its comparison LSB first, one bit per clock,
through serial multipliers (a register of the partial product's upper bits and an adder
one bit wider than the fixed factor: ``N``, ``S1``, ``K``, ``c``) and a serial subtraction
whose last borrow decides the trial; ``S1`` and ``S2`` are read in place by rotating the
accumulators once per trial, ``N`` and ``256*N*N`` come from constant tables.  Nothing
wider than ``S1`` is stored.  The levels are ready ``global_cycles(width, height,
pixel_bits)`` clocks after the frame's last pixel (1465 for 2592 x 1944 x 12 bits, 1041
for 752 x 480 x 10: less than the labeller's own blanking at 2592 columns).
The ``ksigma`` register is read when the ``D`` search starts; if the MCU rewrites it, the
``D`` search is restarted at the end of the trial under way (or started again, between
frames).  So the levels are those of the ksigma in effect at the next frame's start
provided the register was written at least ``ksigma_cycles`` clocks before it (1079 for
2592 x 1944 x 12) and the frame's last pixel came at least ``global_cycles`` before.  A
frame that starts earlier, or after an incomplete frame, uses the fixed registers and
raises ``frame_fallback`` (``FRAME_GLOBAL_FALLBACK``); a ``sof`` abandons a computation
under way.

Local mode (``L = 2**local_log2_window``, ``half = L/2``): per pixel ``x`` of a row, with
``s = contract.local_window_start(x, W, log2 L)``::

    M = (sum(p[s .. s+L]) - p[x]) >> log2(L);   T = min(M + local_offset, full_scale);   B = M

The window reaches up to ``L`` columns ahead of ``x``, so local-mode pixels go through a
circular buffer of ``local_depth(W)`` entries (256 for ``L`` up to 128) in synchronous-read
memories (one M9K each at 2592 x 1944 x 12): the pixel with its position and ``eof`` as the
input counts them (read at ``x``), and two copies of the frame's running sum ``S1`` modulo
``2**bits((L + 1) * full_scale)``, one after each pixel (read at the window's last pixel
``s + L``) and one before it (read at its first, ``s``), so a window's sum is one
difference.  The window moves (``s`` advances by one) at each ``x`` with ``half < x <= W -
1 - half``; elsewhere the second copy's read port keeps its word, so no read reaches back
more than ``half`` pixels before ``x``.  A pixel is *ready* once ``L`` more pixels of the
frame have come after it, or its row's last pixel has come; ready pixels are read one per
clock, in order (every address read was written on an earlier clock: no
read-during-write), and a pixel's beat follows its read 5 clocks later (window addresses,
window sum less the pixel, ``M`` (the shift by ``log2 L`` is a product with ``2**(7 - log2
L)`` in an embedded multiplier), output register with lit and weight).

* Latency: a pixel's beat comes ``LOCAL_LATENCY`` (6) clocks after the input pixel that
  made it ready, or one clock after the previous beat if that is later; within a row
  streaming without gaps, ``L + 6`` clocks after the pixel itself (fixed mode: 1).  The
  last ``L`` pixels of a row follow the row's last pixel one per clock, during the
  horizontal blanking or the next row's first pixels: any horizontal blanking, none
  included, works.  After a frame's last pixel its remaining pixels drain by themselves;
  the ``eof`` beat comes at most ``L + 6`` clocks after it.
* Vertical blanking: after a local-mode frame, ``local_blanking(log2 L)`` = ``L + 5`` idle
  clocks between its last pixel and the next ``sof`` (133 for ``L = 128``; a sensor's
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


def _pass_bits(width, height, pixel_bits):
    """Clocks of one trial of ``B`` and of ``D`` (bits of the numbers the trial compares)."""
    nfs = width * height * C.full_scale(pixel_bits)
    kmax = (1 << C.KSIGMA_BITS) - 1
    # B: S1 against N*c (c <= fs), and one clock more so that S1, which rotates while it
    # is streamed, is in place in a trial's last clock (where the D search copies it).
    # D: K*K*V (V <= (N fs)**2 / 4, Popoviciu) against 256*N*N*c*c; every partial product
    # of the chain is below these bounds too.
    return (C.bits_for(nfs) + 1,
            C.bits_for(max(kmax * kmax * nfs * nfs // 4, (nfs << C.KSIGMA_FRAC_BITS) ** 2)))


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


def _below(value, bound):
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


LOCAL_LATENCY = 6
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
        inp, out = self.pixels, self.out
        p = inp.payload.data
        sof = inp.payload.sof

        # ---- position and frame integrity -------------------------------------------
        x = Signal(range(W), reset_less=True)
        y = Signal(range(H), reset_less=True)
        in_frame = Signal()
        frame_ok = Signal()          # every line so far was exactly W long
        cur_x = Mux(sof, 0, x)
        cur_y = Mux(sof, 0, y)
        last_col = cur_x == W - 1
        line_error = inp.payload.eol != last_col
        frame_end = inp.valid & last_col & (cur_y == H - 1) & (in_frame | sof)

        # ---- levels latched at the start of each frame -------------------------------
        next_t = Signal(pb, reset_less=True)
        next_b = Signal(pb, reset_less=True)
        stats_valid = Signal()       # next_t/next_b hold the levels for ksigma == kreg
        kreg = Signal(C.KSIGMA_BITS, reset_less=True)  # the ksigma the levels are computed for
        have_v = Signal()            # S1, S2 hold a complete frame and next_b its B
        t_frame = Signal(pb, reset_less=True)
        b_frame = Signal(pb, reset_less=True)
        # a sof while in_frame: the previous frame never ended, so its statistics are
        # missing and this frame falls back, as after an incomplete frame.  (stats_valid is
        # 0 while the levels are being computed.)
        k_same = kreg == self.ksigma
        use_global = (self.mode == C.MODE_GLOBAL) & stats_valid & k_same & ~in_frame

        lg_reg = self.local_log2_window
        lg_max = local_log2_window_max(W)    # window narrower than the frame
        lg_table = range(C.LOCAL_LOG2_WINDOW_MIN, (lg_max or C.LOCAL_LOG2_WINDOW_MIN - 1) + 1)
        window_ok = Const(0)
        for k in lg_table:
            window_ok |= lg_reg == k
        local_new = (self.mode == C.MODE_LOCAL) & window_ok
        offset_sat = Mux(self.local_offset[pb:].any(), fs, self.local_offset[:pb])
        local_frame = Signal()       # the current frame is processed in local mode
        lg = Signal.like(lg_reg, reset_less=True)  # its log2(L)
        local_pix = Mux(sof, local_new, local_frame)
        # the frame's T and B (local mode: the offset and 0), latched on the sof pixel
        sof_v = inp.valid & sof
        t_new = Mux(use_global, next_t, self.threshold)
        b_new = Mux(use_global, next_b, self.background)
        t_eff = Mux(sof_v, Mux(local_new, offset_sat, t_new), t_frame)
        b_eff = Mux(sof_v, Mux(local_new, 0, b_new), b_frame)
        m.d.sync += [t_frame.eq(t_eff), b_frame.eq(b_eff)]
        m.d.comb += [self.frame_threshold.eq(t_frame), self.frame_background.eq(b_frame)]

        # ---- statistics of the frame -------------------------------------------------
        # Pixels of a frame only (a stray pixel between frames leaves them alone); a sof
        # restarts them.  The global-levels unit reads them in place by rotating them right
        # (exactly once per trial, so they are back in place after it).  S1 after each pixel
        # is also local mode's prefix sum.
        s1 = Signal(C.bits_for(N * fs), reset_less=True)
        s2 = Signal(C.bits_for(N * fs * fs), reset_less=True)
        p_frame = Mux(inp.valid & (sof | in_frame), p, 0)
        rot1 = Signal()
        rot2 = Signal()
        s1_base = Mux(sof_v, 0, Mux(rot1, s1.rotate_right(1), s1))
        s1_new = s1_base + p_frame
        m.d.sync += [
            s1.eq(s1_new),
            s2.eq(Mux(sof_v, 0, Mux(rot2, s2.rotate_right(1), s2)) + p_frame * p_frame),
        ]

        # ---- local mode: input side --------------------------------------------------
        # Each pixel is stored with its position and eof as the input counts them, and with
        # its frame's running sum (S1 modulo 2**sum_bits) after it (end copy) and before it
        # (start copy): a window's sum is the end copy at its last pixel minus the start
        # copy at its first.
        depth = local_depth(W)
        win_max = 1 << (lg_max or C.LOCAL_LOG2_WINDOW_MIN)
        sum_bits = C.bits_for((win_max + 1) * fs)
        entry = data.StructLayout({"data": pb, "x": range(W), "y": range(H), "eof": 1})
        m.submodules.px_mem = px_mem = Memory(shape=entry, depth=depth, init=[])
        m.submodules.end_mem = end_mem = Memory(shape=sum_bits, depth=depth, init=[])
        m.submodules.start_mem = start_mem = Memory(shape=sum_bits, depth=depth, init=[])
        px_rd, end_rd, start_rd = px_mem.read_port(), end_mem.read_port(), start_mem.read_port()
        wr = inp.valid & local_pix & (sof | in_frame)    # a pixel of a local-mode frame
        drop = inp.valid & sof       # a new frame: discard what is left of the last one
        wp = Signal(range(depth), reset_less=True)  # buffer address of the next pixel written
        px_wr, end_wr, start_wr = px_mem.write_port(), end_mem.write_port(), start_mem.write_port()
        for port in (px_wr, end_wr, start_wr):
            m.d.comb += [port.addr.eq(wp), port.en.eq(wr)]
        m.d.comb += [px_wr.data.eq(Cat(p, cur_x, cur_y, frame_end)),
                     end_wr.data.eq(s1_new[:sum_bits]), start_wr.data.eq(s1_base[:sum_bits])]
        win = Const(1, 1) << lg      # L of the current frame
        with m.If(wr):
            m.d.sync += wp.eq(wp + 1)

        # ---- local mode: reads, one ready pixel per clock ----------------------------
        lag = Signal(range(depth))   # pixels written and not yet read
        ended = Signal(range(depth))  # of them, those up to the last row end written
        ra = Signal(range(depth), reset_less=True)  # buffer address of the oldest unread pixel
        rd = ((lag > win) | (ended != 0)) & ~drop
        lag_new = lag + Cat(wr ^ rd, (rd & ~wr).replicate(len(lag) - 1))
        row_end = wr & (last_col | inp.payload.eol)
        m.d.comb += px_rd.addr.eq(ra)
        with m.If(drop):
            m.d.sync += [ra.eq(wp), lag.eq(wr), ended.eq(row_end)]
        with m.Else():
            m.d.sync += [ra.eq(ra + rd), lag.eq(lag_new),
                         ended.eq(Mux(row_end, lag_new, ended - (rd & (ended != 0))))]

        # stage 1: the pixel's window, from its column x: its last pixel s + L (an address
        # of the end copy) and its first s (of the start copy).  The window moves (s
        # advances by one) at each x with half < x <= W - 1 - half; elsewhere the start
        # copy's read port keeps its last word, so no read reaches back more than half
        # pixels before the pixel.
        st1_valid = Signal()
        ra1 = Signal(range(depth), reset_less=True)  # buffer address of the stage-1 pixel
        last_end = Signal(range(depth), reset_less=True)  # window end of the last pixel
        x1 = px_rd.data.x
        row_start = x1 == 0
        moving = Signal(reset_less=True)  # the window moved at the row's previous pixel
        # x runs 0, 1, 2, .. along a row: the window moves from x = half + 1 up to, not
        # including, x = W - half
        move_first = Const(0, range(W + 1))
        move_end = Const(0, range(W + 1))
        for k in lg_table:
            move_first = Mux(lg == k, (1 << (k - 1)) + 1, move_first)
            move_end = Mux(lg == k, W - (1 << (k - 1)), move_end)
        step = ((x1 == move_first) | moving) & (x1 != move_end) & ~row_start
        end_addr = Mux(row_start, ra1 + win, last_end + step)
        m.d.comb += [end_rd.addr.eq(end_addr), start_rd.addr.eq(end_addr - win),
                     start_rd.en.eq(row_start | step)]
        st2 = Signal(entry, reset_less=True)
        st2_valid = Signal()
        m.d.sync += [st1_valid.eq(rd), st2_valid.eq(st1_valid & ~drop), ra1.eq(ra),
                     st2.eq(px_rd.data)]
        with m.If(st1_valid):
            m.d.sync += [last_end.eq(end_addr), moving.eq(step)]

        # stage 2: the sum of the window's other L pixels
        st3 = Signal(entry, reset_less=True)
        st3_valid = Signal()
        others = Signal(sum_bits, reset_less=True)
        m.d.sync += [others.eq(end_rd.data - start_rd.data - st2.data),
                     st3_valid.eq(st2_valid & ~drop), st3.eq(st2)]
        # stage 3: the window mean M
        st4 = Signal(entry, reset_less=True)
        st4_valid = Signal()
        mean = Signal(pb, reset_less=True)
        # others >> log2(L) as a product (an embedded multiplier instead of a shifter)
        scale = Const(0, 1 << C.LOCAL_LOG2_WINDOW_MAX)
        for k in lg_table:
            scale = Mux(lg == k, 1 << (C.LOCAL_LOG2_WINDOW_MAX - k), scale)
        mean_now = (others * scale)[C.LOCAL_LOG2_WINDOW_MAX:][:pb]
        m.d.sync += [st4_valid.eq(st3_valid & ~drop), st4.eq(st3), mean.eq(mean_now)]
        # stage 4 (into the output register): lit and weight.  p > min(M + offset, fs) is
        # p - M > offset for p <= fs; t_eff is the frame's offset in a local frame.
        local_valid = st4_valid & ~drop
        fixed_valid = inp.valid & ~local_pix

        with m.If(inp.valid):
            with m.If(sof):
                m.d.sync += [
                    self.frame_fallback.eq((self.mode == C.MODE_GLOBAL) & ~use_global),
                    self.frame_local_fallback.eq((self.mode == C.MODE_LOCAL) & ~window_ok),
                    self.frame_tail_dropped.eq((lag != 0) | st1_valid | st2_valid | st3_valid
                                               | st4_valid),
                    local_frame.eq(local_new), lg.eq(lg_reg),
                    in_frame.eq(1),
                ]
            with m.If(last_col | inp.payload.eol):
                m.d.sync += [x.eq(0), y.eq(Mux(cur_y == H - 1, 0, cur_y + 1))]
            with m.Else():
                m.d.sync += [x.eq(cur_x + 1), y.eq(cur_y)]
            m.d.sync += frame_ok.eq(Mux(sof, 1, frame_ok) & ~line_error)
            with m.If(frame_end):
                m.d.sync += in_frame.eq(0)

        # ---- output register: the input pixel (fixed, global) or stage 4 (local) ------
        beat_out = Signal.like(out.payload, reset_less=True)
        m.d.comb += out.payload.eq(beat_out)
        value = Mux(local_valid, st4.data, p)
        above_local = st4.data - mean
        above = Mux(local_valid, above_local, p - b_eff)           # weight, if not < 0
        below = t_eff - Mux(local_valid, above_local, p)           # < 0: lit
        m.d.sync += [
            out.valid.eq(fixed_valid | local_valid),
            beat_out.data.eq(value),
            beat_out.x.eq(Mux(local_valid, st4.x, cur_x)),
            beat_out.y.eq(Mux(local_valid, st4.y, cur_y)),
            beat_out.lit.eq(below[-1]),
            beat_out.weight.eq(Mux(above[-1], 0, above[:pb])),
            beat_out.eof.eq(Mux(local_valid, st4.eof, frame_end)),
        ]

        complete = frame_end & Mux(sof, 1, frame_ok) & ~line_error

        # ---- sequential global-levels unit -------------------------------------------
        # B = S1 // N and D = isqrt(K*K*V) // (16 N) are searched bit by bit, MSB first
        # (c is the value found so far with the trial bit set):
        #   B: N*c <= S1;   D: 256*N*N*c*c <= K*K*(N*S2 - S1*S1)
        # (D is searched below 2**pb: D' = min(D, fs) gives the same T).  Each trial streams
        # both sides LSB first through serial multipliers and compares them serially: a
        # trial passes if the difference has no borrow out.  Nothing wide is stored:
        # S1 and S2 are read in place, one bit per clock.  B's first trial only flushes
        # what an abandoned computation left in the multipliers of c (its c is 0); the
        # other multipliers get zeros during B's trials.
        lb, ld = _pass_bits(W, H, pb)
        run = Signal()               # a trial is under way
        dphase = Signal()            # searching D (else B)
        tbit = Signal(range(max(lb, ld)), reset_less=True)  # bit of the trial in this clock
        trial = Signal(pb + 1, reset_less=True)  # the trial bit, one-hot (pb: B's flush trial)
        found = Signal(pb, reset_less=True)  # the bits of B or D found so far
        last = tbit == Mux(dphase, ld - 1, lb - 1)
        c = found | trial[:pb]

        def stream(value):
            """Bit ``tbit`` of the constant ``value`` while a trial runs, else 0."""
            padded = Cat(value, Const(0, (1 << len(tbit)) - len(value)))
            return padded.bit_select(tbit, 1) & run

        s1c = Signal.like(s1)        # S1, the multiplicand of S1*S1 (s1 rotates)
        m.d.comb += [rot1.eq(run & _below(tbit, len(s1))),
                     rot2.eq(run & dphase & _below(tbit, len(s2)))]
        s1_bit = s1[0] & rot1
        lhs_v, _ = _serial_sub(m, _serial_mul(m, s2[0] & rot2, Const(N)),
                               _serial_mul(m, s1_bit & dphase, s1c), run & ~last)
        lhs_d = _serial_mul(m, _serial_mul(m, lhs_v, kreg), kreg)
        ref = Mux(dphase, stream(Const((N << C.KSIGMA_FRAC_BITS) ** 2)),
                  stream(Const(N)))
        rhs_b = _serial_mul(m, ref, c)
        rhs_d = _serial_mul(m, rhs_b & dphase, c)
        _, borrow = _serial_sub(m, Mux(dphase, lhs_d, s1_bit), Mux(dphase, rhs_d, rhs_b),
                                run & ~last)
        passed = ~borrow             # at the trial's last bit

        def start_d():
            return [dphase.eq(1), kreg.eq(self.ksigma), trial.eq(1 << (pb - 1)),
                    found.eq(0), tbit.eq(0), s1c.eq(s1)]

        m.d.comb += self.stats_busy.eq(run)
        found_now = Mux(passed, c, found)    # at a trial's last bit
        level = next_b + found_now
        with m.If(complete):
            m.d.sync += [stats_valid.eq(0), have_v.eq(0), run.eq(1), dphase.eq(0),
                         trial.eq(1 << pb), found.eq(0), tbit.eq(0)]
        with m.Elif(frame_end | sof_v):      # S1, S2 restart, or the frame was broken
            m.d.sync += [have_v.eq(0), run.eq(0)]
            with m.If(frame_end | in_frame | run):
                m.d.sync += stats_valid.eq(0)
        with m.Elif(~run):
            with m.If(have_v & ~k_same):     # ksigma was rewritten: search D again
                m.d.sync += [stats_valid.eq(0), run.eq(1)] + start_d()
        with m.Else():
            m.d.sync += tbit.eq(tbit + 1)
            with m.If(last):
                m.d.sync += [tbit.eq(0), trial.eq(trial >> 1), found.eq(found_now)]
                with m.If(dphase & ~k_same):
                    m.d.sync += start_d()                 # rewritten meanwhile: restart
                with m.Elif(trial[0] & ~dphase):
                    m.d.sync += [have_v.eq(1), next_b.eq(found_now)] + start_d()
                with m.Elif(trial[0]):                    # T = min(B + D', fs)
                    m.d.sync += [run.eq(0), stats_valid.eq(1),
                                 next_t.eq(Mux(level[pb], fs, level[:pb]))]
        return m
