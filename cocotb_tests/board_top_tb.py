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


async def release_resets(dut, sensor_clock, sensor_reset):
    """Hold both clock domains in reset for 100 ns, then release ``sync`` on a falling
    ``clk`` edge and the sensor domain on a falling edge of its own clock."""
    await Timer(100, unit="ns")
    await FallingEdge(dut.clk)
    dut.rst.value = 0
    await FallingEdge(sensor_clock)
    sensor_reset.value = 0


async def check_idle(master, frames):
    """After ``frames`` frames whose packets were all read: the status word is clean, no
    packet is pending (a stream read gets filler and counts one underrun)."""
    status = await master.read_status()
    assert status == {"frame_counter": frames, "errors": 0, "underruns": 0,
                      "overflow": 0, "busy": 0}, status
    assert await master.read_stream(1) == [0], "no packet is pending"
    status = await master.read_status()
    assert status["underruns"] == 1, status


@cocotb.test()
async def board_top_frames(dut):
    w, h = int(os.environ["TB_WIDTH"]), int(os.environ["TB_HEIGHT"])
    rng = np.random.default_rng(int(os.environ["TB_SEED"]))
    cap = int(os.environ["TB_RECORD_CAPACITY"])
    cocotb.start_soon(Clock(dut.clk, 10, unit="ns").start())
    cocotb.start_soon(Clock(dut.pix_clk, PIX_NS, unit="ns").start())
    dut.rst.value, dut.pix_rst.value = 1, 1
    dut.cs_n.value, dut.sck.value, dut.mosi.value = 1, 0, 0
    dut.line_valid.value, dut.frame_valid.value, dut.pix_d.value = 0, 0, 0
    await release_resets(dut, dut.pix_clk, dut.pix_rst)

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
    assert codec.decode(packets[2]).threshold == 200 and codec.decode(packets[1]).threshold == 50

    await check_idle(master, len(frames))
    dut._log.info("board top: %d frames, %d records, all packets equal the golden results",
                  len(frames), sum(len(codec.decode(p).blobs) for p in packets))
