"""Lost-in-space star identification: the one entry point for every method.

``identify(vectors, database, method='pyramid', tolerance_rad=None, budget=2000, **options)``
returns a :class:`Solution` (``status``, ``q``, ``matches``, ``patterns_tried``,
``probability``; see :mod:`lodestar.firmware.verify`).

* ``vectors``: camera-frame unit vectors of the observed stars, **brightest first**
  (``lodestar.sim`` camera frame: ``+z`` boresight).
* ``database``: a :class:`lodestar.firmware.database.Database` whose image serves the method
  (its ``methods`` bit; ``lodestar.ground.database.build_database(methods=...)``).
* ``tolerance_rad``: largest direction error of one observed star (centroid noise and
  calibration residuals); it is both the verification match radius and the base of every
  method's pattern tolerance.  Default ``fov_h / 1000`` of the database (2.5 px for
  estcube2).
* ``budget``: the deterministic cap on patterns tried (star triples for Pyramid and
  Triangle, star groups for Hashing).
* ``options``: method specific (all: ``max_stars``, ``max_mismatch_prob``,
  ``distinct_rad``).

Methods (:data:`METHODS`):

* ``'pyramid'``: Mortari's Pyramid over the pair k-vector (:mod:`lodestar.firmware.pyramid`);
* ``'triangle'``: Lohmann's planar triangle, area and polar moment over the triangle
  k-vector (:mod:`lodestar.firmware.triangle`);
* ``'hashing'``: Astrometry.net's geometric hash of 4 (or 3) star groups over the hash
  buckets (:mod:`lodestar.firmware.hashing`).

A method whose section the database lacks returns ``BAD_DATABASE``
(``status.DATABASE_UNSUPPORTED``); an unknown method name ``BAD_INPUT``.  Every method
shares the verification and the probability budget of :mod:`lodestar.firmware.verify`, and
every status is a :mod:`lodestar.firmware.status` code.

Pure Python for CPython and MicroPython.
"""

from .verify import (AMBIGUOUS, BAD_DATABASE, BAD_INPUT, BUDGET_EXHAUSTED, NO_MATCH, OK,
                     STATUS_NAMES, TOO_FEW_STARS, Solution, status_name)

METHODS = ("pyramid", "triangle", "hashing")

__all__ = ("identify", "Solution", "status_name", "STATUS_NAMES", "OK", "NO_MATCH",
           "TOO_FEW_STARS", "AMBIGUOUS", "BUDGET_EXHAUSTED", "BAD_INPUT", "BAD_DATABASE",
           "METHODS")


def identify(vectors, database, method="pyramid", tolerance_rad=None, budget=2000, **options):
    """Identify the observed stars; returns a :class:`Solution` (never raises for bad
    input: ``BAD_INPUT``; a method the database does not serve: ``BAD_DATABASE``)."""
    if tolerance_rad is None:
        tolerance_rad = database.fov_h / 1000.0
    if method == "pyramid":
        from . import pyramid as module
    elif method == "triangle":
        from . import triangle as module
    elif method == "hashing":
        from . import hashing as module
    else:
        return Solution(BAD_INPUT)
    return module.identify(vectors, database, tolerance_rad, budget, **options)
