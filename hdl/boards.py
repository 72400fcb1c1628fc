"""Board top levels: sensor front end, detector, packetizer and SPI slave, on Cyclone IV boards.

:class:`GatewareTop` is the whole design with its pins as ports (simulatable and synthesizable
on its own); :class:`BoardTop` puts it on a board of :data:`BOARDS` (clocks, resources) and
``board_platform(name)`` gives the Amaranth ``AlteraPlatform``.  MCU interface: SPI mode 0
with the commands of :mod:`lodestar.hdl.spi_slave` (MISO tri-stated while CS is high);
``irq`` is a registered copy of "a packet is being delivered" whose high and low pulses last
at least ``IRQ_MIN_CLOCKS`` (the MCU reads one packet per rising edge with ``READ_STREAM``);
register writes take effect on the next frame.  The status word's ``overflow`` bits are the
contract's ``OVF_*``.  A frame the sensor stops sending is completed by
:class:`lodestar.hdl.frontend.FrameWatchdog` and its trailer flagged ``FRAME_TIMEOUT``.  Only
the first qualified PLL lock resets the whole design (:class:`ClockGuard`); a later lock
loss holds the detector datapath and the capture domain in reset until the lock is qualified
again and sets ``OVF_CLOCK_LOST``, keeping the registers and the sensor's configuration; the
sensor's RESET_BAR is the MCU's (register ``sensor_reset``, at least
``contract.SENSOR_RESET_S`` with its clock running: :class:`SensorReset`); the MCU's
``SOFT_RESET`` resets the detector datapath only (registers kept), ``FLUSH`` drops the
queued packets, ``READ_REG`` reads the register bank back and ``READ_ID`` names the build
(:class:`GatewareTop`).
:data:`FRONTENDS` gives each sensor its front end, which supplies the sensor's pins, board
clocking and constraints.  Every pin marked
*assumed* in :data:`BOARDS` must be checked against the board's schematic before the
bitstream is loaded.  Details: ``docs/sensors_and_link.md`` (Board top levels).
"""

import math

from amaranth import (
    Cat,
    ClockDomain,
    ClockSignal,
    Const,
    Elaboratable,
    Instance,
    Module,
    Mux,
    ResetInserter,
    Signal,
)
from amaranth.build import Attrs, Clock, Pins, Resource, Subsignal
from amaranth.lib import io, wiring
from amaranth.lib.cdc import FFSynchronizer, ResetSynchronizer
from amaranth.lib.wiring import In, Out
from amaranth.vendor import AlteraPlatform

from lodestar import contract as C

from .detector import Detector
from .frontend import (
    MASTER_DOMAIN,
    STALL_TIMEOUT,
    FrameWatchdog,
    gray_skew_constraints,
    input_buffer,
    io_domain,
)
from .layouts import trailer_layout
from .mt9p031 import MT9P031Frontend
from .mt9v022 import LVDS_LANES, PACKET_BITS, MT9V022Frontend, PhaseStepper
from .packetizer import Packetizer
from .registers import RegisterBank
from .spi_slave import MISO_TCO_NS, SPI_PINS, SPISlave, max_sck_hz

FRONTENDS = {frontend.SENSOR: frontend for frontend in (MT9P031Frontend, MT9V022Frontend)}
"""The hdl side of the contract's ``C.SENSORS``: each sensor's front-end class
(:class:`lodestar.hdl.frontend.SensorFrontend`), which states its pixel width, capture clock
domain, top-level pins, board clocking hook, I/O voltage and SDC lines."""
IRQ_MIN_CLOCKS = 16
"""Shortest high and low pulse of ``irq``, in ``sync`` clocks (160 ns at 100 MHz, 320 ns at
50 MHz: far above what an STM32 EXTI input needs to see an edge)."""
PLL_LOSS_BITS = 2
"""Width of the Gray-coded count of PLL lock losses (``OVF_CLOCK_LOST`` compares it with its
value at the last status read, so 4 losses between two reads would go unseen)."""
LOCK_QUALIFY_CLOCKS = 1 << 16
"""Oscillator clocks the PLL's ``locked`` must stay high before the board releases the
datapath (1.3 ms at 50 MHz, beyond the Cyclone IV PLL's 1 ms lock time: ``ClockGuard``)."""
TIMEOUT_SLOTS = 8
"""Frames whose ``FRAME_TIMEOUT`` mark is remembered until their trailer goes out (indexed by
the frame counter's low bits)."""


SOFT_RESET_CLOCKS = 4
"""Clocks the datapath's reset is held after ``SOFT_RESET`` (the slave's one-clock strobe
included).  One clock restores every flip-flop (``ResetInserter``); the memories need none
(the labeller's free list and bitmap and the feature table are emptied or masked at each
frame start, the record buffer is addressed from its reset pointers).  The hold covers the
two-clock read pipelines (memory read port, ``HalfWordFIFO`` fetch) so no read started before
the reset lands in a reset register; after it the pixels are ignored until the next frame
start, so the first frame the datapath sees is whole."""


def frontend_class(sensor):
    """The front-end class of ``sensor`` (:data:`FRONTENDS`); ``ValueError`` if unknown."""
    if sensor not in FRONTENDS:
        raise ValueError(f"unknown sensor {sensor!r}; choose one of {', '.join(FRONTENDS)}")
    return FRONTENDS[sensor]


