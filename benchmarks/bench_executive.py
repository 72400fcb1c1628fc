"""The flight executive and its link master on the Cortex-M4F build (QEMU, ``-icount``): the
heap their imports keep and their cost, the heap a ``Link`` and an ``Executive`` keep, and one
step's time and allocation around a ``process`` that returns at once, beside a baseline
revision built the same way.

    .venv/bin/python benchmarks/bench_executive.py [--baseline REV] [--steps N] [--smallest]

Each build freezes the MCU image of its checkout (``lodestar.regress.qemu.build``, nothing
else frozen; the ``exec`` and ``exec-baseline`` folders of the cache) and runs one script
under ``run-qemu.py --icount``: ``lodestar.contract`` and ``firmware.status`` imported first
(every loop has them), then ``firmware.link`` and ``firmware.executive`` (with the contract's
``telemetry``), each import's heap kept after a collection and its ticks; a ``Link`` with the
flight record capacity over ``lodestar.regress.linkmodel`` (the gateware's side of the link:
hardware on the board) and an ``Executive`` with a gyro, a store, a watchdog and telemetry;
then ``--steps`` frames of 10 records, each step timed and its allocation counted with the
collector off (steps that write ``min_sum`` back and steps that do not, apart).  The link
model's own share (its status word and its copies) is measured alone and subtracted.  Ticks:
``time.ticks_us()`` under ``-icount shift=0``, 1,000 guest instructions each; F401 ms:
``lodestar.fly.mcu.f401_ms`` (about 3.18 us per tick, an estimate: ``docs/mcu_board.md``).
``--smallest`` adds the smallest heap the executive loop runs the set's estcube2 Pyramid frames
in (``bench_mcu.smallest_heap`` in 512-byte steps on the working tree's build of the
expectations: a ballast in its 80 KiB heap; about 7 QEMU runs of the set, several minutes).
"""

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

HEAP = 73728
"""The build's GC heap (the figures are allocations, not limits: any heap that runs)."""
RECORDS = 10
BASE_US = [0]
"""The packets' first timestamp less 100 ms (``--timestamps-from``): above 2**30 the 32-bit
values are long ints on the MCU."""

GUEST = r"""
import gc, time
from lodestar import contract as C
from lodestar.firmware import status as S
gc.collect()
def mark():
    gc.collect()
    return gc.mem_alloc(), time.ticks_us()
a0, t0 = mark()
t = time.ticks_us()
from lodestar.firmware import link
t1 = time.ticks_diff(time.ticks_us(), t)
a1, _ = mark()
t = time.ticks_us()
from lodestar.firmware import executive
t2 = time.ticks_diff(time.ticks_us(), t)
a2, _ = mark()
print("IMPORT " + repr([a1 - a0, t1, a2 - a1, t2]))
from lodestar.regress import linkmodel
PACKETS = [bytes.fromhex(h) for h in HEXES]

class Settings(object):
    def __init__(self):
        self.clock = None
        self.row_time_s = 3.64e-05
        self.exposure_s = 0.1
        self.epoch_s = 0.0

class Result(object):
    def __init__(self, min_sum):
        self.status = S.OK
        self.q = (0.0, 0.0, 0.6, 0.8)
        self.t_epoch_s = 0.0
        self.min_sum = min_sum
        self.matches = [(0, None, None, 1)] * 8
        self.n_records = 10
        self.sigma_cross_arcsec = 0.5
        self.sigma_roll_arcsec = 5.0

RESULTS = (Result(1000), Result(1000), Result(2000))

class Tracker(object):
    def __init__(self):
        self.status = S.OK
        self.settings = Settings()
        self.k = 0
    def process(self, packet, prior=None, omega=None, dt=None):
        self.k += 1
        return RESULTS[self.k % 3]

class Dog(object):
    def feed(self):
        pass

class Store(object):
    def __init__(self):
        self.data = None
    def read(self):
        return self.data
    def write(self, data):
        pass

RATE = (0.001, 0.0, 0.0)
tracker = Tracker()
dog = Dog()
store = Store()
gyro = lambda: RATE
model = linkmodel.LinkModel()
a3, _ = mark()
lnk = link.Link(model, model.cs, model.irq, time, capacity=C.FLIGHT_RECORD_CAPACITY)
a4, _ = mark()
exe = executive.Executive(lnk, tracker, time, watchdog=dog, store=store,
                          gyro=gyro, telemetry=len, registers={"min_sum": 0},
                          mem_free=gc.mem_free)
a5, _ = mark()
print("OBJECTS " + repr([a4 - a3, a5 - a4]))
for _ in range(4):
    if exe.state not in (executive.BOOT, executive.CONFIGURE):
        break
    exe.step()
rows = []
for i in range(STEPS):
    model.load(PACKETS[i % len(PACKETS)])
    time.sleep_ms(20)
    w = exe.min_sum
    gc.collect()
    gc.disable()
    a = gc.mem_alloc()
    t = time.ticks_us()
    exe.step()
    dt = time.ticks_diff(time.ticks_us(), t)
    b = gc.mem_alloc()
    gc.enable()
    rows.append([dt, b - a, exe.min_sum != w, executive.STATE_NAMES[exe.state]])
print("STEPS " + repr(rows))
# the link model's own share: one status word and the packet's two stream reads
share = []
buf = bytearray(C.packet_bytes(RECORDS))
tx = bytearray(1 + C.TURNAROUND_BYTES + C.STATUS_BYTES)
rx = bytearray(len(tx))
op = bytearray((C.OP_READ_STREAM,) + (0,) * C.TURNAROUND_BYTES)
tx[0] = C.OP_READ_STATUS
head = memoryview(buf)[:C.HEADER_BYTES]
rest = memoryview(buf)[C.HEADER_BYTES:]
for i in range(8):
    model.load(PACKETS[i % len(PACKETS)])
    gc.collect()
    gc.disable()
    a = gc.mem_alloc()
    t = time.ticks_us()
    model.write_readinto(tx, rx)
    model.write(op)
    model.readinto(head, 0)
    model.write(op)
    model.readinto(rest, 0)
    dt = time.ticks_diff(time.ticks_us(), t)
    b = gc.mem_alloc()
    gc.enable()
    share.append([dt, b - a])
print("MODEL " + repr(share))
print("DONE")
"""


