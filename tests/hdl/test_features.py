"""The feature engine in the Amaranth simulator: accumulation, merge, saturation, filters,
record capacity and frame tags, against sums computed here from the contract."""

import numpy as np
from amaranth import Module, Signal
from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.hdl.features import FeatureEngine, _sums
from lodestar.hdl.layouts import record_fields, record_layout
from tests.hdl.streams import stream_collect, stream_idle, stream_put

W, H, PB = 64, 32, 12


def features(pixels, pixel_bits=PB):
    """Contract features of ``[(x, y, p, w)]`` with saturating moments."""
    lim = C.moment_max(pixel_bits)
    out = {"n": len(pixels), "nsat": sum(p == C.full_scale(pixel_bits) for _, _, p, _ in pixels),
           "xmin": min(x for x, *_ in pixels), "xmax": max(x for x, *_ in pixels),
           "ymin": min(y for _, y, *_ in pixels), "ymax": max(y for _, y, *_ in pixels),
           "peak": max(p for _, _, p, _ in pixels), "flags": 0}
    terms = {"s0": lambda x, y, w: w, "sx": lambda x, y, w: w * x, "sy": lambda x, y, w: w * y,
             "sxx": lambda x, y, w: w * x * x, "syy": lambda x, y, w: w * y * y,
             "sxy": lambda x, y, w: w * x * y}
    for name, f in terms.items():
        v = sum(f(x, y, w) for x, y, _, w in pixels)
        if v > lim[name]:
            v, out["flags"] = lim[name], C.BLOB_MOMENTS_SATURATED
        out[name] = v
    return out


def run(ops, min_pixels=1, min_sum=0, max_pixels=C.MAX_PIXELS_UNLIMITED, capacity=8, tag=0):
    dut = FeatureEngine(W, H, PB, slots=4, record_capacity=capacity)
    fields = record_fields(W, H, PB)
    records, counts = [], {}

    async def bench(ctx):
        ctx.set(dut.tag, tag)
        ctx.set(dut.min_pixels, min_pixels)
        ctx.set(dut.min_sum, min_sum)
        ctx.set(dut.max_pixels, max_pixels)
        slot = 0                          # an op's wr_addr goes on wr_slot a clock later
        for op in ops + [None] * 6:
            ctx.set(dut.wr_slot, slot)
            op = dict(op) if op is not None else None
            slot = op.pop("wr_addr", 0) if op is not None else 0
            if op is None:
                await stream_idle(ctx, dut.ops, 1)
            else:
                await stream_put(ctx, dut.ops, op)
        await ctx.tick()                  # the last record's transfer
        counts.update({k: ctx.get(getattr(dut, k)) for k in
                       ("n_blobs", "n_filtered", "dropped_records", "n_records")})

    def unpack(payload):
        raw, rec = int(payload.as_value().value), {}
        for name, bits in fields:
            rec[name], raw = raw & ((1 << bits) - 1), raw >> bits
        return rec

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    stream_collect(sim, dut.records, records, unpack)
    sim.run()
    return records, counts


def px(x, y, p, w, **op):
    """An op adding pixel ``(x, y)`` of value ``p`` and weight ``w``."""
    return dict(pix=1, x=x, y=y, p=p, w=w, **op)


def row(ops):
    """A row as the labeller sends it: ``ops`` by column, a dark op in every other column,
    then the clock of horizontal blanking (no op)."""
    return [ops.get(x, {}) for x in range(W)] + [None]


def test_runs_merge_and_complete():
    a = [(3, 1, 900, 500), (4, 1, 4095, 3000)]
    b = [(7, 1, 1200, 800)]
    c = [(4, 2, 2000, 1000), (5, 2, 100, 0), (6, 2, 700, 300), (7, 2, 50, 0)]
    ops = row({}) + row({3: px(*a[0]), 4: px(*a[1], wr=1, wr_addr=0),
                         7: px(*b[0], wr=1, wr_addr=1)}) + \
        row({4: px(*c[0], rd=1, rd_addr=0), 5: px(*c[1]), 6: px(*c[2]),
             7: px(*c[3], rd=1, rd_addr=1, wr=1, wr_addr=0),
             9: dict(complete=1, rd=1, rd_addr=0)})     # a slot is read back 2 clocks later
    records, counts = run(ops)
    assert records == [features(a + b + c)]
    assert counts == {"n_blobs": 1, "n_filtered": 0, "dropped_records": 0, "n_records": 1}


