"""The flight firmware on its own instruction set: time, heap, stack and flash on MicroPython
1.27 built for a Cortex-M4F with the STM32F401's memory map (``lodestar.regress.qemu``: the
firmware, the estcube2 database and the regression packets frozen into flash, run on QEMU
with ``-icount``), against a baseline revision built the same way in the same run (replaying
its own regression set: the same scenes recorded in its packet format).

    .venv/bin/python benchmarks/bench_mcu.py [--baseline 4641f47] [--repeats 3]
    .venv/bin/python benchmarks/bench_mcu.py --lis 100 [--work DIR]

* **time**: per frame class of the estcube2 regression packets (the flight method, Pyramid),
  ``StarTracker.process`` in guest ticks (instructions / 1000), as F401 milliseconds: ticks
  x the published NUCLEO-F401RE time of ``bm_float`` and ``bm_nqueens`` over their ticks on
  the representation-A build of the same sources (``qemu.calibrate``); the slowest frame's
  stages through ``Settings.clock``; the same frames through the flight executive and its
  link (``step``: waiting for ``irq`` excluded, status, packet, process, telemetry), and
  with the database read from the SPI F-RAM (its reads' Python side measured, their wire
  time at :data:`FRAM_SCK_HZ` added).  Estimates: QEMU has no flash wait states or caches.
* **memory**: the ELF's statics, heap and stack in the 96 KiB; the heap after the imports,
  the live peak per class, the smallest heap the loop runs the frames in, plain and through
  the executive (a ballast held in an 80 KiB build, 2 KiB steps), the stack's high-water
  mark (painted).
* **flash**: the image against the F401's 512 KiB; where each flight database lives.
* **stages**: one :class:`StarTracker` over the frozen estcube2 flight Pyramid database
  (``db build --flight``) replays every estcube2 packet ``--repeats`` times in a row (the
  first call of a tracking packet queries its cone, later ones reuse it), per stage through
  ``Settings.clock``, on this checkout and the baseline built alike; then (a build with
  ``StarTracker.prefetch``) each tracking packet again as the flight loop runs it, the
  idle-time hook before every call (the cone dropped first, so the first hook queries it),
  the hook timed apart; lost in space p50 / p95 / max over every call; then the hostile
  Pyramid searches of ``bench_budget.py`` (work units spent and time: the work budget in
  F401 milliseconds).
* **lost in space on simulated frames** (``--lis N``, opt-in): ``N`` estcube2 frames at rest
  and ``N`` at 1 deg/s (``lodestar.sim`` scenes through the golden detector with the flight
  settings), each solved lost in space with the gyro's rate on the same stage image, the
  packets read from a host file; p50 / p95 / max F401 ms per class and the statuses.

Needs ``build-qemu.sh`` beside MicroPython's ``build.sh`` (``$LODESTAR_MICROPYTHON_BUILD`` or
``../shared``), ``arm-none-eabi-gcc``, ``qemu-system-arm`` and git.  About 15 minutes of
builds the first time on 2 busy cores, then a few minutes.
"""

import argparse
import hashlib
import os
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lodestar import contract as C
from lodestar.firmware import starid
from lodestar.ground.cache import default_cache_dir
from lodestar.ground.database import build_database
from lodestar.ground.onboard import DEFAULT_MAX_MAG, FLIGHT_DENSITY
from lodestar.regress import fram, qemu, replay, unixport
from lodestar.sim import presets
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import load
from lodestar.sim.centroids import centroid_scene

REPO = Path(__file__).resolve().parents[1]
BASELINE = "4641f47"
"""Main when issue 29 was filed (its figures)."""
METHOD = "pyramid"
CAMERA = "estcube2"
FRAM_SCK_HZ = 21_000_000
"""The F-RAM's SPI clock: SPI2 of the F401 at APB1 (42 MHz) / 2; the chip allows 40 MHz."""
BIG_HEAP = qemu.EXPECTATION_HEAP
"""The heap of the build the smallest heaps are found in (the expectations' build: it links
in 96 KiB with a 15 KiB stack; not a flight configuration)."""
SCALE = [3.169]
"""F401 microseconds per guest tick: :func:`lodestar.regress.qemu.calibrate`'s scale, set by
:func:`main` before any table (``docs/mcu_board.md``, Measured on the Cortex-M4F build)."""
CLASSES = ("rest", "moving", "tracking, steady", "tracking, record budget",
           "tracking, coarse prior", "bad packet")


def frame_class(case):
    """The class of a regression case (:data:`CLASSES`)."""
    name = case["name"]
    if case["inputs"].get("prior") is not None:
        if "budget" in name:
            return "tracking, record budget"
        return "tracking, steady" if "steady" in name else "tracking, coarse prior"
    if case["expected"][METHOD]["status_name"] != "OK" and \
            case["expected"][METHOD]["n_stars"] == 0:
        return "bad packet"
    omega = case["inputs"].get("omega")
    return "moving" if omega and any(omega) else "rest"


