"""Geometric-hashing star identification (Astrometry.net's quad hash, as in Schumann 2019).

Lang et al. (2010), Astrometry.net; Schumann (2019), "Using Star Identification Algorithms on
ESTCube-2 Star Tracker".  :func:`identify` takes camera-frame unit vectors of the observed
stars, **brightest first**, and a :class:`lodestar.firmware.database.Database` with the
``hash`` section (``"hashing"`` in the ``methods`` of ``lodestar.ground.database``); statuses
as the other methods.  :func:`group_hash` is the hash of 3 or 4 stars (parity kept: a mirror
image hashes differently), :func:`bucket_code` its database key.  Hash, bucket codes,
tolerances, algorithm and the lean per-group path: ``docs/starid.md`` (Hashing).  Pure Python
for CPython and MicroPython (``math`` only).
"""

import math

from lodestar.contract.stardb import HASH_FLAG_DISTANCE, HASH_MAX_CODE, METHOD_HASHING

from .. import geometry as G
from .. import status as S
from .search import DEFAULT_MAX_WORK, RECORD_WORK, Search, handed, identify_with, triple_bound

DATABASE_BIT = METHOD_HASHING
"""The database's ``methods`` bit this method reads."""
MAX_WORK = DEFAULT_MAX_WORK
"""The method's work budget: the shared default (not calibrated in MCU time)."""

BOUND_MARGIN = 1.1
"""Factor on the first-order hash tolerance (covers the projection's curvature terms)."""

SQRT2 = 1.4142135623730951

MAX_TOL_BUCKETS = 2.0
"""A labelling whose coordinate tolerance exceeds this many buckets is skipped (it would
visit up to ``(2 * MAX_TOL_BUCKETS + 1) ** (2 * (g - 2))`` buckets)."""


def _chord2(a, b):
    dx, dy, dz = a[0] - b[0], a[1] - b[1], a[2] - b[2]
    return dx * dx + dy * dy + dz * dz


def tangent_frame(a, b):
    """``(m, e1, e2)``: the tangent point ``m = (a + b)/|a + b|`` and the right-handed basis
    ``e1`` (along ``b - a``, orthogonal to ``m``), ``e2 = m x e1``."""
    m = G.unit((a[0] + b[0], a[1] + b[1], a[2] + b[2]))
    d = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
    k = G.dot(d, m)
    e1 = G.unit((d[0] - k * m[0], d[1] - k * m[1], d[2] - k * m[2]))
    return m, e1, G.cross(m, e1)


def project(frame, p):
    """Gnomonic coordinates ``(u, v)`` of the unit vector ``p`` in ``frame``."""
    m, e1, e2 = frame
    w = G.dot(p, m)
    return G.dot(p, e1) / w, G.dot(p, e2) / w


def frame_coords(pa, pb, pp):
    """Astrometry.net's ``(x, y)`` of plane point ``pp`` in the frame of ``pa = (0, 0)``,
    ``pb = (1, 1)``: ``z = (pp - pa)(1 + i) / (pb - pa)``."""
    dx, dy = pb[0] - pa[0], pb[1] - pa[1]
    ux, uy = pp[0] - pa[0], pp[1] - pa[1]
    nr, ni = ux - uy, ux + uy              # (u)(1 + i)
    den = dx * dx + dy * dy
    return (nr * dx + ni * dy) / den, (ni * dx - nr * dy) / den


def coords(a, b, others):
    """Hash coordinates ``[x_C, y_C, (x_D, y_D)]`` of the unit vectors ``others`` with
    ``A = a``, ``B = b`` (no canonicalisation)."""
    fr = tangent_frame(a, b)
    pa, pb = project(fr, a), project(fr, b)
    out = []
    for p in others:
        x, y = frame_coords(pa, pb, project(fr, p))
        out.append(x)
        out.append(y)
    return out


_PAIRS = (None, None, None, ((0, 1), (0, 2), (1, 2)),
          ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)))
