"""Quaternions for the MCU (pure Python: ``math`` only; 3-vectors: :mod:`.geometry`).

Convention (shared with ``lodestar.sim``)
-----------------------------------------
* A quaternion is a 4-sequence ``q = [x, y, z, w]``: vector part first, **scalar last** (the
  order of ``scipy.spatial.transform.Rotation``).  Functions return plain lists of floats.
* An attitude quaternion is the rotation that takes **inertial** vectors into the **camera**
  frame: ``v_cam = rotate(q, v_in) = to_matrix(q) v_in``, the same as
  ``Rotation.from_quat(q).apply(v_in)``.
* ``to_matrix(q)`` is therefore Shuster's attitude matrix ``A`` (``b = A r``).  Shuster's own
  quaternion of the same ``A`` is the conjugate ``[-x, -y, -z, w]``: his formula
  ``A = (q4^2 - |q|^2) I + 2 q q^T - 2 q4 [q x]`` has a minus sign where ours has a plus.
* ``multiply(p, q)`` is the Hamilton product, so rotating by ``multiply(p, q)`` is rotating by
  ``q`` first and then by ``p`` (scipy's ``Rotation(p) * Rotation(q)``).
* ``q`` and ``-q`` are the same rotation; :func:`canonical` picks ``w >= 0``.
* Angles are in radians.  :func:`to_matrix` gives three row lists, :func:`matrix` the
  row-major 9-tuple of the flight loops.

Everything here runs unchanged on CPython and MicroPython: no numpy, typing or dataclasses.
Inputs may be any indexable sequences of numbers (lists, tuples, numpy arrays on CPython).
"""

import math

from .emit import native
from .geometry import EPS, finite, is_number, normalise_vector

ORTHONORMAL_TOLERANCE = max(1e-6, 64.0 * EPS)
"""Largest accepted ``|A^T A - I|`` element (and ``|det A - 1|``) in :func:`from_matrix`."""


def _checked(q):
    """``q`` as 4 floats plus its squared norm; ``ValueError`` if not finite or zero."""
    if len(q) != 4:
        raise ValueError("quaternion must have 4 components [x, y, z, w], got %d" % len(q))
    x, y, z, w = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    n2 = x * x + y * y + z * z + w * w
    if not finite(n2):
        raise ValueError("quaternion is not finite: %r" % ([x, y, z, w],))
    if n2 == 0.0:
        raise ValueError("quaternion is zero")
    return x, y, z, w, n2


def normalise(q):
    """Unit quaternion along ``q`` (a list ``[x, y, z, w]``).

    Raises ``ValueError`` if ``q`` does not have 4 components, is zero or contains NaN/inf.
    The sign is kept (see :func:`canonical`).
    """
    x, y, z, w, n2 = _checked(q)
    n = math.sqrt(n2)
    return [x / n, y / n, z / n, w / n]


def canonical(q):
    """Unit quaternion of the same rotation with ``w >= 0`` (ties at ``w == 0`` keep the sign)."""
    q = normalise(q)
    if q[3] < 0.0:
        return [-q[0], -q[1], -q[2], -q[3]]
    return q


def conjugate(q):
    """Conjugate ``[-x, -y, -z, w]``: the inverse rotation for a unit quaternion.

    It also converts between our quaternion and Shuster's quaternion of the same attitude
    matrix (see the module docstring).
    """
    return [-q[0], -q[1], -q[2], q[3]]


@native
def multiply(p, q):
    """Hamilton product ``p (x) q`` (scalar last): the rotation ``q`` followed by ``p``.

    ``rotate(multiply(p, q), v) == rotate(p, rotate(q, v))`` and
    ``to_matrix(multiply(p, q)) == to_matrix(p) to_matrix(q)``.
    """
    px, py, pz, pw = p[0], p[1], p[2], p[3]
    qx, qy, qz, qw = q[0], q[1], q[2], q[3]
    return [pw * qx + qw * px + py * qz - pz * qy,
            pw * qy + qw * py + pz * qx - px * qz,
            pw * qz + qw * pz + px * qy - py * qx,
            pw * qw - px * qx - py * qy - pz * qz]


