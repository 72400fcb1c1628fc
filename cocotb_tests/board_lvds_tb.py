"""cocotb testbench of the board top level with the MT9V022 LVDS front end
(``lodestar.hdl.boards.GatewareTop("mt9v022", ...)``, Verilated): an LVDS sensor model
serialises frames as the MT9V022 stand-alone LVDS stream does and feeds them as
``lvds_bits``, ``LVDS_LANES`` bits per ``ser`` clock (what ALTLVDS_RX hands the fabric); the
SPI master model of ``spi_slave_tb`` writes the registers, waits for ``irq`` and reads each
frame's packet (``board_top_tb.frame_and_packet``), and every packet must equal, byte for
byte, ``lodestar.ground.codec.encode`` of the golden result of its frame
(``lodestar.golden.Detector``,
``detect_frame``'s stateful form: global mode needs the previous frame).

The sensor model (facts from :mod:`lodestar.hdl.mt9v022`, imported): one 12-bit packet per
word (``packet_bits``: start bit, 10 data bits LSB first, stop bit), earliest bit in the
MSB of ``lvds_bits``; the link never stops: blanking words (``RESERVED_WORDS``, a raw 0 as
the link carries it) between lines and frames; a frame is ``FULL, FRAME_START_MIDDLE, FULL``,
then per line ``LINE_START``, the pixels, ``LINE_END``; ``FRAME_END`` follows the last line's
``LINE_END`` on even frames and replaces it on odd ones (the datasheet order is unverified;
the front end accepts both).  The stream starts a random number of bits into a packet, so
the front end must find the word boundary (no framing error may be counted).

Frames: random star fields (Gaussian spots, the brightest saturated) on a dark background
whose raw values include 0 .. 3, plus a raw ``FULL, 0, FULL`` inside a line.  The sensor
never sends 0 .. 3 as pixels: it puts 4 in their place (``link_frame``), which also makes the
raw ``FULL, 0, FULL`` a harmless ``FULL, 4, FULL``; the golden model gets the frames as the
link carries them.

Registers: ``threshold`` written over SPI while frame 1 streams in applies from frame 2 (not
to frame 1); ``mode`` = global, written between the packets of frames 3 and 4, applies from
frame 4, whose levels come from frame 3's statistics over all its pixels (so every pixel
value, the clamped ones included, must arrive exactly: the testbench checks that the golden
packets of the unclamped frames differ).  The status word shows the link down
(``OVF_LINK_DOWN``) before the sensor starts and a clean status (locked, no framing error,
no overflow) after the last frame.

A second test cuts the link inside a frame (``board_lvds_link_stops``): the frame watchdog
completes the frame after its stall timeout and its packet is flagged ``FRAME_TIMEOUT``.

Phase training: the top is built with ``TB_TAPS`` sample phases; the sensor model samples
each bit at the top's ``rx_tap`` (what the board's PLL phase steps select): correctly inside
the link's eye (``eye`` = first phase and width, modulo the taps), at random outside it.
Every test waits for ``trained`` in the status word before its first frame (the trainer
sweeps on the blanking stream); the first two have an eye over every phase, the third
(``board_lvds_skewed_eye``) a narrow one that wraps around the bit's edge: the trainer
centres it, reports its width, and the frames are exact.

Clocks: the DE2-115's (the SPI master model assumes a 10 ns ``sync``): ``sync`` ``T_NS`` =
10 ns (board 100 MHz), ``ser`` = ``sync`` x (board sync / (board pixel clock x 12 /
``LVDS_LANES``)) = 20 ns (board 50 MHz, 2 x the 25 MHz pixel clock), asynchronous to
``sync``; SCK 5 x ``sync``.
Parameters from the environment: ``TB_WIDTH``, ``TB_HEIGHT``, ``TB_SEED``,
``TB_RECORD_CAPACITY``, ``TB_TAPS``.
"""

import os
from collections import deque

import cocotb
import numpy as np
from board_top_tb import (
    board_inputs,
    check_idle,
    frame_and_packet,
    read_packet,
)
from cocotb.clock import Clock
from cocotb.triggers import Event, FallingEdge, Timer
from spi_slave_tb import T_NS, Master

