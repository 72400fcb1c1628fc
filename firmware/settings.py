"""The star tracker's settings: one plain object shared by the flight code, the ground tools,
the regression and the campaigns.

    from lodestar.firmware.settings import Settings
    tracker = StarTracker(database, camera, Settings(method="pyramid", exposure_s=0.1))

Each option is declared once, in :data:`OPTIONS`: its name, its default and its check.
:meth:`Settings.check` reports the first bad one, which
:class:`lodestar.firmware.pipeline.StarTracker` returns as its status (it never raises).
Pure Python for CPython and MicroPython.
"""

from . import status as S
from .geometry import is_number
from .tracking import DEFAULT_MAX_MISMATCH_PROB, DEFAULT_MIN_MATCHES

DEFAULT_TOLERANCE_PX = 2.5
"""Largest centroid error (calibration included) of one star, px: the match tolerance."""
DEFAULT_MAX_STARS = 32
"""Brightest stars used per frame (identification patterns use the first 16)."""
DEFAULT_MIN_SIGMA_PX = 0.02
"""Floor of the residual-based centroid noise estimate, px."""
DEFAULT_MAX_SMEAR_PX = 100.0
"""Longest expected smear (px) the pipeline solves (each star its own,
``docs/campaigns.md``, Spin about the boresight).  A threshold breaks a long track into
pieces; the joined pieces are centred on their extent and carry an unseen half-track of a
tenth of the track (:mod:`lodestar.firmware.centroids`), which covers their centroid errors
to 45 deg/s about the boresight on estcube2 (corners 130 px); beyond 100 px the tracks are
faint pieces the detector mostly loses, and long ones cost the joining time."""
DEFAULT_BUDGET = 2000
"""Lost-in-space pattern budget (deterministic cap on the search)."""
MAX_STARS = 256
"""Most stars a frame may keep (``max_stars``): verification work grows with it."""
DEFAULT_TRACK_SEARCH_DEG = 0.3
"""Largest expected error of the propagated prior, deg."""
DEFAULT_MAX_ERROR_ARCSEC = 180.0
"""Largest 5-sigma bound (arcsec) of an ``OK`` attitude's total error; beyond it ``IMPRECISE``
(``docs/firmware.md``, Result, epoch and statuses).  Issue 33's limit: an ``OK`` attitude
within 5 sigma on every axis is then within 180" of the truth, so an ``OK`` frame is never
wrong by either of its criteria.  It refuses frames whose roll is loose (estcube2 at 20 deg/s
about the boresight: about half, 5 sigma of roll 80-920"; ``docs/campaigns.md``, The 180"
rule); a user who accepts looser attitudes sets it higher (the tracking window, 1,080")."""
DEFAULT_TRACK_STARS = 8
"""Brightest blobs a tracking frame is budgeted for (``track_stars``): the ``min_sum`` a
solved frame returns lets 8 to 10 of them into the next packet (``docs/firmware.md``,
Record budget).  Flux weighting makes the faint stars it leaves out worth little: over 30
estcube2 frames tracked at rest (9 records instead of 54 at the median) the RMS errors are
0.92 (cross-boresight) and 1.03 (roll) of every blob's, at 1 deg/s (9 instead of 29) 1.12
and 1.13 (``benchmarks/bench_track_budget.py``)."""


# Checks of :data:`OPTIONS`: None for a good value, else what the value must be.

def _positive(x):
    return None if is_number(x) and x > 0 else "a positive number"


def _positive_or_none(x):
    return None if x is None or is_number(x) and x > 0 else "a positive number or None"


def _not_negative(x):
    return None if is_number(x) and x >= 0 else "a number >= 0"


def _finite(x):
    return None if is_number(x) else "a finite number"


def _star_count(x):
    return None if isinstance(x, int) and 4 <= x <= MAX_STARS else \
        "an int in 4.." + str(MAX_STARS)


def _count(x):
    return None if type(x) is not bool and isinstance(x, int) and x >= 1 else "an int >= 1"


def _count_or_none(x):
    return None if x is None or _count(x) is None else "None or an int >= 1"


def _budget(x):
    # as _count, but True (one pattern) passes, as it always has
    return None if isinstance(x, int) and x >= 1 else "an int >= 1"


def _velocity(x):
    # the aberration module is imported only when a velocity is set (docs/firmware.md)
    if x is None:
        return None
    from . import aberration
    return None if aberration.beta(x) is not None else \
        "None or 3 finite numbers, km/s, at most " + str(aberration.MAX_SPEED_KM_S) + " km/s"


def _probability(x):
    return None if is_number(x) and 0 < x < 1 else "a number in (0, 1)"


EXTRACT_OPTIONS = (
    ("min_pixels",         _count),
    ("min_sigma_px",       _not_negative),
    ("max_elongation",     _positive),
    ("smear_angle_tol",    _positive),
    ("smear_length_ratio", _positive),
    ("join_across_px",     _not_negative),
)
"""The keywords ``extract_options`` may hold, those of
:func:`lodestar.firmware.centroids.extract` the pipeline does not set itself, and their
checks."""
ID_OPTIONS = (
    ("max_stars",          _star_count),
    ("max_mismatch_prob",  _probability),
    ("distinct_rad",       _positive_or_none),
)
"""The keywords ``id_options`` may hold (of every method's ``identify``) and their checks."""


def _keywords(table):
    """The check of a dict of keywords of ``table``: each key a name of it, each value
    good by its check."""
    names = ", ".join(name for name, _check in table)

    def check(x):
        if not isinstance(x, dict):
            return "a dict of " + names
        for key in x:
            entry = None
            for name, item in table:
                if name == key:
                    entry = item
            if entry is None:
                return "a dict of " + names + ", not " + repr(key)
            must = entry(x[key])
            if must is not None:
                return "a dict whose " + key + " is " + must
        return None
    return check


