"""Analyses that reproduce the seed theses' numbers from first principles.

* Schumann 2019 (Eq 3.1, L339-367): a 4-connected cluster of ``size`` lit pixels through a
  given pixel can take ``cluster_shapes_through_pixel(size)`` shapes (1296 for size 6: 216
  fixed hexominoes x 6 cells), so the chance that noise alone lights such a cluster is
  ``false_blob_probability(p, size)`` ~ 1296 p**6 for a per-pixel tail probability ``p``.
* Sky availability (Dzamba 2013 L1632: > 99.9 % of attitudes see >= 3 stars of V <= 5.75
  in a 7.5 deg half-angle field; Schumann 2019 L505: about 87 % see >= 3 stars of
  V <= 4.5 in the ESTCube-2 field): ``availability`` samples random attitudes.
"""

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import norm


def _fixed_polyominoes(size):
    """All fixed polyominoes of ``size`` cells, as frozensets of (x, y) normalised to the
    origin (translations identified, rotations and reflections distinct)."""
    shapes = {frozenset({(0, 0)})}
    for _ in range(size - 1):
        grown = set()
        for shape in shapes:
            for x, y in shape:
                for nx, ny in ((x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1)):
                    if (nx, ny) in shape:
                        continue
                    cells = shape | {(nx, ny)}
                    mx = min(c[0] for c in cells)
                    my = min(c[1] for c in cells)
                    grown.add(frozenset((cx - mx, cy - my) for cx, cy in cells))
        shapes = grown
    return shapes


def cluster_shapes_through_pixel(size):
    """Number of 4-connected clusters of exactly ``size`` pixels that contain a given pixel.

    Each fixed polyomino can be placed over the pixel with any of its ``size`` cells on it,
    so the count is ``size x (number of fixed polyominoes)``.
    """
    if size < 1:
        raise ValueError(f"size must be >= 1, got {size}")
    return size * len(_fixed_polyominoes(size))


def false_blob_probability(p, size=6):
    """Schumann's bound on the chance that noise lights a ``size``-pixel cluster through a
    pixel, ``cluster_shapes_through_pixel(size) * p**size`` (p: per-pixel probability)."""
    if not 0 <= p <= 1:
        raise ValueError(f"p must be a probability in [0, 1], got {p}")
    return cluster_shapes_through_pixel(size) * p ** size


def gaussian_tail(k_sigma):
    """One-sided tail probability of a Gaussian beyond ``k_sigma`` standard deviations."""
    return float(norm.sf(k_sigma))


def random_boresights(rng, count):
    """``count`` directions uniform on the sphere, (count, 3)."""
    v = rng.standard_normal((count, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def stars_in_view(star_vectors, boresights, half_fov_deg=None, camera=None, rolls=None):
    """Number of stars (rows of ``star_vectors``) in view of each boresight.

    Either a circular field of half-angle ``half_fov_deg`` (Dzamba's availability model), or
    the rectangular frame of ``camera`` at roll angles ``rolls`` (deg) about each boresight.
    """
    if (half_fov_deg is None) == (camera is None):
        raise ValueError("give exactly one of half_fov_deg and camera")
    if camera is None:
        cos_limit = np.cos(np.radians(half_fov_deg))
        return ((boresights @ star_vectors.T) >= cos_limit).sum(axis=1)
    from . import attitude

    ra = np.degrees(np.arctan2(boresights[:, 1], boresights[:, 0])) % 360.0
    dec = np.degrees(np.arcsin(np.clip(boresights[:, 2], -1.0, 1.0)))
    radius = np.cos(np.radians(camera.boresight_radius_deg()))
    counts = np.zeros(len(boresights), dtype=np.int64)
    for i, (a, d, r) in enumerate(zip(ra, dec, rolls)):
        near = star_vectors[star_vectors @ boresights[i] >= radius]
        if len(near):
            v_cam = Rotation.from_quat(attitude.from_radec_roll(a, d, r)).apply(near)
            counts[i] = camera.project(v_cam)[2].sum()
    return counts


def availability(star_vectors, n_min, samples, rng, half_fov_deg=None, camera=None):
    """Fraction of random attitudes with at least ``n_min`` stars in view, and its binomial
    standard error: ``(fraction, sigma)``."""
    boresights = random_boresights(rng, samples)
    rolls = rng.uniform(0.0, 360.0, samples) if camera is not None else None
    counts = stars_in_view(star_vectors, boresights, half_fov_deg, camera, rolls)
    fraction = float(np.mean(counts >= n_min))
    return fraction, float(np.sqrt(fraction * (1 - fraction) / samples))
