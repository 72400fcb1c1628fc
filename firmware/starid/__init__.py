"""Lost-in-space star identification: the registry of methods and the one entry point.

``identify(vectors, database, method='pyramid', tolerance_rad=None, budget=2000, **options)``
returns a :class:`Solution` (``status``, ``q``, ``matches``, ``patterns_tried``,
``probability``, ``star_ids``; :mod:`.search`).

* ``vectors``: camera-frame unit vectors of the observed stars, **brightest first**
  (``+z`` boresight).
* ``database``: a :class:`lodestar.firmware.database.Database` serving the method (its
  ``methods`` bit, the method module's ``DATABASE_BIT``).
* ``tolerance_rad``: largest direction error of one observed star: the verification's match
  radius and the base of every pattern tolerance.  Default ``fov_h / 1000``.
* ``budget``: deterministic cap on the patterns tried.
* ``options``: ``max_stars``, ``max_mismatch_prob``, ``distinct_rad``, ``streaks``.

:data:`METHODS` (the contract's one list) names the methods: ``'pyramid'`` (Mortari's
Pyramid, :mod:`.pyramid`), ``'triangle'`` (Lohmann's planar triangles, :mod:`.triangle`),
``'hashing'`` (Astrometry.net's geometric hash, :mod:`.hashing`).  Statuses are
:mod:`lodestar.firmware.status` codes: ``BAD_INPUT`` for an unknown method,
``DATABASE_UNSUPPORTED`` for a database without the method's section.
Pure Python for CPython and MicroPython.
"""

from lodestar.contract.stardb import METHODS

from .. import status as S
from . import hashing, pyramid, triangle
from .search import Solution

_MODULES = {"pyramid": pyramid, "triangle": triangle, "hashing": hashing}
"""The registry: each of the contract's :data:`METHODS` -> its module."""
if sorted(_MODULES) != sorted(METHODS):
    raise ImportError("starid: the registry does not match contract.stardb.METHODS")


def method(name):
    """The module of identification method ``name`` (``identify``, ``DATABASE_BIT``), or
    None for a name not in :data:`METHODS`."""
    return _MODULES.get(name)


def identify(vectors, database, method="pyramid", tolerance_rad=None, budget=2000, **options):
    """Identify the observed stars; returns a :class:`Solution` (bad input: ``BAD_INPUT``;
    a method the database does not serve: ``DATABASE_UNSUPPORTED``)."""
    if tolerance_rad is None:
        tolerance_rad = database.fov_h / 1000.0
    module = _MODULES.get(method)
    if module is None:
        return Solution(S.BAD_INPUT)
    return module.identify(vectors, database, tolerance_rad, budget, **options)
