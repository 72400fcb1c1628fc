"""The star tracker's settings: one plain object shared by the flight code, the ground tools,
the regression and the campaigns.

    from lodestar.firmware.settings import Settings
    tracker = StarTracker(database, camera, Settings(method="pyramid", exposure_s=0.1))

:class:`Settings` only holds values; :class:`lodestar.firmware.pipeline.StarTracker`
validates them when it is built and reports a bad one as its ``BAD_INPUT`` status (it never
raises).  Pure Python for CPython and MicroPython.
"""

from .starid.search import DEFAULT_MAX_WORK
from .tracking import DEFAULT_MAX_MISMATCH_PROB, DEFAULT_MIN_MATCHES

DEFAULT_TOLERANCE_PX = 2.5
"""Largest centroid error (calibration included) of one star, px: the match tolerance."""
DEFAULT_MAX_STARS = 32
"""Brightest stars used per frame (identification patterns use the first 16)."""
DEFAULT_MIN_SIGMA_PX = 0.02
"""Floor of the residual-based centroid noise estimate, px."""
DEFAULT_MAX_SMEAR_PX = 50.0
"""Longest expected smear (px) the pipeline solves: beyond it a threshold breaks a star's
track into pieces the fragment joining cannot all recover, with centroid errors the
covariance does not describe (``docs/firmware.md``)."""
DEFAULT_BUDGET = 2000
"""Lost-in-space pattern budget (deterministic cap on the search)."""
MAX_STARS = 256
"""Most stars a frame may keep (``max_stars``): verification work grows with it."""
DEFAULT_TRACK_SEARCH_DEG = 0.3
"""Largest expected error of the propagated prior, deg."""
DEFAULT_TRACK_STARS = 8
"""Brightest blobs a tracking frame is budgeted for (``track_stars``): the ``min_sum`` a
solved frame returns lets 8 to 10 of them into the next packet (``docs/firmware.md``,
Record budget).  Flux weighting makes the faint stars it leaves out worth little: over 30
estcube2 frames tracked at rest (9 records instead of 54 at the median) the RMS errors are
0.92 (cross-boresight) and 1.03 (roll) of every blob's, at 1 deg/s (9 instead of 29) 1.12
and 1.13 (``benchmarks/bench_track_budget.py``)."""


class Settings:
    """Settings of a :class:`~lodestar.firmware.pipeline.StarTracker` (keywords only).

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
    ``extract_options``: extra keywords of :func:`lodestar.firmware.centroids.extract`;
    ``id_options``: extra keywords of the identification (``max_stars``,
    ``max_mismatch_prob``, ``distinct_rad``).  ``clock``: optional function returning a
    number (e.g. ``time.ticks_ms``) for ``result.timings``.  ``max_work``: work budget of a
    lost-in-space identification (:data:`lodestar.firmware.starid.search.DEFAULT_MAX_WORK`).
    ``velocity_km_s``: the observer's velocity, km/s, ICRS, for the aberration correction
    (None: none; ``process(velocity_km_s=...)`` overrides it per frame,
    ``docs/apparent_directions.md``).
    """

    def __init__(self, method="pyramid", max_stars=DEFAULT_MAX_STARS,
                 tolerance_px=DEFAULT_TOLERANCE_PX, centroid_sigma_px=None,
                 min_sigma_px=DEFAULT_MIN_SIGMA_PX, flux_weighting=True,
                 budget=DEFAULT_BUDGET, exposure_s=None, row_time_s=0.0, epoch_s=0.0,
                 track_search_deg=DEFAULT_TRACK_SEARCH_DEG,
                 track_min_matches=DEFAULT_MIN_MATCHES,
                 track_max_prob=DEFAULT_MAX_MISMATCH_PROB,
                 track_stars=DEFAULT_TRACK_STARS, fallback=True,
                 drop_border=True, refine=True, max_smear_px=DEFAULT_MAX_SMEAR_PX,
                 extract_options=None, id_options=None, clock=None,
                 max_work=DEFAULT_MAX_WORK, velocity_km_s=None):
        self.method = method
        self.max_stars = max_stars
        self.tolerance_px = tolerance_px
        self.centroid_sigma_px = centroid_sigma_px
        self.min_sigma_px = min_sigma_px
        self.flux_weighting = flux_weighting
        self.budget = budget
        self.exposure_s = exposure_s
        self.row_time_s = row_time_s
        self.epoch_s = epoch_s
        self.track_search_deg = track_search_deg
        self.track_min_matches = track_min_matches
        self.track_max_prob = track_max_prob
        self.track_stars = track_stars
        self.fallback = fallback
        self.drop_border = drop_border
        self.refine = refine
        self.max_smear_px = max_smear_px
        self.extract_options = extract_options if extract_options is not None else {}
        self.id_options = id_options if id_options is not None else {}
        self.clock = clock
        self.max_work = max_work
        self.velocity_km_s = velocity_km_s
