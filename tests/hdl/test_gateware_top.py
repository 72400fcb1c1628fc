"""The board's gateware top level in the Amaranth simulator, driven through its pins: an MT9P031
sending frames and an SPI master in mode 0.  The commands issue 30 added, wired at the top:
``SOFT_RESET`` in the middle of a frame returns the datapath to idle (register bank kept) and
the next frame is detected bit-exactly as the golden model says; ``FLUSH`` drops the queued
packets (one half read) and the next read is a whole packet; ``READ_REG`` returns what was
written (refused writes leave the old value); ``READ_ID`` carries the build's
``contract.build_id``; the ``sensor_reset`` register reaches the board at once and RESET_BAR
held low shows as ``OVF_LINK_DOWN``.  (A PLL lock loss mid-frame: ``cocotb_tests``.)"""

import gc
import inspect
import warnings

import numpy as np
from amaranth.hdl import UnusedElaboratable
from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.firmware.link import Link
from lodestar.golden import DetectorConfig, detect_frame
from lodestar.ground import codec
from lodestar.hdl.boards import BOARDS, GatewareTop

W, H, CAP = 16, 8, 4
HALF = 4                                  # sync clocks per SCK half period (slave: >= 2)
THRESHOLD, BACKGROUND = 50, 40


def _frames(n, seed=3):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        mask = rng.random((H, W)) < 0.3
        out.append(np.where(mask, rng.integers(51, 4096, (H, W)),
                            rng.integers(0, 51, (H, W))).astype(np.uint16))
    return out


def _golden(frame, counter):
    cfg = DetectorConfig(width=W, height=H, pixel_bits=12, threshold=THRESHOLD,
                         background=BACKGROUND, record_capacity=CAP)
    expected = detect_frame(frame, cfg)
    expected.frame_counter = counter
    return expected


def _samples(frame, hblank=16):
    """``(d, lv, fv)`` pixel-clock samples of one frame with blanking before and after."""
    out = [(0, 0, 0)] * 6 + [(0, 0, 1)] * 2
    for row in frame:
        out += [(int(p), 1, 1) for p in row] + [(0, 0, 1)] * hblank
    return out + [(0, 0, 0)] * 300


async def spi(ctx, top, data):
    """One chip-select transaction: ``data`` out on MOSI, the MISO bytes returned."""
    got = bytearray(len(data))
    ctx.set(top.cs_n, 0)
    await ctx.tick().repeat(6)
    for k in range(8 * len(data)):
        byte, bit = divmod(k, 8)
        ctx.set(top.mosi, (data[byte] >> (7 - bit)) & 1)
        await ctx.tick().repeat(HALF)
        got[byte] |= ctx.get(top.miso) << (7 - bit)
        ctx.set(top.sck, 1)
        await ctx.tick().repeat(HALF)
        ctx.set(top.sck, 0)
    await ctx.tick().repeat(HALF)
    ctx.set(top.cs_n, 1)
    await ctx.tick().repeat(6)
    return bytes(got)


async def write_reg(ctx, top, name, value):
    await spi(ctx, top, C.write_reg_command(name, value))


async def read_reg(ctx, top, name):
    reply = await spi(ctx, top, C.read_reg_command(name))
    return int.from_bytes(reply[C.READ_REG_FIRST_REPLY:], "big")


async def read_status(ctx, top):
    reply = await spi(ctx, top, bytes((C.OP_READ_STATUS,)) + bytes(C.TURNAROUND_BYTES
                                                                   + C.STATUS_BYTES))
    return C.decode_status(reply[1 + C.TURNAROUND_BYTES:])


async def read_packet(ctx, top):
    """A ``READ_STREAM`` as long as the largest packet: the first packet's bytes (length from
    its header; whatever follows is filler)."""
    reply = await spi(ctx, top, bytes((C.OP_READ_STREAM,)) + bytes(
        C.TURNAROUND_BYTES + C.packet_bytes(CAP)))
    data = reply[1 + C.TURNAROUND_BYTES:]
    n = int.from_bytes(data[C.HEADER_BYTES - 2:C.HEADER_BYTES], "big")
    return data[:C.packet_bytes(n)]


async def wait_irq(ctx, top, limit=20000):
    for _ in range(limit):
        if ctx.get(top.irq):
            return True
        await ctx.tick()
    return False


