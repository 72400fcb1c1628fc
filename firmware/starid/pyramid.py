"""Mortari's Pyramid lost-in-space star identification over the k-vector pair database.

Mortari, Samaan, Bruccoleri & Junkins, "The Pyramid Star Identification Technique",
Navigation 51(3), 2004.  :func:`identify` takes camera-frame unit vectors of the observed
stars, **brightest first**, and a :class:`lodestar.firmware.database.Database` with the pyramid
sections; it returns a :class:`lodestar.firmware.starid.search.Solution` (``OK``,
``TOO_FEW_STARS`` below 4 stars, ``AMBIGUOUS``, ``NO_MATCH``, ``BUDGET_EXHAUSTED``).  Angles in
radians (``docs/conventions.md``).  Triples are enumerated in Mortari's order, confirmed by a
fourth star and verified by the shared search; the algorithm, tolerances and memory use are in
``docs/starid.md`` (Pyramid).  Pure Python for CPython and MicroPython (``math``, ``array``).
"""

import math
from array import array

from lodestar.contract.stardb import METHOD_PYRAMID

from .. import geometry as G
from ..database import PAIR_BLOCK
from ..emit import native
from .search import Search, handed, identify_with

DATABASE_BIT = METHOD_PYRAMID
"""The database's ``methods`` bit this method reads."""

SQRT2 = 1.4142135623730951

NONE = 0xFFFF
"""End of a chain in the ``array('H')`` pair index of :meth:`_Search._index`."""

CHUNK = 128
"""Most candidate pairs of one side indexed at once (:meth:`_Search._index`; longer ranges are
joined chunk by chunk); entry numbers stay below :data:`NONE`.  128, not 256: the index's
blocks are allocated per search (half a KiB each), and at 256 the lost-in-space frames of
the regression set ran out of the 64 KiB flight heap."""
_HEAD = 256
"""Chain heads of a side's index: a power of two, at least the ``2 * CHUNK`` entries."""


def _side():
    """The buffers of one side's index, ``(head, st, nxt, used)`` (``array('H')``, 4 *
    :data:`CHUNK` + 2 * :data:`_HEAD` bytes, and ``used``: the entries its last index
    filed), every chain empty."""
    head = array("H", range(_HEAD))                 # sized by the ranges: no temporary
    for h in range(_HEAD):
        head[h] = NONE
    return head, array("H", range(2 * CHUNK)), array("H", range(2 * CHUNK)), array("H", [0])


DEFAULT_MAX_STARS = 16
"""Observed stars a search uses for patterns by default (:func:`identify`)."""
MAX_WORK = 20000
"""Pyramid's work budget (:data:`.search.DEFAULT_MAX_WORK`'s units): a search that spends it,
its mirror check (a third more) and its conclusion end within 2 s of F401 time (measured on
the Cortex-M4F build, ``docs/firmware.md``, The work budget on the MCU)."""
PATTERN_WORK = 100
"""Work units of a triple beyond its pair candidates (its three k-vector queries, the
triangles' sort, the handedness tests: about 1,500 guest ticks on the Cortex-M4F build)."""


@native
def _observed_angles(b, n):
    """Angles between the first ``n`` observed vectors, as a flat ``array`` ``[i * n + j]``."""
    ang = G.zeros(n * n)
    for i in range(n):
        for j in range(i + 1, n):
            a = G.angle(b[i], b[j])
            ang[i * n + j] = a
            ang[j * n + i] = a
    return ang


