"""The search shared by every identification method: hypotheses, refinement, decision.

A method enumerates observed patterns brightest first; each catalogue candidate of a pattern
is a hypothesis ``(observed stars -> catalogue stars)`` that :class:`Search` fits (q-method,
partly seen tracks weighted down) and verifies (:func:`lodestar.firmware.starid.verify.verify`).
The first pattern with an accepted hypothesis ends the search: ``AMBIGUOUS`` if two accepted
attitudes are more than ``distinct`` apart, else the best refined over all its matches
(``OK``); ``BUDGET_EXHAUSTED`` / ``NO_MATCH`` otherwise (:mod:`lodestar.firmware.status`),
or ``MIRRORED`` when the first patterns identify the stars mirrored (:meth:`Search.mirrored`).
Angles in radians (``docs/conventions.md``); details in ``docs/starid.md`` (Search).  Pure
Python for CPython and MicroPython (``math`` only).
"""

from .. import attitude
from .. import geometry as G
from .. import status as S
from ..emit import native
from ..quaternion import angle_between
from .verify import SkyCone, fov_solid_angle, least_chance, streak_variance, verify

DEFAULT_MAX_WORK = 5000000
"""Work budget of one identification by a method without a budget of its own (Triangle,
geometric hashing; Pyramid's is :data:`lodestar.firmware.starid.pyramid.MAX_WORK`), in units
of one catalogue pair candidate examined (15-25 guest ticks on the Cortex-M4F build, 50-80
us of F401 time; a verification and a Pyramid pattern are charged as the pair candidates
their time buys, :data:`VERIFY_WORK`, :attr:`Search.PATTERN_WORK`).  A search that spends
its budget ends with ``BUDGET_EXHAUSTED`` whatever its input (``docs/starid.md``, Work
budget)."""
VERIFY_WORK = 1600
"""Work units of one hypothesis verification beyond its observed stars: its fit and a cone of
the catalogue read and matched, about 24,000 guest ticks on the Cortex-M4F build, as long as
1,600 pair candidates."""
RECORD_WORK = 32
"""Work units of one stored triangle or hash group examined (its stars read and compared:
about as long as 32 pair candidates)."""
MIRROR_PATTERNS = 512
"""Patterns of a failed search tried again with the observed stars mirrored
(:meth:`Search.mirrored`): an unmirrored frame identifies within its first patterns (of 40
estcube2 scenes with up to 5 false stars, at most 3 for Pyramid, 83 for Triangle, 338 for
Hashing), so a mirrored one does when turned back."""
MIRROR_SHARE = 4
"""The mirror check tries at most ``1 / MIRROR_SHARE`` of the patterns the failed search
tried (all of them up to :data:`MIRROR_SMALL`) ..."""
MIRROR_SMALL = 32
"""... and the patterns of a search that tried no more than this."""
MIRROR_WORK_SHARE = 3
"""The mirror check spends at most ``max_work // MIRROR_WORK_SHARE`` work units (it was a
tenth of a 5 M budget; of Pyramid's 20,000 units a mirrored estcube2 scene needed up to
5,916 in the firmware tests)."""
MIRROR_EARLY = 32
"""Patterns kept for the mirror check in :data:`_EARLY` (64 bytes, allocated at import); a
search that goes on allocates room for :data:`MIRROR_PATTERNS` (1 KiB, :func:`_keep`)."""
_EARLY = bytearray(2 * MIRROR_EARLY)
"""A search's first patterns, 2 bytes each: up to 4 star indices below 16, a nibble each
(the patterns of the 16 brightest stars; reused by every search)."""


class OutOfWork(Exception):
    """The search spent its work budget (caught by :meth:`Search.run`)."""


