"""Per-stage time of the flight firmware on the Cortex-M4F build, this checkout beside a
baseline revision in the same run (issue 29, the speed half).

    .venv/bin/python benchmarks/bench_mcu_stages.py [--baseline REV] [--repeats 3]

Each side is MicroPython 1.27's qemu port built by ``build-qemu.sh OUT C 65536`` (Thumb-2,
hard single-precision FPU, floats in the object word, a 64 KiB GC heap in the F401's 96 KiB
map) with the firmware, the estcube2 flight Pyramid database (``lodestar db build --preset
estcube2 --flight --method pyramid``) and the regression set's estcube2 packets frozen in
flash; one :class:`StarTracker` over ``Database(buffer)`` of the frozen bytes replays every
packet ``--repeats`` times in a row (the first call of a tracking packet queries the
database's cone, later ones reuse it), timed by ``time.ticks_us`` under ``run-qemu.py
--icount`` (deterministic: proportional to executed instructions) and per stage through
``Settings.clock``; then the hostile Pyramid searches of ``bench_budget.py`` (work units
spent and time: the work budget in MCU time).  F401 ms is an **estimate**: units ×
:data:`US_PER_UNIT`, the published NUCLEO-F401RE times of ``bm_float`` and ``bm_nqueens``
over their units on the representation-A twin of this build (``docs/mcu_board.md``,
Measured on the Cortex-M4F build); QEMU models no flash wait states.

Needs ``arm-none-eabi-gcc``, newlib, ``qemu-system-arm`` and ``build-qemu.sh`` beside
MicroPython's ``build.sh`` (``$LODESTAR_MICROPYTHON_BUILD`` or ``../shared/micropython``).
"""

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from lodestar.firmware import starid
from lodestar.ground.database import build_database
from lodestar.ground.onboard import DEFAULT_MAX_MAG, FLIGHT_DENSITY
from lodestar.regress import replay, unixport
from lodestar.sim import presets
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import load
from lodestar.sim.centroids import centroid_scene

REPO = Path(__file__).resolve().parents[1]
BASELINE = "4641f47"
"""Main when issue 29 measured the firmware on the Cortex-M4F build."""
US_PER_UNIT = 3.18
"""F401 microseconds per ``ticks_us`` unit of the icount build: geometric mean of 3.22
(``bm_float``) and 3.13 (``bm_nqueens``), ``docs/mcu_board.md``."""
HEAP = 65536
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
from lodestar.firmware import starid
for label, tol, vecs in B.BUDGET:
    gc.collect()
    t0 = clock()
    sol = starid.identify(vecs, tr.database, method='pyramid', tolerance_rad=tol,
                          budget=1000000)
    print('WORK', label, sol.status, sol.work, time.ticks_diff(clock(), t0))
print('DONE')
"""


def build_qemu_script():
    """``build-qemu.sh`` beside MicroPython's ``build.sh``, or exit with the reason."""
    script = unixport.build_script(REPO)
    path = None if script is None else script.parent / "build-qemu.sh"
    if path is None or not path.is_file():
        sys.exit(f"bench_mcu_stages: no build-qemu.sh (set {unixport.BUILD_ENV})")
    for tool in ("arm-none-eabi-gcc", "qemu-system-arm"):
        if shutil.which(tool) is None:
            sys.exit(f"bench_mcu_stages: {tool} is not on PATH")
    return path


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


def data_module(path, db, manifest, repeats):
    """Write the frozen data module: the database, the camera, the settings, the estcube2
    packets with their inputs and the work-budget cases."""
    cam = manifest["cameras"]["estcube2"]
    cases = []
    for case in manifest["cases"]:
        if case["camera"] != "estcube2" or not case["name"].startswith("estcube2"):
            continue
        packet = (replay.DEFAULT_SET / case["packet"]).read_bytes()
        i = case["inputs"]
        omega = tuple(i["omega"]) if i.get("omega") is not None else None
        prior = tuple(i["prior"]) if i.get("prior") is not None else None
        cases.append(f"({case['name']!r}, {packet!r}, {prior!r}, {omega!r}, "
                     f"{i.get('exposure_s')!r}),")
    path.write_text(f"DB = {db!r}\nCAMERA = {cam['camera']!r}\n"
                    f"SETTINGS = ({cam['exposure_s']!r}, {cam['row_time_s']!r}, "
                    f"{cam['tolerance_px']!r})\nREPEATS = {repeats}\nCASES = [\n" +
                    "\n".join(cases) + f"\n]\nBUDGET = {budget_cases()!r}\n")


