"""The MCU side of a regression run on the Cortex-M4F build under QEMU
(:mod:`lodestar.regress.qemu`): the flight loop of :mod:`lodestar.regress.loop` over the
recorded set frozen into flash (``regset``: cases, camera settings, packets, and the star
databases that fit as ``regset.db_<name>.DATA``; the others are read from host files through
the F-RAM model, :mod:`lodestar.regress.fram` over :mod:`lodestar.regress.semihost`), plus
what only the real memory map shows: the C stack's high-water mark (the free RAM below the
stack painted and read back through ``machine.mem32``) and a ballast that takes heap away to
try a smaller heap in the same build.  MicroPython on the Cortex-M4F build only.

    from lodestar.regress import qemuloop
    qemuloop.main(CONFIG_JSON)

``CONFIG_JSON``: ``runs`` (hex: two digits of case index, then two of method index, per
run), ``methods``, ``databases`` (``{name: ["frozen"] or ["fram", host path]}``),
``buffer_bytes``, ``peak``, ``timing``, ``threshold`` (as :mod:`lodestar.regress.loop`),
``ballast`` (bytes held for the whole run), ``stack`` (``[low, top]``: the addresses of the
end of the statics and of the top of the stack, from the ELF).  Prints ``HEAP``, the loop's
``OPENED`` and ``RESULT`` lines (``io``: the F-RAM reads and bytes of the solve), ``STACK``
and ``DONE``."""

import gc
import json
import sys

import machine
import micropython
import regset

from lodestar.contract import detection
from lodestar.firmware import database as _database
from lodestar.regress import mcu

PAINT = 0x1A2B3C4D
"""The word painted over the free stack (a small int on the 32-bit build)."""
MARGIN = 512
"""Bytes below the stack pointer left unpainted (the painting call's own frames)."""


def _evict_methods(keep):
    """Drop the identification modules of every method but ``keep`` (imported by earlier
    runs): a flight image runs one method, so only its module is resident."""
    from lodestar.firmware import starid
    for name in ("pyramid", "triangle", "hashing"):
        module = "lodestar.firmware.starid." + name
        if name != keep and module in sys.modules:
            del sys.modules[module]
            if name in starid.__dict__:
                delattr(starid, name)
    gc.collect()


class FrozenRuns(object):
    """The runs of ``config`` over the frozen set, with the methods of
    :class:`lodestar.regress.loop.FileRuns`."""

    def __init__(self, config):
        self.runs = config["runs"]
        self.methods = config["methods"]
        self.databases = config["databases"]
        self.at = 0
        self.chip = None
        self.mark = (0, 0)
        self.method = None

    def next(self):
        if self.at >= len(self.runs):
            return None
        c = int(self.runs[self.at:self.at + 2], 16)
        m = int(self.runs[self.at + 2:self.at + 4], 16)
        self.at += 4
        if self.methods[m] != self.method:
            self.method = self.methods[m]
            _evict_methods(self.method)
        name, camera, offset, length, inputs = json.loads(regset.CASES[c])
        settings = json.loads(regset.CAMERAS[regset.CAMERA_NAMES.index(camera)])
        return [name, self.method, camera, settings["database"], None, settings,
                (offset, length), inputs]

    def open_database(self, name, _path):
        self.chip = None
        how = self.databases[name]
        if how[0] == "frozen":
            data = __import__("regset.db_" + name, None, None, ("DATA",)).DATA
            return _database.Database(data)
        # imported only when used: the harness's heap stays small
        from lodestar.regress import fram, semihost
        self.chip = fram.Fram(semihost.HostFile(how[1]))
        return _database.Database.fram(self.chip, self.chip.cs)

    def view(self, packet):
        """The frozen bytes of ``packet`` (a view of flash; starts the run's F-RAM count)."""
        offset, length = packet
        chip = self.chip
        self.mark = (0, 0) if chip is None else (chip.reads, chip.read_bytes)
        return memoryview(regset.PACKETS)[offset:offset + length]

    def read_into(self, buf, packet):
        view = memoryview(buf)
        view[:packet[1]] = self.view(packet)
        return view[:packet[1]]

    def io(self):
        chip = self.chip
        if chip is None:
            return None
        return [chip.reads - self.mark[0], chip.read_bytes - self.mark[1]]

    def close(self):
        pass


class _Replay(object):
    """The executive's tracker: each frame goes to the current run's tracker with the
    recorded case's inputs (prior, rate, dt, exposure) instead of the executive's own."""

    def __init__(self, clock):
        self.tracker = None
        self.inputs = None
        self.result = None
        self.status = 0
        self.settings = _Settings(clock)

    def process(self, packet, prior=None, omega=None, dt=None):
        tracker = self.tracker
        tracker.settings.clock = self.settings.clock     # the executive's, feeding its dog
        self.result = mcu.process(tracker, packet, self.inputs)
        return self.result


