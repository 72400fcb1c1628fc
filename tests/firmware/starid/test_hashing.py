"""Geometric-hashing identification (``lodestar.firmware.starid.hashing``, Astrometry.net's
quad hash as in Schumann 2019) and the database's hash section: the frame and hash formulas
against hand-computed values, canonical labelling and its invariances, the tolerance bound
against worst-case perturbations, the search's fast paths against the plain formulas (its
labellings bit for bit, the reversed tangent frame exactly negated, its bucket walk equal to
the bucket ranges), the bucket codes, mirror rejection, the 3-star and normalized variants,
refusal of a corrupt or inconsistent section, and the same results under MicroPython 1.27.
The checks every method shares are in ``test_methods.py``.
"""

import functools
import math
import struct

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.contract import stardb
from lodestar.firmware import database, starid
from lodestar.firmware import status as S
from lodestar.firmware.database import Database
from lodestar.firmware.geometry import angle
from lodestar.firmware.starid import hashing
from lodestar.ground.database import build_database
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import load
from lodestar.sim.centroids import centroid_scene
from lodestar.sim.presets import load_preset
from tests.firmware.db_images import reseal, status_of
from tests.firmware.mpy import identify_under_micropython, solved_scenes

TOL = 3.0e-4


@functools.lru_cache(maxsize=None)
def setup(group_size=4, normalized=False):
    cam = load_preset("estcube2")
    cat = load()
    image = build_database(cat, cam, mag_limit=6.0, methods=("hashing",),
                           options={"hashing": {"group_size": group_size,
                                                "normalized": normalized}})
    return cam, cat, image, Database(image)


def about_y(angle):
    """Unit vector at ``angle`` (rad) from +z towards +x."""
    return (math.sin(angle), 0.0, math.cos(angle))


def about_x(angle):
    """Unit vector at ``angle`` (rad) from +z towards +y."""
    return (0.0, math.sin(angle), math.cos(angle))


def group_around(rng, n, spread):
    d = rng.normal(0, spread, (n, 3)) + [0, 0, 1]
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return Rotation.random(random_state=rng).apply(d)


# --------------------------------------------------------------------------------------
# Formulas (hand-checked values)
# --------------------------------------------------------------------------------------

def test_frame_coords_hand_checked():
    """z = (P - A)(1 + i) / (B - A): A -> (0, 0), B -> (1, 1), the midpoint of AB ->
    (1/2, 1/2), the point that completes the square ABP... -> as computed by hand."""
    a, b = (0.0, 0.0), (2.0, 0.0)
    assert hashing.frame_coords(a, b, a) == (0.0, 0.0)
    assert hashing.frame_coords(a, b, b) == (1.0, 1.0)
    assert hashing.frame_coords(a, b, (1.0, 0.0)) == (0.5, 0.5)
    assert hashing.frame_coords(a, b, (1.0, 1.0)) == (0.0, 1.0)        # (1+i)(1+i)/2 = i
    assert hashing.frame_coords(a, b, (1.0, -1.0)) == (1.0, 0.0)       # (1-i)(1+i)/2 = 1
    # invariant to a similarity of the plane (rotation by 30 deg, scale 3, shift)
    c, s = 3 * math.cos(0.5236), 3 * math.sin(0.5236)

    def sim(p):
        return (c * p[0] - s * p[1] + 7.0, s * p[0] + c * p[1] - 2.0)

    for p in ((0.3, 0.4), (1.7, -0.2), (1.0, 1.0)):
        assert hashing.frame_coords(sim(a), sim(b), sim(p)) == \
            pytest.approx(hashing.frame_coords(a, b, p), abs=1e-12)