class Solution:
    """Result of an identification.

    ``status``: a :mod:`lodestar.firmware.status` code; ``q``:
    attitude ``(x, y, z, w)`` or ``None``; ``matches``: list of ``(observed_index, hip)``,
    sorted by observed index; ``patterns_tried``: observed patterns examined (star triples
    for Pyramid and Triangle, star groups for Hashing);
    ``probability``: the binomial false-match probability of the accepted hypothesis (or of
    the best rejected one, ``1.0`` if none was verified; the smallest any could reach when no
    hypothesis could verify); ``hypotheses``: hypotheses
    verified; ``star_ids``: ``(observed_index, database star index)`` pairs; ``work``: work
    units spent (:data:`DEFAULT_MAX_WORK`).
    """

    def __init__(self, status, q=None, matches=None, patterns_tried=0, probability=1.0,
                 hypotheses=0, star_ids=None, work=0):
        self.status = status
        self.q = q
        self.matches = matches if matches is not None else []
        self.patterns_tried = patterns_tried
        self.probability = probability
        self.hypotheses = hypotheses
        self.star_ids = star_ids if star_ids is not None else []
        self.work = work

    @property
    def ok(self):
        return self.status == S.OK

    def __repr__(self):
        return (type(self).__name__ + "(" + S.name(self.status) + ", q=" + repr(self.q) +
                ", matches=" + str(len(self.matches)) + ", patterns_tried=" +
                str(self.patterns_tried) + ", probability=" + repr(self.probability) + ")")


def fit_attitude(observed, reference, weights=None):
    """Least-squares attitude (Wahba) of camera-frame unit vectors ``observed`` and inertial
    unit vectors ``reference`` (equal-length sequences of 3-sequences, at least 2 pairs not
    parallel): ``q = (x, y, z, w)`` with ``w >= 0`` and ``observed ~ R(q) reference``;
    ``None`` when the geometry is degenerate (all vectors parallel) or an input is bad.

    Davenport's q-method of :mod:`lodestar.firmware.attitude` (:func:`~lodestar.firmware.
    attitude.q_method`, a Jacobi eigen-solver: accurate for every rotation angle).
    """
    try:
        q = attitude.q_method(observed, reference, weights)
    except ValueError:
        return None
    return q[0], q[1], q[2], q[3]


def observed(vectors, database, bit, tolerance_rad, budget, max_stars, min_stars, streaks):
    """``(status, b)``: the observed ``vectors`` as unit tuples ``b`` (status ``OK``), or why
    a method cannot search them (``b`` None): ``BAD_INPUT`` (``tolerance_rad`` not positive,
    ``budget < 1``, ``max_stars < min_stars``, malformed ``streaks``, a vector that is not
    a finite non-zero 3-vector), ``DATABASE_UNSUPPORTED`` (the database lacks the method's
    ``bit``) or ``TOO_FEW_STARS`` (fewer than ``min_stars`` vectors)."""
    if not (tolerance_rad > 0.0) or budget < 1 or max_stars < min_stars:
        return S.BAD_INPUT, None
    if not streaks_valid(streaks, len(vectors)):
        return S.BAD_INPUT, None
    if not database.methods & bit:
        return S.DATABASE_UNSUPPORTED, None
    b = []
    for v in vectors:
        try:
            u = v if G.is_unit_tuple(v) else G.unit(v)
        except (TypeError, ValueError, IndexError):
            u = None
        if u is None:
            return S.BAD_INPUT, None
        b.append(u)
    if len(b) < min_stars:
        return S.TOO_FEW_STARS, None
    return S.OK, b


