"""The MT9P031 parallel front end in the Amaranth simulator: a sensor model drives whole frames
with line and frame blanking on its own PIXCLK; the sync-side stream must equal the frames
exactly (pixels, sof, eol), at several clock ratios; a too-slow sync clock raises the sticky
overflow flag, the broken frame is delivered only as a clean prefix, the next frame is exact.
The frame watchdog completes a frame the sensor stops sending.  (The capture registers are
the board's pin flip-flops: ``tests/hdl/test_boards.py``.)"""

import gc
import warnings

import numpy as np
import pytest
from amaranth import ClockDomain, Module
from amaranth.hdl import UnusedElaboratable
from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.hdl.frontend import FrameWatchdog
from lodestar.hdl.labeller import MIN_HBLANK
from lodestar.hdl.mt9p031 import PIXEL_BITS, MT9P031Frontend
from tests.hdl.streams import stream_collect

NS = 1e-9


def frame_samples(lines, hblank, vblank, fv_lead, fv_lag):
    """PIXCLK samples ``(d, line_valid, frame_valid)`` of one frame: ``vblank`` blank lines,
    FRAME_VALID up ``fv_lead`` clocks before the first line, lines separated by ``hblank``
    clocks with LINE_VALID low, FRAME_VALID down ``fv_lag`` clocks after the last line.  The
    data bus carries junk outside the valid pixels (the front end must ignore it)."""
    line_len = max(len(line) for line in lines)
    out = [(0xABC, 0, 0)] * (vblank * (line_len + hblank))
    out += [(0x123, 0, 1)] * fv_lead
    for k, line in enumerate(lines):
        if k:
            out += [(0x456, 0, 1)] * hblank
        out += [(int(p), 1, 1) for p in line]
    out += [(0x789, 0, 1)] * fv_lag
    return out


def expected_beats(lines):
    """The stream beats ``(data, sof, eol)`` a frame of ``lines`` must produce."""
    beats = []
    for k, line in enumerate(lines):
        for j, p in enumerate(line):
            beats.append((int(p), int(k == 0 and j == 0), int(j == len(line) - 1)))
    return beats


def split_frames(beats):
    """Beats grouped into frames at each sof (beats before the first sof form no frame)."""
    frames = []
    for b in beats:
        if b[1]:
            frames.append([])
        assert frames, f"beat {b} before any sof"
        frames[-1].append(b)
    return frames


def run(dut, segments, sync_period, tail=200, clear_at=None):
    """Drive ``segments`` = [(samples, pix_period_s)] on a testbench-made PIXCLK (pins change
    on the falling edge, sampled on the rising edge; after each segment PIXCLK keeps running
    with the pins idle) with ``sync`` at ``sync_period``.
    Returns the sync-side beats, the overflow flag after each segment, the final overflow
    flag and the peak FIFO level.  ``clear_at``: strobe overflow_clear after that segment."""
    top = Module()
    top.domains.pix = pix = ClockDomain("pix")
    top.domains.sync = ClockDomain("sync")
    top.submodules.dut = dut
    pixclk = pix.clk
    beats, flags, peak = [], [], [0]

    async def sensor(ctx):
        for n, (samples, period) in enumerate(segments):
            # PIXCLK runs on with the pins idle, long enough for the FIFO to drain
            idle = [(0, 0, 0)] * (2 + int(20 * sync_period / period))
            for d, lv, fv in samples + idle:
                ctx.set(dut.d, d)
                ctx.set(dut.line_valid, lv)
                ctx.set(dut.frame_valid, fv)
                await ctx.delay(period / 2)
                ctx.set(pixclk, 1)
                await ctx.delay(period / 2)
                peak[0] = max(peak[0], ctx.get(dut.fifo_level))
                ctx.set(pixclk, 0)
            flags.append(ctx.get(dut.overflow))
            if clear_at == n:
                ctx.set(dut.overflow_clear, 1)
                await ctx.delay(sync_period)
                ctx.set(dut.overflow_clear, 0)
        await ctx.delay(tail * sync_period)
        flags.append(ctx.get(dut.overflow))

    sim = Simulator(top)
    sim.add_clock(sync_period, phase=0.37 * sync_period)
    sim.add_testbench(sensor)
    stream_collect(sim, dut.out, beats, lambda p: (p.data, p.sof, p.eol))
    sim.run()
    return beats, flags, peak[0]


