"""The detection gateware in the Amaranth simulator against the golden model.

The broad bit-exactness campaign runs on Verilator (``cocotb_tests/test_detector.py``); these
are the block-level checks: random frames at random capacities, record order and trailer
fields, a slow record reader, truncated frames and line errors, register refusal and its
clearing, lost trailers."""

import numpy as np
import pytest

from lodestar import contract as C
from lodestar.golden import DetectorConfig, detect_frame
from lodestar.hdl.detector import Detector, min_vblank
from tests.hdl.bench import frame_stamp, stream_frames


def frame_of(mask, rng, bits=12):
    fs = C.full_scale(bits)
    return np.where(mask, rng.integers(51, fs + 1, size=mask.shape),
                    rng.integers(0, 51, size=mask.shape)).astype(np.uint16)


def golden_trailer(res, counter, index=None):
    """The trailer of frame ``counter``, streamed as frame ``index`` (default: the counter;
    the bench's timestamp of that frame)."""
    head = res.header()
    head["frame_counter"] = counter
    head["timestamp"] = frame_stamp(counter if index is None else index)
    return {k: head[k] for k in ("mode", "frame_counter", "timestamp", "flags", "threshold",
                                 "background", "n_blobs", "n_filtered", "dropped_records",
                                 "dropped_labels", "n_records")}


def trailer_fields(t):
    return {k: v for k, v in t.items() if k != "records"}


@pytest.mark.parametrize("seed", [0, 1] + [pytest.param(s, marks=pytest.mark.slow)
                                          for s in (2, 3)])
def test_random_frames_random_capacities(seed):
    """Five random geometries and capacities per seed, four frames each, in the Amaranth
    simulator (two seeds by default, four with --runslow; the broad random campaign is
    Verilated, ``cocotb_tests/test_detector.py``)."""
    rng = np.random.default_rng(seed)
    for _ in range(5):
        h, w = int(rng.integers(1, 9)), int(rng.integers(3, 10))
        cap = int(rng.integers(1, C.max_open_blobs(w) + 1))
        rcap = int(rng.integers(1, 8))
        frames = [frame_of(rng.random((h, w)) < d, rng) for d in (0.2, 0.45, 0.6, 0.8)]
        regs = [dict(threshold=50, background=40, min_pixels=int(rng.integers(1, 3)))] + \
            [{}] * 3
        cfg = DetectorConfig(width=w, height=h, threshold=50, background=40,
                             min_pixels=regs[0]["min_pixels"], label_capacity=cap,
                             record_capacity=rcap)
        _, trailers, pending = stream_frames(Detector(w, h, 12, cap, rcap), frames, regs)
        assert pending == [] and len(trailers) == len(frames)
        for i, (frame, t) in enumerate(zip(frames, trailers)):
            res = detect_frame(frame, cfg)
            assert t["records"] == list(res.blobs)
            assert trailer_fields(t) == golden_trailer(res, i)


def test_slow_reader_loses_nothing_it_does_not_count():
    rng = np.random.default_rng(7)
    frames = [frame_of(rng.random((6, 8)) < 0.3, rng) for _ in range(3)]
    regs = [dict(threshold=50, background=40)] + [{}] * 2
    dut = Detector(8, 6, 12, record_capacity=16, record_depth=2)
    _, trailers, pending = stream_frames(dut, frames, regs,
                                         record_ready=lambda cycle: cycle % 7 == 0)
    cfg = DetectorConfig(width=8, height=6, threshold=50, background=40)
    lost = 0
    for frame, t in zip(frames, trailers):
        res = detect_frame(frame, cfg)
        assert t["n_records"] + t["dropped_records"] == len(res.blobs)
        assert bool(t["flags"] & C.FRAME_RECORD_OVERFLOW) == (t["dropped_records"] > 0)
        assert all(r in res.blobs for r in t["records"])
        lost += t["dropped_records"]
    assert lost > 0 and pending == []


def test_truncated_frame_and_line_error_recover_next_frame():
    rng = np.random.default_rng(3)
    h, w = 6, 7
    frames = [frame_of(rng.random((h, w)) < 0.5, rng) for _ in range(4)]
    regs = [dict(threshold=50, background=40)] + [{}] * 3
    # frame 0 stops after 2.5 rows, frame 2 after 4 rows plus 3 pixels
    _, trailers, _ = stream_frames(Detector(w, h, 12), frames, regs,
                                   stop_after={0: 2 * w + 3, 2: 4 * w + 3})
    cfg = DetectorConfig(width=w, height=h, threshold=50, background=40)
    assert [t["flags"] & C.FRAME_TRUNCATED for t in trailers] == \
        [C.FRAME_TRUNCATED, 0, C.FRAME_TRUNCATED, 0]
    for i in (1, 3):
        res = detect_frame(frames[i], cfg)
        assert trailers[i]["records"] == list(res.blobs)
        assert trailer_fields(trailers[i]) == golden_trailer(res, i)