def packets(n):
    """``n`` packets of :data:`RECORDS` records, frame counters 1.. and timestamps 100 ms
    apart (the golden detector's, encoded by the ground codec)."""
    from lodestar.golden import Detector, DetectorConfig
    from lodestar.golden.starfield import star_frame
    from lodestar.ground import codec

    out = []
    for k in range(n):
        frame, _ = star_frame(width=128, height=96, pixel_bits=12, n_stars=RECORDS, seed=7,
                              sigma=1.2)
        cfg = DetectorConfig(width=128, height=96, pixel_bits=12, threshold=80, background=40,
                             min_pixels=2, record_capacity=100)
        res = Detector(cfg).process(frame)
        res.frame_counter = k + 1
        res.timestamp = (BASE_US[0] + 100_000 * (k + 1)) % (1 << 32)
        out.append(codec.encode(res).hex())
    return out


def build(checkout, name):
    from lodestar.cache import default_cache_dir
    from lodestar.regress import qemu

    return qemu.build(REPO, Path(default_cache_dir()) / "qemu" / name, "C", HEAP,
                      checkout=checkout)


def measure(elf, steps):
    """The figures of one build (module docstring)."""
    from lodestar.regress import qemu

    script = f"HEXES = {packets(4)!r}\nSTEPS = {steps}\nRECORDS = {RECORDS}\n" + GUEST
    proc = qemu.run(elf, script, repo=REPO)
    if proc.returncode != 0 or "DONE" not in proc.stdout:
        sys.exit(f"bench_executive: the run failed:\n{proc.stdout[-1500:]}{proc.stderr[-1500:]}")
    got = {}
    for line in proc.stdout.splitlines():
        key, _, rest = line.partition(" ")
        if key in ("IMPORT", "OBJECTS", "STEPS", "MODEL"):
            got[key] = json.loads(rest.replace("True", "true").replace("False", "false")
                                  .replace("'", '"'))
    model_t = statistics.median(r[0] for r in got["MODEL"])
    model_b = statistics.median(r[1] for r in got["MODEL"])
    steps_ = [r for r in got["STEPS"][2:] if r[3] == "TRACK"]     # after the first frames
    out = {"import_link": got["IMPORT"][:2], "import_executive": got["IMPORT"][2:],
           "link_object": got["OBJECTS"][0], "executive_object": got["OBJECTS"][1],
           "model": (model_t, model_b)}
    for label, back in (("step", False), ("step_min_sum", True)):
        rows = [r for r in steps_ if r[2] == back]
        out[label] = (statistics.median(r[0] for r in rows) - model_t,
                      statistics.median(r[1] for r in rows) - model_b, len(rows))
    return out


