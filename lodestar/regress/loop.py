"""The MCU side of a regression replay: recorded packets replayed one after another through
:mod:`lodestar.regress.mcu`, each printed as a line ``RESULT {json}``, then ``DONE``.  The one
replay loop of both MicroPython runners, in the MCU image: the unix port runs :func:`main`
(``micropython -m lodestar.regress.loop CONFIG``, the module frozen), the WebAssembly port
steps :func:`replay` (``run.mjs`` resumes it once per ``runPython`` call: that port collects
only between calls).  :func:`stages` counts one frame's stages for
:mod:`lodestar.regress.mcutime`.  The flight loop runs on CPython too (without its heap
figures and times).

``CONFIG`` is a JSON file: ``runs``, a JSON-lines file of ``[case, method, camera, database,
database path, camera settings, packet path, inputs]``; ``resident`` (``databases``:
``{name: path}``, ``cameras``, ``methods``) for the WebAssembly replay's figures, else the
flight loop (``buffer_bytes``, ``peak``, ``threshold``, ``timing``); ``repeats``.  The
fields and figures: ``docs/regression.md``.
"""

import gc
import json
import sys
import time

from lodestar.contract.stardb import METHODS
from lodestar.firmware import starid
from lodestar.regress import mcu

_MEM_ALLOC = getattr(gc, "mem_alloc", None)


def _live():
    """Bytes allocated on MicroPython's heap (None on CPython)."""
    return None if _MEM_ALLOC is None else _MEM_ALLOC()


def sample_peaks():
    """Collect every 512 bytes allocated from now on, the firmware's own collections off
    (``pipeline.COLLECT``: its frames would set their thresholds again): each collection
    samples the live heap, so ``gc.live_peak()`` is a frame's peak to 512 bytes, however
    few collections the firmware itself would make in it."""
    from lodestar.firmware import pipeline
    pipeline.COLLECT = False
    gc.threshold(512)


def _next_run(runs):
    """The next run of the open JSON-lines file ``runs``, decoded (a list); None at its end.
    Nothing of it stays referenced here, so a caller frees what it drops."""
    line = runs.readline()
    return json.loads(line) if line else None


def _read_into(buf, path):
    """The packet file ``path`` read into ``buf``: a ``memoryview`` of its bytes."""
    f = open(path, "rb")
    packet = memoryview(buf)[:f.readinto(buf)]
    f.close()
    return packet


def replay(config_path, clock=None):
    """Replay the runs of the config file ``config_path`` (the module's docstring), printing
    ``RESULT`` lines and ``DONE``.  A generator: it yields after each ``gc.collect()`` whose
    effect the next figure needs.  ``clock``: a float millisecond clock (WebAssembly:
    ``performance.now``) for the resident replay's ``ms``."""
    f = open(config_path)
    config = json.load(f)
    f.close()
    f = None
    steps = _resident(config, clock) if config.get("resident") else _flight(config)
    config = None
    yield from steps
    print("DONE")


def _resident(config, clock):
    """The WebAssembly replay: every database open and every tracker built first (the heap
    after each, ``RESIDENT``), then per solve the heap before it (``live_before``), what it
    allocates with the collector off (``alloc``) and its time (``ms``); ``LIVE_END``."""
    resident, repeats = config["resident"], config.get("repeats", 1)
    heap = {}
    for name in METHODS:           # every method's module, so that `code` counts them all
        starid.method(name)
    gc.collect()
    yield
    heap["code"] = _live()
    databases = {}
    for name in resident["databases"]:
        databases[name] = mcu.open_database(resident["databases"][name])
    gc.collect()
    yield
    heap["databases"] = _live()
    trackers = {}
    cameras = resident["cameras"]
    for camera in cameras:
        for method in resident["methods"]:
            trackers[camera + "/" + method] = mcu.make_tracker(
                databases[cameras[camera]["database"]], cameras[camera], method)
    gc.collect()
    yield
    heap["trackers"] = _live()
    print("RESIDENT " + json.dumps(heap))
    resident = cameras = None
    gc.collect()
    runs = open(config["runs"])
    while True:
        run = _next_run(runs)
        if run is None:
            break
        case, method, camera, _name, _path, _settings, packet, inputs = run
        run = _name = _path = _settings = None
        tracker = trackers[camera + "/" + method]
        for repeat in range(repeats):
            yield
            live = _live()
            f = open(packet, "rb")
            data = f.read()
            f.close()
            f = None
            gc.disable()
            t0 = clock()
            base = _live()
            out = mcu.replay(tracker, data, inputs)
            alloc = _live() - base
            ms = clock() - t0
            gc.enable()
            print("RESULT " + json.dumps({"case": case, "method": method, "repeat": repeat,
                                          "live_before": live, "ms": ms, "alloc": alloc,
                                          "out": out}))
            data = out = None
            gc.collect()
        tracker = None
    runs.close()
    yield
    print("LIVE_END " + str(_live()))


