"""Board top levels: sensor front end, detector, packetizer and SPI slave, on Cyclone IV boards.

:class:`GatewareTop` is the whole design with its pins as ports (simulatable and synthesizable
on its own); :class:`BoardTop` puts it on a board of :data:`BOARDS` (clocks, resources) and
``board_platform(name)`` gives the Amaranth ``AlteraPlatform``.  MCU interface: SPI mode 0
with the commands of :mod:`lodestar.hdl.spi_slave` (MISO tri-stated while CS is high);
``irq`` is a registered copy of "a packet is being delivered" whose high and low pulses last
at least ``IRQ_MIN_CLOCKS`` (the MCU reads one packet per rising edge with ``READ_STREAM``);
register writes take effect on the next frame.  The status word's ``overflow`` bits are the
contract's ``OVF_*``.  A frame the sensor stops sending is completed by
:class:`lodestar.hdl.mt9p031.FrameWatchdog` and its trailer flagged ``FRAME_TIMEOUT``.  Only
power-up resets the design: a later PLL lock loss sets ``OVF_CLOCK_LOST`` and keeps the
registers and the sensor's configuration.  Every pin marked *assumed* in :data:`BOARDS` must
be checked against the board's schematic before the bitstream is loaded.  Details:
``docs/sensors_and_link.md`` (Board top levels).
"""

from amaranth import (
    Cat,
    ClockDomain,
    ClockSignal,
    Const,
    Elaboratable,
    Instance,
    Module,
    Mux,
    Signal,
)
from amaranth.build import Attrs, Clock, Pins, Resource, Subsignal
from amaranth.lib import wiring
from amaranth.lib.cdc import FFSynchronizer, ResetSynchronizer
from amaranth.lib.wiring import In, Out
from amaranth.vendor import AlteraPlatform

from lodestar import contract as C

from .detector import Detector
from .layouts import trailer_layout
from .mt9p031 import STALL_TIMEOUT, FrameWatchdog, MT9P031Frontend
from .mt9v022 import PACKET_BITS, MT9V022Frontend
from .packetizer import Packetizer
from .spi_slave import SPI_PINS, SPISlave, max_sck_hz

SENSOR_DOMAIN = {"mt9p031": "pix", "mt9v022": "ser"}
"""Clock domain of each front end's capture logic."""
LVDS_LANES = 6
"""Bits per ``ser`` clock from the LVDS deserializer (ALTLVDS_RX, factor 6)."""
IRQ_MIN_CLOCKS = 16
"""Shortest high and low pulse of ``irq``, in ``sync`` clocks (160 ns at 100 MHz, 320 ns at
50 MHz: far above what an STM32 EXTI input needs to see an edge)."""
PLL_LOSS_BITS = 2
"""Width of the Gray-coded count of PLL lock losses (``OVF_CLOCK_LOST`` compares it with its
value at the last status read, so 4 losses between two reads would go unseen)."""
TIMEOUT_SLOTS = 8
"""Frames whose ``FRAME_TIMEOUT`` mark is remembered until their trailer goes out (indexed by
the frame counter's low bits)."""


class IrqLine(wiring.Component):
    """``irq`` follows ``busy`` one clock later, from a flip-flop (no decode glitch reaches
    the pin), and holds each level for at least ``min_clocks`` clocks.  A ``busy`` low pulse
    of one clock between back-to-back packets thus becomes a low pulse of ``min_clocks``,
    provided ``busy`` was high for ``min_clocks`` before it (a packet takes far longer)."""

    def __init__(self, min_clocks=IRQ_MIN_CLOCKS):
        if min_clocks < 1:
            raise ValueError(f"min_clocks must be at least 1, got {min_clocks}")
        self.min_clocks = min_clocks
        super().__init__({"busy": In(1), "irq": Out(1)})

    def elaborate(self, platform):
        m = Module()
        hold = Signal(range(self.min_clocks))     # clocks the present level must still last
        with m.If(hold != 0):
            m.d.sync += hold.eq(hold - 1)
        with m.Elif(self.irq != self.busy):
            m.d.sync += [self.irq.eq(self.busy), hold.eq(self.min_clocks - 1)]
        return m


