"""Lost-in-space star identification: the registry of methods and the one entry point.

``identify(vectors, database, method='pyramid', tolerance_rad=None, budget=2000, **options)``
returns a :class:`Solution` (``status``, ``q``, ``matches``, ``patterns_tried``,
``probability``, ``star_ids``; :mod:`.search`).

* ``vectors``: camera-frame unit vectors of the observed stars, **brightest first**
  (``+z`` boresight).
* ``database``: a :class:`lodestar.firmware.database.Database` serving the method (its
  ``methods`` has the method's bit).
* ``tolerance_rad``: largest direction error of one observed star: the verification's match
  radius and the base of every pattern tolerance.  Default ``fov_h / 1000``.
* ``budget``: deterministic cap on the patterns tried.
* ``max_work``: the work budget (:mod:`.search` units); None: the method's ``MAX_WORK``.
* ``options``: ``max_stars``, ``max_mismatch_prob``, ``distinct_rad``, ``streaks``.

:data:`METHODS` names the methods of the contract's one table
(:data:`lodestar.contract.stardb.METHOD_TABLE`, which also names each method's module):
``'pyramid'`` (Mortari's Pyramid, :mod:`.pyramid`), ``'triangle'`` (Lohmann's planar
triangles, :mod:`.triangle`), ``'hashing'`` (Astrometry.net's geometric hash, :mod:`.hashing`).
A method module exports ``DATABASE_BIT``, ``MAX_WORK`` (its default work budget) and
``identify``, which calls :func:`.search.identify_with` with its :class:`.search.Search`
subclass.  Statuses are
:mod:`lodestar.firmware.status` codes: ``BAD_INPUT`` for an unknown method,
``DATABASE_UNSUPPORTED`` for a database without the method's section.
Pure Python for CPython and MicroPython.
"""

from lodestar.contract.stardb import METHOD_TABLE, METHODS

from .. import status as S
from .search import Solution

MAX_TOLERANCE_FRACTION = 0.05
"""Largest match tolerance as a fraction of the horizontal field (1 deg of a 20 deg field):
beyond it a pattern matches too much of the sky to identify anything."""


def max_tolerance_rad(fov_h):
    """The widest match tolerance (rad) for a horizontal field of ``fov_h`` rad."""
    return MAX_TOLERANCE_FRACTION * fov_h


def method(name):
    """The module of identification method ``name`` (``identify``, ``DATABASE_BIT``), or
    None for a name not in :data:`METHODS`: the module the contract's table names, imported
    on first use (a flight image running one method keeps no other method's code on its
    heap)."""
    if name not in METHODS:
        return None
    return __import__(METHOD_TABLE[METHODS.index(name)][2], None, None, ("identify",))


_method = method        # identify's parameter ``method`` shadows the name


def identify(vectors, database, method="pyramid", tolerance_rad=None, budget=2000,
             max_work=None, **options):
    """Identify the observed stars; returns a :class:`Solution` (bad input: ``BAD_INPUT``;
    a method the database does not serve: ``DATABASE_UNSUPPORTED``; ``budget`` patterns or
    ``max_work`` units of work spent: ``BUDGET_EXHAUSTED``).  A tolerance wider than
    :data:`MAX_TOLERANCE_FRACTION` of the field is ``BAD_INPUT``: it would match anything."""
    module = _method(method)
    if module is not None and max_work is None:
        max_work = module.MAX_WORK              # the method's own budget
    if module is None or isinstance(max_work, bool) or not isinstance(max_work, int) or \
            max_work < 1:
        return Solution(S.BAD_INPUT)
    fov = getattr(database, "fov_h", None)      # None: the method reports the database
    if tolerance_rad is None and fov is not None:
        tolerance_rad = fov / 1000.0
    elif fov is not None and isinstance(tolerance_rad, (int, float)) and \
            tolerance_rad > max_tolerance_rad(fov):
        return Solution(S.BAD_INPUT)
    return module.identify(vectors, database, tolerance_rad, budget, max_work=max_work,
                           **options)