"""``_PAIRS[g]``: the index pairs ``(i, j)``, ``i < j``, of a group of ``g`` stars."""


def _diameter_pairs(c2, g, slack):
    """Index pairs ``(i, j)``, ``i < j``, of a group of ``g`` stars whose chord is within
    ``slack`` of the largest (largest first, ties by index); ``c2``: the squared chords of
    the pairs ``_PAIRS[g]``, in that order."""
    best = max(c2)
    if slack > 0.0:
        lim = math.sqrt(best) - slack
        lim2 = lim * lim if lim > 0.0 else 0.0
    else:
        lim2 = best
    pairs = _PAIRS[g]
    out = [(-c2[k], pairs[k][0], pairs[k][1]) for k in range(len(c2)) if c2[k] >= lim2]
    if len(out) > 1:
        out.sort()
    return [(i, j) for c, i, j in out]


def _chords2(vs):
    """Squared chords of the pairs ``_PAIRS[len(vs)]`` of ``vs``."""
    return [_chord2(vs[i], vs[j]) for i, j in _PAIRS[len(vs)]]


def _labellings(vs, i, j, scale=0.0, den=1.0, max_tol=None):
    """Admissible labellings ``(order, hash, t)`` of the group ``vs`` (3 or 4 unit vectors)
    with the diameter ``i``-``j``: ``order`` the indices of ``A, B, C(, D)``, ``hash`` its
    coordinates (:func:`coords`, bit for bit), ``t = scale * worst / den`` the tolerance of
    the coordinates (:func:`coord_tolerance` with ``(scale, den) = _tolerance_terms(d,
    eps)``; 0 by default: the exact symmetry-breaking rules); labellings with ``t`` above
    ``max_tol`` are left out.  Order: ``A-B = i-j`` then ``j-i``; ``C, D`` in index order
    then swapped.

    The tangent frame and the projections are computed once: ``tangent_frame(b, a)`` is
    exactly ``(m, -e1, -e2)`` of ``tangent_frame(a, b)`` (every operation is sign-symmetric),
    so swapping ``A`` and ``B`` negates every projected coordinate."""
    g = len(vs)
    rest = [k for k in range(g) if k != i and k != j]
    # tangent_frame(vs[i], vs[j]) and project(), inline: uv = [u_i, v_i, u_j, v_j, u, v, ...]
    ax, ay, az = vs[i]
    bx, by, bz = vs[j]
    sx, sy, sz = ax + bx, ay + by, az + bz
    nn = math.sqrt(sx * sx + sy * sy + sz * sz)
    mx, my, mz = sx / nn, sy / nn, sz / nn
    dx, dy, dz = bx - ax, by - ay, bz - az
    k = dx * mx + dy * my + dz * mz
    ex, ey, ez = dx - k * mx, dy - k * my, dz - k * mz
    nn = math.sqrt(ex * ex + ey * ey + ez * ez)
    ex, ey, ez = ex / nn, ey / nn, ez / nn
    fx, fy, fz = my * ez - mz * ey, mz * ex - mx * ez, mx * ey - my * ex
    uv = []
    for r in [i, j] + rest:
        px, py, pz = vs[r]
        w = px * mx + py * my + pz * mz
        uv.append((px * ex + py * ey + pz * ez) / w)
        uv.append((px * fx + py * fy + pz * fz) / w)
    # x_C + x_D <= 1 + 2 t (x_C <= 1/2 + t for 3 stars) with t <= max_tol, else none
    x_max = None if max_tol is None else (0.5 + max_tol if g == 3 else 1.0 + 2.0 * max_tol)
    out = []
    for a, b, s in ((i, j, 1.0), (j, i, -1.0)):
        # frame_coords(pa, pb, p) of the rest, inline
        if s > 0.0:
            pau, pav, pbu, pbv = uv[0], uv[1], uv[2], uv[3]
        else:
            pau, pav, pbu, pbv = -uv[2], -uv[3], -uv[0], -uv[1]
        qx, qy = pbu - pau, pbv - pav
        q2 = qx * qx + qy * qy
        h = []
        for r in range(4, len(uv), 2):
            ux, uy = s * uv[r] - pau, s * uv[r + 1] - pav
            nr, ni = ux - uy, ux + uy
            h.append((nr * qx + ni * qy) / q2)
            h.append((ni * qx - nr * qy) / q2)
        if x_max is not None and (h[0] if g == 3 else h[0] + h[2]) > x_max:
            continue
        t = scale * _worst_factor(h) / den
        if max_tol is not None and t > max_tol:
            continue
        if g == 3:
            if h[0] <= 0.5 + t:
                out.append(((a, b, rest[0]), h, t))
            continue
        if h[0] <= h[2] + 2.0 * t and h[0] + h[2] <= 1.0 + 2.0 * t:
            out.append(((a, b, rest[0], rest[1]), h, t))
        h = [h[2], h[3], h[0], h[1]]
        if h[0] <= h[2] + 2.0 * t and h[0] + h[2] <= 1.0 + 2.0 * t:
            out.append(((a, b, rest[1], rest[0]), h, t))
    return out


