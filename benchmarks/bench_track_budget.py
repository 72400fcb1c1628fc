"""The record budget of tracking frames (``Result.min_sum``, ``Settings.track_stars``): what
it costs in accuracy and saves in MCU time, side by side with every blob, in one run.

    .venv/bin/python benchmarks/bench_track_budget.py [--trials 30] [--rate 1.0]
        [--stars 8 10 12] [--timed 10]

Each trial simulates an estcube2 frame (campaign seeds, ``lodestar.ground.campaign.trials``)
at rest and one turning at ``--rate`` deg/s about a cross-boresight axis, detects it with
the flight registers and every blob, and tracks it on CPython from the true attitude turned
by 7 arcsec (a steady prior, as ``estcube2_tracking_steady``).  For each ``track_stars``
the same image is detected again with the ``min_sum`` that solve returned (the flight
loop's steady state: the budget keeps the same brightest stars) and tracked again.  Prints
per frame class and budget: frames solved, wrong, the records per frame (median, max), the
RMS cross-boresight and roll errors against the simulator's truth and their ratio to every
blob's over the same frames, and the 1-sigma figures' median ratio.  ``--timed``: the first
so many frames of each class are replayed on the flight build (``lodestar.regress``, a
64 KiB heap) and their instructions and F401 estimate (``mcutime``) reported (p50, max).
"""

import argparse
import dataclasses
import math
import statistics
import tempfile
from pathlib import Path

import numpy as np

from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import Settings
from lodestar.golden import detect_frame
from lodestar.ground import codec, onboard
from lodestar.ground.campaign import trials
from lodestar.ground.truth import attitude_error_arcsec
from lodestar.regress import mcutime, unixport
from lodestar.sim import attitude, presets, scene

REPO = Path(__file__).resolve().parents[1]
PRESET = "estcube2"
PRIOR_ERROR_DEG = 0.002


def rms(values):
    return math.sqrt(sum(v * v for v in values) / len(values)) if values else float("nan")


def prior_of(q, rng):
    """``q`` turned by :data:`PRIOR_ERROR_DEG` about a random axis."""
    from scipy.spatial.transform import Rotation
    axis = rng.standard_normal(3)
    axis *= math.radians(PRIOR_ERROR_DEG) / np.linalg.norm(axis)
    return [float(v) for v in (Rotation.from_rotvec(axis) * Rotation.from_quat(q)).as_quat()]


