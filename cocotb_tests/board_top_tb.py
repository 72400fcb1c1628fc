"""cocotb testbench of the board top level (``lodestar.hdl.boards.GatewareTop`` with the
MT9P031 parallel front end, Verilated): a sensor model drives frames on PIXCLK (data launched
on the falling edge, as the MT9P031 does), an SPI master model (``spi_slave_tb.Master``) writes
the registers, waits for ``irq``, reads the status word and each frame's packet, and every
packet must decode to the golden result of its frame.  A threshold written over SPI while a
frame streams in takes effect on the next frame, not on the one under way.  Frames are sent
one at a time (each packet is read before the next frame starts; back-to-back packets are
covered by ``tests/hdl/test_packetizer.py``), so ``irq`` must fall after each packet.

Clocks: ``clk`` (sync) 100 MHz, ``pix_clk`` 76.9 MHz (13 ns), asynchronous.  Parameters from
the environment: ``TB_WIDTH``, ``TB_HEIGHT``, ``TB_SEED``, ``TB_RECORD_CAPACITY``.
"""

import os

import cocotb
import numpy as np
from cocotb.clock import Clock
from cocotb.triggers import FallingEdge, RisingEdge, Timer
from spi_slave_tb import Master

from lodestar import contract as C
from lodestar.golden import DetectorConfig, detect_frame
from lodestar.ground import codec

PIX_NS = 13
SCK_NS = 45
HBLANK = 6
"""PIXCLKs with LINE_VALID low between lines."""


def frame_of(rng, w, h, density):
    mask = rng.random((h, w)) < density
    return np.where(mask, rng.integers(51, 4096, (h, w)),
                    rng.integers(0, 51, (h, w))).astype(np.uint16)


class Sensor:
    """MT9P031 parallel bus model: frames of ``D``, ``LINE_VALID``, ``FRAME_VALID``, changed on
    PIXCLK's falling edge; ``frame``/``row`` say where the bus is (-1: vertical blanking)."""

    def __init__(self, dut, vblank):
        self.dut, self.vblank = dut, vblank
        self.clock = dut.pix_clk
        self.frame, self.row = -1, -1

    async def idle(self, n):
        for _ in range(n):
            await FallingEdge(self.dut.pix_clk)
            self.dut.line_valid.value = 0
            self.dut.frame_valid.value = 0

    async def send(self, index, image):
        dut = self.dut
        h, w = image.shape
        self.frame = index
        for y in range(h):
            self.row = y
            for x in range(w):
                await FallingEdge(dut.pix_clk)
                dut.frame_valid.value, dut.line_valid.value = 1, 1
                dut.pix_d.value = int(image[y, x])
            for _ in range(HBLANK):
                await FallingEdge(dut.pix_clk)
                dut.line_valid.value = 0
        self.frame, self.row = -1, -1
        await self.idle(self.vblank)


async def read_packet(master, dut):
    """The next packet: wait for ``irq``, read the header, then the rest (reads continue)."""
    while not int(dut.irq.value):
        await RisingEdge(dut.irq)
    head = await master.read_stream(C.HEADER_BYTES)
    n = int.from_bytes(bytes(head[-2:]), "big")
    rest = await master.read_stream(C.packet_bytes(n) - C.HEADER_BYTES)
    await Timer(4 * 10, unit="ns")
    assert not int(dut.irq.value), "irq still high after the packet's last byte"
    return bytes(head + rest)


async def frame_and_packet(master, sensor, index, image, during=None):
    """Stream one frame (``during``, if given, runs once the sensor is on its second row)
    and read its packet.  ``sensor``: a model with ``send(index, image)``, the ``frame`` and
    ``row`` it is on (-1 outside frames) and its ``clock``."""
    task = cocotb.start_soon(sensor.send(index, image))
    if during is not None:
        while not (sensor.frame == index and sensor.row >= 1):
            await FallingEdge(sensor.clock)
        await during()
        assert sensor.frame == index, "the register write did not finish inside the frame"
    data = await read_packet(master, sensor.dut)
    await task
    return data


def board_inputs(dut):
    """The board's inputs of a ``GatewareTop`` as after power-up: the PLL's lock qualified
    (``clock_ok``), no lock loss counted, the sensor out of reset."""
    dut.clock_ok.value, dut.pll_losses.value, dut.sensor_in_reset.value = 1, 0, 0


async def release_resets(dut, sensor_clock, sensor_reset):
    """Hold both clock domains in reset for 100 ns, then release ``sync`` on a falling
    ``clk`` edge and the sensor domain on a falling edge of its own clock."""
    await Timer(100, unit="ns")
    await FallingEdge(dut.clk)
    dut.rst.value = 0
    await FallingEdge(sensor_clock)
    sensor_reset.value = 0


async def check_idle(master, frames, trained=0, eye_width=0):
    """After ``frames`` frames whose packets were all read: the status word is clean (the
    phase training's fields as given), no packet is pending (a stream read gets filler and
    counts one underrun)."""
    status = await master.read_status()
    assert status == {"frame_counter": frames, "errors": 0, "underruns": 0,
                      "overflow": 0, "busy": 0, "trained": trained,
                      "eye_width": eye_width}, status
    assert await master.read_stream(1) == [0], "no packet is pending"
    status = await master.read_status()
    assert status["underruns"] == 1, status


