"""Never a wrong attitude through an unknown lens: the distortion study of issue 33.

    .venv/bin/python benchmarks/bench_distortion.py [--preset estcube2|lohmann]
        [--k1 -0.4 -0.3 -0.2 -0.1 0 0.1 0.2] [--trials 6] [--workers 2] [--limit ARCSEC]
        [--own-lens] [--out FILE.json]

Each trial is a frame of ``--preset`` at rest (its camera with the radial ``k1`` set to the
level and every other distortion term zero, or with ``--own-lens`` the preset's own lens
once; the campaigns' seeds, tuned settings and rendering,
``lodestar.ground.campaign.trials.Frame``), solved the two ways ``lodestar solve`` treats a
lens it is not told: ``--fov`` (the true horizontal pinhole FOV given,
``imagesolve.image_camera``) and blind (the FOV searched, ``imagesolve.solve_image`` without
a camera); both fit the focal length and the radial distortion to the matched stars
(``lodestar.ground.lensfit``).  Wrong, as issue 33 counts it: a wrongly named star, or the
truth beyond 5 sigma on an axis or beyond 180" at the solution's instant.  Prints per level
and way: ``OK``, wrong (of those: names, beyond 5 sigma, beyond 180"), ``IMPRECISE``,
``NO_MATCH`` (other statuses named), the largest error and error over sigma, the fitted
``k1`` (mean, and the largest miss of the truth over its 1-sigma) and the CPU seconds per
solve; then, at ``--limit`` (a preset-appropriate ``max_error_arcsec``: an ``IMPRECISE``
attitude whose 5-sigma bound is within it would be ``OK`` there), the same ``OK`` and
wrong counts, and how many of the identified (``OK`` or ``IMPRECISE``, all names right) lie
within 5 sigma.  ``k1`` = -0.4 moves a star in the frame's corner by 32 px on estcube2
(normalised radius 0.22) and 17 px on lohmann (0.31).
"""

import argparse
import dataclasses
import json
import math
import multiprocessing
import time

from lodestar.firmware import pipeline
from lodestar.ground import imagesolve, lensfit
from lodestar.ground.campaign import trials
from lodestar.ground.files import write_atomic
from lodestar.ground.onboard import camera_settings
from lodestar.ground.truth import WRONG_ARCSEC, WRONG_SIGMAS, match_rows
from lodestar.sim import presets

WAYS = ("fov", "blind")
OWN = "own"
"""The level name of ``--own-lens``: the preset's whole lens (k1, k2, p1, p2)."""


def lens_camera(preset, k1):
    """The study's camera: the preset's with radial ``k1`` alone (``OWN``: its own lens)."""
    cam = presets.load_preset(preset)
    if k1 == OWN:
        return cam
    return dataclasses.replace(cam, k1=k1, k2=0.0, k3=0.0, p1=0.0, p2=0.0,
                               name=f"{preset}-k1{k1:+g}")


def judged(res, det, frame, report):
    """:func:`trials.verdict` with the names of an ``IMPRECISE`` solution judged too
    (``wrong_matches`` of ``loose``) and the fitted lens (``lens``: ``[k1, sigma_k1]``)."""
    v = trials.verdict(res, det.blobs, frame)
    if "loose" in v:
        rows = match_rows(res.matches, det.blobs, frame.truth["sources"])
        v["loose"]["wrong_matches"] = sum(not r["right"] for r in rows)
    lens = report.get("lens")
    v["lens"] = None if lens is None else [lens["k1"], lens["sigma_k1"]]
    return v


