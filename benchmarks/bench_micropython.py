"""Solve time and heap of the flight firmware under MicroPython 1.27 (WebAssembly port in
Node.js), per identification method, over the firmware regression set
(``lodestar/regress/data/regression``, ``lodestar regress``), with the CPython figures beside them.

    .venv/bin/python benchmarks/bench_micropython.py [--repeats 5] [--set DIR]

What is measured (``lodestar.regress.micropython`` explains the port's collector):

* **time**: ``StarTracker.process`` of each recorded packet of a simulated frame (the
  corrupted packets, which stop at the decoder, are left out), each method, ``--repeats``
  times; p50/p95 over all those solves and over the solved ones, in ms of wall clock
  (MicroPython: Node's ``performance.now()``; CPython: ``time.perf_counter``).  Node on
  this machine, not an MCU: a Cortex-M4 at 168 MHz is one to two orders of magnitude slower.
* **MicroPython heap**: ``gc.mem_alloc()`` after collection with the firmware imported, the
  databases open (read by offset from files) and the trackers built; the largest live heap
  between solves; the bytes one solve *allocates* (collector disabled: an upper bound of the
  solve's peak, every boxed float counted).  This port cannot show the peak itself:
  ``gc.collect()`` is deferred to the next top-level call and the heap grows instead of
  collecting (``MICROPY_GC_SPLIT_HEAP_AUTO``), and ``loadMicroPython({heapsize})`` is the
  *initial* heap, not a cap -- the probe below allocates 4 MB in a 64 KB heap.  So the
  smallest heap a method solves in cannot be found on this port.
* **CPython live peak**: ``tracemalloc`` peak during one warm solve (refcounting frees at
  once, so this is the live peak), 64-bit CPython objects (a float is 24 B, 16 B on
  MicroPython's heap; tuples and lists about twice MicroPython's 32-bit sizes): a
  conservative bound of the solve's live peak on an MCU, beside the allocation bound, over
  the recorded frames (whole pipeline) and over ``--hard`` hard centroid scenes per camera
  of the set (30 stars of which 10 false, 1 px noise; identification alone, and tracking
  from a prior off by 0.2 deg), against the 96 KB budget of the issue.
"""

import argparse
import math
import statistics
import time
import tracemalloc

import numpy as np
from scipy.spatial.transform import Rotation

from lodestar.firmware import starid, tracking
from lodestar.regress import mcu, micropython, replay
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import load
from lodestar.sim.centroids import centroid_scene
from lodestar.sim.presets import load_preset

HEAP_BUDGET = 96 * 1024
"""The issue's budget: peak heap of one solve under MicroPython, bytes."""

HEAP_PROBE = """
import gc
keep = []
for i in range(64):
    keep.append(bytearray(64 * 1024))
gc.collect()
print("PROBE", gc.mem_alloc())
"""


def percentile(values, p):
    """The ``p``-th percentile (nearest rank) of a non-empty list."""
    ordered = sorted(values)
    return ordered[max(0, math.ceil(p / 100 * len(ordered)) - 1)]


def heap_probe():
    """What ``--heapsize 64k`` does to a script allocating 4 MB: the text to print."""
    proc = micropython.run(HEAP_PROBE, heapsize=64 * 1024)
    for line in proc.stdout.splitlines():
        if line.startswith("PROBE "):
            return (f"--heapsize 64k is no cap: a script held 4 MB (gc.mem_alloc() "
                    f"{int(line.split()[1]) / 1024:.0f} KB) without MemoryError")
    return f"--heapsize 64k caps the heap: {(proc.stdout + proc.stderr).strip()[-200:]}"


def cpython_figures(manifest, set_dir, db_files, cases, repeats):
    """``{method: {"ms": [...], "ms_ok": [...], "peak": [...]}}`` on this interpreter."""
    data = replay.packets(manifest, set_dir)
    dbs = {name: mcu.open_database(str(path)) for name, path in db_files.items()}
    out = {}
    for method in manifest["methods"]:
        fig = out[method] = {"ms": [], "ms_ok": [], "peak": []}
        trackers = {cam: mcu.make_tracker(dbs[s["database"]], s, method)
                    for cam, s in manifest["cameras"].items()}
        for case in cases:
            tracker = trackers[case["camera"]]
            mcu.replay(tracker, data[case["name"]], case["inputs"])   # warm up
            for _ in range(repeats):
                t0 = time.perf_counter()
                res = mcu.replay(tracker, data[case["name"]], case["inputs"])
                ms = (time.perf_counter() - t0) * 1e3
                fig["ms"].append(ms)
                if res["status_name"] == "OK":
                    fig["ms_ok"].append(ms)
            tracemalloc.start()
            base = tracemalloc.get_traced_memory()[0]
            mcu.replay(tracker, data[case["name"]], case["inputs"])
            fig["peak"].append(tracemalloc.get_traced_memory()[1] - base)
            tracemalloc.stop()
    return out


