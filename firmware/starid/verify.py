"""Verification of an identification hypothesis and its chance-agreement probability.

:func:`verify` predicts the catalogue stars in the FOV at a hypothesised attitude, matches
them one to one with the observed stars (within ``tolerance_rad``, or over the region a
partly seen track stretches, :func:`in_region`) and gives the probability that that many
matches happen by chance (binomial, Poisson-binomial with tracks).  A hypothesis is accepted
when the probability is below the caller's ``max_mismatch_prob``.  The model is in
``docs/starid.md`` (Verification).

Conventions (``docs/conventions.md``): ``q = (x, y, z, w)``, scalar last, ``v_cam = R(q)
v_inertial``; angles in radians.  Pure Python for CPython and MicroPython (``math`` only).
"""

import math
from array import array

from .. import geometry as G
from ..emit import native
from ..kvector import lower_bound
from ..quaternion import matrix


@native
def binomial_tail(n, k, p):
    """``P(X >= k)`` for ``X ~ Binomial(n, p)`` (log-domain first term, no ``math.comb``)."""
    if k <= 0:
        return 1.0
    if k > n or p <= 0.0:
        return 0.0
    if p >= 1.0:
        return 1.0
    # log of the first term C(n, k) p^k (1-p)^(n-k)
    log_t = k * math.log(p) + (n - k) * math.log(1.0 - p)
    for i in range(1, k + 1):
        log_t += math.log((n - k + i) / i)
    ratio = p / (1.0 - p)
    s = 1.0
    t = 1.0
    for i in range(k, n):
        t *= (n - i) / (i + 1) * ratio
        s += t
        if t < 1e-12 * s:
            break
    if log_t < -700.0:
        return 0.0
    out = math.exp(log_t) * s
    return out if out < 1.0 else 1.0


@native
def poisson_binomial_tail(ps, k):
    """``P(X >= k)`` for ``X`` the number of successes of independent trials of success
    probabilities ``ps`` (a recursion over the count distribution, every term positive: no
    cancellation)."""
    n = len(ps)
    if k <= 0:
        return 1.0
    if k > n:
        return 0.0
    dist = [1.0] + [0.0] * n          # dist[j] = P(j successes so far)
    for t in range(n):
        p = ps[t]
        q = 1.0 - p
        for j in range(t + 1, 0, -1):
            dist[j] = dist[j] * q + dist[j - 1] * p
        dist[0] *= q
    out = 0.0
    for j in range(k, n + 1):
        out += dist[j]
    return out if out < 1.0 else 1.0


def fov_solid_angle(fov_h, fov_v):
    """Solid angle (sr) of a rectangular pinhole FOV of full angles ``fov_h``, ``fov_v``."""
    return 4.0 * math.asin(math.sin(fov_h / 2) * math.sin(fov_v / 2))


# --------------------------------------------------------------------------------------
# Verification
# --------------------------------------------------------------------------------------

class Verification:
    """Outcome of :func:`verify`: ``pairs`` (list of ``(observed_index, star_index)``),
    ``n_fov`` (catalogue stars predicted in the FOV), ``p_single`` (chance-match probability
    per observed star) and ``probability`` (binomial tail, ``docs/starid.md``)."""

    def __init__(self, pairs, n_fov, p_single, probability):
        self.pairs = pairs
        self.n_fov = n_fov
        self.p_single = p_single
        self.probability = probability

    @property
    def n_matched(self):
        return len(self.pairs)


CONE_MARGIN_RAD = 0.01
"""How much wider than the field (rad) a :class:`SkyCone` is queried: the refinement of a
hypothesis turns the attitude by far less, so its verifications read the cone once."""


class SkyCone:
    """The catalogue stars of one cone query, kept for the next verifications at nearby
    attitudes (:func:`predicted_stars`): ``centre`` (unit vector), ``radius`` (rad),
    ``ids`` (star indices, table order) and ``vecs`` (their vectors ``x, y, z``); ``ids``
    None when empty."""

    __slots__ = ("centre", "radius", "ids", "vecs")

    def __init__(self):
        self.clear()

    def clear(self):
        """Drop the held stars (their heap is free)."""
        self.centre = self.ids = self.vecs = None
        self.radius = 0.0

    def stars(self, database, d, radius):
        """``(ids, vecs)`` of the stars within ``radius`` of ``d``, or more: the held ones
        when their cone covers it (:func:`~lodestar.firmware.geometry.within_cone`, as
        :class:`~lodestar.firmware.tracking.Cone`), else a query
        :data:`CONE_MARGIN_RAD` wider, held.  Either way in table order, so the stars a
        caller keeps are the same stars in the same order as from a query of its own."""
        if self.ids is not None and radius <= self.radius and \
                G.within_cone(self.centre, self.radius, d, radius):
            return self.ids, self.vecs
        self.ids = self.vecs = None                # the old cone's heap is free first
        vecs = []
        radius += CONE_MARGIN_RAD
        self.ids = database.stars_in_cone(d, radius, vecs=vecs)
        self.vecs, self.centre, self.radius = vecs, d, radius
        return self.ids, vecs


