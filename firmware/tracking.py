"""Tracking mode: identify the observed stars from a prior attitude (no pattern search).

:func:`track` takes camera-frame unit vectors of the observed stars, **brightest first**, a
database and a prior ``q = [x, y, z, w]`` (``v_cam = A(q) v_inertial``), optionally propagated
by ``omega`` (rad/s, camera frame) over ``dt`` (s) (:func:`propagate`); angles in radians
(``docs/conventions.md``).  It predicts the catalogue stars, matches them to the observed
ones directly (a prior within the tolerance) or else by displacement consensus (robust to a
prior off by up to ``search_rad``), refines by least squares (``attitude.refine``) and nearest
neighbour, and verifies as lost-in-space does.  Returns a :class:`TrackSolution`; ``NO_MATCH``
tells the pipeline to fall back to lost-in-space.  Never raises for bad data.  Steps and the
result's fields: ``docs/centroids_and_tracking.md`` (Tracking).  Pure Python for CPython and
MicroPython (``math``, ``array``).
"""

import math
from array import array

from . import attitude
from . import status as S
from .emit import native
from .geometry import FLOAT_CODE, is_number, is_unit_tuple, residual2, unit, vector3, within_cone
from .quaternion import from_rotation_vector, matrix, multiply, unit_quaternion
from .starid.search import Solution, streak_weights, streaks_valid
from .starid.verify import (
    chance_agreement,
    chord_of_angle,
    fov_solid_angle,
    in_region,
    near_pairs,
    x_order,
)

DEFAULT_SEARCH_RAD = 0.00524
"""Largest expected error of the (propagated) prior, rad (0.3 deg)."""
DEFAULT_TOLERANCE_RAD = 3.4e-4
"""Fine match radius, rad (2.5 px of estcube2)."""
DEFAULT_MIN_MATCHES = 4
"""Fewest matched stars for an accepted solution."""
DEFAULT_MAX_MISMATCH_PROB = 1e-6
"""Largest accepted chance-agreement probability (one hypothesis: the prior)."""
DEFAULT_COARSE_STARS = 16
"""Brightest observed stars used by the coarse association."""
DEFAULT_ITERATIONS = 4
"""Most fit / predict / match rounds."""
SLACK_TOL = 0.5
"""How far (in match tolerances) a steady frame's fit may turn from the prior for its
matches to be confirmed from the prior's candidates (:func:`confirm`) instead of a new
prediction: the direct match keeps every pair within ``1 + 2 SLACK_TOL`` tolerances, which
holds every pair such a turn (it moves each star by at most its angle) can bring within
one."""


class TrackSolution(Solution):
    """Result of :func:`track`: a :class:`~lodestar.firmware.starid.search.Solution`
    (``patterns_tried`` 0, one hypothesis: the prior) plus ``q_predicted``, ``n_predicted``
    and ``residual_rad`` (``docs/centroids_and_tracking.md``).  ``residual``: ``(observed,
    database, q, pairs, cone)`` of :func:`residual_rms`, which ``residual_rad`` computes
    when first read (the flight pipeline never reads it: 2 ms of F401 time a frame saved),
    or None."""

    @native
    def __init__(self, status, q=None, matches=None, star_ids=None, probability=1.0,
                 q_predicted=None, n_predicted=0, residual=None):
        Solution.__init__(self, status, q=q, matches=matches, probability=probability,
                          hypotheses=1 if q_predicted is not None else 0, star_ids=star_ids)
        self.q_predicted = q_predicted
        self.n_predicted = n_predicted
        self._residual = residual

    @property
    def residual_rad(self):
        """RMS angle (rad) between the matched observed and catalogue stars at the fitted
        attitude, or None (computed once, then kept)."""
        r = self._residual
        if isinstance(r, tuple):
            r = self._residual = residual_rms(r[0], r[1], r[2], r[3], r[4])
        return r


# --------------------------------------------------------------------------------------
# Propagation
# --------------------------------------------------------------------------------------

