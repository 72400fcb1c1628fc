"""Lohmann's planar-triangle identification (``lodestar.firmware.starid.triangle``) and the
database's triangle section: the area and polar-moment formulas against hand-computed
values, the tolerance bounds against worst-case perturbations, vertex correspondence from
side lengths, mirror rejection by handedness, a combined image serving every method,
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
from lodestar.firmware import geometry as G
from lodestar.firmware import status as S
from lodestar.firmware.database import Database
from lodestar.firmware.starid import triangle
from lodestar.ground.database import build_database
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import load
from lodestar.sim.centroids import centroid_scene
from lodestar.sim.presets import load_preset
from tests.firmware.db_images import reseal, status_of
from tests.firmware.mpy import identify_under_micropython, solved_scenes

TOL = 3.0e-4          # rad: ~2.2 px of estcube2 (28.4"/px), > 4 sigma of 0.5 px noise


@functools.lru_cache(maxsize=None)
def setup():
    cam = load_preset("estcube2")
    cat = load()
    image = build_database(cat, cam, mag_limit=6.0, methods=("triangle",))
    return cam, cat, image, Database(image)


def unit(v):
    v = np.asarray(v, dtype=float)
    return tuple(v / np.linalg.norm(v))


# --------------------------------------------------------------------------------------
# Formulas (hand-checked values)
# --------------------------------------------------------------------------------------

def test_area_and_moment_of_hand_checked_triangles():
    # 3-4-5 right triangle: area 6, moment 6 * (9 + 16 + 25) / 36 = 25/3
    for a, b, c in ((3.0, 4.0, 5.0), (5.0, 3.0, 4.0), (4.0, 5.0, 3.0)):
        assert triangle.area(a, b, c) == 6.0
        assert triangle.moment(a, b, c) == pytest.approx(25.0 / 3.0, rel=1e-15)
    # equilateral of side 2: area sqrt(3), moment sqrt(3) * 12 / 36
    assert triangle.area(2.0, 2.0, 2.0) == pytest.approx(math.sqrt(3.0), rel=1e-15)
    assert triangle.moment(2.0, 2.0, 2.0) == pytest.approx(math.sqrt(3.0) / 3.0, rel=1e-15)
    # degenerate and impossible triangles have no area
    assert triangle.area(1.0, 2.0, 3.0) == 0.0 and triangle.area(1.0, 1.0, 3.0) == 0.0
    # Kahan's Heron keeps a needle triangle accurate: sides 1, 1, 1e-8
    c = 1e-8
    assert triangle.area(1.0, 1.0, c) == pytest.approx(0.5 * c * math.sqrt(1 - c * c / 4),
                                                       rel=1e-12)


def test_sides_use_the_corrected_formula_on_unit_vectors():
    """Lohmann's a = |V1| - |V2| is zero for unit vectors; the corrected a = |V1 - V2|."""
    x, y, z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
    assert triangle.sides(x, y, z) == pytest.approx((math.sqrt(2),) * 3, rel=1e-15)
    # equilateral of side sqrt(2): area sqrt(3)/2, moment (sqrt(3)/2) * 6 / 36 = sqrt(3)/12
    ar, mo = triangle.area_moment(x, y, z)
    assert ar == pytest.approx(math.sqrt(3) / 2, rel=1e-15)
    assert mo == pytest.approx(math.sqrt(3) / 12, rel=1e-15)
    v1, v2, v3 = (1.0, 0.0, 0.0), unit([1.0, 0.1, 0.0]), unit([1.0, 0.0, 0.2])
    a, b, c = triangle.sides(v1, v2, v3)
    assert a == pytest.approx(np.linalg.norm(np.subtract(v1, v2)), rel=1e-15)
    assert b == pytest.approx(np.linalg.norm(np.subtract(v2, v3)), rel=1e-15)
    assert c == pytest.approx(np.linalg.norm(np.subtract(v1, v3)), rel=1e-15)


def test_area_moment_are_invariant_and_equal_the_planar_triangle():
    rng = np.random.default_rng(1)
    for _ in range(100):
        d = rng.normal(0, 0.1, (3, 3)) + [0, 0, 1]
        v = d / np.linalg.norm(d, axis=1, keepdims=True)
        ar, mo = triangle.area_moment(*map(tuple, v))
        cross = 0.5 * np.linalg.norm(np.cross(v[1] - v[0], v[2] - v[0]))
        assert ar == pytest.approx(cross, rel=1e-9)
        assert mo == pytest.approx(cross * sum(np.sum((v[i] - v[j]) ** 2)
                                               for i, j in ((0, 1), (1, 2), (0, 2))) / 36,
                                   rel=1e-9)
        rot = Rotation.random(random_state=rng).apply(v)
        mirror = v * [-1, 1, 1]
        for w in (rot, mirror, v[[2, 0, 1]], v[[1, 0, 2]]):
            assert triangle.area_moment(*map(tuple, w)) == pytest.approx((ar, mo), rel=1e-9)


