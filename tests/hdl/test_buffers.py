"""The half-word record buffer: order, capacity, one item in per two clocks and out per
three, any reader; and the detector's claim that records come at most once per two
clocks."""

import random

import numpy as np
import pytest
from amaranth.sim import Simulator

from lodestar.golden import DetectorConfig, detect_frame
from lodestar.hdl.buffers import HalfWordFIFO
from lodestar.hdl.detector import Detector
from tests.hdl.bench import stream_frames


def run_fifo(width, depth, offers, ready):
    """Offer ``offers`` (None: no item) one per clock; ``ready(clock)`` drives ``r_en``.
    Returns (items taken by the buffer, items read, w_rdy seen while a write was pending)."""
    dut = HalfWordFIFO(width, depth)
    taken, read = [], []

    async def bench(ctx):
        for clock, item in enumerate(offers + [None] * (4 * depth + 8)):
            ctx.set(dut.w_en, item is not None)
            ctx.set(dut.w_data, item or 0)
            ctx.set(dut.r_en, ready(clock))
            if item is not None and ctx.get(dut.w_rdy):
                taken.append(item)
            if ready(clock) and ctx.get(dut.r_rdy):
                read.append(ctx.get(dut.r_data))
            await ctx.tick()

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    sim.run()
    return taken, read


@pytest.mark.parametrize("width,depth", [(345, 4), (7, 3), (2, 1)])
def test_items_come_out_whole_and_in_order(width, depth):
    rng = random.Random(width)
    offers = [rng.getrandbits(width) if k % 2 == 0 and rng.random() < 0.8 else None
              for k in range(60)]
    ready = [rng.random() < 0.4 for _ in range(len(offers) + 4 * depth + 8)]
    taken, read = run_fifo(width, depth, offers, ready.__getitem__)
    assert read == taken and len(taken) > depth


def test_holds_exactly_depth_items_and_streams_one_per_three_clocks():
    offers = [k + 1 if k % 2 == 0 else None for k in range(20)]     # one item per 2 clocks
    taken, read = run_fifo(9, 3, offers, lambda clock: clock >= 30)
    assert taken == [1, 3, 5] and read == taken                  # full after 3, no reader
    taken, read = run_fifo(9, 3, offers, lambda clock: True)
    assert taken == read and len(taken) < 10                     # an eager reader lags
    offers = [k + 1 if k % 3 == 0 else None for k in range(30)]     # one item per 3 clocks
    taken, read = run_fifo(9, 2, offers, lambda clock: True)
    assert taken == read == [k + 1 for k in range(0, 30, 3)]     # an eager reader keeps up


def test_detector_records_come_at_most_once_per_two_clocks():
    """The premise of the half-word buffer: the feature engine never offers records on two
    consecutive clocks.  A record offered while the buffer writes a high half would be
    refused and counted in ``dropped_records``; with a buffer deeper than a frame's records
    none may be, on dense random frames and a checkerboard (a completion every other column,
    the fastest there is)."""
    rng = np.random.default_rng(2)
    w, h = 12, 6
    frames = [np.where(rng.random((h, w)) < d, 3000, 10).astype(np.uint16)
              for d in (0.3, 0.5, 0.7)]
    frames.append(np.where(np.indices((h, w)).sum(axis=0) % 2 == 0, 3000, 10)
                  .astype(np.uint16))
    regs = [dict(threshold=50, background=40)] + [{}] * 3
    _, trailers, pending = stream_frames(Detector(w, h, 12), frames, regs)
    cfg = DetectorConfig(width=w, height=h, threshold=50, background=40)
    assert pending == [] and len(trailers) == len(frames)
    for frame, t in zip(frames, trailers):
        res = detect_frame(frame, cfg)
        assert t["dropped_records"] == 0 and t["records"] == list(res.blobs)
    assert trailers[-1]["n_records"] == w * h // 2