@native
def propagate(q, omega=None, dt=None):
    """The attitude ``dt`` seconds after ``q`` at constant body rate ``omega`` (rad/s, camera
    frame): ``R(-omega dt) (x) q``; ``q`` itself (normalised) when ``omega`` or ``dt`` is
    None.  None when ``q``, ``omega`` or ``dt`` is malformed."""
    q = unit_quaternion(q)
    if q is None:
        return None
    if omega is None or dt is None:
        return q
    w = vector3(omega)
    if w is None or not is_number(dt):
        return None
    d = from_rotation_vector((-w[0] * dt, -w[1] * dt, -w[2] * dt))
    return unit_quaternion(multiply(d, q))


# --------------------------------------------------------------------------------------
# Prediction and matching
# --------------------------------------------------------------------------------------

CONE_REUSE_RAD = 0.00873
"""Extra radius (rad, 0.5 deg) of a :class:`Cone`'s query: the stars it holds serve every
later frame whose cone lies inside it, so a tracker turning at 1 deg/s at 10 Hz queries the
database about once in five frames (about 8 % more stars each frame to project)."""


CONE_LEAD = 0.8
"""How far ahead of the next frame's boresight, in :data:`CONE_REUSE_RAD`, the idle-time
hook centres a cone it refills (:meth:`Tracker.prefetch`): the next frame lies 0.4 deg
behind its centre, within the margin, and the boresight then moves about 0.9 deg before the
cone stops covering it: at 1 deg/s across the boresight the hook refilled 3 times in 39
frames instead of 6 (``tests/firmware/test_tracking.py``), each 12-24 ms of the F401's idle
time plus its collection (``docs/mcu_board.md``)."""


def _lead_s(omega):
    """Seconds the boresight takes to move ``CONE_LEAD * CONE_REUSE_RAD`` at body rate
    ``omega`` (rad/s, camera frame: its ``x, y`` turn the boresight); 0 without a rate
    across it.  The boresight's inertial speed is constant at a constant body rate, so it
    moves at most that far (its path curves under a roll)."""
    if omega is None:
        return 0.0
    w = vector3(omega)
    if w is None:
        return 0.0
    cross = math.sqrt(w[0] * w[0] + w[1] * w[1])
    return CONE_LEAD * CONE_REUSE_RAD / cross if cross > 0 else 0.0


class Cone:
    """The catalogue stars around a boresight (:func:`candidates`), kept between frames by a
    tracker: the ``database``, the query's ``centre`` (unit vector) and ``radius`` (rad),
    ``ids`` (``array('H')`` star indices, ascending), ``vecs`` (``array('f')`` inertial
    vectors ``x, y, z`` per star, the database's float32 values exactly), ``stars`` (``(ids,
    vecs)``: predicted stars for :func:`~lodestar.firmware.starid.verify.near_pairs`),
    ``where`` (each star's position in them: a fit looks its stars up there, a binary
    search would cost more than the fit), ``order`` (their
    :func:`~lodestar.firmware.starid.verify.x_order`: the direct match searches them in the
    inertial frame) and ``solid_angle`` (sr; with their count, the catalogue's density
    around the boresight).  Empty (``ids`` None) after :meth:`clear`, its heap then free."""

    __slots__ = ("database", "centre", "radius", "ids", "vecs", "stars", "where", "order",
                 "solid_angle")

    def __init__(self):
        self.clear()

    def clear(self):
        self.database = self.centre = self.ids = self.vecs = self.stars = None
        self.where = self.order = None
        self.radius = self.solid_angle = 0.0

    def covers(self, database, d, radius):
        """True when the held stars include every star within ``radius`` of ``d``: the same
        database, and ``angle(centre, d) + radius <= self.radius`` (tested on the chord,
        accurate in single precision)."""
        if self.ids is None or database is not self.database or not radius <= self.radius:
            return False
        return within_cone(self.centre, self.radius, d, radius)

    def star_vector(self, database, s):
        """Inertial vector of star ``s``: held, else read from ``database``."""
        where = self.where
        i = where.get(s) if where is not None else None
        if i is None:
            return database.star_vector(s)
        vecs = self.vecs
        return vecs[3 * i], vecs[3 * i + 1], vecs[3 * i + 2]

    @native
    def star_vectors(self, database, pairs):
        """:meth:`star_vector` of each star of ``pairs`` (``[(observed index, star)]``), as
        a list: one call for a fit's stars, not one per star."""
        where, vecs = self.where, self.vecs
        out = [None] * len(pairs)
        for k in range(len(pairs)):
            s = pairs[k][1]
            i = where.get(s) if where is not None else None
            if i is None:
                out[k] = database.star_vector(s)
            else:
                j = 3 * i
                out[k] = (vecs[j], vecs[j + 1], vecs[j + 2])
        return out