SET_PATH = "lodestar/regress/data/regression"
"""The regression set's folder in a checkout."""


def baseline_set(baseline, dest):
    """The regression set as ``baseline`` recorded it, extracted into ``dest``: ``(folder,
    manifest, database files, estcube2 Pyramid runs)``.  A baseline replays its own set:
    today's packets carry a header its decoder refuses (the frame timestamp, packet version
    2, came after ``4641f47``), and its set records the same scenes in its own format."""
    dest.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(REPO), "archive", baseline, SET_PATH],
                             capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    folder = dest / SET_PATH
    manifest = replay.load_set(folder)
    runs = [(c, METHOD) for c in manifest["cases"] if c["camera"] == CAMERA]
    return folder, manifest, replay.database_files(manifest), runs


def builds(manifest, db_files, baseline, base):
    """The current and baseline flight images (the baseline with its own set ``base``:
    :func:`baseline_set`) and the representation-A reference."""
    cache = default_cache_dir()
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "baseline"
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "-q", "--detach",
                        str(tree), baseline], check=True)
        try:
            old = qemu.flight_build(base[1], base[0], base[2], cache, REPO, checkout=tree,
                                    name="bench-baseline")
        finally:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force",
                            str(tree)], check=True)
    new = qemu.flight_build(manifest, replay.DEFAULT_SET, db_files, cache, REPO)
    return old, new, qemu.reference_build(cache, REPO)


def _link_checked(case, method):
    """Whether the link master checks ``case``'s packet before the decoder does (a packet the
    decoder refuses for its framing: the link refuses it or, for a trailing byte, reads the
    packet its header delimits and leaves the byte to the next resynchronisation)."""
    return case["expected"][method]["status_name"].startswith("PACKET_") and \
        case["expected"][method]["status_name"] not in ("PACKET_BAD_HEADER",
                                                        "PACKET_BAD_RECORD")


def _expected(runs, key):
    """The recorded status of run ``key``."""
    return next(c["expected"][m]["status"] for c, m in runs if (c["name"], m) == key)


def _ms(ticks, scale):
    return ticks * scale / 1000.0


def _row_stats(values):
    values = sorted(values)
    return statistics.median(values), values[-1]


def time_table(loops, runs, scale, read_ticks, base_runs):
    """Per class: F401 ms p50 / max of ``process`` on the baseline (over its own set's
    ``base_runs``) and now, the executive's step (frames it solved; the build of the
    expectations, 80 KiB of heap) and the F-RAM database (the frame from flash plus its
    reads through the F-RAM model, counted, times ``read_ticks`` and their wire time at
    :data:`FRAM_SCK_HZ`); the slowest frame's stages now."""
    print("\n## Time on the Cortex-M4F build, F401 estimate (ms), estcube2, Pyramid")
    print("| class | frames | baseline p50 / max | now p50 / max | now through the executive "
          "p50 / max | now, database in F-RAM p50 / max | slowest frame's stages now |")
    print("|---|---|---|---|---|---|---|")
    for cls in CLASSES:
        keys = [(c["name"], m) for c, m in runs if frame_class(c) == cls]
        if not keys:
            continue
        cells = []
        for name in ("baseline", "now", "executive", "fram"):
            times, results = loops[name]["times"], loops[name]["results"]
            own = base_runs if name == "baseline" else runs
            mine = [(c["name"], m) for c, m in own if frame_class(c) == cls]
            ok = [k for k in mine if k in times and results[k][0] is not None and
                  results[k][0]["status"] == _expected(own, k)]
            got = [times[k]["step" if name == "executive" else "process"] for k in ok]
            if name == "fram":
                io, now = loops[name]["io"], loops["now"]["times"]
                got = [now[k]["process"] + io.get(k, (0, 0))[0] * read_ticks +
                       fram.wire_us(*io.get(k, (0, 0)), FRAM_SCK_HZ) / scale for k in ok]
            p50, top = _row_stats(got) if got else (None, None)
            text = "-" if p50 is None else f"{_ms(p50, scale):.0f} / {_ms(top, scale):.0f}"
            if len(ok) < len(mine):
                text += f" ({len(mine) - len(ok)} other status)"
            elif len(mine) != len(keys):
                text += f" ({len(mine)} frames)"
            cells.append(text)
        slow = max(keys, key=lambda k: loops["now"]["times"][k]["process"])
        stages = ", ".join(f"{s} {_ms(v, scale):.0f}" for s, v in
                           loops["now"]["times"][slow].items() if s not in ("process", "total"))
        print(f"| {cls} | {len(keys)} | " + " | ".join(cells) + f" | {stages} |")