class IrqLine(wiring.Component):
    """``irq`` follows ``busy`` one clock later, from a flip-flop (no decode glitch reaches
    the pin), and holds each level for at least ``min_clocks`` clocks.  A ``busy`` low pulse
    of one clock between back-to-back packets thus becomes a low pulse of ``min_clocks``,
    provided ``busy`` was high for ``min_clocks`` before it (a packet takes far longer).

    Parameters
    ----------
    min_clocks : int
        Shortest high and low pulse of ``irq``, in ``sync`` clocks.

    Members
    -------
    busy : ``In(1)``
        The packetizer's "a packet is being delivered".
    irq : ``Out(1)``
        The pin's level, from a flip-flop.
    """

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
    """Qualifies the PLL's ``locked`` (asynchronous) in the always-running oscillator domain
    ``osc``: ``qualified`` rises once ``locked`` has stayed high for ``qualify_clocks``
    clocks (a PLL's lock indicator can chatter while it acquires) and falls the clock after
    a loss is seen.  ``ever_qualified`` rises with the first qualification and stays high:
    the board's power-up reset of ``sync`` (the register bank's only reset).  The board holds
    the detector datapath and the capture domain in reset while ``qualified`` is low, so a
    lock loss ends in a clean restart after the next qualified lock, and each loss steps
    ``losses``, a ``PLL_LOSS_BITS``-bit Gray count for ``OVF_CLOCK_LOST``.

    Parameters
    ----------
    qualify_clocks : int
        ``osc`` clocks ``locked`` must stay high before ``qualified`` rises.

    Members
    -------
    locked : ``Signal()``
        The PLL's ``locked``, asynchronous.
    qualified, ever_qualified : ``Signal()``
        In ``osc``: the lock is qualified; it has been since power-up.
    losses : ``Signal(PLL_LOSS_BITS)``
        In ``osc``: Gray count of lock losses (of a qualified lock).
    """

    def __init__(self, qualify_clocks=LOCK_QUALIFY_CLOCKS):
        if qualify_clocks < 1:
            raise ValueError(f"qualify_clocks must be at least 1, got {qualify_clocks}")
        self.qualify_clocks = qualify_clocks
        self.locked = Signal()
        self.qualified = Signal()
        self.ever_qualified = Signal()
        self.losses = Signal(PLL_LOSS_BITS)

    def elaborate(self, platform):
        m = Module()
        locked = Signal()
        m.submodules.locked_cdc = FFSynchronizer(self.locked, locked, o_domain="osc")
        stable = Signal(range(self.qualify_clocks + 1))     # clocks locked without a break
        count = Signal(PLL_LOSS_BITS)
        with m.If(~locked):
            m.d.osc += [stable.eq(0), self.qualified.eq(0)]
            with m.If(self.qualified):
                m.d.osc += [count.eq(count + 1),
                            self.losses.eq((count + 1) ^ ((count + 1) >> 1))]
        with m.Elif(stable == self.qualify_clocks - 1):
            m.d.osc += [self.qualified.eq(1), self.ever_qualified.eq(1)]
        with m.Else():
            m.d.osc += stable.eq(stable + 1)
        return m


class SensorReset(wiring.Component):
    """The sensor's RESET_BAR in the always-running ``osc`` domain: low at power-up, and low
    while ``request`` is high; after the request ends it rises only once ``clocks`` ``osc``
    clocks have passed with ``clock_ok`` high (the sensor's master clock running) without a
    new request; a break of ``clock_ok`` while it is low restarts the count.  A lock loss
    while it is high does not pull it low (the sensor keeps the configuration the MCU
    wrote; the MCU resets it through ``request`` if it must).

    Parameters
    ----------
    clocks : int
        ``osc`` clocks of the shortest low time with the master clock running
        (``contract.SENSOR_RESET_S`` times the oscillator).

    Members
    -------
    request : ``In(1)``
        Hold RESET_BAR low (``osc``, synchronized by the board).
    clock_ok : ``In(1)``
        The master clock runs (``ClockGuard.qualified``).
    reset_n : ``Out(1)``
        RESET_BAR, from a flip-flop.
    """

    def __init__(self, clocks):
        if clocks < 1:
            raise ValueError(f"the sensor reset must last at least 1 clock, got {clocks}")
        self.clocks = clocks
        super().__init__({"request": In(1), "clock_ok": In(1), "reset_n": Out(1)})

    def elaborate(self, platform):
        m = Module()
        left = Signal(range(self.clocks + 1), init=self.clocks)
        with m.If(self.request | (~self.reset_n & ~self.clock_ok)):
            m.d.osc += [left.eq(self.clocks), self.reset_n.eq(0)]
        with m.Elif(~self.reset_n):
            with m.If(left == 0):
                m.d.osc += self.reset_n.eq(1)
            with m.Else():
                m.d.osc += left.eq(left - 1)
        return m


