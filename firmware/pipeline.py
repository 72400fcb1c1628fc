"""The flight API: one FPGA packet in, one attitude (or a status) out; never raises.

    tracker = StarTracker("/flash/stars.lsdb", camera_dict, Settings(exposure_s=0.1))
    result = tracker.process(packet_bytes, prior=None, omega=gyro_rad_s, dt=None,
                             velocity_km_s=None)

Stages, :class:`Result` fields, statuses and the attitude epoch: ``docs/firmware.md``; units
and frames: ``docs/conventions.md``.  Configuration errors found at construction are returned
by every call; malformed optional inputs (``prior``, ``omega``, ``dt``, ``exposure_s``) are
ignored with a note in ``reason`` (``velocity_km_s``: the observer's, for the aberration,
``docs/apparent_directions.md``); a ``MemoryError`` becomes ``OUT_OF_MEMORY`` and any other
unexpected exception ``INTERNAL_ERROR``, so the flight loop always gets a result.
Pure Python for CPython and MicroPython: no numpy, typing, dataclasses or itertools.
"""

import gc
import math
import sys
from array import array

from lodestar.contract.detection import REGISTER_BY_NAME
from lodestar.contract.packet import (
    FRAME_LABEL_OVERFLOW,
    FRAME_LINE_ERROR,
    FRAME_RECORD_OVERFLOW,
    FRAME_TIMEOUT,
    FRAME_TRUNCATED,
)

from . import attitude as _attitude
from . import camera as _camera
from . import centroids, packet, starid, tracking
from . import database as _database
from . import geometry as G
from . import quaternion as Q
from . import screen as _screen
from . import smear as _smear
from . import status as S
from .emit import native
from .geometry import RAD_TO_ARCSEC
from .settings import Settings
from .starid import verify

FLOOR_SHARES = (0.0, 0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.75, 1.0)
"""Candidate shares ``rho`` of the noise floor in a median-flux star's centroid variance
(``0``: photon limited, ``1``: every star alike)."""
MIN_STARS_NOISE_MODEL = 6
"""Fewest matched stars whose residuals choose the floor share; fewer use ``rho = 0``."""
FLOOR_MAX_SMEAR_PX = 2.0
"""Longest expected smear (px) at which the residuals may choose a noise floor: smeared
stars' residuals are dominated by along-track errors a floor does not describe, and
weighting the faint stars up makes the attitude worse (``docs/firmware.md``)."""
FLOOR_EVIDENCE = 1.92
"""Log-likelihood gain a floor share ``rho > 0`` must show over the photon model
(``rho = 0``) to be taken: a likelihood-ratio test at 5 % (``chi2(1)`` 95 % point 3.84,
halved)."""
INCOMPLETE_FLAGS = ((FRAME_TRUNCATED, "FRAME_TRUNCATED"), (FRAME_TIMEOUT, "FRAME_TIMEOUT"),
                    (FRAME_LINE_ERROR, "FRAME_LINE_ERROR"))
"""Frame flags that make a frame ``FRAME_INCOMPLETE``: a blob cut by the frame's end has
a partial record, and a line of the wrong length misplaces every later one."""
LOST_FLAGS = ((FRAME_RECORD_OVERFLOW, "FRAME_RECORD_OVERFLOW"),
              (FRAME_LABEL_OVERFLOW, "FRAME_LABEL_OVERFLOW"))
"""Frame flags noted in ``reason`` of a frame that is solved all the same: blobs were lost
(``dropped_records``, ``dropped_labels``), the others are whole."""
FOV_TOLERANCE = 0.02
"""Largest relative difference between the camera's and the database's horizontal FOV."""
COLLECT = sys.implementation.name == "micropython"
"""On MicroPython a :class:`StarTracker` sets ``gc.threshold`` for each frame
(:data:`GC_THRESHOLD`, :data:`TRACK_GC_THRESHOLD`) and, in a lost-in-space frame, collects
before it and at the stage boundaries of :meth:`StarTracker.process` (after the centroids,
before the identification and before the attitude fit): on an MCU's small heap this keeps
temporaries from fragmenting it, while a tracking frame's low peak needs no collection but
the threshold's (about one per frame: it allocates about 30 KB; ``docs/firmware.md``,
Memory), which the idle-time hook makes before the frame (:data:`HOOK_COLLECT_BYTES`);
CPython's own collector needs no help."""
GC_THRESHOLD = 8192
"""Bytes allocated between two collections on MicroPython in a lost-in-space frame, whose
search and fit peak high: collecting often keeps the heap from fragmenting
(``docs/firmware.md``, Memory)."""
TRACK_GC_THRESHOLD = 40960
"""The same in a tracking frame, whose live peak is a third of a lost-in-space one: fewer
collections, about 30 % fewer instructions per frame (``docs/firmware.md``, Memory).  A
fallback to lost in space goes back to :data:`GC_THRESHOLD`.  40 KiB (32 before): the
budgeted frame at 1 deg/s counts 29 KB of allocations (net 21 KB), and after the hook's
collection (:data:`HOOK_COLLECT_BYTES`) a frame of more records stays under it too; a
heap that fills first collects then, as at any threshold (the executive loop's smallest
heap over the set is unchanged, ``docs/mcu_board.md``)."""
HOOK_COLLECT_BYTES = 4096
"""The idle-time hook (:meth:`StarTracker.prefetch`) collects when at least this much was
allocated since the last collection, as :data:`TRACK_GC_THRESHOLD` counts it (every block,
a freed one or a grown list's old one included: the budgeted frame at 1 deg/s counts 29 KB
against a net 21 KB): the next tracking frame then starts its count at zero and stays under
the threshold, and the collection it would have made (about 10 ms on the F401 on the flight
heap) falls in the idle time instead (``docs/mcu_board.md``, Speed and heap of the
tracking frames).  Small: a frame that collected near its end leaves a few KB counted,
and a hook that let them pass would leave the next frame to collect again."""


SMEAR_MEMO = 48
"""Pixels whose expected smear a moving frame remembers (:func:`_memo`); the
rest are computed again when asked (about 0.1 ms each on the F401).  A frame with a rate
keeps every record's star for the joining of broken tracks, and the memo of a 100-record
frame (its keys, values and a dictionary grown to 2 KiB in one block) took the heap of a
busy frame at 1 deg/s (``docs/mcu_board.md``); the regression set's frames stay within it."""


TRACK_MARGIN_PERCENT = 85
"""The ``min_sum`` a solved frame returns admits blobs down to this share (percent) of the
``track_stars``-th brightest blob's ``s0``, which changes by a few percent from frame to
frame at rest (``docs/firmware.md``, Record budget)."""
TRACK_EXTRA_STARS = 2
"""... but no more than ``track_stars`` plus this many blobs of the frame: a group of stars
of about the same brightness at the cut cannot swell the next frame."""
WIDE_TRACK = 2
"""A budgeted frame too loose for ``max_error_arcsec`` (:meth:`StarTracker._thin`) budgets
the next for this many times ``track_stars``: few stars give a loose bound (the Student-t
tail of their residuals, :func:`tail_factor`); in a 640 x 480 window at rest tracking frames
of 8 records were ``IMPRECISE`` six in a row, with 16 each is ``OK``."""
THIN_SHARE = 0.8
"""A widened frame stays widened while its bound exceeds this share of
``max_error_arcsec``."""
MIN_SUM_MAX = (1 << REGISTER_BY_NAME["min_sum"].bits) - 1
"""Largest value of the gateware's ``min_sum`` register."""