def memory_table(elf, big, loops, runs, manifest, db_files):
    """RAM budgets from the ELF, heap figures from the runs, the executive's smallest heap."""
    layout = qemu.memory_map(elf, qemu.FLIGHT_HEAP)
    print("\n## Memory (bytes): the F401's 96 KiB")
    print("| item | bytes | note |")
    print("|---|---|---|")
    print(f"| statics (data + bss without the heap) | {layout['statics']:,} | the qemu port's; "
          "the STM32 port's are larger |")
    print(f"| GC heap | {layout['heap']:,} | fixed at build time |")
    print(f"| stack (RAM above them) | {layout['stack']:,} | budget {qemu.STACK_BUDGET:,} |")
    for name in ("now", "executive"):
        loop = loops[name]
        print(f"| stack used, {name} loop (painted high-water mark) | "
              f"{loop['stack']['used']:,} | |")
        print(f"| heap in use after the imports, {name} loop | {loop['heap']['alloc']:,} | "
              "firmware, harness and set modules |")
        print(f"| heap in use with the database open, {name} loop | "
              f"{loop['resident'][CAMERA]:,} | and the loop's buffers (the link's) |")
    peaks = loops["peak"]["results"]
    for cls in CLASSES:
        got = [peaks[(c["name"], m)][1] for c, m in runs if frame_class(c) == cls and
               (c["name"], m) in peaks and peaks[(c["name"], m)][1] is not None]
        if got:
            print(f"| live peak of one frame, {cls} | {max(got):,} | above the heap before it |")
    for executive in (False, True):
        smallest = smallest_heap(big, BIG_HEAP, manifest, db_files, runs, executive)
        print(f"| smallest heap, {'executive' if executive else 'plain'} loop over the set | "
              f"{'-' if smallest is None else format(smallest, ',')} | a ballast in a "
              f"{BIG_HEAP // 1024} KiB build, 2 KiB steps |")


def smallest_heap(elf, heap, manifest, db_files, runs, executive, step=2048):
    """The smallest heap (``heap`` of the build ``elf`` less a ballast, ``step`` resolution)
    with which the loop (``executive``: through the executive and its link) gives every
    recorded status and star; None if ``heap`` does not."""
    def fits(ballast):
        loop = qemu.flight_loop(elf, manifest, db_files, runs, heap=heap, ballast=ballast,
                                executive=executive)
        got = loop["results"]
        return loop["finished"] and all(
            got.get((c["name"], m), (0,))[0] is None or
            (got[(c["name"], m)][0]["status"], got[(c["name"], m)][0]["matches"]) ==
            (c["expected"][m]["status"], c["expected"][m]["matches"]) for c, m in runs
            if not (executive and _link_checked(c, m)))

    if not fits(0):
        return None
    low, high = 0, heap // step // 2           # ballast steps; high: half the heap
    while high - low > 1:
        mid = (low + high) // 2
        if fits(mid * step):
            low = mid
        else:
            high = mid
    return heap - low * step


def flash_table(elf, db_files, manifest):
    """The image against the F401's flash, and where each flight database lives."""
    layout = qemu.memory_map(elf, qemu.FLIGHT_HEAP)
    frozen = Path(db_files[CAMERA]).stat().st_size
    data = Path(elf).parent / "data" / "regset" / "__init__.py"
    namespace = {}
    exec(data.read_text(), namespace)           # the staged set: its bytes constants
    regset = len(namespace["PACKETS"]) + sum(len(c) for c in namespace["CASES"]) + \
        sum(len(c) for c in namespace["CAMERAS"])
    flight = layout["flash"] - frozen - regset
    print("\n## Flash (bytes)")
    print("| item | bytes | where |")
    print("|---|---|---|")
    print(f"| the Cortex-M4F image with the regression set | {layout['flash']:,} | the "
          "emulated 1 MiB |")
    print(f"| of which the set's estcube2 database (all three methods) | {frozen:,} | |")
    print(f"| of which the set's packets, cases and camera settings | {regset:,} | |")
    print(f"| MicroPython and the frozen firmware (the flight image) | {flight:,} | internal "
          f"flash, {qemu.FLASH_BYTES:,} |")
    for preset in ("estcube2", "lohmann"):
        camera = presets.load_preset(preset)
        size = len(build_database(camera=camera, methods=(METHOD,), mag_limit=DEFAULT_MAX_MAG,
                                  **FLIGHT_DENSITY))
        room = qemu.FLASH_BYTES - flight
        where = "internal flash or F-RAM" if size <= room else "F-RAM"
        print(f"| {preset} flight database (`db build --flight`), Pyramid | {size:,} | {where} "
              f"(internal room {room:,}; F-RAM {fram.CAPACITY:,}) |")


STAGES = ("decode", "centroids", "directions", "identify", "attitude")

