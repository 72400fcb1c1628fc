"""The flight database's flash budget against availability: the same campaign frames
(estcube2, the ``rate`` study's seeds and settings) solved with each database variant in
one run, so the difference is the database alone.  Variants: ``magnitude`` (every star to
V 6.0, the database before issue 16) and ``density`` (the flight selection,
:data:`lodestar.ground.onboard.FLIGHT_DENSITY`), or any ``--variant NAME:V:P[:K[:PAIR]]``
(V verification and P pattern stars per field, 0 for every star; K stars per separation,
default 6; PAIR the longest pair, deg, default the FOV diagonal).  Prints the image sizes
and, per rate and variant, solved / wrong / failures by status.

    .venv/bin/python benchmarks/bench_flight_db.py [--rest 200] [--moving 100] [--rate 2]
        [--method pyramid] [--workers 1]
"""

import argparse
import collections
import concurrent.futures
import time

from lodestar.firmware.database import Database
from lodestar.ground import onboard
from lodestar.ground.campaign import trials
from lodestar.ground.database import build_database
from lodestar.ground.onboard import camera_settings
from lodestar.sim.presets import load_preset

PRESET = "estcube2"
_DB = {}


def _variants(specs):
    out = {"magnitude": None, "density": dict(onboard.FLIGHT_DENSITY)}
    for spec in specs or ():
        name, *values = spec.split(":")
        v, p, k, pair = (values + [0, 0, 0, 0])[:4]
        out[name] = {"verification_stars_per_fov": float(v) or None,
                     "pattern_stars_per_fov": float(p) or None,
                     "density_per_region": int(k) or None,
                     "max_pair_angle_deg": float(pair) or None}
    return out


def _image(density, method):
    return build_database(camera=load_preset(PRESET), mag_limit=onboard.DEFAULT_MAX_MAG,
                          method=method, **(density or {}))


def _trial(args):
    rate, trial, variants, method = args
    key = (tuple(sorted((k, str(v)) for k, v in variants.items())), method)
    if key not in _DB:
        _DB[key] = {name: Database(_image(d, method)) for name, d in variants.items()}
    settings = camera_settings(PRESET)
    frame = trials.Frame(PRESET, settings, trials.trial_seed(0, "rate", PRESET, trial), rate,
                         "cross")
    out = {}
    for name, db in _DB[key].items():
        _data, res, timings = onboard.process(
            frame.det, frame.fw_cam, db, omega=frame.omega_rad_s,
            exposure_s=frame.truth["exposure_s"], row_time_s=frame.truth["row_time_s"],
            method=method)
        verdict = trials.verdict(res, frame.det.blobs, frame)
        out[name] = (verdict["status"], verdict["solved"] and not verdict["wrong"],
                     verdict["wrong"], timings["solve"])
    return rate, out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rest", type=int, default=200, help="frames at rest")
    ap.add_argument("--moving", type=int, default=100, help="frames at --rate")
    ap.add_argument("--rate", type=float, default=2.0, help="cross-boresight rate, deg/s")
    ap.add_argument("--method", default="pyramid")
    ap.add_argument("--variant", action="append", metavar="NAME:V:P[:K[:PAIR]]")
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args(argv)
    variants = _variants(args.variant)
    for name, density in variants.items():
        size = len(_image(density, args.method))
        print(f"{name:>10}: {density or 'every star to V 6.0'}: {size:,} B "
              f"({size / 1024:.1f} KiB)")
    jobs = [(0.0, t, variants, args.method) for t in range(args.rest)]
    jobs += [(args.rate, t, variants, args.method) for t in range(args.moving)]
    tally = collections.defaultdict(lambda: collections.Counter())
    times = collections.defaultdict(list)
    t0 = time.perf_counter()
    with concurrent.futures.ProcessPoolExecutor(args.workers) as pool:
        for rate, out in pool.map(_trial, jobs, chunksize=4):
            for name, (status, ok, wrong, ms) in out.items():
                tally[(rate, name)]["frames"] += 1
                tally[(rate, name)]["solved"] += ok
                tally[(rate, name)]["wrong"] += wrong
                tally[(rate, name)][status] += not ok
                times[(rate, name)].append(ms)
    print(f"{'rate':>6} {'variant':>10} {'solved':>12} {'wrong':>6} {'p50 ms':>7}  failures")
    for (rate, name), c in sorted(tally.items()):
        ms = sorted(times[(rate, name)])
        fails = {k: v for k, v in c.items() if k not in ("frames", "solved", "wrong") and v}
        print(f"{rate:6g} {name:>10} {c['solved']:>5}/{c['frames']:<6} {c['wrong']:>6} "
              f"{ms[len(ms) // 2]:7.1f}  {fails}")
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
