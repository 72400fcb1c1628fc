"""The MT9V022 LVDS front end in the Amaranth simulator: a sensor model serializes whole frames
(embedded sync words, reserved-value substitution, line and frame blanking) into 12-bit
packets, delivered ``lanes`` bits per clock of a testbench-made ``ser`` clock.  Checked: exact
frames at several clock ratios and lane counts after a misaligned start, pixels near the
reserved values, both frame-end variants, a corrupted stop bit (counted, lock re-acquired,
next frame exact), a too-slow sync clock (overflow flagged, next frame exact), and phase
training on a skewed stream (eye found and centred, frames exact, retrained when the eye
moves)."""

import gc
import warnings

import numpy as np
import pytest
from amaranth import ClockDomain, Module
from amaranth.hdl import UnusedElaboratable
from amaranth.sim import Simulator

from lodestar.hdl.mt9v022 import (
    FRAME_END,
    FULL,
    LINE_END,
    LINE_START,
    LOCK_PACKETS,
    PACKET_BITS,
    PHASE_COUNTER_ALL,
    RESERVED_WORDS,
    MT9V022Frontend,
    PhaseStepper,
    PhaseTrainer,
    ReceiverPllReset,
    packet_bits,
)
from tests.hdl.streams import stream_collect

NS = 1e-9
BLANK = RESERVED_WORDS          # what the link carries between lines and frames (raw 0 -> 4)


def link_value(raw):
    """A raw pixel as the sensor puts it on the link: 0 .. 3 become 4."""
    return max(int(raw), RESERVED_WORDS)


def frame_words(frame, hblank=3, vblank=12, end_after_line_end=True):
    """Link words of one frame: vertical blanking, 1023 0 1023, then per line ``1``, the
    pixels, ``2``, horizontal blanking; the frame ends with ``3`` after the last line's ``2``
    (``end_after_line_end``) or in its place."""
    words = [BLANK] * vblank + [FULL, 0, FULL]
    for k, row in enumerate(frame):
        words += [LINE_START] + [link_value(p) for p in row]
        last = k == len(frame) - 1
        if last and not end_after_line_end:
            words += [FRAME_END]
        else:
            words += [LINE_END] + ([FRAME_END] if last else [])
        words += [BLANK] * hblank
    return words


def expected_beats(frame):
    return [(link_value(p), int(y == 0 and x == 0), int(x == len(row) - 1))
            for y, row in enumerate(frame) for x, p in enumerate(row)]


def split_frames(beats):
    frames = []
    for b in beats:
        if b[1]:
            frames.append([])
        assert frames, f"beat {b} before any sof"
        frames[-1].append(b)
    return frames


def random_frame(rng, width, height):
    """Random pixels biased to the edges of the value range: raw 0 .. 7 (0 .. 3 reserved),
    1016 .. 1023, and a raw 1023, 0, 1023 inside a line."""
    frame = rng.integers(0, FULL + 1, (height, width))
    edge = rng.random((height, width)) < 0.5
    near = np.where(rng.random((height, width)) < 0.5, rng.integers(0, 8, (height, width)),
                    rng.integers(FULL - 7, FULL + 1, (height, width)))
    frame = np.where(edge, near, frame)
    frame[1, 1:4] = (FULL, 0, FULL)
    return [list(row) for row in frame]


def to_bits(words, corrupt_stop=()):
    """Transmission-order bits of ``words``; the stop bit of each index in ``corrupt_stop``
    is flipped to 1."""
    bits = []
    for i, w in enumerate(words):
        pkt = packet_bits(w)
        if i in corrupt_stop:
            pkt[-1] = 1
        bits += pkt
    return bits


