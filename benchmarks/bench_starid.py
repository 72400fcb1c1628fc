"""Monte Carlo benchmark of the flight star identification (Pyramid over the pair k-vector,
Lohmann's planar triangle over the triangle k-vector, Astrometry.net geometric hashing over
the hash buckets; one database image holding all three) on synthetic estcube2 centroid
scenes (CPython timings; the MCU is slower).

A scene: a uniformly random attitude, every V <= 6.0 star in the 2592 x 1944 frame
(close doubles blended), a fraction dropped, Gaussian centroid noise, false stars uniform in
the frame with V uniform in [1, 6], brightness order jittered by 0.2 mag, the 30 brightest
kept.  *correct*: accepted, attitude error <= 0.05 deg and every reported HIP right;
*wrong*: accepted otherwise; *no-solve*: any other status.  (The one *wrong* of the
hardest row, 0.5 px / 10 false / 30 % dropped, is the same scene for every method: attitude
right to 16 arcsec, but a false star fell 1.2 px from a dropped V 3.7 star, HIP 80170, and was
named as it -- indistinguishable from the star itself.)  The grid mirrors the tetra3
anchor table (anchors_software.md section 1.6).

    .venv/bin/python benchmarks/bench_starid.py [--scenes 500] [--per-region 6]
        [--methods pyramid,triangle,hashing]
"""

import argparse
import time

import numpy as np

from lodestar.firmware import starid, status
from lodestar.firmware.database import Database
from lodestar.ground.database import build_database, describe
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import load
from lodestar.sim.centroids import attitude_error_deg, centroid_scene
from lodestar.sim.presets import load_preset

IFOV = 1.375e-4     # rad per pixel of estcube2 (2.2 um / 16 mm)


def tolerance(noise_px):
    """Match tolerance for a centroid noise: 3e-4 rad (2.2 px), or 4 sigma if larger."""
    return max(3.0e-4, 4.0 * noise_px * IFOV)

GRID = [  # (noise px, false stars, drop fraction)
    (0.0, 0, 0.0), (0.5, 0, 0.0), (1.0, 0, 0.0), (0.3, 3, 0.1), (0.5, 5, 0.1),
    (0.5, 10, 0.1), (0.5, 5, 0.3), (0.5, 10, 0.3),
]


def run(db, cam, cat, n, noise, n_false, drop, seed, mirror=False, method="pyramid"):
    rng = np.random.default_rng(seed)
    counts = {"correct": 0, "wrong": 0, "no-solve": 0}
    times, errors, tried = [], [], []
    for _ in range(n):
        q = random_attitude(rng)
        scene = centroid_scene(cam, q, rng, cat, noise_px=noise, n_false=n_false,
                               drop_fraction=drop, max_stars=30)
        vectors = scene.vectors * ([-1.0, 1.0, 1.0] if mirror else 1.0)
        t0 = time.perf_counter()
        sol = starid.identify(vectors.tolist(), db, method=method,
                              tolerance_rad=tolerance(noise))
        times.append(time.perf_counter() - t0)
        tried.append(sol.patterns_tried)
        if sol.status != status.OK:
            counts["no-solve"] += 1
            continue
        err = attitude_error_deg(sol.q, q)
        good = err <= 0.05 and all(h in scene.components[o] for o, h in sol.matches)
        counts["correct" if good else "wrong"] += 1
        if good:
            errors.append(err * 3600)
    t = np.array(times) * 1e3
    return counts, t, np.array(errors), np.array(tried)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=500)
    parser.add_argument("--per-region", type=int, default=6)
    parser.add_argument("--methods", default=",".join(starid.METHODS))
    args = parser.parse_args(argv)
    methods = tuple(args.methods.split(","))
    cam, cat = load_preset("estcube2"), load()
    t0 = time.perf_counter()
    image = build_database(cat, cam, mag_limit=6.0, pattern_per_region=args.per_region,
                           methods=methods)
    build_s = time.perf_counter() - t0
    info = describe(image)
    db = Database(image)
    print(f"database: {len(image)} B ({len(image) / 1024:.1f} KiB), {info['n_stars']} stars, "
          f"{info['n_pattern_stars']} pattern stars, {info['n_pairs']} pairs, "
          f"{info.get('triangles', {}).get('n', 0)} triangles, "
          f"{info.get('hash', {}).get('n', 0)} hash groups; built in {build_s:.2f} s")
    print("sections (B):", info["section_bytes"])
    print(f"estcube2, V <= 6.0, tolerance max(3e-4 rad, 4 sigma), {args.scenes} scenes per row")
    for method in methods:
        print(f"\n{method}")
        print(f"{'noise':>5} {'false':>5} {'drop':>4} | {'correct':>7} {'wrong':>5} "
              f"{'no-sol':>6} | {'p50':>6} {'p95':>6} {'max':>7} ms | {'err p50':>7} "
              f"{'p95':>5} arcsec | {'patterns p95':>12}")
        for i, (noise, n_false, drop) in enumerate(GRID):
            counts, t, err, tried = run(db, cam, cat, args.scenes, noise, n_false, drop,
                                        seed=i, method=method)
            print(f"{noise:5.1f} {n_false:5d} {drop:4.1f} | {counts['correct']:7d} "
                  f"{counts['wrong']:5d} {counts['no-solve']:6d} | "
                  f"{np.percentile(t, 50):6.2f} {np.percentile(t, 95):6.2f} {t.max():7.1f} ms | "
                  f"{np.percentile(err, 50):7.1f} {np.percentile(err, 95):5.1f} arcsec | "
                  f"{np.percentile(tried, 95):12.0f}")
        n_mirror = min(args.scenes, 200)
        counts, t, _, _ = run(db, cam, cat, n_mirror, 0.3, 2, 0.1, seed=99, mirror=True,
                              method=method)
        print(f"mirrored scenes: accepted {counts['correct'] + counts['wrong']} of "
              f"{n_mirror}; p50 {np.percentile(t, 50):.1f} ms, max {t.max():.1f} ms")


if __name__ == "__main__":
    main()