def build(label, checkout, work, db, manifest, repeats, script):
    """Stage ``checkout``'s image (None: this installation's) with the data module, build it
    and return a copy of its ``firmware.elf``."""
    side = work / label
    image = unixport.stage_mcu_image(side / "image", checkout, native=True)
    data = side / "data"
    data.mkdir(parents=True, exist_ok=True)
    data_module(data / "lodestar_bench.py", db, manifest, repeats)
    frozen = side / "manifest.py"
    frozen.write_text(f"package('lodestar', base_path={str(image)!r})\n"
                      f"module('lodestar_bench.py', base_path={str(data)!r})\n")
    env = dict(os.environ, FROZEN_MANIFEST=str(frozen))
    out = side / "mp"           # built from clean: an incremental build keeps the last
    for old in out.glob("build-*"):     # image's qstrs, which moves every time by a few %
        if old.is_dir():
            shutil.rmtree(old)
    proc = subprocess.run(["bash", str(script), str(out), "C", str(HEAP)], env=env,
                          capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"bench_mcu_stages: the {label} build failed:\n{proc.stderr[-2000:]}")
    elf = side / "firmware.elf"
    shutil.copyfile(proc.stdout.strip().splitlines()[-1], elf)
    return elf


def run(elf, script):
    """Replay on QEMU: ``{(case, repeat): {"status", "mode", "matches", "call", stage:
    units}}``."""
    runner = script.parent / "run-qemu.py"
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as f:
        f.write(SCRIPT)
    try:
        proc = subprocess.run([sys.executable, str(runner), str(elf), f.name, "--icount",
                               "--timeout", "3000"], capture_output=True, text=True)
    finally:
        os.unlink(f.name)
    if proc.returncode != 0 or "DONE" not in proc.stdout:
        sys.exit(f"bench_mcu_stages: the run on {elf} failed:\n{proc.stdout[-1500:]}"
                 f"{proc.stderr[-1500:]}")
    out = {}
    for line in proc.stdout.splitlines():
        parts = line.split()
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
    return units * US_PER_UNIT / 1000.0


def frame_class(name):
    if "tracking" in name:
        return "tracking"
    return "lost in space"


def report(results, labels):
    """Print the per-packet table and the per-class summary."""
    names = sorted({k[0] for k in results[labels[0]] if not k[0].startswith("work ")},
                   key=lambda n: (frame_class(n), n))
    repeats = max(k[1] for k in results[labels[0]]) + 1
    print("\n## Per packet, F401 ms (estimate): first call / later calls (median); stages of "
          "a later call")
    print("| packet | " + " | ".join(f"{lab} first / later" for lab in labels) + " | " +
          " | ".join(f"{labels[-1]} {s}" for s in STAGES) + " | status |")
    print("|---|" + "---|" * (len(labels) + len(STAGES) + 1))
    for name in names:
        cells = []
        for lab in labels:
            rows = [results[lab][(name, r)] for r in range(repeats)]
            later = statistics.median(r["call"] for r in rows[1:]) if repeats > 1 else None
            cells.append(f"{ms(rows[0]['call']):.1f} / " +
                         ("–" if later is None else f"{ms(later):.1f}"))
        last = results[labels[-1]][(name, repeats - 1)]
        stages = [f"{ms(last[s]):.1f}" if s in last else "–" for s in STAGES]
        status = " → ".join(str(results[lab][(name, 0)]["status"]) + "/" +
                            str(results[lab][(name, 0)]["matches"]) for lab in labels)
        print(f"| {name} | " + " | ".join(cells) + " | " + " | ".join(stages) +
              f" | {status} |")
    print("\n## Lost in space over the packets (every call), F401 ms (estimate)")
    print("| build | p50 | p95 | max |")
    print("|---|---|---|---|")
    for lab in labels:
        t = sorted(ms(r["call"]) for k, r in results[lab].items()
                   if frame_class(k[0]) == "lost in space" and not k[0].startswith("work "))
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


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default=BASELINE, help="revision to compare (default "
                    f"{BASELINE}); 'none' for this checkout only")
    ap.add_argument("--repeats", type=int, default=3, help="calls per packet (default 3)")
    ap.add_argument("--work", help="build folder kept between runs (default: a temporary one)")
    ap.add_argument("--json", help="write the raw units here")
    a = ap.parse_args()
    script = build_qemu_script()
    work = Path(a.work or tempfile.mkdtemp(prefix="bench_mcu_stages-"))
    work.mkdir(parents=True, exist_ok=True)
    manifest = json.loads((replay.DEFAULT_SET / "manifest.json").read_text())
    db = flight_database()
    sides = []
    if a.baseline != "none":
        base = work / "baseline-src"
        shutil.rmtree(base, ignore_errors=True)
        base.mkdir()
        archive = subprocess.run(["git", "-C", str(REPO), "archive", a.baseline,
                                  "lodestar/__init__.py", "lodestar/contract", "firmware"],
                                 capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(base)], input=archive, check=True)
        sides.append((a.baseline, base))
    sides.append(("now", None))
    results = {}
    for label, checkout in sides:
        elf = build(label, checkout, work, db, manifest, a.repeats, script)
        results[label] = run(elf, script)
    report(results, [label for label, _ in sides])
    if a.json:
        Path(a.json).write_text(json.dumps({lab: {f"{k[0]}#{k[1]}": v for k, v in r.items()}
                                            for lab, r in results.items()}, indent=1))


if __name__ == "__main__":
    main()