def group_hash(vs):
    """Canonical ``(order, hash, d)`` of a group of 3 or 4 unit vectors: ``order`` the
    indices of ``A, B, C(, D)``, ``hash`` the normalized coordinates, ``d`` the angle
    ``A``-``B`` (rad).  The first labelling that keeps the symmetry-breaking rules exactly,
    the diameters in :func:`_diameter_pairs` order (ties by index)."""
    for i, j in _diameter_pairs(_chords2(vs), len(vs), 0.0):
        found = _labellings(vs, i, j)
        if found:
            order, h, _ = found[0]
            return order, h, G.angle(vs[order[0]], vs[order[1]])
    raise ValueError("no canonical labelling")


def _worst_factor(h):
    """Largest ``1 + |1 - w| + |w|``, ``w = (x + i y) / (1 + i)``, over the points ``(x, y)``
    of the hash coordinates ``h``."""
    worst = 0.0
    for k in range(0, len(h), 2):
        wx, wy = 0.5 * (h[k] + h[k + 1]), 0.5 * (h[k + 1] - h[k])
        f = 1.0 + math.sqrt((1.0 - wx) * (1.0 - wx) + wy * wy) + math.sqrt(wx * wx + wy * wy)
        if f > worst:
            worst = f
    return worst


def _tolerance_terms(d, eps):
    """``(scale, den)`` with ``coord_tolerance(h, d, eps) = scale * worst / den``."""
    t = math.tan(0.8660254037844386 * d)
    return BOUND_MARGIN * SQRT2 * eps * (1.0 + t * t), 2.0 * math.tan(0.5 * d)


def coord_tolerance(h, d, eps):
    """Largest change of any hash coordinate ``h`` when each star moves by at most ``eps``
    (rad), for a group of diameter ``d`` (the A-B angle, rad).

    ``z = (P' - A')(1 + i)/(B' - A')`` changes by ``sqrt(2)/|B' - A'| (|dP| + |1 - w| |dA| +
    |w| |dB|)``, ``w = z / (1 + i)``; in the tangent plane ``|B' - A'| = 2 tan(d / 2)`` and a
    direction error ``eps`` is at most ``eps (1 + tan^2 r)`` with ``r <= (sqrt(3) / 2) d``
    (every star lies in the lens of radius ``d`` around ``A`` and ``B``).
    """
    scale, den = _tolerance_terms(d, eps)
    return scale * _worst_factor(h) / den


def bucket(value, lo, width, count):
    """Bucket index of ``value`` on the grid ``lo + width * k``, clamped to ``[0, count)``."""
    k = int(math.floor((value - lo) / width))
    if k < 0:
        return 0
    if k >= count:
        return count - 1
    return k