from lodestar import contract as C
from lodestar.contract import OVF_LINK_DOWN, OVF_LINK_ERROR
from lodestar.golden import Detector, DetectorConfig
from lodestar.ground import codec
from lodestar.hdl.boards import BOARDS
from lodestar.hdl.mt9v022 import (
    FRAME_END,
    FRAME_START_MIDDLE,
    FULL,
    LINE_END,
    LINE_START,
    LVDS_LANES,
    PACKET_BITS,
    PIXEL_BITS,
    RESERVED_WORDS,
    packet_bits,
)

_DE2 = BOARDS["de2-115"]
SER_PS = 2 * round(T_NS * 1000 * _DE2.sync_hz * LVDS_LANES
                   / (_DE2.pixel_hz * PACKET_BITS) / 2)
"""``ser`` period in ps (even, for a 50 % duty cycle at 1 ps resolution)."""
SCK_NS = 5 * T_NS
BLANK = RESERVED_WORDS
"""The word between lines and frames (a raw 0 as the link carries it)."""
HBLANK = 10
"""Blanking words after each line's ``LINE_END``."""
VBLANK = 12
"""Blanking words before each frame's start sequence (more follow while the packet is read)."""
BACKGROUND_ADU, NOISE_ADU = 6, 3
"""Raw background level and its Gaussian noise: about a fifth of the raw background pixels
are 0 .. 3."""


def link_frame(raw):
    """A raw frame as the sensor puts it on the link: the reserved codes 0 .. 3 become 4."""
    return np.maximum(raw, RESERVED_WORDS)


def star_field(rng, w, h, stars):
    """A raw frame: ``stars`` Gaussian spots (peaks 60 .. 1500 ADU, clipped at ``FULL``) on a
    background of ``BACKGROUND_ADU`` +- ``NOISE_ADU`` (so raw 0 .. 3 occur), and a raw
    ``FULL, 0, FULL`` in a line when there are stars."""
    yy, xx = np.mgrid[0:h, 0:w]
    img = rng.normal(BACKGROUND_ADU, NOISE_ADU, (h, w))
    for _ in range(stars):
        x0, y0, sigma = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(0.5, 1.5)
        img += rng.uniform(60, 1500) * np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2)
                                              / (2 * sigma ** 2))
    raw = np.clip(np.rint(img), 0, FULL).astype(np.uint16)
    if stars:
        y, x = int(rng.integers(0, h)), int(rng.integers(0, w - 2))
        raw[y, x:x + 3] = (FULL, 0, FULL)
    return raw


class LvdsSensor:
    """MT9V022 stand-alone LVDS model (module docstring) driving ``lvds_bits`` on the falling
    edge of ``ser_clk``; ``frame``/``row`` say which frame and line the word on the link
    belongs to (-1: blanking between frames)."""

    def __init__(self, dut, slip, rng, eye=None):
        self.dut, self.clock = dut, dut.ser_clk
        self.taps = int(os.environ["TB_TAPS"])
        self.eye = eye or (0, self.taps)     # (first phase, width) sampled correctly
        self.rng = rng
        self.frame, self.row = -1, -1
        self.words = deque()                        # (word, frame, row)
        self.sent = Event()
        self.bits = deque(packet_bits(BLANK)[slip:])
        self.dead = 0          # packets of all-zero bits (link down) after the queued words

    async def drive(self):
        while True:
            await FallingEdge(self.clock)
            while len(self.bits) < LVDS_LANES:
                if self.words:
                    word, self.frame, self.row = self.words.popleft()
                    if not self.words:
                        self.sent.set()
                elif self.dead:
                    self.dead -= 1
                    self.bits.extend([0] * PACKET_BITS)
                    continue
                else:
                    word, self.frame, self.row = BLANK, -1, -1
                self.bits.extend(packet_bits(word))
            chunk = [self.bits.popleft() for _ in range(LVDS_LANES)]
            first, width = self.eye
            if (int(self.dut.rx_tap.value) - first) % self.taps >= width:
                chunk = [int(b) for b in self.rng.integers(0, 2, LVDS_LANES)]  # off the eye
            self.dut.lvds_bits.value = sum(b << (LVDS_LANES - 1 - j) for j, b in enumerate(chunk))

    async def trained(self, master, polls=40):
        """Read the status until the front end reports ``trained`` (each read takes about
        5 us; training on the blanking takes about 15 us); returns that status."""
        for _ in range(polls):
            status = await master.read_status()
            if status["trained"]:
                return status
        raise AssertionError(f"not trained after {polls} status reads: {status}")

    async def send(self, index, image):
        """Serialise frame ``index`` (link values) and return once its last word is on the
        link."""
        words = [(BLANK, -1, -1)] * VBLANK
        words += [(w, index, -1) for w in (FULL, FRAME_START_MIDDLE, FULL)]
        for y, row in enumerate(image):
            line = [LINE_START] + [int(p) for p in row] + [LINE_END]
            if y == len(image) - 1:
                line = line + [FRAME_END] if index % 2 == 0 else line[:-1] + [FRAME_END]
            words += [(w, index, y) for w in line + [BLANK] * HBLANK]
        self.sent.clear()
        self.words.extend(words)
        await self.sent.wait()

    async def send_cut(self, index, image, row, col, dead):
        """Frame ``index`` up to pixel ``col - 1`` of ``row``; then the link carries ``dead``
        packets of zero bits (no start bit: framing errors) and blanking after them."""
        words = [(BLANK, -1, -1)] * VBLANK
        words += [(w, index, -1) for w in (FULL, FRAME_START_MIDDLE, FULL)]
        for y in range(row + 1):
            line = [LINE_START] + [int(p) for p in image[y][:col if y == row else None]]
            words += [(w, index, y) for w in line + ([] if y == row else
                                                      [LINE_END] + [BLANK] * HBLANK)]
        self.sent.clear()
        self.dead = dead
        self.words.extend(words)
        await self.sent.wait()