class _Search(Search):
    BIT = DATABASE_BIT
    MIN_STARS = 4           # a triple and the fourth star that confirms it
    PATTERN_WORK = PATTERN_WORK

    def __init__(self, b, db, tol, max_prob, distinct, streaks, max_stars):
        Search.__init__(self, b, db, tol, max_prob, distinct, streaks, max_stars)
        # the search's buffers (the observed angles, the pair ranges of the pairs i < j,
        # the two sides' pair index: 5 KiB at 16 stars, no block above 1 KiB) live while it
        # runs: the pipeline collects before a lost-in-space search, and a tracking frame's
        # heap does not hold them
        self.ang = _observed_angles(b, self.n)
        self.ptol0 = SQRT2 * tol + db.key_step
        size = self.n * (self.n - 1)                # two per observed pair i < j
        self.ranges = array("i", range(size))
        for c in range(size):
            self.ranges[c] = -1                     # not queried yet
        self.sides = (_side(), _side())

    def ptol(self, i, j):
        """Tolerance (rad) of the observed angle between stars ``i`` and ``j``."""
        return self.ptol0 + self.half[i] + self.half[j]

    @native
    def candidates(self, i, j):
        """``(start, stop)``: the database pairs within ``ptol`` of the observed angle
        ``i``-``j`` (k-vector query, remembered per observed pair for the whole search)."""
        n = self.n
        if i > j:
            i, j = j, i
        c = i * (2 * n - i - 1) + 2 * (j - i - 1)       # the pair's place, i < j, times 2
        r = self.ranges
        if r[c] < 0:
            t = self.ang[i * n + j]
            tol = self.ptol(i, j)
            r[c], r[c + 1] = self.db.pairs_in_range(t - tol, t + tol)
        return r[c], r[c + 1]

    @native
    def bound(self, i, j, k):
        a = self.ang
        n = self.n
        h = self.half
        tol = self.tol + max(h[i], h[j], h[k])
        return tol * (math.sin(a[i * n + j]) + math.sin(a[j * n + k]) + math.sin(a[k * n + i]))

    @native
    def _index(self, start, stop, side):
        """Index the pairs ``start <= p < stop`` (at most :data:`CHUNK`) by star in the
        buffers ``side`` (:func:`_side`): returns them, ``(head, st, nxt, used)``.

        ``st`` lists the pairs' stars ``a, b, a, b, ...``: entry ``e`` is filed under star
        ``st[e]`` with partner ``st[e ^ 1]``.  ``head[star & (_HEAD - 1)]`` starts a chain
        through ``nxt`` (ended by :data:`NONE`) holding the entries of every star with
        those low bits; a reader skips the entries of other stars.  Only the chains the
        last index of these buffers started are emptied first (``used``: its entries), not
        all :data:`_HEAD`."""
        db = self.db
        head, st, nxt, used = side
        mask = _HEAD - 1
        for e in range(used[0]):
            head[st[e] & mask] = NONE
        used[0] = 0
        self.spend(stop - start)
        e = 0
        for p in range(start, stop, PAIR_BLOCK):
            for star in db.pair_stars(p, PAIR_BLOCK if p + PAIR_BLOCK < stop else stop - p):
                st[e] = star
                e += 1
        for e in range(2 * (stop - start)):
            h = st[e] & mask
            nxt[e] = head[h]
            head[h] = e
        used[0] = 2 * (stop - start)
        return side

    @native
    def triangles(self, i, j, k):
        """Consistent catalogue triangles ``(I, J, K)`` of the observed triple, in the order
        of the ``ij`` candidates (``(a, b)`` before ``(b, a)``), then of the ``ik`` ones.

        Memory: the ``ij`` and ``jk`` candidates indexed by star (:meth:`_index`, at most
        :data:`CHUNK` pairs of a side at once: longer ranges are joined chunk by chunk) and
        the triangles found; the ``ik`` candidates are streamed from the database."""
        s_ij = self.candidates(i, j)
        if s_ij[0] == s_ij[1]:
            return []
        s_ik = self.candidates(i, k)
        if s_ik[0] == s_ik[1]:
            return []
        s_jk = self.candidates(j, k)
        if s_jk[0] == s_jk[1]:
            return []
        found = []
        for lo in range(s_ij[0], s_ij[1], CHUNK):
            ij = self._index(lo, lo + CHUNK if lo + CHUNK < s_ij[1] else s_ij[1],
                             self.sides[0])
            for lo2 in range(s_jk[0], s_jk[1], CHUNK):
                jk = self._index(lo2, lo2 + CHUNK if lo2 + CHUNK < s_jk[1] else s_jk[1],
                                 self.sides[1])
                self._join(ij, jk, s_ik, (lo - s_ij[0]) << 1, found)
        found.sort()
        return [t[1:] for t in found]

    @native
    def _join(self, ij, jk, s_ik, e0, found):
        """Append ``(order, I, J, K)`` to ``found`` for every ``ik`` pair ``{I, K}`` closing a
        triangle with an indexed ``ij`` entry ``(I, J)`` and ``jk`` entry ``(J, K)``;
        ``order`` sorts them as :meth:`triangles` returns them (``e0``: the ``ij`` chunk's
        first entry number)."""
        db = self.db
        ij_head, ij_st, ij_nxt, _used = ij
        jk_head, jk_st, jk_nxt, _used = jk
        ij_mask = jk_mask = _HEAD - 1
        start, stop = s_ik
        n_ik = stop - start
        for p0 in range(start, stop, PAIR_BLOCK):
            rec = db.pair_stars(p0, PAIR_BLOCK if p0 + PAIR_BLOCK < stop else stop - p0)
            self.spend(len(rec))
            for t in range(0, len(rec), 2):
                a = rec[t]
                c = rec[t + 1]
                ea = ij_head[a & ij_mask]
                ec = ij_head[c & ij_mask]
                if ea == NONE and ec == NONE:
                    continue            # neither star starts an ij chain: most pairs
                for side in (0, 1):     # (a, c), then (c, a): a constant, no tuple per pair
                    if side:
                        ii, kk, e = c, a, ec
                    else:
                        ii, kk, e = a, c, ea
                    while e != NONE:
                        if ij_st[e] == ii:
                            jj = ij_st[e ^ 1]
                            if jj != kk:
                                f = jk_head[jj & jk_mask]
                                while f != NONE:
                                    if jk_st[f] == jj and jk_st[f ^ 1] == kk:
                                        found.append(((e0 + e) * n_ik + p0 - start + (t >> 1),
                                                      ii, jj, kk))
                                        break
                                    f = jk_nxt[f]
                        e = ij_nxt[e]

    @native
    def fourth_star(self, i, j, k, cat):
        """``(r, R)``: the first observed star confirming the catalogue triangle, or None."""
        db = self.db
        b = self.b
        n = self.n
        ang = self.ang
        ci, cj, ck = cat
        vi, vj, vk = db.star_vector(ci), db.star_vector(cj), db.star_vector(ck)
        for r in range(n):
            if r == i or r == j or r == k:
                continue
            s = self.candidates(r, i)
            t_rj = ang[r * n + j]
            t_rk = ang[r * n + k]
            tol_rj = self.ptol(r, j)
            tol_rk = self.ptol(r, k)
            bound = self.bound(i, j, r)
            t_obs = G.triple(b[i], b[j], b[r])
            for p0 in range(s[0], s[1], PAIR_BLOCK):
                rec = db.pair_stars(p0, PAIR_BLOCK if p0 + PAIR_BLOCK < s[1] else s[1] - p0)
                self.spend(len(rec) >> 1)
                for t in range(0, len(rec), 2):
                    a = rec[t]
                    c = rec[t + 1]
                    if a == ci:
                        cr = c
                    elif c == ci:
                        cr = a
                    else:
                        continue
                    if cr == cj or cr == ck:
                        continue
                    vr = db.star_vector(cr)
                    if abs(G.angle(vr, vj) - t_rj) > tol_rj or \
                            abs(G.angle(vr, vk) - t_rk) > tol_rk:
                        continue
                    if not handed(t_obs, G.triple(vi, vj, vr), bound):
                        continue
                    return r, cr
        return None

    def patterns(self):
        return _triples(self.n)

    def try_pattern(self, triple):
        """Accepted ``[(q, Verification)]`` of the observed ``triple`` (empty if none)."""
        i, j, k = triple
        accepted = []
        bound = self.bound(i, j, k)
        t_obs = G.triple(self.b[i], self.b[j], self.b[k])
        db = self.db
        for cat in self.triangles(i, j, k):
            t_cat = G.triple(db.star_vector(cat[0]), db.star_vector(cat[1]),
                             db.star_vector(cat[2]))
            if not handed(t_obs, t_cat, bound):
                continue
            fourth = self.fourth_star(i, j, k, cat)
            if fourth is None:
                continue
            self.test((i, j, k, fourth[0]), (cat[0], cat[1], cat[2], fourth[1]), accepted)
        return accepted


def identify(vectors, database, tolerance_rad, budget=2000, max_stars=DEFAULT_MAX_STARS,
             max_mismatch_prob=1e-9, distinct_rad=None, streaks=None,
             max_work=MAX_WORK):
    """Pyramid identification (:func:`.search.identify_with`; ``budget`` counts triples);
    returns a :class:`.search.Solution`."""
    return identify_with(_Search, vectors, database, tolerance_rad, budget, max_stars,
                         max_mismatch_prob, distinct_rad, streaks, max_work)


def _triples(n):
    """Mortari's triple order over ``n`` stars (``docs/starid.md``, Pyramid step 2)."""
    for dj in range(1, n - 1):
        for dk in range(1, n - dj):
            for i in range(0, n - dj - dk):
                yield i, i + dj, i + dj + dk