def random_lines(rng, width, height):
    fs = C.full_scale(PIXEL_BITS)
    frame = rng.integers(0, fs + 1, (height, width))
    frame[0, :2] = (0, fs)                             # extremes on the bus
    return [list(row) for row in frame]


@pytest.mark.parametrize("pix_ns,sync_ns", [(10, 10), (10, 7), (25, 10), (10.3, 10)])
def test_frames_exact_at_clock_ratios(pix_ns, sync_ns):
    w, h = 9, 5
    rng = np.random.default_rng(int(pix_ns * 10 + sync_ns))
    frames = [random_lines(rng, w, h) for _ in range(3)]
    frames[1][2] = frames[1][2][:6]                    # a short line passes through as it is
    segments = [(frame_samples(f, hblank=3, vblank=2, fv_lead=2, fv_lag=3), pix_ns * NS)
                for f in frames]
    dut = MT9P031Frontend(w, h)
    beats, flags, peak = run(dut, segments, sync_ns * NS)
    assert split_frames(beats) == [expected_beats(f) for f in frames]
    assert flags == [0, 0, 0, 0]
    assert peak <= 6                                   # the bound of the module docstring


def test_back_to_back_lines_and_frames():
    """Minimal blanking: one clock of LINE_VALID low between lines, FRAME_VALID low for one
    clock between frames, LINE_VALID high in the very first clock of FRAME_VALID."""
    w, h = 6, 3
    rng = np.random.default_rng(5)
    frames = [random_lines(rng, w, h) for _ in range(3)]
    samples = [(0, 0, 0)]                             # FRAME_VALID seen low once after reset
    for f in frames:
        samples += frame_samples(f, hblank=1, vblank=0, fv_lead=0, fv_lag=0) + [(0, 0, 0)]
    beats, flags, _ = run(MT9P031Frontend(w, h), [(samples, 10 * NS)], 10 * NS)
    assert split_frames(beats) == [expected_beats(f) for f in frames]
    assert flags == [0, 0]


