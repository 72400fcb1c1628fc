"""Wrong identities on narrow fields with false stars and magnitude noise.

    .venv/bin/python benchmarks/bench_narrow_ids.py [--scenes 20] [--fovs 6 7 8]
        [--out FILE.json]

Centroid scenes (``lodestar.sim.centroids.centroid_scene``) of a 1024 x 768 pinhole of the
estcube2 sensor (``lodestar.sim.presets.pinhole``) at random attitudes over the whole
Hipparcos (``lodestar.sim.catalogue.load_deep``), in three harshness configurations (as the
reliability review's narrow-field scenes): stars to V 9.0 / 9.0 / 9.5, centroid noise 0.3 /
0.5 / 0.5 px, 3 / 6 / 10 false stars at random places with V in the star range, 5 / 10 / 10 %
of the stars dropped, magnitude-order jitter 0.3 / 0.5 / 0.8 mag, the 40 brightest kept;
each row's flux falls with its rank.  Each is solved by
``lodestar.ground.solve.solve_centroids(rows, 1024, 768, fov)``.  A match is wrong when its
HIP is not among the stars blended into that centroid (a false star named is wrong).
Prints per FOV and configuration: scenes, solved (``OK``), ``IMPRECISE`` (named, the
attitude's 5-sigma bound beyond 180": the identities count), matches, wrong matches, scenes
with a wrong match; and the total wrong-identity rate with its one-sided 95 % Clopper-Pearson upper
bound (:func:`upper_bound`: the issue asks for below 1 in 2,000 with that confidence).  Run
it with another checkout's interpreter to compare firmware versions on the same scenes (the
seeds are fixed).
"""

import argparse
import json

import numpy as np
from scipy import stats

from lodestar.ground.solve import solve_centroids
from lodestar.sim import attitude, catalogue, centroids, presets

CONFIGS = {
    "A": {"mag_limit": 9.0, "noise_px": 0.3, "n_false": 3, "drop_fraction": 0.05,
          "mag_jitter": 0.3},
    "B": {"mag_limit": 9.0, "noise_px": 0.5, "n_false": 6, "drop_fraction": 0.10,
          "mag_jitter": 0.5},
    "C": {"mag_limit": 9.5, "noise_px": 0.5, "n_false": 10, "drop_fraction": 0.10,
          "mag_jitter": 0.8},
}
WIDTH, HEIGHT, MAX_STARS = 1024, 768, 40
CONFIDENCE = 0.95
"""One-sided confidence of the wrong-identity rate's upper bound."""


def upper_bound(wrong, matches, confidence=CONFIDENCE):
    """One-sided Clopper-Pearson upper bound of a rate of ``wrong`` in ``matches`` (the
    ``confidence`` quantile of Beta(wrong + 1, matches - wrong)): 1 of 9,500 gives
    1 / 2,003."""
    if wrong >= matches:
        return 1.0
    return float(stats.beta.ppf(confidence, wrong + 1, matches - wrong))


def run(fov, name, scenes, cat):
    """``scenes`` solves at ``fov`` in configuration ``name``: a row of counts."""
    cam = presets.pinhole("estcube2", fov, WIDTH, HEIGHT)
    cfg = CONFIGS[name]
    row = {"fov_deg": fov, "config": name, "scenes": scenes, "solved": 0, "imprecise": 0,
           "matches": 0,
           "wrong": 0, "scenes_wrong": 0, "wrong_cases": []}
    for k in range(scenes):
        seed = int(1000 * fov) + 100 * ord(name) + k
        rng = np.random.default_rng(seed)
        q = attitude.random_attitude(rng)
        sc = centroids.centroid_scene(cam, q, rng, catalogue=cat, max_stars=MAX_STARS,
                                      false_mag=(3.0, cfg["mag_limit"]), **cfg)
        n = len(sc)
        rows = [(float(x), float(y), float(n - i)) for i, (x, y) in enumerate(sc.pixels)]
        res = solve_centroids(rows, WIDTH, HEIGHT, fov)
        if res.status_name not in ("OK", "IMPRECISE"):
            continue
        row["solved"] += res.status_name == "OK"
        row["imprecise"] += res.status_name == "IMPRECISE"
        wrong = [(i, hip) for i, hip in res.matches.items() if hip not in sc.components[i]]
        row["matches"] += len(res.matches)
        row["wrong"] += len(wrong)
        if wrong:
            row["scenes_wrong"] += 1
            row["wrong_cases"].append({"seed": seed, "wrong": wrong})
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--fovs", nargs="+", type=float, default=[6.0, 7.0, 8.0])
    ap.add_argument("--out", help="write the rows as JSON")
    args = ap.parse_args()
    cat = catalogue.load_deep()
    rows = [run(fov, name, args.scenes, cat) for fov in args.fovs for name in CONFIGS]
    print("FOV  config scenes solved imprecise matches wrong scenes-wrong")
    for r in rows:
        print(f"{r['fov_deg']:>3g}  {r['config']:<6} {r['scenes']:>6} {r['solved']:>6} "
              f"{r['imprecise']:>9} "
              f"{r['matches']:>7} {r['wrong']:>5} {r['scenes_wrong']:>12}")
    matches = sum(r["matches"] for r in rows)
    wrong = sum(r["wrong"] for r in rows)
    print(f"total: {wrong} wrong of {matches} matches ({100.0 * wrong / max(matches, 1):.3f} %)"
          f" in {sum(r['solved'] + r['imprecise'] for r in rows)} identified scenes")
    bound = upper_bound(wrong, matches)
    print(f"{100 * CONFIDENCE:g} % upper bound (Clopper-Pearson, one-sided): "
          f"{100.0 * bound:.4f} % (1 in {1.0 / bound:,.0f})")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
