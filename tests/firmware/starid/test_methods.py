"""Every identification method of the registry (``lodestar.firmware.starid.METHODS``) on the
same checks: Monte Carlo scenes, mirror images (``MIRRORED``), false stars, bad input, the
deterministic budget, partly seen tracks and the heap budget.  Method-specific geometry is tested in
``test_pyramid.py``, ``test_triangle.py`` and ``test_hashing.py``."""

import functools

import numpy as np

from lodestar.contract import stardb
from lodestar.firmware import starid
from lodestar.firmware import status as S
from lodestar.firmware.database import Database
from lodestar.ground.database import build_database
from lodestar.sim.attitude import random_attitude
from lodestar.sim.centroids import centroid_scene

SMALLEST = {"pyramid": 4, "triangle": 3, "hashing": 4}
"""Fewest stars a method searches (a pyramid; a triangle; a hash group of the default 4)."""
MIN_CORRECT = {"pyramid": 190, "triangle": 180, "hashing": 180}
"""Right identifications required of the 200 Monte Carlo scenes."""


def test_registry():
    """Each method of the contract's table is the module the table names."""
    assert starid.METHODS == stardb.METHODS
    for name, bit, module, _, _ in stardb.METHOD_TABLE:
        assert starid.method(name).__name__ == module and starid.method(name).identify
        assert starid.method(name).DATABASE_BIT == bit
    assert starid.method("voting") is None


def test_monte_carlo_200_scenes(method, starid_setup, tol, scene_outcome):
    cam, cat, db = starid_setup
    rng = np.random.default_rng(2024)
    counts = {"correct": 0, "wrong": 0, "no-solve": 0}
    for _ in range(200):
        q = random_attitude(rng)
        scene = centroid_scene(cam, q, rng, cat, noise_px=rng.uniform(0.1, 0.5),
                               n_false=int(rng.integers(0, 6)), drop_fraction=0.1,
                               max_stars=30)
        sol = starid.identify(scene.vectors.tolist(), db, method=method, tolerance_rad=tol)
        counts[scene_outcome(sol, scene)] += 1
        if sol.status == S.OK:
            assert sol.probability < 1e-9 and len(sol.matches) >= 4
            assert sol.patterns_tried >= 1 and sol.hypotheses >= 1
    print("\n", method, "200 estcube2 scenes:", counts)
    assert counts["wrong"] == 0
    assert counts["correct"] >= MIN_CORRECT[method]


def test_mirrored_scenes_are_reported_mirrored(method, starid_setup, tol):
    """A scene flipped in x or in y never gets an attitude: every one is reported
    ``MIRRORED``, and none of the same scenes unflipped is."""
    cam, cat, db = starid_setup
    rng = np.random.default_rng(9)
    counts = {}
    for trial in range(30):
        scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.3, max_stars=30)
        flip = [-1.0, 1.0, 1.0] if trial % 2 else [1.0, -1.0, 1.0]
        sol = starid.identify((scene.vectors * flip).tolist(), db, method=method,
                              tolerance_rad=tol, budget=500)
        assert sol.status != S.OK and sol.q is None and sol.matches == []
        counts[S.name(sol.status)] = counts.get(S.name(sol.status), 0) + 1
        assert starid.identify(scene.vectors.tolist(), db, method=method,
                               tolerance_rad=tol).status != S.MIRRORED
    print("\n", method, "30 mirrored scenes:", counts)
    assert counts == {"MIRRORED": 30}


def test_false_stars_only_are_not_accepted(method, starid_setup, tol):
    cam, _, db = starid_setup
    rng = np.random.default_rng(10)
    for _ in range(10):
        n = int(rng.integers(SMALLEST[method], 25))
        v = cam.unproject(rng.uniform(0, cam.width - 1, n), rng.uniform(0, cam.height - 1, n))
        sol = starid.identify(v.tolist(), db, method=method, tolerance_rad=tol, budget=500)
        assert sol.status in (S.NO_MATCH, S.BUDGET_EXHAUSTED)
        assert sol.q is None and sol.matches == []


