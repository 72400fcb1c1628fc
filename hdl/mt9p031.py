"""MT9P031 parallel front end: PIXCLK, LINE_VALID, FRAME_VALID and D[11:0] in, the detector's
pixel stream out in ``sync`` (the stream contract of :mod:`lodestar.hdl.frontend`).

Capture runs in the pixel clock domain (default ``"pix"``), whose edge the board top level
chooses (R0x0A[15]); ``width x height`` are checked, not enforced (the detector flags bad
frames).  The crossing into ``sync`` is :class:`lodestar.hdl.frontend.PixelCrossing`.  On a
board, PIXCLK clocks ``pix``, D/LINE_VALID/FRAME_VALID are sampled by the pins' own
flip-flops (``io.FFBuffer``, no reset, in the I/O elements) and the board's PLL makes EXTCLK,
forwarded through a DDR output (:meth:`board_clocks`); the front end's inputs are those
flip-flops' outputs.
Derivation: ``docs/sensors_and_link.md``.
"""

from amaranth import ClockDomain, ClockSignal, Const, Module, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In

from lodestar import contract as C
from lodestar.hdl.frontend import (
    FIFO_DEPTH,
    SensorFrontend,
    capture_buffer,
    clock_output,
    crossing_constraints,
    input_buffer,
    io_domain,
)

PIXEL_BITS = C.SENSOR_PIXEL_BITS["mt9p031"]
"""MT9P031 pixel width (the contract's ``SENSOR_PIXEL_BITS``)."""
TPD_NS = (-2.0, 2.0)
"""Estimate, to replace from the datasheet: the MT9P031's output valid times of D,
LINE_VALID and FRAME_VALID about the PIXCLK falling edge that launches them (min, max), at
2.8 V VDD_IO.  The datasheet's I/O timing table (tPD) could not be retrieved here; the
window is the +-3.2 ns valid window about the rising edge at 96 MHz that the gateware review
read from it (5.2 ns half period - 3.2 ns = 2.0 ns)."""
BOARD_SKEW_NS = 0.5
"""Estimate: the largest difference between the PIXCLK trace and a data trace from the
sensor to the FPGA (about 75 mm of mismatch on FR-4), added on both sides of ``TPD_NS``."""


class MT9P031Frontend(SensorFrontend):
    """MT9P031 parallel bus, sampled in ``domain``, to the detector's pixel stream in ``sync``.

    Parameters
    ----------
    width, height : int
        The programmed frame, not enforced (module docstring).
    domain : str
        The pixel clock domain.
    fifo_depth : int
        Entries of the crossing's FIFO.

    Members
    -------
    d : ``In(PIXEL_BITS)``
        The data bus D[11:0], in ``domain``, from registers (the pins' capture flip-flops).
    line_valid, frame_valid : ``In(1)``
        LINE_VALID and FRAME_VALID, in ``domain``, from registers.
    out, overflow, overflow_clear, fifo_level
        As :class:`lodestar.hdl.frontend.SensorFrontend`.
    """

    SENSOR = "mt9p031"
    PIXEL_BITS = PIXEL_BITS
    IO_VOLTS = (1.7, 3.1)
    MASTER_CLOCK_MAX_HZ = 96e6
    """EXTCLK at most 96 MHz (datasheet; the Linux device-tree binding's
    ``input-clock-frequency`` maximum)."""
    """VDD_IO 1.7-3.1 V (datasheet); 96 MHz PIXCLK needs 2.8 V."""
    CLOCK_PINS = ("pixclk",)

    def __init__(self, width, height, *, domain="pix", fifo_depth=FIFO_DEPTH):
        super().__init__(width, height, {
            "d": In(PIXEL_BITS),
            "line_valid": In(1),
            "frame_valid": In(1),
        }, domain=domain, fifo_depth=fifo_depth)

    @property
    def pins(self):
        """The top level's sensor ports: the bus as it comes from the pins."""
        return wiring.Signature({"pix_d": In(PIXEL_BITS), "line_valid": In(1),
                                 "frame_valid": In(1)})

    def connect_pins(self, m, top):
        """Drive the front end from the top level's ``pins``."""
        m.d.comb += [self.d.eq(top.pix_d), self.line_valid.eq(top.line_valid),
                     self.frame_valid.eq(top.frame_valid)]

    def board_clocks(self, m, board, ports, top):
        """PIXCLK clocks ``domain`` (and its reset-less twin, which clocks the capture
        flip-flops of D, LINE_VALID and FRAME_VALID), the master clock is forwarded to EXTCLK
        (the sensor's own PLL makes PIXCLK from it), the captured bus goes to the top level;
        the capture clock runs once the board is up (returns 1)."""
        pixclk = input_buffer(m, "pin_mt9p031_0__pixclk", ports.pixclk)
        m.domains += ClockDomain(io_domain(self.domain), reset_less=True)
        m.d.comb += [ClockSignal(self.domain).eq(pixclk.i),
                     ClockSignal(io_domain(self.domain)).eq(pixclk.i)]
        clock_output(m, "pin_mt9p031_0__extclk", ports.extclk)
        bus = {sub: capture_buffer(m, f"pin_mt9p031_0__{sub}", getattr(ports, sub),
                                   self.domain) for sub in ("d", "line_valid", "frame_valid")}
        m.d.comb += [top.pix_d.eq(bus["d"].i), top.line_valid.eq(bus["line_valid"].i),
                     top.frame_valid.eq(bus["frame_valid"].i)]
        return Const(1)

    @staticmethod
    def sdc_constraints(board):
        """PIXCLK's domain is asynchronous to ``sync`` (the crossing's Gray pointers
        skew-bounded); the bus's input delays: the sensor's output valid times ``TPD_NS``
        about PIXCLK's falling edge, widened by ``BOARD_SKEW_NS``; EXTCLK, a forwarded clock
        with no data relation to any FPGA clock (PIXCLK comes back from the sensor's own
        PLL), is not timed."""
        ports = "mt9p031_0__d__io* mt9p031_0__line_valid__io mt9p031_0__frame_valid__io"
        delay = "set_input_delay -clock [get_clocks {mt9p031_0__pixclk__io}] -clock_fall"
        low, high = TPD_NS[0] - BOARD_SKEW_NS, TPD_NS[1] + BOARD_SKEW_NS
        return ["# the sensor clock domain meets sync only through the AsyncFIFO and "
                "synchronizers",
                "set_clock_groups -asynchronous -group [get_clocks {mt9p031_0__pixclk__io}]",
                *crossing_constraints(board, board.pixel_hz),
                "# D/LV/FV: launched on PIXCLK's falling edge (output valid TPD_NS, an "
                "estimate) plus board skew; sampled on the rising edge",
                f"{delay} -max {high:.3f} [get_ports {{{ports}}}]",
                f"{delay} -min {low:.3f} [get_ports {{{ports}}}]",
                "# EXTCLK: the forwarded master clock (DDR output), no data relation",
                "set_false_path -to [get_ports {mt9p031_0__extclk__io}]"]

    def elaborate(self, platform):
        m = Module()
        pix = self.domain
        cross = self.crossing(m)

        # the inputs come from registers (on a board the pins' capture flip-flops): a frame
        # under way when the domain leaves reset has FRAME_VALID high, so ``armed`` stays low
        # and its pixels are not taken for a frame start
        d, fv = self.d, self.frame_valid
        valid = self.line_valid & fv

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
