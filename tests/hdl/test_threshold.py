"""The threshold unit in the Amaranth simulator against the contract's levels."""

import numpy as np
import pytest
from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.hdl.threshold import (
    LOCAL_LATENCY,
    LocalWindow,
    ThresholdUnit,
    global_cycles,
    ksigma_cycles,
    local_blanking,
    local_sum_bits,
)
from tests.hdl.streams import stream_collect, stream_idle, stream_put


def run_frames(dut, frames, regs, gap, late_regs=()):
    """Stream ``frames`` (list of uint16 arrays) with ``gap`` idle clocks before each;
    ``regs`` (one dict per frame) are written at the start of the gap, as the MCU does
    between frames, except the names in ``late_regs``, written just before the frame.
    Returns per frame the output pixels as (x, y, lit, weight, eof) and the latched
    (T, B, fallback)."""
    levels, beats = [], []

    async def bench(ctx):
        for frame, reg in zip(frames, regs):
            for name, value in reg.items():
                if name not in late_regs:
                    ctx.set(getattr(dut, name), value)
            await stream_idle(ctx, dut.pixels, gap)
            for name in late_regs:
                ctx.set(getattr(dut, name), reg[name])
            h, w = frame.shape
            for k in range(h * w):
                y, x = divmod(k, w)
                await stream_put(ctx, dut.pixels, {"data": int(frame[y, x]), "sof": int(k == 0),
                                                   "eol": int(x == w - 1)})
            await stream_idle(ctx, dut.pixels, 1)
            levels.append((ctx.get(dut.frame_threshold), ctx.get(dut.frame_background),
                           ctx.get(dut.frame_fallback)))
        await ctx.tick()                  # the last beat's transfer

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    stream_collect(sim, dut.out, beats,
                   lambda o: (o.x, o.y, o.lit, o.weight, o.eof))
    sim.run()
    # fixed and global mode: one beat per pixel
    assert len(beats) == sum(frame.size for frame in frames)
    results = []
    for frame, frame_levels in zip(frames, levels):
        results.append((beats[:frame.size], frame_levels))
        del beats[:frame.size]
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