def test_runs_across_row_ends_and_gaps():
    """A run ending at the last column is not carried into a run starting the next row;
    clocks without an op inside a run add nothing, and a run starting after a completion
    starts empty."""
    d = [(61, 0, 300, 30), (62, 0, 4095, 4000), (63, 0, 10, 1)]
    e = [(0, 1, 20, 2), (1, 1, 40, 4)]
    f = [(5, 1, 7, 3)]
    first = row({61: px(*d[0]), 62: px(*d[1]), 63: px(*d[2], wr=1, wr_addr=2)})
    first[62:62] = [None, None]                          # pixels 61 and 62 of d come late
    second = row({0: px(*e[0]), 1: px(*e[1], wr=1, wr_addr=3),
                  3: dict(complete=1, rd=1, rd_addr=2), 5: px(*f[0], wr=1, wr_addr=2),
                  8: dict(complete=1, rd=1, rd_addr=3), 10: dict(complete=1, rd=1, rd_addr=2)})
    records, counts = run(first + second)
    assert records == [features(d), features(e), features(f)]
    assert counts["n_blobs"] == 3


def test_sums_saturate_and_keep_counts_exact():
    """Counts and moments of three records at once, the second one taken or not, as two
    chained saturating combines would give them: random moments up to their maxima (sums
    that saturate, some by a carry from the lowest bits), the empty record as any operand,
    and the saturation flag of an operand carried on (not that of a slot left out); all
    zero when emptied."""
    layout = record_layout(W, H, PB)
    lim = C.moment_max(PB)
    m = Module()
    recs = [Signal(layout) for _ in range(3)]
    use, empties = Signal(), Signal()
    sums, sat = _sums(m, recs[0], recs[1], use, recs[2], empties, record_fields(W, H, PB))
    assert set(sums) == {"n", "nsat", *C.MOMENTS}
    rng = np.random.default_rng(1)
    none = {**{k: 0 for k in C.MOMENTS}, "n": 0, "nsat": 0, "flags": 0}

    def record(scale):
        return {**{k: int(rng.integers(0, lim[k] + 1)) // scale for k in C.MOMENTS},
                "n": int(rng.integers(1, 1000)), "nsat": int(rng.integers(0, 10)),
                "flags": int(rng.random() < 0.1)}

    cases = [([{**none, **{k: lim[k] for k in C.MOMENTS}},
               {**none, **{k: 1 for k in C.MOMENTS}}, none], 1)]
    for i in range(90):
        trio = [record(int(rng.choice([1, 2, 1000, 1 << 20]))) for _ in range(3)]
        if i % 3:
            trio[int(rng.integers(0, 3))] = none
        cases.append((trio, int(rng.integers(0, 2))))
    cases.append(([none, none, none], 1))

    def chained(u, v):                      # the contract's (+) of two records
        out = {k: min(u[k] + v[k], lim[k]) for k in C.MOMENTS}
        over = any(u[k] + v[k] > lim[k] for k in C.MOMENTS)
        out.update(n=u["n"] + v["n"], nsat=u["nsat"] + v["nsat"],
                   flags=int(u["flags"] or v["flags"] or over))
        return out

    async def bench(ctx):
        saturated = left_out = 0
        for trio, taken in cases:
            for sig, values in zip(recs, trio):
                for k, v in values.items():
                    ctx.set(sig[k], v)
            ctx.set(use, taken)
            want = chained(chained(trio[0], trio[1] if taken else none), trio[2])
            saturated += want["flags"]
            left_out += not taken and trio[1] != none
            got = {k: ctx.get(v) for k, v in sums.items()}
            assert {**got, "flags": ctx.get(sat)} == want
            ctx.set(empties, 1)
            assert not any(ctx.get(v) for v in [sat, *sums.values()])
            ctx.set(empties, 0)
        assert saturated >= 10 and left_out >= 15

    sim = Simulator(m)
    sim.add_testbench(bench)
    sim.run()