class ClockGuard(Elaboratable):
    """Resets from the PLL's ``locked`` (asynchronous) for power-up only, in the always-running
    oscillator domain ``osc``.  ``ever_locked`` rises at the first lock and stays high: the
    board holds ``sync``, the capture domain and the sensor in reset until then.  A later lock
    loss does not reset anything (the MCU's registers and the sensor's configuration are
    kept); it increments ``losses``, a ``PLL_LOSS_BITS``-bit Gray count in ``osc`` that the
    board synchronizes into ``sync`` for ``OVF_CLOCK_LOST``."""

    def __init__(self):
        self.locked = Signal()
        self.ever_locked = Signal()
        self.losses = Signal(PLL_LOSS_BITS)

    def elaborate(self, platform):
        m = Module()
        locked = Signal()
        m.submodules.locked_cdc = FFSynchronizer(self.locked, locked, o_domain="osc")
        was = Signal()
        count = Signal(PLL_LOSS_BITS)
        m.d.osc += was.eq(locked)
        with m.If(locked):
            m.d.osc += self.ever_locked.eq(1)
        with m.If(was & ~locked):
            m.d.osc += [count.eq(count + 1), self.losses.eq((count + 1) ^ ((count + 1) >> 1))]
        return m


class GatewareTop(wiring.Component):
    """The star-tracker gateware for one sensor and frame geometry, pins as ports.

    ``sensor``: one of :data:`C.SENSORS`.  ``width x height``: the frames the sensor is
    programmed for.  ``label_capacity``, ``record_capacity``, ``record_depth``: the detector's
    (``record_depth`` records stay buffered until the MCU reads them; the packetizer sends a
    frame's records from there).  Sensor ports: ``pix_d``, ``line_valid``, ``frame_valid``
    in the ``pix`` domain (MT9P031), or ``lvds_bits`` (``LVDS_LANES`` bits, earliest bit
    first as ``MT9V022Frontend`` takes them) in the ``ser`` domain and ``rx_locked`` (the
    LVDS receiver's PLL, synchronized into ``sync`` by the board) (MT9V022).  MCU ports in
    ``sync``: ``sck``, ``mosi``, ``cs_n``, ``miso``, ``miso_oe``, ``irq``.  ``pll_losses``
    (``sync``): the board's Gray count of PLL lock losses (``OVF_CLOCK_LOST``).
    ``stall_timeout``: clocks without a pixel inside a frame before the frame is completed
    with dark pixels and flagged ``FRAME_TIMEOUT`` (:class:`FrameWatchdog`).
    """

    def __init__(self, sensor, width, height, *, label_capacity=None,
                 record_capacity=C.DEFAULT_RECORD_CAPACITY, record_depth=None,
                 stall_timeout=STALL_TIMEOUT):
        if sensor not in C.SENSORS:
            raise ValueError(f"unknown sensor {sensor!r}; choose one of {', '.join(C.SENSORS)}")
        self.sensor, self.width, self.height = sensor, width, height
        self.pixel_bits = C.SENSOR_PIXEL_BITS[sensor]
        if sensor == "mt9p031":
            self.frontend = MT9P031Frontend(width, height, domain=SENSOR_DOMAIN[sensor])
            pins = {"pix_d": In(self.pixel_bits), "line_valid": In(1), "frame_valid": In(1)}
        else:
            self.frontend = MT9V022Frontend(width, height, lanes=LVDS_LANES,
                                            domain=SENSOR_DOMAIN[sensor])
            pins = {"lvds_bits": In(LVDS_LANES), "rx_locked": In(1)}
        self.watchdog = FrameWatchdog(width, height, self.pixel_bits, stall_timeout)
        self.detector = Detector(width, height, self.pixel_bits, label_capacity=label_capacity,
                                 record_capacity=record_capacity, record_depth=record_depth)
        self.packetizer = Packetizer(width, height, self.pixel_bits)
        self.spi = SPISlave()
        self.irq_line = IrqLine()
        super().__init__({
            **pins,
            **SPI_PINS,
            "irq": Out(1),
            "pll_losses": In(PLL_LOSS_BITS),
        })

    def elaborate(self, platform):
        m = Module()
        fe, det, pkt, spi = self.frontend, self.detector, self.packetizer, self.spi
        m.submodules.frontend, m.submodules.detector = fe, det
        m.submodules.packetizer, m.submodules.spi = pkt, spi
        m.submodules.watchdog, m.submodules.irq_line = wd, irq = self.watchdog, self.irq_line
        if self.sensor == "mt9p031":
            m.d.comb += [fe.d.eq(self.pix_d), fe.line_valid.eq(self.line_valid),
                         fe.frame_valid.eq(self.frame_valid)]
        else:
            m.d.comb += fe.bits.eq(self.lvds_bits)
        wiring.connect(m, fe.out, wd.pixels)
        wiring.connect(m, wd.out, det.pixels)
        wiring.connect(m, det.records, pkt.records)
        wiring.connect(m, pkt.packet, spi.packet)

        # ---- FRAME_TIMEOUT: marked per frame number, added to that frame's trailer --------
        # When the watchdog gives up on a frame, the labeller started it long ago, so it is
        # frame ``frame_counter - 1``; a frame's mark is cleared when its pixels start.  The
        # mark of a trailer held unread for TIMEOUT_SLOTS frames (later trailers are then
        # lost: OVF_TRAILER_LOST) may be overwritten.
        slot_bits = C.bits_for(TIMEOUT_SLOTS - 1)
        marks = Signal(TIMEOUT_SLOTS)
        newest = det.frame_counter[:slot_bits]
        with m.If(wd.stalled):
            m.d.sync += marks.bit_select((newest - 1)[:slot_bits], 1).eq(1)
        with m.Elif(wd.pixels.valid & wd.pixels.payload.sof):
            m.d.sync += marks.bit_select(newest, 1).eq(0)
        head = Signal(trailer_layout())
        timed_out = marks.bit_select(det.trailer.payload.frame_counter[:slot_bits], 1)
        m.d.comb += [
            head.eq(det.trailer.payload),
            head.flags.eq(det.trailer.payload.flags | Mux(timed_out, C.FRAME_TIMEOUT, 0)),
            pkt.trailer.payload.eq(head), pkt.trailer.valid.eq(det.trailer.valid),
            det.trailer.ready.eq(pkt.trailer.ready),
        ]
        m.d.comb += [
            spi.sck.eq(self.sck), spi.mosi.eq(self.mosi), spi.cs_n.eq(self.cs_n),
            self.miso.eq(spi.miso), self.miso_oe.eq(spi.miso_oe),
            det.reg_addr.eq(spi.reg_addr), det.reg_data.eq(spi.reg_data),
            det.reg_en.eq(spi.reg_strobe),
            spi.busy.eq(det.busy), spi.frame_counter.eq(det.frame_counter),
            fe.overflow_clear.eq(spi.status_read), det.reg_error_clear.eq(spi.status_read),
            irq.busy.eq(pkt.busy), self.irq.eq(irq.irq),
        ]

        def since_read(counter, name):
            """High while ``counter`` differs from its value at the last status read."""
            seen = Signal.like(counter, name=f"{name}_seen")
            with m.If(spi.status_read):
                m.d.sync += seen.eq(counter)
            return counter != seen

        overflow = [Const(0, 1)] * C.OVERFLOW_BITS
        overflow[C.OVF_PIXEL_FIFO] = fe.overflow
        overflow[C.OVF_TRAILER_LOST] = since_read(det.trailer_lost, "trailer_lost")
        overflow[C.OVF_REG_REFUSED] = det.reg_error
        overflow[C.OVF_FAULT] = det.fault
        overflow[C.OVF_CLOCK_LOST] = since_read(self.pll_losses, "pll_losses")
        if self.sensor == "mt9v022":
            overflow[C.OVF_LINK_DOWN] = ~fe.locked | ~self.rx_locked
            overflow[C.OVF_LINK_ERROR] = since_read(fe.framing_errors, "framing_errors")
        m.d.comb += spi.overflow.eq(Cat(*overflow))
        return m


