"""Stream handshakes for ``amaranth.sim`` testbenches (after Glasgow's ``gateware/stream.py``).

A transfer happens at a clock edge where ``valid`` and ``ready`` are both high; streams
built with ``always_ready`` have a constant ``ready``.  Back-to-back calls stream one beat
per clock: ``valid`` (or ``ready``) drops and rises again in the same instant.  (The waits
are plain ``tick()`` loops: a background testbench left inside ``tick().until()`` or ``.repeat()``
when the simulation ends raises a warning as it is closed.)
"""

from amaranth import Value


async def stream_put(ctx, stream, payload):
    """Offer ``payload`` (a field dict or an integer) on ``stream`` and wait for the clock
    edge that transfers it."""
    ctx.set(stream.valid, 1)
    if isinstance(payload, int):
        ctx.set(Value.cast(stream.payload), payload)
    else:
        ctx.set(stream.payload, payload)
    while not (await ctx.tick().sample(stream.ready))[2]:
        pass
    ctx.set(stream.valid, 0)


async def stream_get(ctx, stream):
    """Accept one beat of ``stream`` and return its payload as sampled at the transfer."""
    always_ready = stream.signature.always_ready
    if not always_ready:
        ctx.set(stream.ready, 1)
    while True:
        _, _, payload, valid = await ctx.tick().sample(stream.payload, stream.valid)
        if valid:
            break
    if not always_ready:
        ctx.set(stream.ready, 0)
    return payload


async def stream_idle(ctx, stream, clocks):
    """Offer nothing on ``stream`` for ``clocks`` clocks."""
    ctx.set(stream.valid, 0)
    for _ in range(clocks):
        await ctx.tick()


def stream_collect(sim, stream, sink, convert=lambda payload: payload):
    """Add a background testbench to ``sim`` that accepts every beat of ``stream`` and
    appends ``convert(payload)`` to ``sink``; returns ``sink``."""
    async def collect(ctx):
        while True:
            sink.append(convert(await stream_get(ctx, stream)))
    sim.add_testbench(collect, background=True)
    return sink