def run(dut, segments, sync_period, clear_at=None, idle_words=4):
    """Drive ``segments`` = [(bits, ser_period_s)] on a testbench-made ``ser`` clock,
    ``lanes`` bits per clock, earliest bit in the MSB; ``sync`` at ``sync_period``.  Returns
    the beats, the (overflow, locked, framing_errors) after each segment, and the peak FIFO
    level.  ``clear_at``: strobe overflow_clear after that segment; ``idle_words`` blanking
    words follow each segment (the link idles on)."""
    L = dut.lanes
    top = Module()
    top.domains.ser = ser = ClockDomain("ser")
    top.domains.sync = ClockDomain("sync")
    top.submodules.dut = dut
    beats, status, peak = [], [], [0]

    async def sensor(ctx):
        for n, (bits, period) in enumerate(segments):
            bits = bits + to_bits([BLANK] * idle_words)
            bits += [0] * (-len(bits) % L)
            for k in range(0, len(bits), L):
                ctx.set(dut.bits, sum(b << (L - 1 - j) for j, b in enumerate(bits[k:k + L])))
                await ctx.delay(period / 2)
                ctx.set(ser.clk, 1)
                await ctx.delay(period / 2)
                peak[0] = max(peak[0], ctx.get(dut.fifo_level))
                ctx.set(ser.clk, 0)
            await ctx.delay(30 * sync_period)          # let the FIFO drain, status settle
            status.append((ctx.get(dut.overflow), ctx.get(dut.locked),
                           ctx.get(dut.framing_errors)))
            if clear_at == n:
                ctx.set(dut.overflow_clear, 1)
                await ctx.delay(sync_period)
                ctx.set(dut.overflow_clear, 0)

    sim = Simulator(top)
    sim.add_clock(sync_period, phase=0.29 * sync_period)
    sim.add_testbench(sensor)
    stream_collect(sim, dut.out, beats, lambda p: (p.data, p.sof, p.eol))
    sim.run()
    return beats, status, peak[0]


@pytest.mark.parametrize("lanes,ser_ns,sync_ns,slip", [
    (1, 4, 10, 5),        # one bit per clock, sync 4.8x the pixel rate
    (1, 4, 48, 7),        # sync clock equal to the pixel clock
    (6, 20, 10, 3),       # ALTLVDS_RX J=6: ser = 2x pixel clock
    (6, 20, 37, 11),      # sync just faster than the 40 ns pixel clock
    (4, 12, 30, 1),
    (2, 8, 47.5, 8),
])
def test_frames_exact_after_misaligned_start(lanes, ser_ns, sync_ns, slip):
    """The link starts ``slip`` bits into a packet.  The blanking before frame 0 leaves two
    alignments; the first 1023 of the frame start rules out the false one before its own last
    bit, so lock comes in time and all frames are exact, with both frame-end variants."""
    w, h = 8, 4
    rng = np.random.default_rng(lanes * 100 + slip)
    frames = [random_frame(rng, w, h) for _ in range(4)]
    words = []
    for k, f in enumerate(frames):
        words += frame_words(f, end_after_line_end=bool(k % 2))
    bits = to_bits(words)[slip:]
    dut = MT9V022Frontend(w, h, lanes=lanes)
    beats, status, peak = run(dut, [(bits, ser_ns * NS)], sync_ns * NS)
    assert split_frames(beats) == [expected_beats(f) for f in frames]
    assert status == [(0, 1, 0)]
    assert peak <= 6                                   # hdl/mt9p031.py's bound