# --------------------------------------------------------------------------------------
# Boards
# --------------------------------------------------------------------------------------

_LVCMOS = "3.3-V LVTTL"
_LVDS = "LVDS"

IO_STANDARD_VOLTS = {_LVCMOS: 3.3, "2.5 V": 2.5}
"""Output high level (VCCIO) of each single-ended I/O standard used here."""
SENSOR_IO_VOLTS = {"mt9p031": (1.7, 3.1), "mt9v022": (3.0, 3.6)}
"""Each sensor's digital I/O supply range (V): MT9P031 VDD_IO 1.7-3.1 V (96 MHz PIXCLK needs
2.8 V); MT9V022 VDD 3.3 V +- 0.3 V (datasheets).  An FPGA output above the range damages the
sensor input; it must go through a level translator."""


class Board:
    """One supported board: part, clocks, sensor, frame, detector capacities and pins.

    ``les``, ``m9k``, ``multipliers``: the part's logic elements, M9K blocks and 18x18
    embedded multipliers (two 9x9 each).  ``pins`` maps a resource name to
    ``{subsignal: (pins, dir, assumed)}``; ``assumed`` marks pins on a custom header whose
    wiring this file assumes.  ``io_standard`` maps a resource name to the I/O standard of its
    single-ended pins (LVDS pairs are ``LVDS``); it must be one the bank's VCCIO allows.
    ``sensor_io_volts``: the sensor board's I/O supply; ``level_translated``: the sensor
    inputs (FPGA outputs) that reach the sensor through a level translator on the sensor
    board because the bank drives them above the sensor's I/O range (:data:`SENSOR_IO_VOLTS`).
    ``notes`` say what is assumed.
    """

    def __init__(self, name, *, device, package, speed, les, m9k, multipliers, osc_hz,
                 osc_pin, sync_hz, sensor, width, height, pixel_hz, sensor_clk_hz,
                 label_capacity, record_capacity, record_depth, pins, io_standard,
                 sensor_io_volts, level_translated, notes):
        self.name, self.device, self.package, self.speed = name, device, package, speed
        self.les, self.m9k, self.multipliers = les, m9k, multipliers
        self.osc_hz, self.osc_pin, self.sync_hz = osc_hz, osc_pin, sync_hz
        self.sensor, self.width, self.height = sensor, width, height
        self.pixel_bits = C.SENSOR_PIXEL_BITS[sensor]
        self.pixel_hz, self.sensor_clk_hz = pixel_hz, sensor_clk_hz
        self.label_capacity, self.record_capacity = label_capacity, record_capacity
        self.record_depth = record_depth
        self.pins, self.io_standard, self.notes = pins, io_standard, notes
        self.sensor_io_volts, self.level_translated = sensor_io_volts, level_translated

    @property
    def spi_sck_max_hz(self):
        """The SPI slave's own limit on SCK at this board's sync clock (estimate:
        :func:`lodestar.hdl.spi_slave.max_sck_hz`)."""
        return max_sck_hz(self.sync_hz)

    @property
    def part(self):
        return f"{self.device}{self.package}{self.speed}"

    def star_tracker(self, width=None, height=None):
        """The board's :class:`GatewareTop` (optionally for another frame geometry)."""
        return GatewareTop(self.sensor, width or self.width, height or self.height,
                           label_capacity=self.label_capacity,
                           record_capacity=self.record_capacity, record_depth=self.record_depth)