def test_bounds_hold_for_worst_case_perturbations():
    """Moving every vertex by ``eps`` along the gradient (the worst case to first order)
    changes area and moment by at most the bounds, and reaches most of them."""
    rng = np.random.default_rng(2)
    worst = [0.0, 0.0]
    for _ in range(150):
        eps = 10 ** rng.uniform(-5, -3)
        d = rng.normal(0, rng.uniform(0.02, 0.15), (3, 3)) + [0, 0, 1]
        v = d / np.linalg.norm(d, axis=1, keepdims=True)
        base = triangle.area_moment(*map(tuple, v))
        bound = triangle.bounds(*map(tuple, v), eps)
        for which in (0, 1):
            for sign in (1.0, -1.0):
                moved = []
                for i in range(3):
                    grad = np.zeros(3)
                    for ax in range(3):
                        h = np.zeros((3, 3))
                        h[i, ax] = 1e-7
                        grad[ax] = (triangle.area_moment(*map(tuple, v + h))[which] -
                                    triangle.area_moment(*map(tuple, v - h))[which]) / 2e-7
                    grad -= (grad @ v[i]) * v[i]
                    n = np.linalg.norm(grad)
                    step = sign * grad / n if n > 0 else np.zeros(3)
                    moved.append(tuple(v[i] * math.cos(eps) + step * math.sin(eps)))
                ratio = abs(triangle.area_moment(*moved)[which] - base[which]) / bound[which]
                worst[which] = max(worst[which], ratio)
    assert max(worst) <= 1.0
    assert min(worst) > 0.8          # the bounds are not loose


# --------------------------------------------------------------------------------------
# Vertex correspondence and handedness
# --------------------------------------------------------------------------------------

def test_canonical_order_and_correspondence_from_side_lengths():
    v = [(1.0, 0.0, 0.0), unit([1.0, 0.05, 0.0]), unit([1.0, 0.0, 0.12])]
    # sides opposite: v0 -> |v1 - v2| (longest), v1 -> |v0 - v2| (middle), v2 -> shortest
    order, opp = triangle.canonical_order(*v)
    assert order == (2, 1, 0)
    assert opp[0] < opp[1] < opp[2]
    cat_opp = opp
    for perm in ((0, 1, 2), (2, 0, 1), (1, 2, 0), (2, 1, 0)):
        obs = [v[order[p]] for p in perm]           # observed vertices in another order
        obs_opp = (G.chord(obs[1], obs[2]), G.chord(obs[0], obs[2]), G.chord(obs[0], obs[1]))
        found = triangle.correspondences(obs_opp, cat_opp, 1e-6)
        # catalogue vertex m (order[m]) is observed vertex perm.index(m)
        assert found == [tuple(perm.index(m) for m in range(3))]
    # an isosceles triangle has two correspondences; handedness picks the right one
    iso = [(1.0, 0.0, 0.0), unit([1.0, 0.1, 0.0]), unit([1.0, 0.05, 0.3])]
    _, iso_opp = triangle.canonical_order(*iso)
    assert abs(iso_opp[1] - iso_opp[2]) < 2e-3
    assert len(triangle.correspondences(iso_opp, iso_opp, 2e-3)) == 2


def test_database_triangles_are_canonical_exact_and_sorted():
    _, _, _, db = setup()
    assert db.methods == stardb.METHOD_TRIANGLE and db.tri_n > 10000
    recs = [db.triangle_record(i) for i in range(db.tri_n)]
    assert recs == sorted(recs)
    rng = np.random.default_rng(3)
    chord_max = 2 * math.sin(db.tri_max_side / 2) * (1 + 1e-6)
    for i in rng.integers(0, db.tri_n, 400).tolist():
        akey, mkey, s0, s1, s2 = recs[i]
        v = [db.star_vector(s) for s in (s0, s1, s2)]
        ar, mo = triangle.area_moment(*v)
        assert akey == round(ar / db.tri_area_step)
        assert mkey == round(mo / db.tri_moment_step)
        opp = (G.chord(v[1], v[2]), G.chord(v[0], v[2]), G.chord(v[0], v[1]))
        assert opp[0] <= opp[1] <= opp[2] <= chord_max
        for s in (s0, s1, s2):
            assert db.star_flags(s) & stardb.STAR_FLAG_TRIANGLE
    keys = np.array([r[0] for r in recs])
    for lo, hi in ((0.0, 1e-4), (1e-3, 1.2e-3), (0.02, 0.021), (-1.0, 0.0), (0.5, 1.0)):
        start, stop = db.triangles_in_range(lo, hi)
        inside = np.flatnonzero((keys >= lo / db.tri_area_step) & (keys <= hi / db.tri_area_step))
        assert (start, stop) == ((inside[0], inside[-1] + 1) if len(inside) else (start, start))