@native
def min_sum(stars, track_stars, wide=False):
    """The ``min_sum`` register value that budgets the next frame for ``track_stars`` to
    ``track_stars +`` :data:`TRACK_EXTRA_STARS` blobs, from this frame's ``stars``
    (:class:`lodestar.firmware.centroids.Star`), each blob's ``s0`` a star's flux (of a star
    joined from ``k`` pieces, ``k`` blobs of ``1/k`` of it: the register filters pieces): the
    larger of :data:`TRACK_MARGIN_PERCENT` of the ``track_stars``-th largest and the
    ``(track_stars + TRACK_EXTRA_STARS)``-th largest.  With fewer blobs (stars left the
    field, or a budget cut too deep), half the smallest: the next frames admit fainter
    blobs until ``track_stars`` are seen again (in a sparse field, every blob after a few
    frames).  0 (every blob) without stars or with ``track_stars`` None.  Integer
    arithmetic: the same value in every float precision.  ``wide``: the pair of that value
    and the one for :data:`WIDE_TRACK` times ``track_stars`` (:meth:`StarTracker._thin`),
    from one sort of the blobs."""
    if track_stars is None or not stars:
        return (0, 0) if wide else 0
    levels = []
    for s in stars:
        v = s._v                        # (x, y, flux, ..., parts): a property is a call
        f = int(v[2])
        parts = v[11]
        if parts:
            levels += [f // len(parts)] * len(parts)
        else:
            levels.append(f)
    levels.sort()
    if wide:
        return _budget(levels, track_stars), _budget(levels, WIDE_TRACK * track_stars)
    return _budget(levels, track_stars)


@native
def _budget(levels, track_stars):
    """:func:`min_sum` of the blobs' sorted ``levels``."""
    n = len(levels)
    if n < track_stars:
        return levels[0] // 2
    level = levels[n - track_stars] * TRACK_MARGIN_PERCENT // 100
    extra = n - track_stars - TRACK_EXTRA_STARS
    if extra >= 0 and levels[extra] > level:
        level = levels[extra]
    return level if level < MIN_SUM_MAX else MIN_SUM_MAX


def _collect():
    if COLLECT:
        gc.collect()


def _collect_over(nbytes):
    """Collect when at least ``nbytes`` were allocated since the last collection (MicroPython's
    ``gc.threshold``: the next allocation collects once the count reaches it), then set the
    tracking frame's threshold again; ``S.OK``, or ``S.OUT_OF_MEMORY``."""
    if not COLLECT:
        return S.OK
    gc.threshold(nbytes)
    try:
        bytearray(1)                    # the allocation that collects, or not
    except MemoryError:
        return S.OUT_OF_MEMORY
    finally:
        gc.threshold(TRACK_GC_THRESHOLD)
    return S.OK


def _threshold(nbytes):
    if COLLECT:
        gc.threshold(nbytes)


MIN_SMEAR_STARS = 3
"""Fewest stars whose own smear is at most ``max_smear_px`` a frame must keep when others
smear beyond it; with fewer the frame is ``SMEAR_TOO_LONG`` (three is the fewest any
identification uses; a frame that has too few stars without any smeared away is
``TOO_FEW_STARS`` as ever)."""


MIN_SCREENED_STARS = 4
"""Fewest matches the match screen leaves (:meth:`StarTracker._screened`); a screen that would
leave fewer drops none (the identification's own probability stands)."""
MIN_FREEDOM = 0.1
"""Smallest ``1 - h_i`` a match's residual variance is scaled by in the match screen (a star
that is most of the fit says little about itself)."""
BOUND_SIGMAS = 5.0
"""Sigmas of the bound ``max_error_arcsec`` limits (:func:`precise`)."""
MAX_BOUNDED_SMEAR_PX = 6.0
"""Longest smear the streaks may allow (:func:`lodestar.firmware.smear.smear_bound_px`) for a
frame with too few stars to fit its rate to be solved without ``omega``: a still frame's
streaks bound its smear by about 3.5 px, and the shear this bound allows over the read-out
is folded into the sigma; beyond it the frame is ``RATE_UNKNOWN``."""


T_TAIL = (1111000.0, 1321.0, 156.7, 56.85, 31.85, 22.02, 17.11, 14.25, 12.43, 11.17, 10.26,
          9.573, 9.040, 8.614, 8.268, 7.980, 7.738, 7.531, 7.353, 7.198, 7.062, 6.941, 6.834,
          6.737)
"""The Student-t quantile of ``nu`` = 1, 2, ... degrees of freedom at the two-sided normal
tail of :data:`BOUND_SIGMAS` (2.9e-7 each side), rounded up to 4 digits
(``scipy.stats.t.isf``); beyond the table the Cornish-Fisher series of :func:`t_tail`
(within 1e-4 of it from 25)."""


def t_tail(nu):
    """:data:`T_TAIL` at ``nu`` degrees of freedom (an int >= 1)."""
    if nu <= len(T_TAIL):
        return T_TAIL[nu - 1]
    z = BOUND_SIGMAS
    z2 = z * z
    g1 = (z2 + 1.0) * z / 4.0
    g2 = ((5.0 * z2 + 16.0) * z2 + 3.0) * z / 96.0
    g3 = (((3.0 * z2 + 19.0) * z2 + 17.0) * z2 - 15.0) * z / 384.0
    g4 = ((((79.0 * z2 + 776.0) * z2 + 1482.0) * z2 - 1920.0) * z2 - 945.0) * z / 92160.0
    u = 1.0 / nu
    return z + u * (g1 + u * (g2 + u * (g3 + u * g4)))


@native
def tail_factor(nu):
    """How much a sigma scaled to the residuals' RMS grows so that :data:`BOUND_SIGMAS` of it
    is the error's bound at the normal tail (``docs/firmware.md``, Attitude): the error
    over a scale estimated from ``nu`` residual degrees of freedom is Student-t distributed,
    whose tail is far heavier than its RMS says (4 stars with a gyro, ``nu`` 5: 4.9; 8
    stars, 1.7; 30 stars, 1.1).  The RMS-scaled sigma divides by ``max(nu - 2, 1)``; the
    factor is ``sqrt(max(nu - 2, 1) / nu) t_tail(nu) / 5``.  An ``OK`` attitude is then
    within 5 of its sigma at the normal tail's odds however few stars fixed it (a blended
    pair, 4 matches at 30 deg/s, was 6.3 sigma off: ``docs/fly.md``)."""
    if nu < 1:
        nu = 1
    return math.sqrt(max(nu - 2, 1) / nu) * t_tail(nu) / BOUND_SIGMAS


@native
def error_bound(sigma_cross, sigma_roll):
    """The :data:`BOUND_SIGMAS` bound (arcsec) on the total error of an attitude of 1-sigma
    ``sigma_cross`` (each axis across the boresight) and ``sigma_roll`` (arcsec),
    ``5 sqrt(2 sigma_cross^2 + sigma_roll^2)``: each axis at its own 5 sigma."""
    return BOUND_SIGMAS * math.sqrt(2.0 * sigma_cross * sigma_cross + sigma_roll * sigma_roll)


@native
def precise(res, limit):
    """``IMPRECISE`` for the solution ``res`` whose :func:`error_bound` exceeds ``limit``
    (``Settings.max_error_arcsec``, arcsec; None: any), noted in ``reason``: an ``OK``
    attitude within 5 sigma on every axis is then within the limit in total (issue 33's two
    criteria of a wrong attitude become one).  Its attitude, matches and sigmas stay in
    ``res`` for diagnostics."""
    if limit is None:
        return
    bound = error_bound(res.sigma_cross_arcsec, res.sigma_roll_arcsec)
    if not bound <= limit:
        res.status = S.IMPRECISE
        _note(res, "{:g}-sigma bound {:.0f} arcsec beyond max_error_arcsec {:g}".format(
            BOUND_SIGMAS, bound, limit))


@native
def _longest_smear(cam, smear):
    """Longest expected smear (px) over the frame's centre and corners (a roll smears the
    corners most, a cross-boresight rate everywhere alike): when it is within the limit no
    star needs its own test."""
    longest = 0.0
    for x, y in ((cam.cx, cam.cy), (0, 0), (cam.width - 1, 0), (0, cam.height - 1),
                 (cam.width - 1, cam.height - 1)):
        d = smear(x, y)
        if d is None:                 # the track leaves the model: a huge smear
            return float("inf")
        length = math.sqrt(d[0] * d[0] + d[1] * d[1])
        if not length <= longest:
            longest = length
    return longest


SHIFT_CHI2_FACTOR = 2
"""A rate difference the streaks cannot show contradicts the gyro by its shift alone
(:func:`_shifted`) only beyond this many times the frame's ``rate_chi2_limit``: with no
streak evidence the chi-square's tail is all there is, and it is heavier than its F model
(the rate campaign at rest and 0.5 deg/s, the true gyro: 3 of 200 frames at chi-square
21-29 against a limit of 19.8, each right within 4"), while the wrong rates the rule is
for give 110 and 393."""


def _shifted(d, dts, w, solved):
    """Whether a rate difference ``d`` (rad/s, camera frame) turns the attitude ``solved``
    (:meth:`StarTracker.attitude`'s tuple) by more than its :data:`BOUND_SIGMAS` bound on
    an axis when carried from the stars' weighted mean instant to the epoch (``dts``: the
    stars' instants from the epoch, s; ``w`` their weights): the error a wrong gyro rate
    makes there, which a difference too small to trail the stars still makes."""
    total = mean = 0.0
    for i in range(len(w)):
        total += w[i]
        mean += w[i] * dts[i]
    if not total > 0:
        return False
    mean = abs(mean / total)
    cross = math.sqrt(d[0] * d[0] + d[1] * d[1]) * mean
    return cross > BOUND_SIGMAS * solved[1] or abs(d[2]) * mean > BOUND_SIGMAS * solved[2]


def _short_smears(stars, smear, limit, max_stars, rejected):
    """The first ``max_stars`` of ``stars`` (brightest first) whose own expected smear
    ``smear(x, y)`` is at most ``limit`` px: a roll smears a star in proportion to its
    distance from the boresight, so the inner stars stay usable when the corners are too
    long.  Returns ``(kept, longest kept smear in px)``; the others count as
    ``rejected["smear"]`` or, beyond ``max_stars``, ``rejected["excess"]`` (unmeasured)."""
    kept = []
    longest = 0.0
    limit2 = limit * limit
    examined = 0
    for s in stars:
        if len(kept) >= max_stars:
            break
        examined += 1
        d = smear(s.x, s.y)
        length2 = d[0] * d[0] + d[1] * d[1] if d is not None else None
        if length2 is not None and length2 <= limit2:
            kept.append(s)
            if length2 > longest:
                longest = length2
    rejected["smear"] = examined - len(kept)
    rejected["excess"] += len(stars) - examined
    return kept, math.sqrt(longest)


@native
def _fit(b, r, w, q0):
    """The attitude of pairs ``b``, ``r`` (weights ``w``, None: equal): refined from ``q0``,
    or by QUEST without one."""
    return _attitude.quest(b, r, w) if q0 is None else _attitude.refine(q0, b, r, w)


@native
def _residuals2(q, b, r):
    """Squared residuals ``|b_i - A(q) r_i|^2`` (rad^2) of camera vectors ``b`` against
    catalogue vectors ``r`` under attitude ``q`` (:func:`lodestar.firmware.geometry.residual2`'s
    arithmetic, inline: it runs for every match of every fit)."""
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = Q.matrix(q)
    out = [0.0] * len(b)
    for i in range(len(b)):
        bv, rv = b[i], r[i]
        r0, r1, r2 = rv[0], rv[1], rv[2]
        dx = bv[0] - (m0 * r0 + m1 * r1 + m2 * r2)
        dy = bv[1] - (m3 * r0 + m4 * r1 + m5 * r2)
        dz = bv[2] - (m6 * r0 + m7 * r1 + m8 * r2)
        out[i] = dx * dx + dy * dy + dz * dz
    return out


@native
def _floor_share(u, e2):
    """The share of :data:`FLOOR_SHARES` whose variances ``g_i = (1 - rho) u_i + rho`` give
    the squared residuals ``e2`` the largest likelihood (:meth:`StarTracker.noise_shares`),
    or None when the residuals are all zero.  One pass per share without a list of its
    ``g`` (the chosen one is made once by the caller, with the same arithmetic)."""
    n = len(u)
    best, best_rho = None, 0.0
    for rho in FLOOR_SHARES:
        keep = 1.0 - rho
        total = 0.0
        logs = 0.0
        prod = 1.0
        for i in range(n):
            g = keep * u[i] + rho
            total += e2[i] / g
            prod *= g
            if i & 3 == 3:              # one log per 4 stars: a product of 4 shares (each
                logs += math.log(prod)  # within 1e-9..1e9 of the median star's) stays
                prod = 1.0              # inside single precision's range
        logs += math.log(prod)
        if not total > 0:
            return None
        score = -logs - n * math.log(total) - (FLOOR_EVIDENCE if rho > 0 else 0.0)
        if best is None or score > best:
            best, best_rho = score, rho
    return best_rho


class Result:
    """Outcome of :meth:`StarTracker.process` (fields in ``docs/firmware.md``)."""

    __slots__ = ("status", "reason", "mode", "q", "t_epoch_s", "rate_rad_s",
                 "sigma_rate_rad_s", "matches", "n_stars", "n_records",
                 "sigma_cross_arcsec", "sigma_roll_arcsec", "centroid_sigma_px",
                 "patterns_tried", "probability", "rejected", "timings", "min_sum")

    @native
    def __init__(self, status, reason=""):
        self.status = status
        self.reason = reason
        self.mode = None
        self.q = None
        self.t_epoch_s = None
        self.rate_rad_s = None
        self.sigma_rate_rad_s = None
        self.matches = []
        self.n_stars = 0
        self.n_records = 0
        self.sigma_cross_arcsec = None
        self.sigma_roll_arcsec = None
        self.centroid_sigma_px = None
        self.patterns_tried = 0
        self.probability = 1.0
        self.rejected = None
        self.timings = {}
        self.min_sum = 0

    @property
    def ok(self):
        return self.status == S.OK

    @property
    def status_name(self):
        return S.name(self.status)

    def as_dict(self):
        out = {}
        for name in Result.__slots__:
            out[name] = getattr(self, name)
        out["status_name"] = S.name(self.status)
        return out

    def __repr__(self):
        return ("Result(" + S.name(self.status) + ", mode=" + repr(self.mode) + ", q=" +
                repr(self.q) + ", matches=" + str(len(self.matches)) + ", n_stars=" +
                str(self.n_stars) + ", sigma_cross_arcsec=" + repr(self.sigma_cross_arcsec) +
                ", sigma_roll_arcsec=" + repr(self.sigma_roll_arcsec) + ")")


class StarTracker:
    """The flight star tracker: a star database, a camera model and the settings.

    ``database``: a :class:`lodestar.firmware.database.Database`, a bytes-like image or a
    file path (opened with :func:`lodestar.firmware.database.load`, read by offset).
    ``camera``: a :class:`lodestar.firmware.camera.Camera` or a dict for
    :meth:`Camera.from_dict` (a ``lodestar.sim`` preset's camera block).
    ``settings``: a :class:`lodestar.firmware.settings.Settings` (None: the defaults),
    checked here (:meth:`Settings.check`, then its method against the database).

    Never raises: a configuration problem sets ``status``/``reason`` and every
    :meth:`process` returns it.
    """

    def __init__(self, database, camera, settings=None):
        self.status = S.OK
        self.reason = ""
        self.database = None
        self.camera = None
        self.settings = settings if settings is not None else Settings()
        self.track_search_rad = 0.0
        self.track_stars = None         # the record budget, at most max_stars
        self.tolerance_rad = 0.0
        self.sigma_rad = None
        self.min_sigma_rad = 0.0
        self.focal_px = 1.0
        self.beta = None
        self._cone = tracking.Cone()   # tracking's catalogue stars, kept between frames
        self._tracker = None            # tracking, with these settings and that cone
        self._frame = None              # process(): (flat second moments, exposure)
        self._last_fit = None           # the final fit's (vectors, weights), for the screen
        self._mode = None               # the frame's mode, while it is fitted
        self._held = None               # _catalogue(): (star_ids, catalogue vectors)
        self._held_w = None             # in _fit: (star_ids, photon, tracked weights)
        self._held_e2 = None            # in _fit: the last attitude()'s residuals (_outliers)
        self._lens_clean = False        # a radial check passed: tracking skips it
        _threshold(GC_THRESHOLD)
        try:
            self._configure(database, camera)
        except MemoryError:
            self._fail(S.OUT_OF_MEMORY, "configuration: out of heap")
        except Exception as exc:
            self._fail(S.INTERNAL_ERROR, "configuration: " + repr(exc))

    def _fail(self, code, reason):
        if self.status == S.OK:
            self.status = code
            self.reason = reason

    def _configure(self, database, camera):
        st = self.settings
        if not isinstance(st, Settings):
            self._fail(S.BAD_INPUT, "settings must be a firmware Settings or None")
            return
        if isinstance(camera, _camera.Camera):
            self.camera = camera
        elif isinstance(camera, dict):
            try:
                self.camera = _camera.Camera.from_dict(camera)
            except (ValueError, TypeError) as exc:
                self._fail(S.BAD_INPUT, "camera: " + str(exc))
                return
        else:
            self._fail(S.BAD_INPUT, "camera must be a firmware Camera or a dict")
            return
        code, reason = st.check()
        if code != S.OK:
            self._fail(code, reason)
            return
        cam = self.camera
        focal = math.sqrt(cam.fx * cam.fy)
        if st.velocity_km_s is not None:
            self.beta = _aberration().beta(st.velocity_km_s)
        self.focal_px = focal
        self.tolerance_rad = st.tolerance_px / focal
        self.sigma_rad = None if st.centroid_sigma_px is None else st.centroid_sigma_px / focal
        self.min_sigma_rad = st.min_sigma_px / focal
        self.track_search_rad = math.radians(st.track_search_deg)
        self._tracker = tracking.Tracker(self.tolerance_rad, self.track_search_rad,
                                          st.track_min_matches, st.track_max_prob,
                                          cone=self._cone)
        self.track_stars = st.track_stars if st.track_stars is None or \
            st.track_stars <= st.max_stars else st.max_stars
        if isinstance(database, _database.Database):
            db = database
        else:
            db, code, reason = _database.load(database)
            if db is None:
                self._fail(code, "database: " + str(code) + ": " +
                           str(reason))
                return
        self.database = db
        module = starid.method(st.method)
        if module is None:
            self._fail(S.BAD_INPUT, "unknown method " + repr(st.method))
            return
        if not db.methods & module.DATABASE_BIT:
            self._fail(S.DATABASE_UNSUPPORTED,
                       "the database does not serve method " + repr(st.method))
            return
        # per-star buffers of process(), allocated with the tracker (before any frame has
        # fragmented the heap) and reused: record index, centroid and flux of each star
        self._index = array("H", range(st.max_stars))
        self._xy = G.zeros(2 * st.max_stars)
        self._flux = G.zeros(st.max_stars)
        fov_h = _camera_fov_h(cam)
        if fov_h is None or abs(fov_h - db.fov_h) > FOV_TOLERANCE * db.fov_h:
            self._fail(S.DATABASE_MISMATCH, "database horizontal FOV " + str(db.fov_h) +
                       " rad, camera " + str(fov_h))
            return
        widest = starid.max_tolerance_rad(db.fov_h)
        if self.tolerance_rad > widest:
            self._fail(S.BAD_INPUT, "tolerance_px must be at most " + str(int(widest * focal)) +
                       " px (" + str(starid.MAX_TOLERANCE_FRACTION) + " of the field)")
            return

    # ---- stages ---------------------------------------------------------------------

    def _tick(self, timings, name, start):
        if self.settings.clock is None:
            return None
        now = self.settings.clock()
        if start is not None:
            timings[name] = now - start
        return now

    def _epoch_turn(self, omega, exposure_s):
        """``(ax, ay, az, rate, t0, row_time)``: a direction seen on row ``y`` is rotated
        back to the epoch (module docstring, stage 3) by ``rate * (t0 + y * row_time -
        epoch_s)`` rad about the unit axis ``a`` (:meth:`directions`); None without a
        rate."""
        if omega is None:
            return None
        rate = G.norm(omega)
        if not rate > 0:
            return None
        half = 0.5 * exposure_s if exposure_s is not None else 0.0
        return (omega[0] / rate, omega[1] / rate, omega[2] / rate, rate, half,
                self.settings.row_time_s)

    @native
    def directions(self, stars, omega=None, exposure_s=None):
        """Camera-frame unit vectors of ``stars`` (:class:`~lodestar.firmware.centroids.Star`)
        at the epoch: ``(vectors, used)`` with ``used`` the indices into ``stars`` of the
        stars whose pixel the camera model inverts (the others are dropped).  The turn to
        the epoch is :func:`lodestar.firmware.geometry.rotate_about`'s arithmetic inline (no
        two calls per star)."""
        cam = self.camera
        turn = self._epoch_turn(omega, exposure_s)
        if turn is not None:
            ax, ay, az, rate, half, row_time = turn
            epoch = self.settings.epoch_s
        vectors = []
        used = []
        for i in range(len(stars)):
            x, y = stars[i]._v[0], stars[i]._v[1]       # properties would cost a call each
            v = cam.pixel_to_vector(x, y)
            if v is None:
                continue
            if turn is not None:
                angle = rate * (half + y * row_time - epoch)
                c = math.cos(angle)
                s = math.sin(angle)
                vx, vy, vz = v
                k = (ax * vx + ay * vy + az * vz) * (1.0 - c)
                v = (vx * c + (ay * vz - az * vy) * s + ax * k,
                     vy * c + (az * vx - ax * vz) * s + ay * k,
                     vz * c + (ax * vy - ay * vx) * s + az * k)
            vectors.append(v)
            used.append(i)
        return vectors, used

    @native
    def streaks(self, stars, used, smear):
        """Per direction of :meth:`directions` (``used``), the partly seen track of its star
        for the identification (:mod:`lodestar.firmware.starid.verify`): None, or ``(ux, uy, uz,
        half)`` with ``u`` the camera-frame unit tangent along the expected smear
        (``smear(x, y) -> (dx, dy)`` px; :meth:`Camera.pixel_tangent`) and ``half`` the
        star's ``unseen`` track in rad; None instead of the list when no star has an unseen
        track.  The tangent is not turned to the epoch as its direction is: the turn, at
        most the rate times the frame's read-out and exposure (2e-3 rad at 1 deg/s), tilts
        the match region's axis by that angle and moves its ends by that share of ``half``
        (0.02 px of a 10 px track)."""
        cam = self.camera
        out = []
        found = False
        for i in used:
            v = stars[i]._v             # (x, y, ...): properties cost a call each
            unseen = stars[i].unseen
            streak = None
            d = smear(v[0], v[1]) if unseen > 0 else None
            length = math.sqrt(d[0] * d[0] + d[1] * d[1]) if d is not None else 0.0
            if length > 0:
                t = cam.pixel_tangent(v[0], v[1], d[0] / length, d[1] / length)
                if t is not None:
                    streak = (t[0], t[1], t[2], unseen * t[3])
                    found = True
            out.append(streak)
        return out if found else None

    @native
    def _track(self, vectors, prior, omega, dt, streaks):
        return self._tracker.track(vectors, self.database, prior, omega, dt, streaks=streaks)

    def prefetch(self, prior=None, omega=None, dt=None):
        """Idle-time work for the next frame, called by a flight loop after a frame with the
        ``prior``, ``omega`` and ``dt`` it will pass to the next :meth:`process`: the
        catalogue cone that frame's tracking would query (one bounded database query,
        ``tracking.Tracker.prefetch``), made now unless the held cone covers it; ``prior``
        None (the next frame is lost in space): the cone is dropped, its heap free for the
        search.  Then, on MicroPython, a collection when :data:`HOOK_COLLECT_BYTES` were
        allocated since the last one (the refill's garbage included): the tracking frame's
        own collection, moved into the idle time.  Optional: a frame that comes first
        queries its own cone, with the same result.  Never raises: a status (``S.OK``;
        ``S.BAD_INPUT`` for a malformed prior, rate or interval; ``S.OUT_OF_MEMORY`` or
        ``S.INTERNAL_ERROR``; a configuration failure's status)."""
        if self.status != S.OK:
            return self.status
        if prior is None:
            self._cone.clear()
            return S.OK
        code = self._tracker.prefetch(self.database, prior, omega, dt)
        if code != S.OK:
            return code
        return _collect_over(HOOK_COLLECT_BYTES)

    def identify(self, vectors, prior=None, omega=None, dt=None, streaks=None):
        """Tracking from ``prior`` (propagated by ``omega``, ``dt``), else (or on failure,
        with ``fallback``) lost-in-space: ``(solution, mode)``.  ``streaks``: per vector
        None or its partly seen track (:meth:`streaks`), or None."""
        sol = None
        mode = None
        if prior is not None:
            sol = self._track(vectors, prior, omega, dt, streaks)
            mode = "tracking"
            if sol.status == S.OK or not self.settings.fallback:
                return sol, mode
        self._cone.clear()              # lost in space: its heap goes to the search
        _threshold(GC_THRESHOLD)
        if prior is not None:           # a tracking frame falls back: collect as for one
            _collect()
        sol = starid.identify(vectors, self.database, method=self.settings.method,
                               tolerance_rad=self.tolerance_rad, budget=self.settings.budget,
                               max_work=self.settings.max_work, streaks=streaks,
                               **self.settings.id_options)
        return sol, "lost_in_space"

    @native
    def weights(self, fluxes):
        """Relative QUEST weights of stars of the given fluxes: ``flux / median``
        (1 for a missing, non-positive or non-finite flux; all 1 without
        ``flux_weighting``)."""
        n = len(fluxes)
        if not self.settings.flux_weighting:
            return [1.0] * n
        good = [f for f in fluxes if G.is_number(f) and f > 0]
        if not good:
            return [1.0] * n
        good.sort()
        k = len(good)
        median = good[k // 2] if k % 2 else 0.5 * (good[k // 2 - 1] + good[k // 2])
        if k == n:                      # every flux good (a frame's): no second test
            return [f / median for f in fluxes]
        out = []
        for f in fluxes:
            out.append(f / median if G.is_number(f) and f > 0 else 1.0)
        return out

    @native
    def noise_shares(self, b, r, photon, q0=None, fitted=False):
        """Relative centroid variances ``g_i = (1 - rho) / photon_i + rho`` of the stars
        with unit vectors ``b`` (camera) and ``r`` (catalogue) and photon-model weights
        ``photon`` (:meth:`weights`), with the floor share ``rho`` of
        :data:`FLOOR_SHARES` that maximises the likelihood of the residuals ``e_i`` of an
        equal-weight fit (per-axis Gaussian noise of variance ``s^2 g_i``, ``s``
        profiled out: maximise ``-sum(log g_i) - n log(sum(e_i^2 / g_i))``); ``rho > 0``
        must gain :data:`FLOOR_EVIDENCE` over ``rho = 0``.  Below
        :data:`MIN_STARS_NOISE_MODEL` stars, ``rho = 0``.  ``q0``: an attitude near the fit
        (:func:`lodestar.firmware.attitude.refine` from it; None: QUEST); ``fitted``: ``q0``
        is that fit already (a tracking solution's), used as it is.  Raises ``ValueError``
        when the fit is degenerate."""
        u = [1.0 / p for p in photon]
        if len(b) < MIN_STARS_NOISE_MODEL:
            return u
        e2 = _residuals2(q0 if fitted else _fit(b, r, None, q0), b, r)
        rho = _floor_share(u, e2)
        return u if rho is None else [(1.0 - rho) * ui + rho for ui in u]

    @native
    def attitude(self, vectors, star_ids, fluxes=None, floor=True, streaks=None, q0=None,
                 fitted=False):
        """Weighted least-squares attitude of ``star_ids`` ``[(vector index, database star
        index)]`` and Shuster's covariance: ``(q, sigma_cross_rad, sigma_roll_rad, s_rad)``
        (``s``: the per-axis noise of a median-flux star); None when degenerate.  ``q0``: the
        identification's attitude, refined from (:func:`lodestar.firmware.attitude.refine`,
        accurate in single precision); None: QUEST; ``fitted``: ``q0`` is the unweighted fit
        of ``star_ids`` already (:meth:`noise_shares` takes its residuals).  ``fluxes``: per
        vector (None: equal weights); ``floor``: let the residuals choose a noise floor
        (:meth:`noise_shares`; else the photon model alone); ``streaks``: per vector None
        or its partly seen track (:meth:`streaks`): the star's relative variance gains
        ``(half^2 / 6) / s0^2`` (a uniform offset over ``+-half`` along one axis is
        ``half^2 / 3``, shared by two axes; ``s0`` the configured noise or a third of the
        match tolerance), then ``s`` scales all as without tracks (no floor)."""
        n = len(star_ids)
        b = [vectors[o] for o, s in star_ids]
        r = self._catalogue(star_ids)
        extra = [0.0] * n
        if streaks is not None:
            for i in range(n):
                extra[i] = verify.streak_variance(streaks[star_ids[i][0]])
        tracks = max(extra) > 0 if n else False
        try:
            w = self._photon(star_ids, fluxes)
            if fluxes is not None:
                if floor and not tracks:
                    w = [1.0 / gi for gi in self.noise_shares(b, r, w, q0, fitted)]
            if tracks:
                # a partly seen track adds its variance in units of a median star's noise,
                # the configured one or a third of the match tolerance
                s0 = self.sigma_rad if self.sigma_rad is not None else self.tolerance_rad / 3.0
                w = [1.0 / (1.0 / w[i] + extra[i] / (s0 * s0)) for i in range(n)]
                held = self._held_w
                if held and held[0] is star_ids:    # the rate check's weights (_rate_weights)
                    self._held_w = (star_ids, held[1], w)
            q = _fit(b, r, w, q0)
            s = self.sigma_rad
            if s is None:
                e2 = _residuals2(q, b, r)
                if self._held_w is not None:    # within _fit: the screen's residuals
                    self._held_e2 = (vectors, star_ids, q, e2)
                total = 0.0
                for i in range(n):
                    total += w[i] * e2[i]
                # s^2 from 2n - 3 residual degrees of freedom: the error over the sigma it
                # scales is Student-t distributed, of variance dof / (dof - 2)
                s = math.sqrt(total / max(2 * n - 5, 1)) if n >= 2 else 0.0
                if not s >= self.min_sigma_rad:
                    s = self.min_sigma_rad
            sigmas = [s / math.sqrt(wi) for wi in w]
            cross, roll = _attitude.sigmas_cross_roll(_attitude.covariance(b, None, sigmas))
        except (ValueError, ZeroDivisionError):
            return None
        return q, cross, roll, s

    def solve_vectors(self, vectors, prior=None, omega=None, dt=None, fluxes=None,
                      result=None, velocity_km_s=None):
        """Identify and fit camera-frame unit ``vectors`` (brightest first, at the epoch;
        ``fluxes``: one per vector for the weights, or None; ``velocity_km_s``: the
        observer's, as for :meth:`process`): a :class:`Result` whose ``matches`` hold
        ``(vector index, None, None, HIP)``.  Never raises."""
        try:
            res = result if result is not None else Result(S.OK)
            beta = self._beta(velocity_km_s, res)
            if beta is not None:
                vectors = list(vectors)         # corrected in place: not the caller's list
            return self._solve_vectors(vectors, prior, omega, dt, fluxes, res, None, 0.0,
                                       None, beta)
        except MemoryError:
            return Result(S.OUT_OF_MEMORY, "out of heap")
        except Exception as exc:
            return Result(S.INTERNAL_ERROR, "internal error: " + repr(exc))

    @native
    def _beta(self, velocity_km_s, res):
        """``v / c`` (ICRS) of this frame's ``velocity_km_s``, else of the settings' (None:
        no aberration correction); a malformed one is ignored with a note."""
        if velocity_km_s is None:
            return self.beta
        b = _aberration().beta(velocity_km_s)
        if b is None:
            _note(res, "velocity_km_s ignored: not 3 finite numbers within " +
                  str(_aberration().MAX_SPEED_KM_S) + " km/s")
            return self.beta
        return b

    def _solve_vectors(self, vectors, prior, omega, dt, fluxes, result, start, smear_px,
                       streaks, beta):
        res = result if result is not None else Result(S.OK)
        if self.status != S.OK:
            res.status = self.status
            res.reason = self.reason
            return res
        timings = res.timings
        if start is None:
            start = self._tick(timings, None, None)
        res.n_stars = len(vectors)
        if prior is not None and Q.unit_quaternion(prior) is None:
            _note(res, "prior ignored: not 4 finite numbers with a non-zero norm")
            prior = None
        if prior is not None and dt is not None and not G.is_number(dt):
            _note(res, "dt ignored: not a finite number")
            dt = None
        if len(vectors) < 3:
            res.status = S.TOO_FEW_STARS
            _note(res, str(len(vectors)) + " usable stars")
            return res
        sol, mode = self.identify(vectors, prior, omega, dt, streaks)
        self._mode = mode
        start = self._tick(timings, "identify", start)
        res.mode = mode
        res.patterns_tried = sol.patterns_tried
        res.probability = sol.probability
        code = sol.status
        if code != S.OK:
            res.status = code
            _note(res, mode + ": " + S.name(code))
            if code == S.MIRRORED:
                _note(res, "the stars match the sky mirrored: flip the read-out (columns or "
                      "rows), or the camera model's x or y axis")
            return res
        if beta is not None:
            _deaberrate(vectors, sol.q, beta)
        star_ids = sol.star_ids
        # a tracking solution names its stars already (matches align with star_ids) and,
        # without tracks to weight or an aberration correction since, its attitude is their
        # unweighted fit
        hips = [hip for _o, hip in sol.matches] if mode == "tracking" else None
        q0 = sol.q
        fitted = mode == "tracking" and streaks is None and beta is None
        if mode == "lost_in_space" and self.settings.refine:
            # the identification's match set, grown to every observed star that agrees
            # (tracking from the identified attitude: it also repairs an attitude fitted to
            # a few clustered stars, which leaves the others outside the match tolerance)
            ref = self._track(vectors, sol.q, None, None, streaks)
            if ref.status == S.OK and len(ref.star_ids) > len(star_ids):
                star_ids = ref.star_ids
                hips = [hip for _o, hip in ref.matches]
                q0 = ref.q
                fitted = streaks is None
            self._cone.clear()          # not kept through a lost-in-space frame's fit
        if not star_ids:
            predicted, n_fov = tracking.predict(self.database, sol.q,
                                                 2.0 * self.tolerance_rad)
            star_ids = tracking.match_nearest(vectors, predicted, self.tolerance_rad, streaks)
            hips, fitted = None, False
        sol = ref = predicted = None     # only star_ids goes on to the fit
        if mode == "lost_in_space":
            _collect()
        status, solved, again = self._fit(res, vectors, star_ids, fluxes,
                                          smear_px <= FLOOR_MAX_SMEAR_PX, streaks, q0, fitted,
                                          omega)
        if again is not star_ids:
            star_ids, hips = again, None
        if status != S.OK:
            res.status = status
            return res
        q, cross, roll, sigma = solved
        if self.sigma_rad is None:      # the scale came from the residuals: their tail
            g = tail_factor(2 * len(star_ids) -
                            (6 if res.sigma_rate_rad_s is not None else 3))
            cross *= g
            roll *= g
        res.status = S.OK
        res.centroid_sigma_px = sigma * self.focal_px
        res.q = q
        if hips is None:
            db = self.database
            hips = [db.star_hip(s) for _o, s in star_ids]
        res.matches = [(star_ids[i][0], None, None, hips[i]) for i in range(len(star_ids))]
        res.sigma_cross_arcsec = cross * RAD_TO_ARCSEC
        res.sigma_roll_arcsec = roll * RAD_TO_ARCSEC
        precise(res, self.settings.max_error_arcsec)
        self._tick(timings, "attitude", start)
        return res

    @native
    def _fit(self, res, vectors, star_ids, fluxes, floor, streaks, q0, fitted, omega):
        """:meth:`attitude` and :meth:`_at_instant` of the matches, then the match screen
        (:mod:`lodestar.firmware.screen`): the matches it rejects are dropped, noted, and
        the rest fitted again.  ``(status, solved, star_ids)``; ``solved`` None unless
        ``OK``."""
        self._held_w = ()               # _photon() holds the fit's weights
        try:
            return self._fit_screened(res, vectors, star_ids, fluxes, floor, streaks, q0,
                                      fitted, omega)
        finally:
            self._held = self._held_w = self._last_fit = self._held_e2 = None  # no list of
            # the frame outlives it

    @native
    def _fit_screened(self, res, vectors, star_ids, fluxes, floor, streaks, q0, fitted,
                      omega):
        """:meth:`_fit`'s work."""
        for attempt in range(2):
            solved = self.attitude(vectors, star_ids, fluxes, floor, streaks, q0,
                                   fitted) if len(star_ids) >= 2 else None
            if solved is None:
                _note(res, "degenerate attitude fit")
                return S.NO_MATCH, None, star_ids
            self._last_fit = None
            solved, star_ids = self._at_instant(res, vectors, star_ids, fluxes, streaks,
                                                omega, solved)
            if solved is None:
                return res.status, None, star_ids
            drop = self._screened(star_ids, fluxes, solved[0]) if attempt == 0 else None
            if not drop:
                break
            _note(res, str(len(drop)) + " matches dropped by the screen (HIP " +
                  ", ".join([str(self.database.star_hip(star_ids[i][1])) for i in drop]) + ")")
            star_ids = [star_ids[i] for i in range(len(star_ids)) if i not in drop]
            q0, fitted = solved[0], False
        return S.OK, solved, star_ids

    def _catalogue(self, star_ids):
        """The catalogue vectors of ``star_ids`` (``[(vector index, star)]``), read once per
        list: the attitude, the rate and radial checks and the screen of one fit share them
        (:meth:`_fit` drops them)."""
        held = self._held
        if held is not None and held[0] is star_ids:
            return held[1]
        r = self._cone.star_vectors(self.database, star_ids)
        self._held = (star_ids, r)
        return r

    @native
    def _photon(self, star_ids, fluxes):
        """:meth:`weights` of the matched stars' ``fluxes`` (None: equal weights); within
        :meth:`_fit` computed once per list as :meth:`_catalogue`'s vectors are: the attitude
        and the rate check of one fit share them (a list read, never changed; 1.2 ms a fit on
        the F401).  Outside it (:meth:`attitude` called alone) nothing is held."""
        held = self._held_w
        if held and held[0] is star_ids:
            return held[1]
        w = [1.0] * len(star_ids) if fluxes is None else \
            self.weights([fluxes[o] for o, _s in star_ids])
        if held is not None:
            self._held_w = (star_ids, w, None)
        return w

    @native
    def _screened(self, star_ids, fluxes, q):
        """Indices of the matches :mod:`lodestar.firmware.screen` rejects: residual outliers of
        the final fit (its vectors and weights, kept by :meth:`_radial`; each residual over
        its variance less the fit's share, ``1 - h_i`` of :func:`screen.leverages`; not when
        it fitted a radial pattern) and brightness outliers (the observed ``fluxes`` against the
        catalogue magnitudes); None when fewer than :data:`MIN_SCREENED_STARS` would stay."""
        if self._last_fit is None:
            return None
        vectors, w, radial = self._last_fit
        self._last_fit = None
        db = self.database
        drop = []
        if not radial:              # a fitted radial pattern is not in these residuals
            drop = self._outliers(vectors, star_ids, w, q)
        if fluxes is not None:
            for i in _screen.brightness_outliers([fluxes[o] for o, _s in star_ids],
                                                     [db.star_mag(s) for _o, s in star_ids]):
                if i not in drop:
                    drop.append(i)
        return drop if len(star_ids) - len(drop) >= MIN_SCREENED_STARS else None

    @native
    def _outliers(self, vectors, star_ids, w, q):
        """Indices of the residual outliers among ``star_ids`` (weights ``w``) at attitude
        ``q``: :func:`lodestar.firmware.screen.residual_outliers` of each residual over its
        variance less the fit's share (``1 - h_i``, :func:`screen.leverages`)."""
        h = _screen.leverages([vectors[o] for o, _s in star_ids], w)
        held = self._held_e2
        if held is not None and held[0] is vectors and held[1] is star_ids and held[2] is q:
            e2 = held[3]                # attitude()'s: the same residuals at the same q
        else:
            e2 = _residuals2(q, [vectors[o] for o, _s in star_ids], self._catalogue(star_ids))
        return _screen.residual_outliers([e2[i] * w[i] / max(1.0 - h[i], MIN_FREEDOM)
                                          for i in range(len(star_ids))])

    @native
    def _at_instant(self, res, vectors, star_ids, fluxes, streaks, omega, solved):
        """The instant ``solved`` (``attitude``'s tuple) holds for, in ``res.t_epoch_s``, and
        its covariance made to cover the truth then (``docs/firmware.md``, Epoch and rate):
        with ``omega``, ``epoch_s`` and the gyro's rate, kept unless the frame contradicts it
        (:meth:`_contradicted`: ``RATE_CONTRADICTED``, None); without, the matched stars'
        weighted mean instant, the rate fitted with the attitude
        (:func:`lodestar.firmware.smear.rate_fit`), or with too few stars bounded by the
        streaks (else ``RATE_UNKNOWN``: None).  A fitted rate is then used to match again the
        stars its shear kept out.  Last, :meth:`_radial`.  Returns ``(solved, star_ids)``;
        frames of :meth:`solve_vectors` have no instants."""
        frame = self._frame
        w = self._rate_weights(star_ids, fluxes, streaks)
        if frame is None:
            return self._radial(res, vectors, star_ids, w, None, 0.0, solved), star_ids
        flat, exposure = frame
        res.rate_rad_s = omega
        if omega is not None:
            res.t_epoch_s = self.settings.epoch_s
            if self._contradicted(res, vectors, star_ids, w, omega, solved):
                return None, star_ids
            return self._radial(res, vectors, star_ids, w, None, 0.0, solved), star_ids
        times = self._times(exposure, len(flat) // 3)
        ts = [times[o] for o, _s in star_ids]
        total = ref = 0.0
        for i in range(len(w)):
            total += w[i]
            ref += w[i] * ts[i]
        ref /= total
        res.t_epoch_s = ref
        fit = None
        if self.settings.row_time_s != 0:       # else every star seen at one instant
            fit = self._rate_fit(vectors, star_ids, w, times, ref, solved[0])
            if fit is None:
                bound = _smear.smear_bound_px(_moments(flat, range(len(flat) // 3)))
                return self._bounded(res, solved, star_ids, ts, ref, bound, exposure), \
                    star_ids
        if fit is None:
            return self._radial(res, vectors, star_ids, w, None, 0.0, solved), star_ids
        q, rate, p, p_rate, s = fit
        turned = self._turned(vectors, times, ref, rate)
        again = self._track(turned, q, None, None, None)
        if again.status == S.OK and len(again.star_ids) > len(star_ids):
            ids = again.star_ids
            w2 = self._rate_weights(ids, fluxes, None)
            fit2 = self._rate_fit(turned, ids, w2, times, ref, again.q)
            if fit2 is not None:
                star_ids, w = ids, w2
                q, extra, p, p_rate, s = fit2
                rate = (rate[0] + extra[0], rate[1] + extra[1], rate[2] + extra[2])
        res.rate_rad_s = rate
        res.sigma_rate_rad_s = tuple(math.sqrt(p_rate[i][i]) for i in range(3))
        cross, roll = _attitude.sigmas_cross_roll(p)
        return self._radial(res, turned, star_ids, w, times, ref, (q, cross, roll, s)), \
            star_ids

    @native
    def _contradicted(self, res, vectors, star_ids, w, omega, solved):
        """Whether the frame contradicts the gyro's ``omega`` (:meth:`_contradicts`), setting
        ``RATE_CONTRADICTED`` with the difference in ``reason``.  Not when the matches
        without their residual outliers (:meth:`_outliers`, the match screen's test, which
        runs after this check) no longer contradict it and still number
        :data:`lodestar.firmware.smear.MIN_CHECK_STARS`: one star off along its track (a
        blend, a cut track end) otherwise fits a rate of its own (estcube2 at 1 deg/s, the
        exact gyro: 2 of 100 frames at chi-square 35 and 42 against 19.8, 1.2 and 1.8
        without its outlier).  A wrong gyro shears every star, so its frames contradict it
        without their outliers too."""
        found = self._contradicts(vectors, star_ids, w, omega, solved)
        if found is None:
            return False
        drop = self._outliers(vectors, star_ids, w, solved[0])
        if drop and len(star_ids) - len(drop) >= _smear.MIN_CHECK_STARS:
            keep = [i for i in range(len(star_ids)) if i not in drop]
            if self._contradicts(vectors, [star_ids[i] for i in keep], [w[i] for i in keep],
                                 omega, solved) is None:
                return False
        d, chi2 = found
        res.status = S.RATE_CONTRADICTED
        _note(res, "omega contradicted by the frame's rate (off by " + _deg3(d) +
              " deg/s, chi2 " + str(int(chi2)) + "): no attitude")
        return True

    @native
    def _contradicts(self, vectors, star_ids, w, omega, solved):
        """``(d, chi2)``, the frame's rate difference from the gyro's ``omega`` (rad/s;
        ``vectors`` turned to ``epoch_s`` by it) and its chi-square, when the matches
        ``star_ids`` (weights ``w``) contradict it, else None: only when at least
        :data:`lodestar.firmware.smear.MIN_CHECK_STARS` matched stars fit a residual rate
        (:func:`lodestar.firmware.smear.rate_fit`) beyond its covariance's limit
        (:func:`lodestar.firmware.smear.rate_chi2_limit`; ``STREAK_RATE_CHI2`` when
        most stars' streaks side with the frame), that difference moves the median star over
        the exposure by more than the stars' own width (their median ``sigma_minor``: the
        PSF's second moment, which a smear leaves alone) or, too small for the streaks to
        show, moves the attitude at the epoch beyond its own bound (:func:`_shifted`: a
        roll rate twice the truth's at 1 deg/s, 330" off against a roll sigma of 12"), and
        the streaks (second moments) do not side with the gyro
        (:func:`lodestar.firmware.smear.streak_votes`: more than a third of the stars, net;
        the frame's rate has its own noise, so a sign error's votes are near zero, not
        exactly zero).  A rate from few, short or noisy streaks never overrides the gyro."""
        flat, exposure = self._frame
        st = self.settings
        if st.row_time_s == 0 or exposure is None or len(star_ids) < _smear.MIN_CHECK_STARS:
            return None
        times = self._times(exposure, len(flat) // 3)
        dts = [times[o] - st.epoch_s for o, _s in star_ids]
        verdict = _smear.check([vectors[o] for o, _s in star_ids], self._catalogue(star_ids),
                               dts, w, solved[0], True, False, self.min_sigma_rad,
                               self.sigma_rad)
        if verdict is None or verdict[1] is None or not verdict[1] > _smear.STREAK_RATE_CHI2:
            return None
        d, chi2 = verdict
        stars = [(vectors[o], m) for (o, _s), m in zip(star_ids, _moments(
            flat, [o for o, _s in star_ids]))]
        frame = (omega[0] + d[0], omega[1] + d[1], omega[2] + d[2])
        scale = self.focal_px * exposure
        if not _smear.visible(stars, d, scale) and not (
                chi2 > SHIFT_CHI2_FACTOR * _smear.rate_chi2_limit(len(stars))
                and _shifted(d, dts, w, solved)):
            return None
        votes = _smear.streak_votes(stars, omega, frame, scale)
        if 3 * votes < -len(stars) or (2 * votes < len(stars) and
                                       not chi2 > _smear.rate_chi2_limit(len(stars))):
            return None
        return verdict

    @native
    def _radial(self, res, vectors, star_ids, w, times, ref, solved):
        """``solved``, or when the matched stars' residuals show a radial pattern (a lens
        distortion or focal length the camera model lacks:
        :func:`lodestar.firmware.smear.radial_fit`, its coefficients beyond
        ``RADIAL_CHI2``) the attitude fitted with it, its sigma grown by it, noted in
        ``reason``.  ``times``: the stars' instants when the rate is fitted too (counted from
        ``ref``; the fitted rate then corrected in ``res``), else None.  The lens does not
        change between frames: once a check finds no pattern, tracking frames skip it (lost
        in space checks every frame); the verdict is one linear solve, and only a pattern
        is fitted in full (``docs/firmware.md``, Epoch and rate)."""
        self._last_fit = (vectors, w, False)
        if len(star_ids) < _smear.MIN_RADIAL_STARS or (self._lens_clean and
                                                        self._mode == "tracking"):
            return solved
        rate = times is not None
        b = [vectors[o] for o, _s in star_ids]
        r = self._catalogue(star_ids)
        dts = [times[o] - ref if rate else 0.0 for o, _s in star_ids]
        # the verdict from one linear solve (the radial terms enter linearly and the
        # attitude and rate are fitted already); the full fit only for a pattern
        verdict = _smear.check(b, r, dts, w, solved[0], rate, True, self.min_sigma_rad,
                               self.sigma_rad)
        if verdict is None:
            return solved
        if verdict[1] is None or verdict[1] <= _smear.RADIAL_CHI2:
            self._lens_clean = True
            return solved
        self._lens_clean = False
        fit = _smear.radial_fit(b, r, dts, w, solved[0], rate, self.min_sigma_rad,
                                self.sigma_rad)
        if fit is None:
            return solved
        q, extra, p, p_rate, s, c, p_c = fit
        chi2 = _smear.chi2_rate(c, p_c)
        if chi2 is None or chi2 <= _smear.RADIAL_CHI2:
            return solved
        _note(res, "the residuals show a radial pattern (chi2 " + str(int(chi2)) + "): an "
              "unmodelled lens distortion or focal length, fitted; sigma grown")
        self._last_fit = (vectors, w, True)
        if rate:
            r0 = res.rate_rad_s
            res.rate_rad_s = (r0[0] + extra[0], r0[1] + extra[1], r0[2] + extra[2])
            res.sigma_rate_rad_s = tuple(math.sqrt(p_rate[i][i]) for i in range(3))
        cross, roll = _attitude.sigmas_cross_roll(p)
        return q, max(cross, solved[1]), max(roll, solved[2]), s

    @native
    def _rate_weights(self, star_ids, fluxes, streaks):
        """Relative weights of the matched stars for the rate fit: the photon model
        (:meth:`weights`) with each partly seen track's variance added (as :meth:`attitude`,
        whose list it takes when that fit of ``star_ids`` added tracks)."""
        held = self._held_w
        if streaks is not None and held and held[0] is star_ids and held[2] is not None:
            return held[2]              # attitude()'s, the same expression of the same values
        n = len(star_ids)
        w = self._photon(star_ids, fluxes)
        if streaks is not None:
            s0 = self.sigma_rad if self.sigma_rad is not None else self.tolerance_rad / 3.0
            w = [1.0 / (1.0 / w[i] + verify.streak_variance(streaks[star_ids[i][0]]) /
                        (s0 * s0)) for i in range(n)]
        return w

    def _rate_fit(self, vectors, star_ids, w, times, ref, q):
        """:func:`lodestar.firmware.smear.rate_fit` of the matched stars, their instants
        counted from ``ref``."""
        return _smear.rate_fit([vectors[o] for o, _s in star_ids], self._catalogue(star_ids),
                               [times[o] - ref for o, _s in star_ids], w, q,
                               self.min_sigma_rad, self.sigma_rad)

    def _turned(self, vectors, times, ref, rate):
        """``vectors`` turned to the instant ``ref`` by ``rate`` (rad/s)."""
        speed = G.norm(rate)
        if not speed > 0:
            return vectors
        axis = (rate[0] / speed, rate[1] / speed, rate[2] / speed)
        return [G.rotate_about(vectors[o], axis, speed * (times[o] - ref))
                for o in range(len(vectors))]

    def _bounded(self, res, solved, star_ids, ts, mean, bound_px, exposure):
        """``solved`` without a rate fit (too few stars) and without ``omega``: its
        covariance grown by the shear of the fastest rate the streaks allow
        (:func:`lodestar.firmware.smear.smear_bound_px`, across the boresight and, for the
        stars' median distance from the centre, about it) over the stars' instants;
        ``RATE_UNKNOWN`` (None) when the streaks allow a smear beyond
        :data:`MAX_BOUNDED_SMEAR_PX` or the exposure is unknown."""
        if bound_px is None or exposure is None or bound_px > MAX_BOUNDED_SMEAR_PX:
            res.status = S.RATE_UNKNOWN
            _note(res, "too few stars (" + str(len(star_ids)) + ") to fit the rate, and "
                  "the streaks do not bound it")
            return None
        cam, xy = self.camera, self._xy
        radii = []
        span = 0.0
        for i in range(len(star_ids)):
            o = star_ids[i][0]
            dx, dy = xy[2 * o] - cam.cx, xy[2 * o + 1] - cam.cy
            radii.append(math.sqrt(dx * dx + dy * dy))
            if abs(ts[i] - mean) > span:
                span = abs(ts[i] - mean)
        radii.sort()
        rate_cross = bound_px / (self.focal_px * exposure)
        rate_roll = bound_px / (max(radii[len(radii) // 2], 1.0) * exposure)
        q, cross, roll, s = solved
        cross = math.sqrt(cross * cross + (rate_cross * span) ** 2)
        roll = math.sqrt(roll * roll + (rate_roll * span) ** 2)
        _note(res, "rate not fitted (" + str(len(star_ids)) + " stars): sigma grown by the "
              "shear of the streaks' bound")
        return q, cross, roll, s

    # ---- the flight entry point --------------------------------------------------------

    def process(self, packet_bytes, prior=None, omega=None, dt=None, exposure_s=None,
                velocity_km_s=None):
        """One frame: ``packet_bytes`` (an FPGA packet, ``lodestar.contract`` layout) ->
        :class:`Result`.  ``prior``: attitude at the previous epoch (enables tracking);
        ``omega``: body rate, rad/s, camera frame; ``dt``: s from the prior's epoch to this
        frame's; ``exposure_s``: this frame's exposure (default: the tracker's);
        ``velocity_km_s``: the observer's velocity, km/s, ICRS (default: the settings'; None
        there: no aberration correction), so that ``q`` is relative to ICRS
        (``docs/apparent_directions.md``).  Never raises."""
        try:
            return self._process(packet_bytes, prior, omega, dt, exposure_s, velocity_km_s)
        except MemoryError:
            return Result(S.OUT_OF_MEMORY, "out of heap")
        except Exception as exc:
            return Result(S.INTERNAL_ERROR, "internal error: " + repr(exc))

    def _process(self, packet_bytes, prior, omega, dt, exposure_s, velocity_km_s):
        res = Result(S.OK)
        if self.status != S.OK:
            res.status = self.status
            res.reason = self.reason
            return res
        timings = res.timings
        _threshold(GC_THRESHOLD if prior is None else TRACK_GC_THRESHOLD)
        if prior is None:
            _collect()
        start = first = self._tick(timings, None, None)
        code, header, reason = packet.check(packet_bytes, records=False)
        start = self._tick(timings, "decode", start)
        if code != S.OK:
            res.status = code
            res.reason = reason
            return res
        self._check_frame(header, res)
        if res.status != S.OK:
            return res
        w = None
        if omega is not None:
            w = G.vector3(omega)
            if w is None:
                _note(res, "omega ignored: not 3 finite numbers")
        exposure = self.settings.exposure_s
        if exposure_s is not None:
            if G.is_number(exposure_s) and exposure_s > 0:
                exposure = exposure_s
            else:
                _note(res, "exposure_s ignored: not a positive number")
        beta = self._beta(velocity_km_s, res)
        cam = self.camera
        smear_at = self._smear_at(w, exposure)
        smear = _memo(smear_at)
        longest = _longest_smear(cam, smear_at) if smear_at is not None else 0.0
        smear_at = None
        limit = self.settings.max_smear_px
        select = not longest <= limit        # some stars may smear beyond the limit
        max_stars = self.settings.max_stars
        border = (cam.width, cam.height) if self.settings.drop_border else None
        try:        # the records are checked as they are read: one decoding each
            stars, rejected = centroids.extract(packet.checked_records(packet_bytes, header),
                                                 max_stars=None if select else max_stars,
                                                 expected_smear_px=smear, border=border,
                                                 **self.settings.extract_options)
        except packet.BadRecord as exc:
            return Result(exc.args[0], exc.args[1])
        res.rejected = rejected
        if select:
            stars, longest = _short_smears(stars, smear, limit, max_stars, rejected)
            if rejected["smear"] and len(stars) < MIN_SMEAR_STARS:
                res.status = S.SMEAR_TOO_LONG
                _note(res, str(rejected["smear"]) + " stars smeared beyond max_smear_px " +
                      str(limit) + ", " + str(len(stars)) + " left")
                return res
        if prior is None:               # a tracking frame's peak is low: no stage collections
            _collect()
        start = self._tick(timings, "centroids", start)
        budget, wide = min_sum(stars, self.track_stars, True)
        vectors, used = self.directions(stars, w, exposure)
        streaks = self.streaks(stars, used, smear) if smear is not None else None
        smear = None                    # the memo goes before the identification's peak
        start = self._tick(timings, "directions", start)
        if len(used) < len(stars):
            _note(res, str(len(stars) - len(used)) + " centroids outside the camera model")
        self._keep(stars, used)
        self._frame = self._instants(stars, used, exposure)
        stars = used = None
        if prior is None:
            _collect()
        try:
            res = self._solve_vectors(vectors, prior, w, dt, self._flux, res, start, longest,
                                      streaks, beta)
        finally:
            self._frame = None
        if res.status == S.OK or res.status == S.IMPRECISE:
            index, xy = self._index, self._xy
            matches = []
            for o, _x, _y, hip in res.matches:
                matches.append((index[o], xy[2 * o], xy[2 * o + 1], hip))
            res.matches = matches
            res.min_sum = wide if self._thin(res) else budget
        self._tick(timings, "total", first)
        return res

    @native
    def _thin(self, res):
        """Whether the next frame is budgeted for :data:`WIDE_TRACK` times ``track_stars``
        (``docs/firmware.md``, Record budget): a frame of the budget's records (at most
        ``track_stars`` plus :data:`TRACK_EXTRA_STARS`) whose solution ``res`` is
        ``IMPRECISE``, or a widened one (at most :data:`WIDE_TRACK` times as many) whose
        bound is still beyond :data:`THIN_SHARE` of ``max_error_arcsec`` (the hysteresis
        that keeps it from flapping).  Few stars give a loose bound (the Student-t tail of
        their residuals, :func:`tail_factor`); a frame of more records is not widened, its
        precision is not the budget's."""
        limit = self.settings.max_error_arcsec
        k = self.track_stars
        if limit is None or k is None or res.n_records > WIDE_TRACK * k + TRACK_EXTRA_STARS:
            return False
        bound = error_bound(res.sigma_cross_arcsec, res.sigma_roll_arcsec)
        if res.n_records > k + TRACK_EXTRA_STARS:
            return bound > THIN_SHARE * limit
        return bound > limit

    @native
    def _instants(self, stars, used, exposure):
        """``(moments, exposure)`` of the used stars (``_keep`` order): their second moments
        ``sigma_major, sigma_minor, orientation`` (px, rad: the streak) three floats per star
        in one flat list (held through the identification: no object per star), read by
        :func:`_moments`; :meth:`_times` gives their instants."""
        flat = [0.0] * (3 * len(used))
        for k in range(len(used)):
            v = stars[used[k]]._v       # (..., sigma_major, sigma_minor, elongation,
            flat[3 * k] = v[3]          # orientation, ...): a property is a call
            flat[3 * k + 1] = v[4]
            flat[3 * k + 2] = v[6]
        return flat, exposure

    @native
    def _times(self, exposure, n):
        """Each of the ``n`` used stars' mean instant, s after the start of row 0's exposure
        (``exposure / 2 + y row_time_s``; an unknown exposure counts from row 0's
        mid-exposure)."""
        half = 0.5 * exposure if exposure is not None else 0.0
        row_time = self.settings.row_time_s
        xy = self._xy
        return [half + xy[2 * o + 1] * row_time for o in range(n)]

    @native
    def _check_frame(self, header, res):
        """Set ``res`` to ``FRAME_INCOMPLETE`` or ``BAD_INPUT`` (a frame not of the camera's
        size) for a frame that cannot be solved; note the lost blobs of one that can."""
        flags = header["flags"]
        res.n_records = header["n_records"]
        for bit, name in INCOMPLETE_FLAGS:
            if flags & bit:
                res.status = S.FRAME_INCOMPLETE
                _note(res, name)
        if res.status != S.OK:
            return
        for bit, name in LOST_FLAGS:
            if flags & bit:
                _note(res, name + ": blobs lost")
        cam = self.camera
        if header["width"] != cam.width or header["height"] != cam.height:
            res.status = S.BAD_INPUT
            res.reason = "frame is {}x{}, the camera {}x{}".format(
                header["width"], header["height"], cam.width, cam.height)

    def _smear_at(self, omega, exposure_s):
        """``smear(x, y)``: the expected smear (px) of a star at pixel ``(x, y)``
        (:meth:`Camera.smear_function` of ``omega`` and ``exposure_s``), not remembered (the
        frame's corners, :func:`_longest_smear`, which no star asks for again; the stars'
        go through :func:`_memo`); None without a non-zero rate or an exposure."""
        if omega is None or exposure_s is None or not (omega[0] or omega[1] or omega[2]):
            return None
        return self.camera.smear_function(omega, exposure_s)

    @native
    def _keep(self, stars, used):
        """Copy the record index, centroid and flux of each used star into the tracker's
        buffers: the rest of a frame needs no more of them, so the star objects are dropped
        before the identification (``docs/firmware.md``, Memory)."""
        index, xy, fluxes = self._index, self._xy, self._flux
        for o in range(len(used)):
            v = stars[used[o]]._v       # (x, y, flux, ..., index, parts): a property is a
            index[o] = v[10]            # call
            xy[2 * o] = v[0]
            xy[2 * o + 1] = v[1]
            fluxes[o] = v[2]


def _memo(smear_at):
    """``smear_at`` (:meth:`StarTracker._smear_at`) remembered per pixel for the first
    :data:`SMEAR_MEMO` pixels (extraction, joining and streaks ask again); None for None."""
    if smear_at is None:
        return None
    known = {}

    @native
    def smear(x, y):                    # one lookup for a hit (a smear is never None in
        key = (x, y)                    # the memo: a None is computed again)
        d = known.get(key)
        if d is not None:
            return d
        d = smear_at(x, y)
        if d is not None and len(known) < SMEAR_MEMO:
            known[key] = d
        return d
    return smear


def _aberration():
    """:mod:`lodestar.firmware.aberration`, imported on first use: a flight image that
    never corrects the aberration keeps none of it on its heap."""
    from . import aberration
    return aberration


def _deaberrate(vectors, q, beta):
    """Turn the apparent camera-frame unit ``vectors`` into geometric ones in place
    (:func:`lodestar.firmware.aberration.deaberrate`), ``beta`` (ICRS) taken into the
    camera frame by the identified attitude ``q`` (its error of the aberration's size, 1e-4
    rad, changes ``beta`` by 1e-8 of itself)."""
    deaberrate = _aberration().deaberrate
    bc = G.mat_vec(Q.matrix(q), beta)
    for i in range(len(vectors)):
        vectors[i] = deaberrate(vectors[i], bc)


def _moments(flat, indices):
    """The second moments ``(sigma_major, sigma_minor, orientation)`` of the stars
    ``indices`` from :meth:`StarTracker._instants`'s flat list."""
    return [(flat[3 * o], flat[3 * o + 1], flat[3 * o + 2]) for o in indices]


def _deg3(v):
    """A rate (rad/s) as text in deg/s, to 0.01."""
    return "(" + ", ".join([str(round(math.degrees(x), 2)) for x in v]) + ")"


def _note(res, text):
    res.reason = text if not res.reason else res.reason + "; " + text


def _camera_fov_h(cam):
    """Horizontal FOV (rad) through the camera model, along the middle row (as
    ``lodestar.sim.camera.Camera.fov_deg``); None if the model cannot invert the edges."""
    ym = 0.5 * (cam.height - 1)
    a = cam.pixel_to_vector(-0.5, ym)
    b = cam.pixel_to_vector(cam.width - 0.5, ym)
    if a is None or b is None:
        return None
    return G.angle(a, b)
