"""Noise-free image formation in electrons: pixel-integrated Gaussian stars along their tracks.

Images are ``float64`` arrays indexed ``[y, x]`` holding electrons; pixel ``(x, y)`` covers
``[x - 1/2, x + 1/2] x [y - 1/2, y + 1/2]`` (``docs/conventions.md``); times are seconds from
the start of row 0's exposure.  Each source's circular Gaussian PSF (``sigma_px``) is
integrated over every pixel along its track, under a global (``t_row = 0``) or rolling
shutter; a source fully inside the frame deposits exactly its ``electrons`` (up to
``TAIL_SIGMAS``), except for the rolling-shutter exposure stretch of one moving along the
columns.  The image model, the time quadrature and its measured error: ``docs/simulator.md``.
"""

from dataclasses import dataclass

import numpy as np
from scipy.special import erf, ndtr

TAIL_SIGMAS = 7.0
"""Stamps reach this many sigma beyond the track (one-sided tail mass 1.3e-12)."""

PROBE_INTERVALS = 16
"""Time intervals of the first sampling of the tracks (refined from there)."""

MAX_TIME_SAMPLES = 1 << 20
"""Refuse to sample tracks on more time nodes than this (memory guard)."""

MAX_CHUNK_NODES = 1024
"""Most time samples rendered into one stamp."""

PIXEL_RESPONSES = ("area", "point")
"""``area``: PSF integrated over each pixel; ``point``: sampled at pixel centres (Dzamba)."""


@dataclass(frozen=True)
class RenderTruth:
    """Per-source truth of a rendered frame (arrays of length N, in input order).

    ``centroid``: (N, 2) ``(x, y)`` px, the flux-weighted mean of the continuous smeared PSF
    over the detector area (NaN where nothing lands); ``electrons_in_frame``: e⁻ deposited
    in the frame; ``in_frame_fraction``: ``electrons_in_frame / electrons`` (the share of the
    nominal signal inside the frame; it exceeds 1 only through the rolling-shutter exposure
    stretch, ``docs/simulator.md``).
    """

    centroid: np.ndarray
    in_frame_fraction: np.ndarray
    electrons_in_frame: np.ndarray


@dataclass(frozen=True)
class CosmicRay:
    """One cosmic-ray streak: ``start`` and ``end`` ``(x, y)`` px, ``electrons`` deposited."""

    start: tuple
    end: tuple
    electrons: float


# --------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------