SCRIPT = """\
import gc, time
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import Settings
import lodestar_bench as B
clock = time.ticks_us
s = B.SETTINGS
tr = StarTracker(B.DB, B.CAMERA, Settings(method='pyramid', exposure_s=s[0],
                 row_time_s=s[1], tolerance_px=s[2], clock=clock))
print('CONFIG', tr.status, gc.mem_free())
for name, pkt, prior, omega, exposure in B.CASES:
    for rep in range(B.REPEATS):
        t0 = clock()
        r = tr.process(pkt, prior=prior, omega=omega, exposure_s=exposure)
        t1 = clock()
        t = r.timings
        print('RUN', name, rep, r.status, r.mode, len(r.matches), time.ticks_diff(t1, t0),
              ' '.join([k + '=' + str(t[k]) for k in t]))
    if prior is None or not hasattr(tr, 'prefetch'):
        continue
    tr.prefetch(None)               # the same calls with the idle-time hook before each
    for rep in range(B.REPEATS):
        t0 = clock()
        code = tr.prefetch(prior, omega)
        t1 = clock()
        r = tr.process(pkt, prior=prior, omega=omega, exposure_s=exposure)
        t2 = clock()
        print('PREFETCH', name, rep, code, time.ticks_diff(t1, t0), r.status,
              len(r.matches), time.ticks_diff(t2, t1))
from lodestar.firmware import starid
for label, tol, vecs in B.BUDGET:
    gc.collect()
    t0 = clock()
    sol = starid.identify(vecs, tr.database, method='pyramid', tolerance_rad=tol,
                          budget=1000000)
    print('WORK', label, sol.status, sol.work, time.ticks_diff(clock(), t0))
print('DONE')
"""


def flight_database():
    """The estcube2 flight Pyramid database image (bytes)."""
    return bytes(build_database(camera=presets.load_preset("estcube2"), methods=("pyramid",),
                                mag_limit=DEFAULT_MAX_MAG, **FLIGHT_DENSITY))


BUDGET_TOLERANCES_PX = (30.0, 100.0, None)
"""Match tolerances (px) of the work-budget cases; None: the widest the firmware accepts."""


def budget_cases():
    """The hostile search of ``benchmarks/bench_budget.py`` (30 estcube2 stars, 10 of them
    false, 1 px noise, seed 7) at wide tolerances: ``[(label, tolerance_rad, vectors)]``,
    searches that spend the whole work budget or the heap."""
    cam = presets.load_preset("estcube2")
    rng = np.random.default_rng(7)
    scene = centroid_scene(cam, random_attitude(rng), rng, load(), noise_px=1.0, n_false=10,
                           max_stars=30)
    vectors = [tuple(v) for v in scene.vectors.tolist()]
    fov_h = np.radians(cam.fov_deg()[0])
    px = fov_h / cam.width
    out = []
    for tol_px in BUDGET_TOLERANCES_PX:
        tol = starid.max_tolerance_rad(fov_h) if tol_px is None else tol_px * px
        out.append((f"tolerance_{tol / px:.0f}px", float(tol), vectors))
    return out


def data_module(path, db, manifest, set_dir, repeats):
    """Write the frozen data module: the database, the camera, the settings, the estcube2
    packets of the set in ``set_dir`` with their inputs and the work-budget cases."""
    cam = manifest["cameras"]["estcube2"]
    cases = []
    for case in manifest["cases"]:
        if case["camera"] != "estcube2" or not case["name"].startswith("estcube2"):
            continue
        packet = (set_dir / case["packet"]).read_bytes()
        i = case["inputs"]
        omega = tuple(i["omega"]) if i.get("omega") is not None else None
        prior = tuple(i["prior"]) if i.get("prior") is not None else None
        cases.append(f"({case['name']!r}, {packet!r}, {prior!r}, {omega!r}, "
                     f"{i.get('exposure_s')!r}),")
    path.write_text(f"DB = {db!r}\nCAMERA = {cam['camera']!r}\n"
                    f"SETTINGS = ({cam['exposure_s']!r}, {cam['row_time_s']!r}, "
                    f"{cam['tolerance_px']!r})\nREPEATS = {repeats}\nCASES = [\n" +
                    "\n".join(cases) + f"\n]\nBUDGET = {budget_cases()!r}\n")