def table(results):
    from lodestar.fly import mcu

    names = list(results)
    lines = ["| on the Cortex-M4F build | " + " | ".join(names) + " |",
             "|---|" + "---|" * len(names)]

    def row(label, cell):
        lines.append(f"| {label} | " + " | ".join(cell(results[n]) for n in names) + " |")

    row("`import` of `link`: heap kept, ticks (F401 ms)",
        lambda r: f"{r['import_link'][0]:,} B, {r['import_link'][1]:,} "
                  f"({mcu.f401_ms(r['import_link'][1]):.1f})")
    row("`import` of `executive` (with `contract.telemetry`): heap kept, ticks (F401 ms)",
        lambda r: f"{r['import_executive'][0]:,} B, {r['import_executive'][1]:,} "
                  f"({mcu.f401_ms(r['import_executive'][1]):.1f})")
    row("`Link(capacity=100)` kept (its packet buffer 4,844 B)",
        lambda r: f"{r['link_object']:,} B")
    row("`Executive(...)` kept (gyro ring, records, buffers)",
        lambda r: f"{r['executive_object']:,} B")
    for key, label in (("step", "one step, 10-record packet, no write-back"),
                       ("step_min_sum", "one step with `min_sum` written back")):
        row(label + ": ticks (F401 ms), bytes allocated",
            lambda r, k=key: f"{r[k][0]:,.0f} ({mcu.f401_ms(r[k][0]):.2f}), {r[k][1]:,.0f} B")
    row("the link model's share subtracted: ticks, bytes",
        lambda r: f"{r['model'][0]:,.0f}, {r['model'][1]:,.0f} B")
    return "\n".join(lines)


def main():
    from lodestar.regress import qemu

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--baseline", default=None, help="git revision to compare with")
    p.add_argument("--steps", type=int, default=24)
    p.add_argument("--timestamps-from", type=int, default=0, metavar="US",
                   help="the packets' timestamps start here (us; default 0)")
    p.add_argument("--smallest", action="store_true",
                   help="also the executive loop's smallest heap (several minutes of QEMU)")
    args = p.parse_args()
    if qemu.unavailable_reason(REPO) is not None:
        sys.exit(f"bench_executive: {qemu.unavailable_reason(REPO)}")
    BASE_US[0] = args.timestamps_from
    if args.steps < 6:
        sys.exit("bench_executive: --steps must be at least 6")
    results = {}
    if args.baseline:
        with tempfile.TemporaryDirectory() as tmp:
            tree = Path(tmp) / "baseline"
            subprocess.run(["git", "-C", str(REPO), "worktree", "add", "-q", "--detach",
                            str(tree), args.baseline], check=True)
            try:
                elf = build(tree, "exec-baseline")
            finally:
                subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force",
                                str(tree)], check=True)
        results[f"baseline {args.baseline}"] = measure(elf, args.steps)
    results["working tree"] = measure(build(None, "exec"), args.steps)
    print(table(results))
    if args.smallest:
        print(f"smallest heap, executive loop over the set: {smallest():,} B (512-byte steps)")


def smallest():
    """The executive loop's smallest heap over the set's estcube2 Pyramid runs (module
    docstring)."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    import bench_mcu

    from lodestar.cache import default_cache_dir
    from lodestar.regress import qemu, replay

    manifest = replay.load_set(replay.DEFAULT_SET)
    db_files = replay.database_files(manifest)
    runs = [(c, bench_mcu.METHOD) for c in manifest["cases"] if c["camera"] == bench_mcu.CAMERA]
    big = qemu.expectation_build(manifest, replay.DEFAULT_SET, db_files, default_cache_dir(),
                                 REPO)
    return bench_mcu.smallest_heap(big, bench_mcu.BIG_HEAP, manifest, db_files, runs, True,
                                   step=512)


if __name__ == "__main__":
    main()