async def release_sync(dut):
    """Release ``sync``'s reset; the ``ser`` domain stays in reset until the link runs (on
    the board the receiver's PLL locks only on the running LVDS clock)."""
    await Timer(100, unit="ns")
    await FallingEdge(dut.clk)
    dut.rst.value = 0


async def bring_up(dut, rng):
    """Power-up of the board top: both domains in reset, the SPI idle, the receiver's PLL
    locked, ``sync``'s clock and ``ser``'s at a random phase against it; ``sync`` released
    and the detector's registers written (fixed threshold 40, background 8, one pixel).
    Returns the SPI master."""
    dut.rst.value, dut.ser_rst.value = 1, 1
    dut.cs_n.value, dut.sck.value, dut.mosi.value = 1, 0, 0
    dut.lvds_bits.value = 0
    dut.rx_locked.value = 1                        # the LVDS receiver PLL is locked
    board_inputs(dut)
    cocotb.start_soon(Clock(dut.clk, T_NS, unit="ns").start())
    await Timer(int(rng.integers(1, SER_PS)), unit="ps")        # ser phase against sync
    cocotb.start_soon(Clock(dut.ser_clk, SER_PS, unit="ps").start())
    await release_sync(dut)
    master = Master(dut, SCK_NS)
    for name, value in (("threshold", 40), ("background", 8), ("min_pixels", 1)):
        await master.write_reg(C.REGISTER_BY_NAME[name].address, value)
    return master


async def start_link(dut, sensor):
    """The sensor's link starts (blanking) and the ``ser`` domain leaves reset: the trainer's
    first sweep sees the link at every phase."""
    cocotb.start_soon(sensor.drive())
    await FallingEdge(dut.ser_clk)
    dut.ser_rst.value = 0


def stamped(expected, data):
    """The golden packet ``expected`` with the ``timestamp`` of the gateware's packet
    ``data`` (the top's clock, which the golden model has not got), CRC and all."""
    stamp = codec.decode(data).timestamp
    return codec.encode(codec.decode(expected).replace(timestamp=stamp))


def rising(packets):
    """True if the packets' timestamps rise strictly (one frame after another)."""
    stamps = [codec.decode(p).timestamp for p in packets]
    return all(b > a for a, b in zip(stamps, stamps[1:]))


def golden_packets(frames, configs):
    """The golden model's packets of ``frames`` streamed in order from reset, frame ``i``
    under ``configs[i]`` (state carried across frames as the gateware does)."""
    detector = Detector(configs[0])
    packets = []
    for image, cfg in zip(frames, configs):
        detector.configure(cfg)
        packets.append(codec.encode(detector.process(image)))
    return packets