def test_hash_on_the_sphere_hand_checked():
    """A and B at -alpha and +alpha from +z (in the x-z plane) project to (-tan alpha, 0)
    and (tan alpha, 0); a star at alpha towards +y projects to (0, tan alpha), i.e.
    z = (tan a + i tan a)(1 + i) / (2 tan a) = i: hash (0, 1).  Towards -y: (1, 0)."""
    alpha = math.radians(5.0)
    a, b = about_y(-alpha), about_y(alpha)
    assert hashing.coords(a, b, [about_x(alpha)]) == pytest.approx([0.0, 1.0], abs=1e-12)
    assert hashing.coords(a, b, [about_x(-alpha)]) == pytest.approx([1.0, 0.0], abs=1e-12)
    assert hashing.coords(a, b, [(0.0, 0.0, 1.0)]) == pytest.approx([0.5, 0.5], abs=1e-12)
    # a 3-star group: the diameter is A-B (10 deg > 7.07 deg); C towards -y has x = 1 > 1/2,
    # so the canonical labelling swaps A and B: (1 - 1, 1 - 0) = (0, 1)
    c = about_x(-alpha)
    order, h, d = hashing.group_hash([a, b, c])
    assert order == (1, 0, 2) and h == pytest.approx([0.0, 1.0], abs=1e-12)
    assert d == pytest.approx(2 * alpha, rel=1e-12)
    # 4 stars: C = centre (1/2, 1/2), D = towards +y (0, 1): x_C + x_D = 1/2 <= 1 and
    # x_D = 0 <= x_C, so D comes first
    order, h, d = hashing.group_hash([a, b, (0.0, 0.0, 1.0), about_x(alpha)])
    assert order == (0, 1, 3, 2) and h == pytest.approx([0.0, 1.0, 0.5, 0.5], abs=1e-12)


def test_canonical_labelling_rules_and_invariance():
    rng = np.random.default_rng(1)
    for g in (3, 4):
        for _ in range(60):
            v = group_around(rng, g, 0.08)
            order, h, d = hashing.group_hash([tuple(x) for x in v])
            chords = {(i, j): np.linalg.norm(v[i] - v[j]) for i in range(g)
                      for j in range(g) if i < j}
            assert np.linalg.norm(v[order[0]] - v[order[1]]) == pytest.approx(
                max(chords.values()), rel=1e-12)
            if g == 3:
                assert h[0] <= 0.5
            else:
                assert h[0] <= h[2] and h[0] + h[2] <= 1.0
            # the same hash (and stars) whatever the input order, orientation or position
            perm = rng.permutation(g)
            w = Rotation.random(random_state=rng).apply(v[perm])
            order2, h2, d2 = hashing.group_hash([tuple(x) for x in w])
            assert [perm[o] for o in order2] == list(order)
            assert h2 == pytest.approx(h, abs=1e-9) and d2 == pytest.approx(d, rel=1e-9)
            # a mirror image hashes differently (no mirror invariance) unless symmetric
            _, hm, _ = hashing.group_hash([tuple(x) for x in v * [-1.0, 1.0, 1.0]])
            assert max(abs(p - q) for p, q in zip(hm, h)) > 1e-6


def test_tolerance_bound_holds_for_worst_case_perturbations():
    rng = np.random.default_rng(2)
    worst = 0.0
    for _ in range(80):
        g = 3 + int(rng.integers(0, 2))
        eps = 10 ** rng.uniform(-5, -3)
        v = group_around(rng, g, rng.uniform(0.03, 0.1))
        order, h, d = hashing.group_hash([tuple(x) for x in v])
        tol = hashing.coord_tolerance(h, d - 2 * eps, eps)

        def f(w):
            return hashing.coords(tuple(w[order[0]]), tuple(w[order[1]]),
                            [tuple(w[o]) for o in order[2:]])

        for comp in range(len(h)):
            for sign in (1.0, -1.0):
                moved = np.array(v)
                for i in range(g):
                    grad = np.zeros(3)
                    for ax in range(3):
                        dv = np.zeros((g, 3))
                        dv[i, ax] = 1e-7
                        grad[ax] = (f(v + dv)[comp] - f(v - dv)[comp]) / 2e-7
                    grad -= (grad @ v[i]) * v[i]
                    n = np.linalg.norm(grad)
                    if n > 0:
                        moved[i] = v[i] * math.cos(eps) + sign * grad / n * math.sin(eps)
                worst = max(worst, abs(f(moved)[comp] - h[comp]) / tol)
    assert 0.7 < worst <= 1.0


