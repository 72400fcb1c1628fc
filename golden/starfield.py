"""Seeded synthetic star frames for the built-in detection run and the benchmarks.

A deliberately small image model (the full simulator with catalogue, optics, motion and the
sensor's defects is ``lodestar.sim``'s job): stars are Gaussian PSFs *integrated over each
pixel* (differences of the error function, not samples at pixel centres) on a flat
background, with Poisson shot noise, Gaussian read noise, rounding to ADU and clipping at
full scale.  Units: positions in pixels (contract convention, pixel centre at the integer
index), flux in ADU summed over the whole PSF.
"""

import numpy as np
from scipy.special import erf

from lodestar import contract as C


class Star:
    """One rendered star: centre ``(x, y)`` in pixels and total ``flux`` in ADU."""

    __slots__ = ("x", "y", "flux")

    def __init__(self, x, y, flux):
        self.x, self.y, self.flux = x, y, flux

    def __repr__(self):
        return f"Star(x={self.x:.3f}, y={self.y:.3f}, flux={self.flux:.1f})"


def _pixel_fractions(centre, sigma, lo, hi):
    """Fraction of a 1-D Gaussian's mass inside each pixel ``lo .. hi - 1``."""
    edges = (np.arange(lo, hi + 1) - 0.5 - centre) / (sigma * np.sqrt(2.0))
    return 0.5 * np.diff(erf(edges))


def star_frame(width=2592, height=1944, pixel_bits=12, n_stars=100, seed=0, sigma=1.2,
               flux_range=(2e3, 2e5), background=40.0, read_noise=4.0, gain=1.0):
    """Render a frame; returns ``(frame, stars)``.

    ``frame`` is ``uint16`` (height, width) with values in ``0 .. full_scale(pixel_bits)``;
    ``stars`` lists the ``Star`` truths, brightest first.  Fluxes are log-uniform in
    ``flux_range`` (ADU); ``background`` is the mean level in ADU, ``read_noise`` its
    Gaussian sigma in ADU, ``gain`` electrons per ADU for the shot noise.
    """
    if pixel_bits not in C.PIXEL_BITS:
        raise ValueError(f"pixel_bits={pixel_bits} is not one of {C.PIXEL_BITS}")
    if sigma <= 0 or gain <= 0 or read_noise < 0 or background < 0:
        raise ValueError("sigma and gain must be > 0, read_noise and background >= 0")
    rng = np.random.default_rng(seed)
    margin = 2.0
    xs = rng.uniform(margin, width - 1 - margin, n_stars)
    ys = rng.uniform(margin, height - 1 - margin, n_stars)
    fluxes = np.exp(rng.uniform(np.log(flux_range[0]), np.log(flux_range[1]), n_stars))
    order = np.argsort(-fluxes)
    stars = [Star(float(xs[i]), float(ys[i]), float(fluxes[i])) for i in order]

    signal = np.full((height, width), background, dtype=np.float64)
    reach = int(np.ceil(5 * sigma))
    for s in stars:
        x0, x1 = max(int(s.x) - reach, 0), min(int(s.x) + reach + 2, width)
        y0, y1 = max(int(s.y) - reach, 0), min(int(s.y) + reach + 2, height)
        stamp = np.outer(_pixel_fractions(s.y, sigma, y0, y1), _pixel_fractions(s.x, sigma, x0, x1))
        signal[y0:y1, x0:x1] += s.flux * stamp
    electrons = rng.poisson(signal * gain).astype(np.float64)
    adu = electrons / gain + rng.normal(0.0, read_noise, signal.shape)
    frame = np.clip(np.rint(adu), 0, C.full_scale(pixel_bits)).astype(np.uint16)
    return frame, stars