@native
def candidates(database, q, margin_rad, cone=None, ahead=None):
    """A :class:`Cone` of the catalogue stars within the FOV's half-diagonal plus
    ``margin_rad`` of the boresight of ``q``: the stars :func:`predict` can find at any
    attitude within ``margin_rad`` of ``q`` (one cone query, reused).  ``cone``: the
    :class:`Cone` to return when it covers them, else to refill (queried
    :data:`CONE_REUSE_RAD` wider; a superset changes nothing :func:`predict` returns),
    centred on the boresight of ``propagate(*ahead)`` when ``ahead`` is given (within that
    margin of ``q``'s: :meth:`Tracker.prefetch`; propagated only for a refill); None: a new
    one."""
    m = matrix(q)
    d = (m[6], m[7], m[8])
    radius = 0.5 * database.fov_diag + margin_rad
    if cone is None:
        cone = Cone()
    elif cone.covers(database, d, radius):
        return cone
    else:
        cone.clear()                                # its heap is free for the new query
        radius += CONE_REUSE_RAD
        if ahead is not None:
            m = matrix(propagate(*ahead))
            d = (m[6], m[7], m[8])
    found = []                                     # filled by the same read as the ids
    ids = array("H", database.stars_in_cone(d, radius, vecs=found))
    vecs = array("f", found)
    found = None
    where = dict.fromkeys(ids)      # sized once (no rehash as it fills), then each slot set
    for i in range(len(ids)):
        where[ids[i]] = i
    cone.database, cone.centre, cone.radius = database, d, radius
    cone.ids, cone.vecs, cone.stars, cone.where = ids, vecs, (ids, vecs), where
    cone.order = x_order(vecs, len(ids))
    cone.solid_angle = 4.0 * math.pi * math.sin(0.5 * radius) ** 2     # 2 pi (1 - cos r)
    return cone


@native
def predict(database, q, margin_rad=0.0, cone=None):
    """Catalogue stars in the FOV at attitude ``q`` (a unit quaternion):
    ``(predicted, n_fov)`` with ``predicted`` the stars inside the FOV rectangle widened by
    ``margin_rad`` on every side (``(ids, vecs)``, as
    :func:`lodestar.firmware.starid.verify.predicted_stars`) and ``n_fov`` the number of them
    inside the plain rectangle.  ``cone``: the :func:`candidates` to consider (None: a cone
    query around ``q``)."""
    m = matrix(q)
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = m
    tan_h = math.tan(0.5 * database.fov_h)
    tan_v = math.tan(0.5 * database.fov_v)
    tan_hm = math.tan(0.5 * database.fov_h + margin_rad)
    tan_vm = math.tan(0.5 * database.fov_v + margin_rad)
    if cone is None:
        cone = candidates(database, q, margin_rad)
    ids, vecs = cone.ids, cone.vecs
    n = len(ids)
    keep = array("H", range(n))             # the kept stars, compacted (sized by the range)
    cam = array(FLOAT_CODE, range(3 * n))   # and their camera-frame vectors
    n_out = n_fov = 0
    for i in range(n):
        j = 3 * i
        r0, r1, r2 = vecs[j], vecs[j + 1], vecs[j + 2]
        z = m6 * r0 + m7 * r1 + m8 * r2
        if z <= 0.0:
            continue
        x = m0 * r0 + m1 * r1 + m2 * r2
        lim = tan_hm * z
        if x > lim or -x > lim:         # abs(x) > lim without the call to abs
            continue
        y = m3 * r0 + m4 * r1 + m5 * r2
        lim = tan_vm * z
        if y > lim or -y > lim:
            continue
        keep[n_out] = ids[i]
        j = 3 * n_out
        cam[j], cam[j + 1], cam[j + 2] = x, y, z
        n_out += 1
        lim = tan_h * z
        if -lim <= x <= lim:
            lim = tan_v * z
            if -lim <= y <= lim:
                n_fov += 1
    return (keep[:n_out], cam[:3 * n_out]), n_fov