def test_start_mid_frame_waits_for_frame_start():
    """Capture starting inside a frame (FRAME_VALID already high) delivers nothing of that
    frame: its beginning was missed, so the first beat is the next frame's sof."""
    w, h = 7, 4
    rng = np.random.default_rng(7)
    frames = [random_lines(rng, w, h) for _ in range(2)]
    first = frame_samples(frames[0], hblank=2, vblank=1, fv_lead=1, fv_lag=1)
    first = first[len(first) // 2:]                   # join in the middle of frame 0
    second = frame_samples(frames[1], hblank=2, vblank=1, fv_lead=1, fv_lag=1)
    beats, _, _ = run(MT9P031Frontend(w, h), [(first + second, 10 * NS)], 10 * NS)
    assert beats[0][1] == 1
    assert split_frames(beats) == [expected_beats(frames[1])]


def test_overflow_breaks_frame_and_recovers():
    """Frame 1 arrives with PIXCLK twice the sync clock: the FIFO overflows, the flag sticks,
    frame 1 is delivered only as a prefix (never shifted), frames 0 and 2 are exact; the
    flag stays up until the clear strobe."""
    w, h = 24, 3
    rng = np.random.default_rng(11)
    frames = [random_lines(rng, w, h) for _ in range(4)]
    seg = [(frame_samples(f, hblank=4, vblank=1, fv_lead=2, fv_lag=2), p * NS)
           for f, p in zip(frames, (10, 5, 10, 10))]
    beats, flags, _ = run(MT9P031Frontend(w, h), seg, 10 * NS, clear_at=2)
    got = split_frames(beats)
    assert flags == [0, 1, 1, 0, 0]                    # set in frame 1, cleared after frame 2
    assert len(got) == 4
    assert got[0] == expected_beats(frames[0])
    want1 = expected_beats(frames[1])
    assert 0 < len(got[1]) < len(want1) and got[1] == want1[:len(got[1])]
    assert got[2] == expected_beats(frames[2])
    assert got[3] == expected_beats(frames[3])


def test_geometry_outside_contract():
    with warnings.catch_warnings():       # the half-built component is never elaborated
        warnings.simplefilter("ignore", UnusedElaboratable)
        for w, h in ((C.MAX_WIDTH + 1, 10), (10, 0)):
            with pytest.raises(ValueError, match="outside the contract"):
                MT9P031Frontend(w, h)
        gc.collect()


# ---- FrameWatchdog ------------------------------------------------------------------------

def watchdog_run(w, h, beats, timeout):
    """Drive ``FrameWatchdog(w, h, 12, timeout)`` in ``sync`` with ``beats`` (``None`` = an
    idle clock, else ``(data, sof, eol)``) and then idle clocks until it has been quiet for
    ``2 * timeout + 2 * w * h``.  Returns the out beats with the clock each came out on, and
    the clocks at which ``stalled`` pulsed."""
    dut = FrameWatchdog(w, h, PIXEL_BITS, timeout)
    out, stalls = [], []
    tail = 2 * timeout + 2 * w * h + 4

    async def bench(ctx):
        for t, beat in enumerate(list(beats) + [None] * tail):
            ctx.set(dut.pixels.valid, beat is not None)
            if beat is not None:
                ctx.set(dut.pixels.payload, {"data": beat[0], "sof": beat[1], "eol": beat[2]})
            if ctx.get(dut.stalled):
                stalls.append(t)
            await ctx.tick()
            if ctx.get(dut.out.valid):
                o = dut.out.payload
                out.append((t, (ctx.get(o.data), ctx.get(o.sof), ctx.get(o.eol))))

    sim = Simulator(dut)
    sim.add_clock(10 * NS)
    sim.add_testbench(bench)
    sim.run()
    return out, stalls


def with_gaps(beats, hblank):
    """Beats with ``hblank`` idle clocks after each eol."""
    out = []
    for b in beats:
        out.append(b)
        if b[2]:
            out += [None] * hblank
    return out


def test_watchdog_passes_complete_frames_and_never_fires_between_frames():
    w, h, timeout = 5, 3, 20
    rng = np.random.default_rng(11)
    frames = [random_lines(rng, w, h) for _ in range(2)]
    beats = with_gaps(expected_beats(frames[0]), 3) + [None] * (5 * timeout)
    beats += with_gaps(expected_beats(frames[1]), timeout - 1)   # row gaps just below it
    out, stalls = watchdog_run(w, h, beats, timeout)
    assert stalls == []
    assert [b for _, b in out] == expected_beats(frames[0]) + expected_beats(frames[1])
    sent = [t for t, b in enumerate(beats) if b is not None]
    assert [t for t, _ in out] == sent                 # one register: no reordering, no gap


def test_watchdog_completes_a_stalled_frame_with_dark_pixels():
    """The sensor stops after 1.4 rows: after ``timeout`` idle clocks the frame is completed
    with dark pixels (eol on each row's last, ``MIN_HBLANK`` idle after it); a pixel that
    arrives while it pads is dropped; the next frame passes exactly."""
    w, h, timeout = 5, 4, 12
    rng = np.random.default_rng(3)
    first, second = random_lines(rng, w, h), random_lines(rng, w, h)
    sent = expected_beats(first)[:w + 2]
    beats = with_gaps(sent, 2) + [None] * timeout + [None, (77, 0, 0)]
    beats += [None] * (3 * w * h) + with_gaps(expected_beats(second), 2)
    out, stalls = watchdog_run(w, h, beats, timeout)
    assert len(stalls) == 1
    padded = [(0, 0, int(x == w - 1)) for y in range(1, h) for x in range(w)][2:]
    frames = split_frames([b for _, b in out])
    assert frames == [sent + padded, expected_beats(second)]
    pad_times = [t for t, b in out if t > stalls[0]][:len(padded)]
    gaps = np.diff(pad_times)
    assert set(gaps) <= {1, 1 + MIN_HBLANK} and sum(g > 1 for g in gaps) == h - 2
    assert pad_times[0] == stalls[0] + 1 and stalls[0] == len(with_gaps(sent, 2)) + timeout - 1


def test_watchdog_padding_ends_at_a_new_frame():
    """A sof while the watchdog pads ends the padding and passes through (the detector then
    ends the stalled frame FRAME_TRUNCATED)."""
    w, h, timeout = 6, 5, 8
    rng = np.random.default_rng(4)
    first, second = random_lines(rng, w, h), random_lines(rng, w, h)
    sent = expected_beats(first)[:3]
    beats = sent + [None] * (timeout + 4) + with_gaps(expected_beats(second), 1)
    out, stalls = watchdog_run(w, h, beats, timeout)
    frames = split_frames([b for _, b in out])
    assert len(stalls) == 1 and len(frames) == 2
    assert frames[0][:3] == sent and 3 < len(frames[0]) < w * h
    assert all(b[0] == 0 for b in frames[0][3:])
    assert frames[1] == expected_beats(second)