def _run(top, sensor, master):
    sim = Simulator(top)
    sim.add_clock(10e-9)
    sim.add_clock(10.4e-9, domain="pix")
    sim.add_testbench(sensor, background=True)
    sim.add_testbench(master)
    sim.run()


def _sensor(top, frames, progress, gaps=None):
    """The MT9P031 sending ``frames`` (``progress["pixels"]``: samples sent in the frame
    under way, ``progress["frame"]``: its number); ``gaps[k]``: clocks before frame ``k``."""
    async def sensor(ctx):
        for k, frame in enumerate(frames):
            while gaps and not gaps[k](progress):
                await ctx.tick("pix")
            progress["frame"] = k
            for i, (d, lv, fv) in enumerate(_samples(frame)):
                progress["pixels"] = i
                ctx.set(top.pix_d, d)
                ctx.set(top.line_valid, lv)
                ctx.set(top.frame_valid, fv)
                await ctx.tick("pix")
            progress["done"] = k + 1
        while True:
            await ctx.tick("pix")
    return sensor


async def _configure(ctx, top):
    await write_reg(ctx, top, "threshold", THRESHOLD)
    await write_reg(ctx, top, "background", BACKGROUND)


def test_register_read_back_and_id():
    """``READ_REG`` returns each written value and the reset values of the others; a refused
    write (mode 3, a value too wide for its register) leaves the old value and raises
    ``OVF_REG_REFUSED``; a soft reset keeps every value; ``READ_ID`` has the build byte."""
    top = GatewareTop("mt9p031", W, H, record_capacity=CAP, record_depth=2 * CAP)
    got = {}

    async def master(ctx):
        await ctx.tick().repeat(4)
        writes = {"threshold": 1234, "mode": C.MODE_LOCAL, "min_sum": (1 << 28) - 1,
                  "local_log2_window": 5, "ksigma": 0x9C}
        for name, value in writes.items():
            await write_reg(ctx, top, name, value)
        got["written"] = {n: await read_reg(ctx, top, n) for n in writes}
        got["reset"] = {r.name: await read_reg(ctx, top, r.name) for r in C.REGISTERS
                        if r.name not in writes}
        await write_reg(ctx, top, "mode", 3)
        got["after_refusal"] = await read_reg(ctx, top, "mode")
        status = await read_status(ctx, top)
        got["refused"] = (status["overflow"] >> C.OVF_REG_REFUSED) & 1
        await spi(ctx, top, C.keyed_command(C.OP_SOFT_RESET))
        got["after_reset"] = {n: await read_reg(ctx, top, n) for n in writes}
        reply = await spi(ctx, top, bytes((C.OP_READ_ID,)) + bytes(C.TURNAROUND_BYTES
                                                                  + C.ID_BYTES))
        got["id"] = C.decode_id(reply[C.ID_FIRST_REPLY:])
        got["writes"] = writes

    async def idle(ctx):
        while True:
            await ctx.tick("pix")

    _run(top, idle, master)
    writes = got["writes"]
    assert got["written"] == writes
    assert got["reset"] == {r.name: r.reset for r in C.REGISTERS if r.name not in writes}
    assert got["after_refusal"] == C.MODE_LOCAL and got["refused"] == 1
    assert got["after_reset"] == writes
    build = C.build_id("mt9p031", W, H, 12, C.max_open_blobs(W), CAP, 2 * CAP)
    assert got["id"] == {"magic": C.ID_MAGIC, "link_version": C.LINK_VERSION, "build": build}
    assert top.build == build