@native
def _claim(near):
    """The matching rule of :func:`match_nearest` over ``near``, a list of ``(observed
    index, star index, squared distance)`` of the pairs within their match regions, in
    observed then star order: ``[(observed index, star index)]``."""
    claimed = {}
    pairs = []
    best, best_d2, second, current = -1, 0.0, False, -1
    for o, s, d2 in near:
        if o != current:
            if best >= 0 and not second:
                claimed[best] = current
                pairs.append((current, best))
            best, second, current = -1, False, o
        if s in claimed:
            continue
        if best >= 0:
            second = True
        if best < 0 or d2 <= best_d2:
            best, best_d2 = s, d2
    if best >= 0 and not second:
        pairs.append((current, best))
    return pairs


@native
def match_nearest(observed, predicted, tolerance_rad, streaks=None, slack_rad=None,
                  order=None):
    """Unique nearest-neighbour matches ``[(observed index, star index)]`` (sorted by observed
    index) closer than ``tolerance_rad`` (or within the region stretched along a star's
    track, ``streaks``: :func:`lodestar.firmware.starid.verify.in_region`): observed stars in
    order (brightest first) take the nearest unclaimed predicted star; a star with a second
    unclaimed prediction within tolerance is left unnamed.  ``slack_rad``: also return the
    candidates, ``(pairs, candidates)``: every ``(observed index, star index)`` within
    ``tolerance_rad + 2 slack_rad`` (:func:`confirm` re-tests them at an attitude within
    ``slack_rad`` of the prediction's).  ``order``: as for
    :func:`lodestar.firmware.starid.verify.near_pairs`."""
    ids = predicted[0]
    lim = chord_of_angle(tolerance_rad)
    radius = tolerance_rad if slack_rad is None else tolerance_rad + 2.0 * slack_rad
    near = []
    candidates = [] if slack_rad is not None else None
    for o, p, dx, dy, dz in near_pairs(observed, predicted, radius, streaks=streaks,
                                       order=order):
        if candidates is not None:
            candidates.append((o, ids[p]))
            if not in_region(dx, dy, dz, streaks[o] if streaks is not None else None, lim):
                continue
        near.append((o, ids[p], dx * dx + dy * dy + dz * dz))
    pairs = _claim(near)
    return pairs if candidates is None else (pairs, candidates)


@native
def confirm(observed, database, q, candidates, tolerance_rad, streaks=None, cone=None):
    """:func:`match_nearest` at attitude ``q`` from the ``candidates`` it returned at an
    attitude within its ``slack_rad`` of ``q``: the same matches as predicting anew, from
    the few stars that can be in a match region (a star moves by at most the turn between
    the two attitudes).  ``cone``: as for :func:`fit`."""
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = matrix(q)
    lim = chord_of_angle(tolerance_rad)
    near = []
    last, streak = -1, None
    where = cone.where if cone is not None else None     # Cone.star_vector, inline
    vecs = cone.vecs if cone is not None else None
    for o, s in candidates:
        i = where.get(s) if where is not None else None
        if i is None:
            r0, r1, r2 = database.star_vector(s)
        else:
            j = 3 * i
            r0, r1, r2 = vecs[j], vecs[j + 1], vecs[j + 2]
        v = observed[o]
        dx = v[0] - (m0 * r0 + m1 * r1 + m2 * r2)
        dy = v[1] - (m3 * r0 + m4 * r1 + m5 * r2)
        dz = v[2] - (m6 * r0 + m7 * r1 + m8 * r2)
        if o != last and streaks is not None:       # candidates are grouped by o
            last, streak = o, streaks[o]
        if in_region(dx, dy, dz, streak, lim):
            near.append((o, s, dx * dx + dy * dy + dz * dz))
    return _claim(near)