def bucket_code(h, d, db):
    """Bucket code of hash coordinates ``h`` and A-B angle ``d`` (rad) in ``db``'s grid."""
    lo, w, nb = db.hash_coord_lo, db.hash_coord_bucket, db.hash_coord_buckets
    code = 0
    for x in h:
        code = code * nb + bucket(x, lo, w, nb)
    if db.hash_flags & HASH_FLAG_DISTANCE:
        code = code * db.hash_dist_buckets + bucket(d, 0.0, db.hash_dist_bucket,
                                                    db.hash_dist_buckets)
    return code


def box_codes(h, tol, d, d_tol, db):
    """All bucket codes that the box ``h +- tol`` (and ``d +- d_tol``) overlaps, ascending
    (:func:`bucket` inline: this is the search's inner loop)."""
    lo, w, nb = db.hash_coord_lo, db.hash_coord_bucket, db.hash_coord_buckets
    digits = [(x - tol, x + tol, lo, w, nb) for x in h]
    if db.hash_flags & HASH_FLAG_DISTANCE:
        digits.append((d - d_tol, d + d_tol, 0.0, db.hash_dist_bucket, db.hash_dist_buckets))
    code = 0
    codes = None                    # None while every digit so far has a single bucket
    for v0, v1, lo, w, nb in digits:
        k0 = int(math.floor((v0 - lo) / w))
        k0 = 0 if k0 < 0 else (nb - 1 if k0 >= nb else k0)
        k1 = int(math.floor((v1 - lo) / w))
        k1 = 0 if k1 < 0 else (nb - 1 if k1 >= nb else k1)
        if codes is not None:
            codes = [c * nb + k for c in codes for k in range(k0, k1 + 1)]
        elif k0 == k1:
            code = code * nb + k0
        else:
            codes = [code * nb + k for k in range(k0, k1 + 1)]
    return [code] if codes is None else codes


def box_records(db, codes):
    """Indices of the stored groups in the buckets ``codes`` (ascending, as
    :func:`box_codes` gives them), in table order: the ranges ``db.hash_bucket(code)`` one
    after the other.  The groups are sorted by code, so after one k-vector query the code
    of the next group bounds the following buckets: a code below it is an empty bucket,
    known without a query or a read."""
    out = []
    hn = db.hash_n
    r = 0
    nxt = -1                        # the code of group r (None: not read yet)
    for code in codes:
        if nxt is None:
            nxt = db.hash_code(r) if r < hn else HASH_MAX_CODE
        if nxt < code:
            r, stop = db.hash_bucket(code)
            nxt = code if stop > r else None
        while nxt == code:
            out.append(r)
            r += 1
            nxt = db.hash_code(r) if r < hn else HASH_MAX_CODE
    return out