@native
def predicted_stars(database, q, margin=0.0, sky=None):
    """Catalogue stars inside the FOV at attitude ``q``, as *predicted stars*: ``(ids,
    vecs)``, ``array('H')`` star indices and ``array(FLOAT_CODE)`` camera vectors ``x, y, z``
    per star (compact: no object per star).  ``margin`` (rad) widens the FOV rectangle on
    every side.  ``sky``: a :class:`SkyCone` to read the stars around the boresight from
    (None: a query of their own; the same stars either way)."""
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = matrix(q)
    half_diag = 0.5 * database.fov_diag + margin
    tan_h = math.tan(0.5 * database.fov_h + margin)
    tan_v = math.tan(0.5 * database.fov_v + margin)
    if sky is None:
        cat = []                        # the cone's vectors, read with its stars
        cone = database.stars_in_cone((m6, m7, m8), half_diag, vecs=cat)   # the boresight's
    else:
        cone, cat = sky.stars(database, (m6, m7, m8), half_diag)
    inside = bytearray(len(cone))       # count and mark, then fill arrays of the final size:
    n = 0                               # two passes over the cone's vectors
    for fill in (False, True):
        if fill:
            ids = array("H", range(n))              # sized by the range, then overwritten
            vecs = G.zeros(3 * n)
            k = 0
        for i in range(len(cone)):
            if fill and not inside[i]:
                continue
            t = 3 * i
            r0, r1, r2 = cat[t], cat[t + 1], cat[t + 2]
            z = m6 * r0 + m7 * r1 + m8 * r2
            if fill:
                ids[k] = cone[i]
                vecs[3 * k] = m0 * r0 + m1 * r1 + m2 * r2
                vecs[3 * k + 1] = m3 * r0 + m4 * r1 + m5 * r2
                vecs[3 * k + 2] = z
                k += 1
            elif z > 0.0:               # abs(x) <= tan_h z, ...: no call to abs, and no y
                lim = tan_h * z         # for a star off the sides
                x = m0 * r0 + m1 * r1 + m2 * r2
                if -lim <= x <= lim:
                    lim = tan_v * z
                    y = m3 * r0 + m4 * r1 + m5 * r2
                    if -lim <= y <= lim:
                        inside[i] = 1
                        n += 1
    return ids, vecs


def chord_of_angle(angle):
    """Chord length of an angle (rad): ``|a - b|`` of unit vectors ``angle`` apart
    (:func:`lodestar.firmware.geometry.chord` is that of two vectors)."""
    return 2.0 * math.sin(0.5 * angle)


@native
def in_region(dx, dy, dz, streak, lim):
    """True when the offset ``(dx, dy, dz)`` of an observed unit vector from a predicted one
    lies in the observed star's match region: within the chord ``lim`` of the predicted
    star, widened along a ``streak`` ``(ux, uy, uz, half)`` to the stadium of points within
    ``lim`` of the segment ``+-chord_of_angle(half)`` along ``u`` (``docs/starid.md``;
    None: a disc)."""
    d2 = dx * dx + dy * dy + dz * dz
    if streak is None:
        return d2 <= lim * lim
    a = dx * streak[0] + dy * streak[1] + dz * streak[2]          # along the track
    if a < 0.0:
        a = -a                          # abs() would cost a call: it runs for every pair
    beyond = a - chord_of_angle(streak[3])                         # past the segment's end
    if beyond < 0.0:
        beyond = 0.0
    return d2 - a * a + beyond * beyond <= lim * lim