@native
def _to_inertial(vectors, q, m=None):
    """Camera-frame ``vectors`` turned into the inertial frame by attitude ``q``: ``A^T v``
    (distances and in-region tests are the same in either frame); ``m``: ``matrix(q)``
    when the caller has it."""
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = matrix(q) if m is None else m
    out = []
    for v in vectors:
        x, y, z = v[0], v[1], v[2]
        out.append((m0 * x + m3 * y + m6 * z, m1 * x + m4 * y + m7 * z,
                    m2 * x + m5 * y + m8 * z))
    return out


@native
def _streaks_to_inertial(streaks, q, m=None):
    """``streaks`` with each track's tangent turned as :func:`_to_inertial` (None stays),
    each turned track made once (no list of turned tangents to extend: 0.5 KB a frame);
    ``m``: ``matrix(q)`` when the caller has it."""
    if streaks is None:
        return None
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = matrix(q) if m is None else m   # one for every track
    out = []
    for st in streaks:
        if st is None:
            out.append(None)
        else:
            x, y, z = st[0], st[1], st[2]
            out.append((m0 * x + m3 * y + m6 * z, m1 * x + m4 * y + m7 * z,
                        m2 * x + m5 * y + m8 * z, st[3]))
    return out


@native
def _within(q, q0, angle):
    """True when the rotation from ``q0`` to ``q`` (unit quaternions) is at most ``angle``
    rad: the vector part of their quotient is ``sin(angle / 2)``."""
    w, w0 = q[3], q0[3]
    vx = w0 * q[0] - w * q0[0] - (q0[1] * q[2] - q0[2] * q[1])
    vy = w0 * q[1] - w * q0[1] - (q0[2] * q[0] - q0[0] * q[2])
    vz = w0 * q[2] - w * q0[2] - (q0[0] * q[1] - q0[1] * q[0])
    h = math.sin(0.5 * angle)
    return vx * vx + vy * vy + vz * vz <= h * h


@native
def coarse_match(observed, predicted, search_rad, cluster_rad, max_stars):
    """Displacement-consensus association (step 4 of ``docs/centroids_and_tracking.md``):
    ``[(observed index, star index)]``."""
    n = len(observed) if len(observed) < max_stars else max_stars
    cands = list(near_pairs(observed, predicted, search_rad, n))    # (o, p, dx, dy, dz)
    if not cands:
        return []
    c2 = cluster_rad * cluster_rad
    best = -1
    best_count = 0
    for i in range(len(cands)):
        _, _, ax, ay, az = cands[i]
        count = 0
        last_o = -1
        for j in range(len(cands)):
            o, _, bx, by, bz = cands[j]
            if o == last_o:
                continue
            dx = ax - bx
            dy = ay - by
            dz = az - bz
            if dx * dx + dy * dy + dz * dz <= c2:
                count += 1
                last_o = o              # candidates are grouped by o: count o once
        if count > best_count:
            best = i
            best_count = count
    _, _, ax, ay, az = cands[best]
    chosen = {}             # o -> (distance^2 to the consensus displacement, p)
    for o, p, bx, by, bz in cands:
        dx = ax - bx
        dy = ay - by
        dz = az - bz
        d2 = dx * dx + dy * dy + dz * dz
        if d2 <= c2:
            prev = chosen.get(o)
            if prev is None or d2 < prev[0]:
                chosen[o] = (d2, p)
    used = {}
    pairs = []
    for o in range(n):
        e = chosen.get(o)
        if e is None or e[1] in used:
            continue
        used[e[1]] = o
        pairs.append((o, predicted[0][e[1]]))
    return pairs


@native
def fit(observed, database, pairs, q, weights=None, cone=None):
    """Least-squares attitude of ``pairs`` ``[(observed index, star index)]`` refined from
    ``q`` (:func:`lodestar.firmware.attitude.refine`: the pairs were matched near ``q``), or
    None when the geometry is degenerate (fewer than two pairs, all parallel).  ``cone``:
    the :func:`candidates` to take catalogue vectors from (None, or a star not among them:
    read from the database)."""
    if len(pairs) < 2:
        return None
    b = [observed[o] for o, s in pairs]
    if cone is None:
        r = [database.star_vector(s) for o, s in pairs]
    else:
        r = cone.star_vectors(database, pairs)
    w = None if weights is None else [weights[o] for o, s in pairs]
    try:
        return attitude.refine(q, b, r, w)
    except (ValueError, ZeroDivisionError):
        return None