def live_peak(call):
    """``tracemalloc`` live peak (bytes) of one ``call()`` after a warm-up call."""
    call()
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    call()
    peak = tracemalloc.get_traced_memory()[1] - base
    tracemalloc.stop()
    return peak


def hard_peaks(manifest, db_files, methods, n, seed=3):
    """``{(camera, method or "tracking"): [peak bytes per scene]}`` over ``n`` hard centroid
    scenes per camera of the set (module docstring), the databases read by offset from
    their files as on the MCU."""
    cat = load()
    out = {}
    for cam_name, settings in manifest["cameras"].items():
        cam = load_preset(cam_name)
        db = mcu.open_database(str(db_files[settings["database"]]))
        tol = settings["tolerance_px"] / cam.fx_px
        rng = np.random.default_rng(seed)
        for _ in range(n):
            scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=1.0,
                                   n_false=10, drop_fraction=0.1, max_stars=30)
            v = scene.vectors.tolist()
            axis = rng.normal(size=3)
            axis *= math.radians(0.2) / np.linalg.norm(axis)
            prior = (Rotation.from_rotvec(axis) * Rotation.from_quat(scene.q)).as_quat()
            for method in methods:
                out.setdefault((cam_name, method), []).append(live_peak(
                    lambda: starid.identify(v, db, method=method, tolerance_rad=tol)))
            out.setdefault((cam_name, "tracking"), []).append(live_peak(
                lambda: tracking.track(v, db, prior, tolerance_rad=tol)))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="solves per packet and method")
    ap.add_argument("--set", dest="set_dir", default=str(replay.DEFAULT_SET))
    ap.add_argument("--hard", type=int, default=20, help="hard centroid scenes per camera")
    args = ap.parse_args()

    manifest = replay.load_set(args.set_dir)
    db_files = replay.database_files(manifest)
    frames = [c for c in manifest["cases"] if c["truth"] is not None]
    bench = dict(manifest, cases=frames)
    t0 = time.perf_counter()
    mp = micropython.replay(bench, args.set_dir, db_files, manifest["methods"],
                                    args.repeats)
    wall = time.perf_counter() - t0
    cp = cpython_figures(manifest, args.set_dir, db_files, frames, args.repeats)

    n_ok = {m: sum(c["expected"][m]["status_name"] == "OK" for c in frames)
            for m in manifest["methods"]}
    print(f"{len(frames)} recorded frames x {args.repeats} repeats per method "
          f"(MicroPython run: {wall:.0f} s of wall clock)")
    print()
    print(f"{'method':<9} {'solved':>6} | {'MicroPython ms p50':>18} {'p95':>7} "
          f"{'solved p50':>10} {'p95':>7} {'alloc/solve KB p50':>18} {'max':>7} | "
          f"{'CPython ms p50':>14} {'p95':>6} {'live peak KB p50':>16} {'max':>6}")
    for method in manifest["methods"]:
        rows = [r for r in mp["results"] if r["method"] == method]
        ms = [r["ms"] for r in rows]
        ms_ok = [r["ms"] for r in rows if r["out"]["status_name"] == "OK"]
        alloc = [r["alloc"] / 1024 for r in rows]
        c = cp[method]
        peak = [p / 1024 for p in c["peak"]]
        print(f"{method:<9} {n_ok[method]:>3}/{len(frames):<2} | "
              f"{percentile(ms, 50):>18.1f} {percentile(ms, 95):>7.1f} "
              f"{percentile(ms_ok, 50):>10.1f} {percentile(ms_ok, 95):>7.1f} "
              f"{percentile(alloc, 50):>18.0f} {max(alloc):>7.0f} | "
              f"{percentile(c['ms'], 50):>14.2f} {percentile(c['ms'], 95):>6.2f} "
              f"{statistics.median(peak):>16.1f} {max(peak):>6.1f}")
    print()
    print(replay.format_resident(mp))
    live = [r["live_before"] for r in mp["results"]]
    print(f"MicroPython live heap between solves: first {live[0] / 1024:.1f} KB, last "
          f"{mp['live_end'] / 1024:.1f} KB (growth across {len(live)} solves: "
          f"{(mp['live_end'] - live[0]) / 1024:.1f} KB)")
    print(heap_probe())
    print()
    hard = hard_peaks(manifest, db_files, manifest["methods"], args.hard)
    print(f"CPython live peak of one solve, {args.hard} hard scenes per camera (30 stars of "
          f"which 10 false, 1 px noise; budget {HEAP_BUDGET // 1024} KB):")
    for (cam_name, method), peaks in hard.items():
        kb = [p / 1024 for p in peaks]
        print(f"  {cam_name:<9} {method:<9} p50 {statistics.median(kb):6.1f} KB  max "
              f"{max(kb):6.1f} KB  {'within' if max(peaks) < HEAP_BUDGET else 'OVER'} budget")


if __name__ == "__main__":
    main()
