"""Catalogue depth by density against fixed magnitude limits, on narrow and wide fields:
``lodestar.ground.solve.solve_centroids`` at its default database (about 30 stars and 10
pattern stars per field, ``docs/stardb.md``) beside databases of every star to V 6 and V 7,
on the same synthetic scenes.

A scene (:func:`lodestar.sim.centroids.centroid_scene`): a 1024 x 768 pinhole camera of
horizontal FOV ``--fov``, a uniformly random attitude, every star of the whole Hipparcos to
V 9 in the frame (close doubles blended), 10 % dropped, 0.3 px centroid noise, 3 false stars
(V 1-6), the 40 brightest kept; fluxes fall with the brightness order.  *solved*: status
OK with every named star right (a blend may be named after any of its components);
*wrong*: OK with a star named wrongly (a false star named after a catalogue star is not
counted).  Times: the solve alone (database cached), ms.

    .venv/bin/python benchmarks/bench_density.py --fov 6.1 --scenes 100
"""

import argparse
import dataclasses
import math
import os
import tempfile

import numpy as np

from lodestar.ground import solve
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import load_deep
from lodestar.sim.centroids import centroid_scene
from lodestar.sim.presets import load_preset

WIDTH, HEIGHT = 1024, 768
DEPTHS = {"V<=6": 6.0, "V<=7": 7.0, "density": None}


def camera(fov_deg):
    """A sim camera of the estcube2 sensor model, ``WIDTH x HEIGHT``, pinhole ``fov_deg``."""
    base = load_preset("estcube2")
    f = (WIDTH / 2) / math.tan(math.radians(fov_deg) / 2)
    return dataclasses.replace(base, width=WIDTH, height=HEIGHT, fx_px=f, fy_px=f,
                               cx=(WIDTH - 1) / 2, cy=(HEIGHT - 1) / 2,
                               focal_length_mm=f * base.pixel_pitch_um / 1000)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fov", type=float, default=6.1, help="horizontal FOV, deg")
    ap.add_argument("--scenes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args(argv)
    os.environ.setdefault("LODESTAR_CACHE_DIR", tempfile.mkdtemp(prefix="lodestar-bench-"))
    cam, deep = camera(args.fov), load_deep()
    rng = np.random.default_rng(args.seed)
    tally = {name: {"solved": 0, "wrong": 0, "ms": []} for name in DEPTHS}
    for _ in range(args.scenes):
        scene = centroid_scene(cam, random_attitude(rng), rng, catalogue=deep, mag_limit=9.0,
                               noise_px=0.3, n_false=3, drop_fraction=0.1, max_stars=40)
        flux = 10 ** (-0.04 * np.arange(len(scene.hip)))
        rows = np.column_stack([scene.pixels, flux])
        for name, mag in DEPTHS.items():
            res = solve.solve_centroids(rows, WIDTH, HEIGHT, args.fov, max_mag=mag)
            wrong = res.ok and any(scene.hip[i] and h not in scene.components[i]
                                   for i, h in res.matches.items())
            tally[name]["solved"] += res.ok and not wrong
            tally[name]["wrong"] += wrong
            tally[name]["ms"].append(res.solve_ms)
    print(f"FOV {args.fov:g} deg, {args.scenes} scenes")
    for name, t in tally.items():
        p50, p95 = np.percentile(t["ms"], [50, 95])
        print(f"{name:>8}: solved {t['solved']}/{args.scenes}, wrong {t['wrong']}, "
              f"p50 {p50:.0f} ms, p95 {p95:.0f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