@native
def x_order(vecs, n):
    """``(order, shift, steps)``: the ``n`` unit vectors ``vecs`` (``x, y, z`` each) in ``x``
    order for :func:`near_pairs`, as one sorted list of small ints ``(k << shift) | p`` with
    ``k = int((x + 1) steps)`` a power-of-two quantisation of ``x + 1`` (monotonic, so a
    window of keys holds every vector within reach): sorting it calls no key per comparison
    (MicroPython's sort would) and allocates neither tuples nor long ints (keys below
    2**30)."""
    shift = 1
    while (1 << shift) < n:
        shift += 1
    steps = float(1 << (28 - shift))
    order = [0] * n
    for p in range(n):
        order[p] = (int((vecs[3 * p] + 1.0) * steps) << shift) | p
    order.sort()
    return order, shift, steps


@native
def near_pairs(observed, predicted, radius_rad, n_observed=None, streaks=None, order=None):
    """Yield ``(o, p, dx, dy, dz)`` for every observed unit vector ``observed[o]`` (the first
    ``n_observed``) within ``radius_rad`` of predicted star ``p`` (of ``predicted``, as
    :func:`predicted_stars`; of the stretch ``streaks[o]`` along its track,
    :func:`in_region`), with ``(dx, dy, dz)`` the observed minus the predicted vector; in
    ``o`` then ``p`` order.  The predicted stars are sorted by ``x`` once (:func:`x_order`;
    ``order``: that of ``predicted``, kept by the caller), so each observed star tests only
    those whose ``x`` is within reach (a binary search), not all."""
    lim = chord_of_angle(radius_rad)
    n = len(observed) if n_observed is None else min(n_observed, len(observed))
    vecs = predicted[1]
    n_pred = len(predicted[0])
    order, shift, steps = x_order(vecs, n_pred) if order is None else order
    mask = (1 << shift) - 1
    for o in range(n):
        ox, oy, oz = observed[o]
        streak = streaks[o] if streaks is not None else None
        reach = lim if streak is None else lim + chord_of_angle(streak[3])
        # a window wider than the exact test below
        lo = lower_bound(order, int((ox - 2.0 * reach + 1.0) * steps) << shift)
        high = (int((ox + 2.0 * reach + 1.0) * steps) << shift) | mask
        found = None
        while lo < n_pred and order[lo] <= high:
            p = order[lo] & mask
            lo += 1
            k = 3 * p
            dx = ox - vecs[k]
            if dx > reach or -dx > reach:
                continue
            dy = oy - vecs[k + 1]
            if dy > reach or -dy > reach:
                continue
            if found is None:
                found = [p]
            else:
                found.append(p)
        if found is None:
            continue
        if len(found) > 1:
            found.sort()
        for p in found:
            k = 3 * p
            dx = ox - vecs[k]
            dy = oy - vecs[k + 1]
            dz = oz - vecs[k + 2]
            if in_region(dx, dy, dz, streak, lim):
                yield o, p, dx, dy, dz


@native
def match_stars(observed, predicted, tolerance_rad, streaks=None):
    """One-to-one matches ``[(observed_index, star_index)]`` within each observed star's
    match region (``tolerance_rad``, stretched along ``streaks``: :func:`in_region`),
    closest first; ``predicted`` as returned by :func:`predicted_stars`.  An observed star
    that is also within tolerance of a predicted star left unmatched is dropped (a close
    double with one component unseen: either name could be right), and so are two observed
    stars whose swapped assignment is also within tolerance."""
    cands = [(dx * dx + dy * dy + dz * dz, o, p)
             for o, p, dx, dy, dz in near_pairs(observed, predicted, tolerance_rad,
                                                streaks=streaks)]
    cands.sort()
    used_o = {}
    used_p = {}
    for _d2, o, p in cands:
        if o in used_o or p in used_p:
            continue
        used_o[o] = p
        used_p[p] = o
    # An observed star that also lies within tolerance of a catalogue star nobody claimed
    # (a close double with one component unseen) cannot be named reliably, nor can two
    # observed stars whose swapped assignment is also within tolerance: drop them.
    npred = len(predicted[0])
    admissible = {}
    for _d2, o, p in cands:
        admissible[o * npred + p] = 1
    drop = []
    for _d2, o, p in cands:
        q = used_o.get(o)
        if q is None or q == p:
            continue
        o2 = used_p.get(p)
        if o2 is None:
            drop.append(o)
        elif o2 != o and (o2 * npred + q) in admissible:
            drop.append(o)
            drop.append(o2)
    for o in drop:
        used_o[o] = None
    pairs = []
    for o in used_o:
        if used_o[o] is not None:
            pairs.append((o, predicted[0][used_o[o]]))
    pairs.sort()
    return pairs