def identify_with(search_class, vectors, database, tolerance_rad, budget, max_stars,
                  max_mismatch_prob, distinct_rad, streaks, max_work):
    """The identification of every method (LOST's ``StarIdAlgorithm::Go``): checks the input
    (:func:`observed`, ``search_class.refuses``), makes the method's :class:`Search`
    subclass and runs its patterns (none, ``NO_MATCH``, when even every observed star matched
    could not verify: :func:`.verify.least_chance`); returns a :class:`Solution`.

    ``tolerance_rad``: largest direction error of one observed star (the verification match
    radius).  ``budget``: most patterns tried.  ``max_stars``: observed stars the patterns
    use.  ``distinct_rad``: attitudes further apart are distinct solutions (None: ``20 *
    tolerance_rad``).  ``streaks``: per star None or its partly seen track
    (``docs/starid.md``, Search), or None.  ``max_work``: work units (:data:`DEFAULT_MAX_WORK`).
    """
    code, b = observed(vectors, database, search_class.BIT, tolerance_rad, budget, max_stars,
                       search_class.MIN_STARS, streaks)
    if b is None:
        return Solution(code)
    code = search_class.refuses(b, database, max_stars)
    if code is not None:
        return Solution(code)
    least = least_chance(len(b), fov_solid_angle(database.fov_h, database.fov_v),
                         tolerance_rad, max_mismatch_prob, streaks)
    if least is not None:           # no hypothesis could verify: no pattern tried
        return Solution(S.NO_MATCH, probability=least)
    search = search_class(b, database, tolerance_rad, max_mismatch_prob,
                          20.0 * tolerance_rad if distinct_rad is None else distinct_rad,
                          streaks, max_stars)
    search.max_work = max_work
    return search.run(search.patterns(), budget)


@native
def streak_weights(streaks, tolerance_rad):
    """Relative fit weights of observed stars with ``streaks`` (None: None, equal weights):
    ``1 / (1 + streak_variance / (tolerance_rad / 3)^2)`` (:func:`streak_variance` against
    a point tolerance of three sigma per axis); 1 without a streak."""
    if streaks is None or not any(streaks):
        return None
    s2 = tolerance_rad * tolerance_rad / 9.0
    return [1.0 / (1.0 + streak_variance(streak) / s2) for streak in streaks]


