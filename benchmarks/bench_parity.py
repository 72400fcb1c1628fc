"""What the parity check (``Search.mirrored``, ``docs/apparent_directions.md``) costs and
finds, per identification method, on synthetic estcube2 centroid scenes (CPython timings):

* *normal*: random attitudes, 0.3 px noise, up to 5 false stars: solve time with the check
  and with it switched off (``Search.mirrored`` returning the failure as it is);
* *failing*: false stars only (8-24 in the frame): time of the failed search with and
  without the check;
* *mirrored*: the normal scenes flipped in x (even) or y (odd): how many end ``MIRRORED``,
  how many get an attitude (must be 0), and their time.

    .venv/bin/python benchmarks/bench_parity.py [--scenes 40] [--methods pyramid,triangle,hashing]
"""

import argparse
import time

import numpy as np

from lodestar.firmware import starid, status
from lodestar.firmware.database import Database
from lodestar.firmware.starid import search
from lodestar.ground.database import build_database
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import load
from lodestar.sim.centroids import centroid_scene
from lodestar.sim.presets import load_preset

TOL = 3.0e-4
"""Match tolerance, rad (about 2.2 px of estcube2), as the star-id tests."""


REPEATS = 3
"""Each timing is the fastest of this many runs (the machine is shared)."""


def _timed(vectors, db, method):
    best = None
    for _ in range(REPEATS):
        t = time.perf_counter()
        sol = starid.identify(vectors, db, method=method, tolerance_rad=TOL)
        ms = (time.perf_counter() - t) * 1e3
        best = ms if best is None or ms < best else best
    return sol, best


def _both(vectors, db, method):
    """``(solution, ms)`` with the check, then ``(solution, ms)`` without it."""
    with_check = _timed(vectors, db, method)
    real = search.Search.mirrored
    search.Search.mirrored = lambda self, first, kept, size, failed: failed
    try:
        without = _timed(vectors, db, method)
    finally:
        search.Search.mirrored = real
    return with_check, without


def run(n, methods):
    cam = load_preset("estcube2")
    cat = load()
    db = Database(build_database(cat, cam, mag_limit=6.0, methods=tuple(methods)))
    print(f"{n} scenes per row, estcube2, V <= 6 database, tolerance {TOL} rad")
    print("method   | normal ms p50 (off) | failing ms p50/p95 (off)     | "
          "mirrored: MIRRORED / attitude / ms p50")
    for method in methods:
        rng = np.random.default_rng(7)
        normal, normal_off, fail, fail_off, mir_ms = ([] for _ in range(5))
        n_mirrored = n_attitude = 0
        for k in range(n):
            scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.3,
                                   n_false=int(rng.integers(0, 6)), max_stars=30)
            (sol, ms), (_sol, ms_off) = _both(scene.vectors.tolist(), db, method)
            normal.append(ms)
            normal_off.append(ms_off)
            flip = [-1.0, 1.0, 1.0] if k % 2 == 0 else [1.0, -1.0, 1.0]
            msol, ms = _timed((scene.vectors * flip).tolist(), db, method)
            n_mirrored += msol.status == status.MIRRORED
            n_attitude += msol.q is not None
            mir_ms.append(ms)
            m = int(rng.integers(8, 25))
            false = cam.unproject(rng.uniform(0, cam.width - 1, m),
                                  rng.uniform(0, cam.height - 1, m))
            (_fsol, ms), (_fsol_off, ms_off) = _both(false.tolist(), db, method)
            fail.append(ms)
            fail_off.append(ms_off)
        p = np.percentile
        print(f"{method:8s} | {p(normal, 50):8.2f} ({p(normal_off, 50):6.2f}) | "
              f"{p(fail, 50):6.1f}/{p(fail, 95):6.1f} ({p(fail_off, 50):6.1f}/"
              f"{p(fail_off, 95):6.1f}) | {n_mirrored}/{n} / {n_attitude} / "
              f"{p(mir_ms, 50):.1f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=int, default=40)
    ap.add_argument("--methods", default=",".join(starid.METHODS))
    args = ap.parse_args()
    run(args.scenes, args.methods.split(","))


if __name__ == "__main__":
    main()
