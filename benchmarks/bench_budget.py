"""The work budget of the flight identification, measured: wall time and work units of the
hostile cases of issue 19 (wide tolerances, many false stars) at the default budget, beside
the same searches without a budget (the baseline, cut at ``--cap`` seconds).  CPython on
this machine; the MCU is slower by its own factor.

    .venv/bin/python benchmarks/bench_budget.py [--cap 30]
"""

import argparse
import signal
import time

import numpy as np

from lodestar.firmware import starid
from lodestar.firmware import status as S
from lodestar.firmware.database import Database
from lodestar.firmware.starid import search
from lodestar.ground.database import build_database
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import load
from lodestar.sim.centroids import centroid_scene
from lodestar.sim.presets import load_preset


class _Cut(Exception):
    pass


def _timed(vectors, db, method, tol, max_work, cap):
    """``(status name, work units, seconds)`` of one identification (``cap`` s at most)."""
    def cut(*_):
        raise _Cut

    signal.signal(signal.SIGALRM, cut)
    signal.alarm(cap)
    t = time.perf_counter()
    try:
        sol = starid.identify(vectors, db, method=method, tolerance_rad=tol, budget=10 ** 6,
                              max_work=max_work)
        status, work = S.name(sol.status), sol.work
    except _Cut:
        status, work = f"> {cap} s", None
    finally:
        signal.alarm(0)
    return status, work, time.perf_counter() - t


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cap", type=int, default=30, help="seconds per unbudgeted search")
    args = parser.parse_args()
    cam = load_preset("estcube2")
    cat = load()
    rng = np.random.default_rng(7)
    scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=1.0, n_false=10,
                           max_stars=30)
    vectors = [tuple(v) for v in scene.vectors.tolist()]
    print(f"{'method':9} {'tolerance':>10} {'budget':>10}  status              work      s   "
          f"| unbudgeted: status          work       s")
    for method in starid.METHODS:
        db = Database(build_database(cat, cam, mag_limit=6.0, methods=(method,)))
        px = db.fov_h / cam.width
        for tol_px in (2.5, 30.0, 100.0, 0.049 * db.fov_h / px):
            tol = tol_px * px
            got = _timed(vectors, db, method, tol, search.DEFAULT_MAX_WORK, args.cap)
            free = _timed(vectors, db, method, tol, 10 ** 15, args.cap)
            print(f"{method:9} {tol_px:8.1f}px {search.DEFAULT_MAX_WORK:>10}  {got[0]:16} "
                  f"{got[1]:>9} {got[2]:6.2f} | {free[0]:16} {free[1] or '-':>10} {free[2]:7.2f}",
                  flush=True)


if __name__ == "__main__":
    main()
