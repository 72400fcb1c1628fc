"""Tests of the flight star identification (``lodestar.firmware.pyramid``, ``verify``,
``starid``) on synthetic estcube2 centroid scenes: success rate, zero wrong solutions,
mirror images, false stars, too few stars, ambiguity, budget; and the helpers (q-method
attitude fit, binomial tail) against scipy.

A scene is *correct* when it is accepted with an attitude error <= 0.05 deg and every
reported HIP is a component of the observed star (close doubles blend into one centroid);
*wrong* when it is accepted otherwise.  Larger campaigns: ``benchmarks/bench_starid.py``.
"""

import functools
import math

import numpy as np
import pytest
from lodestar.firmware import quaternion, starid
from lodestar.firmware import status as S
from lodestar.firmware.database import Database
from lodestar.firmware.starid import search as SE
from lodestar.firmware.starid import verify as V
from lodestar.ground.database import build_database
from lodestar.ground.scenes import attitude_error_deg, centroid_scene
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import Catalogue, load
from lodestar.sim.goldenset import window_camera
from lodestar.sim.presets import load_preset
from scipy.spatial.transform import Rotation
from scipy.stats import binom
from starid_support import assert_identify_within_heap_budget, outcome

TOL = 3.0e-4          # rad: ~2.2 px of estcube2 (28.4"/px), > 4 sigma of 0.5 px noise


@functools.lru_cache(maxsize=None)
def setup():
    cam = load_preset("estcube2")
    cat = load()
    return cam, cat, Database(build_database(cat, cam, mag_limit=6.0))


# --------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------

def test_fit_attitude_matches_scipy_convention():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = random_attitude(rng)
        ref = rng.normal(size=(6, 3))
        ref /= np.linalg.norm(ref, axis=1, keepdims=True)
        obs = Rotation.from_quat(q).apply(ref) + rng.normal(0, 1e-5, (6, 3))
        est = SE.fit_attitude(obs.tolist(), ref.tolist())
        assert attitude_error_deg(est, q) < 0.01
        assert np.allclose(np.array(quaternion.matrix(q)).reshape(3, 3),
                           Rotation.from_quat(q).as_matrix(), atol=1e-12)
    # narrow field (all vectors within 10 deg of one direction), 180 deg rotations
    for q in ([1.0, 0, 0, 0], [0, 0, 1.0, 0], random_attitude(rng)):
        d = rng.normal(0, 0.1, (5, 3)) + [0, 0, 1]
        ref = d / np.linalg.norm(d, axis=1, keepdims=True)
        obs = Rotation.from_quat(q).apply(ref)
        assert attitude_error_deg(SE.fit_attitude(obs.tolist(), ref.tolist()), q) < 1e-5


def test_binomial_tail_matches_scipy():
    for n, k, p in [(20, 5, 1e-4), (30, 10, 0.05), (10, 0, 0.3), (10, 11, 0.3), (50, 3, 0.2),
                    (28, 26, 1e-4), (5, 5, 0.999), (12, 4, 0.0)]:
        expected = binom.sf(k - 1, n, p)
        got = V.binomial_tail(n, k, p)
        assert got == pytest.approx(expected, rel=1e-9, abs=1e-300), (n, k, p)


def test_solid_angle():
    assert V.fov_solid_angle(math.pi, math.pi) == pytest.approx(2 * math.pi)
    small = math.radians(1.0)
    assert V.fov_solid_angle(small, small) == pytest.approx(small * small, rel=1e-4)


# --------------------------------------------------------------------------------------
# Scenes
# --------------------------------------------------------------------------------------

def test_monte_carlo_200_scenes():
    cam, cat, db = setup()
    rng = np.random.default_rng(2024)
    counts = {"correct": 0, "wrong": 0, "no-solve": 0}
    for _ in range(200):
        q = random_attitude(rng)
        scene = centroid_scene(cam, q, rng, cat, noise_px=rng.uniform(0.1, 0.5),
                               n_false=int(rng.integers(0, 6)), drop_fraction=0.1,
                               max_stars=30)
        sol = starid.identify(scene.vectors.tolist(), db, tolerance_rad=TOL)
        counts[outcome(sol, scene)] += 1
        if sol.status == S.OK:
            assert sol.probability < 1e-9 and len(sol.matches) >= 4
            assert sol.patterns_tried >= 1 and sol.hypotheses >= 1
    print("\npyramid, 200 estcube2 scenes:", counts)
    assert counts["wrong"] == 0
    assert counts["correct"] >= 190


def test_windowed_frame_and_default_tolerance():
    """A 1024 x 1024 sensor window (8.05 x 8.05 deg) with its own database and the default
    tolerance (fov_h / 1000 = 1 px).  Median 8 stars per field at V <= 6: sparse fields do
    not solve, none may solve wrongly."""
    _, cat, _ = setup()
    cam = window_camera(load_preset("estcube2"), (784, 460, 1024, 1024))
    db = Database(build_database(cat, cam, mag_limit=6.0))
    rng = np.random.default_rng(5)
    counts = {"correct": 0, "wrong": 0, "no-solve": 0}
    for _ in range(60):
        scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.3, n_false=2,
                               drop_fraction=0.1)
        sol = starid.identify(scene.vectors.tolist(), db)
        counts[outcome(sol, scene)] += 1
    assert counts["wrong"] == 0
    assert counts["correct"] >= 42


