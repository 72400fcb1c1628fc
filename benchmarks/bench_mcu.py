"""The flight firmware as the STM32F401 runs it: heap, time and flash, measured on MicroPython
1.27's unix port built as the flight build (32-bit, single-precision floats in the object word,
``MICROPY_OBJ_REPR_C``, the firmware frozen: ``lodestar.regress.unixport``), against a
baseline revision built the same way in the same run.

    .venv/bin/python benchmarks/bench_mcu.py [--baseline REV] [--repeats 3]

* **heap**: per method and camera, the smallest heap (2 KiB steps) with which the regression
  packets, one after another in one process with the camera's database open, give the
  recorded results; and the largest live peak of one solve per packet class (rest and moving
  lost-in-space, tracking), baseline beside current.
* **time**: per packet class and method, the wall time of ``StarTracker.process`` at a 64 KiB
  heap (best of ``--repeats``; the collector's work included) and the stage times of the
  slowest solve, on this machine; then an **estimate** for an STM32F401 at 84 MHz: the
  time here times how much slower a NUCLEO-F401RE ran two of MicroPython's own benchmarks
  (published figures, run here on the same MicroPython in the published run's object
  representation A, ``unixport.reference_build``: :mod:`lodestar.regress.mcutime`).
* **instructions**: per packet class and method, the instructions of ``process`` (valgrind's
  count of the build's x86 instructions: the same under any load) and each stage's, scaled to
  the F401 by the same benchmarks' microseconds per instruction on the representation-A
  build (needs ``valgrind``).
* **flash**: the frozen firmware's bytecode (``mpy-cross`` of the build) and the estcube2
  database of each method, with where each lives.

Needs MicroPython's ``build.sh`` (``$LODESTAR_MICROPYTHON_BUILD`` or ``../shared``) and git.
"""

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from lodestar import contract as C
from lodestar.contract.stardb import METHODS
from lodestar.ground.cache import default_cache_dir
from lodestar.ground.database import build_database
from lodestar.ground.onboard import DEFAULT_MAX_MAG, FLIGHT_DENSITY
from lodestar.regress import mcutime, replay, unixport
from lodestar.sim import presets

REPO = Path(__file__).resolve().parents[1]
BASELINE = "1118c7c"
"""The firmware before the heap work of issue 16."""
HEAP = 64 * 1024
def packet_class(case):
    """``tracking`` (a prior given), ``bad packet`` (a decoder status), ``moving`` (a body
    rate given) or ``rest``."""
    if case["inputs"].get("prior") is not None:
        return "tracking"
    if 1 <= case["expected"]["pyramid"]["status"] <= 7:
        return "bad packet"
    omega = case["inputs"].get("omega")
    return "moving" if omega and any(omega) else "rest"


def build(checkout, out_dir):
    script = unixport.build_script(REPO)
    if script is None:
        sys.exit(f"bench_mcu: no MicroPython build script (set {unixport.BUILD_ENV})")
    return unixport.build(script, REPO / "manifest.py", out_dir, "float32", checkout=checkout)


def heap_table(binaries, manifest, db_files):
    print(f"\n## Heap (32-bit float32, REPR_C, frozen): smallest working heap (packet buffer "
          f"{unixport.FLIGHT_BUFFER} B: {C.FLIGHT_RECORD_CAPACITY} records) and live peak, KiB")
    print("| method | camera | smallest heap, baseline -> now | live peak rest / moving / "
          "tracking, baseline -> now |")
    print("|---|---|---|---|")
    for method in manifest["methods"]:
        for camera in manifest["cameras"]:
            runs = [(c, method) for c in manifest["cases"] if c["camera"] == camera]
            cells = []
            for binary in binaries:
                low = unixport.min_heap(binary, manifest, replay.DEFAULT_SET, db_files, runs,
                                        buffer_bytes=unixport.FLIGHT_BUFFER)
                loop = unixport.flight_loop(binary, manifest, replay.DEFAULT_SET, db_files,
                                            runs, 4 << 20, peak=True)
                peaks = {}
                for case, _ in runs:
                    cls = packet_class(case)
                    peaks[cls] = max(peaks.get(cls, 0),
                                     loop["results"][(case["name"], method)][1])
                cells.append((low, peaks))
            (low0, p0), (low1, p1) = cells
            peak_text = " / ".join(f"{p0[k] / 1024:.1f} -> {p1[k] / 1024:.1f}" if k in p1
                                   else "-" for k in ("rest", "moving", "tracking"))
            print(f"| {method} | {camera} | {low0 / 1024:.0f} -> {low1 / 1024:.0f} | "
                  f"{peak_text} |")