def test_reversed_tangent_frame_is_the_negated_one_exactly():
    """``tangent_frame(b, a)`` is ``(m, -e1, -e2)`` of ``tangent_frame(a, b)`` bit for bit,
    so the search negates projections instead of recomputing them."""
    rng = np.random.default_rng(5)
    for _ in range(300):
        a, b = (tuple(x) for x in group_around(rng, 2, 10 ** rng.uniform(-3, -0.5)))
        m, e1, e2 = hashing.tangent_frame(a, b)
        m2, f1, f2 = hashing.tangent_frame(b, a)
        assert m2 == m
        assert f1 == tuple(-x for x in e1) and f2 == tuple(-x for x in e2)
        p = tuple(group_around(rng, 1, 0.1)[0])
        u, v = hashing.project((m, e1, e2), p)
        assert hashing.project((m2, f1, f2), p) == (-u, -v)


def reference_labellings(vs, i, j, d, eps, max_tol):
    """The search's labellings of diameter ``i``-``j`` from the plain formulas: every order
    with ``A-B = i-j`` then ``j-i``, ``coords`` and ``coord_tolerance`` of each."""
    rest = [k for k in range(len(vs)) if k not in (i, j)]
    out = []
    for a, b in ((i, j), (j, i)):
        for others in ([rest] if len(rest) == 1 else [rest, rest[::-1]]):
            h = hashing.coords(vs[a], vs[b], [vs[k] for k in others])
            t = hashing.coord_tolerance(h, d, eps)
            if t > max_tol:
                continue
            if len(rest) == 1:
                keep = h[0] <= 0.5 + t
            else:
                keep = h[0] <= h[2] + 2.0 * t and h[0] + h[2] <= 1.0 + 2.0 * t
            if keep:
                out.append(((a, b) + tuple(others), h, t))
    return out


def test_search_labellings_equal_the_plain_formulas_bit_for_bit():
    """The search's labellings (one frame per diameter pair, both orientations and orders
    from it) are exactly those of ``coords`` / ``coord_tolerance`` and the rules, in order,
    the near-symmetric groups (two or more admitted) included."""
    rng = np.random.default_rng(6)
    several = 0
    for trial in range(400):
        g = 3 + trial % 2
        v = group_around(rng, g, rng.uniform(0.01, 0.1))
        if trial % 5 == 0:          # x_C ~ x_D or x_C + x_D ~ 1: several labellings admitted
            v[g - 1] = v[0] + v[1] - v[g - 2] + rng.normal(0, 1e-4, 3)
            v[g - 1] /= np.linalg.norm(v[g - 1])
        vs = [tuple(x) for x in v.tolist()]
        eps = 10 ** rng.uniform(-5, -3)
        for i, j in hashing._diameter_pairs(hashing._chords2(vs), g, 4.0 * eps):
            d = angle(vs[i], vs[j]) - 2.0 * eps
            scale, den = hashing._tolerance_terms(d, eps)
            got = hashing._labellings(vs, i, j, scale, den, 0.15)
            assert got == reference_labellings(vs, i, j, d, eps, 0.15)
            several += len(got) > 1
    assert several > 20


def test_box_records_are_the_bucket_ranges():
    """``box_records`` (one k-vector query per run of buckets) returns exactly the groups
    of ``hash_bucket`` over the box codes, in order: around stored groups and anywhere."""
    _, _, _, db = setup()
    rng = np.random.default_rng(8)
    nonempty = 0
    for trial in range(300):
        if trial % 2:
            _, *stars = db.hash_record(int(rng.integers(0, db.hash_n)))
            vs = [db.star_vector(s) for s in stars]
            h = hashing.coords(vs[0], vs[1], vs[2:])
            d = angle(vs[0], vs[1])
        else:
            h = rng.uniform(-0.5, 1.5, 4).tolist()
            d = float(rng.uniform(0.0, 0.5))
        codes = hashing.box_codes(h, float(rng.uniform(0.0, 0.1)), d, 1e-3, db)
        want = [r for c in codes for r in range(*db.hash_bucket(c))]
        assert hashing.box_records(db, codes) == want
        nonempty += bool(want)
    assert nonempty > 100
    last = db.hash_code(db.hash_n - 1)
    assert hashing.box_records(db, [0, last, last + 1]) == \
        list(range(*db.hash_bucket(0))) + list(range(*db.hash_bucket(last)))