@native
def residual_rms(observed, database, q, pairs, cone=None):
    """RMS angle (rad) between matched observed stars and their catalogue stars at ``q``
    (``cone``: as for :func:`fit`)."""
    if not pairs:
        return None
    m = matrix(q)
    total = 0.0
    for o, s in pairs:
        r = database.star_vector(s) if cone is None else cone.star_vector(database, s)
        total += residual2(m, observed[o], r)
    return math.sqrt(total / len(pairs))


@native
def _unit_vectors(vectors):
    """Unit tuples of ``vectors`` (a unit tuple is shared), or None unless
    it is a sequence of finite, non-zero 3-vectors of numbers."""
    out = []
    try:
        for v in vectors:
            if is_unit_tuple(v):
                u = v                       # shared, not copied
            else:
                u = vector3(v)
                u = None if u is None else unit(u)
            if u is None:
                return None
            out.append(u)
    except TypeError:
        return None
    return out


# --------------------------------------------------------------------------------------
# Entry point
# --------------------------------------------------------------------------------------

def track(vectors, database, q_prior, omega=None, dt=None, tolerance_rad=DEFAULT_TOLERANCE_RAD,
          search_rad=DEFAULT_SEARCH_RAD, min_matches=DEFAULT_MIN_MATCHES,
          max_mismatch_prob=DEFAULT_MAX_MISMATCH_PROB, coarse_stars=DEFAULT_COARSE_STARS,
          iterations=DEFAULT_ITERATIONS, weights=None, streaks=None, cone=None):
    """Identify ``vectors`` (camera frame, brightest first) from the prior ``q_prior``
    propagated by ``omega`` (rad/s) over ``dt`` (s); returns a :class:`TrackSolution`.

    ``weights`` (one positive number per observed star, e.g. ``sigma**-2``) weight the QUEST
    fits; None: equal (or :func:`lodestar.firmware.starid.search.streak_weights`).  ``streaks``:
    per star None or its partly seen track (:mod:`lodestar.firmware.starid.verify`): the fine
    matching and the probability use its stretched region.  See ``docs/centroids_and_tracking.md``
    for the algorithm and the statuses.  ``cone``: a :class:`Cone` kept between calls (the
    catalogue stars around the boresight are then read once per several frames).  A
    :class:`Tracker` kept between calls does the same without allocating itself each time.
    """
    try:
        tracker = Tracker(tolerance_rad, search_rad, min_matches, max_mismatch_prob,
                          coarse_stars, iterations, cone)
    except MemoryError:
        return TrackSolution(S.OUT_OF_MEMORY)
    return tracker.track(vectors, database, q_prior, omega, dt, weights, streaks)