def trial(task):
    """One frame solved both ways: ``(k1, i, {way: verdict})``, each verdict with its CPU
    seconds (``cpu_s``)."""
    preset, k1, i = task
    cam = lens_camera(preset, k1)
    frame = trials.Frame(preset, camera_settings(preset, "tuned"),
                         trials.trial_seed(0, "distortion", preset, i), cam=cam)
    image = imagesolve.SkyImage(frame.image, cam.pixel_bits, "simulated", cam.width,
                                cam.height, 1, [])
    fov = math.degrees(2.0 * math.atan(cam.width / 2.0 / cam.fx_px))
    out = {}
    for way in WAYS:
        t = time.process_time()
        camera = imagesolve.image_camera(image, fov_deg=fov)[0] if way == "fov" else None
        report, det, res, _cam = imagesolve.solve_image(image, camera,
                                                        refine=lensfit.refine)
        if res is None:
            out[way] = {"status": "NO_MATCH", "solved": False, "wrong": False, "lens": None}
        else:
            out[way] = judged(res, det, frame, report)
        out[way]["cpu_s"] = time.process_time() - t
    return k1, i, out


def beyond(v, limit=WRONG_ARCSEC):
    """``(wrong name, beyond 5 sigma on an axis, beyond limit)`` of a solution (a wrong
    name: all three)."""
    if v.get("wrong_matches"):
        return True, True, True
    x, y, roll = v["error_arcsec"]
    sc, sr = v["sigma_arcsec"]
    return (False, max(abs(x), abs(y)) > WRONG_SIGMAS * sc or abs(roll) > WRONG_SIGMAS * sr,
            math.sqrt(x * x + y * y + roll * roll) > limit)


def at_limit(v, limit):
    """The solution ``v`` would be as ``max_error_arcsec`` = ``limit``: the verdict's own
    fields of an ``OK`` one, the ``loose`` ones of an ``IMPRECISE`` one whose 5-sigma bound
    is within ``limit``, else None."""
    if v["solved"] or v["wrong"]:
        return v
    loose = v.get("loose")
    if loose is None:
        return None
    if not pipeline.error_bound(*loose["sigma_arcsec"]) <= limit:
        return None
    return loose


def _row(vs, limit):
    """The counts of one level and way (:func:`summary`)."""
    ok = [v for v in vs if v["solved"] or v["wrong"]]
    err = [math.sqrt(sum(e * e for e in v["error_arcsec"])) for v in ok]
    z = [max(max(abs(v["error_arcsec"][0]), abs(v["error_arcsec"][1])) /
             v["sigma_arcsec"][0], abs(v["error_arcsec"][2]) / v["sigma_arcsec"][1])
         for v in ok]
    flags = [beyond(v) for v in ok]
    loose = [w for w in (at_limit(v, limit) for v in vs) if w is not None]
    loose_flags = [beyond(w, limit) for w in loose]
    ident = [v if v["solved"] or v["wrong"] else v["loose"] for v in vs
             if v["solved"] or v["wrong"] or "loose" in v]
    ident = [w for w in ident if not w.get("wrong_matches")]
    return {"trials": len(vs), "ok": len(ok),
            "wrong": sum(any(f) for f in flags),
            "wrong_names": sum(f[0] for f in flags),
            "beyond_5_sigma": sum(f[1] for f in flags),
            "beyond_180": sum(f[2] for f in flags),
            "imprecise": sum(v["status"] == "IMPRECISE" for v in vs),
            "no_match": sum(v["status"] == "NO_MATCH" for v in vs),
            "other": sorted({v["status"] for v in vs} - {"OK", "WRONG", "IMPRECISE",
                                                          "NO_MATCH"}),
            "max_error_arcsec": max(err) if err else None,
            "max_z": max(z) if z else None,
            "limit_ok": len(loose), "limit_wrong": sum(any(f) for f in loose_flags),
            "limit_beyond_5_sigma": sum(f[1] for f in loose_flags),
            "limit_beyond_limit": sum(f[2] for f in loose_flags),
            "limit_beyond_180": sum(beyond(w)[2] for w in loose),
            "identified": len(ident),
            "identified_within_5_sigma": sum(not beyond(w)[1] for w in ident),
            "cpu_s": sum(v["cpu_s"] for v in vs) / len(vs)}