class GatewareTop(wiring.Component):
    """The star-tracker gateware for one sensor and frame geometry, pins as ports.

    The sensor's front end (:data:`FRONTENDS`), :class:`FrameWatchdog`, the detector, the
    packetizer and the SPI slave; the front end's clock domain and ``sync``.

    A lock loss of the board's PLL (``clock_ok`` low) holds the datapath in reset until the
    lock is qualified again, and then as long as a ``SOFT_RESET`` does; the register bank,
    the SPI slave and the counts of the status word are not reset.

    The SPI slave's commands: ``SOFT_RESET`` holds the datapath (watchdog, threshold,
    labeller, features, output stage, packetizer, the ``FRAME_TIMEOUT`` marks) in reset for
    :data:`SOFT_RESET_CLOCKS` and then ignores pixels until the next frame start; the
    register bank keeps its values (its flip-flops are ``reset_less`` and reload only on the
    domain's own reset), its sticky refusal flag is cleared, and the frame counter restarts
    at 0.  The front end (clock-domain crossing) is not reset.  ``FLUSH`` drains what is
    queued for the MCU inside the gateware: the packet being delivered and the held trailer's
    packet are read out at one byte per clock with ``irq`` held low and ``READ_STREAM``
    seeing no bytes (the records of the frame under detection stay, and become the next
    packet), so the next packet the MCU reads is whole; it takes at most
    :meth:`flush_clocks` clocks.  ``READ_REG`` reads a mirror of the detector's register
    bank (the same :class:`RegisterBank` fed the same writes, so equal to it bit for bit).
    The ID word's ``build`` is :attr:`build` (``contract.build_id`` of the build parameters).

    Parameters
    ----------
    sensor : str
        One of :data:`FRONTENDS` (``C.SENSORS``).
    width, height : int
        The frames the sensor is programmed for.
    label_capacity, record_capacity, record_depth : int or None
        The detector's (``record_depth`` records stay buffered until the MCU reads them; the
        packetizer sends a frame's records from there).
    stall_timeout : int
        Clocks without a pixel inside a frame before the frame is completed with dark pixels
        and flagged ``FRAME_TIMEOUT`` (:class:`FrameWatchdog`).
    sync_hz : float
        The ``sync`` clock, for the packet header's microsecond ``timestamp``: a counter of
        ``contract.timestamp_divider(sync_hz)`` clocks per count, free-running from power-up
        (not reset by ``SOFT_RESET`` or a PLL loss), latched at each frame's first pixel.
    taps : int
        MT9V022: sample phases per bit of the LVDS receiver (> 1: the front end trains its
        phase, ``rx_tap`` is a port and the status word carries ``trained`` and
        ``eye_width``; 1: a fixed phase, both read 0), and ``tap_settle`` its clocks from a
        tap change to the receiver sampling at it.

    Members
    -------
    (the front end's ``pins``)
        The sensor's ports, in the front end's domain (MT9P031: ``pix_d``, ``line_valid``,
        ``frame_valid``; MT9V022: ``lvds_bits`` and the board's synchronized ``rx_locked``).
    sck, mosi, cs_n : ``In(1)``; miso, miso_oe : ``Out(1)``
        The MCU's SPI bus (``SPI_PINS``), sampled in ``sync``.
    irq : ``Out(1)``
        A packet is being delivered (:class:`IrqLine`).
    pll_losses : ``In(PLL_LOSS_BITS)``
        The board's Gray count of PLL lock losses in ``sync`` (``OVF_CLOCK_LOST``).
    clock_ok : ``In(1, init=1)``
        The board's PLL lock is qualified (``ClockGuard``, synchronized into ``sync``); while
        it is low the datapath is held in reset as by ``SOFT_RESET``.
    sensor_reset : ``Out(1)``
        The ``sensor_reset`` register (the board stretches it into RESET_BAR).
    sensor_in_reset : ``In(1)``
        The board holds the sensor's RESET_BAR low (``sync``): ``OVF_LINK_DOWN``.
    datapath_reset, flushing : ``Signal()``
        Not ports: high while the soft reset is held, and while a flush drains.
    """

    def __init__(self, sensor, width, height, *, label_capacity=None,
                 record_capacity=C.DEFAULT_RECORD_CAPACITY, record_depth=None,
                 stall_timeout=STALL_TIMEOUT, sync_hz=100e6, taps=1, tap_settle=4):
        frontend = frontend_class(sensor)
        if taps > 1 and not frontend.PHASE_TRAINING:
            raise ValueError(f"taps > 1: the {sensor} front end has no phase training")
        self.timestamp_divider = C.timestamp_divider(sync_hz)
        # the contract's check before any part is built (a part built for a refused frame
        # would warn UnusedElaboratable)
        C.check_geometry(width, height, frontend.PIXEL_BITS)
        self.sensor, self.width, self.height = sensor, width, height
        self.pixel_bits = frontend.PIXEL_BITS
        self.frontend = frontend(width, height, **({"taps": taps, "settle": tap_settle}
                                                   if taps > 1 else {}))
        self.watchdog = FrameWatchdog(width, height, self.pixel_bits, stall_timeout)
        self.detector = Detector(width, height, self.pixel_bits, label_capacity=label_capacity,
                                 record_capacity=record_capacity, record_depth=record_depth)
        self.packetizer = Packetizer(width, height, self.pixel_bits)
        det = self.detector
        self.build = C.build_id(sensor, width, height, self.pixel_bits, det.label_capacity,
                                det.record_capacity, det.record_depth)
        self.spi = SPISlave(build=self.build)
        self.irq_line = IrqLine()
        self.mirror = RegisterBank(self.pixel_bits)
        self.datapath_reset = Signal()
        self.flushing = Signal()
        super().__init__({
            **self.frontend.pins.members,
            **SPI_PINS,
            "irq": Out(1),
            "pll_losses": In(PLL_LOSS_BITS),
            "clock_ok": In(1, init=1),
            "sensor_reset": Out(1),
            "sensor_in_reset": In(1),
        })

    def flush_clocks(self):
        """Most clocks a ``FLUSH`` drains for: the packet being delivered and the held
        trailer's, each at most ``record_capacity`` records at one byte per clock and two
        clocks more per record (``HalfWordFIFO``)."""
        cap = min(self.detector.record_capacity, self.detector.record_depth)
        return 2 * (C.packet_bytes(cap) + 2 * cap + 4)

    def elaborate(self, platform):
        m = Module()
        fe, det, pkt, spi = self.frontend, self.detector, self.packetizer, self.spi
        rst = self.datapath_reset
        m.submodules.frontend, m.submodules.spi = fe, spi
        m.submodules.detector = ResetInserter(rst)(det)
        m.submodules.packetizer = ResetInserter(rst)(pkt)
        m.submodules.watchdog = ResetInserter(rst)(self.watchdog)
        m.submodules.irq_line = irq = self.irq_line
        m.submodules.mirror = mirror = self.mirror
        wd = self.watchdog
        fe.connect_pins(m, self)
        self._soft_reset(m, fe, wd)
        wiring.connect(m, wd.out, det.pixels)
        wiring.connect(m, det.records, pkt.records)
        self._flush(m, pkt, spi, irq)
        self._timeouts(m, det, wd, pkt)
        self._timestamp(m, det)
        m.d.comb += [
            spi.sck.eq(self.sck), spi.mosi.eq(self.mosi), spi.cs_n.eq(self.cs_n),
            self.miso.eq(spi.miso), self.miso_oe.eq(spi.miso_oe),
            det.reg_addr.eq(spi.reg_addr), det.reg_data.eq(spi.reg_data),
            det.reg_en.eq(spi.reg_strobe),
            mirror.addr.eq(spi.reg_addr), mirror.data.eq(spi.reg_data),
            mirror.en.eq(spi.reg_strobe), mirror.raddr.eq(spi.reg_addr),
            spi.reg_rdata.eq(mirror.rdata),
            spi.busy.eq(det.busy), spi.frame_counter.eq(det.frame_counter),
            spi.trained.eq(getattr(fe, "trained", 0)),
            spi.eye_width.eq(getattr(fe, "eye_width", 0)),
            fe.overflow_clear.eq(spi.status_read), det.reg_error_clear.eq(spi.status_read),
            self.irq.eq(irq.irq), self.sensor_reset.eq(mirror.sensor_reset),
        ]
        self._overflow(m, fe, det, spi)
        return m

    def _timestamp(self, m, det):
        """The free-running microsecond counter (``sync``, outside the datapath's reset)."""
        ticks = Signal(C.TIMESTAMP_BITS)
        div = self.timestamp_divider
        if div > 1:
            pre = Signal(range(div))
            with m.If(pre == div - 1):
                m.d.sync += [pre.eq(0), ticks.eq(ticks + 1)]
            with m.Else():
                m.d.sync += pre.eq(pre + 1)
        else:
            m.d.sync += ticks.eq(ticks + 1)
        m.d.comb += det.timestamp.eq(ticks)

    def _soft_reset(self, m, fe, wd):
        """``datapath_reset`` while ``clock_ok`` is low and for :data:`SOFT_RESET_CLOCKS` after
        it rises or after ``spi.soft_reset``, from the clock after; then the front end's
        pixels reach the watchdog only from the next frame start on.  The reset is a register
        (its fan-out into every datapath flip-flop starts at one) and does not gate the pixels
        (the watchdog is in reset meanwhile): timing, ``docs/synthesis.md``."""
        hold = Signal(range(SOFT_RESET_CLOCKS), name="soft_reset_hold")
        request = self.spi.soft_reset | ~self.clock_ok
        with m.If(request):
            m.d.sync += hold.eq(SOFT_RESET_CLOCKS - 1)
        with m.Elif(hold != 0):
            m.d.sync += hold.eq(hold - 1)
        m.d.sync += self.datapath_reset.eq(request | (hold != 0))
        waiting = Signal(name="wait_for_sof")       # after a soft reset, until a frame start
        sof = fe.out.valid & fe.out.payload.sof
        with m.If(self.datapath_reset):
            m.d.sync += waiting.eq(1)
        with m.Elif(sof):
            m.d.sync += waiting.eq(0)
        m.d.comb += [wd.pixels.payload.eq(fe.out.payload),
                     wd.pixels.valid.eq(fe.out.valid & (~waiting | sof))]

    def _flush(self, m, pkt, spi, irq):
        """From ``spi.flush`` until the packetizer is idle with no trailer offered, take its
        bytes here (``READ_STREAM`` sees none, ``irq`` stays low)."""
        flushing = self.flushing
        idle = ~pkt.busy & ~pkt.trailer.valid
        with m.If(self.datapath_reset):
            m.d.sync += flushing.eq(0)
        with m.Elif(spi.flush):
            m.d.sync += flushing.eq(1)
        with m.Elif(idle):
            m.d.sync += flushing.eq(0)
        m.d.comb += [
            spi.packet.payload.eq(pkt.packet.payload),
            spi.packet.valid.eq(pkt.packet.valid & ~flushing),
            pkt.packet.ready.eq(Mux(flushing, 1, spi.packet.ready)),
            irq.busy.eq(pkt.busy & ~flushing),
        ]

    def _timeouts(self, m, det, wd, pkt):
        """FRAME_TIMEOUT: marked per frame number, added to that frame's trailer.  When the
        watchdog gives up on a frame, the labeller started it long ago, so it is frame
        ``frame_counter - 1``; a frame's mark is cleared when its pixels start.  The mark of
        a trailer held unread for TIMEOUT_SLOTS frames (later trailers are then lost:
        OVF_TRAILER_LOST) may be overwritten.  The marks are the datapath's (soft reset)."""
        slot_bits = C.bits_for(TIMEOUT_SLOTS - 1)
        marks = Signal(TIMEOUT_SLOTS, name="timeout_marks")
        newest = det.frame_counter[:slot_bits]
        with m.If(self.datapath_reset):
            m.d.sync += marks.eq(0)
        with m.Elif(wd.stalled):
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

    def _overflow(self, m, fe, det, spi):
        """The status word's overflow bits (``contract.OVF_*``)."""
        def since_read(counter, name, reset=None):
            """High while ``counter`` differs from its value at the last status read (or at
            ``reset``, when the counter itself restarts)."""
            seen = Signal.like(counter, name=f"{name}_seen")
            with m.If(spi.status_read | (reset if reset is not None else 0)):
                m.d.sync += seen.eq(Mux(spi.status_read, counter, 0))
            return counter != seen

        overflow = [Const(0, 1)] * C.OVERFLOW_BITS
        overflow[C.OVF_PIXEL_FIFO] = fe.overflow
        overflow[C.OVF_TRAILER_LOST] = since_read(det.trailer_lost, "trailer_lost",
                                                  self.datapath_reset)
        overflow[C.OVF_REG_REFUSED] = det.reg_error
        overflow[C.OVF_FAULT] = det.fault
        overflow[C.OVF_CLOCK_LOST] = since_read(self.pll_losses, "pll_losses")
        for bit, value in fe.status(self, since_read).items():
            overflow[bit] = value
        overflow[C.OVF_LINK_DOWN] = overflow[C.OVF_LINK_DOWN] | self.sensor_in_reset
        m.d.comb += spi.overflow.eq(Cat(*overflow))


