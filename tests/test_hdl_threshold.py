"""The threshold unit in the Amaranth simulator against the contract's levels."""

import numpy as np
import pytest
from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.hdl.threshold import ThresholdUnit, global_cycles, ksigma_cycles


def run_frames(dut, frames, regs, gap, late_regs=()):
    """Stream ``frames`` (list of uint16 arrays) with ``gap`` idle clocks before each;
    ``regs`` (one dict per frame) are written at the start of the gap, as the MCU does
    between frames, except the names in ``late_regs``, written just before the frame.
    Returns per frame the output pixels as (x, y, lit, weight, eof) and the latched
    (T, B, fallback)."""
    results = []

    async def bench(ctx):
        for frame, reg in zip(frames, regs):
            for name, value in reg.items():
                if name not in late_regs:
                    ctx.set(getattr(dut, name), value)
            for _ in range(gap):
                await ctx.tick()
            for name in late_regs:
                ctx.set(getattr(dut, name), reg[name])
            pixels = []
            h, w = frame.shape
            for k in range(h * w + 1):
                if k < h * w:
                    y, x = divmod(k, w)
                    ctx.set(dut.pixels.valid, 1)
                    ctx.set(dut.pixels.payload.data, int(frame[y, x]))
                    ctx.set(dut.pixels.payload.sof, int(k == 0))
                    ctx.set(dut.pixels.payload.eol, int(x == w - 1))
                else:
                    ctx.set(dut.pixels.valid, 0)
                await ctx.tick()
                if ctx.get(dut.out.valid):
                    o = dut.out.payload
                    pixels.append((ctx.get(o.x), ctx.get(o.y), ctx.get(o.lit),
                                   ctx.get(o.weight), ctx.get(o.eof)))
            levels = (ctx.get(dut.frame_threshold), ctx.get(dut.frame_background),
                      ctx.get(dut.frame_fallback))
            results.append((pixels, levels))

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    sim.run()
    return results


def expected(frame, t, b):
    h, w = frame.shape
    out = []
    for k in range(h * w):
        y, x = divmod(k, w)
        p = int(frame[y, x])
        out.append((x, y, int(p > t), max(p - b, 0), int(k == h * w - 1)))
    return out


@pytest.mark.parametrize("pixel_bits", [10, 12])
def test_fixed_and_global_modes(pixel_bits):
    w, h = 7, 5
    rng = np.random.default_rng(pixel_bits)
    fs = C.full_scale(pixel_bits)
    frames = [rng.integers(0, fs + 1, (h, w)).astype(np.uint16) for _ in range(5)]
    frames[3][:] = 77                                   # flat frame: sigma 0
    regs = [dict(mode=C.MODE_FIXED, threshold=300, background=20, ksigma=48),
            dict(mode=C.MODE_GLOBAL, threshold=250, background=10, ksigma=48),
            dict(mode=C.MODE_GLOBAL, threshold=250, background=10, ksigma=255),
            dict(mode=C.MODE_GLOBAL, threshold=250, background=10, ksigma=7),
            dict(mode=C.MODE_GLOBAL, threshold=250, background=10, ksigma=16)]
    dut = ThresholdUnit(w, h, pixel_bits)
    results = run_frames(dut, frames, regs, gap=global_cycles(w, h, pixel_bits) + 2)
    prev = None
    for frame, reg, (pixels, (t, b, fallback)) in zip(frames, regs, results):
        if reg["mode"] == C.MODE_GLOBAL and prev is not None:
            p64 = prev.astype(np.int64)
            want = C.global_levels(p64.size, int(p64.sum()), int((p64 * p64).sum()),
                                   reg["ksigma"], pixel_bits)
            assert (t, b, fallback) == (*want, 0)
        else:
            assert (t, b, fallback) == (reg["threshold"], reg["background"], 0)
        assert pixels == expected(frame, t, b)
        prev = frame


def test_global_falls_back_without_time_or_after_a_broken_frame():
    w, h, pb = 6, 4, 12
    dut = ThresholdUnit(w, h, pb)
    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 4096, (h, w)).astype(np.uint16) for _ in range(2)]
    reg = dict(mode=C.MODE_GLOBAL, threshold=111, background=22, ksigma=48)
    # no blanking after the first frame: the statistics are not ready yet
    results = run_frames(dut, frames, [reg, reg], gap=0)
    assert results[0][1] == (111, 22, 1) and results[1][1] == (111, 22, 1)

    assert results[1][0] == expected(frames[1], 111, 22)


def test_blanking_budget_is_sufficient_and_tight():
    w, h, pb = 5, 3, 10
    rng = np.random.default_rng(4)
    frames = [rng.integers(0, 1024, (h, w)).astype(np.uint16) for _ in range(2)]
    reg = dict(mode=C.MODE_GLOBAL, threshold=500, background=0, ksigma=32)
    enough = run_frames(ThresholdUnit(w, h, pb), frames, [reg, reg],
                        gap=global_cycles(w, h, pb))
    short = run_frames(ThresholdUnit(w, h, pb), frames, [reg, reg],
                       gap=global_cycles(w, h, pb) - 3)
    assert enough[1][1][2] == 0 and short[1][1][2] == 1


def test_ksigma_rewritten_between_frames_is_used_or_flagged():
    w, h, pb = 6, 4, 12
    rng = np.random.default_rng(5)
    frames = [rng.integers(0, 4096, (h, w)).astype(np.uint16) for _ in range(2)]
    regs = [dict(mode=C.MODE_GLOBAL, threshold=100, background=0, ksigma=48),
            dict(mode=C.MODE_GLOBAL, threshold=100, background=0, ksigma=20)]
    p64 = frames[0].astype(np.int64)
    want = C.global_levels(p64.size, int(p64.sum()), int((p64 * p64).sum()), 20, pb)
    gap = global_cycles(w, h, pb) + ksigma_cycles(w, h, pb)
    # written at the start of the gap (long enough after the frame): the new k is used
    ok = run_frames(ThresholdUnit(w, h, pb), frames, regs, gap=gap)
    assert ok[1][1] == (*want, 0)
    # written just before the frame: no time to recompute, so the fixed registers + flag
    late = run_frames(ThresholdUnit(w, h, pb), frames, regs, gap=gap, late_regs=("ksigma",))
    assert late[1][1] == (100, 0, 1)
    assert late[1][0] == expected(frames[1], 100, 0)
