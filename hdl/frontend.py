"""What every sensor front end shares: the clock-domain crossing into ``sync``, the frame
watchdog after it, the geometry check, and :class:`SensorFrontend`, the base class that
declares the stream and status ports and the board hooks each front end implements, and the
pin buffers the hooks use (:func:`capture_buffer`, :func:`clock_output`, :func:`input_buffer`).

A front end delivers an always-ready ``lib.stream`` in ``sync`` of
``threshold.pixel_layout(PIXEL_BITS)`` (``data``, ``sof`` on a frame's first pixel, ``eol`` on
each line's last, raster order).  :class:`PixelCrossing` crosses from the sensor's clock
domain through an AsyncFIFO: with the sync clock at least the pixel rate the write side never
counts more than 6 entries (``FIFO_DEPTH = 8``); on overflow the sticky ``overflow`` rises and
the frame is cut until the next ``sof``, never delivered shifted.  :class:`FrameWatchdog` (in
``sync``, after the front end) completes a frame the sensor stops sending.  Derivation:
``docs/sensors_and_link.md``.
"""

from amaranth import Module, Mux, ResetSignal, Signal
from amaranth.lib import io, stream, wiring
from amaranth.lib.cdc import PulseSynchronizer
from amaranth.lib.fifo import AsyncFIFO
from amaranth.lib.wiring import In, Out

from lodestar import contract as C
from lodestar.hdl.labeller import MIN_HBLANK
from lodestar.hdl.threshold import pixel_layout

FIFO_DEPTH = 8
"""Entries of the pixel-clock -> sync FIFO when the sync clock is at least the pixel rate
(module docstring: at most 6 are ever counted by the write side)."""


def io_domain(domain):
    """Name of the reset-less twin of clock domain ``domain`` (same clock, no reset) that a
    board clocks its pin flip-flops with: a register in an I/O element has no reset."""
    return f"{domain}_io"


def input_buffer(m, name, port):
    """An ``io.Buffer`` input on ``port`` (a clock pin, or a pin a synchronizer or a
    receiver registers), added to ``m`` as ``name``; returns the buffer."""
    m.submodules[name] = buffer = io.Buffer("i", port)
    return buffer


def capture_buffer(m, name, port, domain):
    """An ``io.FFBuffer`` input on ``port`` sampled on the rising edge of ``domain``'s
    reset-less twin (:func:`io_domain`): the pin's capture register, which the platform
    places in the I/O element; returns the buffer."""
    m.submodules[name] = buffer = io.FFBuffer("i", port, i_domain=io_domain(domain))
    return buffer


MASTER_DOMAIN = "master"
"""The reset-less clock domain of the sensor's master clock (EXTCLK, SYSCLK), made by the
board's PLL."""


def clock_output(m, name, port, domain=MASTER_DOMAIN):
    """Forward the clock of ``domain`` (reset-less) to ``port`` through an ``io.DDRBuffer``
    (high after the rising edge, low after the falling one): the pin toggles from the I/O
    element's DDR register, not from a clock net routed out through the fabric, so its
    duty cycle and delay are the I/O element's; returns the buffer."""
    m.submodules[name] = buffer = io.DDRBuffer("o", port, o_domain=domain)
    m.d.comb += [buffer.o[0].eq(1), buffer.o[1].eq(0)]
    return buffer


def gray_skew_constraints(source, target, limit_ns):
    """SDC lines that bound a Gray-coded bus crossing clock domains: from the ``source``
    registers (a Quartus name pattern) to the first stage of their synchronizer ``target``,
    ``set_net_delay`` and ``set_max_skew`` of ``limit_ns`` (0.8 x the faster clock's period):
    the bits then arrive within one destination clock of each other, so the synchronizer
    never samples a value two codes apart, which the clock groups' false path alone would
    allow."""
    keys = f"-from [get_keepers {{{source}}}] -to [get_keepers {{{target}}}]"
    return [f"set_net_delay -max {limit_ns:.3f} {keys}", f"set_max_skew {limit_ns:.3f} {keys}"]


def crossing_constraints(board, capture_hz):
    """The Gray pointers of the board's :class:`PixelCrossing` (both directions), its capture
    domain clocked at ``capture_hz``."""
    limit = 0.8e9 / max(board.sync_hz, capture_hz)
    fifo = "*|frontend|crossing|fifo"
    return (gray_skew_constraints(f"{fifo}|produce_w_gry*", f"{fifo}|produce_cdc|*", limit)
            + gray_skew_constraints(f"{fifo}|consume_r_gry*", f"{fifo}|consume_cdc|*",
                                    limit))


