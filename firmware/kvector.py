"""Mortari's k-vector (Mortari & Neta 2000): a search-less range query over sorted keys.

:func:`query` returns ``(start, stop)`` such that ``keys[start:stop]`` are exactly the keys
with ``lo <= key <= hi`` (``start == stop`` when there are none), identical to a brute-force
scan: the bin range is widened by one bin each side against float32 rounding, then trimmed
by binary searches (``docs/firmware.md``, k-vector, gives the construction and ``eps``).
Table and keys are read through caller-supplied functions, so lists, arrays and tables read
by offset from a database (:mod:`lodestar.firmware.database`) share the code.  :func:`build`
is the reference builder (the ground's numpy builder must agree with it).
Pure Python for CPython and MicroPython (only ``math``).
"""

import math

from .emit import native


def build(keys, n_bins=None, margin=None):
    """Build the k-vector of ``keys`` (a sorted sequence of numbers, ascending).

    ``n_bins`` defaults to ``len(keys)`` (Mortari's choice); ``margin`` (``eps``)
    defaults to ``1e-9 * max(1, |y0|, |y_last|, span)``.  Returns ``(m, q, table)`` with
    ``table`` a list of ``n_bins + 1`` ints.  Raises ``ValueError`` for an empty or unsorted
    key list or ``n_bins < 1``.
    """
    n = len(keys)
    if n == 0:
        raise ValueError("k-vector of an empty key list")
    if n_bins is None:
        n_bins = n
    if n_bins < 1:
        raise ValueError("n_bins must be >= 1")
    for i in range(1, n):
        if keys[i] < keys[i - 1]:
            raise ValueError("keys are not sorted ascending")
    lo, hi = keys[0], keys[n - 1]
    m, q = line(lo, hi, n_bins, margin)
    return m, q, table(keys, m, q, n_bins)


def line(lo, hi, n_bins, margin=None):
    """The k-vector line ``(m, q)`` through ``(0, lo - eps)`` and ``(n_bins, hi + eps)``."""
    if margin is None:
        margin = 1e-9 * max(1.0, abs(lo), abs(hi), hi - lo)
    q = lo - margin
    m = (hi - lo + 2 * margin) / n_bins
    return m, q


def table(keys, m, q, n_bins):
    """``[#{y <= q + m*j} for j in 0..n_bins]`` for sorted ``keys`` (one linear sweep)."""
    out = []
    n = len(keys)
    i = 0
    for j in range(n_bins + 1):
        z = q + m * j
        while i < n and keys[i] <= z:
            i += 1
        out.append(i)
    out[n_bins] = n          # the line ends above the last key by construction
    return out


@native
def _bin_floor(x, n_bins):
    """``floor(x)`` clamped to ``[-1, n_bins + 1]`` (safe for huge or infinite x)."""
    if x != x:               # NaN
        return -1
    if x < -1.0:
        return -1
    if x > n_bins + 1.0:
        return n_bins + 1
    return int(math.floor(x))


@native
def query(lo, hi, m, q, n_bins, table_at, key_at, n):
    """Exact index range ``(start, stop)`` of the sorted keys with ``lo <= key <= hi``.

    ``m``, ``q``, ``n_bins``: the k-vector line and its number of bins; ``table_at(j)``
    returns ``K[j]`` for ``0 <= j <= n_bins``; ``key_at(i)`` returns ``y[i]``; ``n`` is the
    number of keys.  ``lo > hi`` (or NaN) gives an empty range.
    """
    if n <= 0 or not (lo <= hi):
        return 0, 0
    # widened bins: z(jb) < lo and z(jt) > hi by at least one bin despite rounding
    jb = _bin_floor((lo - q) / m, n_bins) - 1
    jt = _bin_floor((hi - q) / m, n_bins) + 2     # ceil(x) <= floor(x) + 1, plus one bin
    if jb > n_bins or jt < 0:
        return 0, 0
    start = table_at(jb) if jb > 0 else 0
    stop = table_at(jt) if jt < n_bins else n
    # trim: first index with key >= lo, then first index with key > hi
    a, b = start, stop
    while a < b:
        mid = (a + b) >> 1
        if key_at(mid) < lo:
            a = mid + 1
        else:
            b = mid
    first = a
    b = stop
    while a < b:
        mid = (a + b) >> 1
        if key_at(mid) <= hi:
            a = mid + 1
        else:
            b = mid
    return first, a


def lower_bound(keys, value):
    """The first index ``i`` of the ascending indexable ``keys`` with ``keys[i] >= value``
    (``len(keys)`` when there is none): a binary search."""
    lo, hi = 0, len(keys)
    while lo < hi:
        mid = (lo + hi) >> 1
        if keys[mid] < value:
            lo = mid + 1
        else:
            hi = mid
    return lo


def query_list(keys, lo, hi, kvec):
    """Convenience: :func:`query` over a Python list ``keys`` and ``kvec = (m, q, table)``."""
    m, q, tab = kvec
    return query(lo, hi, m, q, len(tab) - 1, tab.__getitem__, keys.__getitem__, len(keys))