def time_table(binary, reference, manifest, db_files, repeats):
    """Per method and packet class: the wall time of ``process`` on the flight ``binary``
    and the F401 estimate, scaled by the benchmarks on the ``reference`` build."""
    cal = mcutime.calibrate(reference)
    scale = cal["scale"]
    ratios = ", ".join(f"{name} {mcutime.F401_US[name]:,.0f} us there / {min(us)} us here = "
                       f"{cal['ratio'][name]:.0f}x" for name, us in cal["runs"].items())
    print(f"\n## Time: F401 estimate = time here x {scale:.0f} (geometric mean of {ratios}, "
          f"on the representation-A build; {mcutime.F401_SOURCE})")
    print("| method | class | solves | here p50 / p95 / max, ms | F401 estimate p50 / p95 / "
          "max, ms | slowest solve's stages here, ms |")
    print("|---|---|---|---|---|---|")
    for method in manifest["methods"]:
        runs = [(c, method) for c in manifest["cases"]]
        best = {}
        for _ in range(repeats):
            for camera in manifest["cameras"]:
                part = [r for r in runs if r[0]["camera"] == camera]
                loop = unixport.flight_loop(binary, manifest, replay.DEFAULT_SET, db_files,
                                            part, HEAP, timing=True)
                for key, times in loop["times"].items():
                    if key not in best or times["process"] < best[key]["process"]:
                        best[key] = times
        for cls in ("rest", "moving", "tracking"):
            cases = [c for c, _ in runs if packet_class(c) == cls]
            ms = sorted(best[(c["name"], method)]["process"] / 1000 for c in cases)
            if not ms:
                continue
            p95 = ms[min(len(ms) - 1, int(round(0.95 * (len(ms) - 1))))]
            slowest = max(cases, key=lambda c: best[(c["name"], method)]["process"])
            stages = best[(slowest["name"], method)]
            stage_text = ", ".join(f"{k} {v / 1000:.0f}" for k, v in stages.items()
                                   if k not in ("process", "total"))
            print(f"| {method} | {cls} | {len(ms)} | {statistics.median(ms):.0f} / {p95:.0f} / "
                  f"{ms[-1]:.0f} | {statistics.median(ms) * scale:.0f} / {p95 * scale:.0f} / "
                  f"{ms[-1] * scale:.0f} | {stage_text} |")