def test_bucket_codes_hand_checked():
    class Grid:
        hash_coord_lo, hash_coord_bucket, hash_coord_buckets = -1.0, 0.5, 6
        hash_flags, hash_dist_bucket, hash_dist_buckets = 0, 0.1, 5

    grid = Grid()
    assert hashing.bucket(-1.0, -1.0, 0.5, 6) == 0 and hashing.bucket(0.49, -1.0, 0.5, 6) == 2
    assert hashing.bucket(-7.0, -1.0, 0.5, 6) == 0 and hashing.bucket(9.0, -1.0, 0.5, 6) == 5
    # digits (2, 3) for (0.2, 0.6): 2 * 6 + 3
    assert hashing.bucket_code([0.2, 0.6], 0.33, grid) == 15
    assert hashing.bucket_code([0.2, 0.6, 1.9, -0.8], 0.33, grid) == ((2 * 6 + 3) * 6 + 5) * 6 + 0
    grid.hash_flags = stardb.HASH_FLAG_DISTANCE
    assert hashing.bucket_code([0.2, 0.6], 0.33, grid) == 15 * 5 + 3
    # the box -0.05 +- 0.1 spans buckets 1..2, 0.6 +- 0.1 bucket 3, d 0.33 +- 0.08 -> 2..4
    assert hashing.box_codes([-0.05, 0.6], 0.1, 0.33, 0.08, grid) == [
        (1 * 6 + 3) * 5 + k for k in (2, 3, 4)] + [(2 * 6 + 3) * 5 + k for k in (2, 3, 4)]


def test_database_groups_are_canonical_and_indexed():
    _, _, _, db = setup()
    assert db.methods == stardb.METHOD_HASHING and db.hash_group_size == 4 and db.hash_n > 10000
    assert db.hash_flags == stardb.HASH_FLAG_DISTANCE
    recs = [db.hash_record(i) for i in range(db.hash_n)]
    assert recs == sorted(recs)
    rng = np.random.default_rng(3)
    for i in rng.integers(0, db.hash_n, 300).tolist():
        code, *stars = recs[i]
        vs = [db.star_vector(s) for s in stars]
        order, h, d = hashing.group_hash(vs)
        assert order == (0, 1, 2, 3)                    # stored in canonical order
        assert hashing.bucket_code(h, d, db) == code
        assert db.hash_min_diameter <= d <= db.hash_max_diameter * (1 + 1e-6)
        start, stop = db.hash_bucket(code)
        assert start <= i < stop
        assert all(recs[k][0] == code for k in range(start, stop))
        assert (start == 0 or recs[start - 1][0] < code) and \
            (stop == db.hash_n or recs[stop][0] > code)
        assert all(db.star_flags(s) & stardb.STAR_FLAG_HASH for s in stars)
    assert db.hash_bucket(recs[-1][0] + 1) == (db.hash_n, db.hash_n)
    start, stop = db.hash_bucket(0)
    assert start == stop or recs[start][0] == 0


def test_mirror_images_are_not_accepted():
    cam, cat, _, db = setup()
    rng = np.random.default_rng(9)
    for _ in range(10):
        scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.3, max_stars=30)
        mirrored = (scene.vectors * [-1.0, 1.0, 1.0]).tolist()
        assert starid.identify(mirrored, db, method="hashing", tolerance_rad=TOL,
                               budget=400).status != S.OK


# --------------------------------------------------------------------------------------
# Scenes
# --------------------------------------------------------------------------------------

def run_scenes(db, n, seed, outcome):
    cam, cat = load_preset("estcube2"), load()
    rng = np.random.default_rng(seed)
    counts = {"correct": 0, "wrong": 0, "no-solve": 0}
    for _ in range(n):
        q = random_attitude(rng)
        scene = centroid_scene(cam, q, rng, cat, noise_px=rng.uniform(0.1, 0.5),
                               n_false=int(rng.integers(0, 6)), drop_fraction=0.1,
                               max_stars=30)
        sol = starid.identify(scene.vectors.tolist(), db, method="hashing", tolerance_rad=TOL)
        counts[outcome(sol, scene)] += 1
        if sol.status == S.OK:
            assert sol.probability < 1e-9 and len(sol.matches) >= 4
    return counts


