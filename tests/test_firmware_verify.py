"""Tests of the shared verification's partly seen tracks (``lodestar.firmware.verify``):
the stretched match region, the Poisson-binomial chance probability, the streak checks
and a verification that names stars displaced along their tracks.  The rest of the module
(binomial tail, q-method fit, solid angle) is tested with Pyramid in
``test_firmware_pyramid.py``."""

import functools
import itertools
import math

import numpy as np
import pytest
from lodestar.firmware import geometry as G
from lodestar.firmware import starid
from lodestar.firmware import status as S
from lodestar.firmware.database import Database
from lodestar.firmware.starid import search as SE
from lodestar.firmware.starid import verify as V
from lodestar.ground.database import build_database
from lodestar.ground.scenes import centroid_scene
from lodestar.sim.attitude import random_attitude
from starid_support import outcome, streaked
from test_firmware_pyramid import TOL, setup


def test_match_region_is_a_stadium_along_the_track():
    u = (1.0, 0.0, 0.0)
    streak = u + (5e-4,)
    lim = V.chord(1e-4)
    # along the track: out to half + tolerance
    assert V.in_region(5.9e-4, 0.0, 0.0, streak, lim)
    assert not V.in_region(6.1e-4, 0.0, 0.0, streak, lim)
    assert V.in_region(-5.9e-4, 0.0, 0.0, streak, lim)
    # across it: the point tolerance only
    assert V.in_region(3e-4, 0.99e-4, 0.0, streak, lim)
    assert not V.in_region(3e-4, 1.01e-4, 0.0, streak, lim)
    # the rounded ends
    assert V.in_region(5e-4 + 0.7e-4, 0.7e-4, 0.0, streak, lim)
    assert not V.in_region(5e-4 + 0.72e-4, 0.72e-4, 0.0, streak, lim)
    # no streak: a disc
    assert V.in_region(0.0, 0.99e-4, 0.0, None, lim)
    assert not V.in_region(1.01e-4, 0.0, 0.0, None, lim)


def test_poisson_binomial_tail():
    # equal probabilities: the binomial tail
    for n, k, p in [(10, 3, 1e-3), (28, 5, 0.01), (6, 0, 0.5), (6, 7, 0.5), (12, 12, 0.2)]:
        assert V.poisson_binomial_tail([p] * n, k) == pytest.approx(
            V.binomial_tail(n, k, p), rel=1e-9, abs=1e-300)
    # unequal ones: the sum over all outcomes
    ps = [0.1, 0.02, 0.3, 0.05, 0.5]
    for k in range(7):
        exact = 0.0
        for hits in itertools.product((0, 1), repeat=len(ps)):
            if sum(hits) >= k:
                exact += math.prod(p if h else 1 - p for p, h in zip(ps, hits))
        assert V.poisson_binomial_tail(ps, k) == pytest.approx(exact, rel=1e-12, abs=1e-300)


def test_streaks_are_checked():
    assert SE.streaks_valid(None, 3)
    assert SE.streaks_valid([None, (0.0, 1.0, 0.0, 1e-4), None], 3)
    for bad in ([None, None], [None, (0.0, 1.0, 0.0), None], [None, (0, 1, 0, -1e-4), None],
                [None, (0, 1, float("nan"), 1e-4), None], 5, [None, "abcd", None]):
        assert not SE.streaks_valid(bad, 3), bad


def test_verification_names_stars_displaced_along_their_tracks():
    cam, cat, db = setup()
    rng = np.random.default_rng(7)
    scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.2, max_stars=20)
    half = 12 * TOL
    vectors, streaks = streaked(scene.vectors, rng, half, every=2)
    b = [G.unit(v) for v in vectors]
    plain = V.verify(b, db, scene.q, TOL)
    stretched = V.verify(b, db, scene.q, TOL, streaks=streaks)
    n = len(b)
    n_streaks = sum(s is not None for s in streaks)
    assert plain.n_matched <= n - n_streaks + 1
    assert stretched.n_matched == n
    for o, s in stretched.pairs:
        assert db.star_hip(s) in scene.components[o]
    # each stretched region is more likely hit by chance, and the bound says so
    assert stretched.p_single > plain.p_single
    assert stretched.probability < 1e-9
    # an attitude off by more than a track reaches matches little
    assert V.verify(b, db, _turned(scene.q, 3 * half), TOL, streaks=streaks).n_matched <= 2


def _turned(q, angle):
    """``q`` turned by ``angle`` rad about the camera x axis."""
    from scipy.spatial.transform import Rotation

    return (Rotation.from_rotvec([angle, 0.0, 0.0]) * Rotation.from_quat(q)).as_quat()


@functools.lru_cache(maxsize=None)
def all_methods_database():
    cam, cat, _db = setup()
    return Database(build_database(cat, cam, mag_limit=6.0,
                                   methods=("pyramid", "triangle", "hashing")))


@pytest.mark.parametrize("method", starid.METHODS)
def test_identification_with_partly_seen_tracks(method):
    """All stars but the four brightest (eight for hashing, whose hash boxes ignore
    streaks) sit up to 12 tolerances along their tracks.  Without their streaks the
    verification cannot name them: with four good stars of a dozen or more nothing is
    accepted right (a displaced star may even land on another catalogue star), with eight
    half the stars stay unnamed.  With the streaks every scene is named right, all but a
    few stars (a stretched region holding a second catalogue star leaves its star
    unnamed)."""
    cam, cat, _ = setup()
    db = all_methods_database()
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
        vectors, streaks = streaked(scene.vectors, rng, 12 * TOL, keep_first=keep)
        for name, s in (("plain", None), ("streaks", streaks)):
            sol = starid.identify(vectors, db, method=method, tolerance_rad=TOL, streaks=s)
            verdict = outcome(sol, scene)
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


@pytest.mark.parametrize("method", starid.METHODS)
def test_bad_streaks_are_bad_input(method):
    _cam, _cat, _ = setup()
    db = all_methods_database()
    vectors = [[0.0, 0.0, 1.0], [0.01, 0.0, 1.0], [0.0, 0.01, 1.0], [0.01, 0.01, 1.0]]
    sol = starid.identify(vectors, db, method=method, tolerance_rad=TOL,
                          streaks=[None, None, (0.0, 1.0, 0.0, -1.0), None])
    assert sol.status == S.BAD_INPUT