# --------------------------------------------------------------------------------------
# Boards
# --------------------------------------------------------------------------------------

_LVCMOS = "3.3-V LVTTL"
_LVDS = "LVDS"

IO_STANDARD_VOLTS = {_LVCMOS: 3.3, "2.5 V": 2.5}
"""Output high level (VCCIO) of each single-ended I/O standard used here."""


class Board:
    """One supported board: part, clocks, sensor, frame, detector capacities and pins.

    Each board is a subclass that states its values as class attributes, a board derived
    from another only what differs; :data:`BOARDS` holds one instance of each.  An instance
    may be copied and given another frame or capacities (``lodestar synth``).  Every pin
    marked *assumed* must be checked against the board's schematic.

    Attributes
    ----------
    name : str
        The name in :data:`BOARDS` (``lodestar synth --board``).
    device, package, speed : str
        The Cyclone IV E part (:attr:`part` joins them).
    les, m9k, multipliers : int
        The part's logic elements, M9K blocks and 18x18 embedded multipliers (two 9x9 each).
    osc_hz, osc_pin : float, str
        The board oscillator (50 MHz by default) and its pin.
    sync_hz : float
        The ``sync`` clock: the oscillator itself if equal to ``osc_hz``, else the PLL's.
    sensor : str
        One of :data:`FRONTENDS`.
    width, height : int
        The frame the sensor is programmed for.
    pixel_hz, sensor_clk_hz : float
        The pixel rate, and the sensor's master clock (made by the PLL).
    label_capacity, record_capacity, record_depth : int or None
        The detector's (by default: its defaults, with two frames of records buffered).
    pins : dict
        Resource name -> ``{subsignal: (pins, dir, assumed)}``; ``assumed`` marks pins on a
        custom header whose wiring this file assumes.  The sensor's resource is named after
        the sensor (its front end's subsignals and ``reset_n``); ``mcu`` has the SPI pins
        and ``irq``.
    io_standard : dict
        Resource name -> the I/O standard of its single-ended pins (LVDS pairs are ``LVDS``);
        one the bank's VCCIO allows.
    sensor_io_volts : float
        The sensor board's I/O supply (V), within the front end's ``IO_VOLTS``.
    level_translated : tuple of str
        The sensor inputs (FPGA outputs) that reach the sensor through a level translator on
        the sensor board because the bank drives them above the sensor's I/O range.
    notes : str
        What is assumed.
    """

    osc_hz = 50e6
    lvds_taps = 1
    label_capacity = None
    record_capacity = C.DEFAULT_RECORD_CAPACITY
    record_depth = 2 * C.DEFAULT_RECORD_CAPACITY

    @property
    def pixel_bits(self):
        return C.SENSOR_PIXEL_BITS[self.sensor]

    @property
    def frontend(self):
        """The sensor's front-end class (:data:`FRONTENDS`)."""
        return frontend_class(self.sensor)

    @property
    def spi_sck_max_hz(self):
        """The SPI slave's own limit on SCK at this board's sync clock (estimate:
        :func:`lodestar.hdl.spi_slave.max_sck_hz`)."""
        return max_sck_hz(self.sync_hz)

    @property
    def master_clock_hz(self):
        """The sensor's master clock as the board's PLL makes it: the ratio nearest
        ``sensor_clk_hz`` (it may differ from it; must not exceed the front end's
        ``MASTER_CLOCK_MAX_HZ``)."""
        mul, div = _ratio(self.sensor_clk_hz, self.osc_hz)
        return self.osc_hz * mul / div

    @property
    def part(self):
        return f"{self.device}{self.package}{self.speed}"

    def gateware_top(self):
        """The board's :class:`GatewareTop`; ``ValueError`` if its frame is outside the
        contract (checked before the top is built)."""
        C.check_geometry(self.width, self.height, self.pixel_bits)
        return GatewareTop(self.sensor, self.width, self.height,
                           label_capacity=self.label_capacity,
                           record_capacity=self.record_capacity, record_depth=self.record_depth,
                           sync_hz=self.sync_hz, **self.phase_training())

    def phase_training(self):
        """:class:`GatewareTop`'s ``taps`` and ``tap_settle`` of this board: ``lvds_taps``
        phase steps per bit, each tap change settled within the receiver's
        :class:`PhaseStepper` bound (in ``osc`` clocks, as clocks of the LVDS word clock);
        none for a board without phase training."""
        if self.lvds_taps <= 1:
            return {}
        word_hz = self.pixel_hz * PACKET_BITS / LVDS_LANES
        scan = PhaseStepper.settle_bound(self.lvds_taps)
        return {"taps": self.lvds_taps, "tap_settle": math.ceil(scan * word_hz / self.osc_hz) + 4}


