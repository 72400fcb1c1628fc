"""The register bank: contract reset values, accepted and refused writes."""

from amaranth import ClockDomain, Module
from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.hdl.registers import RegisterBank


def run(writes, pixel_bits=12):
    dut = RegisterBank(pixel_bits)
    seen = []

    async def bench(ctx):
        seen.append({r.name: ctx.get(getattr(dut, r.name)) for r in C.REGISTERS})
        for addr, data in writes:
            ctx.set(dut.addr, addr)
            ctx.set(dut.data, data)
            ctx.set(dut.en, 1)
            await ctx.tick()
            ctx.set(dut.en, 0)
            seen.append(({r.name: ctx.get(getattr(dut, r.name)) for r in C.REGISTERS},
                         ctx.get(dut.error)))
            ctx.set(dut.error_clear, 1)
            await ctx.tick()
            ctx.set(dut.error_clear, 0)

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    sim.run()
    return seen


def test_reset_values_are_the_contracts():
    assert run([])[0] == {r.name: r.reset for r in C.REGISTERS}


def test_accepted_and_refused_writes():
    reg = C.REGISTER_BY_NAME
    writes = [
        (reg["threshold"].address, 300),               # ok
        (reg["threshold"].address, 4096),              # above 12-bit full scale
        (reg["mode"].address, C.MODE_LOCAL),           # ok
        (reg["mode"].address, 3),                      # not a mode
        (reg["local_log2_window"].address, 0),         # below the minimum
        (reg["local_log2_window"].address, 3),         # ok
        (reg["min_sum"].address, 1 << 30),             # wider than the field
        (15, 1),                                       # no such register
        (reg["max_pixels"].address, 77),               # ok
    ]
    seen = run(writes)[1:]
    assert [err for _, err in seen] == [0, 1, 0, 1, 1, 0, 1, 1, 0]
    final = seen[-1][0]
    assert final["threshold"] == 300 and final["mode"] == C.MODE_LOCAL
    assert final["local_log2_window"] == 3 and final["max_pixels"] == 77
    assert final["min_sum"] == reg["min_sum"].reset


def test_domain_reset_restores_the_contract_values():
    """The bank loads the reset values itself while the domain's reset is high (its
    flip-flops have no reset of their own): after writes, a reset brings every register
    back; writes are refused while it is high."""
    reg = C.REGISTER_BY_NAME
    dut = RegisterBank(12)
    m = Module()
    m.domains.sync = sync = ClockDomain()
    m.submodules.dut = dut
    seen = {}

    async def bench(ctx):
        for r in C.REGISTERS:
            ctx.set(dut.addr, r.address)
            ctx.set(dut.data, r.reset ^ 1)
            ctx.set(dut.en, 1)
            await ctx.tick()
        seen["written"] = {r.name: ctx.get(getattr(dut, r.name)) for r in C.REGISTERS}
        ctx.set(dut.addr, reg["threshold"].address)
        ctx.set(dut.data, 7)
        ctx.set(sync.rst, 1)
        await ctx.tick()
        ctx.set(sync.rst, 0)
        ctx.set(dut.en, 0)
        seen["reset"] = {r.name: ctx.get(getattr(dut, r.name)) for r in C.REGISTERS}

    sim = Simulator(m)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    sim.run()
    assert seen["written"] == {r.name: r.reset ^ 1 for r in C.REGISTERS}
    assert seen["reset"] == {r.name: r.reset for r in C.REGISTERS}