def summary(results, levels, limit):
    """One row per level and way: :func:`_row`'s counts, and the fitted ``k1`` (mean and the
    largest ``|k1 - truth| / sigma``) where lenses were fitted."""
    rows = []
    for k1 in levels:
        for way in WAYS:
            vs = [r[way] for kk, _i, r in results if kk == k1]
            row = {"k1": k1, "way": way, **_row(vs, limit)}
            fits = [v["lens"] for v in vs if v.get("lens")]
            row["lenses"] = len(fits)
            row["k1_fitted_mean"] = sum(f[0] for f in fits) / len(fits) if fits else None
            row["k1_max_z"] = (max(abs(f[0] - k1) / f[1] for f in fits)
                               if fits and k1 != OWN else None)
            rows.append(row)
    return rows


def _print(rows, preset, trials_n, limit):
    print(f"{preset}, solved with its lens unknown, {trials_n} frames per level "
          f"(OK, wrong: names/>5sig/>180\", IMPRECISE, NO_MATCH)")
    print("   k1  way    OK  wrong  n/5s/180  IMPR  NOM  max err\"  max z   lens  k1 fit "
          f"(max z)  CPU-s | at {limit:g}\": OK wrong >5s >lim >180 | id within 5s")
    for r in rows:
        far = (f"{r['max_error_arcsec']:8.1f}  {r['max_z']:5.2f}" if r["ok"]
               else f"{'-':>8}  {'-':>5}")
        lens = (f"{r['lenses']:>2} {r['k1_fitted_mean']:+.3f}" +
                (f" ({r['k1_max_z']:4.1f})" if r["k1_max_z"] is not None else "       ")
                if r["lenses"] else f"{'-':>17}")
        k1 = f"{r['k1']:+5.2f}" if r["k1"] != OWN else f"{OWN:>5}"
        print(f"{k1}  {r['way']:<6}{r['ok']:>2}/{r['trials']:<2}{r['wrong']:>3}  "
              f"{r['wrong_names']:>2}/{r['beyond_5_sigma']}/{r['beyond_180']}  "
              f"{r['imprecise']:>4} {r['no_match']:>4}  {far}  {lens}  {r['cpu_s']:5.1f} | "
              f"{r['limit_ok']:>12} {r['limit_wrong']:>5} {r['limit_beyond_5_sigma']:>3} "
              f"{r['limit_beyond_limit']:>4} {r['limit_beyond_180']:>4} | "
              f"{r['identified_within_5_sigma']}/{r['identified']}"
              + (f"  {','.join(r['other'])}" if r["other"] else ""))
    total = {key: sum(r[key] for r in rows) for key in
             ("trials", "ok", "wrong", "wrong_names", "beyond_5_sigma", "beyond_180",
              "imprecise", "no_match", "limit_ok", "limit_wrong", "identified",
              "identified_within_5_sigma")}
    print("total: " + ", ".join(f"{k} {v}" for k, v in total.items()))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", choices=presets.PRESETS, default="estcube2")
    ap.add_argument("--k1", nargs="+", type=float, default=[-0.4, -0.3, -0.2, -0.1, 0.0,
                                                            0.1, 0.2])
    ap.add_argument("--own-lens", action="store_true",
                    help="the preset's own lens instead of the k1 levels")
    ap.add_argument("--trials", type=int, default=6)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--limit", type=float, default=WRONG_ARCSEC,
                    help="a preset-appropriate max_error_arcsec for the second count")
    ap.add_argument("--out", help="write the rows and every verdict as JSON (atomically)")
    args = ap.parse_args()
    levels = [OWN] if args.own_lens else args.k1
    tasks = [(args.preset, k1, i) for k1 in levels for i in range(args.trials)]
    with multiprocessing.Pool(args.workers) as pool:
        results = list(pool.imap_unordered(trial, tasks))
    rows = summary(results, levels, args.limit)
    _print(rows, args.preset, args.trials, args.limit)
    if args.out:
        write_atomic(args.out, json.dumps({"preset": args.preset, "trials": args.trials,
                                           "limit": args.limit, "rows": rows,
                                           "results": results}, indent=1))


if __name__ == "__main__":
    main()