def test_too_few_stars_and_bad_input(method, starid_setup, starid_database_of, tol):
    cam, cat, db = starid_setup
    rng = np.random.default_rng(12)
    scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.2)
    vec = scene.vectors.tolist()
    for n in range(SMALLEST[method]):
        sol = starid.identify(vec[:n], db, method=method, tolerance_rad=tol)
        assert sol.status == S.TOO_FEW_STARS
    bad = list(vec)
    bad[2] = [float("nan"), 0.0, 1.0]
    assert starid.identify(bad, db, method=method).status == S.BAD_INPUT
    bad[2] = [0.0, 0.0, 0.0]
    assert starid.identify(bad, db, method=method).status == S.BAD_INPUT
    assert starid.identify([[1, 2]] * 5, db, method=method).status == S.BAD_INPUT
    for t in (-1.0, 0.0):
        assert starid.identify(vec, db, method=method, tolerance_rad=t).status == S.BAD_INPUT
    assert starid.identify(vec, db, method="voting").status == S.BAD_INPUT
    other = starid_database_of([m for m in starid.METHODS if m != method][0])[2]
    assert starid.identify(vec, other, method=method).status == S.DATABASE_UNSUPPORTED


def test_budget_is_deterministic(method, starid_setup, tol):
    """False stars first: the first patterns cannot solve, a budget of 3 runs out; the full
    search is repeatable and leaves the false stars unnamed."""
    cam, cat, db = starid_setup
    rng = np.random.default_rng(13)
    scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.2)
    n_false = SMALLEST[method] - 1 if method == "hashing" else 4
    false = cam.unproject(rng.uniform(0, cam.width - 1, n_false),
                          rng.uniform(0, cam.height - 1, n_false))
    vectors = np.concatenate([false, scene.vectors]).tolist()
    sol = starid.identify(vectors, db, method=method, tolerance_rad=tol, budget=3)
    assert sol.status == S.BUDGET_EXHAUSTED and sol.patterns_tried == 3
    full = starid.identify(vectors, db, method=method, tolerance_rad=tol)
    again = starid.identify(vectors, db, method=method, tolerance_rad=tol)
    assert full.status == S.OK and full.patterns_tried > 3
    assert (full.q, full.matches, full.patterns_tried) == (again.q, again.matches,
                                                           again.patterns_tried)
    assert all(o >= n_false for o, _ in full.matches)


@functools.lru_cache(maxsize=None)
def all_methods_database(cam, cat):
    return Database(build_database(cat, cam, mag_limit=6.0, methods=starid.METHODS))


def test_identification_with_partly_seen_tracks(method, starid_setup, tol, scene_outcome,
                                                streaked):
    """All stars but the four brightest (eight for hashing, whose hash boxes ignore
    streaks) sit up to 12 tolerances along their tracks.  Without their streaks the
    verification cannot name them: with four good stars of a dozen or more nothing is
    accepted right (a displaced star may even land on another catalogue star), with eight
    half the stars stay unnamed.  With the streaks every scene is named right, all but a
    few stars (a stretched region holding a second catalogue star leaves its star
    unnamed)."""
    cam, cat, _ = starid_setup
    db = all_methods_database(cam, cat)
    rng = np.random.default_rng(11)
    keep = 8 if method == "hashing" else 4
    counts = {"plain": {"correct": 0, "wrong": 0, "no-solve": 0},
              "streaks": {"correct": 0, "wrong": 0, "no-solve": 0}}
    named = {"plain": [], "streaks": []}
    for _ in range(12):
        scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.2,
                               max_stars=16)
        if len(scene) < 12:
            continue
        vectors, streaks = streaked(scene.vectors, rng, 12 * tol, keep_first=keep)
        for name, s in (("plain", None), ("streaks", streaks)):
            sol = starid.identify(vectors, db, method=method, tolerance_rad=tol, streaks=s)
            verdict = scene_outcome(sol, scene)
            counts[name][verdict] += 1
            if verdict == "correct":
                named[name].append(len(sol.matches) / len(scene))
    print("\n", method, counts, "named", {k: np.round(v, 2) for k, v in named.items()})
    assert counts["streaks"] == {"correct": 12, "wrong": 0, "no-solve": 0}
    assert min(named["streaks"]) >= 0.75
    if keep == 4:
        assert counts["plain"]["correct"] == 0
    else:
        assert max(named["plain"]) <= 0.7


def test_bad_streaks_are_bad_input(method, starid_setup, tol):
    db = starid_setup[2]
    vectors = [[0.0, 0.0, 1.0], [0.01, 0.0, 1.0], [0.0, 0.01, 1.0], [0.01, 0.01, 1.0]]
    sol = starid.identify(vectors, db, method=method, tolerance_rad=tol,
                          streaks=[None, None, (0.0, 1.0, 0.0, -1.0), None])
    assert sol.status == S.BAD_INPUT


def test_live_peak_of_a_hard_solve_is_within_the_heap_budget(method, starid_setup,
                                                             heap_budget_check):
    """30 stars of which 10 false, 1 px noise, the pipeline's tolerance: the CPython live
    peak of one identification (a bound of MicroPython's) stays within the 96 KB budget."""
    heap_budget_check(method, *starid_setup)
