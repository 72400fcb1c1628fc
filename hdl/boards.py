"""Board top levels: sensor front end, detector, packetizer and SPI slave, on Cyclone IV boards.

:class:`GatewareTop` is the whole design with its pins as ports (simulatable and synthesizable
on its own); :class:`BoardTop` puts it on a board of :data:`BOARDS` (clocks, resources) and
``board_platform(name)`` gives the Amaranth ``AlteraPlatform``.  MCU interface: SPI mode 0
with the commands of :mod:`lodestar.hdl.spi_slave`; ``irq`` is high while a packet is being
delivered (the MCU reads one packet per rising edge with ``READ_STREAM``); register writes
take effect on the next frame.  The status word's ``overflow`` bits are the contract's
``OVF_*``.  Every pin marked *assumed* in :data:`BOARDS` must be checked against the board's
schematic before the bitstream is loaded.  Details: ``docs/sensors_and_link.md`` (Board top
levels).
"""

from amaranth import (
    Cat,
    ClockDomain,
    ClockSignal,
    Const,
    Elaboratable,
    Instance,
    Module,
    Signal,
)
from amaranth.build import Attrs, Clock, Pins, Resource, Subsignal
from amaranth.lib import wiring
from amaranth.lib.cdc import FFSynchronizer, ResetSynchronizer
from amaranth.lib.wiring import In, Out
from amaranth.vendor import AlteraPlatform

from lodestar import contract as C

from .detector import Detector
from .mt9p031 import MT9P031Frontend
from .mt9v022 import MT9V022Frontend
from .packetizer import Packetizer
from .spi_slave import SPI_PINS, SPISlave

SENSOR_DOMAIN = {"mt9p031": "pix", "mt9v022": "ser"}
"""Clock domain of each front end's capture logic."""
LVDS_LANES = 6
"""Bits per ``ser`` clock from the LVDS deserializer (ALTLVDS_RX, factor 6)."""


