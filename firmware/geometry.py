"""3-vector and rotation helpers shared by the firmware, and the finite-number test.

Vectors are any indexable 3-sequences of numbers; functions return tuples.  A rotation
matrix is a row-major 9-tuple (:func:`lodestar.firmware.quaternion.matrix`).  Angles are
radians.  The small-angle forms (:func:`angle`, :func:`chord`) stay accurate in
single precision, where ``acos`` of a dot product would not.  Pure Python (``math``, ``array``).
"""

import math
from array import array

from .emit import native


def _machine_epsilon():
    e = 1.0
    while 1.0 + 0.5 * e != 1.0:
        e *= 0.5
    return e


EPS = _machine_epsilon()
"""Machine epsilon of this interpreter's float: 2.2e-16 for double, 1.2e-7 on MicroPython
ports built with single-precision floats (tolerances scale with it)."""

RAD_TO_ARCSEC = 180.0 * 3600.0 / math.pi

FLOAT_CODE = "f" if EPS > 1e-10 else "d"
"""``array`` typecode of this interpreter's float: buffers of computed values hold them
unrounded (4 bytes each on a single-precision MCU, where a boxed float takes a 16-byte heap
block)."""


def zeros(n):
    """``array(FLOAT_CODE)`` of ``n`` zeros, allocated once at its final size: MicroPython
    grows an array 8 entries at a time (``append``) or exactly (``extend``) and each move
    leaves a hole in the heap; built from a ``range`` (sized by its length, no temporary
    buffer) and cleared."""
    out = array(FLOAT_CODE, range(n))
    for i in range(n):
        out[i] = 0.0
    return out


@native
def finite(x):
    """True for a finite number: ``inf - inf`` and ``nan - nan`` are nan, and nan is not 0
    (MicroPython has no ``math.isfinite`` on every port)."""
    return x - x == 0


_NUMBER_TYPES = (int, float)
MAX_INT = 3.4e38
"""Largest magnitude of an ``int`` taken as a number: about the largest float32 (the MCU's
float), so ``float()`` of a number is finite on every build; a larger int (``10**400``)
would raise ``OverflowError`` or become infinite where it is used as a float."""


_TUPLE = tuple
_FLOAT = float
_INT = int
"""Builtins under module names for the per-star type tests (:func:`is_number`,
:func:`is_unit_tuple`): a module global is one dictionary lookup, a builtin two."""
_UNIT_TOL = 4.0 * EPS


@native
def is_number(x):
    """True for an int or float (not a bool) that is finite, an int at most
    :data:`MAX_INT` in magnitude.  An exact ``float`` takes the first test alone: this runs
    for every coordinate of every star, and on MicroPython two ``isinstance`` calls and a
    ``finite`` call cost as much as twenty float operations."""
    t = x.__class__                 # type(x) would be a call
    if t is _FLOAT:
        return x - x == 0
    if t is _INT:
        return -MAX_INT <= x <= MAX_INT
    if isinstance(x, bool) or not isinstance(x, _NUMBER_TYPES):
        return False
    if isinstance(x, int):
        return -MAX_INT <= x <= MAX_INT
    return finite(x)


def vector3(v):
    """``v`` as a tuple of three floats, or None when it is not three finite numbers (also
    when it has no length or an item fails to read: it comes from outside)."""
    try:
        if len(v) != 3:
            return None
        x, y, z = v[0], v[1], v[2]
    except MemoryError:
        raise
    except Exception:
        return None
    if not (is_number(x) and is_number(y) and is_number(z)):
        return None
    return float(x), float(y), float(z)


@native
def dot(u, v):
    """Dot product of two 3-vectors."""
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


@native
def cross(u, v):
    """Cross product ``u x v`` of two 3-vectors."""
    return (u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0])


@native
def norm(v):
    """Euclidean length of a 3-vector (no overflow protection: star vectors are ~unit)."""
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def normalise_vector(v):
    """Unit 3-vector along ``v`` as a list; ``ValueError`` if ``v`` is zero or not finite."""
    if len(v) != 3:
        raise ValueError("vector must have 3 components, got %d" % len(v))
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    n = math.sqrt(x * x + y * y + z * z)
    if not finite(n):
        raise ValueError("vector is not finite: %r" % ([x, y, z],))
    if n == 0.0:
        raise ValueError("cannot normalise a zero vector")
    return [x / n, y / n, z / n]