@native
def matrix(q):
    """Attitude matrix ``A`` of a **unit** ``q`` as a row-major 9-tuple (``v_cam = A v_in``):
    ``A = (w^2 - |v|^2) I + 2 v v^T + 2 w [v x]`` for ``q = [v, w]``, in the form the flight
    loops use (no normalisation, no checks)."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    return (1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y))


def to_matrix(q):
    """Attitude matrix ``A`` (3 row lists) with ``v_cam = A v_in``; equals scipy's ``as_matrix``.

    :func:`matrix` of ``q`` normalised first; zero or non-finite ``q`` raises ``ValueError``.
    """
    m = matrix(normalise(q))
    return [list(m[0:3]), list(m[3:6]), list(m[6:9])]


def rotate(q, v):
    """``A(q) v`` as a list: an inertial vector ``v`` expressed in the camera frame.

    Uses ``t = 2 u x v``, ``v' = v + w t + u x t`` (``q = [u, w]``), divided through by
    ``|q|^2`` so a non-unit ``q`` is normalised implicitly; zero or non-finite ``q`` raises.
    """
    x, y, z, w, n2 = _checked(q)
    s = 2.0 / n2
    v0, v1, v2 = v[0], v[1], v[2]
    t0 = s * (y * v2 - z * v1)
    t1 = s * (z * v0 - x * v2)
    t2 = s * (x * v1 - y * v0)
    return [v0 + w * t0 + y * t2 - z * t1,
            v1 + w * t1 + z * t0 - x * t2,
            v2 + w * t2 + x * t1 - y * t0]


def from_matrix(m, tol=ORTHONORMAL_TOLERANCE):
    """Unit quaternion ``[x, y, z, w]`` (``w >= 0``) of the rotation matrix ``m`` (``b = m r``).

    Shepperd's method: the largest of ``w^2, x^2, y^2, z^2`` (read off the trace and the
    diagonal) is taken from a square root and the other three from the off-diagonal sums and
    differences, so no division by a small number ever occurs.  ``m`` must be a proper
    rotation: ``ValueError`` if it is not 3x3, not finite, or ``m^T m`` differs from ``I`` (or
    ``det m`` from 1) by more than ``tol``.
    """
    if len(m) != 3:
        raise ValueError("matrix must have 3 rows, got %d" % len(m))
    a = []
    for i in range(3):
        row = m[i]
        if len(row) != 3:
            raise ValueError("matrix row %d must have 3 elements, got %d" % (i, len(row)))
        for j in range(3):
            e = float(row[j])
            if not finite(e):
                raise ValueError("matrix element [%d][%d] is not finite" % (i, j))
            a.append(e)
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = a
    worst = 0.0
    for i in range(3):
        for j in range(i, 3):
            g = a[i] * a[j] + a[3 + i] * a[3 + j] + a[6 + i] * a[6 + j]
            if i == j:
                g -= 1.0
            if abs(g) > worst:
                worst = abs(g)
    det = (m00 * (m11 * m22 - m12 * m21) - m01 * (m10 * m22 - m12 * m20)
           + m02 * (m10 * m21 - m11 * m20))
    if worst > tol or abs(det - 1.0) > tol:
        raise ValueError("matrix is not a rotation (|M^T M - I| = %.3g, det = %.9g)"
                         % (worst, det))
    tr = m00 + m11 + m22
    if tr >= m00 and tr >= m11 and tr >= m22:
        w = 0.5 * math.sqrt(max(1.0 + tr, 0.0))
        f = 0.25 / w
        q = [(m21 - m12) * f, (m02 - m20) * f, (m10 - m01) * f, w]
    elif m00 >= m11 and m00 >= m22:
        x = 0.5 * math.sqrt(max(1.0 + 2.0 * m00 - tr, 0.0))
        f = 0.25 / x
        q = [x, (m01 + m10) * f, (m02 + m20) * f, (m21 - m12) * f]
    elif m11 >= m22:
        y = 0.5 * math.sqrt(max(1.0 + 2.0 * m11 - tr, 0.0))
        f = 0.25 / y
        q = [(m01 + m10) * f, y, (m12 + m21) * f, (m02 - m20) * f]
    else:
        z = 0.5 * math.sqrt(max(1.0 + 2.0 * m22 - tr, 0.0))
        f = 0.25 / z
        q = [(m02 + m20) * f, (m12 + m21) * f, z, (m10 - m01) * f]
    return canonical(q)


def angle_between(q1, q2):
    """Angle in radians (``0 .. pi``) of the rotation taking attitude ``q1`` to ``q2``.

    Computed as ``2 atan2(|vec(d)|, |scalar(d)|)`` with ``d = q2 (x) conj(q1)`` (both
    normalised first), which stays accurate for tiny angles where ``acos`` would not.
    ``q`` and ``-q`` count as the same attitude.
    """
    a = normalise(q1)
    b = normalise(q2)
    d = multiply(b, conjugate(a))
    s = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    return 2.0 * math.atan2(s, abs(d[3]))


def from_axis_angle(axis, angle):
    """Unit quaternion of a right-handed rotation by ``angle`` (rad) about ``axis``."""
    u = normalise_vector(axis)
    h = 0.5 * float(angle)
    if not finite(h):
        raise ValueError("angle is not finite")
    s = math.sin(h)
    return [u[0] * s, u[1] * s, u[2] * s, math.cos(h)]


def from_rotation_vector(rotvec):
    """Unit quaternion of the rotation vector ``rotvec`` (axis times angle, rad); below
    1e-12 rad the first-order ``[rotvec / 2, 1]``."""
    x, y, z = rotvec[0], rotvec[1], rotvec[2]
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-12:
        return [0.5 * x, 0.5 * y, 0.5 * z, 1.0]
    s = math.sin(0.5 * angle) / angle
    return [x * s, y * s, z * s, math.cos(0.5 * angle)]


def unit_quaternion(q):
    """``q`` as a unit list ``[x, y, z, w]`` (``w >= 0``), or None when it is not four finite
    numbers with a non-zero norm (the never-raising form of :func:`canonical` for inputs
    from outside)."""
    try:
        if len(q) != 4:
            return None
        x, y, z, w = q[0], q[1], q[2], q[3]
    except MemoryError:
        raise
    except Exception:             # no length, or an item that fails to read
        return None
    if not (is_number(x) and is_number(y) and is_number(z) and is_number(w)):
        return None
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not (n > 0.0 and finite(n)):
        return None
    if w < 0:
        n = -n
    return [x / n, y / n, z / n, w / n]