@native
def chance_probabilities(n_fov, omega, tolerance_rad, streaks, n):
    """Per observed star, the probability that one of ``n_fov`` stars scattered over the
    solid angle ``omega`` falls in its match region (``docs/starid.md``)."""
    disc = math.pi * tolerance_rad * tolerance_rad
    out = []
    for o in range(n):
        streak = streaks[o] if streaks is not None else None
        area = disc if streak is None else disc + 4.0 * tolerance_rad * streak[3]
        p = n_fov * area / omega
        out.append(p if p < 1.0 else 1.0)
    return out


def verify(observed, database, q, tolerance_rad, free_matches=2, streaks=None, sky=None):
    """Verify attitude ``q`` against all ``observed`` camera-frame unit vectors (their
    match regions stretched along ``streaks``); returns a :class:`Verification` (accept
    when ``probability < max_mismatch_prob``; ``p_single``: the largest per-star chance
    probability).  ``sky``: as for :func:`predicted_stars`."""
    predicted = predicted_stars(database, q, sky=sky)
    pairs = match_stars(observed, predicted, tolerance_rad, streaks)
    n_fov = len(predicted[0])
    omega = fov_solid_angle(database.fov_h, database.fov_v)
    p, prob = chance_agreement(n_fov, omega, tolerance_rad, len(observed), len(pairs),
                               streaks, free_matches)
    return Verification(pairs, n_fov, p, prob)


def chance_agreement(n_fov, omega, tolerance_rad, n_observed, n_matched, streaks=None,
                     free_matches=2):
    """``(p_single, probability)``: the largest per-star chance-match probability and the
    probability that ``n_matched`` of ``n_observed`` stars (``free_matches`` of them free)
    agree by chance with ``n_fov`` stars over the solid angle ``omega`` (``docs/starid.md``:
    binomial, or Poisson-binomial with ``streaks``)."""
    if streaks is None or not any(streaks):
        p = n_fov * math.pi * tolerance_rad * tolerance_rad / omega
        if p > 1.0:
            p = 1.0
        return p, binomial_tail(n_observed - free_matches, n_matched - free_matches, p)
    ps = chance_probabilities(n_fov, omega, tolerance_rad, streaks, n_observed)
    ps.sort()
    return ps[-1], poisson_binomial_tail(ps[free_matches:], n_matched - free_matches)


FUTILE_MARGIN = 1.000001
""":func:`least_chance` calls a search futile only this far above the threshold: the
probability's rounding, not its model."""


@native
def least_chance(n_observed, omega, tolerance_rad, max_prob, streaks=None, free_matches=2):
    """None when some hypothesis of ``n_observed`` stars could be accepted (probability below
    ``max_prob``), else the smallest probability any could reach: a search that cannot
    succeed ends before its first pattern (a frame of a few long tracks, whose match regions
    are wide).  Exact, not a heuristic: ``k`` one-to-one matches need ``n_fov >= k``
    predicted stars and :func:`chance_agreement` grows with ``n_fov``, so ``n_fov = k``
    bounds every hypothesis with ``k`` matches from below.  A usual frame costs O(n): all
    its stars matched among as many predicted, the probability is the product of the
    largest ``n - free_matches`` chances."""
    n = n_observed
    if streaks is None or not any(streaks):
        ps = [n * math.pi * tolerance_rad * tolerance_rad / omega] * n
    else:
        ps = chance_probabilities(n, omega, tolerance_rad, streaks, n)
        ps.sort()
    prod = 1.0
    for p in ps[free_matches:]:
        prod *= p if p < 1.0 else 1.0
    if prod * 2.0 < max_prob:
        return None
    least = 1.0
    for k in range(n, 0, -1):
        prob = chance_agreement(k, omega, tolerance_rad, n, k, streaks, free_matches)[1]
        if prob < max_prob * FUTILE_MARGIN:
            return None
        if prob < least:
            least = prob
    return least


def streak_variance(streak):
    """Per-axis variance (rad^2) a streak adds to its star's direction: a uniform offset over
    ``+-half`` along one axis (``half^2 / 3``) shared by two, ``half^2 / 6``; 0 for None."""
    return 0.0 if streak is None else streak[3] * streak[3] / 6.0
