"""Never a wrong attitude through an unmodelled lens: the distortion study of issue 33.

    .venv/bin/python benchmarks/bench_distortion.py [--preset estcube2|lohmann]
        [--k1 -0.4 -0.3 -0.2 -0.1 0 0.1 0.2] [--trials 6] [--workers 2] [--out FILE.json]

Each trial is a frame of ``--preset`` at rest (its camera with the radial ``k1`` set to the
level and every other distortion term zero; the campaigns' seeds, tuned settings and
rendering, ``lodestar.ground.campaign.trials.Frame``), solved the two ways ``lodestar solve``
treats an unknown lens, both as a pinhole: ``--fov`` (the true horizontal FOV given,
``imagesolve.image_camera``) and blind (the FOV searched, ``imagesolve.solve_image`` without
a camera).  Wrong, as issue 33 counts it: a wrongly named star, or the truth beyond 5 sigma
on an axis or beyond 180" at the solution's instant.  Prints per level and way: solved,
wrong (of those: beyond 5 sigma, beyond 180"), refused (with their statuses), the largest
error and error over sigma.  ``k1`` = -0.4 moves a star in the frame's corner by 32 px on
estcube2 (normalised radius 0.22) and 17 px on lohmann (0.31).
"""

import argparse
import dataclasses
import json
import math
import multiprocessing

from lodestar.ground import imagesolve
from lodestar.ground.campaign import trials
from lodestar.ground.files import write_atomic
from lodestar.ground.onboard import camera_settings
from lodestar.ground.truth import WRONG_ARCSEC, WRONG_SIGMAS
from lodestar.sim import presets

WAYS = ("fov", "blind")


def lens_camera(preset, k1):
    """The study's camera: the preset's with radial ``k1`` alone."""
    cam = presets.load_preset(preset)
    return dataclasses.replace(cam, k1=k1, k2=0.0, k3=0.0, p1=0.0, p2=0.0,
                               name=f"{preset}-k1{k1:+g}")


def trial(task):
    """One frame solved both ways: ``(k1, i, {way: verdict})``."""
    preset, k1, i = task
    cam = lens_camera(preset, k1)
    frame = trials.Frame(preset, camera_settings(preset, "tuned"),
                         trials.trial_seed(0, "distortion", preset, i), cam=cam)
    image = imagesolve.SkyImage(frame.image, cam.pixel_bits, "simulated", cam.width,
                                cam.height, 1, [])
    fov = math.degrees(2.0 * math.atan(cam.width / 2.0 / cam.fx_px))
    out = {}
    for way in WAYS:
        camera = imagesolve.image_camera(image, fov_deg=fov)[0] if way == "fov" else None
        _report, det, res, _cam = imagesolve.solve_image(image, camera)
        if res is None:
            out[way] = {"status": "NO_MATCH", "solved": False, "wrong": False}
        else:
            out[way] = trials.verdict(res, det.blobs, frame)
    return k1, i, out


def beyond(v):
    """``(beyond 5 sigma on an axis, beyond 180")`` of a solution (a wrong name: both)."""
    if v.get("wrong_matches"):
        return True, True
    x, y, roll = v["error_arcsec"]
    sc, sr = v["sigma_arcsec"]
    return (max(abs(x), abs(y)) > WRONG_SIGMAS * sc or abs(roll) > WRONG_SIGMAS * sr,
            math.sqrt(x * x + y * y + roll * roll) > WRONG_ARCSEC)


def summary(results, levels):
    rows = []
    for k1 in levels:
        for way in WAYS:
            vs = [r[way] for kk, _i, r in results if kk == k1]
            ok = [v for v in vs if v["solved"] or v["wrong"]]
            err = [math.sqrt(sum(e * e for e in v["error_arcsec"])) for v in ok]
            z = [max(max(abs(v["error_arcsec"][0]), abs(v["error_arcsec"][1])) /
                     v["sigma_arcsec"][0], abs(v["error_arcsec"][2]) / v["sigma_arcsec"][1])
                 for v in ok]
            flags = [beyond(v) for v in ok]
            rows.append({"k1": k1, "way": way, "trials": len(vs), "solved": len(ok),
                         "wrong": sum(a or b for a, b in flags),
                         "beyond_5_sigma": sum(a for a, _b in flags),
                         "beyond_180": sum(b for _a, b in flags),
                         "refused": len(vs) - len(ok),
                         "max_error_arcsec": max(err) if err else None,
                         "max_z": max(z) if z else None,
                         "statuses": sorted({v["status"] for v in vs if v not in ok})})
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", choices=presets.PRESETS, default="estcube2")
    ap.add_argument("--k1", nargs="+", type=float, default=[-0.4, -0.3, -0.2, -0.1, 0.0,
                                                            0.1, 0.2])
    ap.add_argument("--trials", type=int, default=6)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", help="write the rows and every verdict as JSON (atomically)")
    args = ap.parse_args()
    tasks = [(args.preset, k1, i) for k1 in args.k1 for i in range(args.trials)]
    with multiprocessing.Pool(args.workers) as pool:
        results = list(pool.imap_unordered(trial, tasks))
    rows = summary(results, args.k1)
    print(f"{args.preset} with radial k1 only, solved as a pinhole, {args.trials} frames per level")
    print("   k1  way    solved wrong >5sig >180\" refused  max error\"  max z  refused as")
    for r in rows:
        far = (f"{r['max_error_arcsec']:9.1f}  {r['max_z']:5.2f}" if r["solved"]
               else f"{'-':>9}  {'-':>5}")
        print(f"{r['k1']:+5.2f}  {r['way']:<6} {r['solved']:>3}/{r['trials']:<3}"
              f"{r['wrong']:>4} {r['beyond_5_sigma']:>5} {r['beyond_180']:>5} "
              f"{r['refused']:>6}  {far}  {','.join(r['statuses'])}")
    if args.out:
        write_atomic(args.out, json.dumps({"preset": args.preset, "trials": args.trials,
                                           "rows": rows, "results": results}, indent=1))


if __name__ == "__main__":
    main()
