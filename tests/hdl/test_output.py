"""The detector's output stage in the simulator: a lost trailer, its frame's orphan and a record
taken in a ``done`` clock never reach a packetizer-like reader, which stays in step.  (Every
input pattern: ``tests/formal/test_output.py``.)"""

from amaranth.sim import Simulator

from lodestar.hdl.output import OutputStage

GAP = 3                                  # clocks between events (the buffer takes 1 per 2)


def run(events, reader_from):
    """Play ``events`` (``("record", value)``, ``("done", n_records, frame_counter)``, or
    ``("record+done", value, n_records, frame_counter)``), one every ``GAP`` clocks; from
    clock ``reader_from`` a reader takes a trailer when it owes no record, then its
    ``n_records`` records.  Returns what it took and the final ``trailer_lost``."""
    dut = OutputStage(8, 4)
    took, status = [], {}

    async def bench(ctx):
        owed = 0
        script = [e for event in events for e in [event] + [None] * (GAP - 1)]
        for clock, event in enumerate(script + [None] * 40):
            kind = event[0] if event else None
            ctx.set(dut.records_in.valid, kind in ("record", "record+done"))
            ctx.set(dut.records_in.payload, event[1] if kind in ("record", "record+done") else 0)
            ctx.set(dut.done, kind in ("done", "record+done"))
            if kind in ("done", "record+done"):
                ctx.set(dut.trailer_in.n_records, event[-2])
                ctx.set(dut.trailer_in.frame_counter, event[-1])
            if kind in ("record", "record+done"):
                assert ctx.get(dut.records_in.ready), f"record {event[1]} refused"
            reading = clock >= reader_from
            ctx.set(dut.trailer.ready, reading and owed == 0)
            ctx.set(dut.records.ready, reading and owed != 0)
            if reading and owed == 0 and ctx.get(dut.trailer.valid):
                owed = ctx.get(dut.trailer.payload.n_records)
                took.append(("trailer", ctx.get(dut.trailer.payload.frame_counter)))
            elif reading and owed and ctx.get(dut.records.valid):
                owed -= 1
                took.append(ctx.get(dut.records.payload))
            await ctx.tick()
        status["lost"] = ctx.get(dut.trailer_lost)

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    sim.run()
    return took, status["lost"]


def test_lost_trailer_and_orphans_never_reach_the_reader():
    events = [("record", 10), ("record", 11), ("done", 2, 0),      # frame 0
              ("record", 20), ("done", 1, 1),                      # frame 1: trailer lost
              ("record", 30), ("record+done", 31, 1, 2),           # frame 2, 31 is nobody's
              ("record", 41), ("done", 1, 3)]                      # frame 3
    took, lost = run(events, reader_from=5 * GAP + 1)             # after frame 1's done
    assert took == [("trailer", 0), 10, 11, ("trailer", 2), 30, ("trailer", 3), 41]
    assert lost == 1


def test_eager_reader_gets_every_frame():
    events = [("record", 1), ("done", 1, 0), ("done", 0, 1), ("record", 2), ("record", 3),
              ("done", 2, 2)]
    took, lost = run(events, reader_from=0)
    assert took == [("trailer", 0), 1, ("trailer", 1), ("trailer", 2), 2, 3] and lost == 0