def stage_build(label, checkout, work, db, manifest, set_dir, repeats, script, extra=()):
    """Stage ``checkout``'s image (None: this installation's) with the data module (the set
    ``manifest`` in ``set_dir``) and the ``extra`` modules of :mod:`lodestar.regress` (this
    installation's), build it and return a copy of its ``firmware.elf``."""
    side = work / label
    image = unixport.stage_mcu_image(side / "image", checkout, native=True)
    for name in extra:
        shutil.copyfile(REPO / "lodestar" / "regress" / f"{name}.py",
                        image / "lodestar" / "regress" / f"{name}.py")
    data = side / "data"
    data.mkdir(parents=True, exist_ok=True)
    data_module(data / "lodestar_bench.py", db, manifest, set_dir, repeats)
    frozen = side / "manifest.py"
    frozen.write_text(f"package('lodestar', base_path={str(image)!r})\n"
                      f"module('lodestar_bench.py', base_path={str(data)!r})\n")
    elf = side / "firmware.elf"
    stamp = side / "firmware.key"
    key = _tree_key([script] + sorted(image.rglob("*.py")) + [data / "lodestar_bench.py"])
    if elf.is_file() and stamp.is_file() and stamp.read_text() == key:
        return elf                  # the same sources and data: the same image
    env = dict(os.environ, FROZEN_MANIFEST=str(frozen))
    out = side / "mp"           # built from clean: an incremental build keeps the last
    for old in out.glob("build-*"):     # image's qstrs, which moves every time by a few %
        if old.is_dir():
            shutil.rmtree(old)
    proc = subprocess.run(["bash", str(script), str(out), "C", str(qemu.FLIGHT_HEAP)], env=env,
                          capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"bench_mcu: the {label} build failed:\n{proc.stderr[-2000:]}")
    shutil.copyfile(proc.stdout.strip().splitlines()[-1], elf)
    stamp.write_text(key)
    return elf


def _tree_key(paths):
    """A content hash of ``paths`` (names and bytes): a kept stage build (``--work``) is
    reused while it matches."""
    h = hashlib.sha256(str(qemu.FLIGHT_HEAP).encode())
    for path in paths:
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()


def stage_run(elf):
    """Replay on QEMU (``qemu.run``: the guest's clock restarted, so a run repeats exactly):
    ``{(case, repeat): {"status", "mode", "matches", "call", stage: units}}``."""
    proc = qemu.run(elf, SCRIPT, timeout=3000, repo=REPO)
    if proc.returncode != 0 or "DONE" not in proc.stdout:
        sys.exit(f"bench_mcu: the run on {elf} failed:\n{proc.stdout[-1500:]}"
                 f"{proc.stderr[-1500:]}")
    out = {}
    for line in proc.stdout.splitlines():
        parts = line.split()
        if parts and parts[0] == "PREFETCH":
            out[("prefetch " + parts[1], int(parts[2]))] = {
                "code": int(parts[3]), "prefetch": int(parts[4]), "status": int(parts[5]),
                "matches": int(parts[6]), "call": int(parts[7])}
        if parts and parts[0] == "WORK":
            out[("work " + parts[1], 0)] = {"status": int(parts[2]), "work": int(parts[3]),
                                            "call": int(parts[4])}
        if not parts or parts[0] != "RUN":
            continue
        row = {"status": int(parts[3]), "mode": parts[4], "matches": int(parts[5]),
               "call": int(parts[6])}
        for kv in parts[7:]:
            k, _, v = kv.partition("=")
            row[k] = int(v)
        out[(parts[1], int(parts[2]))] = row
    return out


def ms(units):
    return units * SCALE[0] / 1000.0


def stage_class(name):
    if "tracking" in name:
        return "tracking"
    return "lost in space"


def stage_report(results, labels):
    """Print the per-packet table and the per-class summary."""
    names = sorted({k[0] for lab in labels for k in results[lab]
                    if not k[0].startswith(("work ", "prefetch "))},
                   key=lambda n: (stage_class(n), n))       # each build's own set's packets
    repeats = max(k[1] for k in results[labels[0]]) + 1
    print("\n## Per packet, F401 ms (estimate): first call / later calls (median); stages of "
          "the last call, baseline → now")
    print("| packet | " + " | ".join(f"{lab} first / later" for lab in labels) + " | " +
          " | ".join(f"{s} {labels[0]} → {labels[-1]}" for s in STAGES) + " | status |")
    print("|---|" + "---|" * (len(labels) + len(STAGES) + 1))
    for name in names:
        cells = []
        for lab in labels:
            rows = [results[lab][(name, r)] for r in range(repeats) if (name, r) in results[lab]]
            if not rows:
                cells.append("–")
                continue
            later = statistics.median(r["call"] for r in rows[1:]) if repeats > 1 else None
            cells.append(f"{ms(rows[0]['call']):.1f} / " +
                         ("–" if later is None else f"{ms(later):.1f}"))
        last = results[labels[-1]].get((name, repeats - 1), {})
        base = results[labels[0]].get((name, repeats - 1), {})
        stages = [(f"{ms(base[s]):.1f} → " if s in base else "") +
                  (f"{ms(last[s]):.1f}" if s in last else "–") for s in STAGES]
        status = " → ".join(str(results[lab][(name, 0)]["status"]) + "/" +
                            str(results[lab][(name, 0)]["matches"])
                            if (name, 0) in results[lab] else "–" for lab in labels)
        print(f"| {name} | " + " | ".join(cells) + " | " + " | ".join(stages) +
              f" | {status} |")
    prefetch_report(results, labels, names)
    print("\n## Lost in space over the packets (every call), F401 ms (estimate)")
    print("| build | p50 | p95 | max |")
    print("|---|---|---|---|")
    for lab in labels:
        t = sorted(ms(r["call"]) for k, r in results[lab].items()
                   if stage_class(k[0]) == "lost in space" and not k[0].startswith("work "))
        p95 = t[min(len(t) - 1, int(0.95 * len(t)))]
        print(f"| {lab} | {statistics.median(t):.0f} | {p95:.0f} | {t[-1]:.0f} |")
    print("\n## The work budget's worst case: a hostile Pyramid search (bench_budget.py's), "
          "F401 ms (estimate)")
    print("| build | case | status | work units | F401 ms | F401 ms per million units |")
    print("|---|---|---|---|---|---|")
    for lab in labels:
        for (name, _r), row in sorted(results[lab].items()):
            if name.startswith("work "):
                print(f"| {lab} | {name[5:]} | {row['status']} | {row['work']:,} | "
                      f"{ms(row['call']):.0f} | {ms(row['call']) / row['work'] * 1e6:.0f} |")


