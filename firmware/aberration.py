"""Stellar aberration: the apparent direction of a star seen by an observer moving at
``velocity`` (km/s, ICRS axes: the Earth's barycentric velocity plus the satellite's).

First order in ``beta = v / c``: apparent ``p = u + beta - (u . beta) u`` from the geometric
(catalogue, ICRS) direction ``u``, and back ``u = p - beta + (p . beta) p``.  The exact
(relativistic) formula differs by terms of order ``beta^2`` (at most ``1.2e-7`` rad =
0.023" at :data:`MAX_SPEED_KM_S`, 0.002" at the Earth's 30 km/s), below float32's resolution
of a unit vector (``2^-24`` = 6e-8 rad = 0.012"); and the first-order form adds a small
vector ``beta_perp`` (~1e-4) to ``u`` without the ``sqrt(1 - beta^2)`` and
``1 + u . beta`` factors that round to 1 in single precision.  ``|p|`` is 1 to ``beta^2``:
no normalisation.  What is corrected and what is not: ``docs/apparent_directions.md``.
Pure Python for CPython and MicroPython (no allocation but the vector returned).
"""

import math

SPEED_OF_LIGHT_KM_S = 299792.458
"""``c``, km/s (exact, SI)."""
MAX_SPEED_KM_S = 100.0
"""Fastest accepted observer speed: the Earth's orbital 29.3-30.3 km/s plus a satellite's
at most 11 km/s, with margin; beyond it the first-order form loses 0.02"."""


def beta(velocity_km_s):
    """``(bx, by, bz) = velocity / c`` of an observer velocity given as 3 finite numbers
    (km/s) no faster than :data:`MAX_SPEED_KM_S`; None for anything else."""
    try:
        if len(velocity_km_s) != 3:
            return None
        vx, vy, vz = float(velocity_km_s[0]), float(velocity_km_s[1]), float(velocity_km_s[2])
    except MemoryError:
        raise
    except Exception:       # not numbers, an int no float holds, an item that fails to read
        return None
    speed = math.sqrt(vx * vx + vy * vy + vz * vz)
    if not speed <= MAX_SPEED_KM_S:             # also NaN and inf
        return None
    c = SPEED_OF_LIGHT_KM_S
    return vx / c, vy / c, vz / c


def aberrate(u, b):
    """Apparent direction ``u + b - (u . b) u`` of the unit geometric direction ``u`` for an
    observer of velocity ``b = v / c`` (:func:`beta`), in the same axes."""
    d = u[0] * b[0] + u[1] * b[1] + u[2] * b[2]
    return u[0] + b[0] - d * u[0], u[1] + b[1] - d * u[1], u[2] + b[2] - d * u[2]


def deaberrate(p, b):
    """Geometric direction ``p - b + (p . b) p`` of the unit apparent direction ``p`` (the
    inverse of :func:`aberrate` to order ``b^2``), in the axes of ``b``."""
    d = p[0] * b[0] + p[1] * b[1] + p[2] * b[2]
    return p[0] - b[0] + d * p[0], p[1] - b[1] + d * p[1], p[2] - b[2] + d * p[2]
