"""Shared star-identification verification, result type and small geometry helpers.

Every identification method (Pyramid, Triangle, Hashing) ends the same way: a
hypothesis ``(observed star -> catalogue star)`` gives an attitude, and :func:`verify`
decides whether the whole field agrees with it:

1. **Predict.** Rotate every catalogue star within the FOV's half-diagonal of the hypothesised
   boresight into the camera frame and keep those inside the FOV rectangle
   (``|x/z| <= tan(fov_h/2)``, ``|y/z| <= tan(fov_v/2)``): ``N_fov`` stars.
2. **Match.** Pair observed and predicted stars closer than ``tolerance_rad`` (one to one,
   closest pairs first; an observed star that could equally be an unclaimed second catalogue
   star, or two observed stars whose names could be swapped, are left unnamed): ``k``
   matches among the ``n`` observed stars.
3. **Probability of a chance agreement** (as tetra3 / cedar-solve do it).  For a *wrong*
   attitude the catalogue stars land at positions unrelated to the observed ones, so each
   observed star matches one of them by chance with probability

       p = N_fov * (pi * tolerance_rad**2) / Omega_fov,
       Omega_fov = 4 asin(sin(fov_h/2) sin(fov_v/2))        (solid angle of the FOV),

   independently, and the number of chance matches is binomial.  The two stars that define
   the hypothesis' attitude (``free_matches = 2``, tetra3's "minus two degrees of freedom")
   are not evidence, so

       probability = P(X >= k - 2),  X ~ Binomial(n - 2, p).

   **Streaks.**  A star smeared by a known rate whose track the detector saw only in part
   lies up to ``half`` rad from its centroid along the track direction ``u`` (the unseen
   half of the track, ``lodestar.firmware.centroids``).  ``streaks[o]`` is then
   ``(ux, uy, uz, half)`` (``u`` a camera-frame unit tangent at the star; None for a star
   known to ``tolerance_rad`` all round): its match region is the stadium of points within
   ``tolerance_rad`` of the segment ``+-half`` along ``u`` (:func:`in_region`), of area
   ``pi tolerance_rad**2 + 4 tolerance_rad half``, and each observed star gets its own
   ``p_o = N_fov * area_o / Omega_fov``.  The number of chance matches is then
   Poisson-binomial; the ``free_matches`` stars taken as free are those of the smallest
   ``p_o`` (the bound stays conservative) and ``probability = P(X >= k - 2)`` over the
   others (:func:`poisson_binomial_tail`).

   A hypothesis is **accepted** when ``probability < max_mismatch_prob`` (default ``1e-9``).
   This is a per-hypothesis false-match probability: over a search that verifies ``H``
   hypotheses the chance of accepting any wrong one is at most ``H * max_mismatch_prob``
   (e.g. 1e-6 for 1000 hypotheses), which :class:`Solution` reports through
   ``hypotheses``.

The methods share :class:`Search` (fit + verify a hypothesis, refine the accepted one over
all its matches, decide ``OK`` / ``AMBIGUOUS`` among the accepted hypotheses of one pattern)
and the handedness test :func:`handed`.  The attitude fit is Davenport's q-method of
:mod:`lodestar.firmware.attitude` (:func:`fit_attitude`, weighted by
:func:`streak_weights` when there are streaks; it replaced a private inverse iteration that
lost up to ~10 arcmin on two-star, sub-degree fits).  Status codes are those of
:mod:`lodestar.firmware.status`, re-exported here under the names the identification
methods use (``BAD_DATABASE`` is ``DATABASE_UNSUPPORTED``).

Conventions (``lodestar.sim``): ``q = (x, y, z, w)``, scalar last, rotating inertial vectors
into the camera frame, ``v_cam = R(q) v_inertial``.

Pure Python for CPython and MicroPython (``math`` only).
"""

import math

from . import attitude as _attitude
from . import geometry as G
from . import status as S
from .quaternion import angle_between, matrix

# --------------------------------------------------------------------------------------
# Status codes (lodestar.firmware.status, re-exported) and the shared result type
# --------------------------------------------------------------------------------------

