"""Analyses that reproduce the seed theses' numbers from first principles.

* Schumann 2019 (Eq 3.1, L339-367): a 4-connected cluster of ``size`` lit pixels through a
  given pixel can take ``cluster_shapes_through_pixel(size)`` shapes (1296 for size 6: 216
  fixed hexominoes x 6 cells), so the chance that noise alone lights such a cluster is
  ``false_blob_probability(p, size)`` ~ 1296 p**6 for a per-pixel tail probability ``p``.
"""

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
