"""Attitude quaternions in the ``lodestar.sim`` convention, built on scipy's ``Rotation``.

Quaternions and frames as ``docs/conventions.md``: ``q = [x, y, z, w]`` with
``v_cam = Rotation.from_quat(q).apply(v_inertial)``.  Pointing angles ``(ra, dec, roll)`` in
degrees: the boresight at ``(ra, dec)``, roll 0 showing north up and east left, positive roll
a right-handed turn about ``+z`` (``docs/simulator.md`` gives the camera axes and the poles).
Every function accepts one quaternion ``(4,)`` or a stack ``(N, 4)``; NaN, inf or non-unit
quaternions (norm off by more than :data:`UNIT_TOLERANCE`) raise ``ValueError``.
"""

import numpy as np
from scipy.spatial.transform import Rotation

UNIT_TOLERANCE = 1e-6
"""Largest accepted ``| |q| - 1 |``."""


def _rotation(q):
    q = np.asarray(q, dtype=float)
    if q.ndim not in (1, 2) or q.shape[-1] != 4:
        raise ValueError(f"quaternion must have shape (4,) or (N, 4), got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise ValueError("quaternion contains NaN or inf")
    norm = np.linalg.norm(q, axis=-1)
    if np.any(np.abs(norm - 1) > UNIT_TOLERANCE):
        raise ValueError(f"quaternion is not unit length (norm {np.ravel(norm)[0]!r} ...)")
    return Rotation.from_quat(q)


def _sky_axes(ra, dec):
    """Inertial ``(boresight, east, north)`` unit vectors at ``(ra, dec)`` in radians."""
    cr, sr, cd, sd = np.cos(ra), np.sin(ra), np.cos(dec), np.sin(dec)
    boresight = np.stack([cd * cr, cd * sr, sd], axis=-1)
    east = np.stack([-sr, cr, np.zeros_like(ra)], axis=-1)
    north = np.stack([-sd * cr, -sd * sr, cd], axis=-1)
    return boresight, east, north


def from_radec_roll(ra_deg, dec_deg, roll_deg):
    """Quaternion(s) ``[x, y, z, w]`` pointing the boresight at ``(ra, dec)`` with ``roll``.

    Angles in degrees, scalars or arrays (broadcast); returns ``(4,)`` for scalars and
    ``(..., 4)`` otherwise.  ``dec`` must lie in ``[-90, 90]``; NaN or inf raise ``ValueError``.
    """
    ra, dec, roll = np.broadcast_arrays(*(np.asarray(a, dtype=float)
                                          for a in (ra_deg, dec_deg, roll_deg)))
    if not all(np.all(np.isfinite(a)) for a in (ra, dec, roll)):
        raise ValueError("ra, dec and roll must be finite")
    if np.any(np.abs(dec) > 90):
        raise ValueError("dec must lie in [-90, 90] degrees")
    b, e, n = _sky_axes(np.radians(ra), np.radians(dec))
    cr, sr = np.cos(np.radians(roll))[..., None], np.sin(np.radians(roll))[..., None]
    rows = np.stack([-cr * e - sr * n, sr * e - cr * n, b], axis=-2)  # attitude matrix A
    q = Rotation.from_matrix(rows.reshape(-1, 3, 3)).as_quat(canonical=True)
    return q.reshape(ra.shape + (4,))


def boresight(q):
    """Inertial unit vector(s) of the camera boresight ``+z`` (the third row of ``A``)."""
    return _rotation(q).inv().apply([0.0, 0.0, 1.0])


def to_radec_roll(q):
    """``(ra, dec, roll)`` in degrees of quaternion(s) ``q``: the inverse of
    :func:`from_radec_roll`, with ``ra`` in ``[0, 360)``, ``dec`` in ``[-90, 90]`` and
    ``roll`` in ``(-180, 180]``.  Scalars for one quaternion, arrays for a stack."""
    a = _rotation(q).as_matrix()
    x_cam, z_cam = a[..., 0, :], a[..., 2, :]
    ra = np.arctan2(z_cam[..., 1], z_cam[..., 0])
    dec = np.arcsin(np.clip(z_cam[..., 2], -1.0, 1.0))
    _, e, n = _sky_axes(ra, dec)
    roll = np.arctan2(-np.sum(x_cam * n, axis=-1), -np.sum(x_cam * e, axis=-1))
    ra_deg = np.degrees(ra) % 360.0
    ra_deg = np.where(ra_deg >= 360.0, 0.0, ra_deg)   # -1e-17 % 360 rounds to 360
    roll_deg = np.degrees(roll)
    roll_deg = np.where(roll_deg <= -180.0, roll_deg + 360.0, roll_deg)
    return ra_deg[()], np.degrees(dec)[()], roll_deg[()]


def random_attitude(rng, n=None):
    """Attitude(s) uniform on SO(3) (Haar measure) from the numpy Generator ``rng``.

    A normalised 4-D Gaussian is uniform on the unit 3-sphere, hence its rotation is uniform
    on SO(3).  Returns ``(4,)`` for ``n=None``, else ``(n, 4)``; scalar part ``w >= 0``.
    """
    q = rng.standard_normal((1 if n is None else n, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    return q[0] if n is None else q