def test_soft_reset_mid_frame_then_next_frame_is_golden():
    """``SOFT_RESET`` while the detector is inside a frame: after the hold the datapath is
    idle (no frame, no packet, no trailer, ``irq`` low, frame counter 0), the rest of that
    frame is ignored, and the next frame's packet (the only one) equals the golden result
    (frame counter 0); the registers written before the reset still apply."""
    top = GatewareTop("mt9p031", W, H, record_capacity=CAP, record_depth=2 * CAP)
    frames = _frames(2)
    progress = {"pixels": 0, "frame": -1, "done": 0}
    ready = {"configured": False}
    got = {}

    async def master(ctx):
        await ctx.tick().repeat(4)
        await _configure(ctx, top)
        ready["configured"] = True
        while not (progress["frame"] == 0 and progress["pixels"] > 8 + 2 * (W + 16)):
            await ctx.tick()
        data = C.keyed_command(C.OP_SOFT_RESET)
        got["busy_before"] = ctx.get(top.detector.busy)
        await spi(ctx, top, data)
        got["mid_frame"] = progress["frame"] == 0 and progress["pixels"] < 8 + H * (W + 16)
        got["idle"] = (ctx.get(top.detector.busy), ctx.get(top.packetizer.busy),
                       ctx.get(top.detector.trailer.valid), ctx.get(top.detector.records.valid),
                       ctx.get(top.irq), ctx.get(top.detector.frame_counter),
                       ctx.get(top.datapath_reset))
        assert await wait_irq(ctx, top, 40000)
        got["packet"] = await read_packet(ctx, top)
        await ctx.tick().repeat(3000)
        got["irq_after"] = ctx.get(top.irq)
        got["status"] = await read_status(ctx, top)

    sensor = _sensor(top, frames, progress, gaps=[lambda p: ready["configured"],
                                                  lambda p: True])
    _run(top, sensor, master)
    assert got["busy_before"] == 1 and got["mid_frame"]
    assert got["idle"] == (0, 0, 0, 0, 0, 0, 0)
    decoded = codec.decode(got["packet"])
    assert decoded == _golden(frames[1], 0)
    assert got["irq_after"] == 0
    assert got["status"]["overflow"] == 0 and got["status"]["errors"] == 0


def test_timestamp_counts_microseconds_from_the_first_pixel_through_a_soft_reset():
    """The header's ``timestamp`` is the top's free-running counter (one count every
    ``sync_hz / TIMESTAMP_HZ`` clocks: 3 here) as the frame's first pixel entered the
    detector; a ``SOFT_RESET`` restarts the frame counter, not the time."""
    top = GatewareTop("mt9p031", W, H, record_capacity=CAP, record_depth=2 * CAP, sync_hz=3e6)
    frames = _frames(2)
    progress = {"pixels": 0, "frame": -1, "done": 0}
    ready = {"configured": False, "reset": False}
    got = {"sof": [], "packets": []}

    async def master(ctx):
        await ctx.tick().repeat(4)
        await _configure(ctx, top)
        ready["configured"] = True
        assert await wait_irq(ctx, top, 40000)
        got["packets"].append(await read_packet(ctx, top))
        before = ctx.get(top.detector.timestamp)
        await spi(ctx, top, C.keyed_command(C.OP_SOFT_RESET))
        got["across_reset"] = (before, ctx.get(top.detector.timestamp))
        ready["reset"] = True
        assert await wait_irq(ctx, top, 40000)
        got["packets"].append(await read_packet(ctx, top))

    async def watch(ctx):
        clock = 0
        while True:
            if ctx.get(top.detector.pixels.valid) and ctx.get(top.detector.pixels.payload.sof):
                got["sof"].append((clock, ctx.get(top.detector.timestamp)))
            await ctx.tick()
            clock += 1

    sim = Simulator(top)
    sim.add_clock(10e-9)
    sim.add_clock(10.4e-9, domain="pix")
    sim.add_testbench(_sensor(top, frames, progress, gaps=[lambda p: ready["configured"],
                                                           lambda p: ready["reset"]]),
                      background=True)
    sim.add_testbench(watch, background=True)
    sim.add_testbench(master)
    sim.run()
    decoded = [codec.decode(p) for p in got["packets"]]
    assert [d.frame_counter for d in decoded] == [0, 0]
    assert [d.timestamp for d in decoded] == [t for _, t in got["sof"]]
    (c0, t0), (c1, t1) = got["sof"]
    assert abs((t1 - t0) - (c1 - c0) / top.timestamp_divider) <= 1 and t1 > t0 > 0
    before, after = got["across_reset"]
    assert after >= before > t0
    assert decoded[1] == _golden(frames[1], 0)


