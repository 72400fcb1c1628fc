"""Tests of ``lodestar.firmware.kvector``: the k-vector range query returns exactly the
brute-force range, for float and integer keys, Mortari's one-bin-per-key table and coarse
tables, float32-rounded line parameters, and the database's pair index."""

import bisect
import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lodestar.firmware import kvector
from lodestar.firmware.database import Database
from lodestar.ground.database import build_database, kvector_numpy


def brute(keys, lo, hi):
    """Index range of ``lo <= key <= hi`` in sorted ``keys`` by bisection."""
    if not lo <= hi:
        return 0, 0
    a = bisect.bisect_left(keys, lo)
    b = bisect.bisect_right(keys, hi)
    return (a, b) if a < b else (a, a)


def same_range(got, expected):
    """Equal ranges, or both empty."""
    return got == expected or (got[0] == got[1] and expected[0] == expected[1])


def f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


@pytest.mark.parametrize("n_bins", [None, 1, 7, 100])
def test_random_float_keys(n_bins):
    rng = np.random.default_rng(1)
    keys = sorted(rng.uniform(-3.0, 5.0, 500).tolist() + [1.0] * 5 + [2.5] * 3)
    kv = kvector.build(keys, n_bins)
    queries = [(keys[i], keys[j]) for i, j in rng.integers(0, len(keys), (200, 2))]
    queries += [tuple(sorted(rng.uniform(-5, 7, 2))) for _ in range(300)]
    queries += [(1.0, 1.0), (2.5, 2.5), (keys[0], keys[-1]), (-10, -4), (6, 9), (-1e300, 1e300),
                (0.3, 0.2), (float("nan"), 1.0), (-math.inf, math.inf)]
    for lo, hi in queries:
        assert same_range(kvector.query_list(keys, lo, hi, kv), brute(keys, lo, hi)), (lo, hi)


@settings(max_examples=200, deadline=None)
@given(keys=st.lists(st.integers(0, 60), min_size=1, max_size=80),
       n_bins=st.integers(1, 100), lo=st.integers(-5, 65), width=st.integers(-3, 70))
def test_integer_keys_property(keys, n_bins, lo, width):
    keys = sorted(keys)
    kv = kvector.build(keys, n_bins)
    hi = lo + width
    assert same_range(kvector.query_list(keys, lo, hi, kv), brute(keys, lo, hi))
    # fractional bounds too (the database converts angles to key units)
    assert same_range(kvector.query_list(keys, lo - 0.5, hi + 0.25, kv),
                      brute(keys, lo - 0.5, hi + 0.25))


def test_float32_line_parameters_stay_exact():
    """m, q stored as float32 (as in the database image) with a table built from them."""
    rng = np.random.default_rng(2)
    keys = np.sort(rng.integers(0, 65536, 20000))
    for n_bins in (1, 50, 625, 20000):
        m, q, table = kvector_numpy(keys, n_bins)
        assert f32(m) == m and f32(q) == q
        klist = keys.tolist()
        tlist = table.tolist()
        for lo, hi in rng.uniform(-10, 65546, (300, 2)):
            lo, hi = min(lo, hi), max(lo, hi)
            got = kvector.query(lo, hi, m, q, n_bins, tlist.__getitem__, klist.__getitem__,
                                len(klist))
            assert same_range(got, brute(klist, lo, hi))


def test_numpy_builder_equals_reference():
    rng = np.random.default_rng(3)
    keys = np.sort(rng.integers(0, 1000, 3000))
    m, q, table = kvector_numpy(keys, 250)
    assert table.tolist() == kvector.table(keys.tolist(), m, q, 250)
    assert table[0] == 0 and table[-1] == len(keys)
    assert np.all(np.diff(table) >= 0)


def test_single_key_and_errors():
    kv = kvector.build([3.0])
    assert kvector.query_list([3.0], 3.0, 3.0, kv) == (0, 1)
    assert kvector.query_list([3.0], 3.1, 4.0, kv)[0] == kvector.query_list([3.0], 3.1, 4.0,
                                                                            kv)[1]
    with pytest.raises(ValueError):
        kvector.build([])
    with pytest.raises(ValueError):
        kvector.build([2.0, 1.0])
    with pytest.raises(ValueError):
        kvector.build([1.0, 2.0], n_bins=0)


def test_database_pair_index_is_exact():
    """``Database.pairs_in_range`` against a brute-force scan of the stored pair keys."""
    db = Database(build_database(fov_h_deg=20.0, aspect=4 / 3, mag_limit=5.0))
    keys = [db.pair_key(i) for i in range(db.n_pairs)]
    assert keys == sorted(keys)
    step = db.key_step
    rng = np.random.default_rng(4)
    queries = [tuple(sorted(rng.uniform(-0.01, db.pair_max_angle + 0.01, 2)))
               for _ in range(300)]
    queries += [(k * step - 3e-4, k * step + 3e-4) for k in rng.choice(keys, 100)]
    queries += [(k * step, k * step) for k in rng.choice(keys, 50)]
    for lo, hi in queries:
        start, stop = db.pairs_in_range(lo, hi)
        expected = [i for i, k in enumerate(keys) if lo / step <= k <= hi / step]
        assert list(range(start, stop)) == expected, (lo, hi)


@given(st.lists(st.integers(-50, 50), max_size=40), st.integers(-60, 60))
def test_lower_bound_equals_bisect_left(keys, value):
    keys.sort()
    assert kvector.lower_bound(keys, value) == bisect.bisect_left(keys, value)