# MT9P031 on a 40-pin header, MCU on the same header.  DE0-Nano GPIO-0 (JP1) pins follow the
# amaranth-boards DE0NanoPlatform connector table ("gpio", 0); which header pin carries which
# sensor signal is this project's choice (the sensor board is custom): all assumed.
_MT9P031_PINS = {
    "mt9p031": {
        "pixclk": ("A8", "i", True),
        "d": ("D3 C3 A2 A3 B3 B4 A4 B5 A5 D5 B6 A6", "i", True),
        "line_valid": ("B7", "i", True),
        "frame_valid": ("D6", "i", True),
        "extclk": ("A7", "o", True),
        "reset_n": ("C6", "o", True),
    },
    "mcu": {
        "sck": ("D8", "i", True),
        "mosi": ("E8", "i", True),
        "cs_n": ("F8", "i", True),
        "miso": ("F9", "oe", True),
        "irq": ("E9", "o", True),
    },
}

# MT9V022 LVDS on the DE2-115 HSMC connector (Lohmann's custom PCB), MCU on GPIO (JP5).
_MT9V022_PINS = {
    "mt9v022": {
        # LVDS inputs: the positive pin is assigned; Quartus places the negative pin of the
        # pair (J28, G28) itself for the LVDS I/O standard.
        "ser_clk": ("J27", "i", True),          # HSMC_CLKIN_P1 / N1 (J28), a clock input
        "ser_data": ("G25", "i", True),         # HSMC_RX_D_P[3] / N[3] (G26), receiver pair
        "sysclk": ("D27", "o", True),           # HSMC_TX_D_P[0], single-ended 2.5 V
        "reset_n": ("D28", "o", True),          # HSMC_TX_D_N[0], single-ended 2.5 V
    },
    "mcu": {
        "sck": ("AB22", "i", True),
        "mosi": ("AC15", "i", True),
        "cs_n": ("AB21", "i", True),
        "miso": ("Y17", "oe", True),
        "irq": ("AC21", "o", True),
    },
}