OK = S.OK                               # identified and verified
NO_MATCH = S.NO_MATCH                   # every pattern tried, nothing verified
TOO_FEW_STARS = S.TOO_FEW_STARS         # fewer observed stars than the method needs
AMBIGUOUS = S.AMBIGUOUS                 # two distinct attitudes both verified
BUDGET_EXHAUSTED = S.BUDGET_EXHAUSTED   # the pattern budget ran out first
BAD_INPUT = S.BAD_INPUT                 # NaN / zero vectors, bad parameters
BAD_DATABASE = S.DATABASE_UNSUPPORTED   # the database does not serve the method
STATUS_NAMES = {}
"""``{code: name}`` of the statuses an identification returns."""
for _code in (OK, NO_MATCH, TOO_FEW_STARS, AMBIGUOUS, BUDGET_EXHAUSTED, BAD_INPUT,
              BAD_DATABASE):
    STATUS_NAMES[_code] = S.name(_code)


def status_name(code):
    """Text name of a status code (:func:`lodestar.firmware.status.name`)."""
    return S.name(code)


class Solution:
    """Result of an identification.

    ``status``: a :mod:`lodestar.firmware.status` code (:data:`STATUS_NAMES`); ``q``:
    attitude ``(x, y, z, w)`` or ``None``; ``matches``: list of ``(observed_index, hip)``,
    sorted by observed index; ``patterns_tried``: observed patterns examined (star triples
    for Pyramid and Triangle, star groups for Hashing);
    ``probability``: the binomial false-match probability of the accepted hypothesis (or of
    the best rejected one, ``1.0`` if none was verified); ``hypotheses``: hypotheses
    verified; ``star_ids``: ``(observed_index, database star index)`` pairs.
    """

    def __init__(self, status, q=None, matches=None, patterns_tried=0, probability=1.0,
                 hypotheses=0, star_ids=None):
        self.status = status
        self.q = q
        self.matches = matches if matches is not None else []
        self.patterns_tried = patterns_tried
        self.probability = probability
        self.hypotheses = hypotheses
        self.star_ids = star_ids if star_ids is not None else []

    @property
    def ok(self):
        return self.status == OK

    def __repr__(self):
        return ("Solution(" + status_name(self.status) + ", q=" + repr(self.q) +
                ", matches=" + str(len(self.matches)) + ", patterns_tried=" +
                str(self.patterns_tried) + ", probability=" + repr(self.probability) + ")")


# --------------------------------------------------------------------------------------
# Attitude fit
# --------------------------------------------------------------------------------------

def fit_attitude(observed, reference, weights=None):
    """Least-squares attitude (Wahba) of camera-frame unit vectors ``observed`` and inertial
    unit vectors ``reference`` (equal-length sequences of 3-sequences, at least 2 pairs not
    parallel): ``q = (x, y, z, w)`` with ``w >= 0`` and ``observed ~ R(q) reference``;
    ``None`` when the geometry is degenerate (all vectors parallel) or an input is bad.

    Davenport's q-method of :mod:`lodestar.firmware.attitude` (:func:`~lodestar.firmware.
    attitude.q_method`, a Jacobi eigen-solver: accurate for every rotation angle).
    """
    try:
        q = _attitude.q_method(observed, reference, weights)
    except ValueError:
        return None
    return q[0], q[1], q[2], q[3]


