"""lodestar.firmware.starid.verify: the stretched match region of a partly seen track, the
binomial and Poisson-binomial chance probabilities, the FOV solid angle and a verification
that names stars displaced along their tracks."""

import itertools
import math
from array import array

import numpy as np
import pytest
from scipy.stats import binom

from lodestar.firmware import geometry as G
from lodestar.firmware.starid import verify
from lodestar.sim.attitude import random_attitude
from lodestar.sim.centroids import centroid_scene


def test_match_region_is_a_stadium_along_the_track():
    u = (1.0, 0.0, 0.0)
    streak = u + (5e-4,)
    lim = verify.chord_of_angle(1e-4)
    # along the track: out to half + tolerance
    assert verify.in_region(5.9e-4, 0.0, 0.0, streak, lim)
    assert not verify.in_region(6.1e-4, 0.0, 0.0, streak, lim)
    assert verify.in_region(-5.9e-4, 0.0, 0.0, streak, lim)
    # across it: the point tolerance only
    assert verify.in_region(3e-4, 0.99e-4, 0.0, streak, lim)
    assert not verify.in_region(3e-4, 1.01e-4, 0.0, streak, lim)
    # the rounded ends
    assert verify.in_region(5e-4 + 0.7e-4, 0.7e-4, 0.0, streak, lim)
    assert not verify.in_region(5e-4 + 0.72e-4, 0.72e-4, 0.0, streak, lim)
    # no streak: a disc
    assert verify.in_region(0.0, 0.99e-4, 0.0, None, lim)
    assert not verify.in_region(1.01e-4, 0.0, 0.0, None, lim)


def test_poisson_binomial_tail():
    # equal probabilities: the binomial tail
    for n, k, p in [(10, 3, 1e-3), (28, 5, 0.01), (6, 0, 0.5), (6, 7, 0.5), (12, 12, 0.2)]:
        assert verify.poisson_binomial_tail([p] * n, k) == pytest.approx(
            verify.binomial_tail(n, k, p), rel=1e-9, abs=1e-300)
    # unequal ones: the sum over all outcomes
    ps = [0.1, 0.02, 0.3, 0.05, 0.5]
    for k in range(7):
        exact = 0.0
        for hits in itertools.product((0, 1), repeat=len(ps)):
            if sum(hits) >= k:
                exact += math.prod(p if h else 1 - p for p, h in zip(ps, hits))
        assert verify.poisson_binomial_tail(ps, k) == pytest.approx(exact, rel=1e-12, abs=1e-300)


def test_verification_names_stars_displaced_along_their_tracks(starid_database_of, tol,
                                                              streaked):
    cam, cat, db = starid_database_of("pyramid")
    TOL = tol
    rng = np.random.default_rng(7)
    scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.2, max_stars=20)
    half = 12 * TOL
    vectors, streaks = streaked(scene.vectors, rng, half, every=2)
    b = [G.unit(v) for v in vectors]
    plain = verify.verify(b, db, scene.q, TOL)
    stretched = verify.verify(b, db, scene.q, TOL, streaks=streaks)
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
    assert verify.verify(b, db, _turned(scene.q, 3 * half), TOL, streaks=streaks).n_matched <= 2


def _turned(q, angle):
    """``q`` turned by ``angle`` rad about the camera x axis."""
    from scipy.spatial.transform import Rotation

    return (Rotation.from_rotvec([angle, 0.0, 0.0]) * Rotation.from_quat(q)).as_quat()


def test_binomial_tail_matches_scipy():
    for n, k, p in [(20, 5, 1e-4), (30, 10, 0.05), (10, 0, 0.3), (10, 11, 0.3), (50, 3, 0.2),
                    (28, 26, 1e-4), (5, 5, 0.999), (12, 4, 0.0)]:
        expected = binom.sf(k - 1, n, p)
        got = verify.binomial_tail(n, k, p)
        assert got == pytest.approx(expected, rel=1e-9, abs=1e-300), (n, k, p)


def test_solid_angle():
    assert verify.fov_solid_angle(math.pi, math.pi) == pytest.approx(2 * math.pi)
    small = math.radians(1.0)
    assert verify.fov_solid_angle(small, small) == pytest.approx(small * small, rel=1e-4)