BOARDS = {
    "de2-115": Board(
        "de2-115", device="EP4CE115", package="F29", speed="C7", les=114480, m9k=432,
        multipliers=266, osc_hz=50e6, osc_pin="Y2", sync_hz=50e6, sensor="mt9v022",
        width=752, height=480, pixel_hz=26.667e6, sensor_clk_hz=26.667e6,
        label_capacity=None, record_capacity=C.DEFAULT_RECORD_CAPACITY,
        record_depth=2 * C.DEFAULT_RECORD_CAPACITY, pins=_MT9V022_PINS,
        io_standard={"mt9v022": "2.5 V", "mcu": _LVCMOS},
        sensor_io_volts=3.3, level_translated=("sysclk", "reset_n"),
        notes=("Terasic DE2-115, EP4CE115F29C7, CLOCK_50 on Y2 (board manual).  sync runs "
               "from CLOCK_50 directly (50 MHz >= the 26.67 MHz pixel rate).  A PLL makes "
               "the sensor's 26.67 MHz SYSCLK (50 x 8 / 15).  MT9V022 LVDS (Lohmann's custom "
               "PCB) on the HSMC connector, pins from Terasic's System Builder QSF: the "
               "returned LVDS clock on HSMC_CLKIN_P1/N1, the data on the receiver pair "
               "HSMC_RX_D_P/N[3] (100 ohm termination on the PCB, Cyclone IV E inputs have "
               "none on chip), SYSCLK and RESET_BAR single-ended on HSMC_TX_D_P/N[0] at "
               "2.5 V, the HSMC bank's VCCIO set by JP7 (2.5 V "
               "default, which the LVDS inputs also need); the 3.3-V sensor sees them through "
               "level translators on the PCB (assumed).  The ALTLVDS_RX receiver (factor 6, "
               "320 Mbit/s, inclock phase shifted half a bit so that an edge-aligned clock "
               "samples mid-bit) is instantiated as documented and must be checked in the "
               "Quartus MegaWizard.  MCU SPI and IRQ on GPIO header JP5 pins 1-5 "
               "(GPIO[0..4], Terasic QSF), 3.3-V LVTTL.")),
    "de0-nano": Board(
        "de0-nano", device="EP4CE22", package="F17", speed="C6", les=22320, m9k=66,
        multipliers=66, osc_hz=50e6, osc_pin="R8", sync_hz=100e6, sensor="mt9p031",
        width=2592, height=1944, pixel_hz=96e6, sensor_clk_hz=25e6,
        label_capacity=254, record_capacity=256, record_depth=128, pins=_MT9P031_PINS,
        io_standard={"mt9p031": _LVCMOS, "mcu": _LVCMOS},
        sensor_io_volts=2.8, level_translated=("extclk", "reset_n"),
        notes=("Terasic DE0-Nano, EP4CE22F17C6, CLOCK_50 on R8 (amaranth-boards "
               "DE0NanoPlatform).  A PLL makes sync = 100 MHz (>= the 96 MHz pixel rate) "
               "and the sensor's EXTCLK = 25 MHz (its own PLL makes the 96 MHz PIXCLK).  "
               "MT9P031 and MCU on GPIO-0 (JP1), whose bank is 3.3 V (3.3-V LVTTL); the "
               "header wiring is assumed (custom sensor board).  The sensor runs its I/O at "
               "2.8 V (needed for 96 MHz; range 1.7-3.1 V): its 2.8-V outputs meet the "
               "3.3-V LVTTL input levels, but EXTCLK and RESET_BAR must reach it through "
               "level translators on the sensor board.  PIXCLK on GPIO_0_IN0 (A8), assumed "
               "to be usable as a clock input (verify in the pin planner).  The sensor's "
               "two-wire serial port is driven by the MCU (firmware/sensor.py).")),
    "estcube2": Board(
        "estcube2", device="EP4CE22", package="F17", speed="I7", les=22320, m9k=66,
        multipliers=66, osc_hz=50e6, osc_pin="R8", sync_hz=100e6, sensor="mt9p031",
        width=2592, height=1944, pixel_hz=96e6, sensor_clk_hz=25e6,
        label_capacity=254, record_capacity=256, record_depth=128, pins=_MT9P031_PINS,
        io_standard={"mt9p031": _LVCMOS, "mcu": _LVCMOS},
        sensor_io_volts=2.8, level_translated=("extclk", "reset_n"),
        notes=("ESTCube-2 star tracker configuration (Schumann 2019): EP4CE22 with the "
               "MT9P031.  The flight board is custom: the package (F17), the industrial "
               "speed grade I7, the 50 MHz oscillator and every pin are assumptions that "
               "mirror the DE0-Nano layout; replace them from the flight schematic.  Clocks "
               "as on the DE0-Nano (sync 100 MHz from a PLL, EXTCLK 25 MHz).")),
}
"""Supported boards by name (``lodestar synth --board``)."""


