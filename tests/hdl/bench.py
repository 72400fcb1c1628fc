"""Amaranth-simulator bench of the whole detector: stream frames in, collect records and
trailers, convert them to the golden model's types (shared by the hdl unit tests)."""

from amaranth.sim import Simulator

from lodestar import contract as C
from lodestar.cosim.runner import unpack
from lodestar.hdl.labeller import vblank_cycles
from lodestar.hdl.layouts import record_fields, trailer_fields
from lodestar.hdl.output import idle_bound
from tests.hdl.streams import stream_idle, stream_put


def to_record(fields):
    """``contract.BlobRecord`` of an unpacked compact record."""
    return C.BlobRecord(**{name: fields[name] for name in C.RECORD_NAMES})


def frame_stamp(index):
    """The ``timestamp`` the bench drives at frame ``index``'s first pixel (every bit of the
    field used); between first pixels it drives another value, which no trailer may carry."""
    return (0x9E3779B1 * (index + 1)) & ((1 << C.TIMESTAMP_BITS) - 1)


def stream_frames(dut, frames, regs=None, hblank=1, vblank=None, stop_after=None,
                  record_ready=lambda cycle: True, trailer_ready=lambda cycle: True,
                  trailer_first=False, status=None):
    """Run ``frames`` (uint16 arrays) through ``dut`` (a ``Detector``).

    ``regs``: one ``{name: value}`` per frame, written before it.  ``hblank``/``vblank``:
    idle clocks after each row / frame (``vblank`` defaults to what the detector needs).
    ``stop_after``: ``{frame index: pixels}`` streams only that many pixels of a frame.
    ``record_ready``/``trailer_ready``: when the reader is ready, by clock.  ``trailer_first``:
    read as the packetizer does, a trailer first and then its ``n_records`` records.
    ``status``: a dict that receives the detector's final ``trailer_lost``.  ``timestamp``
    is :func:`frame_stamp` of the frame at each first pixel, its complement after it.
    Returns ``(records, trailers, leftover)``: the ``BlobRecord`` list, the trailer dicts in
    output order, each with its frame's records in ``["records"]`` (the ``n_records``
    records before it in the record stream), and records no trailer claimed.
    """
    h, w = frames[0].shape
    vblank = vblank_cycles(w) + 2 if vblank is None else vblank
    rec_fields = record_fields(dut.width, dut.height, dut.pixel_bits)
    tr_fields = trailer_fields()
    out_records, trailers, pending = [], [], []
    done = {"flag": False}

    async def driver(ctx):
        for i, frame in enumerate(frames):
            for name, value in (regs[i] if regs else {}).items():
                ctx.set(dut.reg_addr, C.REGISTER_BY_NAME[name].address)
                ctx.set(dut.reg_data, value)
                ctx.set(dut.reg_en, 1)
                await ctx.tick()
            ctx.set(dut.reg_en, 0)
            limit = (stop_after or {}).get(i, h * w)
            for k in range(limit):
                y, x = divmod(k, w)
                stamp = frame_stamp(i)
                ctx.set(dut.timestamp, stamp if k == 0 else stamp ^ 0xFFFFFFFF)
                await stream_put(ctx, dut.pixels, {"data": int(frame[y, x]), "sof": int(k == 0),
                                                   "eol": int(x == w - 1)})
                if x == w - 1:
                    await stream_idle(ctx, dut.pixels, hblank)
            await stream_idle(ctx, dut.pixels, vblank)
        await ctx.tick().repeat(64 if trailer_first else 8)   # records follow the trailer
        for _ in range(idle_bound(dut.record_depth)):   # the record buffer drains
            if len(pending) >= sum(t["n_records"] for t in trailers):
                break
            await ctx.tick()
        done["flag"] = True

    async def monitor(ctx):
        cycle = 0
        owed = 0                  # trailer_first: records of the last trailer still to read
        while True:
            t_ready = trailer_ready(cycle) and not (trailer_first and owed)
            ready = record_ready(cycle) and (owed > 0 or not trailer_first)
            ctx.set(dut.trailer.ready, t_ready)
            ctx.set(dut.records.ready, ready)
            if ready and ctx.get(dut.records.valid):
                raw = ctx.get(dut.records.payload.as_value())
                pending.append(to_record(unpack(raw, rec_fields)))
                owed -= trailer_first
            if t_ready and ctx.get(dut.trailer.valid):
                trailers.append(unpack(ctx.get(dut.trailer.payload.as_value()), tr_fields))
                owed += trailers[-1]["n_records"] if trailer_first else 0
            if status is not None:
                status["trailer_lost"] = ctx.get(dut.trailer_lost)
            await ctx.tick()
            cycle += 1

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(driver)
    sim.add_testbench(monitor, background=True)
    sim.run()
    for t in trailers:       # a frame's records are the n_records before its trailer
        n = t["n_records"]
        t["records"] = pending[:n]
        out_records.extend(pending[:n])
        del pending[:n]
    return out_records, trailers, pending
