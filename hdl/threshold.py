"""Threshold unit: pixel stream in, lit flag and weight out, at one pixel per clock.

Implements the ``fixed`` and ``global`` modes of ``lodestar.contract`` bit-exactly (the
``local`` mode's window unit is still to come: until then a frame started in local mode is
processed with the fixed registers and flagged by ``frame_local_unsupported``).

Stream conventions: ``pixels`` carries one pixel per clock while ``valid`` (no backpressure,
a sensor cannot be stalled) with ``sof`` on the first pixel of a frame and ``eol`` on the
last pixel of each line.  The runtime registers are latched on the ``sof`` pixel.  ``out``
follows one clock later with the pixel, its position, ``lit = p > T`` and
``weight = max(p - B, 0)``, and ``eof`` on the frame's last pixel.

Global mode: the unit accumulates ``S1 = sum(p)`` and ``S2 = sum(p*p)`` over every frame.
When a frame completes (``W*H`` pixels, every line ``W`` long) a sequential unit computes
the next frame's levels exactly as ``contract.global_levels``::

    B = S1 // N;  V = N*S2 - S1**2;  r = isqrt(K*K*V);  T = min(B + r // (16 N), full_scale)

with shift-add multipliers, restoring dividers and a digit-by-digit square root, one bit per
clock: ``global_cycles(width, height, pixel_bits)`` clocks after the frame's last pixel.
The ``ksigma`` register is read when the k-dependent part starts; if the MCU rewrites it
between frames, that part (``ksigma_cycles(...)`` clocks) is redone.  So the levels are
those of the ksigma in effect at the next frame's start provided the register was written
at least ``ksigma_cycles`` clocks before it (and the frame's last pixel came at least
``global_cycles`` before).  A frame that starts earlier, or after an incomplete frame, uses
the fixed registers and raises ``frame_fallback`` (``FRAME_GLOBAL_FALLBACK``).
"""

from amaranth import Cat, Const, Module, Mux, Signal
from amaranth.lib import data, stream, wiring
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
    """Bit widths of the global-mode arithmetic, from the contract's bounds."""
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
    return w


def ksigma_cycles(width, height, pixel_bits):
    """Clocks of the k-dependent part: K*K, K*K*V, square root, division, done."""
    w = _widths(width, height, pixel_bits)
    return C.KSIGMA_BITS + w["k2"] + w["r"] + w["r"] + 2


def global_cycles(width, height, pixel_bits):
    """Clocks the global-mode computation needs after a frame's last pixel."""
    w = _widths(width, height, pixel_bits)
    # DIV B, MUL S1*S1, MUL N*S2, SUB, then the k-dependent part
    return w["s1"] + w["s1"] + w["n"] + 1 + ksigma_cycles(width, height, pixel_bits)