def test_mirrored_scenes_are_not_accepted():
    cam, cat, db = setup()
    rng = np.random.default_rng(9)
    for _ in range(30):
        scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.3, max_stars=30)
        mirrored = scene.vectors * [-1.0, 1.0, 1.0]
        sol = starid.identify(mirrored.tolist(), db, tolerance_rad=TOL)
        assert sol.status != S.OK


def test_false_stars_only_are_not_accepted():
    cam, _, db = setup()
    rng = np.random.default_rng(10)
    for _ in range(15):
        n = int(rng.integers(4, 25))
        v = cam.unproject(rng.uniform(0, cam.width - 1, n), rng.uniform(0, cam.height - 1, n))
        sol = starid.identify(v.tolist(), db, tolerance_rad=TOL)
        assert sol.status in (S.NO_MATCH, S.BUDGET_EXHAUSTED)
        assert sol.q is None and sol.matches == []


def test_too_few_stars_and_bad_input():
    cam, cat, db = setup()
    rng = np.random.default_rng(12)
    scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.2)
    for n in range(4):
        sol = starid.identify(scene.vectors[:n].tolist(), db, tolerance_rad=TOL)
        assert sol.status == S.TOO_FEW_STARS
        assert S.name(sol.status) == "TOO_FEW_STARS"
    bad = scene.vectors.tolist()
    bad[2] = [float("nan"), 0.0, 1.0]
    assert starid.identify(bad, db).status == S.BAD_INPUT
    bad[2] = [0.0, 0.0, 0.0]
    assert starid.identify(bad, db).status == S.BAD_INPUT
    assert starid.identify([[1, 2]] * 5, db).status == S.BAD_INPUT
    assert starid.identify(scene.vectors.tolist(), db, tolerance_rad=-1.0).status == \
        S.BAD_INPUT
    assert starid.identify(scene.vectors.tolist(), db, method="triangle").status == \
        S.DATABASE_UNSUPPORTED
    assert starid.identify(scene.vectors.tolist(), db, method="voting").status == \
        S.BAD_INPUT


def test_budget_is_deterministic():
    cam, cat, db = setup()
    rng = np.random.default_rng(13)
    q = random_attitude(rng)
    scene = centroid_scene(cam, q, rng, cat, noise_px=0.2)
    # four false stars first: the first triples cannot solve
    false = cam.unproject(rng.uniform(0, cam.width - 1, 4), rng.uniform(0, cam.height - 1, 4))
    vectors = np.concatenate([false, scene.vectors]).tolist()
    sol = starid.identify(vectors, db, tolerance_rad=TOL, budget=3)
    assert sol.status == S.BUDGET_EXHAUSTED and sol.patterns_tried == 3
    full = starid.identify(vectors, db, tolerance_rad=TOL)
    again = starid.identify(vectors, db, tolerance_rad=TOL)
    assert full.status == S.OK and full.patterns_tried > 3
    assert (full.q, full.matches, full.patterns_tried) == (again.q, again.matches,
                                                           again.patterns_tried)
    assert all(o >= 4 for o, _ in full.matches)       # the false stars stay unnamed


def test_file_backed_database_gives_the_same_solution(tmp_path):
    cam, cat, db = setup()
    path = tmp_path / "db.bin"
    from lodestar.ground.database import build_database as build
    path.write_bytes(build(cat, cam, mag_limit=6.0))
    fdb = Database.open(str(path))
    try:
        rng = np.random.default_rng(14)
        scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.3, n_false=2)
        a = starid.identify(scene.vectors.tolist(), db, tolerance_rad=TOL)
        b = starid.identify(scene.vectors.tolist(), fdb, tolerance_rad=TOL)
        assert a.status == S.OK
        assert (a.q, a.matches, a.patterns_tried) == (b.q, b.matches, b.patterns_tried)
    finally:
        fdb.close()