def frames(n_trials, rate, seed):
    """``(label, image, det config, q, omega_deg_s, truth)`` per frame."""
    cam = presets.load_preset(PRESET)
    settings = onboard.camera_settings(PRESET)
    for label, level in (("rest", 0.0), (f"{rate:g} deg/s", rate)):
        for trial in range(n_trials):
            s = trials.trial_seed(seed, "budget", PRESET, trial)
            rng = np.random.default_rng(s)
            q = attitude.random_attitude(rng)
            omega = trials.rate_vector(rng, level, "cross")
            sim = scene.simulate(cam, q, omega, settings["exposure_s"], s)
            yield label, sim.frame, onboard.detector_config(cam, settings), q, omega, sim.truth, s


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--trials", type=int, default=30)
    p.add_argument("--rate", type=float, default=1.0)
    p.add_argument("--stars", type=int, nargs="+", default=[8, 10, 12])
    p.add_argument("--timed", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    cam = presets.load_preset(PRESET)
    fw_cam = onboard.firmware_camera(cam)
    db, db_path = onboard.star_database(fw_cam)
    exposure = onboard.camera_settings(PRESET)["exposure_s"] or cam.exposure_s
    row_time = cam.row_time_s if cam.shutter == "rolling" else 0.0
    tol = onboard.default_tolerance_px(fw_cam)
    budgets = [None] + list(args.stars)

    def tracker(k):
        return StarTracker(db, fw_cam, Settings(exposure_s=exposure, row_time_s=row_time,
                                                tolerance_px=tol, track_stars=k))

    trackers = {k: tracker(k) for k in budgets}
    rows = {}               # (label, k) -> list of (ok, wrong, records, error, sigma)
    packets = {}            # (label, k) -> [(packet bytes, inputs)] for the timed replays
    for label, image, cfg, q, omega, truth, s in frames(args.trials, args.rate, args.seed):
        rng = np.random.default_rng(s + 1)
        inputs = {"prior": prior_of(q, rng), "omega": [math.radians(w) for w in omega],
                  "exposure_s": truth["exposure_s"], "dt": None}
        det = detect_frame(image, cfg)
        full = trackers[None].process(codec.encode(det), prior=inputs["prior"],
                                      omega=inputs["omega"], exposure_s=exposure)
        for k in budgets:
            if k is None:
                d, res = det, full
            else:
                ms = trackers[k].process(codec.encode(det), prior=inputs["prior"],
                                         omega=inputs["omega"], exposure_s=exposure).min_sum
                d = detect_frame(image, dataclasses.replace(cfg, min_sum=ms)) if ms else det
                res = trackers[k].process(codec.encode(d), prior=inputs["prior"],
                                          omega=inputs["omega"], exposure_s=exposure)
            data = codec.encode(d)
            packets.setdefault((label, k), []).append((data, inputs))
            row = [res.ok, False, len(d.blobs), None, None]
            if res.ok:
                err = attitude_error_arcsec(res.q, q)
                hips = {src["hip"] for src in truth["sources"] if src.get("hip")}
                row[1] = err["total"] > 60 or any(m[3] not in hips for m in res.matches)
                row[3] = (math.hypot(err["x"], err["y"]) / math.sqrt(2), err["roll"])
                row[4] = (res.sigma_cross_arcsec, res.sigma_roll_arcsec)
            rows.setdefault((label, k), []).append(row)
    print(f"{args.trials} frames per class, tracked from a prior {PRIOR_ERROR_DEG} deg off; "
          f"budget None: every blob")
    print(f"{'class':>10} {'budget':>6} {'solved':>6} {'wrong':>5} {'records p50/max':>15} "
          f"{'cross rms':>9} {'roll rms':>8} {'x/all':>6} {'roll/all':>8} {'sigma/all':>9}")
    for label in dict.fromkeys(lbl for lbl, _k in rows):
        base = rows[label, None]
        for k in budgets:
            r = rows[label, k]
            both = [i for i in range(len(r)) if r[i][0] and base[i][0]]
            cross = rms([r[i][3][0] for i in both])
            roll = rms([r[i][3][1] for i in both])
            cross0 = rms([base[i][3][0] for i in both])
            roll0 = rms([base[i][3][1] for i in both])
            sig = statistics.median(r[i][4][0] / base[i][4][0] for i in both) if both else 0
            recs = [x[2] for x in r]
            print(f"{label:>10} {k!s:>6} {sum(x[0] for x in r):>6} {sum(x[1] for x in r):>5} "
                  f"{statistics.median(recs):>9.0f}/{max(recs):<5} {cross:>9.2f} {roll:>8.1f} "
                  f"{cross / cross0:>6.2f} {roll / roll0:>8.2f} {sig:>9.2f}")
    if args.timed <= 0:
        return
    binary = unixport.float32_build(repo=REPO)
    us_per = mcutime.calibrate_instructions(unixport.reference_build(repo=REPO))[
        "us_per_ir_mean"]
    camera = {"camera": fw_cam.as_dict(), "exposure_s": exposure, "row_time_s": row_time,
              "tolerance_px": tol}
    print(f"\nflight build {binary.name}, 64 KiB heap, first {args.timed} frames per class: "
          f"instructions (M) and F401 estimate (ms, {us_per * 1e3:.2f} ns per instruction), "
          "p50 / max")
    with tempfile.TemporaryDirectory() as tmp:
        for (label, k), items in packets.items():
            counts = []
            for i, (data, inputs) in enumerate(items[:args.timed]):
                path = Path(tmp) / f"{i}.bin"
                path.write_bytes(data)
                status, stages = mcutime.frame_instructions(
                    binary, {"inputs": inputs}, "pyramid", db_path, camera, path, 64 * 1024)
                counts.append(stages["process"])
            counts.sort()
            p50, top = statistics.median(counts), counts[-1]
            print(f"{label:>10} budget {k!s:>4}: {p50 / 1e6:6.2f} / {top / 1e6:6.2f} M  "
                  f"{p50 * us_per / 1e3:5.0f} / {top * us_per / 1e3:5.0f} ms")


if __name__ == "__main__":
    main()