def prefetch_report(results, labels, names):
    """Print the tracking packets' calls with the flight loop's idle-time hook before each
    (``StarTracker.prefetch``: the cone made beforehand, then a collection), first (the
    cone made by that hook) / later, and the hook's own time, first (the cone's query) / later
    (median: a collection); builds without the hook show none."""
    print("\n## Tracking with the idle-time hook (`StarTracker.prefetch`) before each call, "
          "F401 ms (estimate): first / later (median) call; the hook before them")
    print("| packet | " + " | ".join(f"{lab} first / later; hook first / later" for lab in labels) +
          " | status |")
    print("|---|" + "---|" * (len(labels) + 1))
    for name in names:
        if stage_class(name) != "tracking":
            continue
        cells, status = [], "–"
        for lab in labels:
            rows = [row for (key, _r), row in sorted(results[lab].items())
                    if key == "prefetch " + name]
            if not rows:
                cells.append("–")
                continue
            later = statistics.median(r["call"] for r in rows[1:]) if len(rows) > 1 else None
            hook = statistics.median(r["prefetch"] for r in rows[1:]) if len(rows) > 1 else None
            cells.append(f"**{ms(rows[0]['call']):.1f}** / " +
                         ("–" if later is None else f"**{ms(later):.1f}**") +
                         f"; {ms(rows[0]['prefetch']):.1f} / " +
                         ("–" if hook is None else f"{ms(hook):.1f}"))
            status = ", ".join(f"{r['code']}: {r['status']}/{r['matches']}" for r in rows)
        print(f"| {name} | " + " | ".join(cells) + f" | {status} |")


def stages(baseline, repeats, keep):
    """Build this checkout and ``baseline`` with the stage data module (in ``keep``, or a
    temporary folder) and print :func:`stage_report`."""
    script = qemu.script_dir(REPO) / "build-qemu.sh"
    work = Path(keep or tempfile.mkdtemp(prefix="bench_mcu-")).resolve()
    work.mkdir(parents=True, exist_ok=True)
    manifest = replay.load_set(replay.DEFAULT_SET)
    db = flight_database()
    base = work / "baseline-src"
    shutil.rmtree(base, ignore_errors=True)
    base.mkdir()
    archive = subprocess.run(["git", "-C", str(REPO), "archive", baseline,
                              "lodestar/__init__.py", "lodestar/contract", "firmware"],
                             capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(base)], input=archive, check=True)
    base_set, base_manifest = baseline_set(baseline, work / "baseline-set")[:2]
    results = {}
    for label, checkout, man, folder in ((baseline, base, base_manifest, base_set),
                                         ("now", None, manifest, replay.DEFAULT_SET)):
        elf = stage_build(label, checkout, work, db, man, folder, repeats, script)
        results[label] = stage_run(elf)
    stage_report(results, [baseline, "now"])
    if keep is None:
        shutil.rmtree(work, ignore_errors=True)


LIS_RATE_DEG_S = 1.0
"""The moving frames' rate (deg/s, about a random axis) of the simulated lost-in-space
frames (:func:`lis_frames`)."""
LIS_SEED = 29
LIS_HEADER = "<I3f"
"""Each frame in the host file of :func:`lis_frames`: its packet's length and ``omega``
(rad/s), then the packet."""