@pytest.mark.parametrize("seed", range(5))
def test_near_pairs_finds_what_testing_every_pair_finds(seed):
    """The x-sorted search yields exactly the pairs, in the same order, of testing every
    observed star against every predicted one (clustered stars, equal x, streaks)."""
    rng = np.random.default_rng(seed)
    n_pred = 120
    vecs = rng.normal(size=(n_pred, 3)) * [0.1, 0.1, 0.0] + [0.0, 0.0, 1.0]
    vecs /= np.linalg.norm(vecs, axis=1)[:, None]
    vecs[5:9, 0] = vecs[4, 0]                               # equal x, still unit vectors
    vecs[5:9, 1:] *= (np.sqrt(1.0 - vecs[4, 0] ** 2) /
                      np.linalg.norm(vecs[5:9, 1:], axis=1))[:, None]
    assert len({float(x) for x in vecs[4:9, 0]}) == 1
    predicted = (list(range(n_pred)), array(G.FLOAT_CODE, vecs.ravel().tolist()))
    picks = rng.choice(n_pred, size=30)
    observed = [tuple(G.unit(tuple(vecs[p] + rng.normal(scale=3e-4, size=3)))) for p in picks]
    streaks = [None] * 30
    for o in range(0, 30, 4):
        u = G.unit(tuple(np.cross(observed[o], [0.0, 0.0, 1.0]) + [0.0, 0.0, 1e-9]))
        streaks[o] = (u[0], u[1], u[2], 2e-3)
    radius = 1e-3
    lim = verify.chord_of_angle(radius)

    def every_pair(streaks):
        for o, (ox, oy, oz) in enumerate(observed):
            streak = streaks[o] if streaks else None
            for p in range(n_pred):
                dx, dy, dz = (ox - predicted[1][3 * p], oy - predicted[1][3 * p + 1],
                              oz - predicted[1][3 * p + 2])
                if verify.in_region(dx, dy, dz, streak, lim):
                    yield o, p, dx, dy, dz

    for s in (None, streaks):
        got = list(verify.near_pairs(observed, predicted, radius, streaks=s))
        assert got == list(every_pair(s))
        assert len(got) >= 30


def test_least_chance_bounds_every_hypothesis_from_below():
    omega = verify.fov_solid_angle(0.2, 0.15)
    tol = 3.5e-4
    # a usual frame: some hypothesis can verify
    assert verify.least_chance(20, omega, tol, 1e-9) is None
    assert verify.least_chance(5, omega, tol, 1e-9, [None] * 5) is None
    # four long tracks: no hypothesis can (estcube2_3dps' stars, halves in tolerances)
    streaks = [(1.0, 0.0, 0.0, h * tol) for h in (0.6, 1.5, 1.5, 6.9)]
    least = verify.least_chance(4, omega, tol, 1e-9, streaks)
    assert least is not None and least >= 1e-9
    # exact: every (n_fov >= matched) a verification could meet is at least the bound, and
    # the bound is met
    got = [verify.chance_agreement(n_fov, omega, tol, 4, k, streaks)[1]
           for k in range(5) for n_fov in range(k, k + 40)]
    assert min(got) == least
    # a threshold just above it: the search may succeed
    assert verify.least_chance(4, omega, tol, least * 1.01, streaks) is None
    # points only: six stars can verify; three cannot (one match beyond the free ones)
    assert verify.least_chance(6, omega, tol, 1e-9) is None
    assert verify.least_chance(3, omega, tol, 1e-9) is not None


def test_a_sky_cone_predicts_the_stars_of_a_query_of_their_own(starid_database_of):
    _cam, _cat, db = starid_database_of("pyramid")
    rng = np.random.default_rng(11)
    sky = verify.SkyCone()
    queries = []
    counted = db.stars_in_cone

    def counting(*args, **kwargs):
        queries.append(args[1])
        return counted(*args, **kwargs)

    db.stars_in_cone = counting
    try:
        for _ in range(5):
            q0 = np.array(random_attitude(rng))
            for step in (0.0, 2e-4, 5e-4, 0.05):    # a refinement's turns, then a jump
                q = q0 + step * rng.normal(size=4)
                q = tuple(float(c) for c in q / np.linalg.norm(q))
                own = verify.predicted_stars(db, q)
                held = verify.predicted_stars(db, q, sky=sky)
                assert list(own[0]) == list(held[0]) and list(own[1]) == list(held[1])
    finally:
        del db.stars_in_cone
    # per attitude: its own query each time; the sky cone once, again after the jump
    assert len(queries) == 5 * 4 + 5 * 2