def test_flush_drops_queued_packets_and_next_read_is_whole():
    """Two frames end unread (the first's packet is being delivered, the second's trailer is
    held); the MCU reads part of the first packet, then ``FLUSH``: within ``flush_clocks()``
    nothing is queued and ``irq`` is low; the next frame's packet is read whole and equals
    the golden result (frame counter 2)."""
    top = GatewareTop("mt9p031", W, H, record_capacity=CAP, record_depth=4 * CAP)
    frames = _frames(3, seed=8)
    progress = {"pixels": 0, "frame": -1, "done": 0}
    ready = {"configured": False, "flushed": False}
    got = {}

    async def master(ctx):
        await ctx.tick().repeat(4)
        await _configure(ctx, top)
        ready["configured"] = True
        while progress["done"] < 2:
            await ctx.tick()
        await ctx.tick().repeat(500)
        got["queued"] = (ctx.get(top.packetizer.busy), ctx.get(top.detector.trailer.valid),
                         ctx.get(top.irq))
        part = await spi(ctx, top, bytes((C.OP_READ_STREAM,)) + bytes(C.TURNAROUND_BYTES + 20))
        got["part"] = part[2:]
        await spi(ctx, top, C.keyed_command(C.OP_FLUSH))
        clocks = 0
        while ctx.get(top.flushing):
            clocks += 1
            await ctx.tick()
        got["flush_clocks"] = clocks
        await ctx.tick().repeat(40)
        got["empty"] = (ctx.get(top.packetizer.busy), ctx.get(top.detector.trailer.valid),
                        ctx.get(top.irq))
        ready["flushed"] = True
        assert await wait_irq(ctx, top, 40000)
        got["packet"] = await read_packet(ctx, top)

    sensor = _sensor(top, frames, progress, gaps=[lambda p: ready["configured"],
                                                  lambda p: True,
                                                  lambda p: ready["flushed"]])
    _run(top, sensor, master)
    assert got["queued"] == (1, 1, 1)
    assert got["part"][:2] == C.PACKET_MAGIC.to_bytes(2, "big")
    assert got["flush_clocks"] <= top.flush_clocks()
    assert got["empty"] == (0, 0, 0)
    decoded = codec.decode(got["packet"])
    assert decoded == _golden(frames[2], 2)


def test_flight_board_record_capacity_is_the_links():
    """One record capacity: the estcube2 gateware emits at most the records the MCU's link
    buffer holds by default (both ``contract.FLIGHT_RECORD_CAPACITY``), and its build byte
    names that capacity."""
    board = BOARDS["estcube2"]
    default = inspect.signature(Link.__init__).parameters["capacity"].default
    assert board.record_capacity == default == C.FLIGHT_RECORD_CAPACITY
    with warnings.catch_warnings():       # built to read its parameters, never elaborated
        warnings.simplefilter("ignore", UnusedElaboratable)
        top = board.gateware_top()
        assert top.detector.record_capacity == C.FLIGHT_RECORD_CAPACITY
        assert top.build == C.build_id("mt9p031", 2592, 1944, 12, 254,
                                       C.FLIGHT_RECORD_CAPACITY, board.record_depth)
        del top
        gc.collect()


def test_sensor_reset_register_and_link_down_status():
    """``sensor_reset`` acts at once (no frame start needed): writing 1 raises the top's
    ``sensor_reset`` output for the board, 0 lowers it; while the board reports RESET_BAR
    low (``sensor_in_reset``) the status shows ``OVF_LINK_DOWN``, live."""
    top = GatewareTop("mt9p031", W, H, record_capacity=CAP, record_depth=2 * CAP)
    got = {}

    async def master(ctx):
        got["idle"] = ctx.get(top.sensor_reset)
        await write_reg(ctx, top, "sensor_reset", 1)
        got["requested"] = ctx.get(top.sensor_reset)
        got["read_back"] = await read_reg(ctx, top, "sensor_reset")
        ctx.set(top.sensor_in_reset, 1)
        got["down"] = (await read_status(ctx, top))["overflow"]
        await write_reg(ctx, top, "sensor_reset", 0)
        got["released"] = ctx.get(top.sensor_reset)
        ctx.set(top.sensor_in_reset, 0)
        await ctx.tick().repeat(4)
        got["up"] = (await read_status(ctx, top))["overflow"]

    async def idle_sensor(ctx):
        while True:
            await ctx.tick("pix")

    _run(top, idle_sensor, master)
    assert (got["idle"], got["requested"], got["read_back"], got["released"]) == (0, 1, 1, 0)
    assert got["down"] == 1 << C.OVF_LINK_DOWN and got["up"] == 0
