"""Benchmark of the ground solve at unknown FOV and of failing solves
(``lodestar.ground.solve.solve_centroids``; ``docs/solve_centroids.md``, Unknown FOV and
Failures fast).

Scenes: a centred pinhole 1024 x 768 px at a uniformly random attitude; the shipped catalogue
to V 8 in the frame (close doubles blended), 5 % dropped, 0.3 px centroid noise, 3 false
stars, brightness order jittered by 0.2 mag, the 40 brightest kept, fluxes falling with the
order.

* ``blind``: per FOV (``--fovs``), solved with no FOV given: solved, wrong (attitude error
  > 0.05 deg), the fitted FOV's relative error (p95 of its absolute value) and the solve time.
* ``known``: the same scenes with the true FOV, with the ground work budget
  (:data:`lodestar.ground.solve.GROUND_MAX_WORK`) and with the firmware's default
  (:data:`lodestar.firmware.starid.search.DEFAULT_MAX_WORK`): what the budget costs.
* ``failing``: frames that cannot be solved: 40 random centroids at each FOV (known FOV),
  real scenes given a FOV 25 % too wide, real scenes cut to their 5 brightest stars, and
  random centroids at unknown FOV: p50 / p95 / max time; the issue asks p95 <= 300 ms
  (``--max-work 5000000``: the firmware's default budget, as before).

Times are this process's CPU time (``--clock wall``: the wall clock); databases and the quad
index are built (and cached) before timing.

    .venv/bin/python benchmarks/bench_fov.py                     # 20 scenes per FOV
    .venv/bin/python benchmarks/bench_fov.py --scenes 100 --fovs 8,10,15,20,25,30
"""

import argparse
import time

import numpy as np

from lodestar.firmware.starid.search import DEFAULT_MAX_WORK
from lodestar.ground import fovsearch, solve
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import load
from lodestar.sim.centroids import attitude_error_deg, centroid_scene
from lodestar.sim.presets import pinhole as pinhole_preset

W, H = 1024, 768
MAX_ERR_DEG = 0.05
CLOCKS = {"cpu": time.process_time, "wall": time.perf_counter}


def pinhole(fov_deg):
    """The estcube2 sensor cut to ``W x H`` as a centred pinhole of ``fov_deg``."""
    return pinhole_preset("estcube2", fov_deg, W, H)


def scenes(fov_deg, n, rng, cat):
    """``n`` ``(scene, rows)`` of the module docstring at ``fov_deg``."""
    cam = pinhole(fov_deg)
    out = []
    for _ in range(n):
        sc = centroid_scene(cam, random_attitude(rng), rng, cat, mag_limit=8.0, noise_px=0.3,
                            n_false=3, drop_fraction=0.05, max_stars=40)
        out.append((sc, np.column_stack([sc.pixels, 1e5 / (1.0 + np.arange(len(sc)))])))
    return out


def timed(clock, **kwargs):
    t0 = clock()
    res = solve.solve_centroids(**kwargs)
    return res, (clock() - t0) * 1e3


def stats(ms):
    ms = np.asarray(ms)
    return f"p50 {np.median(ms):7.1f}  p95 {np.percentile(ms, 95):7.1f}  max {ms.max():7.1f} ms"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=20, help="scenes per FOV and kind")
    parser.add_argument("--fovs", default="8,10,15,20,25,30", help="horizontal FOVs, deg")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--clock", choices=tuple(CLOCKS), default="cpu")
    parser.add_argument("--max-work", type=int, default=solve.GROUND_MAX_WORK,
                        help="work budget of the failing solves (default the ground's; "
                             f"{DEFAULT_MAX_WORK} is the firmware's, the behaviour before)")
    parser.add_argument("--skip", default="", help="comma-separated parts to skip "
                        "(blind, known, failing)")
    args = parser.parse_args(argv)
    clock = CLOCKS[args.clock]
    skip = set(args.skip.split(","))
    fovs = [float(f) for f in args.fovs.split(",")]
    rng = np.random.default_rng(args.seed)
    cat = load()
    t0 = time.perf_counter()
    fovsearch.load_index()
    print(f"quad index ready in {time.perf_counter() - t0:.1f} s; {args.clock} clock; "
          f"{args.scenes} scenes per FOV, {W}x{H}")
    per_fov = {fov: scenes(fov, args.scenes, rng, cat) for fov in fovs}
    for fov in fovs:                       # build the databases outside the timing
        solve.solve_centroids(per_fov[fov][0][1], W, H, fov)
        solve.solve_centroids(per_fov[fov][0][1], W, H, fov * 1.25)

    if "blind" not in skip:
        print("\nblind (no FOV given)")
        for fov in fovs:
            ok = wrong = 0
            errs, ms = [], []
            for sc, rows in per_fov[fov]:
                res, dt = timed(clock, centroids=rows, width=W, height=H)
                ms.append(dt)
                if res.ok:
                    if attitude_error_deg(res.q, sc.q) > MAX_ERR_DEG:
                        wrong += 1
                    else:
                        ok += 1
                        errs.append(abs(res.fov_deg[0] / fov - 1))
            fov_err = f"{np.percentile(errs, 95):.2e}" if errs else "-"
            print(f"  {fov:5.1f} deg: solved {ok}/{len(ms)}, wrong {wrong}, |FOV error| p95 "
                  f"{fov_err}; {stats(ms)}")

    if "known" not in skip:
        print("\nknown FOV: ground budget vs the firmware default")
        for fov in fovs:
            line = f"  {fov:5.1f} deg:"
            for name, work in (("ground", solve.GROUND_MAX_WORK), ("default", DEFAULT_MAX_WORK)):
                ok, ms = 0, []
                for sc, rows in per_fov[fov]:
                    res, dt = timed(clock, centroids=rows, width=W, height=H, fov_deg=fov,
                                    max_work=work)
                    ms.append(dt)
                    ok += res.ok and attitude_error_deg(res.q, sc.q) <= MAX_ERR_DEG
                line += f"  {name} {ok}/{len(ms)} p95 {np.percentile(ms, 95):6.1f} ms"
            print(line)

    if "failing" not in skip:
        print("\nfailing solves")
        kinds = {"random stars": [], "FOV 25 % too wide": [], "5 stars": [],
                 "random, unknown FOV": []}
        statuses = {k: {} for k in kinds}
        for fov in fovs:
            for _sc, rows in per_fov[fov]:
                rnd = np.column_stack([rng.uniform(-0.5, W - 0.5, 40),
                                       rng.uniform(-0.5, H - 0.5, 40),
                                       1e5 / (1.0 + np.arange(40))])
                for kind, kw in (("random stars", dict(centroids=rnd, fov_deg=fov)),
                                 ("FOV 25 % too wide", dict(centroids=rows, fov_deg=fov * 1.25)),
                                 ("5 stars", dict(centroids=rows[:5], fov_deg=fov)),
                                 ("random, unknown FOV", dict(centroids=rnd))):
                    res, dt = timed(clock, width=W, height=H, max_work=args.max_work, **kw)
                    if res.ok:
                        continue           # solved after all: not a failing solve
                    kinds[kind].append(dt)
                    statuses[kind][res.status_name] = statuses[kind].get(res.status_name, 0) + 1
        everything = []
        for kind, ms in kinds.items():
            everything += ms
            if ms:
                print(f"  {kind:<20} n={len(ms):4d}  {stats(ms)}  {statuses[kind]}")
        print(f"  {'all':<20} n={len(everything):4d}  {stats(everything)}  (issue: p95 <= "
              f"300 ms)")


if __name__ == "__main__":
    main()