def test_start_mid_frame_waits_for_frame_start():
    """A link that comes up inside a frame (lock taken on its pixels) delivers nothing of it:
    lines outside a seen frame start are ignored; the next frame is exact."""
    w, h = 8, 5
    rng = np.random.default_rng(21)
    frames = [random_frame(rng, w, h) for _ in range(2)]
    first = frame_words(frames[0])
    bits = to_bits(first[len(first) // 2:] + frame_words(frames[1]))[7:]
    beats, status, _ = run(MT9V022Frontend(w, h, lanes=3), [(bits, 10 * NS)], 10 * NS)
    assert split_frames(beats) == [expected_beats(frames[1])]
    assert status == [(0, 1, 0)]


def test_corrupted_stop_bits_are_counted_and_lock_recovers():
    """A corrupted stop bit in frame 1 (mid-line) and one in the vertical blanking before
    frame 3: each is one framing error; frame 1 is delivered as a clean prefix ending before
    the pixel held for its eol, frames 0, 2 and 3 are exact (lock comes back on the same
    alignment after ``LOCK_PACKETS`` packets although the blanking is ambiguous)."""
    w, h = 10, 4
    rng = np.random.default_rng(3)
    frames = [random_frame(rng, w, h) for _ in range(4)]
    per_frame = [frame_words(f) for f in frames]
    start1 = len(per_frame[0])
    bad_pixel = 12 + 3 + (1 + w + 1 + 3) + 1 + 4       # frame 1, line 1, column 4
    bad_blank = start1 + len(per_frame[1]) + len(per_frame[2]) + 2
    words = sum(per_frame, [])
    assert words[start1 + bad_pixel] == link_value(frames[1][1][4])
    assert words[bad_blank] == BLANK
    bits = to_bits(words, corrupt_stop=(start1 + bad_pixel, bad_blank))
    beats, status, _ = run(MT9V022Frontend(w, h, lanes=6), [(bits, 20 * NS)], 10 * NS)
    got = split_frames(beats)
    assert len(got) == 4 and got[0] == expected_beats(frames[0])
    assert got[1] == expected_beats(frames[1])[:w + 3]         # up to the held pixel
    assert got[2:] == [expected_beats(frames[2]), expected_beats(frames[3])]
    assert status == [(0, 1, 2)]


def test_lock_needs_lock_packets_and_is_lost_on_error():
    """``locked`` rises only after ``LOCK_PACKETS`` well-framed packets and falls on a framing
    error; garbage (no start bits) never locks."""
    dut = MT9V022Frontend(4, 2, lanes=1)
    blank = to_bits([BLANK] * 3 + [FULL] * (LOCK_PACKETS + 1))
    seg_short = to_bits([FULL] * (LOCK_PACKETS - 2))
    _, status, _ = run(dut, [([0] * 200, 4 * NS), (seg_short, 4 * NS), (blank, 4 * NS)],
                       10 * NS, idle_words=0)
    assert [s[1] for s in status] == [0, 0, 1]
    assert all(s[2] == 0 for s in status)


def test_overflow_breaks_frame_and_recovers():
    """Frame 1 arrives with the pixel clock twice the sync clock: overflow flagged (sticky
    until cleared), frame 1 only a clean prefix, frames 2 and 3 exact."""
    w, h = 24, 3
    rng = np.random.default_rng(9)
    frames = [random_frame(rng, w, h) for _ in range(4)]
    seg = [(to_bits(frame_words(f)), p * NS) for f, p in zip(frames, (20, 5, 20, 20))]
    beats, status, _ = run(MT9V022Frontend(w, h, lanes=6), seg, 20 * NS, clear_at=2)
    got = split_frames(beats)
    assert [s[0] for s in status] == [0, 1, 1, 0]
    assert all(s[1:] == (1, 0) for s in status[1:])
    want1 = expected_beats(frames[1])
    assert len(got) == 4 and got[0] == expected_beats(frames[0])
    assert 0 < len(got[1]) < len(want1) and got[1] == want1[:len(got[1])]
    assert got[2:] == [expected_beats(frames[2]), expected_beats(frames[3])]


def test_bad_parameters():
    with warnings.catch_warnings():       # the half-built component is never elaborated
        warnings.simplefilter("ignore", UnusedElaboratable)
        with pytest.raises(ValueError, match="lanes must divide"):
            MT9V022Frontend(8, 4, lanes=5)
        with pytest.raises(ValueError, match="outside the contract"):
            MT9V022Frontend(0, 4)
        gc.collect()
    assert PACKET_BITS == 12


def test_receiver_pll_reset_waits_for_the_clock_and_retries():
    """``pll_areset`` stays high while the returned LVDS clock does not run, is released once
    it has run ``active_clocks``, is pulsed again (a retry, counted) when the PLL has not
    locked ``lock_timeout`` clocks later, stays low once locked, and rises when the clock
    stops."""
    dut = ReceiverPllReset(active_clocks=4, lock_timeout=10)
    top = Module()
    top.domains.osc = ClockDomain("osc", reset_less=True)
    top.submodules.dut = dut
    trace = []

    async def bench(ctx):
        toggle = 0
        # (clocks, the clock runs, locked): off; on without lock for two timeouts; locks;
        # stops
        for clocks, runs, locked in ((12, 0, 0), (40, 1, 0), (20, 1, 1), (12, 0, 1)):
            for _ in range(clocks):
                if runs:
                    toggle ^= 1
                ctx.set(dut.toggle, toggle)
                ctx.set(dut.locked, locked)
                await ctx.tick("osc")
                trace.append(ctx.get(dut.areset))
        trace.append(ctx.get(dut.retries))

    sim = Simulator(top)
    sim.add_clock(20e-9, domain="osc")
    sim.add_testbench(bench)
    sim.run()
    retries = trace.pop()
    levels = "".join(map(str, trace))
    assert levels[:12] == "1" * 12                     # no clock: held in reset
    on = levels[12:52]
    assert on.startswith("1111") and "0" * 10 in on    # released after 4 clocks of clock
    assert retries >= 2 and on.count("01") >= 2        # two timeouts: two retries
    assert levels[52:72].endswith("0" * 10)            # locked: released
    assert levels[-4:] == "1111"                       # the clock stopped


TAPS = 8


def run_skewed(dut, segments, ser_period, sync_period, rng):
    """Drive ``segments`` = [(bits, (first, width))] like :func:`run`, each bit sampled at
    the front end's ``tap``: correctly inside the eye (``width`` phases from ``first``,
    modulo ``TAPS``), at random outside it (a sample on the transition).  Returns the beats
    and after each segment (trained, eye_width, tap)."""
    L = dut.lanes
    top = Module()
    top.domains.ser = ser = ClockDomain("ser")
    top.domains.sync = ClockDomain("sync")
    top.submodules.dut = dut
    beats, status = [], []

    async def sensor(ctx):
        for bits, (first, width) in segments:
            bits = bits + [0] * (-len(bits) % L)
            for k in range(0, len(bits), L):
                inside = (ctx.get(dut.tap) - first) % TAPS < width
                chunk = [b if inside else int(rng.integers(2)) for b in bits[k:k + L]]
                ctx.set(dut.bits, sum(b << (L - 1 - j) for j, b in enumerate(chunk)))
                await ctx.delay(ser_period / 2)
                ctx.set(ser.clk, 1)
                await ctx.delay(ser_period / 2)
                ctx.set(ser.clk, 0)
            await ctx.delay(30 * sync_period)
            status.append((ctx.get(dut.trained), ctx.get(dut.eye_width), ctx.get(dut.tap)))

    sim = Simulator(top)
    sim.add_clock(sync_period, phase=0.29 * sync_period)
    sim.add_testbench(sensor)
    stream_collect(sim, dut.out, beats, lambda p: (p.data, p.sof, p.eol))
    sim.run()
    return beats, status


@pytest.mark.parametrize("eye,moved", [((2, 4), (6, 3)), ((6, 4), (1, 5))])
def test_phase_training_centres_the_eye_and_retrains(eye, moved):
    """On the blanking stream the trainer sweeps the phases, finds the eye (also one that
    wraps around the bit's edge) and samples at its centre; the frames after it are exact.
    The eye then moves off the sample point: the trainer sees no framed alignment, retrains
    on the blanking, centres the new eye, and the next frames are exact."""
    w, h = 8, 3
    rng = np.random.default_rng(eye[0])
    frames = [random_frame(rng, w, h) for _ in range(4)]
    dut = MT9V022Frontend(w, h, lanes=6, taps=TAPS)
    warmup, dwell = PhaseTrainer.timing(PACKET_BITS // 6)
    train_words = (TAPS * (warmup + dwell) + 2 * TAPS + 1) // 2 + 8     # 2 clocks a word
    lost_words = dwell // 2 + 8
    segments = [(to_bits([BLANK] * train_words), eye),
                (to_bits(frame_words(frames[0]) + frame_words(frames[1])), eye),
                (to_bits([BLANK] * (lost_words + train_words)), moved),
                (to_bits(frame_words(frames[2]) + frame_words(frames[3])), moved)]
    beats, status = run_skewed(dut, segments, 20 * NS, 10 * NS, rng)
    assert split_frames(beats) == [expected_beats(f) for f in frames]
    centre = [(first + width // 2) % TAPS for first, width in (eye, moved)]
    assert status == [(1, eye[1], centre[0]), (1, eye[1], centre[0]),
                      (1, moved[1], centre[1]), (1, moved[1], centre[1])]


def test_phase_trainer_bad_parameters():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnusedElaboratable)
        with pytest.raises(ValueError, match="taps >= 2"):
            PhaseTrainer(1, 2, "ser")
        with pytest.raises(ValueError, match="taps must be >= 1"):
            MT9V022Frontend(8, 4, taps=0)
        with pytest.raises(ValueError, match="taps >= 2 and timeout >= 2"):
            PhaseStepper(1)
        gc.collect()


def altpll_phase_shift(dut, low_clocks, log, dead=False):
    """A Cyclone IV ALTPLL's dynamic phase-shift side (PLL handbook, "Dynamic Phase
    Shifting"), as a background testbench in ``osc``: ``phasestep`` is latched at a clock; on the
    second clock after, ``phaseupdown`` and ``phasecounterselect`` are latched and
    ``phasedone`` falls; it rises ``low_clocks`` later with the phase moved one step.  Logs
    ``("step", up, counters)`` and every violation of the handshake: ``phasestep`` released
    before ``phasedone`` fell, still high when it rises (a second step), or the direction
    or counters changed while latched.  ``dead``: ``phasedone`` never falls."""
    async def process(ctx):
        ctx.set(dut.phasedone, 1)
        while True:
            await ctx.tick("osc")
            if not ctx.get(dut.phasestep):
                continue
            setting = (ctx.get(dut.phaseupdown), ctx.get(dut.phasecounterselect))
            for _ in range(2):
                await ctx.tick("osc")
                if not ctx.get(dut.phasestep):
                    log.append("released before phasedone fell")
            if (ctx.get(dut.phaseupdown), ctx.get(dut.phasecounterselect)) != setting:
                log.append("setting changed")
            if dead:
                while ctx.get(dut.phasestep):
                    await ctx.tick("osc")
                continue
            ctx.set(dut.phasedone, 0)
            for _ in range(low_clocks):
                await ctx.tick("osc")
            if ctx.get(dut.phasestep):
                log.append("phasestep high when phasedone rose")
            ctx.set(dut.phasedone, 1)
            log.append(("step",) + setting)
    return process


def run_stepper(dut, script, low_clocks=4, dead=False):
    """Drive ``dut`` (a :class:`PhaseStepper`) with ``script`` = [(tap, hold, clocks)];
    returns the model's log and, after each entry, (phase, timeouts, clocks until
    ``phase == tap`` or None)."""
    top = Module()
    top.domains.osc = ClockDomain("osc")
    top.submodules.dut = dut
    log, out = [], []

    async def bench(ctx):
        for tap, hold, clocks in script:
            ctx.set(dut.tap, tap)
            ctx.set(dut.hold, hold)
            reached = None
            for k in range(clocks):
                await ctx.tick("osc")
                if reached is None and ctx.get(dut.phase) == tap:
                    reached = k + 1
            out.append((ctx.get(dut.phase), ctx.get(dut.timeouts), reached))

    sim = Simulator(top)
    sim.add_clock(20e-9, domain="osc")
    sim.add_testbench(altpll_phase_shift(dut, low_clocks, log, dead), background=True)
    sim.add_testbench(bench)
    sim.run()
    return log, out


def test_phase_stepper_steps_to_each_tap_within_its_bound():
    """Each tap change is reached by (tap - phase) mod taps up-steps of all output counters,
    each one a clean handshake, within ``settle_clocks``; a hold returns the phase to 0."""
    dut = PhaseStepper(16, timeout=8)
    bound = dut.settle_clocks()
    script = [(5, 0, bound), (6, 0, bound), (2, 0, bound), (15, 0, bound), (0, 0, bound),
              (9, 1, 40), (9, 0, bound)]
    log, out = run_stepper(dut, script)
    steps = [e for e in log if isinstance(e, tuple)]
    assert [e for e in log if not isinstance(e, tuple)] == []
    assert set(steps) == {("step", 1, PHASE_COUNTER_ALL)}
    assert len(steps) == 5 + 1 + 12 + 13 + 1 + 9         # the hold: back to 0, then 9 steps
    assert [(p, t) for p, t, _ in out] == [(5, 0), (6, 0), (2, 0), (15, 0), (0, 0), (0, 0),
                                           (9, 0)]
    assert all(r is not None and r <= bound for tap, hold, r in
               ((s[0], s[1], o[2]) for s, o in zip(script, out)) if not hold)


def test_phase_stepper_never_hangs_on_a_silent_pll():
    """A PLL that never answers: every step gives up after its bound, is counted, and the
    stepper still reaches the tap (it never waits for ever)."""
    dut = PhaseStepper(8, timeout=6)
    log, out = run_stepper(dut, [(3, 0, dut.settle_clocks())], dead=True)
    assert out == [(3, 3, out[0][2])] and out[0][2] <= dut.settle_clocks()
    assert "released before phasedone fell" not in log
