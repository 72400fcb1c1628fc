"""A ``machine.SPI`` + CS + IRQ whose far end is the Amaranth simulation of
``hdl.spi_slave.SPISlave``: every byte the firmware's link master sends is clocked bit by bit
(SPI mode 0, SCK asynchronous to the system clock, CS lead/lag/high just above the documented
minimums) into the gateware, which answers from a packet queue and a register bank modelled
as the board wires them (``reg_rdata`` one clock after ``reg_addr``; ``irq`` high while a
packet's bytes remain; ``flush`` empties the queue; ``soft_reset`` is counted)."""

from collections import deque

from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.fly.bus import Pin
from lodestar.hdl.spi_slave import SPISlave

NS = 1e-9


class AmaranthBus:
    """``spi``, ``cs``, ``irq``: the objects :class:`lodestar.firmware.link.Link` takes.
    ``packets``: packets (bytes) queued for the MCU; ``bank``: the register words; ``mosi_hook``
    and ``miso_hook``: optional ``f(byte_number, byte) -> byte`` that corrupt the wires."""

    def __init__(self, T=10 * NS, sck=53 * NS, build=0x21):
        self.T, self.half = T, sck / 2
        self.dut = dut = SPISlave(build=build)
        self.packets = deque()       # whole packets not yet started
        self.current = deque()       # bytes of the packet being delivered
        self.bank = {r.address: r.reset for r in C.REGISTERS}
        self.resets = self.flushes = 0
        self.status_in = {"busy": 0, "overflow": 0, "frame_counter": 0}
        self.miso_hook = None
        self._ops = deque()
        self._done = None
        self._cs = 1
        self._byte_no = 0
        sim = self.sim = Simulator(dut)
        sim.add_clock(T, phase=0.43 * T)
        self._benches = [self._master, self._fabric]
        self.spi = self
        self.cs = Pin(read=lambda: self._cs, write=self._set_cs)
        self.irq = Pin(read=lambda: int(bool(self.current or self.packets)))

    # ---- the far end: packet source, register bank, strobes ---------------------------

    async def _fabric(self, ctx):
        dut = self.dut
        while True:
            if not self.current and self.packets:
                self.current.extend(self.packets.popleft())
            ctx.set(dut.packet.valid, bool(self.current))
            if self.current:
                ctx.set(dut.packet.payload, self.current[0])
            for name, value in self.status_in.items():
                ctx.set(getattr(dut, name), value)
            _, _, valid, ready, strobe, addr, data, reset, flush = await ctx.tick().sample(
                dut.packet.valid, dut.packet.ready, dut.reg_strobe, dut.reg_addr, dut.reg_data,
                dut.soft_reset, dut.flush)
            if valid and ready:
                self.current.popleft()
            if strobe:
                self.bank[addr] = data
            ctx.set(dut.reg_rdata, self.bank.get(ctx.get(dut.reg_addr), 0))
            self.resets += reset
            if flush:
                self.flushes += 1
                self.current.clear()
                self.packets.clear()

    # ---- the master's pins, driven from the queue of operations -----------------------

    async def _master(self, ctx):
        dut = self.dut
        while True:
            if not self._ops:
                await ctx.delay(self.T)
                continue
            op = self._ops.popleft()
            if op[0] == "cs":
                if op[1] == 0:
                    ctx.set(dut.cs_n, 0)
                    await ctx.delay(4.1 * self.T)
                else:
                    await ctx.delay(max(2.1 * self.T - self.half, 0))
                    ctx.set(dut.cs_n, 1)
                    await ctx.delay(3.1 * self.T)
                self._done = True
                continue
            out = op[1]
            got = bytearray(len(out))
            for k in range(8 * len(out)):
                byte, bit = divmod(k, 8)
                ctx.set(dut.mosi, (out[byte] >> (7 - bit)) & 1)
                await ctx.delay(self.half)
                got[byte] |= ctx.get(dut.miso) << (7 - bit)
                ctx.set(dut.sck, 1)
                await ctx.delay(self.half)
                ctx.set(dut.sck, 0)
            self._done = got

    def _run(self, op):
        # the testbenches join at the first transaction: a bus that is never clocked
        # leaves no coroutine that was never awaited
        for bench in self._benches:
            self.sim.add_testbench(bench, background=True)
        self._benches = []
        self._done = None
        self._ops.append(op)
        while self._done is None:
            self.sim.advance()
        return self._done

    def _set_cs(self, v):
        v = int(bool(v))
        if v != self._cs:
            self._cs = v
            self._byte_no = 0
            self._run(("cs", v))

    # ---- machine.SPI ------------------------------------------------------------------

    def write_readinto(self, out, into):
        got = self._run(("bytes", bytes(out)))
        if self.miso_hook is not None:
            for i in range(len(got)):
                got[i] = self.miso_hook(self._byte_no + i, got[i])
        self._byte_no += len(got)
        into[:len(got)] = got

    def write(self, out):
        self.write_readinto(out, bytearray(len(out)))

    def readinto(self, into, write=0):
        self.write_readinto(bytes([write]) * len(into), into)


class SimClock:
    """``time``'s ``ticks_ms``/``ticks_diff``/``sleep_ms`` on a simulated millisecond count
    (``sleep_ms`` advances it; ``on_sleep`` may react)."""

    def __init__(self):
        self.now = 0
        self.on_sleep = None

    def ticks_ms(self):
        return self.now

    def ticks_diff(self, a, b):
        return a - b

    def sleep_ms(self, n):
        self.now += n
        if self.on_sleep is not None:
            self.on_sleep(self.now)


class GatewareTopBus(AmaranthBus):
    """The same master, but its far end is a whole :class:`lodestar.hdl.boards.GatewareTop`
    (an idle MT9P031 on a small frame; ``pix`` clocked): the register bank, soft reset, flush
    and ``irq`` are the gateware's own."""

    def __init__(self, T=10 * NS, sck=53 * NS, width=16, height=8, capacity=4):
        from lodestar.hdl.boards import GatewareTop

        self.T, self.half = T, sck / 2
        self.dut = GatewareTop("mt9p031", width, height, record_capacity=capacity,
                               record_depth=2 * capacity)
        self.miso_hook = None
        self._ops = deque()
        self._done = None
        self._cs = 1
        self._byte_no = 0
        self._irq = 0
        sim = self.sim = Simulator(self.dut)
        sim.add_clock(T, phase=0.43 * T)
        sim.add_clock(1.04 * T, domain="pix")
        self._benches = [self._master, self._watch]
        self.spi = self
        self.cs = Pin(read=lambda: self._cs, write=self._set_cs)
        self.irq = Pin(read=lambda: self._irq)

    async def _watch(self, ctx):
        async for _, _, irq in ctx.tick().sample(self.dut.irq):
            self._irq = irq