def instruction_table(binary, reference, manifest, db_files):
    """Per method and packet class: the instructions of ``process`` on the flight ``binary``
    (valgrind, the second of two frames) and the F401 estimate from them (ns per
    instruction of the benchmarks on the ``reference`` build); the slowest frame's stages."""
    if mcutime.valgrind() is None:
        print("\n## Instructions: skipped (valgrind is not installed)")
        return
    cal = mcutime.calibrate_instructions(reference)
    per = ", ".join(f"{name} {cal['ir'][name] / 1e6:.2f} M instructions on A here, "
                    f"{mcutime.F401_US[name]:,.0f} us there" for name in cal["ir"])
    us_per = cal["us_per_ir_mean"]
    print(f"\n## Instructions at a {HEAP // 1024} KiB heap: F401 estimate = instructions x "
          f"{us_per * 1e3:.2f} ns ({per}; {mcutime.F401_SOURCE})")
    print("| method | class | solves | instructions p50 / p95 / max, M | F401 estimate p50 / "
          "p95 / max, ms | slowest frame's stages, F401 ms |")
    print("|---|---|---|---|---|---|")
    for method in manifest["methods"]:
        stages = {}
        for case in manifest["cases"]:
            if packet_class(case) == "bad packet":
                continue
            camera = manifest["cameras"][case["camera"]]
            _, stages[case["name"]] = mcutime.frame_instructions(
                binary, case, method, db_files[camera["database"]], camera,
                replay.DEFAULT_SET / case["packet"], HEAP)
        for cls in ("rest", "moving", "tracking"):
            names = [c["name"] for c in manifest["cases"] if packet_class(c) == cls]
            ir = sorted(stages[n]["process"] for n in names)
            if not ir:
                continue
            p95 = ir[min(len(ir) - 1, int(round(0.95 * (len(ir) - 1))))]
            slowest = max(names, key=lambda n: stages[n]["process"])
            split = ", ".join(f"{k} {v * us_per / 1e3:.0f}" for k, v in stages[slowest].items()
                              if k != "process")
            print(f"| {method} | {cls} | {len(ir)} | {statistics.median(ir) / 1e6:.1f} / "
                  f"{p95 / 1e6:.1f} / {ir[-1] / 1e6:.1f} | "
                  f"{statistics.median(ir) * us_per / 1e3:.0f} / {p95 * us_per / 1e3:.0f} / "
                  f"{ir[-1] * us_per / 1e3:.0f} | {split} |")


def flash_table(binary):
    """The frozen bytecode of the MCU image ``binary`` froze (its build folder's ``mpy-cross``
    and staged image) and the estcube2 databases."""
    out_dir = Path(binary).parent
    mpy_cross = next(out_dir.glob("micropython-*/mpy-cross/build/mpy-cross"))
    image = out_dir / "mcu-image"
    total = 0
    with tempfile.TemporaryDirectory() as tmp:
        for py in sorted(image.rglob("*.py")):
            mpy = Path(tmp) / (py.stem + ".mpy")
            subprocess.run([str(mpy_cross), "-march=armv7emsp", "-o", str(mpy), str(py)],
                           check=True)
            total += mpy.stat().st_size
    print("\n## Flash")
    print("| item | bytes | where |")
    print("|---|---|---|")
    print(f"| firmware + contract, frozen bytecode (mpy-cross, armv7emsp) | {total:,} | "
          "MCU internal flash (512 KiB, with MicroPython itself) |")
    camera = presets.load_preset("estcube2")
    for method in METHODS:
        size = len(build_database(camera=camera, methods=(method,), mag_limit=DEFAULT_MAX_MAG,
                                  **FLIGHT_DENSITY))
        print(f"| estcube2 flight database (`db build --flight`), {method} | {size:,} | "
              "F-RAM (512 KiB) behind the FPGA, or internal flash when it fits beside the "
              "firmware |")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--baseline", default=BASELINE, help="git revision to compare with")
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args()
    manifest = replay.load_set(replay.DEFAULT_SET)
    db_files = replay.database_files(manifest)
    cache = default_cache_dir() / "micropython-bench"   # not replaced by a test run
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        base_tree = Path(tmp) / "baseline"
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "-q", "--detach",
                        str(base_tree), args.baseline], check=True)
        try:
            baseline = build(base_tree, default_cache_dir() / "micropython-baseline")
        finally:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force",
                            str(base_tree)], check=True)
    current = build(None, cache)
    reference = unixport.reference_build(repo=REPO)
    print(f"# bench_mcu: baseline {args.baseline} -> working tree; builds "
          f"{time.perf_counter() - t0:.0f} s")
    heap_table((baseline, current), manifest, db_files)
    time_table(current, reference, manifest, db_files, args.repeats)
    instruction_table(current, reference, manifest, db_files)
    flash_table(current)


if __name__ == "__main__":
    main()