@cocotb.test(timeout_time=3, timeout_unit="ms")     # about 0.8 ms are needed
async def board_lvds_frames(dut):
    w, h = int(os.environ["TB_WIDTH"]), int(os.environ["TB_HEIGHT"])
    rng = np.random.default_rng(int(os.environ["TB_SEED"]))
    cap = int(os.environ["TB_RECORD_CAPACITY"])
    slip = int(rng.integers(0, PACKET_BITS))
    master = await bring_up(dut, rng)
    status = await master.read_status()
    assert status["overflow"] == 1 << OVF_LINK_DOWN, status

    sensor = LvdsSensor(dut, slip, rng)
    await start_link(dut, sensor)
    await sensor.trained(master)
    raw = [star_field(rng, w, h, n) for n in (6, 9, 9, 0, 8, 7)]
    frames = [link_frame(r) for r in raw]
    thresholds = [40, 40, 150, 150, 150, 150]      # 150 is written during frame 1
    modes = [C.MODE_FIXED] * 4 + [C.MODE_GLOBAL] * 2   # global written after frame 3's packet
    configs = [DetectorConfig(width=w, height=h, pixel_bits=PIXEL_BITS,
                              threshold_mode=C.MODE_NAMES[m], threshold=t, background=8,
                              min_pixels=1, record_capacity=cap)
               for m, t in zip(modes, thresholds)]
    want = golden_packets(frames, configs)
    assert golden_packets(raw, configs) != want, "the stimulus does not exercise the clamp"

    async def write_threshold():
        await master.write_reg(C.REGISTER_BY_NAME["threshold"].address, thresholds[2])

    packets = []
    for i, image in enumerate(frames):
        if i and modes[i] != modes[i - 1]:
            await master.write_reg(C.REGISTER_BY_NAME["mode"].address, modes[i])
        packets.append(await frame_and_packet(master, sensor, i, image,
                                              write_threshold if i == 1 else None))
    for i, (data, expected) in enumerate(zip(packets, want)):
        assert data == stamped(expected, data), (i, codec.decode(data), codec.decode(expected))
    assert rising(packets)
    got = [codec.decode(p) for p in packets]
    assert [g.mode for g in got] == modes
    assert [g.threshold for g in got[:4]] == thresholds[:4]
    assert not any(g.flags & C.FRAME_GLOBAL_FALLBACK for g in got[4:])
    assert all(len(g.blobs) for k, g in enumerate(got) if k != 3) and not got[3].blobs

    await check_idle(master, len(frames), trained=1, eye_width=sensor.taps)
    dut._log.info("board LVDS: stream %d bits into a packet, %d frames, %d records, all packets "
                  "equal the golden results", slip, len(frames),
                  sum(len(g.blobs) for g in got))