@native
def unit(v):
    """Unit vector of ``v`` (a 3-sequence) as a tuple; None if zero or not finite."""
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    n = math.sqrt(x * x + y * y + z * z)
    if not (n > 0.0) or n != n or n == float("inf"):
        return None
    return x / n, y / n, z / n


@native
def is_unit_tuple(v):
    """True when ``v`` is a tuple of three floats of unit norm (to a few ulp): such a vector
    can be shared instead of normalised into a copy (an MCU heap then holds the observed
    stars' vectors once).  Types are read as ``__class__`` (``type(x)``, a call, would make
    the test twice as dear on the MCU: 43 against 20 ticks) and the norm without ``abs``."""
    if v.__class__ is not _TUPLE or len(v) != 3:
        return False
    x, y, z = v
    if not (x.__class__ is _FLOAT and y.__class__ is _FLOAT and z.__class__ is _FLOAT):
        return False
    d = x * x + y * y + z * z - 1.0
    return -_UNIT_TOL <= d <= _UNIT_TOL


@native
def chord(a, b):
    """``|a - b|``: the chord between two unit vectors."""
    dx, dy, dz = a[0] - b[0], a[1] - b[1], a[2] - b[2]
    return math.sqrt(dx * dx + dy * dy + dz * dz)


def within_cone(centre, held, d, radius):
    """True when the cone of ``radius`` (rad) about unit vector ``d`` lies inside the held
    cone of radius ``held`` about ``centre``: ``angle(centre, d) + radius <= held``, tested
    on the chord (accurate in single precision; no ``asin``).  Whether a cone query's stars
    can be reused for a nearby one."""
    dx, dy, dz = centre[0] - d[0], centre[1] - d[1], centre[2] - d[2]
    room = 2.0 * math.sin(0.5 * (held - radius))
    return dx * dx + dy * dy + dz * dz <= room * room


@native
def angle(a, b):
    """Angle between unit vectors ``a`` and ``b`` (rad), ``2 asin(|a - b| / 2)``."""
    h = 0.5 * chord(a, b)
    return 2.0 * math.asin(h if h < 1.0 else 1.0)


@native
def triple(a, b, c):
    """Triple product ``(a x b) . c``."""
    return ((a[1] * b[2] - a[2] * b[1]) * c[0] + (a[2] * b[0] - a[0] * b[2]) * c[1] +
            (a[0] * b[1] - a[1] * b[0]) * c[2])


def mat_vec(m, v):
    """``m v`` for a row-major 9-tuple ``m``."""
    return (m[0] * v[0] + m[1] * v[1] + m[2] * v[2],
            m[3] * v[0] + m[4] * v[1] + m[5] * v[2],
            m[6] * v[0] + m[7] * v[1] + m[8] * v[2])


@native
def residual2(m, b, r):
    """``|b - m r|^2`` (rad^2 for unit vectors): a camera vector ``b`` against a catalogue
    vector ``r`` under the attitude matrix ``m``."""
    dx = b[0] - (m[0] * r[0] + m[1] * r[1] + m[2] * r[2])
    dy = b[1] - (m[3] * r[0] + m[4] * r[1] + m[5] * r[2])
    dz = b[2] - (m[6] * r[0] + m[7] * r[1] + m[8] * r[2])
    return dx * dx + dy * dy + dz * dz


@native
def rotate_about(v, axis, angle):
    """``v`` rotated by ``angle`` (rad, right-handed) about the unit ``axis`` (Rodrigues),
    as a tuple."""
    c = math.cos(angle)
    s = math.sin(angle)
    ax, ay, az = axis
    vx, vy, vz = v
    k = (ax * vx + ay * vy + az * vz) * (1.0 - c)
    return (vx * c + (ay * vz - az * vy) * s + ax * k,
            vy * c + (az * vx - ax * vz) * s + ay * k,
            vz * c + (ax * vy - ay * vx) * s + az * k)