class _Search(Search):
    """The hash search over the first ``n`` observed stars: the squared chord and the angle
    of each of their pairs are computed once (``n * n`` tables, index ``i * n + j``,
    ``i < j``)."""

    BIT = DATABASE_BIT

    def __init__(self, b, db, tol, max_prob, distinct, streaks, max_stars):
        Search.__init__(self, b, db, tol, max_prob, distinct, streaks, max_stars)
        n = self.n
        self.use_d = bool(db.hash_flags & HASH_FLAG_DISTANCE)
        self.d_tol = 2.0 * tol * BOUND_MARGIN + 1e-7
        self.min_d = db.hash_min_diameter - self.d_tol
        self.max_d = db.hash_max_diameter + self.d_tol
        self.slack = 4.0 * tol * BOUND_MARGIN
        self.max_tol = MAX_TOL_BUCKETS * db.hash_coord_bucket
        self.chord2 = [0.0] * (n * n)
        self.angle = [0.0] * (n * n)
        for j in range(n):
            for i in range(j):
                self.chord2[i * n + j] = _chord2(b[i], b[j])
                self.angle[i * n + j] = G.angle(b[i], b[j])

    @staticmethod
    def refuses(b, db, max_stars):
        """``TOO_FEW_STARS`` below the database's group size, ``BAD_INPUT`` for a
        ``max_stars`` below it, else None."""
        g = db.hash_group_size
        if len(b) < g:
            return S.TOO_FEW_STARS
        return S.BAD_INPUT if max_stars < g else None

    def patterns(self):
        return _groups(self.db.hash_group_size, self.n)

    def try_pattern(self, idx):
        """Accepted ``[(q, Verification)]`` of the observed group ``idx`` (ascending star
        indices)."""
        n = self.n
        chord2 = self.chord2
        g = len(idx)
        c2 = [chord2[idx[i] * n + idx[j]] for i, j in _PAIRS[g]]
        i, j = _PAIRS[g][c2.index(max(c2))]      # the diameter (ties: the first pair)
        d = self.angle[idx[i] * n + idx[j]]
        if d < self.min_d or d > self.max_d:
            return []
        d_low = d - self.d_tol      # the smallest diameter consistent with the observation
        if d_low <= 0.0:
            return []
        scale, den = _tolerance_terms(d_low, self.tol)
        vs = [self.b[k] for k in idx]
        accepted = []
        seen = {}
        for i, j in _diameter_pairs(c2, g, self.slack):
            d_obs = self.angle[idx[i] * n + idx[j]]
            # a labelling whose tolerance exceeds max_tol buckets would be a huge box
            for order, h, t in _labellings(vs, i, j, scale, den, self.max_tol):
                self.look_up(idx, order, h, t, d_obs, accepted, seen)
        return accepted

    def look_up(self, idx, order, h, t, d_obs, accepted, seen):
        """Test every stored group in the buckets of the box ``h +- t`` (``d_obs +-
        d_tol``) whose recomputed hash, angle and handedness agree with the labelling
        ``order`` of the observed group ``idx``."""
        db = self.db
        t_obs = t_bound = None
        for r in box_records(db, box_codes(h, t, d_obs, self.d_tol, db)):
            self.spend(RECORD_WORK)
            stars = db.hash_record(r)[1:]
            cat = [db.star_vector(s) for s in stars]
            if self.use_d and abs(G.angle(cat[0], cat[1]) - d_obs) > self.d_tol:
                continue
            hc = coords(cat[0], cat[1], cat[2:])
            ok = True
            for k in range(len(h)):
                if abs(hc[k] - h[k]) > t:
                    ok = False
                    break
            if not ok:
                continue
            if t_obs is None:
                vs = self.b
                a, b, c = vs[idx[order[0]]], vs[idx[order[1]]], vs[idx[order[2]]]
                t_bound = triple_bound(a, b, c, self.tol)
                t_obs = G.triple(a, b, c)
            if not handed(t_obs, G.triple(cat[0], cat[1], cat[2]), t_bound):
                continue
            obs_idx = tuple(idx[o] for o in order)
            key = (obs_idx, stars)
            if key in seen:
                continue
            seen[key] = 1
            self.test(obs_idx, stars, accepted)


def identify(vectors, database, tolerance_rad, budget=2000, max_stars=16,
             max_mismatch_prob=1e-9, distinct_rad=None, streaks=None,
             max_work=MAX_WORK):
    """Geometric-hashing identification (:func:`.search.identify_with`; ``budget`` counts
    groups); returns a :class:`.search.Solution`.  A streak's star is matched over its
    stretched region by the verification, but the hash boxes stay those of
    ``tolerance_rad`` (a group holding a streak's star may be missed)."""
    return identify_with(_Search, vectors, database, tolerance_rad, budget, max_stars,
                         max_mismatch_prob, distinct_rad, streaks, max_work)


def _groups(g, n):
    """Groups of ``g`` (3 or 4) of ``n`` stars, ascending indices, every one whose faintest
    star is ``k`` before any with a fainter one (``docs/starid.md``, Hashing step 2)."""
    for k in range(g - 1, n):
        for j in range(g - 2, k):
            for i in range(g - 3, j):
                if g == 3:
                    yield i, j, k
                else:
                    for h in range(i):
                        yield h, i, j, k