class Tracker:
    """:func:`track` with its settings fixed (``tol``: the match tolerance, ``search``: the
    search radius, rad; ``cone``: a :class:`Cone` or None), kept between frames by a flight
    tracker.  While :meth:`track` runs it also holds the frame's ``database``, observed unit
    vectors ``b``, ``weights``, ``streaks``, the propagated prior ``q_pred`` and the
    ``slack`` of the direct match (:data:`SLACK_TOL` tolerances, rad), which its steps
    share."""

    __slots__ = ("tol", "search", "min_matches", "max_prob", "coarse_stars", "iterations",
                 "cone", "database", "b", "weights", "streaks", "q_pred", "slack")

    def __init__(self, tolerance_rad=DEFAULT_TOLERANCE_RAD, search_rad=DEFAULT_SEARCH_RAD,
                 min_matches=DEFAULT_MIN_MATCHES, max_mismatch_prob=DEFAULT_MAX_MISMATCH_PROB,
                 coarse_stars=DEFAULT_COARSE_STARS, iterations=DEFAULT_ITERATIONS, cone=None):
        self.tol = tolerance_rad
        self.search = search_rad
        self.min_matches = min_matches
        self.max_prob = max_mismatch_prob
        self.coarse_stars = coarse_stars
        self.iterations = iterations
        self.cone = cone
        self.database = self.b = self.weights = self.streaks = self.q_pred = None
        self.slack = 0.0

    @native
    def track(self, vectors, database, q_prior, omega=None, dt=None, weights=None,
              streaks=None):
        """:func:`track` of these arguments with this tracker's settings; never raises."""
        cone = self.cone
        try:
            return self._track(vectors, database, q_prior, omega, dt, weights, streaks)
        except MemoryError:
            return TrackSolution(S.OUT_OF_MEMORY)
        except Exception:   # a database read error or a bug must not reach the flight loop
            return TrackSolution(S.INTERNAL_ERROR)
        finally:            # the frame's data is dropped, and a cone made for it
            self.database = self.b = self.weights = self.streaks = self.q_pred = None
            self.cone = cone

    def prefetch(self, database, q_prior, omega=None, dt=None):
        """Make now the cone that :meth:`track` of ``q_prior`` (propagated by ``omega``,
        ``dt``) will use, when the held one does not cover it: the frame's one database
        query (:func:`candidates`), moved into the flight loop's idle time after the frame
        before.  A refill of a kept cone is centred :data:`CONE_LEAD` of its margin ahead of
        that frame's boresight along its motion (:func:`_lead_s`), so it serves the frames
        after it twice as long.  Bounded (one cone query); the next frame checks coverage
        itself, so a frame whose prior differs queries its own cone.  Never raises:
        ``S.OK``, ``S.BAD_INPUT`` (a malformed prior, rate or interval), else
        ``S.OUT_OF_MEMORY`` or ``S.INTERNAL_ERROR`` with the cone emptied (the next frame
        then queries it)."""
        try:
            q = propagate(q_prior, omega, dt)
            if q is None:
                return S.BAD_INPUT
            lead = _lead_s(omega)
            ahead = (q_prior, omega, lead if dt is None else dt + lead) if lead > 0 else None
            self.cone = candidates(database, q, self._reach(), self.cone, ahead)
            return S.OK
        except MemoryError:
            status = S.OUT_OF_MEMORY
        except Exception:   # a database read error or a bug must not reach the flight loop
            status = S.INTERNAL_ERROR
        if self.cone is not None:
            self.cone.clear()
        return status

    def _reach(self):
        """The margin (rad) of a frame's cone beyond the FOV: every attitude its fits may
        reach (the search radius of the prior) plus a tolerance, on both sides."""
        return 2.0 * self.search + 2.0 * self.tol

    @native
    def _fail(self, status, n_fov=0):
        return TrackSolution(status, q_predicted=self.q_pred, n_predicted=n_fov)

    @native
    def _track(self, vectors, database, q_prior, omega, dt, weights, streaks):
        tol, search = self.tol, self.search
        if not (is_number(tol) and tol > 0 and is_number(search) and search >= 0 and
                is_number(self.max_prob) and self.min_matches >= 2 and self.coarse_stars >= 2):
            return TrackSolution(S.BAD_INPUT)
        self.q_pred = q_pred = propagate(q_prior, omega, dt)
        if q_pred is None:
            return TrackSolution(S.BAD_INPUT)
        self.b = b = _unit_vectors(vectors)
        if b is None:
            return TrackSolution(S.BAD_INPUT)
        if weights is not None and len(weights) != len(b):
            return TrackSolution(S.BAD_INPUT)
        if not streaks_valid(streaks, len(b)):
            return TrackSolution(S.BAD_INPUT)
        self.weights = weights if weights is not None else streak_weights(streaks, tol)
        self.streaks = streaks
        self.database = database
        if len(b) < self.min_matches:
            return TrackSolution(S.TOO_FEW_STARS, q_predicted=q_pred)

        # one cone query serves every prediction below (the fitted attitudes stay within the
        # search radius of the prior)
        self.cone = cone = candidates(database, q_pred, self._reach(), self.cone)
        # steady state: the prior is within the match tolerance, so match at it directly, in
        # the inertial frame: the observed stars turned back by the prior against the cone's
        # stars (sorted once per cone), the catalogue's density from the cone
        self.slack = SLACK_TOL * tol
        m = matrix(q_pred)              # one matrix turns the stars and their tracks
        pairs, near = match_nearest(_to_inertial(b, q_pred, m), cone.stars, tol,
                                    _streaks_to_inertial(streaks, q_pred, m), self.slack,
                                    order=cone.order)
        m = None
        n_fov = len(cone.ids) * fov_solid_angle(database.fov_h, database.fov_v) / \
            cone.solid_angle
        if len(pairs) >= self.min_matches:
            sol = self._settle(q_pred, pairs, n_fov, near=near)
            if sol.status == S.OK:
                return sol
        near = None
        # coarse association: the prior may be off by up to the search radius
        predicted, n_fov = predict(database, q_pred, search, cone)
        spread = 2.0 * math.sin(0.5 * database.fov_diag) * search      # roll error, field
        pairs = coarse_match(b, predicted, search, 2.0 * tol + spread, self.coarse_stars)
        predicted = None
        if len(pairs) < 2:
            return self._fail(S.NO_MATCH, n_fov)
        return self._settle(q_pred, pairs, n_fov, coarse=True)

    @native
    def _settle(self, q, pairs, n_fov, coarse=False, near=None):
        """Fit ``pairs`` from ``q``, then predict, match and refit at the fitted attitude while
        the matches change; verify the final set as lost-in-space does.  ``n_fov``: the stars
        predicted inside the FOV at ``q``; ``coarse``: ``pairs`` are a coarse association, never
        final (the fine matching always runs at least once); ``near``: the candidates of
        :func:`match_nearest` at ``q``, which confirm a fit's matches while it lies within
        ``slack`` of ``q`` (``n_fov`` then stays the direct match's, from the cone's density);
        each new prediction gives the candidates of the fits after it (:func:`confirm`: the
        same matches as predicting anew)."""
        b, database, cone = self.b, self.database, self.cone     # (more than three: a tuple)
        tol, streaks = self.tol, self.streaks
        q0 = q
        q = fit(b, database, pairs, q, self.weights, cone)
        if q is None:
            return self._fail(S.NO_MATCH, n_fov)
        if coarse:
            pairs = None
        converged = False
        for _ in range(self.iterations):
            if near is not None and _within(q, q0, self.slack):
                new = confirm(b, database, q, near, tol, streaks, cone)
            else:               # a new prediction, whose candidates serve the next fits
                predicted, n_fov = predict(database, q, 2.0 * tol, cone)
                new, near = match_nearest(b, predicted, tol, streaks, self.slack)
                predicted, q0 = None, q
            if new == pairs:
                converged = True        # the matches at q are pairs: the check below holds
                break
            q_new = fit(b, database, new, q, self.weights, cone)
            if q_new is None:
                break
            pairs = new
            q = q_new
        if pairs is None or len(pairs) < 2:
            return self._fail(S.NO_MATCH, n_fov)
        # the reported matches must hold at the returned attitude
        final = pairs
        if not converged:
            predicted, n_fov = predict(database, q, 2.0 * tol, cone)
            final = match_nearest(b, predicted, tol, streaks)
        predicted = None
        if final != pairs:
            keep = {}
            for pair in final:
                keep[pair] = 1
            pairs = [pair for pair in pairs if pair in keep]
            q2 = fit(b, database, pairs, q, self.weights, cone)
            if q2 is None:
                return self._fail(S.NO_MATCH, n_fov)
            q = q2
        omega_fov = fov_solid_angle(database.fov_h, database.fov_v)
        _p, prob = chance_agreement(n_fov, omega_fov, tol, len(b), len(pairs), streaks)
        matches = [(o, database.star_hip(s)) for o, s in pairs]
        status = S.OK if len(pairs) >= self.min_matches and prob < self.max_prob else S.NO_MATCH
        return TrackSolution(status, q=q if status == S.OK else None,
                             matches=matches if status == S.OK else [],
                             star_ids=list(pairs) if status == S.OK else [], probability=prob,
                             q_predicted=self.q_pred, n_predicted=n_fov,
                             residual=(b, database, q, pairs, cone))