class DE2115Board(Board):
    """Terasic DE2-115 with the MT9V022 (LVDS) on the HSMC connector."""

    name = "de2-115"
    device, package, speed = "EP4CE115", "F29", "C7"
    les, m9k, multipliers = 114480, 432, 266
    osc_pin = "Y2"
    sync_hz = 100e6
    sensor = "mt9v022"
    width, height = 752, 480
    pixel_hz = sensor_clk_hz = 25e6
    # MT9V022 LVDS on the HSMC connector (Lohmann's custom PCB), MCU on GPIO (JP5).
    pins = {
        "mt9v022": {
            # LVDS inputs: the positive pin is assigned; Quartus places the negative pin of
            # the pair (J28, G28) itself for the LVDS I/O standard.
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
    io_standard = {"mt9v022": "2.5 V", "mcu": _LVCMOS}
    sensor_io_volts = 3.3
    level_translated = ("sysclk", "reset_n")
    lvds_taps = 16
    """Phase steps per bit: the receiver PLL's VCO at 600 MHz (the 300 Mbit/s bit clock x 2),
    one dynamic phase step 1/8 of its period, 208 ps."""
    notes = ("Terasic DE2-115, EP4CE115F29C7, CLOCK_50 on Y2 (board manual).  A PLL makes "
             "sync = 100 MHz (so that the MCU's 10.5 MHz SCK is within 0.8 x the SPI "
             "slave's limit) and the sensor's 25 MHz SYSCLK (below its 26.6 MHz maximum; "
             "300 Mbit/s on the link).  MT9V022 LVDS (Lohmann's custom "
             "PCB) on the HSMC connector, pins from Terasic's System Builder QSF: the "
             "returned LVDS clock on HSMC_CLKIN_P1/N1, the data on the receiver pair "
             "HSMC_RX_D_P/N[3] (100 ohm termination on the PCB, Cyclone IV E inputs have "
             "none on chip), SYSCLK and RESET_BAR single-ended on HSMC_TX_D_P/N[0] at "
             "2.5 V, the HSMC bank's VCCIO set by JP7 (2.5 V "
             "default, which the LVDS inputs also need); the 3.3-V sensor sees them through "
             "level translators on the PCB (assumed).  The ALTLVDS_RX receiver (factor 6, "
             "300 Mbit/s, inclock phase shifted half a bit so that an edge-aligned clock "
             "samples mid-bit) is instantiated as documented and must be checked in the "
             "Quartus MegaWizard.  MCU SPI and IRQ on GPIO header JP5 pins 1-5 "
             "(GPIO[0..4], Terasic QSF), 3.3-V LVTTL.")


class DE0NanoBoard(Board):
    """Terasic DE0-Nano with the MT9P031 (parallel) on GPIO-0."""

    name = "de0-nano"
    device, package, speed = "EP4CE22", "F17", "C6"
    les, m9k, multipliers = 22320, 66, 66
    osc_pin = "R8"
    sync_hz = 75e6
    sensor = "mt9p031"
    width, height = 2592, 1944
    pixel_hz, sensor_clk_hz = 70e6, 25e6
    label_capacity, record_capacity, record_depth = 254, 256, 128
    # MT9P031 and MCU on the 40-pin header GPIO-0 (JP1), whose pins follow the
    # amaranth-boards DE0NanoPlatform connector table ("gpio", 0); which header pin carries
    # which sensor signal is this project's choice (the sensor board is custom): all assumed.
    pins = {
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
    io_standard = {"mt9p031": _LVCMOS, "mcu": _LVCMOS}
    sensor_io_volts = 2.8
    level_translated = ("extclk", "reset_n")
    notes = ("Terasic DE0-Nano, EP4CE22F17C6, CLOCK_50 on R8 (amaranth-boards "
             "DE0NanoPlatform).  A PLL makes sync = 75 MHz (50 x 3 / 2, >= the 70 MHz "
             "pixel rate) and the sensor's EXTCLK = 25 MHz (its own PLL makes the 70 MHz "
             "PIXCLK: M 28, N 2, P1 5; 10 frames/s at full frame, docs/synthesis.md).  "
             "MT9P031 and MCU on GPIO-0 (JP1), whose bank is 3.3 V (3.3-V LVTTL); the "
             "header wiring is assumed (custom sensor board).  The sensor runs its I/O at "
             "2.8 V (needed for 96 MHz; range 1.7-3.1 V): its 2.8-V outputs meet the "
             "3.3-V LVTTL input levels, but EXTCLK and RESET_BAR must reach it through "
             "level translators on the sensor board.  PIXCLK on GPIO_0_IN0 (A8), assumed "
             "to be usable as a clock input (verify in the pin planner).  The sensor's "
             "two-wire serial port is driven by the MCU (firmware/sensor.py).")


class ESTCube2Board(DE0NanoBoard):
    """The ESTCube-2 flight board: the DE0-Nano's part and layout at industrial grade, its
    record capacity the contract's ``FLIGHT_RECORD_CAPACITY`` (the MCU's packet buffer;
    ``record_depth`` 128 as on the DE0-Nano: 5 M9K)."""

    name = "estcube2"
    speed = "I7"
    record_capacity = C.FLIGHT_RECORD_CAPACITY
    notes = ("ESTCube-2 star tracker configuration (Schumann 2019): EP4CE22 with the "
             "MT9P031.  The flight board is custom: the package (F17), the industrial "
             "speed grade I7, the 50 MHz oscillator and every pin are assumptions that "
             "mirror the DE0-Nano layout; replace them from the flight schematic.  Clocks "
             "as on the DE0-Nano (sync 75 MHz from a PLL, EXTCLK 25 MHz, PIXCLK 70 MHz).")


BOARDS = {board.name: board() for board in (DE2115Board, DE0NanoBoard, ESTCube2Board)}
"""Supported boards by name (``lodestar synth --board``)."""


_REGISTERED_OUTPUTS = ("miso", "irq")
"""Outputs driven straight from a flip-flop without reset (``FAST_OUTPUT_REGISTER``)."""


def _resources(board):
    """Pins as Amaranth resources: each sensor input the front end captures gets
    ``FAST_INPUT_REGISTER`` (its ``io.FFBuffer`` flip-flop has no reset, so the fitter packs
    it into the I/O element), each output from a bare flip-flop ``FAST_OUTPUT_REGISTER``;
    the SPI inputs get none (their first flip-flop is a synchronizer's, which keeps its
    resolution time in the fabric); the front end's ``LVDS_PINS`` the LVDS standard, its
    ``CLOCK_PINS`` the pixel rate as their clock."""
    resources = [Resource("clk_osc", 0, Pins(board.osc_pin, dir="i"), Clock(board.osc_hz),
                          Attrs(io_standard=_LVCMOS))]
    fe = board.frontend
    for name, signals in board.pins.items():
        lvds_pins = fe.LVDS_PINS if name == board.sensor else ()
        clock_pins = fe.CLOCK_PINS if name == board.sensor else ()
        subs = []
        for sub, (pins, direction, _assumed) in signals.items():
            if sub in lvds_pins:
                extra = [Clock(board.pixel_hz)] if sub in clock_pins else []
                subs.append(Subsignal(sub, Pins(pins, dir=direction), *extra,
                                      Attrs(io_standard=_LVDS)))
            else:
                extra = [Clock(board.pixel_hz)] if sub in clock_pins else []
                attrs = {"io_standard": board.io_standard[name]}
                if direction == "i" and name == board.sensor and sub not in clock_pins:
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

    The board makes ``sync`` (the oscillator or a PLL) and the sensor's master clock
    (``MASTER_DOMAIN``), and leaves the capture domain and the sensor's pins to the front
    end's ``board_clocks``.  Every pin goes through an ``amaranth.lib.io`` buffer of a
    resource requested with ``dir="-"``: the sensor's bus through input flip-flops, its
    master clock through a DDR output, IRQ through an output flip-flop (their domains are
    reset-less twins, ``frontend.io_domain``: an I/O element's register has no reset).

    Parameters
    ----------
    board : str or :class:`Board`
        A name of :data:`BOARDS` or a :class:`Board` (e.g. a copy with another frame or other
        capacities).
    """

    def __init__(self, board):
        if isinstance(board, str):
            if board not in BOARDS:
                raise ValueError(f"unknown board {board!r}; choose one of {', '.join(BOARDS)}")
            board = BOARDS[board]
        self.board = board
        self.core = board.gateware_top()

    def elaborate(self, platform):
        m = Module()
        b = self.board
        m.submodules.core = core = self.core
        fe = core.frontend
        osc = input_buffer(m, "pin_clk_osc_0", platform.request("clk_osc", 0, dir="-")).i
        sensor = platform.request(b.sensor, 0, dir="-")
        mcu = platform.request("mcu", 0, dir="-")

        # ---- clocks: sync, the sensor's master clock, the capture domain ----------------
        m.domains.sync = ClockDomain("sync")
        m.domains.osc = ClockDomain("osc", reset_less=True)
        m.domains += [ClockDomain(MASTER_DOMAIN, reset_less=True),
                      ClockDomain(io_domain("sync"), reset_less=True)]
        m.d.comb += [ClockSignal("osc").eq(osc),
                     ClockSignal(io_domain("sync")).eq(ClockSignal("sync"))]
        if b.sync_hz == b.osc_hz:
            outputs = []
            m.d.comb += ClockSignal("sync").eq(osc)
        else:
            outputs = [(ClockSignal("sync"), *_ratio(b.sync_hz, b.osc_hz))]
        outputs.append((ClockSignal(MASTER_DOMAIN), *_ratio(b.sensor_clk_hz, b.osc_hz)))
        # power-up reset of sync (the register bank) at the first qualified lock; the
        # datapath and the capture domain are held in reset while the lock is not qualified
        m.submodules.clock_guard = guard = ClockGuard()
        m.d.comb += guard.locked.eq(_altpll(m, "pll", osc, b.osc_hz, outputs))
        m.submodules.sync_reset = ResetSynchronizer(~guard.ever_qualified, domain="sync")
        m.submodules.pll_losses_cdc = FFSynchronizer(guard.losses, core.pll_losses)
        m.submodules.clock_ok_cdc = FFSynchronizer(guard.qualified, core.clock_ok)
        m.domains += ClockDomain(fe.domain)
        capture_up = Signal()
        m.submodules.capture_reset = ResetSynchronizer(~capture_up, domain=fe.domain)
        running = fe.board_clocks(m, b, sensor, core)
        m.d.comb += capture_up.eq(guard.qualified & running)
        # RESET_BAR: low at power-up and on the MCU's request, each time for at least
        # SENSOR_RESET_S with the master clock running (SensorReset, in osc)
        m.submodules.sensor_reset = sensor_reset = SensorReset(
            math.ceil(C.SENSOR_RESET_S * b.osc_hz))
        m.submodules.sensor_reset_cdc = FFSynchronizer(core.sensor_reset, sensor_reset.request,
                                                       o_domain="osc")
        m.submodules.sensor_in_reset_cdc = FFSynchronizer(~sensor_reset.reset_n,
                                                          core.sensor_in_reset, init=1)
        reset_n = io.FFBuffer("o", sensor.reset_n, o_domain="osc")
        m.submodules[f"pin_{b.sensor}_0__reset_n"] = reset_n
        m.d.comb += [sensor_reset.clock_ok.eq(guard.qualified),
                     reset_n.o.eq(sensor_reset.reset_n)]

        # ---- MCU: SCK, MOSI and CS_N into the slave's synchronizers; MISO straight from
        # the slave's shift register (FAST_OUTPUT_REGISTER; an output flip-flop more would
        # cost a sync clock of every SCK period); IRQ from an output flip-flop ------------
        spi_in = {sub: input_buffer(m, f"pin_mcu_0__{sub}", getattr(mcu, sub)).i
                  for sub in ("sck", "mosi", "cs_n")}
        m.submodules.pin_mcu_0__miso = miso = io.Buffer("o", mcu.miso)
        m.submodules.pin_mcu_0__irq = irq = io.FFBuffer("o", mcu.irq, o_domain=io_domain("sync"))
        m.d.comb += [core.sck.eq(spi_in["sck"]), core.mosi.eq(spi_in["mosi"]),
                     core.cs_n.eq(spi_in["cs_n"]), miso.o.eq(core.miso),
                     miso.oe.eq(core.miso_oe), irq.o.eq(core.irq)]
        return m


def sdc_constraints(board):
    """Extra SDC lines, after the platform's ``create_clock`` of every clock pin (the
    oscillator and the front end's ``CLOCK_PINS``, from their resources' ``Clock``), so that
    ``derive_pll_clocks`` derives the PLLs' outputs from created clocks: the MCU pins (SCK,
    MOSI, CS_N into synchronizers and IRQ, an asynchronous event, not timed; MISO bounded to
    the clock-to-pin the slave's SCK rule assumes, ``spi_slave.MISO_TCO_NS``), the Gray count
    of PLL losses skew-bounded, RESET_BAR (from the oscillator domain, asynchronous to the
    sensor) not timed, then the front end's lines."""
    miso = "[get_ports {mcu_0__miso__io}]"
    lines = ["derive_pll_clocks", "derive_clock_uncertainty",
             "# SCK, MOSI and CS_N pass 2-flop synchronizers; IRQ is an asynchronous event",
             "set_false_path -from [get_ports {mcu_0__sck__io mcu_0__mosi__io "
             "mcu_0__cs_n__io}]",
             "set_false_path -to [get_ports {mcu_0__irq__io}]",
             "# MISO: the master samples it T_sck - 4 T after the slave acts (its SCK rule); "
             "the FPGA's part is the clock-to-pin",
             f"set_max_delay {MISO_TCO_NS:.3f} -to {miso}",
             "# hold: MISO changes >= 2 sync clocks after the SCK edge the master samples on",
             f"set_min_delay 0.000 -to {miso}",
             *gray_skew_constraints("*|clock_guard|losses*", "*|pll_losses_cdc|*",
                                    0.8e9 / max(board.osc_hz, board.sync_hz)),
             f"set_false_path -to [get_ports {{{board.sensor}_0__reset_n__io}}]"]
    return "\n".join(lines + board.frontend.sdc_constraints(board))


QSF_SETTINGS = (
    "set_global_assignment -name ENABLE_CRC_ERROR_CHECK ON",
    'set_global_assignment -name RESERVE_ALL_UNUSED_PINS_WEAK_PULLUP "AS INPUT TRI-STATED"',
)
"""Global QSF settings of every board: configuration RAM upsets checked in the background
(``ENABLE_CRC_ERROR_CHECK``, the flight board's single-event-upset detector), and unused pins
tri-stated inputs with weak pull-ups (a board's other devices wired to FPGA pins, such as the
DE0-Nano's ADC, accelerometer and SDRAM, are never driven)."""


def project_overrides(board):
    """The ``prepare`` overrides of a board's Quartus project: its SDC lines and QSF
    settings."""
    return {"add_constraints": sdc_constraints(board), "add_settings": "\n".join(QSF_SETTINGS)}