class _Settings(object):
    def __init__(self, clock):
        self.clock = clock


def _step_frame(exe, model, replay, executive):
    """Step ``exe`` until it has taken the loaded packet (solved, or refused by the link);
    at most 8 steps (a refused packet can take a recovery step; SAFE is left by command)."""
    for _ in range(8):
        if replay.result is not None or (model.pending() == 0 and exe.state in
                                          (executive.ACQUIRE, executive.TRACK,
                                           executive.COAST)):
            return
        if exe.state == executive.SAFE:
            exe.command(executive.CMD_MODE, executive.MODE_AUTO)
        exe.step()


def _executive(config, runs):
    """The flight loop through the executive (``executive`` in the config): its
    :class:`lodestar.firmware.link.Link` (``FLIGHT_RECORD_CAPACITY`` buffer) reads each
    packet from :class:`lodestar.regress.linkmodel.LinkModel`, telemetry and heap sampling
    as in flight; per run ``RESULT`` as the loop's (``out`` None when the link refused the
    packet, ``link`` its code) and ``step``, the executive's ticks for it."""
    import time

    from lodestar.firmware import executive
    from lodestar.firmware import link as _link
    from lodestar.regress import linkmodel
    peak, timing = config.get("peak"), config.get("timing")
    if peak:
        from lodestar.regress.loop import sample_peaks
        sample_peaks()
    model = linkmodel.LinkModel()
    lnk = _link.Link(model, model.cs, model.irq, time, capacity=detection.FLIGHT_RECORD_CAPACITY)
    replay = _Replay(time.ticks_us if timing else None)
    exe = executive.Executive(lnk, replay, time, mem_free=gc.mem_free, telemetry=len)
    for _ in range(4):
        if exe.state not in (executive.BOOT, executive.CONFIGURE):
            break
        exe.step()
    config = database = opened = None
    while True:
        run = runs.next()
        if run is None:
            break
        case, method, _camera, name, path, settings, packet, inputs = run
        run = _camera = None
        if name != opened:
            database = replay.tracker = None
            gc.collect()
            database = runs.open_database(name, path)
            opened = name
            gc.collect()
            print("OPENED " + json.dumps([name, gc.mem_alloc()]))
        replay.tracker = mcu.make_tracker(database, settings, method)
        replay.inputs, replay.result = inputs, None
        model.load(runs.view(packet))
        settings = inputs = packet = None
        if peak:
            gc.collect()
            base = gc.mem_alloc()
            gc.live_peak(0)
        t0 = time.ticks_us()
        _step_frame(exe, model, replay, executive)
        step = time.ticks_diff(time.ticks_us(), t0)
        peak_bytes = gc.live_peak()[0] - base if peak else None
        result, replay.result, replay.tracker = replay.result, None, None
        out = None if result is None else mcu.outcome(result)
        times = None
        if timing and result is not None:
            times = {"step": step}
            for stage in result.timings:
                times[stage] = result.timings[stage] % 1073741824
            times["process"] = times.get("total", step)
        result = None
        print("RESULT " + json.dumps({"case": case, "method": method, "out": out,
                                      "peak": peak_bytes, "times": times, "io": runs.io(),
                                      "link": _link.CODE_NAMES[exe.last_link],
                                      "state": executive.STATE_NAMES[exe.state],
                                      "step": step}))
        out = times = None
        yield
    print("HEALTH " + json.dumps(list(exe.health)))


def paint(low, top):
    """Paint the free stack from ``low`` up to :data:`MARGIN` below the stack pointer;
    returns the painted top."""
    high = (top - micropython.stack_use() - MARGIN) & ~3
    mem = machine.mem32
    for addr in range(low, high, 4):
        mem[addr] = PAINT
    return high


def high_water(low, high, top):
    """Bytes of stack ever used: from ``top`` down to the lowest word of ``[low, high)`` no
    longer painted."""
    mem = machine.mem32
    for addr in range(low, high, 4):
        if mem[addr] != PAINT:
            return top - addr
    return top - high


def main(config_json):
    """Run the flight loop of ``config_json`` (the module's docstring)."""
    config = json.loads(config_json)
    config_json = None
    stack = config.get("stack")
    painted = paint(stack[0], stack[1]) if stack else None
    ballast = bytearray(config["ballast"]) if config.get("ballast") else None
    gc.collect()
    print("HEAP " + json.dumps({"free": gc.mem_free(), "alloc": gc.mem_alloc(),
                                "ballast": len(ballast) if ballast else 0}))
    if config.get("executive"):
        steps = _executive
    else:
        from lodestar.regress import loop
        steps = loop._flight
    for _ in steps(config, FrozenRuns(config)):
        pass
    if stack:
        print("STACK " + json.dumps({"used": high_water(stack[0], painted, stack[1]),
                                     "painted": painted - stack[0]}))
    print("DONE")
