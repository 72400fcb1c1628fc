"""Lohmann's planar-triangle star identification: area and polar moment over a k-vector.

Lohmann (2017), "Star Imager for Nanosatellite Applications"; tolerances after Cole &
Crassidis (2006).  :func:`identify` takes camera-frame unit vectors of the observed stars,
**brightest first**, and a :class:`lodestar.firmware.database.Database` with the ``triangles``
section (``"triangle"`` in the ``methods`` of ``lodestar.ground.database``); statuses as the
other methods (``TOO_FEW_STARS`` below 3 stars).  The geometry helpers (:func:`sides`,
:func:`area`, :func:`moment`, :func:`bounds`) work on planar chord triangles of unit vectors.
Geometry, database layout, tolerances and algorithm: ``docs/starid.md`` (Triangle).  Pure
Python for CPython and MicroPython (``math`` only).
"""

import math

from lodestar.contract.stardb import METHOD_TRIANGLE

from ..geometry import chord, norm, triple
from .search import DEFAULT_MAX_WORK, RECORD_WORK, Search, handed, identify_with, triple_bound

DATABASE_BIT = METHOD_TRIANGLE
"""The database's ``methods`` bit this method reads."""
MAX_WORK = DEFAULT_MAX_WORK
"""The method's work budget: the shared default (not calibrated in MCU time)."""

BOUND_MARGIN = 1.05
"""Factor on the first-order tolerance bounds (covers the neglected curvature terms)."""


def sides(v1, v2, v3):
    """Lohmann's (corrected) sides ``(a, b, c) = (|v1 - v2|, |v2 - v3|, |v1 - v3|)``."""
    return chord(v1, v2), chord(v2, v3), chord(v1, v3)


def area(a, b, c):
    """Heron's area of the triangle of sides ``a, b, c`` (Kahan's stable evaluation of
    ``sqrt(s (s - a)(s - b)(s - c))``); 0 for a degenerate or impossible triangle."""
    if a < b:
        a, b = b, a
    if b < c:
        b, c = c, b
    if a < b:
        a, b = b, a
    p = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c))
    return 0.25 * math.sqrt(p) if p > 0.0 else 0.0


def moment(a, b, c, area_=None):
    """Polar moment ``A (a^2 + b^2 + c^2) / 36`` (``area_``: ``A`` if already known)."""
    if area_ is None:
        area_ = area(a, b, c)
    return area_ * (a * a + b * b + c * c) / 36.0


def area_moment(v1, v2, v3):
    """``(area, moment)`` of the planar triangle of three unit vectors."""
    a, b, c = sides(v1, v2, v3)
    ar = area(a, b, c)
    return ar, moment(a, b, c, ar)


def _twice_minus(a, b, c):
    """``(a - b) - (c - a)``, i.e. ``2 a - b - c`` (3 times ``a``'s offset from the
    triangle's centroid)."""
    return ((a[0] - b[0]) - (c[0] - a[0]), (a[1] - b[1]) - (c[1] - a[1]),
            (a[2] - b[2]) - (c[2] - a[2]))


def bounds(v1, v2, v3, eps):
    """``(dA, dJ)``: bounds on the change of area and polar moment when each vertex moves by
    at most ``eps`` (rad); first order (Cole & Crassidis' Jacobian, worst case) times
    :data:`BOUND_MARGIN`, plus second-order terms."""
    a, b, c = sides(v1, v2, v3)
    ar = area(a, b, c)
    s2 = a * a + b * b + c * c
    # |grad_i A| = opposite side / 2; |2 v_i - v_j - v_k| = 3 |v_i - centroid|
    m1 = norm(_twice_minus(v1, v2, v3))
    m2 = norm(_twice_minus(v2, v3, v1))
    m3 = norm(_twice_minus(v3, v1, v2))
    half = 0.5 * (a + b + c)
    d_area = eps * half
    d_moment = eps * (s2 / 36.0 * half + ar / 18.0 * (m1 + m2 + m3))
    e2 = eps * eps
    return (BOUND_MARGIN * d_area + 3.0 * e2,
            BOUND_MARGIN * d_moment + e2 * (s2 / 6.0 + 4.0 * ar + half * half))