@cocotb.test(timeout_time=3, timeout_unit="ms")
async def board_lvds_link_stops(dut):
    """The link dies inside frame 1 (zero bits: framing errors, the front end abandons the
    frame), then recovers.  The frame watchdog completes frame 1 with dark pixels after its
    stall timeout: its packet equals the golden packet of the frame as it arrived (the
    pixels before the cut; the last one sent is held by the front end for its ``eol`` and
    dropped with the frame) with dark pixels after, flagged ``FRAME_TIMEOUT``.  The status
    word shows the framing errors; ``rx_locked`` low shows as ``OVF_LINK_DOWN``.  Frames 0
    and 2 are exact."""
    w, h = int(os.environ["TB_WIDTH"]), int(os.environ["TB_HEIGHT"])
    rng = np.random.default_rng(int(os.environ["TB_SEED"]) + 1)
    cap = int(os.environ["TB_RECORD_CAPACITY"])
    master = await bring_up(dut, rng)
    await master.read_status()                     # clears the link-down of the start
    sensor = LvdsSensor(dut, int(rng.integers(0, PACKET_BITS)), rng)
    await start_link(dut, sensor)
    await sensor.trained(master)

    frames = [link_frame(star_field(rng, w, h, n)) for n in (6, 9, 7)]
    row, col = h // 2, w // 2
    arrived = frames[1].copy()
    arrived[row, col - 1:] = 0
    arrived[row + 1:] = 0
    cfg = DetectorConfig(width=w, height=h, pixel_bits=PIXEL_BITS, threshold_mode="fixed",
                         threshold=40, background=8, min_pixels=1, record_capacity=cap)
    detector = Detector(cfg)
    want = []
    for k, image in enumerate((frames[0], arrived, frames[2])):
        result = detector.process(image)
        if k == 1:
            result = result.replace(flags=result.flags | C.FRAME_TIMEOUT)
        want.append(codec.encode(result))

    got = [await frame_and_packet(master, sensor, 0, frames[0])]
    assert (await master.read_status())["overflow"] == 0
    task = cocotb.start_soon(sensor.send_cut(1, frames[1], row, col, dead=40))
    got.append(await read_packet(master, dut))
    await task
    status = await master.read_status()
    # errors counted; the dead link outlasted the trainer's dwell: it retrained (its first
    # phase may overlap the dead link's tail) and forgot the aligner's lock, which returns
    # at the next frame start
    assert status["overflow"] & ~(1 << OVF_LINK_DOWN) == 1 << OVF_LINK_ERROR, status
    assert status["trained"] and status["eye_width"] >= sensor.taps - 1, status
    eye = status["eye_width"]
    dut.rx_locked.value = 0
    await Timer(100, unit="ns")
    assert (await master.read_status())["overflow"] == 1 << OVF_LINK_DOWN
    dut.rx_locked.value = 1
    await Timer(100, unit="ns")
    got.append(await frame_and_packet(master, sensor, 2, frames[2]))
    for k, (data, expected) in enumerate(zip(got, want)):
        assert data == stamped(expected, data), (k, codec.decode(data), codec.decode(expected))
    assert rising(got)
    assert codec.decode(got[1]).flags & C.FRAME_TIMEOUT
    assert not any(codec.decode(g).flags for g in (got[0], got[2]))
    await check_idle(master, 3, trained=1, eye_width=eye)
    dut._log.info("board LVDS link stops: frame 1 cut at (%d, %d), %d records after the "
                  "timeout, frames 0 and 2 exact", col, row, len(codec.decode(got[1]).blobs))


@cocotb.test(timeout_time=3, timeout_unit="ms")
async def board_lvds_skewed_eye(dut):
    """A skewed link: only 4 of the 8 phases sample the bits correctly, and the eye wraps
    around the bit's edge (phases 6, 7, 0, 1).  The trainer sweeps the phases on the
    blanking stream, samples at the eye's centre (phase 0) and reports its width (4) in the
    status word; two frames are then exact."""
    w, h = int(os.environ["TB_WIDTH"]), int(os.environ["TB_HEIGHT"])
    rng = np.random.default_rng(int(os.environ["TB_SEED"]) + 2)
    cap = int(os.environ["TB_RECORD_CAPACITY"])
    master = await bring_up(dut, rng)
    first, width = 6, 4
    sensor = LvdsSensor(dut, int(rng.integers(0, PACKET_BITS)), rng, eye=(first, width))
    await start_link(dut, sensor)
    status = await sensor.trained(master)
    centre = (first + width // 2) % sensor.taps
    assert status["eye_width"] == width and int(dut.rx_tap.value) == centre, (status, centre)

    frames = [link_frame(star_field(rng, w, h, n)) for n in (7, 5)]
    cfg = DetectorConfig(width=w, height=h, pixel_bits=PIXEL_BITS, threshold_mode="fixed",
                         threshold=40, background=8, min_pixels=1, record_capacity=cap)
    want = golden_packets(frames, [cfg, cfg])
    await master.read_status()          # the training's framing errors read (and cleared)
    got = [await frame_and_packet(master, sensor, k, image) for k, image in enumerate(frames)]
    for k, (data, expected) in enumerate(zip(got, want)):
        assert data == stamped(expected, data), (k, codec.decode(data), codec.decode(expected))
    await check_idle(master, len(frames), trained=1, eye_width=width)
    dut._log.info("board LVDS skewed eye: phases %d..%d good, sampled at %d, frames exact",
                  first, (first + width - 1) % sensor.taps, centre)