@pytest.mark.parametrize("pixel_bits", [8, 16])
def test_global_levels_at_the_arithmetic_bounds(pixel_bits):
    """Frames at the ends of the statistics' ranges (full scale everywhere, the largest
    variance, one lit pixel) with the largest ksigma, and a ksigma (240) for which D exceeds
    full scale while ``B + D mod 2**pixel_bits`` does not (T must still saturate)."""
    w, h = 5, 3
    fs = C.full_scale(pixel_bits)
    kmax = (1 << C.KSIGMA_BITS) - 1
    checker = (np.indices((h, w)).sum(axis=0) % 2) * fs
    one = np.zeros((h, w))
    one[1, 2] = fs
    frames = [np.full((h, w), fs), checker, one, 1 - checker // fs, checker, one]
    frames = [f.astype(np.uint16) for f in frames]
    ksigmas = [kmax] * 5 + [240]
    regs = [dict(mode=C.MODE_GLOBAL, threshold=3, background=1, ksigma=k) for k in ksigmas]
    results = run_frames(ThresholdUnit(w, h, pixel_bits), frames, regs,
                         gap=global_cycles(w, h, pixel_bits))
    for prev, reg, (_, levels) in zip(frames, regs[1:], results[1:]):
        p64 = prev.astype(np.int64)
        want = C.global_levels(p64.size, int(p64.sum()), int((p64 * p64).sum()),
                               reg["ksigma"], pixel_bits)
        assert levels == (*want, 0)


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


# ---- local mode -----------------------------------------------------------------------


def run_clocks(dut, steps, tail):
    """Drive ``steps`` (one ``(registers, pixel)`` per clock: a dict of register values to
    write or None, and ``(data, sof, eol)`` or None for an idle clock), then ``tail`` idle
    clocks.  Returns the output beats as ``(clock, x, y, data, lit, weight, eof)``, the clock
    being the index of the step whose edge produced it (fixed mode: the pixel's own step),
    and per ``sof`` the latched status as a dict."""
    beats, status = [], []
    names = ("frame_threshold", "frame_background", "frame_fallback",
             "frame_local_fallback", "frame_tail_dropped")

    async def bench(ctx):
        for k, (regs, px) in enumerate(steps + [(None, None)] * tail):
            for name, value in (regs or {}).items():
                ctx.set(getattr(dut, name), value)
            if px is None:
                await stream_idle(ctx, dut.pixels, 1)
            else:
                await stream_put(ctx, dut.pixels, dict(zip(("data", "sof", "eol"), px)))
            if ctx.get(dut.out.valid):
                o = dut.out.payload
                beats.append((k, ctx.get(o.x), ctx.get(o.y), ctx.get(o.data), ctx.get(o.lit),
                              ctx.get(o.weight), ctx.get(o.eof)))
            if px is not None and px[1]:
                status.append({name: ctx.get(getattr(dut, name)) for name in names})

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    sim.run()
    return beats, status


def frame_steps(frame, regs, gap, hblank=0):
    """Steps of one frame: ``gap`` idle clocks (the registers written on the first, or on the
    ``sof`` clock if there is no gap), then the rows with ``hblank`` idle clocks after each."""
    h, w = frame.shape
    steps = [(None, None)] * gap
    for y in range(h):
        for x in range(w):
            steps.append((None, (int(frame[y, x]), int(x == 0 and y == 0), int(x == w - 1))))
        steps += [(None, None)] * hblank
    steps[0] = (regs, steps[0][1])
    return steps


def local_beats(frame, log2_window, offset, pixel_bits):
    """Expected ``(x, y, data, lit, weight, eof)`` of a local-mode frame, straight from the
    contract's formula (``local_window_start``, L + 1 columns minus the pixel itself)."""
    h, w = frame.shape
    fs = C.full_scale(pixel_bits)
    out = []
    for y in range(h):
        row = [int(v) for v in frame[y]]
        for x in range(w):
            s = C.local_window_start(x, w, log2_window)
            mean = (sum(row[s:s + (1 << log2_window) + 1]) - row[x]) >> log2_window
            t = min(mean + offset, fs)
            out.append((x, y, row[x], int(row[x] > t), max(row[x] - mean, 0),
                        int(x == w - 1 and y == h - 1)))
    return out


def frame_beats(frame, t, b):
    """Expected beats of a fixed- or global-mode frame with levels ``(t, b)``."""
    return [(x, y, d, lit, wt, eof) for (x, y, lit, wt, eof), d in
            zip(expected(frame, t, b), frame.ravel().tolist())]


def star_frame(rng, h, w, pixel_bits):
    """A dim noisy background with bright pixels and a slope along the rows."""
    fs = C.full_scale(pixel_bits)
    base = rng.integers(0, fs // 16 + 1, (h, w)) + np.linspace(0, fs // 4, w).astype(int)
    spikes = rng.random((h, w)) < 0.15
    frame = np.where(spikes, rng.integers(0, fs + 1, (h, w)), base)
    return np.minimum(frame, fs).astype(np.uint16)


@pytest.mark.parametrize("pixel_bits,width,windows,hblank", [
    (10, 3, (1, 1, 1), 0),          # L = 2, frame just wider than the window
    (12, 5, (2, 1, 2), 2),
    (10, 129, (7, 7, 3), 0),        # L = 128, frame just wider than the window
    (12, 300, (7, 1, 5, 6), 3),
    (12, 300, (4, 7, 2), 0),
])
def test_local_mode_matches_contract(pixel_bits, width, windows, hblank):
    """Back-to-back frames at the minimum blanking, random registers per frame."""
    h = 3
    fs = C.full_scale(pixel_bits)
    rng = np.random.default_rng(width * pixel_bits + hblank)
    steps, want, prev = [], [], None
    for k, lg in enumerate(windows):
        frame = star_frame(rng, h, width, pixel_bits)
        # the last frame's offset exceeds full scale (the register has 16 bits): T = fs
        offset = int(rng.integers(0, fs // 4)) if k < len(windows) - 1 else \
            (1 << C.REGISTER_BY_NAME["local_offset"].bits) - 1
        regs = dict(mode=C.MODE_LOCAL, local_log2_window=lg, local_offset=offset,
                    threshold=int(rng.integers(0, fs + 1)), background=0)
        steps += frame_steps(frame, regs, local_blanking(prev) if prev else 1, hblank)
        want.append(local_beats(frame, lg, offset, pixel_bits))
        prev = lg
    beats, status = run_clocks(ThresholdUnit(width, h, pixel_bits), steps,
                               local_blanking(prev))
    assert [b[1:] for b in beats] == [b for frame in want for b in frame]
    assert [s["frame_tail_dropped"] for s in status] == [0] * len(windows)
    assert [s["frame_local_fallback"] for s in status] == [0] * len(windows)
    assert status[-1]["frame_threshold"] == fs and status[-1]["frame_background"] == 0


def test_local_window_alone():
    """The delay line by itself, given each pixel's running S1 as the unit's statistics
    give it: every pixel comes out once, in raster order, with the mean of its window's
    other L pixels, and nothing is pending after the blanking."""
    w, h, pb, lg = 12, 3, 10, 2
    frame = star_frame(np.random.default_rng(5), h, w, pb)
    dut = LocalWindow(w, h, pb)
    mask = (1 << local_sum_bits(w, pb)) - 1
    beats, pending = [], []

    async def bench(ctx):
        ctx.set(dut.log2_window, lg)
        s1 = 0
        for k, p in enumerate(frame.ravel().tolist()):
            y, x = divmod(k, w)
            ctx.set(dut.start, int(k == 0))
            await stream_put(ctx, dut.pixels, {
                "data": p, "x": x, "y": y, "sof": int(k == 0), "eof": int(k == w * h - 1),
                "row_end": int(x == w - 1), "sum_before": s1 & mask,
                "sum_after": (s1 + p) & mask})
            s1 += p
        ctx.set(dut.start, 0)
        await stream_idle(ctx, dut.pixels, local_blanking(lg))
        pending.append(ctx.get(dut.pending))

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    stream_collect(sim, dut.out, beats, lambda o: (o.x, o.y, o.data, o.mean, o.eof))
    sim.run()
    want = [(x, y, d, eof) for x, y, d, _, _, eof in local_beats(frame, lg, 0, pb)]
    assert [(x, y, d, eof) for x, y, d, _, eof in beats] == want
    means = [(sum(row[C.local_window_start(x, w, lg):][:(1 << lg) + 1]) - row[x]) >> lg
             for row in frame.astype(int).tolist() for x in range(w)]
    assert [b[3] for b in beats] == means
    assert pending == [0]


def test_local_latency_and_drain():
    """Pixel x leaves L + LOCAL_LATENCY clocks after it enters (rows without gaps), the
    frame's last beat L + LOCAL_LATENCY clocks after the last pixel, with no more input."""
    w, h, pb, lg = 40, 3, 12, 4
    frame = star_frame(np.random.default_rng(9), h, w, pb)
    steps = frame_steps(frame, dict(mode=C.MODE_LOCAL, local_log2_window=lg,
                                    local_offset=50), gap=0)
    beats, _ = run_clocks(ThresholdUnit(w, h, pb), steps, tail=3 * w)
    # the step index of a fixed-mode beat is its pixel's: local beats come later by
    assert [b[0] for b in beats] == [k + (1 << lg) + LOCAL_LATENCY - 1 for k in range(w * h)]
    assert beats[-1][6] == 1 and len(beats) == w * h


def test_local_blanking_is_sufficient_and_tight():
    w, h, pb, lg = 20, 3, 10, 3
    rng = np.random.default_rng(11)
    frames = [star_frame(rng, h, w, pb) for _ in range(2)]
    regs = dict(mode=C.MODE_LOCAL, local_log2_window=lg, local_offset=30)
    want = [local_beats(f, lg, 30, pb) for f in frames]
    for gap in (local_blanking(lg), local_blanking(lg) - 1):
        steps = frame_steps(frames[0], regs, 1) + frame_steps(frames[1], regs, gap)
        beats, status = run_clocks(ThresholdUnit(w, h, pb), steps, local_blanking(lg))
        got = [b[1:] for b in beats]
        if gap == local_blanking(lg):
            assert got == want[0] + want[1] and status[1]["frame_tail_dropped"] == 0
        else:   # the first frame's last beat is discarded, the second frame is intact
            assert got == want[0][:-1] + want[1] and status[1]["frame_tail_dropped"] == 1


def test_mode_changes_between_frames():
    """local -> fixed -> global -> local -> global, at the minimum blanking; the global
    levels come from the previous frame whatever its mode."""
    w, h, pb = 24, 4, 12
    rng = np.random.default_rng(12)
    gc = global_cycles(w, h, pb)
    plan = [dict(mode=C.MODE_LOCAL, local_log2_window=3, local_offset=40),
            dict(mode=C.MODE_FIXED, threshold=900, background=100),
            dict(mode=C.MODE_GLOBAL, threshold=10, background=5),
            dict(mode=C.MODE_LOCAL, local_log2_window=4, local_offset=0),
            dict(mode=C.MODE_GLOBAL, threshold=10, background=5),
            dict(mode=C.MODE_LOCAL, local_log2_window=1, local_offset=7)]
    steps, want, prev = [], [], None
    for regs in plan:
        frame = star_frame(rng, h, w, pb)
        regs = dict(dict(threshold=0, background=0, ksigma=40, local_log2_window=1,
                         local_offset=0), **regs)
        steps += frame_steps(frame, regs, gc + 1 if prev is not None else 1)
        if regs["mode"] == C.MODE_LOCAL:
            want += local_beats(frame, regs["local_log2_window"], regs["local_offset"], pb)
        elif regs["mode"] == C.MODE_GLOBAL:
            p64 = prev.astype(np.int64)
            t, b = C.global_levels(p64.size, int(p64.sum()), int((p64 * p64).sum()),
                                   regs["ksigma"], pb)
            want += frame_beats(frame, t, b)
        else:
            want += frame_beats(frame, regs["threshold"], regs["background"])
        prev = frame
    beats, status = run_clocks(ThresholdUnit(w, h, pb), steps, gc)
    assert [b[1:] for b in beats] == want
    assert [s["frame_fallback"] for s in status] == [0] * len(plan)
    assert [s["frame_tail_dropped"] for s in status] == [0] * len(plan)
    # the fixed frame keeps its one-clock latency right after the local frame
    assert beats[w * h][0] == (1 + w * h) + (gc + 1)


def test_ksigma_written_during_the_computation_is_used_after_ksigma_cycles():
    """ksigma rewritten while B is searched, while D is searched (the search restarts), on
    the computation's last clocks and after it: a frame starting global_cycles after the
    last pixel and ksigma_cycles after the write gets the levels of the new ksigma."""
    w, h, pb = 6, 4, 12
    rng = np.random.default_rng(17)
    frames = [rng.integers(0, 4096, (h, w)).astype(np.uint16) for _ in range(2)]
    gc, kc = global_cycles(w, h, pb), ksigma_cycles(w, h, pb)
    p64 = frames[0].astype(np.int64)
    stats = (p64.size, int(p64.sum()), int((p64 * p64).sum()))
    old, new = C.global_levels(*stats, 48, pb), C.global_levels(*stats, 20, pb)
    assert old != new
    regs = dict(mode=C.MODE_GLOBAL, threshold=100, background=0, ksigma=48)
    for written in (1, 2, gc // 3, 2 * gc // 3, gc - 2, gc - 1, gc, gc + 3):
        steps = frame_steps(frames[0], regs, 1)
        last = len(steps) - 1                   # the first frame's last pixel
        start = max(last + gc, last + written + kc)
        steps += [(None, None)] * (start - len(steps))
        steps[last + written] = (dict(ksigma=20), None)
        steps += frame_steps(frames[1], {}, 0)
        _, status = run_clocks(ThresholdUnit(w, h, pb), steps, 1)
        got = (status[1]["frame_threshold"], status[1]["frame_background"],
               status[1]["frame_fallback"])
        assert got == (*new, 0), written


def test_local_fixed_frame_right_after_local_frame_drops_the_tail_only():
    w, h, pb = 16, 2, 10
    rng = np.random.default_rng(13)
    frames = [star_frame(rng, h, w, pb) for _ in range(2)]
    local = dict(mode=C.MODE_LOCAL, local_log2_window=2, local_offset=20)
    fixed = dict(mode=C.MODE_FIXED, threshold=300, background=50)
    steps = frame_steps(frames[0], local, 1) + frame_steps(frames[1], fixed, 0)
    beats, status = run_clocks(ThresholdUnit(w, h, pb), steps, 10)
    got = [b[1:] for b in beats]
    kept = len(got) - w * h
    assert 0 < kept < w * h and got[:kept] == local_beats(frames[0], 2, 20, pb)[:kept]
    assert got[kept:] == frame_beats(frames[1], 300, 50)
    assert [b[0] for b in beats[kept:]] == list(range(1 + w * h, 1 + 2 * w * h))
    assert status[1]["frame_tail_dropped"] == 1


@pytest.mark.parametrize("log2_window", [0, 3, 4])
def test_local_falls_back_when_the_window_is_not_narrower_than_the_frame(log2_window):
    w, h, pb = 8, 3, 12
    frame = star_frame(np.random.default_rng(14), h, w, pb)
    regs = dict(mode=C.MODE_LOCAL, local_log2_window=log2_window, local_offset=5,
                threshold=700, background=40)
    beats, status = run_clocks(ThresholdUnit(w, h, pb), frame_steps(frame, regs, 1), 0)
    assert [b[1:] for b in beats] == frame_beats(frame, 700, 40)
    assert status[0]["frame_local_fallback"] == 1
    assert (status[0]["frame_threshold"], status[0]["frame_background"]) == (700, 40)


def test_local_recovers_from_truncated_frames_and_bad_lines():
    """A frame cut mid-row, then a frame with a short and a long line, then a clean frame:
    nothing hangs, every beat of the bad frames carries the input's count of positions, and
    the clean frame is exact with no stale beat before it."""
    w, h, pb, lg = 12, 3, 12, 2
    rng = np.random.default_rng(15)
    regs = dict(mode=C.MODE_LOCAL, local_log2_window=lg, local_offset=25)
    cut = frame_steps(star_frame(rng, h, w, pb), regs, 1)[:1 + w + 5]   # row 1 stops at 5
    bad = []                    # lines of 7, 12 and 17 pixels, eol on each
    for y, n in enumerate((7, 12, 17)):
        bad += [(None, (int(v), int(y == 0 and x == 0), int(x == n - 1)))
                for x, v in enumerate(rng.integers(0, 4096, n))]
    clean = star_frame(rng, h, w, pb)
    steps = cut + [(None, None)] * 50 + bad + [(None, None)] * local_blanking(lg) + \
        frame_steps(clean, regs, 0)
    beats, status = run_clocks(ThresholdUnit(w, h, pb), steps, local_blanking(lg))
    got = [b[1:] for b in beats]
    # the cut frame: its complete row and the part of row 1 that was ready (5 - L pixels)
    # leave; its last L pixels wait and are discarded by the next sof
    first = w + 5 - (1 << lg)
    assert [g[:2] for g in got[:first]] == [divmod(k, w)[::-1] for k in range(first)]
    assert status[1]["frame_tail_dropped"] == 1
    # the bad frame: positions as the input counts them (x wraps at W - 1 or an eol); it
    # ends at (W - 1, H - 1), in its last line: the line's last 5 pixels are in no frame
    counted, x, y = [], 0, 0
    for (_, (_, _, eol)) in bad:
        counted.append((x, y))
        if (x, y) == (w - 1, h - 1):
            break
        x, y = (0, y + 1) if x == w - 1 or eol else (x + 1, y)
    assert len(counted) == len(bad) - 5
    assert [g[:2] for g in got[first:first + len(counted)]] == counted
    assert got[first + len(counted) - 1][5] == 1 and status[2]["frame_tail_dropped"] == 0
    assert got[first + len(counted):] == local_beats(clean, lg, 25, pb)


def test_sof_mid_frame_restarts_positions_in_fixed_mode():
    w, h, pb = 6, 4, 10
    rng = np.random.default_rng(16)
    frames = [rng.integers(0, 1024, (h, w)).astype(np.uint16) for _ in range(2)]
    regs = dict(mode=C.MODE_FIXED, threshold=500, background=30)
    steps = frame_steps(frames[0], regs, 1)[:1 + 2 * w + 3] + frame_steps(frames[1], regs, 0)
    beats, _ = run_clocks(ThresholdUnit(w, h, pb), steps, 1)
    assert [b[1:] for b in beats[2 * w + 3:]] == frame_beats(frames[1], 500, 30)