LIS_SCRIPT = """\
import gc, struct, time
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import Settings
from lodestar.regress import semihost
import lodestar_bench as B
clock = time.ticks_us
s = B.SETTINGS
tr = StarTracker(B.DB, B.CAMERA, Settings(method='pyramid', exposure_s=s[0],
                 row_time_s=s[1], tolerance_px=s[2], clock=clock))
B.CASES = B.BUDGET = None          # the stage tables' data: not the flight loop's heap
f = semihost.HostFile('lis_frames.bin')
head = bytearray(16)
buf = bytearray(BUFFER)
view = memoryview(buf)
gc.collect()
print('FREE', gc.mem_free())
k = 0
while f.readinto(head) == 16:
    n, wx, wy, wz = struct.unpack('<I3f', head)
    f.readinto(view[:n])
    omega = (wx, wy, wz)
    gc.collect()
    t0 = clock()
    r = tr.process(view[:n], omega=omega)
    t1 = clock()
    print('LIS', k, r.status, len(r.matches), time.ticks_diff(t1, t0))
    r = None
    k += 1
print('DONE')
"""


def lis_frames(n, path, seed=LIS_SEED):
    """Simulate ``n`` estcube2 frames at rest and ``n`` at :data:`LIS_RATE_DEG_S` about a
    random axis (uniformly random attitudes, ``lodestar.sim.scene``; the golden detector with
    the preset's flight settings, ``lodestar.ground.onboard``, and the flight record
    capacity) and write their packets with ``omega`` (the gyro's rate, exact) to ``path``
    (:data:`LIS_HEADER` per frame; a file already there is kept: the frames are the same).
    Returns the labels (``rest``/``1dps``) in order."""
    from lodestar.golden import detect_frame
    from lodestar.ground import codec, onboard
    from lodestar.sim import scene
    labels = ["rest"] * n + [f"{LIS_RATE_DEG_S:g}dps"] * n
    if Path(path).is_file():
        return labels
    cam = presets.load_preset(CAMERA)
    chosen = onboard.camera_settings(CAMERA)
    rng = np.random.default_rng(seed)
    with open(str(path) + ".tmp", "wb") as out:
        for i in range(2 * n):
            q = random_attitude(rng)
            axis = rng.normal(size=3)
            rate = (0.0, 0.0, 0.0) if i < n else \
                tuple(float(a) for a in LIS_RATE_DEG_S * axis / np.linalg.norm(axis))
            sim = scene.simulate(cam, q, rate, seed=seed + i)
            cfg = onboard.detector_config(cam, chosen, sim.truth["exposure_s"]).replace(
                record_capacity=C.FLIGHT_RECORD_CAPACITY)
            packet = codec.encode(detect_frame(sim.frame, cfg))
            out.write(struct.pack(LIS_HEADER, len(packet), *np.radians(rate)) + packet)
    os.replace(str(path) + ".tmp", path)
    return labels


def lis(n, keep):
    """Lost in space over :func:`lis_frames` on this checkout's stage image (the estcube2
    flight Pyramid database frozen, the packets read from a host file by semihosting, which
    costs the guest no ticks): per class p50 / p95 / max F401 ms of ``process`` and the
    statuses."""
    script = qemu.script_dir(REPO) / "build-qemu.sh"
    work = Path(keep or tempfile.mkdtemp(prefix="bench_mcu-")).resolve()
    work.mkdir(parents=True, exist_ok=True)
    frames = work / f"lis_frames-{n}-{LIS_SEED}.bin"
    t0 = time.perf_counter()
    labels = lis_frames(n, frames)
    print(f"\n{len(labels)} frames in {time.perf_counter() - t0:.0f} s")
    manifest = replay.load_set(replay.DEFAULT_SET)
    elf = stage_build("lis", None, work, flight_database(), manifest, replay.DEFAULT_SET, 1,
                      script, extra=("semihost",))
    proc = qemu.run(elf, LIS_SCRIPT.replace("BUFFER", str(unixport.FLIGHT_BUFFER)).replace(
        "lis_frames.bin", frames.name), files=[frames], timeout=6000, repo=REPO)
    if proc.returncode != 0 or "DONE" not in proc.stdout:
        sys.exit(f"bench_mcu: the lost-in-space run failed:\n{proc.stdout[-1500:]}"
                 f"{proc.stderr[-1500:]}")
    rows = [line.split() for line in proc.stdout.splitlines() if line.startswith("LIS ")]
    free = next(line.split()[1] for line in proc.stdout.splitlines() if line.startswith("FREE"))
    print(f"heap free before the first frame: {int(free):,} of {qemu.FLIGHT_HEAP:,} bytes")
    print(f"\n## Lost in space over {n} simulated estcube2 frames at rest and {n} at "
          f"{LIS_RATE_DEG_S:g} deg/s (Pyramid, flight database), F401 ms (estimate)")
    print("| frames | n | p50 | p95 | max | OK | statuses |")
    print("|---|---|---|---|---|---|---|")
    for label in sorted(set(labels), key=labels.index) + ["all"]:
        got = [r for r in rows if label == "all" or labels[int(r[1])] == label]
        t = sorted(ms(int(r[4])) for r in got)
        p95 = t[min(len(t) - 1, int(0.95 * len(t)))]
        codes = _count(int(r[2]) for r in got)
        print(f"| {label} | {len(t)} | {statistics.median(t):.0f} | {p95:.0f} | {t[-1]:.0f} | "
              f"{codes.get(0, 0)} | " + ", ".join(f"{k}: {v}" for k, v in sorted(codes.items()))
              + " |")
    other = [f"{r[1]} ({labels[int(r[1])]}): {r[2]}" for r in rows if int(r[2]) != 0]
    print("frames with another status (index, class: status): " + (", ".join(other) or "none"))
    if keep is None:
        shutil.rmtree(work, ignore_errors=True)


