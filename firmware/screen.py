"""The last check of a solution's matches before ``OK``: a match its own fit or the sky's
brightness order contradicts is not named.

A false star (a cosmic ray, a satellite, a hot-pixel cluster) that happens to lie within the
match tolerance of a catalogue star too faint to be seen would take that star's name.  Two
tests catch it (``docs/firmware.md``, Match screen):

* :func:`residual_outliers`: the tolerance is several centroid sigmas wide, so a chance
  neighbour lies anywhere in it while the real stars cluster near their predicted places: a
  match whose squared residual over its expected variance (the fit's share of it taken out:
  :func:`leverages`) exceeds :data:`OUTLIER_CHI2` times the matches' median (a robust noise
  scale) is an outlier;
* :func:`brightness_outliers`: a match observed brighter than several matched stars that the
  catalogue makes far brighter than it (:data:`MAG_SLACK`) contradicts the sky's brightness
  order.

Pure Python for CPython and MicroPython; the per-match loops are ``@native``
(:mod:`lodestar.firmware.emit`).
"""

from .emit import native

MEDIAN_CHI2_2 = 1.386
"""The median of a chi-square of 2 degrees of freedom (a residual's two axes): the median of
the matches' normalised squared residuals over it estimates their noise variance."""
OUTLIER_CHI2 = 25.0
"""A match whose squared residual exceeds this many noise variances (5 sigma over two axes;
chance 4e-6 for a real star) is an outlier."""
MAG_SLACK = 2.0
"""A matched star observed brighter than another whose catalogue magnitude is this much
brighter contradicts the brightness order (beyond blends, colour and noise)."""
MIN_CONTRADICTIONS = 3
"""Fewest such contradictions, and more than half the matched stars observed fainter, that
make a match a brightness outlier."""


def _median(values):
    v = sorted(values)
    k = len(v)
    return v[k // 2] if k % 2 else 0.5 * (v[k // 2 - 1] + v[k // 2])


@native
def leverages(vectors, w):
    """Each match's leverage ``h_i`` in an attitude fit (its share of the fit, which absorbs
    that share of its own error: a residual's variance is ``sigma^2 (1 - h_i)``): the
    weight's share ``w_i / sum w`` of the two cross-boresight axes, which move every star
    alike, plus half (one of a star's two axes is tangential) its share ``w_i rho_i^2 /
    sum w rho^2`` of the roll about the weighted mean direction, ``rho_i`` a star's angle
    from it.  ``vectors``: unit vectors of the matches, ``w``: their relative weights."""
    n = len(vectors)
    total = cx = cy = cz = 0.0
    for i in range(n):
        v, wi = vectors[i], w[i]
        total += wi
        cx += wi * v[0]
        cy += wi * v[1]
        cz += wi * v[2]
    norm = (cx * cx + cy * cy + cz * cz) ** 0.5
    if not total > 0 or not norm > 0:
        return [0.0] * n
    rho2 = []
    spread = 0.0
    for i in range(n):
        v = vectors[i]
        c = (v[0] * cx + v[1] * cy + v[2] * cz) / norm
        rho2.append(max(1.0 - c * c, 0.0))
        spread += w[i] * rho2[-1]
    out = []
    for i in range(n):
        out.append(w[i] / total + (0.5 * w[i] * rho2[i] / spread if spread > 0 else 0.0))
    return out


def residual_outliers(chi2s):
    """Indices of the matches whose normalised squared residual ``chi2s[i]`` (``|e_i|^2``
    over the star's relative variance, any common scale) exceeds :data:`OUTLIER_CHI2` noise
    variances, the variance the matches' median over :data:`MEDIAN_CHI2_2`.  Fewer than 5
    matches: none (the median is no scale)."""
    if len(chi2s) < 5:
        return []
    scale = _median(chi2s) / MEDIAN_CHI2_2
    if not scale > 0:
        return []
    limit = OUTLIER_CHI2 * scale
    out = []
    for i in range(len(chi2s)):
        if chi2s[i] > limit:
            out.append(i)
    return out


@native
def brightness_outliers(fluxes, mags):
    """Indices of the matches observed brighter (``fluxes``) than at least
    :data:`MIN_CONTRADICTIONS`, and more than half, of the matched stars observed fainter,
    whose catalogue magnitudes ``mags`` are :data:`MAG_SLACK` brighter than theirs.  A match
    without a positive flux is not judged."""
    out = []
    n = len(fluxes)
    for i in range(n):
        fi = fluxes[i]
        if not fi > 0:
            continue
        fainter = bad = 0
        for j in range(n):
            if j != i and 0 < fluxes[j] < fi:
                fainter += 1
                if mags[j] < mags[i] - MAG_SLACK:
                    bad += 1
        if bad >= MIN_CONTRADICTIONS and 2 * bad > fainter:
            out.append(i)
    return out