class PixelCrossing(wiring.Component):
    """Pixel stream from a sensor clock domain into ``sync``; frames broken on overflow.

    See ``docs/sensors_and_link.md`` for the depth and the broken-frame rule.

    Parameters
    ----------
    pixel_bits : int
        Pixel width of the payload ``pixel_layout(pixel_bits)``.
    domain : str
        The sensor's clock domain (the FIFO's write side).
    depth : int
        FIFO entries, at least 2.

    Members
    -------
    pixels : ``In(stream.Signature(pixel_layout(pixel_bits), always_ready=True))``
        Pixels in ``domain``.
    out : ``Out(stream.Signature(pixel_layout(pixel_bits), always_ready=True))``
        The same pixels in ``sync``; a frame that lost a pixel ends there.
    overflow : ``Out(1)``
        A pixel was lost (``sync``); sticky until ``overflow_clear``.
    overflow_clear : ``In(1)``
        Clears ``overflow`` (``sync``).
    fifo_level : ``Out(range(depth + 1))``
        FIFO occupancy as the write side sees it (in ``domain``): entries written and not
        yet known to be read, the quantity that overflows.
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
        # nothing is taken while the write side is in reset (the FIFO drops it: it would be
        # counted lost)
        in_reset = ResetSignal(w, allow_reset_less=True)
        take = p.valid & ~in_reset & (p.payload.sof | ~broken)
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


STALL_TIMEOUT = 1 << 20
"""Default clocks without a pixel inside a frame before :class:`FrameWatchdog` completes it:
10.5 ms at 100 MHz, 21 ms at 50 MHz, over 200x the longest row blanking either sensor can
be programmed for (MT9P031 R0x05 <= 4095, MT9V022 R0x05 <= 1023 pixel clocks; frame
blanking lies outside a frame and is never timed)."""


class FrameWatchdog(wiring.Component):
    """Completes a frame the sensor stopped sending, so that the detector always ends it.

    Positions are counted as the threshold unit counts them (a line ends at ``eol`` or at
    column ``width - 1``; the frame at its last row's end).  When a frame has started and
    ``timeout`` clocks pass without a pixel, the watchdog pulses ``stalled`` and sends dark
    pixels (0, never lit: ``lit = p > T``) for the rest of the frame, one per clock with
    ``MIN_HBLANK`` idle clocks after each line; the detector then ends the frame normally and
    the board top level flags its trailer ``FRAME_TIMEOUT``.  Sensor pixels that arrive while
    it pads are dropped, except a ``sof``, which ends the padding (the detector then ends the
    frame ``FRAME_TRUNCATED``).  Everything is in ``sync``.

    Parameters
    ----------
    width, height : int
        The programmed frame (within the contract).
    pixel_bits : int
        Pixel width of the payload ``pixel_layout(pixel_bits)``.
    timeout : int
        Clocks without a pixel inside a frame before it is completed.

    Members
    -------
    pixels : ``In(stream.Signature(pixel_layout(pixel_bits), always_ready=True))``
        Pixels from the front end.
    out : ``Out(stream.Signature(pixel_layout(pixel_bits), always_ready=True))``
        The pixels one register later, padded frames completed, to the detector.
    stalled : ``Out(1)``
        Pulses when the watchdog gives up on a frame.
    padding : ``Out(1)``
        High while dark pixels are being sent.
    """

    def __init__(self, width, height, pixel_bits, timeout=STALL_TIMEOUT):
        C.check_geometry(width, height)
        if timeout < 1:
            raise ValueError(f"stall timeout must be at least 1 clock, got {timeout}")
        self.width, self.height, self.pixel_bits = width, height, pixel_bits
        self.timeout = timeout
        layout = pixel_layout(pixel_bits)
        super().__init__({
            "pixels": In(stream.Signature(layout, always_ready=True)),
            "out": Out(stream.Signature(layout, always_ready=True)),
            "stalled": Out(1),
            "padding": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        W, H = self.width, self.height
        p, out = self.pixels, self.out
        x = Signal(range(W))                 # the next pixel's position
        y = Signal(range(H))
        in_frame = Signal()                  # a frame has started and not reached its end
        idle = Signal(range(self.timeout))
        gap = Signal(range(MIN_HBLANK + 1))  # idle clocks still owed after a padded line

        # the pixel sent this clock (registered into ``out``): the sensor's or a dark one
        send = Signal()
        sof = Signal()
        eol = Signal()
        data = Signal(self.pixel_bits)
        m.d.sync += [out.valid.eq(send), out.payload.sof.eq(sof), out.payload.eol.eq(eol),
                     out.payload.data.eq(data)]
        cur_x = Mux(sof, 0, x)
        cur_y = Mux(sof, 0, y)
        row_end = eol | (cur_x == W - 1)
        with m.If(send):
            with m.If(row_end):
                m.d.sync += [x.eq(0), y.eq(Mux(cur_y == H - 1, 0, cur_y + 1))]
            with m.Else():
                m.d.sync += [x.eq(cur_x + 1), y.eq(cur_y)]
            m.d.sync += in_frame.eq(~(row_end & (cur_y == H - 1)))

        with m.FSM():
            with m.State("PASS"):
                m.d.comb += [send.eq(p.valid), sof.eq(p.payload.sof), eol.eq(p.payload.eol),
                             data.eq(p.payload.data)]
                with m.If(p.valid | ~in_frame):
                    m.d.sync += idle.eq(0)
                with m.Elif(idle == self.timeout - 1):
                    m.d.comb += self.stalled.eq(1)
                    m.d.sync += gap.eq(0)
                    m.next = "PAD"
                with m.Else():
                    m.d.sync += idle.eq(idle + 1)
            with m.State("PAD"):
                m.d.comb += self.padding.eq(1)
                with m.If(p.valid & p.payload.sof):
                    m.d.comb += [send.eq(1), sof.eq(1), eol.eq(p.payload.eol),
                                 data.eq(p.payload.data)]
                    m.d.sync += idle.eq(0)
                    m.next = "PASS"
                with m.Elif(gap != 0):
                    m.d.sync += gap.eq(gap - 1)
                with m.Else():
                    m.d.comb += [send.eq(1), eol.eq(x == W - 1)]
                    with m.If(x == W - 1):
                        m.d.sync += gap.eq(MIN_HBLANK)
                        with m.If(y == H - 1):
                            m.d.sync += idle.eq(0)
                            m.next = "PASS"
        return m


class SensorFrontend(wiring.Component):
    """Base of the sensor front ends: the geometry check, the ports every front end has (D5)
    and the :class:`PixelCrossing` behind them.  A subclass states its sensor and implements
    the board hooks, which :mod:`lodestar.hdl.boards` calls without knowing the sensor.

    Class attributes of a subclass: ``SENSOR`` (its name in ``C.SENSORS``), ``PIXEL_BITS``
    (``C.SENSOR_PIXEL_BITS[SENSOR]``), ``IO_VOLTS`` (the sensor's digital I/O supply range in V,
    low and high: an FPGA output above it must reach the sensor through a level translator),
    ``MASTER_CLOCK_MAX_HZ`` (the highest master clock the sensor accepts: the board's PLL output
    must not exceed it), ``CLOCK_PINS`` (board pins that clock the capture domain: given the
    pixel rate as their clock, no input register) and ``LVDS_PINS`` (pins with the LVDS I/O
    standard, registered by the receiver).  Board hooks: ``pins`` (the ``wiring.Signature`` of
    the top level's sensor ports), ``connect_pins(m, top)`` (drive the front end from them),
    ``status(top, since_read)`` (``{OVF_* bit: value}`` beyond ``OVF_PIXEL_FIFO``),
    ``board_clocks(m, board, ports, top)`` (on a board: give the sensor resource's ``ports``
    (requested with ``dir="-"``) their buffers, clock the capture domain, forward the
    :data:`MASTER_DOMAIN` clock to the sensor with :func:`clock_output`, drive the top level's
    sensor ports; returns the capture clock's "running" signal) and ``sdc_constraints(board)``
    (SDC lines).  The board's sensor resource has the subsignal ``reset_n`` besides the
    subclass's own (the board drives it).

    Parameters
    ----------
    width, height : int
        The frames the sensor is programmed for: checked against the contract, not enforced
        (the detector flags bad frames).
    members : dict
        The subclass's own members (its sensor inputs and status outputs).
    domain : str
        The capture clock domain.
    fifo_depth : int
        Entries of the :class:`PixelCrossing` FIFO.

    Members
    -------
    out : ``Out(stream.Signature(pixel_layout(PIXEL_BITS), always_ready=True))``
        The pixel stream in ``sync``.
    overflow : ``Out(1)``
        A pixel was lost in the crossing (``sync``); sticky until ``overflow_clear``.
    overflow_clear : ``In(1)``
        Clears ``overflow`` (``sync``).
    fifo_level : ``Out(range(fifo_depth + 1))``
        The crossing's FIFO occupancy, in ``domain`` (:class:`PixelCrossing`).
    """

    CLOCK_PINS = ()
    LVDS_PINS = ()
    PHASE_TRAINING = False
    """The front end takes ``taps`` and ``settle`` and trains its receiver's sample phase."""

    def __init__(self, width, height, members, *, domain, fifo_depth):
        C.check_geometry(width, height)
        self.width, self.height, self.domain, self.fifo_depth = width, height, domain, fifo_depth
        super().__init__({
            **members,
            "out": Out(stream.Signature(pixel_layout(self.PIXEL_BITS), always_ready=True)),
            "overflow": Out(1),
            "overflow_clear": In(1),
            "fifo_level": Out(range(fifo_depth + 1)),
        })

    def crossing(self, m):
        """Add the :class:`PixelCrossing` to ``m`` as ``crossing``, its ``sync`` side wired to
        the ports; returns it (its ``pixels`` are the subclass's to drive, in ``domain``)."""
        m.submodules.crossing = cross = PixelCrossing(self.PIXEL_BITS, self.domain,
                                                      self.fifo_depth)
        wiring.connect(m, wiring.flipped(self.out), cross.out)
        m.d.comb += [cross.overflow_clear.eq(self.overflow_clear),
                     self.overflow.eq(cross.overflow), self.fifo_level.eq(cross.fifo_level)]
        return cross

    def status(self, top, since_read):
        """No status bits beyond ``OVF_PIXEL_FIFO`` (the parallel sensors')."""
        return {}