def test_local_frame_cut_early_says_its_tail_was_dropped():
    """Local mode: frame 1 stops mid-row, so its last pixels wait in the threshold unit's
    delay line until frame 2's sof discards them: frame 1's trailer says
    ``FRAME_TAIL_DROPPED`` (and ``FRAME_TRUNCATED``).  Frame 3 stops at a row end, where the
    delay line empties by itself: ``FRAME_TRUNCATED`` only.  Frame 5 stops after 2 pixels,
    none of which came out: it has no trailer, and frame 6's says ``FRAME_TAIL_DROPPED``
    (frame 6 is otherwise exact).  The complete frames are exact, without the flag."""
    rng = np.random.default_rng(21)
    h, w, lg = 5, 9, 2
    frames = [frame_of(rng.random((h, w)) < 0.4, rng) for _ in range(7)]
    regs = [dict(mode=C.MODE_LOCAL, local_log2_window=lg, local_offset=30)] + [{}] * 6
    _, trailers, pending = stream_frames(
        Detector(w, h, 12), frames, regs, stop_after={1: 2 * w + 5, 3: 3 * w, 5: 2},
        vblank=min_vblank(w, h, 12, C.MODE_LOCAL, lg))
    flags = [t["flags"] & (C.FRAME_TRUNCATED | C.FRAME_TAIL_DROPPED) for t in trailers]
    assert flags == [0, C.FRAME_TRUNCATED | C.FRAME_TAIL_DROPPED, 0, C.FRAME_TRUNCATED, 0,
                     C.FRAME_TAIL_DROPPED]
    cfg = DetectorConfig(width=w, height=h, threshold_mode="local", local_log2_window=lg,
                         local_offset=30)
    for i, t in ((0, trailers[0]), (2, trailers[2]), (4, trailers[4]), (6, trailers[5])):
        res = detect_frame(frames[i], cfg)
        assert t["records"] == list(res.blobs)
        want = golden_trailer(res, t["frame_counter"], i)
        want["flags"] |= t["flags"] & C.FRAME_TAIL_DROPPED
        assert trailer_fields(t) == want
    assert [t["frame_counter"] for t in trailers] == [0, 1, 2, 3, 4, 5] and pending == []


def test_short_horizontal_blanking_is_flagged():
    rng = np.random.default_rng(4)
    frames = [frame_of(rng.random((5, 6)) < 0.6, rng) for _ in range(2)]
    regs = [dict(threshold=50, background=40), {}]
    _, trailers, _ = stream_frames(Detector(6, 5, 12), frames, regs, hblank=0)
    assert all(t["flags"] & C.FRAME_LINE_ERROR for t in trailers)


def test_refused_register_write_keeps_value():
    rng = np.random.default_rng(5)
    frames = [frame_of(rng.random((4, 5)) < 0.5, rng, bits=10)]
    # threshold above 10-bit full scale is refused: the reset threshold (120) stays
    regs = [dict(threshold=4000, background=40)]
    _, trailers, _ = stream_frames(Detector(5, 4, 10), frames, regs)
    assert trailers[0]["threshold"] == C.REGISTER_BY_NAME["threshold"].reset


def test_lost_trailer_keeps_later_packets_in_step():
    """A reader that reads like the packetizer (a trailer, then its records) and takes no
    trailer until the third frame has ended: frame 1's trailer finds frame 0's still held
    and is lost; frame 1's records are discarded, and frames 0, 2 and 3 each get exactly
    their own records."""
    rng = np.random.default_rng(11)
    h, w = 5, 8
    frames = [frame_of(rng.random((h, w)) < 0.35, rng) for _ in range(4)]
    regs = [dict(threshold=50, background=40)] + [{}] * 3
    frame_clocks = h * (w + 1) + w + 8
    status = {}
    _, trailers, pending = stream_frames(
        Detector(w, h, 12), frames, regs, trailer_first=True, status=status,
        trailer_ready=lambda cycle: cycle > 2 * frame_clocks + 10)
    cfg = DetectorConfig(width=w, height=h, threshold=50, background=40)
    assert [t["frame_counter"] for t in trailers] == [0, 2, 3]
    assert status["trailer_lost"] == 1 and pending == []
    for t in trailers:
        res = detect_frame(frames[t["frame_counter"]], cfg)
        assert len(res.blobs) > 0
        assert t["records"] == list(res.blobs)
        assert trailer_fields(t) == golden_trailer(res, t["frame_counter"])


def test_register_error_is_cleared_through_the_detector():
    from amaranth.sim import Simulator

    dut = Detector(5, 4, 10)
    seen = []

    async def bench(ctx):
        ctx.set(dut.reg_addr, C.REGISTER_BY_NAME["threshold"].address)
        ctx.set(dut.reg_data, 4000)                 # above 10-bit full scale: refused
        ctx.set(dut.reg_en, 1)
        await ctx.tick()
        ctx.set(dut.reg_en, 0)
        await ctx.tick().repeat(2)
        seen.append(ctx.get(dut.reg_error))         # sticky
        ctx.set(dut.reg_error_clear, 1)
        await ctx.tick()
        ctx.set(dut.reg_error_clear, 0)
        await ctx.tick()
        seen.append(ctx.get(dut.reg_error))
        ctx.set(dut.reg_data, 300)                  # a valid write leaves it clear
        ctx.set(dut.reg_en, 1)
        await ctx.tick()
        ctx.set(dut.reg_en, 0)
        await ctx.tick()
        seen.append(ctx.get(dut.reg_error))

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    sim.run()
    assert seen == [1, 0, 0]
