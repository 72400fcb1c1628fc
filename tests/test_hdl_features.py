"""The feature engine in the Amaranth simulator: accumulation, merge, saturation, filters,
record capacity and frame tags, against sums computed here from the contract."""

import numpy as np
from amaranth import Module, Signal
from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.hdl.features import (KEEP, LOAD, MERGE, NEW, FeatureEngine, _combine,
                                   empty_features)
from lodestar.hdl.layouts import record_fields, record_layout

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
    records = []

    async def bench(ctx):
        ctx.set(dut.tag, tag)
        ctx.set(dut.min_pixels, min_pixels)
        ctx.set(dut.min_sum, min_sum)
        ctx.set(dut.max_pixels, max_pixels)
        ctx.set(dut.records.ready, 1)
        for op in ops + [None] * 6:
            ctx.set(dut.ops.valid, op is not None)
            op = op or {}
            ctx.set(dut.ops.payload.as_value(), 0)
            for name, value in op.items():
                ctx.set(getattr(dut.ops.payload, name), value)
            await ctx.tick()
            if ctx.get(dut.records.valid):
                raw = ctx.get(dut.records.payload.as_value())
                rec = {}
                for name, bits in fields:
                    rec[name], raw = raw & ((1 << bits) - 1), raw >> bits
                records.append(rec)
        records.append({k: ctx.get(getattr(dut, k)) for k in
                        ("n_blobs", "n_filtered", "dropped_records", "n_records")})

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    sim.run()
    return records[:-1], records[-1]


def px(x, y, p, w, **op):
    """An op adding pixel ``(x, y)`` of value ``p`` and weight ``w``; ``{}`` is a dark column."""
    return dict(pix=1, x=x, y=y, p=p, w=w, **op)


def test_runs_merge_and_complete():
    a = [(3, 1, 900, 500), (4, 1, 4095, 3000)]
    b = [(7, 1, 1200, 800)]
    c = [(4, 2, 2000, 1000), (5, 2, 100, 0), (6, 2, 700, 300), (7, 2, 50, 0)]
    ops = [px(*a[0], base=NEW), px(*a[1], base=KEEP, wr=1, wr_addr=0),
           px(*b[0], base=NEW, wr=1, wr_addr=1),
           px(*c[0], base=LOAD, rd=1, rd_addr=0), px(*c[1]), px(*c[2]),
           px(*c[3], base=MERGE, rd=1, rd_addr=1, wr=1, wr_addr=0),
           {}, dict(complete=1, rd=1, rd_addr=0)]      # a slot is read back 2 clocks later
    records, counts = run(ops)
    assert records == [features(a + b + c)]
    assert counts == {"n_blobs": 1, "n_filtered": 0, "dropped_records": 0, "n_records": 1}


def test_filters_capacity_and_stale_tag():
    single = [px(2, 3, 500, 100, base=NEW, wr=1, wr_addr=2), {},
              dict(complete=1, rd=1, rd_addr=2)]
    _, counts = run(single, min_sum=101)
    assert counts["n_filtered"] == 1 and counts["n_records"] == 0
    _, counts = run(single, min_pixels=2)
    assert counts["n_filtered"] == 1
    records, counts = run(single + single + single, capacity=2)
    assert len(records) == 2 and counts["dropped_records"] == 1 and counts["n_blobs"] == 3
    records, counts = run([dict(op, tag=1) if op else op for op in single], tag=0)
    assert records == [] and counts["n_blobs"] == 0


def test_combine_saturates_and_keeps_counts_exact():
    """Three records at once, as two chained saturating combines would give them: random
    moments up to their maxima (sums that saturate, some by a carry from the lowest bits),
    the empty record as any operand, and the saturation flag of an operand carried on."""
    layout = record_layout(W, H, PB)
    lim = C.moment_max(PB)
    m = Module()
    recs = [Signal(layout) for _ in range(3)]
    out = _combine(m, *recs, record_fields(W, H, PB))
    rng = np.random.default_rng(1)
    none = {**{k: 0 for k in C.MOMENTS}, "n": 0, "nsat": 0, "xmin": 63, "xmax": 0,
            "ymin": 31, "ymax": 0, "peak": 0, "flags": 0}
    assert empty_features(W, H) == {"xmin": 63, "ymin": 31}

    def record(scale):
        x0, y0 = (int(v) for v in rng.integers(0, [W, H]))
        return {**{k: int(rng.integers(0, lim[k] + 1)) // scale for k in C.MOMENTS},
                "n": int(rng.integers(1, 1000)), "nsat": int(rng.integers(0, 10)),
                "xmin": x0, "xmax": int(rng.integers(x0, W)), "ymin": y0,
                "ymax": int(rng.integers(y0, H)), "peak": int(rng.integers(0, 4096)),
                "flags": int(rng.random() < 0.1)}

    cases = [[{**none, **{k: lim[k] for k in C.MOMENTS}}, {**none, **{k: 1 for k in C.MOMENTS}},
              none]]
    for i in range(60):
        trio = [record(int(rng.choice([1, 2, 1000, 1 << 20]))) for _ in range(3)]
        if i % 3:
            trio[int(rng.integers(0, 3))] = none
        cases.append(trio)
    cases.append([none, none, none])

    def chained(u, v):                      # the contract's (+) of two records
        out = {k: min(u[k] + v[k], lim[k]) for k in C.MOMENTS}
        over = any(u[k] + v[k] > lim[k] for k in C.MOMENTS)
        out.update(n=u["n"] + v["n"], nsat=u["nsat"] + v["nsat"],
                   xmin=min(u["xmin"], v["xmin"]), ymin=min(u["ymin"], v["ymin"]),
                   xmax=max(u["xmax"], v["xmax"]), ymax=max(u["ymax"], v["ymax"]),
                   peak=max(u["peak"], v["peak"]), flags=int(u["flags"] or v["flags"] or over))
        return out

    async def bench(ctx):
        saturated = 0
        for trio in cases:
            for sig, values in zip(recs, trio):
                for k, v in values.items():
                    ctx.set(sig[k], v)
            want = chained(chained(trio[0], trio[1]), trio[2])
            saturated += want["flags"]
            assert {k: ctx.get(out[k]) for k in want} == want
        assert saturated >= 10

    sim = Simulator(m)
    sim.add_testbench(bench)
    sim.run()
