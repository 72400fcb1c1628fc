"""Lost-in-space star identification: the one entry point for every method.

``identify(vectors, database, method='pyramid', tolerance_rad=None, budget=2000, **options)``
returns a :class:`Solution` (``status``, ``q``, ``matches``, ``patterns_tried``,
``probability``; see :mod:`lodestar.firmware.verify`).

* ``vectors``: camera-frame unit vectors of the observed stars, **brightest first**
  (``lodestar.sim`` camera frame: ``+z`` boresight).
* ``database``: a :class:`lodestar.firmware.database.Database`.
* ``tolerance_rad``: largest direction error of one observed star (centroid noise and
  calibration residuals); it is both the verification match radius and the base of the
  pair-angle tolerance.  Default ``fov_h / 1000`` of the database (2.5 px for estcube2).
* ``budget``: the deterministic cap on patterns tried (star triples for Pyramid).
* ``options``: method specific (Pyramid: ``max_stars``, ``max_mismatch_prob``,
  ``distinct_rad``).

Methods: ``'pyramid'`` (:mod:`lodestar.firmware.pyramid`).  ``'triangle'`` and
``'hashing'`` are reserved names (database sections 4 and 5); they return ``BAD_DATABASE``
until implemented.  Every method shares the verification and the probability budget of
:mod:`lodestar.firmware.verify`.

Pure Python for CPython and MicroPython.
"""

from .verify import (AMBIGUOUS, BAD_DATABASE, BAD_INPUT, BUDGET_EXHAUSTED, NO_MATCH, OK,
                     STATUS_NAMES, TOO_FEW_STARS, Solution, status_name)

METHODS = ("pyramid",)

__all__ = ("identify", "Solution", "status_name", "STATUS_NAMES", "OK", "NO_MATCH",
           "TOO_FEW_STARS", "AMBIGUOUS", "BUDGET_EXHAUSTED", "BAD_INPUT", "BAD_DATABASE",
           "METHODS")


def identify(vectors, database, method="pyramid", tolerance_rad=None, budget=2000, **options):
    """Identify the observed stars; returns a :class:`Solution` (never raises for bad
    input: ``BAD_INPUT``; unknown or unsupported method: ``BAD_DATABASE``)."""
    if tolerance_rad is None:
        tolerance_rad = database.fov_h / 1000.0
    if method == "pyramid":
        from . import pyramid
        return pyramid.identify(vectors, database, tolerance_rad, budget, **options)
    if method in ("triangle", "hashing"):
        return Solution(BAD_DATABASE)
    return Solution(BAD_INPUT)

