"""What is Pyramid's own (``lodestar.firmware.starid.pyramid``): a windowed sensor with the
default tolerance, a file-backed database, a repeated constellation (``AMBIGUOUS``), the
wide lohmann field's heap peak, and the same results under MicroPython 1.27.  The checks
every method shares are in ``test_methods.py``.  Larger campaigns:
``benchmarks/bench_starid.py``.
"""

import functools

import numpy as np
from scipy.spatial.transform import Rotation

from lodestar.firmware import starid
from lodestar.firmware import status as S
from lodestar.firmware.database import Database
from lodestar.ground.database import build_database
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import Catalogue, load
from lodestar.sim.centroids import attitude_error_deg, centroid_scene
from lodestar.sim.goldenset import window_camera
from lodestar.sim.presets import load_preset
from tests.firmware.mpy import identify_under_micropython, solved_scenes

TOL = 3.0e-4          # rad: ~2.2 px of estcube2 (28.4"/px), > 4 sigma of 0.5 px noise


@functools.lru_cache(maxsize=None)
def setup():
    cam = load_preset("estcube2")
    cat = load()
    return cam, cat, Database(build_database(cat, cam, mag_limit=6.0))


# --------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------

# --------------------------------------------------------------------------------------
# Scenes
# --------------------------------------------------------------------------------------

def test_windowed_frame_and_default_tolerance(scene_outcome):
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
        counts[scene_outcome(sol, scene)] += 1
    assert counts["wrong"] == 0
    assert counts["correct"] >= 42


def test_file_backed_database_gives_the_same_solution(tmp_path):
    cam, cat, db = setup()
    path = tmp_path / "db.bin"
    path.write_bytes(build_database(cat, cam, mag_limit=6.0))
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

_CORRUPT_CHECKS = r'''
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
'''


def test_identification_under_micropython(micropython):
    """File-backed database and Pyramid under MicroPython give the CPython solutions."""
    cam, cat, _ = setup()
    image = build_database(cat, cam, mag_limit=6.0)
    scenes, expected = solved_scenes(cam, cat, Database(image), "pyramid",
                                     np.random.default_rng(31), 6, 4, TOL, 2000)
    assert [e[0] for e in expected] == [S.OK] * 5 + [S.MIRRORED]
    code, out = identify_under_micropython(micropython, image, "pyramid", scenes, expected,
                                           TOL, 2000, epilogue=_CORRUPT_CHECKS)
    print(out)
    assert code == 0, out
    assert "IMPLEMENTATION micropython (1, 27" in out
    assert "SOLVED 6" in out and "CORRUPT DATABASE_CORRUPT DATABASE_BAD_LENGTH" in out
    assert "RAISED DATABASE_BAD_LENGTH True" in out and "DONE" in out


def test_live_peak_of_a_hard_solve_on_the_wide_field_is_within_the_heap_budget(
        heap_budget_check):
    """As ``test_methods.py``'s heap test, on the wide lohmann field: it has Pyramid's
    longest pair-candidate ranges (materialised as dicts of lists they took about 200 KB)."""
    _, cat, _ = setup()
    cam = load_preset("lohmann")
    db = Database(build_database(cat, cam, mag_limit=6.0))
    heap_budget_check("pyramid", cam, cat, db)