def _positive(name, value):
    """``value`` as a float; ``ValueError`` unless finite and > 0."""
    number = float(value)
    if not (np.isfinite(number) and number > 0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return number


def _non_negative(name, value):
    """``value`` as a float; ``ValueError`` unless finite and >= 0."""
    number = float(value)
    if not (np.isfinite(number) and number >= 0):
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return number


def _frame_size(name, value):
    """An image dimension: a positive integer."""
    if int(value) != value or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _source_electrons(electrons):
    """The per-source signals (e⁻) as a 1-D float64 array of finite values >= 0."""
    values = np.asarray(electrons, dtype=np.float64)
    if values.ndim != 1 or not np.all(np.isfinite(values)) or np.any(values < 0):
        raise ValueError("electrons must be a 1-D array of finite values >= 0")
    return values


def _evaluate(positions, times, n_sources):
    """``positions(times)`` checked to be a finite (N, T, 2) float64 array."""
    tracks = np.asarray(positions(times), dtype=np.float64)
    if tracks.shape != (n_sources, len(times), 2):
        raise ValueError(f"positions(t) must return shape {(n_sources, len(times), 2)}, "
                         f"got {tracks.shape}")
    if not np.all(np.isfinite(tracks)):
        raise ValueError("positions(t) returned non-finite coordinates")
    return tracks


# --------------------------------------------------------------------------------------
# Time sampling and quadrature weights
# --------------------------------------------------------------------------------------


def _near_frame(tracks, pad, height, width):
    """Sources whose track bounding box, grown by ``pad`` px, meets the frame."""
    low, high = tracks.min(axis=1) - pad, tracks.max(axis=1) + pad
    return ((high[:, 0] >= -0.5) & (low[:, 0] <= width - 0.5)
            & (high[:, 1] >= -0.5) & (low[:, 1] <= height - 0.5))


def _largest_step(tracks):
    """Largest distance (px) any source moves between consecutive samples."""
    if tracks.shape[0] == 0 or tracks.shape[1] < 2:
        return 0.0
    return float(np.hypot(*np.moveaxis(np.diff(tracks, axis=1), -1, 0)).max())


def _sample_tracks(positions, n_sources, span, max_step, pad, height, width):
    """Uniform times over ``[0, span]`` fine enough that near-frame sources move at most
    ``max_step`` px per step, and the tracks there; a single sample if nothing moves."""
    intervals = PROBE_INTERVALS
    while True:
        times = np.linspace(0.0, span, intervals + 1)
        tracks = _evaluate(positions, times, n_sources)
        step = _largest_step(tracks[_near_frame(tracks, pad, height, width)])
        if step == 0.0:
            return times[:1], tracks[:, :1]
        if step <= max_step:
            return times, tracks
        needed = max(int(np.ceil(1.1 * intervals * step / max_step)), intervals + 1)
        if needed >= MAX_TIME_SAMPLES:
            raise ValueError(f"tracks need more than {MAX_TIME_SAMPLES} time samples (a source "
                             f"near the frame moves {step:.3g} px in 1/{intervals} of the "
                             "span); positions must be continuous, or raise max_step_px")
        intervals = needed


def _hat_cdf(z):
    """Integral from -inf to ``z`` of the unit hat ``max(0, 1 - |u|)``."""
    z = np.clip(z, -1.0, 1.0)
    return np.where(z < 0.0, 0.5 * (1.0 + z) ** 2, 1.0 - 0.5 * (1.0 - z) ** 2)


def _window_weights(times, starts, stops):
    """Quadrature weights (s) of samples ``times`` for windows ``[starts, stops]``.

    Shape (len(starts), len(times)).  On a uniform grid each weight is the integral of the
    sample's hat function over the window, i.e. the window integral of the piecewise-linear
    interpolant; a single sample (static source) gets the whole window length.
    """
    if len(times) == 1:
        return (stops - starts)[:, None]
    step = times[1] - times[0]
    return step * (_hat_cdf((stops[:, None] - times) / step)
                   - _hat_cdf((starts[:, None] - times) / step))


# --------------------------------------------------------------------------------------
# One-dimensional pixel profiles
# --------------------------------------------------------------------------------------


def _band_moments(first, count, centres, sigma):
    """Mass and first moment of unit Gaussians N(centre, sigma²) in pixels ``first ..``.

    Returns ``(mass, moment)``, each (count, K) for K centres: the Gaussian's mass inside
    ``[k - 1/2, k + 1/2]`` and its first moment there (px), ``c m + sigma (phi(a) - phi(b))``
    with ``a, b`` the standardised band edges (the truncated-normal mean times the mass).
    """
    edges = (np.arange(first, first + count + 1) - 0.5)[:, None]
    z = (edges - centres) / sigma
    cdf = ndtr(z)
    density = np.exp(-0.5 * z * z) / np.sqrt(2.0 * np.pi)
    mass = np.diff(cdf, axis=0)
    return mass, centres * mass + sigma * (density[:-1] - density[1:])


def _centre_samples(first, count, centres, sigma):
    """Unit Gaussian density (px⁻¹) at pixel centres ``first ..``, shape (count, K)."""
    z = (np.arange(first, first + count)[:, None] - centres) / sigma
    return np.exp(-0.5 * z * z) / (sigma * np.sqrt(2.0 * np.pi))


# --------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------


def _chunks(track, length_px):
    """Slices of a track's samples: stretches of about ``length_px`` px of path each."""
    steps = np.hypot(*np.diff(track, axis=0).T)
    path = np.concatenate(([0.0], np.cumsum(steps)))
    marks = np.searchsorted(path, np.arange(length_px, path[-1], length_px))
    bounds = np.unique(np.concatenate(
        ([0, len(track)], marks, np.arange(0, len(track), MAX_CHUNK_NODES))))
    return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def _span(low, high, pad, size):
    """First index and count of the pixels within ``pad`` of ``[low, high]``, in the frame."""
    first = max(int(np.floor(low - pad)), 0)
    last = min(int(np.ceil(high + pad)), size - 1)
    return first, last - first + 1


def _render_source(image, scale, times, track, row_time, exposure, sigma, pad, pixel_response):
    """Add one source of ``scale`` e⁻ along ``track`` (K, 2) sampled at ``times`` (K,) to
    ``image``; return the in-frame ``(mass, x moment, y moment)`` of its continuous PSF per
    unit flux (mass as a fraction of the nominal signal, moments in px)."""
    height, width = image.shape
    totals = np.zeros(3)
    for part in _chunks(track, max(2.0 * pad, 16.0)):
        xs, ys = track[part, 0], track[part, 1]
        col0, ncols = _span(xs.min(), xs.max(), pad, width)
        row0, nrows = _span(ys.min(), ys.max(), pad, height)
        if ncols <= 0 or nrows <= 0:
            continue
        starts = np.arange(row0, row0 + nrows) * row_time
        weights = _window_weights(times[part], starts, starts + exposure) / exposure
        if not weights.any():
            continue
        row_mass, row_moment = _band_moments(row0, nrows, ys, sigma)
        col_mass, col_moment = _band_moments(col0, ncols, xs, sigma)
        weighted_rows = weights * row_mass
        frame_mass, frame_moment = col_mass.sum(axis=0), col_moment.sum(axis=0)
        totals += ((weighted_rows @ frame_mass).sum(), (weighted_rows @ frame_moment).sum(),
                   ((weights * row_moment) @ frame_mass).sum())
        if pixel_response == "point":
            weighted_rows = weights * _centre_samples(row0, nrows, ys, sigma)
            col_mass = _centre_samples(col0, ncols, xs, sigma)
        image[row0:row0 + nrows, col0:col0 + ncols] += scale * (weighted_rows @ col_mass.T)
    return totals


def render_stars(height, width, positions, electrons, sigma_px, exposure_s, row_time_s=0.0,
                 *, max_step_px=None, pixel_response="area"):
    """Render N moving Gaussian sources into a noise-free ``(height, width)`` image in e⁻.

    ``positions(t)``: callable taking a 1-D float array of times (s, from the start of row
    0's exposure, within ``[0, (height - 1) row_time_s + exposure_s]``) and returning an
    (N, len(t), 2) array of ``(x, y)`` pixel positions.  ``electrons``: (N,) e⁻ per source
    over a nominal exposure.  ``sigma_px``: Gaussian PSF sigma (px).  ``exposure_s``: t_e
    (s, > 0).  ``row_time_s``: rolling-shutter row period (s, 0 = global shutter).
    ``max_step_px``: largest track motion between time samples (px; default
    ``0.1 min(sigma_px, 1)``).  ``pixel_response``: ``"area"`` (integrated over each
    pixel) or ``"point"`` (density in e⁻/px² at pixel centres, as Dzamba samples it; truth
    stays that of the continuous PSF).

    Returns ``(image_e, truth)``: ``image_e`` float64 (height, width), ``truth`` a
    :class:`RenderTruth`.
    """
    height, width = _frame_size("height", height), _frame_size("width", width)
    sigma = _positive("sigma_px", sigma_px)
    exposure = _positive("exposure_s", exposure_s)
    row_time = _non_negative("row_time_s", row_time_s)
    signals = _source_electrons(electrons)
    step = 0.1 * min(sigma, 1.0) if max_step_px is None else _positive("max_step_px", max_step_px)
    if pixel_response not in PIXEL_RESPONSES:
        raise ValueError(f"pixel_response must be one of {PIXEL_RESPONSES}, got {pixel_response!r}")

    pad = TAIL_SIGMAS * sigma + 1.0
    times, tracks = _sample_tracks(positions, len(signals), (height - 1) * row_time + exposure,
                                   step, pad, height, width)
    near = _near_frame(tracks, pad, height, width)
    image = np.zeros((height, width))
    totals = np.zeros((len(signals), 3))
    for i in np.flatnonzero(near):
        static = bool(np.all(tracks[i] == tracks[i, 0]))
        samples = slice(0, 1) if static else slice(None)
        totals[i] = _render_source(image, signals[i], times[samples], tracks[i, samples],
                                   row_time, exposure, sigma, pad, pixel_response)
    mass = totals[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        centroid = np.where(mass[:, None] > 0, totals[:, 1:] / mass[:, None], np.nan)
    return image, RenderTruth(centroid, mass, mass * signals)


# --------------------------------------------------------------------------------------
# Dzamba's closed form
# --------------------------------------------------------------------------------------


def dzamba_smeared_psf(x, y, xi, yi, s_dx, s_dy, sigma, exposure_s, electrons):
    """Dzamba Eqs 4.11-4.18 (as corrected): linearly smeared Gaussian density, e⁻/px².

    A Gaussian of sigma ``sigma`` (px) moving at constant velocity from ``(xi, yi)`` to
    ``(xi + s_dx, yi + s_dy)`` (px) during ``exposure_s`` (s), time-averaged and normalised
    so that its integral over the plane is ``electrons``; evaluated at points ``(x, y)`` (px).
    Corrections to the printed thesis: the exponent of Eq 4.16 is ``a0 - a1**2 / (4 a2)``
    and the time integral is divided by ``t_e``.  For ``|s| < 1e-5 sigma`` (the omega -> 0
    limit, where ``a2 -> 0`` is singular) it returns the static Gaussian at the track
    midpoint, which agrees to second order in ``|s| / sigma``.
    """
    x, y, xi, yi, s_dx, s_dy = np.broadcast_arrays(
        *(np.asarray(v, dtype=np.float64) for v in (x, y, xi, yi, s_dx, s_dy)))
    sigma = _positive("sigma", sigma)
    t_e = _positive("exposure_s", exposure_s)
    amplitude = float(electrons) / (2.0 * np.pi * sigma**2)                     # A_o
    smear2 = s_dx**2 + s_dy**2
    moving = smear2 > (1e-5 * sigma) ** 2
    dx, dy = x - xi, y - yi
    a0 = -(dx**2 + dy**2) / (2.0 * sigma**2)
    a1 = (s_dx * dx + s_dy * dy) / (sigma**2 * t_e)
    a2 = -np.where(moving, smear2, 1.0) / (2.0 * sigma**2 * t_e**2)
    root = np.sqrt(-a2)
    b0 = np.sqrt(np.pi) / (2.0 * root) * (erf(a1 / (2.0 * root))
                                          - erf((2.0 * a2 * t_e + a1) / (2.0 * root)))
    smeared = amplitude * b0 * np.exp(a0 - a1**2 / (4.0 * a2)) / t_e
    mid_r2 = (dx - s_dx / 2.0) ** 2 + (dy - s_dy / 2.0) ** 2
    static = amplitude * np.exp(-mid_r2 / (2.0 * sigma**2))
    return np.where(moving, smeared, static)


# --------------------------------------------------------------------------------------
# Cosmic rays
# --------------------------------------------------------------------------------------


def _streak_pixels(start, delta):
    """Pixels crossed by the segment ``start -> start + delta`` and the fraction of its
    length inside each: ``(rows, cols, fractions)``, exact (pixel edges at half-integers)."""
    cuts = [np.array([0.0, 1.0])]
    for axis in (0, 1):
        if delta[axis] != 0.0:
            ends = sorted((start[axis], start[axis] + delta[axis]))
            edges = np.arange(np.ceil(ends[0] - 0.5), np.floor(ends[1] - 0.5) + 1) + 0.5
            cuts.append((edges - start[axis]) / delta[axis])
    s = np.unique(np.clip(np.concatenate(cuts), 0.0, 1.0))
    middle = start + np.outer(0.5 * (s[:-1] + s[1:]), delta)
    pixels = np.floor(middle + 0.5).astype(np.int64)
    return pixels[:, 1], pixels[:, 0], np.diff(s)


def add_cosmic_rays(image_e, rng, count, length_px=(1.0, 10.0), electrons=(500.0, 5000.0)):
    """Add ``count`` cosmic-ray streaks to ``image_e`` (e⁻, modified in place).

    Each streak is a sharp straight segment (no PSF) with length uniform in ``length_px``
    (px), direction uniform in angle, total deposit uniform in ``electrons`` (e⁻) shared
    among the pixels in proportion to the path length inside each; it lies wholly inside
    the frame.  ``rng``: a ``numpy.random.Generator``.  Returns a list of
    :class:`CosmicRay` (start, end, electrons) for the truth file.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError("rng must be a numpy.random.Generator")
    if int(count) != count or count < 0:
        raise ValueError(f"count must be an integer >= 0, got {count!r}")
    shortest, longest = (_positive("length_px", v) for v in length_px)
    least, most = (_non_negative("electrons", v) for v in electrons)
    if shortest > longest or least > most:
        raise ValueError("length_px and electrons must be (low, high) ranges")
    if image_e.ndim != 2 or min(image_e.shape) <= longest:
        raise ValueError(f"image_e must be 2-D and larger than {longest} px on each side")
    size = np.array(image_e.shape[::-1], dtype=np.float64)                     # (W, H)
    rays = []
    for _ in range(int(count)):
        length, angle = rng.uniform(shortest, longest), rng.uniform(0.0, 2.0 * np.pi)
        deposit = rng.uniform(least, most)
        delta = length * np.array([np.cos(angle), np.sin(angle)])
        start = -0.5 - np.minimum(delta, 0.0) + rng.uniform(0.0, 1.0, 2) * (size - np.abs(delta))
        rows, cols, fractions = _streak_pixels(start, delta)
        np.add.at(image_e, (rows, cols), deposit * fractions)
        rays.append(CosmicRay(tuple(map(float, start)), tuple(map(float, start + delta)),
                              float(deposit)))
    return rays