_REGISTERED_OUTPUTS = ("miso", "irq")
"""Outputs driven straight from a flip-flop without reset (``FAST_OUTPUT_REGISTER``)."""


def _resources(board):
    """Pins as Amaranth resources: each sampled input gets ``FAST_INPUT_REGISTER`` (its first
    flip-flop has no reset, so the fitter can pack it into the I/O element), each output
    from a bare flip-flop ``FAST_OUTPUT_REGISTER``."""
    resources = [Resource("clk_osc", 0, Pins(board.osc_pin, dir="i"), Clock(board.osc_hz),
                          Attrs(io_standard=_LVCMOS))]
    for name, signals in board.pins.items():
        subs = []
        for sub, (pins, direction, _assumed) in signals.items():
            if sub in ("ser_clk", "ser_data"):
                subs.append(Subsignal(sub, Pins(pins, dir=direction),
                                      Attrs(io_standard=_LVDS)))
            else:
                extra = [Clock(board.pixel_hz)] if sub == "pixclk" else []
                attrs = {"io_standard": board.io_standard[name]}
                if direction == "i" and sub != "pixclk":
                    attrs["FAST_INPUT_REGISTER"] = "ON"
                if sub in _REGISTERED_OUTPUTS:
                    attrs["FAST_OUTPUT_REGISTER"] = "ON"
                subs.append(Subsignal(sub, Pins(pins, dir=direction), *extra, Attrs(**attrs)))
        resources.append(Resource(name, 0, *subs))
    return resources


def board_platform(name):
    """The ``AlteraPlatform`` (Quartus toolchain) of board ``name`` with its pins."""
    if name not in BOARDS:
        raise ValueError(f"unknown board {name!r}; choose one of {', '.join(BOARDS)}")
    board = BOARDS[name]
    attrs = {"device": board.device, "package": board.package, "speed": board.speed,
             "default_clk": "clk_osc", "resources": _resources(board), "connectors": []}
    return type(f"{name.replace('-', '_')}_platform", (AlteraPlatform,), attrs)()