def test_repeated_constellation_is_ambiguous():
    """Two identical star groups in different parts of the sky: both attitudes verify."""
    rng = np.random.default_rng(15)
    d = rng.normal(0, 0.05, (10, 3)) + [1.0, 0.0, 0.0]     # a group around RA 0, Dec 0
    group = d / np.linalg.norm(d, axis=1, keepdims=True)
    copy = Rotation.from_euler("zy", [120, -40], degrees=True).apply(group)
    vec = np.concatenate([group, copy])
    ra = np.degrees(np.arctan2(vec[:, 1], vec[:, 0])) % 360
    dec = np.degrees(np.arcsin(vec[:, 2]))
    mags = np.tile(np.linspace(2.0, 5.0, 10), 2).astype(np.float32)
    cat = Catalogue(np.arange(1, 21, dtype=np.int32), ra, dec, mags,
                    np.full(20, np.nan, dtype=np.float32), 2024.0)
    cam = load_preset("estcube2")
    db = Database(build_database(cat, cam, mag_limit=6.0, pattern_per_region=20))
    q = Rotation.from_euler("y", -90, degrees=True).as_quat()     # boresight towards +x
    obs = Rotation.from_quat(q).apply(group)
    assert np.all(cam.project(obs)[2])
    sol = starid.identify(obs.tolist(), db, tolerance_rad=TOL)
    assert sol.status == S.AMBIGUOUS
    assert sol.q is None
    # with the copy removed the same observation solves
    db1 = Database(build_database(cat[np.arange(10)], cam, mag_limit=6.0,
                                  pattern_per_region=20))
    sol = starid.identify(obs.tolist(), db1, tolerance_rad=TOL)
    assert sol.status == S.OK and attitude_error_deg(sol.q, q) < 1e-3
    assert sorted(h for _, h in sol.matches) == list(range(1, 11))


# --------------------------------------------------------------------------------------
# The same identification under MicroPython 1.27 (WebAssembly port in Node)
# --------------------------------------------------------------------------------------

MICROPYTHON_STARID = r'''
import binascii
import gc
import sys
from lodestar.firmware import database, starid, status
print("IMPLEMENTATION", sys.implementation.name, sys.implementation.version)
with open("/db.bin", "wb") as f:
    f.write(binascii.a2b_base64(IMAGE_B64))
IMAGE_B64 = None
#@split
gc.collect()
base = gc.mem_alloc()
db, code, reason = database.load("/db.bin")
assert code == status.OK, reason
#@split
gc.collect()
print("DBMEM", gc.mem_alloc() - base)
for scene, expected in zip(SCENES, EXPECTED):
    sol = starid.identify(scene, db, tolerance_rad=TOL)
    got = (sol.status, sol.matches, sol.patterns_tried)
    assert got == expected[:3], (got, expected)
    if sol.q is not None:
        d = max(abs(a - b) for a, b in zip(sol.q, expected[3]))
        assert d < 1e-9, d
print("SOLVED", len(SCENES))
db.close()
#@split
with open("/db.bin", "rb") as f:
    bad = bytearray(f.read())
bad[len(bad) // 2] ^= 1
print("CORRUPT", status.name(database.check(bad)[0]),
      status.name(database.check(bytes(bad[:200]))[0]))
try:
    database.Database(bytes(bad[:100]))
except database.DatabaseError as exc:
    print("RAISED", status.name(exc.status), str(exc).startswith("DATABASE_BAD_LENGTH: "))
print("DONE")
'''


def test_identification_under_micropython():
    """File-backed database and Pyramid under MicroPython give the CPython solutions."""
    import base64

    from micropython_support import run_micropython
    from test_firmware_micropython import lit

    cam, cat, _ = setup()
    image = build_database(cat, cam, mag_limit=6.0)
    db = Database(image)
    rng = np.random.default_rng(31)
    scenes, expected = [], []
    for k in range(6):
        scene = centroid_scene(cam, random_attitude(rng), rng, cat, noise_px=0.3,
                               n_false=k % 4, drop_fraction=0.1, max_stars=20)
        vectors = [tuple(v) for v in scene.vectors.tolist()]
        if k == 5:
            vectors = [(-x, y, z) for x, y, z in vectors]          # a mirror image
        sol = starid.identify(vectors, db, tolerance_rad=TOL)
        scenes.append(vectors)
        expected.append((sol.status, sol.matches, sol.patterns_tried, sol.q))
    assert [e[0] for e in expected] == [S.OK] * 5 + [S.NO_MATCH]
    script = "\n".join(["TOL = " + lit(TOL), "SCENES = " + lit(scenes),
                        "EXPECTED = " + lit(expected),
                        "IMAGE_B64 = " + lit(base64.b64encode(image))])
    code, out = run_micropython(script + "\n" + MICROPYTHON_STARID, heapsize=16 << 20,
                                timeout=600)
    print(out)
    assert code == 0, out
    assert "IMPLEMENTATION micropython (1, 27" in out
    assert "SOLVED 6" in out and "CORRUPT DATABASE_CORRUPT DATABASE_BAD_LENGTH" in out
    assert "RAISED DATABASE_BAD_LENGTH True" in out and "DONE" in out


@pytest.mark.parametrize("preset", ["estcube2", "lohmann"])
def test_live_peak_of_a_hard_solve_is_within_the_heap_budget(preset):
    """30 stars of which 10 false, 1 px noise, the pipeline's tolerance: the CPython live
    peak of one identification (a bound of MicroPython's) stays within the 96 KB budget.
    The wide lohmann field has the longest pair-candidate ranges (materialised as dicts of
    lists they took about 200 KB)."""
    _, cat, _ = setup()
    cam = load_preset(preset)
    db = Database(build_database(cat, cam, mag_limit=6.0))
    assert_identify_within_heap_budget("pyramid", cam, cat, db)