@pytest.mark.parametrize("group_size,normalized", [(3, False), (4, True), (3, True)])
def test_variants(group_size, normalized, scene_outcome):
    db = setup(group_size, normalized)[3]
    assert db.hash_group_size == group_size
    assert bool(db.hash_flags & stardb.HASH_FLAG_DISTANCE) == (not normalized)
    counts = run_scenes(db, 30, 7, scene_outcome)
    print("\nhashing", group_size, "normalized" if normalized else "non-normalized", counts)
    assert counts["wrong"] == 0
    assert counts["correct"] >= 27


# --------------------------------------------------------------------------------------
# Corruption
# --------------------------------------------------------------------------------------



def test_corrupt_hash_section_is_refused():
    _, _, image, _ = setup()
    off, length = struct.unpack_from("<II", image, stardb.DIRECTORY_OFFSET + 8 * stardb.SEC_HASH)
    rng = np.random.default_rng(4)
    for i in [off, off + 13, off + stardb.HASH_HEADER_SIZE, off + length - 2] + \
            rng.integers(off, off + length, 20).tolist():
        b = bytearray(image)
        b[i] ^= 0x04
        assert database.check(b)[0] == S.DATABASE_CORRUPT
    assert status_of(reseal(image, lambda b: b.__setitem__(slice(off, off + 4), b"HSH2"))) == \
        S.DATABASE_UNSUPPORTED
    assert status_of(reseal(image, lambda b: struct.pack_into("<H", b, off + 12, 5))) == \
        S.DATABASE_UNSUPPORTED                       # group size 5
    assert status_of(reseal(image, lambda b: struct.pack_into("<H", b, off + 14, 2))) == \
        S.DATABASE_UNSUPPORTED                       # unknown flag
    n = struct.unpack_from("<I", image, off + 4)[0]
    assert status_of(reseal(image, lambda b: struct.pack_into("<I", b, off + 4, n - 1))) == \
        S.DATABASE_BAD_LAYOUT
    assert status_of(reseal(image, lambda b: struct.pack_into("<H", b, off + 24, 4000))) == \
        S.DATABASE_BAD_LAYOUT                        # codes would exceed 2**30
    assert status_of(reseal(image, lambda b: struct.pack_into("<f", b, off + 20, 0.0))) == \
        S.DATABASE_BAD_LAYOUT


# --------------------------------------------------------------------------------------
# MicroPython 1.27 (WebAssembly port in Node)
# --------------------------------------------------------------------------------------

_HASH_CHECKS = r'''
from lodestar.firmware.starid import hashing
assert hashing.frame_coords((0.0, 0.0), (2.0, 0.0), (1.0, 1.0)) == (0.0, 1.0)
for vs, order, h in HASHES:
    got = hashing.group_hash(vs)
    assert got[0] == order, (got, order)
    assert max(abs(a - b) for a, b in zip(got[1], h)) < 1e-12
'''


def test_hashing_under_micropython(micropython):
    """Hash formulas, the file-backed hash database and identification under MicroPython
    give the CPython results (a mirror image included)."""
    cam, cat, image, db = setup()
    rng = np.random.default_rng(31)
    hashes = []
    for g in (3, 4, 4):
        vs = [tuple(x) for x in group_around(rng, g, 0.08).tolist()]
        order, h, _ = hashing.group_hash(vs)
        hashes.append((vs, order, h))
    scenes, expected = solved_scenes(cam, cat, db, "hashing", rng, 5, 3, TOL, 300)
    assert [e[0] for e in expected[:4]] == [S.OK] * 4 and expected[4][0] != S.OK
    code, out = identify_under_micropython(micropython, image, "hashing", scenes, expected,
                                           TOL, 300, checks=_HASH_CHECKS,
                                           data={"HASHES": hashes})
    print(out)
    assert code == 0, out
    assert "IMPLEMENTATION micropython (1, 27" in out
    assert "SOLVED 5" in out and "DONE" in out