def _count(values):
    out = {}
    for v in values:
        out[v] = out.get(v, 0) + 1
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--baseline", default=BASELINE, help="git revision to compare with")
    p.add_argument("--repeats", type=int, default=3,
                   help="calls per packet in the stage table (default 3)")
    p.add_argument("--stages-only", action="store_true",
                   help="only the stage and work-budget tables (a few minutes)")
    p.add_argument("--work", help="build folder of the stage table kept between runs")
    p.add_argument("--lis", type=int, metavar="N",
                   help="only lost in space over N simulated frames at rest and N at 1 deg/s "
                        "(opt-in: about a minute of QEMU per 20 frames)")
    args = p.parse_args()
    if qemu.unavailable_reason(REPO) is not None:
        sys.exit(f"bench_mcu: {qemu.unavailable_reason(REPO)}")
    if args.repeats < 1:
        sys.exit("bench_mcu: --repeats must be at least 1")
    manifest = replay.load_set(replay.DEFAULT_SET)
    db_files = replay.database_files(manifest)
    t0 = time.perf_counter()
    if args.lis:
        cal = qemu.calibrate(qemu.reference_build(default_cache_dir(), REPO))
        SCALE[0] = cal["scale"]
        print(f"F401 estimate = ticks x {cal['scale']:.3f} us")
        lis(args.lis, args.work)
        return
    if args.stages_only:
        cal = qemu.calibrate(qemu.reference_build(default_cache_dir(), REPO))
        SCALE[0] = cal["scale"]
        print(f"F401 estimate = ticks x {cal['scale']:.3f} us")
        stages(args.baseline, args.repeats, args.work)
        return
    base_dir = Path(tempfile.mkdtemp(prefix="bench_mcu-set-"))
    base = baseline_set(args.baseline, base_dir)
    old, new, reference = builds(manifest, db_files, args.baseline, base)
    cal = qemu.calibrate(reference)
    SCALE[0] = cal["scale"]
    print(f"# bench_mcu: baseline {args.baseline} -> working tree; builds "
          f"{time.perf_counter() - t0:.0f} s")
    print(f"F401 estimate = ticks x {cal['scale']:.3f} us (" + ", ".join(
        f"{n}: {qemu.mcutime.F401_US[n]:,.0f} us published / {t:,} ticks on A = "
        f"{cal['ratio'][n]:.3f}" for n, t in cal["ticks"].items()) + f"; "
        f"{qemu.mcutime.F401_SOURCE})")
    runs = [(c, METHOD) for c in manifest["cases"] if c["camera"] == CAMERA]
    big = qemu.expectation_build(manifest, replay.DEFAULT_SET, db_files, default_cache_dir(),
                                 REPO)
    base_runs = base[3]
    loops = {"baseline": qemu.flight_loop(old, base[1], base[2], base_runs, timing=True),
             "now": qemu.flight_loop(new, manifest, db_files, runs, timing=True),
             "executive": qemu.flight_loop(big, manifest, db_files, runs, timing=True,
                                           executive=True, heap=BIG_HEAP),
             "fram": qemu.flight_loop(new, manifest, db_files, runs, timing=True,
                                      frozen=()),
             "peak": qemu.flight_loop(new, manifest, db_files, runs, peak=True)}
    shutil.rmtree(base_dir, ignore_errors=True)
    for name, loop in loops.items():
        own = base_runs if name == "baseline" else runs
        bad = unixport.disagreements(loop, own) if name != "executive" else []
        print(f"{name}: {'finished' if loop['finished'] else 'DID NOT FINISH'}"
              f"{', differs: ' + str(bad) if bad else ''}")
    read_ticks = qemu.fram_read_ticks(new)
    print(f"F-RAM: a read costs {read_ticks:.3f} ticks more than from flash (the reader's "
          f"side), plus its wire time at {FRAM_SCK_HZ / 1e6:.0f} MHz")
    time_table(loops, runs, cal["scale"], read_ticks, base_runs)
    memory_table(new, big, loops, runs, manifest, db_files)
    flash_table(new, db_files, manifest)
    print(f"\n(packet buffer {unixport.FLIGHT_BUFFER} B: {C.FLIGHT_RECORD_CAPACITY} records)")
    stages(args.baseline, args.repeats, args.work)


if __name__ == "__main__":
    main()