def test_mirror_images_are_rejected_by_handedness(monkeypatch):
    """Mirrored fields never solve; the handedness test removes most mirrored candidates
    before any verification."""
    cam, cat, _, db = setup()
    rng = np.random.default_rng(9)
    mirrored = []
    for _ in range(15):
        scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.3, max_stars=30)
        mirrored.append((scene.vectors * [-1.0, 1.0, 1.0]).tolist())
    with_check = [starid.identify(m, db, method="triangle", tolerance_rad=TOL) for m in mirrored]
    assert all(sol.status != S.OK for sol in with_check)
    monkeypatch.setattr(triangle, "handed", lambda t_obs, t_cat, bound: True)
    without = [starid.identify(m, db, method="triangle", tolerance_rad=TOL) for m in mirrored]
    assert all(sol.status != S.OK for sol in without)     # verification catches them
    hyp_with = sum(s.hypotheses for s in with_check)
    hyp_without = sum(s.hypotheses for s in without)
    assert hyp_without > 20 and hyp_with < 0.2 * hyp_without


# --------------------------------------------------------------------------------------
# Scenes
# --------------------------------------------------------------------------------------

def test_combined_image_serves_every_method(scene_outcome):
    cam, cat, _, _ = setup()
    db = Database(build_database(cat, cam, mag_limit=6.0,
                                 methods=("pyramid", "triangle", "hashing")))
    assert db.methods == stardb.METHOD_PYRAMID | stardb.METHOD_TRIANGLE | stardb.METHOD_HASHING
    rng = np.random.default_rng(17)
    for _ in range(5):
        q = random_attitude(rng)
        scene = centroid_scene(cam, q, rng, cat, noise_px=0.3, n_false=2, max_stars=30)
        for method in starid.METHODS:
            sol = starid.identify(scene.vectors.tolist(), db, method=method, tolerance_rad=TOL)
            assert scene_outcome(sol, scene) == "correct", method


# --------------------------------------------------------------------------------------
# Corruption
# --------------------------------------------------------------------------------------



def test_corrupt_triangle_section_is_refused():
    _, _, image, _ = setup()
    off, length = struct.unpack_from(
        "<II", image, stardb.DIRECTORY_OFFSET + 8 * stardb.SEC_TRIANGLES)
    rng = np.random.default_rng(4)
    for i in [off, off + 5, off + stardb.TRI_HEADER_SIZE + 3, off + length - 1] + \
            rng.integers(off, off + length, 20).tolist():
        b = bytearray(image)
        b[i] ^= 0x10
        assert database.check(b)[0] == S.DATABASE_CORRUPT
    # CRC-consistent but inconsistent section headers
    assert status_of(reseal(image, lambda b: b.__setitem__(slice(off, off + 4), b"TRI9"))) == \
        S.DATABASE_UNSUPPORTED
    n = struct.unpack_from("<I", image, off + 4)[0]
    assert status_of(reseal(image, lambda b: struct.pack_into("<I", b, off + 4, n + 1))) == \
        S.DATABASE_BAD_LAYOUT
    assert status_of(reseal(image, lambda b: struct.pack_into("<f", b, off + 12, -1.0))) == \
        S.DATABASE_BAD_LAYOUT
    kv_end = off + length - 4                       # the last k-vector entry must be n
    assert status_of(reseal(image, lambda b: struct.pack_into("<I", b, kv_end, n - 1))) == \
        S.DATABASE_BAD_LAYOUT
    entry = stardb.DIRECTORY_OFFSET + 8 * stardb.SEC_TRIANGLES
    assert status_of(reseal(image, lambda b: struct.pack_into(
        "<II", b, entry, 0, 0))) == S.DATABASE_BAD_LAYOUT


# --------------------------------------------------------------------------------------
# MicroPython 1.27 (WebAssembly port in Node)
# --------------------------------------------------------------------------------------

_AREA_CHECK = r'''
from lodestar.firmware.starid import triangle
assert triangle.area(3.0, 4.0, 5.0) == 6.0
'''

_CORRUPT_CHECK = r'''
with open("/db.bin", "rb") as f:
    bad = bytearray(f.read())
bad[len(bad) - 100] ^= 1
print("CORRUPT", status.name(database.check(bad)[0]))
'''


def test_triangle_under_micropython(micropython):
    """File-backed triangle database and identification under MicroPython give the CPython
    solutions (a mirror image included)."""
    cam, cat, image, db = setup()
    scenes, expected = solved_scenes(cam, cat, db, "triangle", np.random.default_rng(31), 5,
                                     4, TOL, 2000)
    assert [e[0] for e in expected[:4]] == [S.OK] * 4 and expected[4][0] != S.OK
    code, out = identify_under_micropython(micropython, image, "triangle", scenes, expected,
                                           TOL, 2000, checks=_AREA_CHECK,
                                           epilogue=_CORRUPT_CHECK)
    print(out)
    assert code == 0, out
    assert "IMPLEMENTATION micropython (1, 27" in out
    assert "SOLVED 5" in out and "CORRUPT DATABASE_CORRUPT" in out and "DONE" in out
