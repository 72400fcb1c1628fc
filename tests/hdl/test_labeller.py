"""The labeller block in the Amaranth simulator, column by column against its algorithm
(the wavefront model): the op it sends for every column (slot read for a
continuation or a merge, slot write, completion) and the dropped-label count."""

import gc

import numpy as np
import pytest
from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.golden.wavefront import WavefrontLabeller
from lodestar.hdl.labeller import Labeller, max_nodes, max_stack, vblank_cycles
from tests.hdl.streams import stream_collect, stream_idle, stream_put


def hardware_ops(mask, cap, hblank=1):
    """``(ops per column in decision order, dropped_labels at done, fault)``."""
    h, w = mask.shape
    dut = Labeller(w, h, 12, cap)
    ops, end = [], {}

    async def bench(ctx):
        ctx.set(dut.feat_busy, 0)
        for y in range(h):
            for x in range(w):
                await stream_put(ctx, dut.pixels, {"x": x, "y": y, "lit": int(mask[y, x])})
            await stream_idle(ctx, dut.pixels, hblank)
        await stream_idle(ctx, dut.pixels, vblank_cycles(w) + 2)

    async def watch(ctx):
        while True:
            if ctx.get(dut.done):
                end["dropped"] = ctx.get(dut.dropped_labels)
            end["fault"] = ctx.get(dut.fault)
            await ctx.tick()

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    sim.add_testbench(watch, background=True)
    stream_collect(sim, dut.ops, ops, lambda op: (op.rd, op.wr, op.complete))
    sim.run()
    return ops, end.get("dropped"), end["fault"]


def model_ops(mask, cap):
    h, w = mask.shape
    frame = np.where(mask, 100, 0).astype(np.uint16)
    model = WavefrontLabeller(w, h, 12, cap, 1 << 16).run(mask, frame, frame)
    per = {}
    for t, kind in model.events:
        per.setdefault(t, set()).add(kind)
    ops = []
    for y in range(h + 1):
        for x in range(w):
            k = per.get(y * (w + 1) + x, set())
            ops.append((int("feat_read" in k), int("feat_write" in k), int("complete" in k)))
    return ops, model.dropped_labels


@pytest.mark.parametrize("seed", range(6))
def test_ops_column_by_column(seed):
    rng = np.random.default_rng(seed)
    for _ in range(6):
        h, w = int(rng.integers(1, 9)), int(rng.integers(3, 11))
        mask = rng.random((h, w)) < rng.choice([0.3, 0.5, 0.6, 0.8])
        cap = int(rng.integers(1, C.max_open_blobs(w) + 1))
        got, dropped, fault = hardware_ops(mask, cap)
        want, want_dropped = model_ops(mask, cap)
        assert got == want, (mask.astype(int), cap)
        assert dropped == want_dropped and fault == 0


def test_memory_bounds():
    assert max_nodes(2592) == 1296 and max_stack(2592) == 649
    assert max_nodes(5) == 3 and max_stack(5) == 2


@pytest.mark.filterwarnings("ignore::amaranth.hdl.UnusedElaboratable")
def test_rejects_impossible_builds():
    """The rejected objects are never elaborated: Amaranth warns of them when they are
    collected, which ``gc.collect`` does here, under the filter (their tracebacks hold them
    in cycles, else collected during a later test)."""
    with pytest.raises(ValueError, match="at least 3 columns"):
        Labeller(2, 4, 12, 1)
    with pytest.raises(ValueError, match="label_capacity"):
        Labeller(8, 4, 12, 0)
    gc.collect()


NESTED = """
AAAAAAAAAAAAA
A...........A
A.BBBBBBBBB.A
A.B.......B.A
"""


@pytest.mark.parametrize("inner", ["A.B.SS....B.A", "A.B.TTT...B.A", "A.B.SS.TTTB.A"])
@pytest.mark.parametrize("below", ["", ".............", "AAAAAAAAAAAAA", "A.B.S.T.B.A.A"])
def test_stack_spill_then_pop_one_and_two_clocks_later(inner, below):
    """Two nested components on the stack, then single-node components two and three
    pixels wide: a spill followed one or two clocks later by the pop that needs the
    spilled entry back (the stack memory's write-behind bypass), with the row below dark,
    all lit or crossing them."""
    rows = NESTED.strip().splitlines() + [inner] + ([below] if below else [])
    mask = np.array([[c != "." for c in r] for r in rows])
    for m in (mask, mask[:, ::-1]):
        for cap in (1, 2, C.max_open_blobs(m.shape[1])):
            got, dropped, fault = hardware_ops(m, cap)
            want, want_dropped = model_ops(m, cap)
            assert got == want, (m.astype(int), cap)
            assert dropped == want_dropped and fault == 0


@pytest.mark.parametrize("cap", [1, 2])
def test_node_zero_untracked_at_the_row_end(cap):
    """A merge in a row's last column untracks a survivor whose first node is the row's
    node 0: the next row reads node 0 from the registers that follow its patches."""
    mask = np.array([[c != "." for c in r] for r in ("XXX.Y.Z", "X.XXXXX", "X......",
                                                     "XX.....")])
    got, dropped, fault = hardware_ops(mask, cap)
    want, want_dropped = model_ops(mask, cap)
    assert got == want and dropped == want_dropped and fault == 0
