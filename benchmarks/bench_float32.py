"""Accuracy at rest of the single-precision MCU build against the double-precision one: the
same simulated frames (a ``lodestar campaign rate`` at 0 deg/s) solved by the firmware on
CPython (double) and on the flight build of MicroPython 1.27's unix port (32-bit, float32 in
the object word, the firmware frozen: ``lodestar.regress.unixport``; a 64 KiB heap and the
flight packet buffer, ``contract.FLIGHT_RECORD_CAPACITY`` records, frames with more not run;
and a 4 MiB heap, every frame), in one run.

    .venv/bin/python benchmarks/bench_float32.py [--preset estcube2] [--trials 100]

Prints per build the solved and wrong counts, the RMS cross-boresight and roll errors against
the simulator's truth and their ratio float32 / double over the same frames (the goal of
issue 16: within 10 %),
and the largest difference between the two builds' attitudes of one frame (cross-boresight
and roll, arcsec).
"""

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np

from lodestar import contract as C
from lodestar.ground.campaign import trials
from lodestar.ground.onboard import camera_settings, default_tolerance_px, process, star_database
from lodestar.ground.truth import attitude_error_arcsec
from lodestar.regress import unixport

REPO = Path(__file__).resolve().parents[1]
HEAP = 64 * 1024


def rms(values):
    return math.sqrt(sum(v * v for v in values) / len(values)) if values else float("nan")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--preset", default="estcube2")
    p.add_argument("--trials", type=int, default=100)
    p.add_argument("--method", default="pyramid")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    settings = camera_settings(args.preset)
    binary = unixport.float32_build(repo=REPO)
    frames, double = [], []         # double: (verdict, q, [(record index, HIP)])
    for trial in range(args.trials):
        frame = trials.Frame(args.preset, settings, trials.trial_seed(args.seed, "rate",
                                                                      args.preset,
                                                            trial))
        db, _path = star_database(frame.fw_cam, method=args.method)
        data, res, _ = process(frame.det, frame.fw_cam, db, omega=frame.omega_rad_s,
                               exposure_s=frame.truth["exposure_s"],
                               row_time_s=frame.truth["row_time_s"], method=args.method)
        frames.append((frame, data))
        double.append((trials.verdict(res, frame.det.blobs, frame), res.q,
                       [(m[0], m[3]) for m in res.matches]))
    frame0 = frames[0][0]
    _db, db_path = star_database(frame0.fw_cam, method=args.method)
    cam = frame0.fw_cam
    camera = {"camera": {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy,
                         "cx": cam.cx, "cy": cam.cy, "k1": cam.k1, "k2": cam.k2, "k3": cam.k3,
                         "p1": cam.p1, "p2": cam.p2},
              "exposure_s": frame0.truth["exposure_s"],
              "row_time_s": frame0.truth["row_time_s"],
              "tolerance_px": default_tolerance_px(cam), "database": "db"}
    with tempfile.TemporaryDirectory() as tmp:
        cases = []
        for i, (frame, data) in enumerate(frames):
            (Path(tmp) / f"{i}.bin").write_bytes(data)
            cases.append({"name": str(i), "camera": "cam", "packet": f"{i}.bin",
                          "inputs": {"omega": frame.omega_rad_s,
                                     "exposure_s": frame.truth["exposure_s"]}})
        manifest = {"cameras": {"cam": camera}}
        runs = [(c, args.method) for c in cases]
        # the flight loop: a packet buffer for the flight gateware's record capacity, which
        # sends no frame with more records (it drops the rest; those frames are not run)
        flight = [(c, m) for c, m in runs
                  if (Path(tmp) / c["packet"]).stat().st_size <= unixport.FLIGHT_BUFFER]
        loops = {HEAP: unixport.flight_loop(binary, manifest, tmp, {"db": db_path}, flight,
                                            HEAP, buffer_bytes=unixport.FLIGHT_BUFFER),
                 4 << 20: unixport.flight_loop(binary, manifest, tmp, {"db": db_path}, runs,
                                               4 << 20)}
    print(f"# bench_float32: {args.preset}, {args.trials} frames at rest, {args.method}; "
          f"float32 build {binary.name}")
    records = sorted(len(frame.det.blobs) for frame, _data in frames)
    print(f"records per frame: min {records[0]}, median {records[len(records) // 2]}, "
          f"p95 {records[int(0.95 * (len(records) - 1))]}, max {records[-1]}; "
          f"{len(runs) - len(flight)} over the flight capacity "
          f"({C.FLIGHT_RECORD_CAPACITY}), not run at {HEAP // 1024} KiB")
    rows = {"double (CPython)": _errors(frames, double, None)}
    for heap, loop in loops.items():
        if not loop["finished"]:
            raise SystemExit("bench_float32: the float32 loop failed:\n" + loop["error"])
        rows[f"float32, {heap // 1024} KiB heap"] = _errors(frames, double, loop, args.method)
    print("| build | right | failed (status: count) | same stars as double | RMS cross, "
          "arcsec | RMS roll, arcsec | largest difference from double, cross / roll, arcsec |")
    print("|---|---|---|---|---|---|---|")
    for name, r in rows.items():
        base = _errors(frames, double, None, only=r["frames"])     # the same frames
        fails = ", ".join(f"{k}: {v}" for k, v in sorted(r["failed"].items())) or "-"
        print(f"| {name} | {r['right']} | {fails} | {r['same']} | {r['cross']:.3f} "
              f"({r['cross'] / base['cross']:.3f}) | {r['roll']:.2f} "
              f"({r['roll'] / base['roll']:.3f}) | {r['between_cross']:.2f} / "
              f"{r['between_roll']:.2f} |")


def _errors(frames, double, loop, method=None, only=None):
    """Errors against the truth of the frames the double build got right (of those in
    ``only``, frame indices, when given); ``loop``: a float32 flight loop (None: the double
    build itself).  ``frames``: the indices of the frames counted."""
    cross, roll, between_cross, between_roll, same, failed = [], [], [0.0], [0.0], 0, {}
    counted = set()
    for i, (frame, _data) in enumerate(frames):
        verdict, q_double, ids_double = double[i]
        if not (verdict["solved"] and not verdict["wrong"]) or (only is not None and
                                                                 i not in only):
            continue
        if loop is None:
            q, ids = q_double, ids_double
        else:
            got = loop["results"].get((str(i), method))
            if got is None:
                failed["over capacity, not run"] = failed.get("over capacity, not run", 0) + 1
                continue
            out = got[0]
            if out["status"] != 0:
                failed[out["status_name"]] = failed.get(out["status_name"], 0) + 1
                continue
            q, ids = out["q"], [tuple(m) for m in out["matches"]]
        counted.add(i)
        same += ids == ids_double
        e = attitude_error_arcsec(q, frame.q)
        cross += [e["x"], e["y"]]
        roll.append(e["roll"])
        d = attitude_error_arcsec(q, q_double)
        between_cross.append(d["cross"])
        between_roll.append(abs(d["roll"]))
    return {"right": len(roll), "failed": failed, "same": same, "cross": rms(cross),
            "roll": rms(roll), "between_cross": max(between_cross),
            "between_roll": max(between_roll), "frames": counted}

if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