def canonical_order(v1, v2, v3):
    """Vertex order ``(i0, i1, i2)`` (indices 0..2) opposite the shortest, middle and
    longest side (ties by index) and those sides ``(t0, t1, t2)``."""
    s = [(chord(v2, v3), 0), (chord(v1, v3), 1), (chord(v1, v2), 2)]
    s.sort()                            # (side, index) tuples: ties by index, no key calls
    return (s[0][1], s[1][1], s[2][1]), (s[0][0], s[1][0], s[2][0])


_PERMUTATIONS = ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0))


def correspondences(obs_opp, cat_opp, tol):
    """Vertex permutations ``p`` (catalogue vertex ``m`` -> observed vertex ``p[m]``) whose
    opposite sides agree: ``|obs_opp[p[m]] - cat_opp[m]| <= tol`` for ``m = 0, 1, 2``."""
    out = []
    for p in _PERMUTATIONS:
        if abs(obs_opp[p[0]] - cat_opp[0]) <= tol and \
                abs(obs_opp[p[1]] - cat_opp[1]) <= tol and \
                abs(obs_opp[p[2]] - cat_opp[2]) <= tol:
            out.append(p)
    return out


class _Search(Search):
    BIT = DATABASE_BIT

    def __init__(self, b, db, tol, max_prob, distinct, streaks, max_stars):
        Search.__init__(self, b, db, tol, max_prob, distinct, streaks, max_stars)
        self.max_side0 = 2.0 * math.sin(0.5 * db.tri_max_side)

    def patterns(self):
        return _triples(self.n)

    def try_pattern(self, tri):
        """Accepted ``[(q, Verification)]`` of the observed triple ``tri = (i, j, k)``."""
        i, j, k = tri
        b = self.b
        db = self.db
        v = (b[i], b[j], b[k])
        h = self.half
        tol = self.tol + max(h[i], h[j], h[k])     # a streak: off by up to half along it
        side_tol = 2.0 * tol * BOUND_MARGIN + 1e-7
        max_side = self.max_side0 + 2.0 * tol
        opp = (chord(v[1], v[2]), chord(v[0], v[2]), chord(v[0], v[1]))
        if opp[0] > max_side or opp[1] > max_side or opp[2] > max_side:
            return []
        ar = area(opp[0], opp[1], opp[2])
        mo = moment(opp[0], opp[1], opp[2], ar)
        d_area, d_moment = bounds(v[0], v[1], v[2], tol)
        d_area += 0.5 * db.tri_area_step
        d_moment += 0.5 * db.tri_moment_step
        mstep = db.tri_moment_step
        start, stop = db.triangles_in_range(ar - d_area, ar + d_area)
        t_bound = triple_bound(v[0], v[1], v[2], tol)
        accepted = []
        for r in range(start, stop):
            self.spend(RECORD_WORK)
            _, mkey, c0, c1, c2 = db.triangle_record(r)
            if abs(mkey * mstep - mo) > d_moment:
                continue
            r0, r1, r2 = db.star_vector(c0), db.star_vector(c1), db.star_vector(c2)
            cat_opp = (chord(r1, r2), chord(r0, r2), chord(r0, r1))
            perms = correspondences(opp, cat_opp, side_tol)
            if not perms:
                continue
            t_cat = triple(r0, r1, r2)
            for p in perms:
                t_obs = triple(v[p[0]], v[p[1]], v[p[2]])
                if not handed(t_obs, t_cat, t_bound):
                    continue
                self.test((tri[p[0]], tri[p[1]], tri[p[2]]), (c0, c1, c2), accepted)
        return accepted


def identify(vectors, database, tolerance_rad, budget=2000, max_stars=16,
             max_mismatch_prob=1e-9, distinct_rad=None, streaks=None,
             max_work=MAX_WORK):
    """Planar-triangle identification (:func:`.search.identify_with`; ``budget`` counts
    triples; a streak widens a triangle's tolerances by the largest ``half`` of its stars);
    returns a :class:`.search.Solution`."""
    return identify_with(_Search, vectors, database, tolerance_rad, budget, max_stars,
                         max_mismatch_prob, distinct_rad, streaks, max_work)


def _triples(n):
    """Triples of ``n`` stars, every one whose faintest star is ``k`` before any with a
    fainter one (``docs/starid.md``, Triangle step 2)."""
    for k in range(2, n):
        for j in range(1, k):
            for i in range(j):
                yield i, j, k