class GatewareTop(wiring.Component):
    """The star-tracker gateware for one sensor and frame geometry, pins as ports.

    ``sensor``: one of :data:`C.SENSORS`.  ``width x height``: the frames the sensor is
    programmed for.  ``label_capacity``, ``record_capacity``, ``record_depth``: the detector's
    (``record_depth`` records stay buffered until the MCU reads them; the packetizer sends a
    frame's records from there).  Sensor ports: ``pix_d``, ``line_valid``, ``frame_valid``
    in the ``pix`` domain (MT9P031), or ``lvds_bits`` (``LVDS_LANES`` bits, earliest bit
    first as ``MT9V022Frontend`` takes them) in the ``ser`` domain (MT9V022).  MCU ports in
    ``sync``: ``sck``, ``mosi``, ``cs_n``, ``miso``, ``miso_oe``, ``irq``.
    """

    def __init__(self, sensor, width, height, *, label_capacity=None,
                 record_capacity=C.DEFAULT_RECORD_CAPACITY, record_depth=None):
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
            pins = {"lvds_bits": In(LVDS_LANES)}
        self.detector = Detector(width, height, self.pixel_bits, label_capacity=label_capacity,
                                 record_capacity=record_capacity, record_depth=record_depth)
        self.packetizer = Packetizer(width, height, self.pixel_bits)
        self.spi = SPISlave()
        super().__init__({
            **pins,
            **SPI_PINS,
            "irq": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        fe, det, pkt, spi = self.frontend, self.detector, self.packetizer, self.spi
        m.submodules.frontend, m.submodules.detector = fe, det
        m.submodules.packetizer, m.submodules.spi = pkt, spi
        if self.sensor == "mt9p031":
            m.d.comb += [fe.d.eq(self.pix_d), fe.line_valid.eq(self.line_valid),
                         fe.frame_valid.eq(self.frame_valid)]
        else:
            m.d.comb += fe.bits.eq(self.lvds_bits)
        wiring.connect(m, fe.out, det.pixels)
        wiring.connect(m, det.records, pkt.records)
        wiring.connect(m, det.trailer, pkt.trailer)
        wiring.connect(m, pkt.packet, spi.packet)
        m.d.comb += [
            spi.sck.eq(self.sck), spi.mosi.eq(self.mosi), spi.cs_n.eq(self.cs_n),
            self.miso.eq(spi.miso), self.miso_oe.eq(spi.miso_oe),
            det.reg_addr.eq(spi.reg_addr), det.reg_data.eq(spi.reg_data),
            det.reg_en.eq(spi.reg_strobe),
            spi.busy.eq(det.busy), spi.frame_counter.eq(det.frame_counter),
            fe.overflow_clear.eq(spi.status_read), det.reg_error_clear.eq(spi.status_read),
            self.irq.eq(pkt.busy),
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
        if self.sensor == "mt9v022":
            overflow[C.OVF_LINK_DOWN] = ~fe.locked
            overflow[C.OVF_LINK_ERROR] = since_read(fe.framing_errors, "framing_errors")
        m.d.comb += spi.overflow.eq(Cat(*overflow))
        return m


# --------------------------------------------------------------------------------------
# Boards
# --------------------------------------------------------------------------------------

_LVCMOS = "3.3-V LVTTL"


class Board:
    """One supported board: part, clocks, sensor, frame, detector capacities and pins.

    ``les``, ``m9k``, ``multipliers``: the part's logic elements, M9K blocks and 18x18
    embedded multipliers (two 9x9 each).  ``pins`` maps a resource name to
    ``{subsignal: (pins, dir, assumed)}``; ``assumed`` marks pins on a custom header whose
    wiring this file assumes.  ``notes`` say what is assumed.
    """

    def __init__(self, name, *, device, package, speed, les, m9k, multipliers, osc_hz,
                 osc_pin, sync_hz, sensor, width, height, pixel_hz, sensor_clk_hz,
                 label_capacity, record_capacity, record_depth, pins, io_standard, notes):
        self.name, self.device, self.package, self.speed = name, device, package, speed
        self.les, self.m9k, self.multipliers = les, m9k, multipliers
        self.osc_hz, self.osc_pin, self.sync_hz = osc_hz, osc_pin, sync_hz
        self.sensor, self.width, self.height = sensor, width, height
        self.pixel_bits = C.SENSOR_PIXEL_BITS[sensor]
        self.pixel_hz, self.sensor_clk_hz = pixel_hz, sensor_clk_hz
        self.label_capacity, self.record_capacity = label_capacity, record_capacity
        self.record_depth = record_depth
        self.pins, self.io_standard, self.notes = pins, io_standard, notes

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
        "miso": ("F9", "o", True),
        "irq": ("E9", "o", True),
    },
}

# MT9V022 LVDS on the DE2-115 HSMC connector (Lohmann's custom PCB), MCU on GPIO (JP5).
_MT9V022_PINS = {
    "mt9v022": {
        # LVDS inputs: the positive pin is assigned; Quartus places the negative pin of the
        # pair (J28, G28) itself for the LVDS I/O standard.
        "ser_clk": ("J27", "i", True),          # LVDS pair on an HSMC clock input
        "ser_data": ("G27", "i", True),         # LVDS pair on an HSMC receiver channel
        "sysclk": ("D27", "o", True),
        "reset_n": ("D28", "o", True),
    },
    "mcu": {
        "sck": ("AB22", "i", True),
        "mosi": ("AC15", "i", True),
        "cs_n": ("AB21", "i", True),
        "miso": ("Y17", "o", True),
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
        io_standard=_LVCMOS,
        notes=("Terasic DE2-115, EP4CE115F29C7, CLOCK_50 on Y2 (board manual).  sync runs "
               "from CLOCK_50 directly (50 MHz >= the 26.67 MHz pixel rate, >= 4x SCK for "
               "SCK <= 10 MHz).  A PLL makes the sensor's 26.67 MHz SYSCLK (50 x 8 / 15).  "
               "MT9V022 LVDS (Lohmann's custom PCB) on the HSMC connector: pin pairs "
               "assumed; the ALTLVDS_RX receiver (factor 6, 320 Mbit/s, inclock = the "
               "26.67 MHz clock returned on an HSMC clock input) is instantiated as "
               "documented from memory and must be checked in the Quartus MegaWizard.  "
               "MCU SPI and IRQ on GPIO header JP5 pins 1-5 (GPIO[0..4]; pin numbers from "
               "memory of the DE2-115 manual, to verify).")),
    "de0-nano": Board(
        "de0-nano", device="EP4CE22", package="F17", speed="C6", les=22320, m9k=66,
        multipliers=66, osc_hz=50e6, osc_pin="R8", sync_hz=100e6, sensor="mt9p031",
        width=2592, height=1944, pixel_hz=96e6, sensor_clk_hz=25e6,
        label_capacity=254, record_capacity=256, record_depth=128, pins=_MT9P031_PINS,
        io_standard=_LVCMOS,
        notes=("Terasic DE0-Nano, EP4CE22F17C6, CLOCK_50 on R8 (amaranth-boards "
               "DE0NanoPlatform).  A PLL makes sync = 100 MHz (>= the 96 MHz pixel rate, "
               ">= 4x SCK for SCK <= 20 MHz) and the sensor's EXTCLK = 25 MHz (its own PLL "
               "makes the 96 MHz PIXCLK).  MT9P031 and MCU on GPIO-0 (JP1), 3.3-V LVTTL; "
               "the header wiring is assumed (custom sensor board); PIXCLK on GPIO_0_IN0 "
               "(A8), assumed to be usable as a clock input (verify in the pin planner).  "
               "The sensor's I2C is driven by the MCU.")),
    "estcube2": Board(
        "estcube2", device="EP4CE22", package="F17", speed="I7", les=22320, m9k=66,
        multipliers=66, osc_hz=50e6, osc_pin="R8", sync_hz=100e6, sensor="mt9p031",
        width=2592, height=1944, pixel_hz=96e6, sensor_clk_hz=25e6,
        label_capacity=254, record_capacity=256, record_depth=128, pins=_MT9P031_PINS,
        io_standard=_LVCMOS,
        notes=("ESTCube-2 star tracker configuration (Schumann 2019): EP4CE22 with the "
               "MT9P031.  The flight board is custom: the package (F17), the industrial "
               "speed grade I7, the 50 MHz oscillator and every pin are assumptions that "
               "mirror the DE0-Nano layout; replace them from the flight schematic.  Clocks "
               "as on the DE0-Nano (sync 100 MHz from a PLL, EXTCLK 25 MHz).")),
}
"""Supported boards by name (``lodestar synth --board``)."""


def _resources(board):
    resources = [Resource("clk_osc", 0, Pins(board.osc_pin, dir="i"), Clock(board.osc_hz),
                          Attrs(io_standard=_LVCMOS))]
    for name, signals in board.pins.items():
        subs = []
        for sub, (pins, direction, _assumed) in signals.items():
            if sub in ("ser_clk", "ser_data"):
                subs.append(Subsignal(sub, Pins(pins, dir=direction),
                                      Attrs(io_standard="LVDS")))
            else:
                extra = [Clock(board.pixel_hz)] if sub == "pixclk" else []
                attrs = {"io_standard": board.io_standard}
                if direction == "i" and sub not in ("pixclk",):
                    attrs["FAST_INPUT_REGISTER"] = "ON"
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
        if b.sync_hz == b.osc_hz:
            outputs = []
            m.d.comb += ClockSignal("sync").eq(osc)
        else:
            outputs = [(ClockSignal("sync"), *_ratio(b.sync_hz, b.osc_hz))]
        sensor_clk = Signal()
        outputs.append((sensor_clk, *_ratio(b.sensor_clk_hz, b.osc_hz)))
        locked = _altpll(m, "pll", osc, b.osc_hz, outputs)
        m.submodules.sync_reset = ResetSynchronizer(~locked, domain="sync")
        capture = SENSOR_DOMAIN[b.sensor]
        m.domains += ClockDomain(capture)
        m.submodules.capture_reset = ResetSynchronizer(~locked, domain=capture)
        if b.sensor == "mt9p031":
            m.d.comb += [ClockSignal("pix").eq(sensor.pixclk.i),
                         sensor.extclk.o.eq(sensor_clk),
                         core.pix_d.eq(sensor.d.i), core.line_valid.eq(sensor.line_valid.i),
                         core.frame_valid.eq(sensor.frame_valid.i)]
        else:
            ser_clk = Signal()
            rx_locked = Signal()
            m.submodules.lvds_rx = Instance(
                "altlvds_rx",
                p_intended_device_family="Cyclone IV E", p_lpm_type="altlvds_rx",
                p_number_of_channels=1, p_deserialization_factor=LVDS_LANES,
                p_data_rate=f"{b.pixel_hz * 12 / 1e6:.1f} Mbps",
                p_input_data_rate=round(b.pixel_hz * 12 / 1e6),
                p_inclock_period=round(1e12 / b.pixel_hz), p_implement_in_les="ON",
                p_registered_output="ON", p_use_external_pll="OFF",
                i_rx_in=sensor.ser_data.i, i_rx_inclock=sensor.ser_clk.i,
                o_rx_out=core.lvds_bits, o_rx_outclock=ser_clk, o_rx_locked=rx_locked)
            m.d.comb += [ClockSignal("ser").eq(ser_clk), sensor.sysclk.o.eq(sensor_clk)]
        # the sensor is held in reset until the clocks are up
        reset_n = Signal()
        m.submodules.sensor_reset = FFSynchronizer(locked, reset_n)
        m.d.comb += sensor.reset_n.o.eq(reset_n)

        # ---- MCU ----------------------------------------------------------------------
        m.d.comb += [core.sck.eq(mcu.sck.i), core.mosi.eq(mcu.mosi.i), core.cs_n.eq(mcu.cs_n.i),
                     mcu.miso.o.eq(core.miso), mcu.irq.o.eq(core.irq)]
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
