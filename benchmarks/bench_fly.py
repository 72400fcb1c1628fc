"""The twin's fault scenarios: per scenario, frames to recovery (sensor periods from the
fault's end to the next tracking solve) against the number ``docs/fly.md`` states,
availability (solved steps over the steps that read or waited for a frame, after the first
solve), wrong attitudes and how the fault shows in the telemetry; plus the twin's own speed
(wall and CPU seconds per sensor frame).

    .venv/bin/python benchmarks/bench_fly.py [--engine golden|verilator] [--window W H]
        [--frames N] [--seeds N] [--scenarios NAME...] [--json FILE]

Default: the golden engine on a 640 x 480 window of the estcube2 camera (the field and
aperture of the flight camera: ``tests/fly/conftest.py``), 45 sensor frames, the first
fault at period 20 (the ``watchdog`` scenario 25 frames more, its hang), seeds 0 and 1,
every scenario and a run without faults.  ``--window
2592 1944`` runs the flight frame (about 1 s of CPU a frame on the golden engine, 8-10 s on
the Verilated top).  Wrong: beyond 60" scaled by the window's pixel size to the flight
camera's (2.1 px).
"""

import argparse
import dataclasses
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))


def _cpu():
    own = resource.getrusage(resource.RUSAGE_SELF)
    return own.ru_utime + own.ru_stime


def camera(width, height):
    from lodestar.sim import presets

    base = presets.load_preset("estcube2")
    if (width, height) == (base.width, base.height):
        return base
    cam = presets.pinhole("estcube2", 20.2, width, height)
    return dataclasses.replace(cam, aperture_mm=base.aperture_mm)


def run_one(args, cam, scenario, seed):
    from lodestar.fly import faults, trajectory, twin
    from lodestar.sim import attitude

    q0 = attitude.random_attitude(np.random.default_rng(seed))
    path = trajectory.Trajectory("rest", q0)
    wrong = twin.WRONG_ARCSEC * 2592 / cam.width
    t0, c0 = time.perf_counter(), _cpu()
    loop = twin.Twin(cam, twin.make_engine(args.engine, cam), path, trajectory.Gyro(path, seed),
                     [scenario] if scenario else [], args.fault_frame, seed,
                     wrong_arcsec=wrong)
    frames = args.frames + (faults.HANG_MS // 100 if scenario == "watchdog" else 0)
    rows = loop.run(frames)
    s = twin.summary(rows, loop)
    rec = s["recovery"].get(scenario, {})
    return {"scenario": scenario or "none", "seed": seed, "wrong": s["wrong"],
            "frames_to_recovery": rec.get("frames_to_recovery"), "stated": rec.get("stated"),
            "within": rec.get("within", True), "availability": s["availability_after_first"],
            "solved": s["solved"], "steps": s["steps"], "reboots": s["reboots"],
            "health": {k: v for k, v in s["health"].items() if v},
            "link": {k: v for k, v in s["link"].items() if v},
            "wall_s_per_frame": (time.perf_counter() - t0) / frames,
            "cpu_s_per_frame": (_cpu() - c0) / frames}


def table(results):
    lines = ["| scenario | seed | frames to recovery (stated) | availability | wrong | "
             "shows in telemetry | CPU s / frame |", "|---|---|---|---|---|---|---|"]
    for r in results:
        shown = ", ".join(f"{k} {v}" for k, v in {**r["health"], **r["link"]}.items()
                          if k not in ("frames", "ok", "packets", "status", "sensor_init",
                                       "frames_skipped", "overflow", "resync"))
        rec = "-" if r["scenario"] == "none" else f"{r['frames_to_recovery']} ({r['stated']})"
        lines.append(f"| {r['scenario']} | {r['seed']} | {rec} | "
                     f"{100 * r['availability']:.0f} % | {r['wrong']} | {shown or '-'} | "
                     f"{r['cpu_s_per_frame']:.2f} |")
    return "\n".join(lines)


def main():
    from lodestar.fly import faults

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--engine", choices=("golden", "verilator"), default="golden")
    p.add_argument("--window", nargs=2, type=int, default=(640, 480))
    p.add_argument("--frames", type=int, default=45)
    p.add_argument("--fault-frame", type=int, default=20)
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--scenarios", nargs="+", default=[None] + list(faults.SCENARIOS))
    p.add_argument("--json", default=None)
    args = p.parse_args()
    cam = camera(*args.window)
    results = []
    for scenario in args.scenarios:
        for seed in range(args.seeds):
            results.append(run_one(args, cam, None if scenario in (None, "none") else scenario,
                                   seed))
            print(json.dumps(results[-1]), file=sys.stderr, flush=True)
    print(table(results))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
