"""The twin's fault scenarios: per scenario, frames to recovery (sensor periods from the
fault's end to the next tracking solve) against the number ``docs/fly.md`` states,
availability (solved steps over the steps that read or waited for a frame, after the first
solve), wrong attitudes and how the fault shows in the telemetry; plus the twin's own speed
(wall and CPU seconds per sensor frame).

    .venv/bin/python benchmarks/bench_fly.py [--engine golden|verilator] [--window W H]
        [--frames N] [--seeds N] [--first-seed K] [--scenarios NAME...] [--combined]
        [--json FILE]
    .venv/bin/python benchmarks/bench_fly.py --table FILE.json...   # saved runs' table

Default: the golden engine on a 640 x 480 window of the estcube2 camera (the field and
aperture of the flight camera: ``tests/fly/conftest.py``), 45 sensor frames, the first
fault at period 20 (the ``watchdog`` scenario 25 frames more, its hang), seeds 0 and 1,
every scenario and a run without faults, each its own run; ``--combined``: every scenario
in one run, 15 periods apart (``db-crc`` from boot), each judged over its own stretch.
``--window
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
    frames = (args.frames or 45) + (faults.HANG_MS // 100 if scenario == "watchdog" else 0)
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


def _counters(loop):
    from lodestar.firmware import executive
    from lodestar.firmware import link as _link

    out = {name: loop.exe.health[i] for i, name in enumerate(executive.HEALTH_NAMES)}
    out.update({name: loop.link.counters[i] for i, name in enumerate(_link.COUNTER_NAMES)})
    return out


def _deltas(snaps):
    """Counter increments over consecutive snapshots (a counter that fell was reset with
    the MCU: its new value is all increment)."""
    out = {}
    for before, after in zip(snaps, snaps[1:]):
        for k, v in after.items():
            d = v - before.get(k, 0) if v >= before.get(k, 0) else v
            if d:
                out[k] = out.get(k, 0) + d
    return out


def run_combined(args, cam, scenarios, seed):
    """One run with every scenario of ``scenarios`` in turn (``db-crc`` from boot, the
    others ``SPACING`` periods apart from ``--fault-frame``): per scenario the figures of
    :func:`run_one`, over the steps from its start to the next one's; and the run's rows."""
    from lodestar.fly import faults, trajectory, twin
    from lodestar.sim import attitude

    q0 = attitude.random_attitude(np.random.default_rng(seed))
    path = trajectory.Trajectory("rest", q0)
    wrong = twin.WRONG_ARCSEC * 2592 / cam.width
    t0, c0 = time.perf_counter(), _cpu()
    loop = twin.Twin(cam, twin.make_engine(args.engine, cam), path, trajectory.Gyro(path, seed),
                     scenarios, args.fault_frame, seed, wrong_arcsec=wrong)
    timed = [n for n in scenarios if n != "db-crc"]
    frames = args.frames or (args.fault_frame + faults.SPACING * len(timed) + 5
                             + (faults.HANG_MS // 100 if "watchdog" in timed else 0))
    rows, snaps = [], [_counters(loop)]
    while loop.world.frame_index < frames and len(rows) < 20 * frames + 50:
        row = loop.step()
        row["index"] = len(rows)
        rows.append(row)
        snaps.append(_counters(loop))
        print(f"step {len(rows)} t {row['t_s']:.3f} {row['mode']} {row['status']} "
              f"{row['faults']}", file=sys.stderr, flush=True)
    s = twin.summary(rows, loop)
    first = s["first_solve_step"] or 0
    starts = sorted((w[0], n) for n, w in loop.schedule.windows.items())
    out = []
    for k, (start, name) in enumerate(starts):
        end = starts[k + 1][0] if k + 1 < len(starts) else float("inf")
        idx = [i for i, r in enumerate(rows) if start <= r["t_s"] < end]
        steps = [rows[i] for i in idx if i >= first
                 and (rows[i]["frame"] is not None or rows[i]["status"] != "NO_FRAME")]
        rec = s["recovery"][name]
        counted = _deltas([snaps[i] for i in ([idx[0]] + [i + 1 for i in idx])]) if idx else {}
        out.append({"scenario": name, "seed": seed,
                    "wrong": sum(rows[i]["wrong"] for i in idx),
                    "frames_to_recovery": rec["frames_to_recovery"], "stated": rec["stated"],
                    "within": rec["within"],
                    "availability": (sum(r["status"] == "OK" for r in steps) / len(steps)
                                     if steps else 0.0),
                    "solved": sum(rows[i]["status"] == "OK" for i in idx), "steps": len(idx),
                    "reboots": s["reboots"],
                    "health": {k: v for k, v in counted.items() if k in s["health"]},
                    "link": {k: v for k, v in counted.items() if k in s["link"]},
                    "wall_s_per_frame": (time.perf_counter() - t0) / frames,
                    "cpu_s_per_frame": (_cpu() - c0) / frames})
    return out, rows


def table(results):
    lines = ["| scenario | seed | frames to recovery (stated) | availability | wrong | "
             "shows in telemetry | CPU s / frame |", "|---|---|---|---|---|---|---|"]
    for r in results:
        shown = ", ".join(f"{k} {v}" for k, v in {**r["health"], **r["link"]}.items()
                          if k not in ("frames", "ok", "packets", "status", "sensor_init",
                                       "frames_skipped", "overflow", "resync", "missed"))
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
    p.add_argument("--frames", type=int, default=None,
                   help="sensor frames per run (default 45; --combined: to the last "
                        "scenario's end)")
    p.add_argument("--fault-frame", type=int, default=20)
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--first-seed", type=int, default=0,
                   help="the first sky seed (the runs take seeds FIRST .. FIRST + SEEDS - 1)")
    p.add_argument("--scenarios", nargs="+", default=[None] + list(faults.SCENARIOS))
    p.add_argument("--combined", action="store_true",
                   help="every scenario in one run, each --fault-frame + 15 k periods")
    p.add_argument("--json", default=None)
    p.add_argument("--table", nargs="+", default=None, metavar="FILE",
                   help="print the table of the results saved by earlier --json runs")
    args = p.parse_args()
    if args.table:
        print(table([r for f in args.table for r in json.loads(Path(f).read_text())]))
        return
    cam = camera(*args.window)
    results = []
    if args.combined:
        names = [n for n in args.scenarios if n not in (None, "none")]
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            got, rows = run_combined(args, cam, names, seed)
            results += got
            if args.json:
                Path(args.json).with_suffix(f".rows{seed}.json").write_text(json.dumps(rows))
        args.scenarios = []
    for scenario in args.scenarios:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            results.append(run_one(args, cam, None if scenario in (None, "none") else scenario,
                                   seed))
            print(json.dumps(results[-1]), file=sys.stderr, flush=True)
    print(table(results))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