def _altpll(m, name, inclk, in_hz, outputs):
    """An ALTPLL (Cyclone IV E) with ``outputs`` = ``[(signal, multiply_by, divide_by)]``;
    returns its ``locked`` signal."""
    clk = Signal(5, name=f"{name}_clk")
    locked = Signal(name=f"{name}_locked")
    params = {"p_intended_device_family": "Cyclone IV E", "p_lpm_type": "altpll",
              "p_operation_mode": "NORMAL", "p_pll_type": "AUTO", "p_bandwidth_type": "AUTO",
              "p_compensate_clock": "CLK0", "p_width_clock": 5,
              "p_inclk0_input_frequency": round(1e12 / in_hz),
              "p_port_inclk0": "PORT_USED", "p_port_locked": "PORT_USED"}
    for k, (sig, mul, div) in enumerate(outputs):
        params.update({f"p_clk{k}_multiply_by": mul, f"p_clk{k}_divide_by": div,
                       f"p_clk{k}_duty_cycle": 50, f"p_clk{k}_phase_shift": "0",
                       f"p_port_clk{k}": "PORT_USED"})
        m.d.comb += sig.eq(clk[k])
    m.submodules[name] = Instance("altpll", **params, i_inclk=Cat(inclk, Const(0, 1)),
                                  i_areset=Const(0, 1), o_clk=clk, o_locked=locked)
    return locked


def _ratio(out_hz, in_hz, limit=64):
    """``(multiply_by, divide_by)`` of the ALTPLL output nearest ``out_hz``."""
    best = None
    for div in range(1, limit + 1):
        mul = max(1, round(out_hz * div / in_hz))
        err = abs(in_hz * mul / div - out_hz)
        if best is None or err < best[0] - 1e-3:
            best = (err, mul, div)
    return best[1], best[2]


class BoardTop(Elaboratable):
    """:class:`GatewareTop` on a board (see :data:`BOARDS`): clocks, resets and pins.

    ``board``: a name of :data:`BOARDS` or a :class:`Board` (e.g. a copy with another frame
    or other capacities)."""

    def __init__(self, board):
        if isinstance(board, str):
            if board not in BOARDS:
                raise ValueError(f"unknown board {board!r}; choose one of {', '.join(BOARDS)}")
            board = BOARDS[board]
        self.board = board
        self.core = board.star_tracker()

    def elaborate(self, platform):
        m = Module()
        b = self.board
        m.submodules.core = core = self.core
        osc = platform.request("clk_osc", 0).i
        sensor = platform.request(b.sensor, 0)
        mcu = platform.request("mcu", 0)

        # ---- clocks: sync, the sensor's master clock, the capture domain ----------------
        m.domains.sync = ClockDomain("sync")
        m.domains.osc = ClockDomain("osc", reset_less=True)
        m.d.comb += ClockSignal("osc").eq(osc)
        if b.sync_hz == b.osc_hz:
            outputs = []
            m.d.comb += ClockSignal("sync").eq(osc)
        else:
            outputs = [(ClockSignal("sync"), *_ratio(b.sync_hz, b.osc_hz))]
        sensor_clk = Signal()
        outputs.append((sensor_clk, *_ratio(b.sensor_clk_hz, b.osc_hz)))
        # power-up reset only: a later lock loss is counted, not a reset (ClockGuard)
        m.submodules.clock_guard = guard = ClockGuard()
        m.d.comb += guard.locked.eq(_altpll(m, "pll", osc, b.osc_hz, outputs))
        m.submodules.sync_reset = ResetSynchronizer(~guard.ever_locked, domain="sync")
        m.submodules.pll_losses_cdc = FFSynchronizer(guard.losses, core.pll_losses)
        capture = SENSOR_DOMAIN[b.sensor]
        m.domains += ClockDomain(capture)
        capture_up = Signal()
        m.submodules.capture_reset = ResetSynchronizer(~capture_up, domain=capture)
        if b.sensor == "mt9p031":
            m.d.comb += capture_up.eq(guard.ever_locked)
            m.d.comb += [ClockSignal("pix").eq(sensor.pixclk.i),
                         sensor.extclk.o.eq(sensor_clk),
                         core.pix_d.eq(sensor.d.i), core.line_valid.eq(sensor.line_valid.i),
                         core.frame_valid.eq(sensor.frame_valid.i)]
        else:
            ser_clk = Signal()
            rx_locked = Signal()
            bit_ps = 1e12 / (b.pixel_hz * PACKET_BITS)
            m.submodules.lvds_rx = Instance(
                "altlvds_rx",
                p_intended_device_family="Cyclone IV E", p_lpm_type="altlvds_rx",
                p_number_of_channels=1, p_deserialization_factor=LVDS_LANES,
                p_data_rate=f"{1e6 / bit_ps:.1f} Mbps",
                p_input_data_rate=round(1e6 / bit_ps),
                p_inclock_period=round(1e12 / b.pixel_hz), p_implement_in_les="ON",
                # no DPA on Cyclone IV: shift the sampling clock by half a bit so that a
                # clock edge-aligned with the data samples each bit in its middle
                p_inclock_phase_shift=round(bit_ps / 2),
                p_registered_output="ON", p_use_external_pll="OFF",
                i_rx_in=sensor.ser_data.i, i_rx_inclock=sensor.ser_clk.i,
                o_rx_out=core.lvds_bits, o_rx_outclock=ser_clk, o_rx_locked=rx_locked)
            m.d.comb += [ClockSignal("ser").eq(ser_clk), sensor.sysclk.o.eq(sensor_clk),
                         capture_up.eq(guard.ever_locked & rx_locked)]
            m.submodules.rx_locked_cdc = FFSynchronizer(rx_locked, core.rx_locked)
        # the sensor is held in reset until the clocks first come up, never after (it
        # keeps the configuration the MCU wrote)
        m.d.comb += sensor.reset_n.o.eq(guard.ever_locked)

        # ---- MCU ----------------------------------------------------------------------
        m.d.comb += [core.sck.eq(mcu.sck.i), core.mosi.eq(mcu.mosi.i), core.cs_n.eq(mcu.cs_n.i),
                     mcu.miso.o.eq(core.miso), mcu.miso.oe.eq(core.miso_oe),
                     mcu.irq.o.eq(core.irq)]
        return m