class ThresholdUnit(wiring.Component):
    """Fixed and global thresholds for ``width x height`` frames of ``pixel_bits`` pixels."""

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
            "frame_threshold": Out(pixel_bits),
            "frame_background": Out(pixel_bits),
            "frame_fallback": Out(1),
            "frame_local_unsupported": Out(1),
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

        # ---- position and frame integrity -------------------------------------------
        x = Signal(range(W))
        y = Signal(range(H))
        in_frame = Signal()
        frame_ok = Signal()          # every line so far was exactly W long
        cur_x = Mux(inp.payload.sof, 0, x)
        cur_y = Mux(inp.payload.sof, 0, y)
        last_col = cur_x == W - 1
        line_error = inp.payload.eol != last_col
        frame_end = inp.valid & last_col & (cur_y == H - 1) & (in_frame | inp.payload.sof)

        # ---- levels latched at the start of each frame -------------------------------
        next_t = Signal(pb)
        next_b = Signal(pb)
        stats_valid = Signal()       # next_t/next_b hold the levels for ksigma == kreg
        kreg = Signal(C.KSIGMA_BITS)  # the ksigma the levels are computed for
        have_v = Signal()            # the last frame was complete and V is computed
        t_frame = Signal(pb)
        b_frame = Signal(pb)
        use_global = (self.mode == C.MODE_GLOBAL) & stats_valid & ~self.stats_busy & \
            (kreg == self.ksigma)
        t_new = Mux(use_global, next_t, self.threshold)
        b_new = Mux(use_global, next_b, self.background)
        t_eff = Mux(inp.payload.sof, t_new, t_frame)
        b_eff = Mux(inp.payload.sof, b_new, b_frame)

        with m.If(inp.valid):
            with m.If(inp.payload.sof):
                m.d.sync += [
                    t_frame.eq(t_new), b_frame.eq(b_new),
                    self.frame_threshold.eq(t_new), self.frame_background.eq(b_new),
                    self.frame_fallback.eq((self.mode == C.MODE_GLOBAL) & ~use_global),
                    self.frame_local_unsupported.eq(self.mode == C.MODE_LOCAL),
                    in_frame.eq(1),
                ]
            with m.If(last_col | inp.payload.eol):
                m.d.sync += [x.eq(0), y.eq(Mux(cur_y == H - 1, 0, cur_y + 1))]
            with m.Else():
                m.d.sync += x.eq(cur_x + 1)
            m.d.sync += frame_ok.eq(Mux(inp.payload.sof, 1, frame_ok) & ~line_error)
            with m.If(frame_end):
                m.d.sync += in_frame.eq(0)

        # ---- output (one register stage) --------------------------------------------
        m.d.sync += [
            out.valid.eq(inp.valid),
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
            m.d.sync += [s1.eq(Mux(inp.payload.sof, 0, s1) + p),
                         s2.eq(Mux(inp.payload.sof, 0, s2) + p * p)]
        complete = frame_end & Mux(inp.payload.sof, 1, frame_ok) & ~line_error

        # ---- sequential global-levels unit -------------------------------------------
        a1 = Signal(wd["s1"])        # S1 snapshot
        a2 = Signal(wd["s2"])        # S2 snapshot
        vreg = Signal(wd["v"])       # N*S2 - S1**2 of the last complete frame
        bq = Signal(wd["s1"])        # B quotient
        rem = Signal(wd["x"] + 2)    # divider remainder / root remainder
        acc = Signal(wd["x"])        # multiplier accumulator / root operand
        sq = Signal(wd["sq"])        # S1**2
        k2 = Signal(wd["k2"])        # K**2
        root = Signal(wd["x"] + 1)     # holds partial results up to the operand size
        one = Signal(wd["x"] + 1)    # square-root bit (a power of four)
        i = Signal(range(max(wd.values()) + 2))
        m.d.comb += self.stats_busy.eq(0)

        with m.FSM():
            with m.State("IDLE"):
                with m.If(complete):
                    m.d.sync += [a1.eq(s1 + p), a2.eq(s2 + p * p), stats_valid.eq(0),
                                 bq.eq(0), rem.eq(0), i.eq(wd["s1"] - 1)]
                    m.next = "DIV_B"
                with m.Elif(frame_end):       # incomplete frame: no statistics
                    m.d.sync += [stats_valid.eq(0), have_v.eq(0)]
                with m.Elif(have_v & (self.ksigma != kreg)):
                    # ksigma was rewritten between frames: redo the k-dependent part
                    m.d.sync += [stats_valid.eq(0), k2.eq(0), i.eq(0)]
                    m.next = "K2"
            with m.State("DIV_B"):            # bq = a1 // N, restoring, MSB first
                m.d.comb += self.stats_busy.eq(1)
                trial = Cat(a1.bit_select(i, 1), rem[:wd["s1"]])
                with m.If(trial >= N):
                    m.d.sync += [rem.eq(trial - N), bq.eq(bq | (1 << i))]
                with m.Else():
                    m.d.sync += rem.eq(trial)
                with m.If(i == 0):
                    m.d.sync += [acc.eq(0), sq.eq(0), i.eq(0)]
                    m.next = "SQ"
                with m.Else():
                    m.d.sync += i.eq(i - 1)
            with m.State("SQ"):               # sq = a1 * a1, shift-add, LSB first
                m.d.comb += self.stats_busy.eq(1)
                with m.If(a1.bit_select(i, 1)):
                    m.d.sync += sq.eq(sq + (a1 << i))
                with m.If(i == wd["s1"] - 1):
                    m.d.sync += i.eq(0)
                    m.next = "NS2"
                with m.Else():
                    m.d.sync += i.eq(i + 1)
            with m.State("NS2"):              # acc = N * a2 (N constant), shift-add
                m.d.comb += self.stats_busy.eq(1)
                nbits = Const(N, wd["n"])
                with m.If(nbits.bit_select(i, 1)):
                    m.d.sync += acc.eq(acc + (a2 << i))
                with m.If(i == wd["n"] - 1):
                    m.next = "SUB"
                with m.Else():
                    m.d.sync += i.eq(i + 1)
            with m.State("SUB"):              # vreg = V = N*S2 - S1**2 (>= 0)
                m.d.comb += self.stats_busy.eq(1)
                m.d.sync += [vreg.eq(acc - sq), have_v.eq(1), k2.eq(0), i.eq(0)]
                m.next = "K2"
            with m.State("K2"):               # k2 = K * K, K = the ksigma register now
                m.d.comb += self.stats_busy.eq(1)
                with m.If(self.ksigma.bit_select(i, 1)):
                    m.d.sync += k2.eq(k2 + (self.ksigma << i))
                with m.If(i == C.KSIGMA_BITS - 1):
                    m.d.sync += [i.eq(0), acc.eq(0), kreg.eq(self.ksigma)]
                    m.next = "K2V"
                with m.Else():
                    m.d.sync += i.eq(i + 1)
            with m.State("K2V"):              # acc = k2 * V
                m.d.comb += self.stats_busy.eq(1)
                with m.If(k2.bit_select(i, 1)):
                    m.d.sync += acc.eq(acc + (vreg << i))
                with m.If(i == wd["k2"] - 1):
                    m.d.sync += [i.eq(wd["r"] - 1), root.eq(0),
                                 one.eq(1 << (wd["x"] - 2))]
                    m.next = "SQRT"
                with m.Else():
                    m.d.sync += i.eq(i + 1)
            with m.State("SQRT"):             # root = isqrt(acc), digit by digit
                m.d.comb += self.stats_busy.eq(1)
                with m.If(acc >= root + one):
                    m.d.sync += [acc.eq(acc - (root + one)), root.eq((root >> 1) + one)]
                with m.Else():
                    m.d.sync += root.eq(root >> 1)
                m.d.sync += one.eq(one >> 2)
                with m.If(i == 0):
                    m.d.sync += [i.eq(wd["r"] - 1), rem.eq(0), acc.eq(0)]
                    m.next = "DIV_D"
                with m.Else():
                    m.d.sync += i.eq(i - 1)
            with m.State("DIV_D"):            # acc = root // (16 N)
                m.d.comb += self.stats_busy.eq(1)
                divisor = N << C.KSIGMA_FRAC_BITS
                trial = Cat(root.bit_select(i, 1), rem[:wd["r"]])
                with m.If(trial >= divisor):
                    m.d.sync += [rem.eq(trial - divisor), acc.eq(acc | (1 << i))]
                with m.Else():
                    m.d.sync += rem.eq(trial)
                with m.If(i == 0):
                    m.next = "DONE"
                with m.Else():
                    m.d.sync += i.eq(i - 1)
            with m.State("DONE"):
                m.d.comb += self.stats_busy.eq(1)
                level = bq + acc
                m.d.sync += [next_b.eq(bq), next_t.eq(Mux(level > fs, fs, level)),
                             stats_valid.eq(kreg == self.ksigma)]
                m.next = "IDLE"
        return m