class FileRuns(object):
    """The runs of a flight loop from the JSON-lines file ``path`` (the unix port): databases
    opened by path, packets read from their files.  :mod:`lodestar.regress.qemuloop` has the
    same methods over the data frozen into the Cortex-M4F build."""

    def __init__(self, path):
        self.f = open(path)

    def next(self):
        """The next run (``[case, method, camera, database, path, settings, packet,
        inputs]``), None at the end."""
        return _next_run(self.f)

    def open_database(self, _name, path):
        return mcu.open_database(path)

    def read_into(self, buf, packet):
        return _read_into(buf, packet)

    def io(self):
        """Bus figures of the last run (None: nothing read over a bus)."""
        return None

    def close(self):
        self.f.close()


def _flight(config, runs=None):
    """The flight loop: only the current camera's database open (the heap with it open at
    its opening, ``OPENED``), a new tracker per run, one packet buffer; per solve its live
    peak above the heap before it (``peak``) and its stage times (``timing``).  ``runs``:
    where the runs come from (default :class:`FileRuns` of the config's ``runs``)."""
    peak, timing = config.get("peak"), config.get("timing")
    if peak:
        sample_peaks()
    elif config.get("threshold"):
        gc.threshold(config["threshold"])
    buf = bytearray(config["buffer_bytes"])       # one packet buffer, reused (as the SPI loop's)
    if runs is None:
        runs = FileRuns(config["runs"])
    config = database = opened = None
    while True:
        run = runs.next()
        if run is None:
            break
        case, method, _camera, name, path, settings, packet, inputs = run
        run = _camera = None
        if name != opened:
            database = None
            gc.collect()
            database = runs.open_database(name, path)
            opened = name
            gc.collect()
            print("OPENED " + json.dumps([name, _live()]))
        tracker = mcu.make_tracker(database, settings, method)
        if timing:
            tracker.settings.clock = time.ticks_us
        packet = runs.read_into(buf, packet)
        settings = None
        if peak:
            gc.collect()
            base = gc.mem_alloc()
            gc.live_peak(0)
        t0 = time.ticks_us() if timing else None
        result = mcu.process(tracker, packet, inputs)
        t1 = time.ticks_us() if timing else None
        peak_bytes = gc.live_peak()[0] - base if peak else None
        tracker = packet = inputs = None
        out = mcu.outcome(result)
        times = None
        if timing:
            times = {"process": time.ticks_diff(t1, t0)}
            for stage in result.timings:
                times[stage] = result.timings[stage] % 1073741824      # ticks_us wrap
        result = None
        print("RESULT " + json.dumps({"case": case, "method": method, "out": out,
                                      "peak": peak_bytes, "times": times, "io": runs.io()}))
        out = times = None
        yield
    runs.close()


def stages(config_path):
    """Print ``[status, [[stage, tick], ...]]`` of the second of two ``process`` calls of the
    one run in the config file ``config_path`` (a flight-loop config), whose clock returns
    ``2 ** k`` at its ``k``-th call: under callgrind with a dump at each entry into the C
    clock, the part that ends at tick ``k`` is the stage's instructions
    (:func:`lodestar.regress.mcutime.frame_instructions`).  A collection before the first
    call: where the frames' collections fall then depends on the frames only."""
    f = open(config_path)
    config = json.load(f)
    f.close()
    f = open(config["runs"])
    _case, method, _camera, _name, path, settings, packet, inputs = _next_run(f)
    f.close()
    tracker = mcu.make_tracker(mcu.open_database(path), settings, method)
    packet = _read_into(bytearray(config["buffer_bytes"]), packet)
    config = settings = None
    gc.collect()        # the collector's count starts here, not with the imports and reads
    mcu.process(tracker, packet, inputs)        # warm: the second frame is counted
    ticks = [0]

    def clock():
        time.ticks_us()                 # callgrind starts a new part on entering the C clock
        ticks[0] += 1
        return 1 << ticks[0]            # a stage's timing 2**(k-1) names its tick k

    tracker.settings.clock = clock
    result = mcu.process(tracker, packet, inputs)
    print(json.dumps([result.status, [[k, v] for k, v in result.timings.items()]]))


def main(argv):
    """``loop CONFIG`` replays (:func:`replay`, its steps run one after another);
    ``loop --stages CONFIG`` counts (:func:`stages`)."""
    if "--stages" in argv:
        stages(argv[-1])
        return
    for _ in replay(argv[-1]):
        pass


if __name__ == "__main__":
    main(sys.argv)