def sdc_constraints(board):
    """Extra SDC lines (after the platform's ``create_clock`` of the oscillator and the sensor
    clock pin): PLL clocks, the sensor domain asynchronous to ``sync``, MCU pins through
    synchronizers."""
    lines = ["derive_pll_clocks", "derive_clock_uncertainty",
             "# the sensor clock domain meets sync only through the AsyncFIFO and synchronizers",
             "set_clock_groups -asynchronous -group [get_clocks {*mt9*}]"
             if board.sensor == "mt9p031" else "# (LVDS clock group below)",
             "# SPI and IRQ pins are asynchronous to every clock (2-flop synchronizers)",
             "set_false_path -from [get_ports {mcu_0__*}]",
             "set_false_path -to [get_ports {mcu_0__*}]"]
    if board.sensor == "mt9v022":
        lines += ["# the LVDS receiver's reference clock (its PLL's outputs come from "
                  "derive_pll_clocks)",
                  f"create_clock -name mt9v022_ser_clk -period {1e9 / board.pixel_hz:.3f} "
                  "[get_ports {mt9v022_0__ser_clk__io}]",
                  "set_clock_groups -asynchronous -group [get_clocks {mt9v022_ser_clk "
                  "*lvds_rx*}]"]
    if board.sensor == "mt9p031":
        lines += ["# MT9P031 launches D/LV/FV on PIXCLK's falling edge; the FPGA samples on the "
                  "rising edge.",
                  "# Output delay window assumed +-2 ns around the falling edge (datasheet "
                  "tPD, to verify).",
                  "set_input_delay -clock [get_clocks {*mt9p031_0__pixclk*}] -clock_fall "
                  "-max 2.0 [get_ports {mt9p031_0__d* mt9p031_0__line_valid* "
                  "mt9p031_0__frame_valid*}]",
                  "set_input_delay -clock [get_clocks {*mt9p031_0__pixclk*}] -clock_fall "
                  "-min -2.0 [get_ports {mt9p031_0__d* mt9p031_0__line_valid* "
                  "mt9p031_0__frame_valid*}]"]
    return "\n".join(lines)