# --------------------------------------------------------------------------------------
# Probability
# --------------------------------------------------------------------------------------

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
    per observed star) and ``probability`` (binomial tail, see the module docstring)."""

    def __init__(self, pairs, n_fov, p_single, probability):
        self.pairs = pairs
        self.n_fov = n_fov
        self.p_single = p_single
        self.probability = probability

    @property
    def n_matched(self):
        return len(self.pairs)


def predicted_stars(database, q, margin=0.0):
    """Catalogue stars inside the FOV at attitude ``q``: list of ``(camera vector, index)``.

    ``margin`` (rad) widens the FOV rectangle on every side."""
    m = matrix(q)
    boresight = (m[6], m[7], m[8])           # inertial direction of camera +z
    half_diag = 0.5 * database.fov_diag + margin
    tan_h = math.tan(0.5 * database.fov_h + margin)
    tan_v = math.tan(0.5 * database.fov_v + margin)
    out = []
    for s in database.stars_in_cone(boresight, half_diag):
        c = G.mat_vec(m, database.star_vector(s))
        if c[2] <= 0.0:
            continue
        if abs(c[0]) <= tan_h * c[2] and abs(c[1]) <= tan_v * c[2]:
            out.append((c, s))
    return out


def chord(angle):
    """Chord length of an angle (rad): ``|a - b|`` of unit vectors ``angle`` apart."""
    return 2.0 * math.sin(0.5 * angle)


def in_region(dx, dy, dz, streak, lim):
    """True when the offset ``(dx, dy, dz)`` of an observed unit vector from a predicted one
    lies in the observed star's match region: within the chord ``lim`` of the predicted
    star, widened along a ``streak`` ``(ux, uy, uz, half)`` to the stadium of points within
    ``lim`` of the segment ``+-chord(half)`` along ``u`` (module docstring; None: a disc)."""
    d2 = dx * dx + dy * dy + dz * dz
    if streak is None:
        return d2 <= lim * lim
    a = abs(dx * streak[0] + dy * streak[1] + dz * streak[2])    # along the track
    beyond = a - chord(streak[3])                                  # past the segment's end
    if beyond < 0.0:
        beyond = 0.0
    return d2 - a * a + beyond * beyond <= lim * lim


def near_pairs(observed, predicted, radius_rad, n_observed=None, streaks=None):
    """Yield ``(o, p, dx, dy, dz)`` for every observed unit vector ``observed[o]`` (the first
    ``n_observed``) within ``radius_rad`` of a predicted star ``predicted[p][0]`` (of the
    stretch ``streaks[o]`` along its track, :func:`in_region`), with ``(dx, dy, dz) =
    observed[o] - predicted[p][0]``; in ``o`` then ``p`` order."""
    lim = chord(radius_rad)
    n = len(observed) if n_observed is None else min(n_observed, len(observed))
    for o in range(n):
        ox, oy, oz = observed[o]
        streak = streaks[o] if streaks is not None else None
        reach = lim if streak is None else lim + chord(streak[3])
        for p in range(len(predicted)):
            c = predicted[p][0]
            dx = ox - c[0]
            if dx > reach or -dx > reach:
                continue
            dy = oy - c[1]
            if dy > reach or -dy > reach:
                continue
            dz = oz - c[2]
            if in_region(dx, dy, dz, streak, lim):
                yield o, p, dx, dy, dz


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
    for d2, o, p in cands:
        if o in used_o or p in used_p:
            continue
        used_o[o] = p
        used_p[p] = o
    # An observed star that also lies within tolerance of a catalogue star nobody claimed
    # (a close double with one component unseen) cannot be named reliably, nor can two
    # observed stars whose swapped assignment is also within tolerance: drop them.
    npred = len(predicted)
    admissible = {}
    for d2, o, p in cands:
        admissible[o * npred + p] = 1
    drop = []
    for d2, o, p in cands:
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
            pairs.append((o, predicted[used_o[o]][1]))
    pairs.sort()
    return pairs


def chance_probabilities(n_fov, omega, tolerance_rad, streaks, n):
    """Per observed star, the probability that one of ``n_fov`` stars scattered over the
    solid angle ``omega`` falls in its match region (module docstring)."""
    disc = math.pi * tolerance_rad * tolerance_rad
    out = []
    for o in range(n):
        streak = streaks[o] if streaks is not None else None
        area = disc if streak is None else disc + 4.0 * tolerance_rad * streak[3]
        p = n_fov * area / omega
        out.append(p if p < 1.0 else 1.0)
    return out


def verify(observed, database, q, tolerance_rad, free_matches=2, streaks=None):
    """Verify attitude ``q`` against all ``observed`` camera-frame unit vectors (their
    match regions stretched along ``streaks``); returns a :class:`Verification` (accept
    when ``probability < max_mismatch_prob``; ``p_single``: the largest per-star chance
    probability)."""
    predicted = predicted_stars(database, q)
    pairs = match_stars(observed, predicted, tolerance_rad, streaks)
    n_fov = len(predicted)
    omega = fov_solid_angle(database.fov_h, database.fov_v)
    p, prob = chance_agreement(n_fov, omega, tolerance_rad, len(observed), len(pairs),
                               streaks, free_matches)
    return Verification(pairs, n_fov, p, prob)


def chance_agreement(n_fov, omega, tolerance_rad, n_observed, n_matched, streaks=None,
                     free_matches=2):
    """``(p_single, probability)``: the largest per-star chance-match probability and the
    probability that ``n_matched`` of ``n_observed`` stars (``free_matches`` of them free)
    agree by chance with ``n_fov`` stars over the solid angle ``omega`` (module docstring:
    binomial, or Poisson-binomial with ``streaks``)."""
    if streaks is None or not any(streaks):
        p = n_fov * math.pi * tolerance_rad * tolerance_rad / omega
        if p > 1.0:
            p = 1.0
        return p, binomial_tail(n_observed - free_matches, n_matched - free_matches, p)
    ps = chance_probabilities(n_fov, omega, tolerance_rad, streaks, n_observed)
    ps.sort()
    return ps[-1], poisson_binomial_tail(ps[free_matches:], n_matched - free_matches)


# --------------------------------------------------------------------------------------
# Search bookkeeping shared by the identification methods
# --------------------------------------------------------------------------------------

def prepare(vectors):
    """Unit-vector tuples of the observed ``vectors``, or ``None`` if any is not a finite,
    non-zero 3-vector (the methods then return ``BAD_INPUT``)."""
    b = []
    for v in vectors:
        try:
            u = G.unit(v)
        except (TypeError, ValueError, IndexError):
            u = None
        if u is None:
            return None
        b.append(u)
    return b


def streak_variance(streak):
    """Per-axis variance (rad^2) a streak adds to its star's direction: a uniform offset over
    ``+-half`` along one axis (``half^2 / 3``) shared by two, ``half^2 / 6``; 0 for None."""
    return 0.0 if streak is None else streak[3] * streak[3] / 6.0


def streak_weights(streaks, tolerance_rad):
    """Relative fit weights of observed stars with ``streaks`` (None: None, equal weights):
    ``1 / (1 + streak_variance / (tolerance_rad / 3)^2)`` (:func:`streak_variance` against
    a point tolerance of three sigma per axis); 1 without a streak."""
    if streaks is None or not any(streaks):
        return None
    s2 = tolerance_rad * tolerance_rad / 9.0
    return [1.0 / (1.0 + streak_variance(streak) / s2) for streak in streaks]


def streaks_valid(streaks, n):
    """True when ``streaks`` is None or ``n`` entries, each None or ``(ux, uy, uz, half)``
    of finite numbers with ``half >= 0`` (``u`` is used as given: a unit vector)."""
    if streaks is None:
        return True
    try:
        if len(streaks) != n:
            return False
        for s in streaks:
            if s is None:
                continue
            if len(s) != 4:
                return False
            for v in s:
                if not G.finite(v):
                    return False
            if s[3] < 0:
                return False
    except TypeError:
        return False
    return True


class Search:
    """Hypothesis testing, refinement and the final decision, common to every method.

    ``b``: observed unit vectors (brightest first); ``db``: the database; ``tol``: the
    direction tolerance (rad); ``max_prob``: acceptance threshold of the binomial
    probability; ``distinct``: attitudes further apart (rad) are distinct solutions;
    ``streaks``: per observed star None or its track ``(ux, uy, uz, half)`` (module
    docstring), or None for none.  ``half`` lists each star's ``half`` (0 without a
    streak) and ``weights`` the fits' (:func:`streak_weights`).  ``hypotheses`` counts
    verified hypotheses, ``best_rejected`` is the smallest probability of a rejected one.
    """

    def __init__(self, b, db, tol, max_prob, distinct, streaks=None):
        self.b = b
        self.db = db
        self.tol = tol
        self.max_prob = max_prob
        self.distinct = distinct
        self.hypotheses = 0
        self.best_rejected = 1.0
        self.streaks = streaks if streaks is not None and any(streaks) else None
        self.half = [0.0] * len(b)
        self.weights = streak_weights(self.streaks, tol)
        if self.streaks is not None:
            for o in range(len(b)):
                if streaks[o] is not None:
                    self.half[o] = streaks[o][3]

    def hypothesis(self, obs_idx, cat_idx):
        """Fit (q-method, :meth:`fit`) and verify observed stars ``obs_idx`` as catalogue
        stars ``cat_idx``; returns ``(q, Verification)`` or ``(None, None)`` (degenerate)."""
        q = self.fit([(obs_idx[t], cat_idx[t]) for t in range(len(obs_idx))])
        if q is None:
            return None, None
        self.hypotheses += 1
        return q, verify(self.b, self.db, q, self.tol, streaks=self.streaks)

    def test(self, obs_idx, cat_idx, accepted):
        """:meth:`hypothesis`; appends ``(q, Verification)`` to ``accepted`` and returns True
        when it is accepted (probability below ``max_prob``)."""
        q, ver = self.hypothesis(obs_idx, cat_idx)
        if ver is None:
            return False
        if ver.probability < self.max_prob:
            accepted.append((q, ver))
            return True
        if ver.probability < self.best_rejected:
            self.best_rejected = ver.probability
        return False

    def refine(self, ver, rounds=4):
        """Attitude from all matches: refit and re-verify while the match set grows (up to
        ``rounds`` times).  Returns ``(q, ver)`` with ``q`` the q-method fit of exactly
        ``ver.pairs`` (a re-verification that loses matches or acceptance is discarded)."""
        for _ in range(rounds):
            q = self.fit(ver.pairs)
            if q is None:
                break
            ver2 = verify(self.b, self.db, q, self.tol, streaks=self.streaks)
            if ver2.probability >= self.max_prob or ver2.n_matched < ver.n_matched or \
                    ver2.pairs == ver.pairs:
                return q, ver
            ver = ver2
        return self.fit(ver.pairs), ver

    def fit(self, pairs):
        """The q-method attitude of the matches ``pairs`` (observed, catalogue index),
        weighted by :attr:`weights`; None when degenerate."""
        db = self.db
        obs = [self.b[o] for o, s in pairs]
        ref = [db.star_vector(s) for o, s in pairs]
        w = None if self.weights is None else [self.weights[o] for o, s in pairs]
        return fit_attitude(obs, ref, w)

    def conclude(self, accepted, tried):
        """The :class:`Solution` of the accepted hypotheses of one pattern: ``AMBIGUOUS`` if
        two of them are more than ``distinct`` apart, else the most probable one refined
        (status ``OK``)."""
        best = 0
        for h in range(1, len(accepted)):
            if accepted[h][1].probability < accepted[best][1].probability:
                best = h
        q, ver = accepted[best]
        for h in range(len(accepted)):
            if angle_between(accepted[h][0], q) > self.distinct:
                return Solution(AMBIGUOUS, patterns_tried=tried, probability=ver.probability,
                                hypotheses=self.hypotheses)
        q, ver = self.refine(ver)
        db = self.db
        matches = [(o, db.star_hip(s)) for o, s in ver.pairs]
        return Solution(OK, q=q, matches=matches, patterns_tried=tried,
                        probability=ver.probability, hypotheses=self.hypotheses,
                        star_ids=list(ver.pairs))

    def fail(self, status, tried):
        """A :class:`Solution` without attitude (``NO_MATCH``, ``BUDGET_EXHAUSTED``)."""
        return Solution(status, patterns_tried=tried, probability=self.best_rejected,
                        hypotheses=self.hypotheses)


def handed(t_obs, t_cat, bound):
    """Handedness test: False only when the observed triple product ``t_obs`` is reliably
    (beyond ``bound``) of the other sign than the catalogue's ``t_cat`` (a mirror image)."""
    if t_obs > bound:
        return t_cat > 0.0
    if t_obs < -bound:
        return t_cat < 0.0
    return True


def triple_bound(b1, b2, b3, tol):
    """Error bound of the triple product ``(b1 x b2) . b3`` of unit vectors each known to
    ``tol`` rad: ``tol (|b1 - b2| + |b2 - b3| + |b3 - b1|)`` (first order, with margin)."""
    return tol * (G.chord(b1, b2) + G.chord(b2, b3) + G.chord(b3, b1))