@native
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
                if not v - v == 0:      # G.finite, inline: it runs for every frame's tracks
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
    ``streaks``: per observed star None or its track ``(ux, uy, uz, half)`` (``docs/starid.md``,
    Search), or None for none; ``max_stars``: observed stars the patterns use (``n``, the
    first of ``b``).  ``half`` lists each star's ``half`` (0 without a
    streak) and ``weights`` the fits' (:func:`streak_weights`).  ``hypotheses`` counts
    verified hypotheses, ``best_rejected`` is the smallest probability of a rejected one;
    ``sky`` the :class:`~.verify.SkyCone` of the last accepted hypothesis (its refinement's
    verifications read it again).

    A method subclasses it (:func:`identify_with` makes and runs it): ``BIT`` (its database
    bit), ``MIN_STARS`` (fewest observed stars), :meth:`refuses`, :meth:`patterns` and
    :meth:`try_pattern`.
    """

    BIT = 0
    """The database's ``methods`` bit the method reads."""
    PATTERN_WORK = 0
    """Work units charged per observed pattern tried, beyond what the method charges for
    its candidates (a method whose patterns cost time of their own sets it)."""
    MIN_STARS = 3
    """Fewest observed stars the method searches (fewer: ``TOO_FEW_STARS``)."""

    def __init__(self, b, db, tol, max_prob, distinct, streaks, max_stars):
        self.b = b
        self.n = len(b) if len(b) < max_stars else max_stars
        self.db = db
        self.tol = tol
        self.max_prob = max_prob
        self.distinct = distinct
        self.hypotheses = 0
        self.best_rejected = 1.0
        self.work = 0
        self.max_work = DEFAULT_MAX_WORK
        self.streaks = streaks if streaks is not None and any(streaks) else None
        self.half = [0.0] * len(b)
        self.weights = streak_weights(self.streaks, tol)
        self.sky = SkyCone()        # a hypothesis's cone, read again by its refinement
        if self.streaks is not None:
            for o in range(len(b)):
                if streaks[o] is not None:
                    self.half[o] = streaks[o][3]

    @staticmethod
    def refuses(b, db, max_stars):
        """A status when the method cannot search the observed ``b`` of ``db`` beyond the
        checks of :func:`observed`, else None (the default)."""
        return None

    def patterns(self):
        """The observed patterns (star index tuples) in search order, for :meth:`run`."""
        raise NotImplementedError

    def try_pattern(self, pattern):
        """Accepted ``[(q, Verification)]`` of the observed ``pattern`` (star indices): the
        method's catalogue candidates, each through :meth:`test`."""
        raise NotImplementedError

    def spend(self, units):
        """Count ``units`` of work; raises :class:`OutOfWork` past :attr:`max_work`."""
        self.work += units
        if self.work > self.max_work:
            raise OutOfWork()

    def hypothesis(self, obs_idx, cat_idx):
        """Fit (q-method, :meth:`fit`) and verify observed stars ``obs_idx`` as catalogue
        stars ``cat_idx``; returns ``(q, Verification)`` or ``(None, None)`` (degenerate)."""
        self.spend(VERIFY_WORK + len(self.b))
        q = self.fit([(obs_idx[t], cat_idx[t]) for t in range(len(obs_idx))])
        if q is None:
            return None, None
        self.hypotheses += 1
        return q, verify(self.b, self.db, q, self.tol, streaks=self.streaks, sky=self.sky)

    def test(self, obs_idx, cat_idx, accepted):
        """:meth:`hypothesis`; appends ``(q, Verification)`` to ``accepted`` and returns True
        when it is accepted (probability below ``max_prob``)."""
        q, ver = self.hypothesis(obs_idx, cat_idx)
        if ver is None:
            return False
        if ver.probability < self.max_prob:
            accepted.append((q, ver))
            return True
        self.sky.clear()            # a rejected attitude's cone: not held through the search
        if ver.probability < self.best_rejected:
            self.best_rejected = ver.probability
        return False

    def refine(self, q, ver, rounds=4):
        """Attitude from all matches of the hypothesis ``q`` (verified as ``ver``): refit
        from ``q`` and re-verify while the match set grows (up to ``rounds`` times).
        Returns ``(q, ver)`` with ``q`` the least-squares fit of exactly ``ver.pairs`` (a
        re-verification that loses matches or acceptance is discarded)."""
        start = q
        for _ in range(rounds):
            q = self.fit(ver.pairs, start)
            if q is None:
                break
            ver2 = verify(self.b, self.db, q, self.tol, streaks=self.streaks, sky=self.sky)
            if ver2.probability >= self.max_prob or ver2.n_matched < ver.n_matched or \
                    ver2.pairs == ver.pairs:
                return q, ver
            ver = ver2
            start = q
        return self.fit(ver.pairs, start), ver

    def fit(self, pairs, q0=None):
        """The least-squares attitude of the matches ``pairs`` (observed, catalogue index),
        weighted by :attr:`weights`: the q-method (a pattern's first fit), or refined from a
        nearby attitude ``q0`` (:func:`lodestar.firmware.attitude.refine`: one or two steps
        instead of a 4x4 Jacobi, and accurate in single precision); None when degenerate."""
        db = self.db
        obs = [self.b[o] for o, s in pairs]
        ref = [db.star_vector(s) for o, s in pairs]
        w = None if self.weights is None else [self.weights[o] for o, s in pairs]
        if q0 is None:
            return fit_attitude(obs, ref, w)
        try:
            q = attitude.refine(q0, obs, ref, w)
        except ValueError:
            return None
        return q[0], q[1], q[2], q[3]

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
                return Solution(S.AMBIGUOUS, patterns_tried=tried, probability=ver.probability,
                                hypotheses=self.hypotheses, work=self.work)
        q, ver = self.refine(q, ver)
        db = self.db
        matches = [(o, db.star_hip(s)) for o, s in ver.pairs]
        return Solution(S.OK, q=q, matches=matches, patterns_tried=tried,
                        probability=ver.probability, hypotheses=self.hypotheses,
                        star_ids=list(ver.pairs), work=self.work)

    def run(self, patterns, budget):
        """Try ``patterns`` (observed-star index tuples, in search order) with the method's
        ``try_pattern`` until one has accepted hypotheses (:meth:`conclude`), ``budget``
        patterns were tried or :attr:`max_work` units spent (``BUDGET_EXHAUSTED``) or none is
        left (``NO_MATCH``)."""
        tried = kept = size = 0     # kept: the first patterns, in ``first``, for the mirror check
        first = _EARLY
        status = S.NO_MATCH
        try:
            for pattern in patterns:
                if tried >= budget:
                    status = S.BUDGET_EXHAUSTED
                    break
                tried += 1
                if kept == tried - 1 and kept < MIRROR_PATTERNS:
                    first = _keep(first, kept, pattern)
                    if first is not None:
                        size = len(pattern)
                        kept += 1
                self.spend(self.PATTERN_WORK)
                accepted = self.try_pattern(pattern)
                if accepted:
                    return self.conclude(accepted, tried)
        except OutOfWork:
            status = S.BUDGET_EXHAUSTED
        except MemoryError:
            return self.fail(S.OUT_OF_MEMORY, tried)
        return self.mirrored(first, kept, size, self.fail(status, tried))

    def mirrored(self, first, kept, size, failed):
        """The failed search's verdict ``failed``, or ``MIRRORED`` (no attitude) when one of
        its first ``kept`` patterns (of ``size`` stars, in ``first``, :func:`_keep`) with every
        observed star and track mirrored (``x -> -x``: a flip of the columns; a flip of the
        rows is that and a half turn) gives an accepted hypothesis.  Angles are
        parity-invariant, so a mirrored frame finds its patterns, but the handedness tests
        and the rotation fit reject them; here they are tried turned back, within
        ``max_work // MIRROR_WORK_SHARE`` work units and a :data:`MIRROR_SHARE` of the
        patterns ``failed`` tried.  ``failed`` keeps its counts either way
        (``docs/apparent_directions.md``)."""
        tried = failed.patterns_tried
        if tried > MIRROR_SMALL and kept > tried // MIRROR_SHARE:
            kept = tried // MIRROR_SHARE
        streaks = self.streaks
        if streaks is not None:
            self.streaks = [None if t is None else (-t[0], t[1], t[2], t[3]) for t in streaks]
        _mirror(self.b)                 # in place (and back: a negation is exact)
        work, max_work = self.work, self.max_work
        self.work, self.max_work = 0, max_work // MIRROR_WORK_SHARE
        try:
            for k in range(kept):
                code = first[2 * k] | first[2 * k + 1] << 8
                self.spend(self.PATTERN_WORK)
                if self.try_pattern(tuple((code >> 4 * t) & 15 for t in range(size))):
                    failed.status = S.MIRRORED
                    break
        except (OutOfWork, MemoryError):
            pass
        _mirror(self.b)
        self.streaks = streaks
        self.work, self.max_work = work + self.work, max_work     # the search's whole spend
        return failed

    def fail(self, status, tried):
        """A :class:`Solution` without attitude (``NO_MATCH``, ``BUDGET_EXHAUSTED``)."""
        return Solution(status, patterns_tried=tried, probability=self.best_rejected,
                        hypotheses=self.hypotheses, work=self.work)


def _keep(buf, k, pattern):
    """Store ``pattern`` (star indices) as the ``k``-th of ``buf`` for the mirror check and
    return the buffer: :data:`_EARLY`, or past :data:`MIRROR_EARLY` patterns a new one for
    :data:`MIRROR_PATTERNS`; None when it cannot be kept (more than 4 stars, an index above
    15, no heap for the larger buffer: the check then tries the patterns kept so far)."""
    if len(pattern) > 4 or max(pattern) > 15:
        return None
    if 2 * k == len(buf):
        try:
            grown = bytearray(2 * MIRROR_PATTERNS)
        except MemoryError:
            return None
        for i in range(len(buf)):
            grown[i] = buf[i]
        buf = grown
    code = 0
    for t in range(len(pattern)):
        code |= pattern[t] << 4 * t
    buf[2 * k] = code & 255
    buf[2 * k + 1] = code >> 8
    return buf


def _mirror(b):
    """Mirror the unit vectors of the list ``b`` in place (``x -> -x``)."""
    for o in range(len(b)):
        v = b[o]
        b[o] = (-v[0], v[1], v[2])


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