async def power_up(dut):
    """Start the clocks, hold and release both domains' resets, board inputs idle."""
    cocotb.start_soon(Clock(dut.clk, 10, unit="ns").start())
    cocotb.start_soon(Clock(dut.pix_clk, PIX_NS, unit="ns").start())
    dut.rst.value, dut.pix_rst.value = 1, 1
    board_inputs(dut)
    dut.cs_n.value, dut.sck.value, dut.mosi.value = 1, 0, 0
    dut.line_valid.value, dut.frame_valid.value, dut.pix_d.value = 0, 0, 0
    await release_resets(dut, dut.pix_clk, dut.pix_rst)


@cocotb.test()
async def board_top_frames(dut):
    w, h = int(os.environ["TB_WIDTH"]), int(os.environ["TB_HEIGHT"])
    rng = np.random.default_rng(int(os.environ["TB_SEED"]))
    cap = int(os.environ["TB_RECORD_CAPACITY"])
    await power_up(dut)
    master = Master(dut, SCK_NS)
    for name, value in (("threshold", 50), ("background", 40), ("min_pixels", 1)):
        await master.write_reg(C.REGISTER_BY_NAME[name].address, value)
    sensor = Sensor(dut, vblank=2 * w + 60)
    await sensor.idle(20)
    frames = [frame_of(rng, w, h, d) for d in (0.15, 0.3, 0.3, 0.0, 0.2)]
    thresholds = [50, 50, 200, 200, 200]     # 200 is written during frame 1
    packets = []

    async def write_threshold():
        await master.write_reg(C.REGISTER_BY_NAME["threshold"].address, 200)

    for i, image in enumerate(frames):
        packets.append(await frame_and_packet(master, sensor, i, image,
                                              write_threshold if i == 1 else None))
    for i, (image, data) in enumerate(zip(frames, packets)):
        cfg = DetectorConfig(width=w, height=h, pixel_bits=12, threshold=thresholds[i],
                             background=40, min_pixels=1, record_capacity=cap)
        expected = detect_frame(image, cfg)
        expected.frame_counter = i
        got = codec.decode(data)
        assert got == expected, (i, got, expected)
    assert any(len(codec.decode(p).blobs) for p in packets)
    stamps = [codec.decode(p).timestamp for p in packets]      # the frames' first pixels
    assert all(b > a for a, b in zip(stamps, stamps[1:])), stamps
    assert codec.decode(packets[2]).threshold == 200 and codec.decode(packets[1]).threshold == 50

    await check_idle(master, len(frames))
    dut._log.info("board top: %d frames, %d records, all packets equal the golden results",
                  len(frames), sum(len(codec.decode(p).blobs) for p in packets))


@cocotb.test()
async def board_top_lock_loss(dut):
    """The PLL loses lock in the middle of a frame, as ``BoardTop`` shows it to the top
    level: ``clock_ok`` falls, the capture domain is held in reset, the Gray loss count
    steps; after the qualified relock the rest of that frame is ignored, and the next frame
    (whole) gives the golden packet with the frame counter restarted at 0, the registers
    written before the loss still in force; the status shows ``OVF_CLOCK_LOST`` once."""
    w, h = int(os.environ["TB_WIDTH"]), int(os.environ["TB_HEIGHT"])
    rng = np.random.default_rng(int(os.environ["TB_SEED"]) + 1)
    cap = int(os.environ["TB_RECORD_CAPACITY"])
    await power_up(dut)
    master = Master(dut, SCK_NS)
    for name, value in (("threshold", 60), ("background", 40), ("min_pixels", 1)):
        await master.write_reg(C.REGISTER_BY_NAME[name].address, value)
    sensor = Sensor(dut, vblank=2 * w + 60)
    await sensor.idle(20)
    frames = [frame_of(rng, w, h, 0.2) for _ in range(3)]
    cfg = DetectorConfig(width=w, height=h, pixel_bits=12, threshold=60, background=40,
                         min_pixels=1, record_capacity=cap)

    first = codec.decode(await frame_and_packet(master, sensor, 0, frames[0]))
    assert first == detect_frame(frames[0], cfg)
    assert (await master.read_status())["overflow"] == 0

    cut = cocotb.start_soon(sensor.send(1, frames[1]))
    while not (sensor.frame == 1 and sensor.row >= h // 2):
        await FallingEdge(dut.pix_clk)
    dut.clock_ok.value, dut.pix_rst.value, dut.pll_losses.value = 0, 1, 1
    await Timer(300, unit="ns")                     # unlocked, then relocked and qualified
    dut.clock_ok.value = 1
    await FallingEdge(dut.pix_clk)
    dut.pix_rst.value = 0
    assert sensor.frame == 1, "the relock must come inside the frame it cut"
    await cut
    assert not int(dut.irq.value), "no packet of the cut frame"

    after = codec.decode(await frame_and_packet(master, sensor, 2, frames[2]))
    expected = detect_frame(frames[2], cfg)
    expected.frame_counter = 0
    assert after == expected, (after, expected)
    status = await master.read_status()
    assert status["overflow"] == 1 << C.OVF_CLOCK_LOST and status["frame_counter"] == 1, status
    await check_idle(master, 1)
    dut._log.info("lock loss: the frame after the relock (%d records) equals the golden one",
                  len(after.blobs))