def _clock(x):
    # called once here: a clock that raises or returns no number fails every frame
    if x is None:
        return None
    try:
        now = x()
    except MemoryError:
        raise
    except Exception:
        now = None
    return None if is_number(now) else "None or a function returning a number"


OPTIONS = (
    # name               default                    check (None: any value)
    "tolerance_px",      DEFAULT_TOLERANCE_PX,       _positive,
    "centroid_sigma_px", None,                       _positive_or_none,
    "min_sigma_px",      DEFAULT_MIN_SIGMA_PX,       _positive,
    "max_stars",         DEFAULT_MAX_STARS,          _star_count,
    "track_stars",       DEFAULT_TRACK_STARS,        _count_or_none,
    "max_work",          None,                       _count_or_none,
    "budget",            DEFAULT_BUDGET,             _budget,
    "max_smear_px",      DEFAULT_MAX_SMEAR_PX,       _positive,
    "max_error_arcsec",  DEFAULT_MAX_ERROR_ARCSEC,   _positive_or_none,
    "track_search_deg",  DEFAULT_TRACK_SEARCH_DEG,   _not_negative,
    "row_time_s",        0.0,                        _finite,
    "epoch_s",           0.0,                        _finite,
    "exposure_s",        None,                       _positive_or_none,
    "velocity_km_s",     None,                       _velocity,
    "method",            "pyramid",                  None,   # StarTracker: by the database
    "flux_weighting",    True,                       None,
    "track_min_matches", DEFAULT_MIN_MATCHES,        None,
    "track_max_prob",    DEFAULT_MAX_MISMATCH_PROB,  None,
    "fallback",          True,                       None,
    "drop_border",       True,                       None,
    "refine",            True,                       None,
    "extract_options",   None,                       _keywords(EXTRACT_OPTIONS),
    "id_options",        None,                       _keywords(ID_OPTIONS),
    "clock",             None,                       _clock,
)
"""Every option of :class:`Settings`, three items each: ``name, default, check``,
``check(value)`` None for a good value, else what it must be; checked in this order
(:meth:`Settings.check`).  One flat tuple: a tuple per option would keep 24 more objects
on the MCU's heap (about 600 bytes, ``docs/mcu_board.md``, Heap and stack)."""


class Settings:
    """Settings of a :class:`~lodestar.firmware.pipeline.StarTracker` (keywords of
    :data:`OPTIONS` only; an unknown one raises ``TypeError``).

    ``method``: lost-in-space method, a name of :data:`lodestar.firmware.starid.METHODS`.
    ``max_stars``: brightest stars kept per frame.  ``tolerance_px``: match tolerance, px.
    ``centroid_sigma_px``: per-axis centroid noise of a median-flux star for the covariance,
    px (None: estimated from each frame's residuals, at least ``min_sigma_px``).
    ``flux_weighting``: weight stars by their flux.  ``budget``: lost-in-space pattern
    budget.  ``exposure_s``, ``row_time_s``: exposure and rolling-shutter line time, s (smear
    and rate compensation; ``process(exposure_s=...)`` overrides the exposure per frame).
    ``epoch_s``: the instant the attitude refers to, s after the start of row 0's exposure.
    ``track_search_deg``: error of the propagated prior tracking must absorb, deg.
    ``track_min_matches``, ``track_max_prob``: tracking acceptance.  ``track_stars``: the
    record budget of a tracking frame, in stars (``result.min_sum``; None: every blob).
    ``fallback``: run lost-in-space when tracking fails.  ``drop_border``: ignore blobs
    touching the frame edge.  ``refine``: grow a lost-in-space match set by tracking from
    its attitude.  ``max_smear_px``: longest expected smear solved (beyond: ``SMEAR_TOO_LONG``).
    ``max_error_arcsec``: largest 5-sigma bound of an ``OK`` attitude's total error, arcsec
    (beyond: ``IMPRECISE``; None: any).
    ``extract_options``: extra keywords of :func:`lodestar.firmware.centroids.extract`
    (:data:`EXTRACT_OPTIONS`); ``id_options``: extra keywords of the identification
    (:data:`ID_OPTIONS`).  ``clock``: optional function returning a number (e.g.
    ``time.ticks_ms``) for ``result.timings``, called once by :meth:`check`.  ``max_work``:
    work budget of a lost-in-space identification (None: the method's own, ``MAX_WORK`` of
    its module: Pyramid's is 2 s of F401 time, :data:`lodestar.firmware.starid.pyramid.MAX_WORK`).
    ``velocity_km_s``: the observer's velocity, km/s, ICRS, for the aberration correction
    (None: none; ``process(velocity_km_s=...)`` overrides it per frame,
    ``docs/apparent_directions.md``).
    """

    def __init__(self, **options):
        for i in range(0, len(OPTIONS), 3):
            setattr(self, OPTIONS[i], options.pop(OPTIONS[i], OPTIONS[i + 1]))
        if options:
            raise TypeError("unknown settings " + ", ".join(sorted(options)))
        if self.extract_options is None:
            self.extract_options = {}
        if self.id_options is None:
            self.id_options = {}

    def check(self):
        """``(status, reason)``: ``(OK, "")``, or ``BAD_INPUT`` and what the first bad
        option of :data:`OPTIONS` must be.  The method is checked by the
        :class:`~lodestar.firmware.pipeline.StarTracker`, against its database."""
        for i in range(0, len(OPTIONS), 3):
            name, check = OPTIONS[i], OPTIONS[i + 2]
            must = None if check is None else check(getattr(self, name))
            if must is not None:
                return S.BAD_INPUT, name + " must be " + must
        return S.OK, ""
