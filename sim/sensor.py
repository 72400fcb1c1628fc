"""The sensor chain: a noise-free electron image to a quantised, clipped ``uint16`` frame.

Units: signals in electrons (e⁻), rates in e⁻ per pixel per second, exposure in seconds,
gain in ADU per e⁻, offsets in ADU.  Images are indexed ``[y, x]`` (row, column).

Per pixel, in this order::

    photo   = prnu * (image_e + sky_e_per_px_s * t)          (PRNU acts on all photo-signal)
    dark    = dark_current_e_per_s * t * dark_multiplier       (DSNU; hot pixels raised)
    e       = Poisson(photo + dark) + Normal(0, read_noise_e)  (shot and read noise)
    code    = clip(round(gain * e + adc_offset_adu), 0, 2**pixel_bits - 1)
    code    = max(code, reserved_low_codes)                    (optional, MT9V022: 4)

Fixed-pattern maps (:class:`SensorDefects`) come from their own seed, so the same sensor can
be imaged with any per-frame noise generator; the defect streams are derived from the seed
through a ``SeedSequence`` spawn key, so they never coincide with ``default_rng(seed)``.
"""

from dataclasses import dataclass

import numpy as np

DEFECTS_SPAWN_KEY = 0x5E750
"""Spawn key separating the defect streams from a plain ``default_rng(seed)``."""

MAX_PIXEL_BITS = 16
"""The frame is ``uint16``: ADCs of 1 .. 16 bits."""


def _number(name, value, ok, requirement):
    """``value`` as a float; ``ValueError`` unless finite and ``ok(value)``."""
    number = float(value)
    if not (np.isfinite(number) and ok(number)):
        raise ValueError(f"{name} must be finite and {requirement}, got {value!r}")
    return number


def _integer(name, value, low, high):
    """``value`` as an int in ``low .. high``; ``ValueError`` otherwise."""
    if isinstance(value, bool) or int(value) != value or not low <= value <= high:
        raise ValueError(f"{name} must be an integer in {low} .. {high}, got {value!r}")
    return int(value)


@dataclass(frozen=True)
class SensorDefects:
    """Fixed-pattern maps of one sensor, shape (height, width).

    ``dark_multiplier``: per-pixel factor on the mean dark current (DSNU; mean 1 apart from
    hot pixels, which hold ``hot_dark_factor``); ``prnu_gain``: per-pixel photo-response
    factor (mean 1); ``hot_pixels``: (K, 2) int ``(x, y)`` of the hot pixels, in raster order.
    """

    dark_multiplier: np.ndarray
    prnu_gain: np.ndarray
    hot_pixels: np.ndarray

    @classmethod
    def generate(cls, height, width, seed, dsnu=0.2, prnu=0.01, hot_fraction=1e-4,
                 hot_dark_factor=100.0):
        """Deterministic maps for ``seed`` (an integer >= 0).

        ``dsnu``: relative rms of the dark-current multiplier, drawn lognormal with mean 1
        (so it stays positive); ``prnu``: relative rms of the gain map ``1 + prnu N(0, 1)``
        (clipped at 0); ``hot_fraction``: share of pixels made hot (rounded to a count,
        distinct pixels); ``hot_dark_factor``: their dark-current multiplier.  PRNU, DSNU
        and hot pixels use separate streams, so changing one parameter leaves the other maps.
        """
        height = _integer("height", height, 1, 1 << 20)
        width = _integer("width", width, 1, 1 << 20)
        seed = _integer("seed", seed, 0, (1 << 63) - 1)
        dsnu = _number("dsnu", dsnu, lambda v: v >= 0, ">= 0")
        prnu = _number("prnu", prnu, lambda v: v >= 0, ">= 0")
        hot_fraction = _number("hot_fraction", hot_fraction, lambda v: 0 <= v <= 1, "in [0, 1]")
        hot_factor = _number("hot_dark_factor", hot_dark_factor, lambda v: v >= 0, ">= 0")
        streams = [np.random.default_rng(s) for s in
                   np.random.SeedSequence(seed, spawn_key=(DEFECTS_SPAWN_KEY,)).spawn(3)]
        shape = (height, width)
        prnu_gain = np.maximum(1.0 + prnu * streams[0].standard_normal(shape), 0.0)
        log_sigma = np.sqrt(np.log1p(dsnu**2))
        dark = np.exp(log_sigma * streams[1].standard_normal(shape) - 0.5 * log_sigma**2)
        n_hot = int(round(hot_fraction * height * width))
        hot = np.sort(streams[2].choice(height * width, size=n_hot, replace=False))
        dark.flat[hot] = hot_factor
        return cls(dark, prnu_gain, np.column_stack((hot % width, hot // width)))


def expose(image_e, rng, exposure_s, sky_e_per_px_s, dark_current_e_per_s, read_noise_e,
           gain_adu_per_e, adc_offset_adu, pixel_bits, defects=None, reserved_low_codes=None):
    """Turn a noise-free image (e⁻ over the exposure) into a ``uint16`` frame of ADC codes.

    ``rng``: ``numpy.random.Generator`` for the per-frame noise; ``exposure_s``: s (>= 0);
    ``sky_e_per_px_s``: sky background, e⁻/px/s; ``dark_current_e_per_s``: mean dark
    current, e⁻/px/s; ``read_noise_e``: e⁻ rms; ``gain_adu_per_e``: ADU/e⁻ (> 0);
    ``adc_offset_adu``: ADU added before rounding; ``pixel_bits``: ADC width 1 .. 16 (codes
    clip at ``2**pixel_bits - 1``: saturation); ``defects``: optional
    :class:`SensorDefects` of the image's shape; ``reserved_low_codes``: optional code
    ``c`` such that codes below ``c`` read as ``c`` (the MT9V022 reserves 0 .. 3: use 4).
    See the module docstring for the order of operations.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError("rng must be a numpy.random.Generator")
    image = np.asarray(image_e, dtype=np.float64)
    if image.ndim != 2 or not np.all(np.isfinite(image)) or np.any(image < 0):
        raise ValueError("image_e must be a 2-D array of finite electrons >= 0")
    exposure = _number("exposure_s", exposure_s, lambda v: v >= 0, ">= 0")
    sky = _number("sky_e_per_px_s", sky_e_per_px_s, lambda v: v >= 0, ">= 0")
    dark_rate = _number("dark_current_e_per_s", dark_current_e_per_s, lambda v: v >= 0, ">= 0")
    read_noise = _number("read_noise_e", read_noise_e, lambda v: v >= 0, ">= 0")
    gain = _number("gain_adu_per_e", gain_adu_per_e, lambda v: v > 0, "> 0")
    offset = _number("adc_offset_adu", adc_offset_adu, lambda v: True, "a real number")
    full_scale = (1 << _integer("pixel_bits", pixel_bits, 1, MAX_PIXEL_BITS)) - 1
    if reserved_low_codes is not None:
        reserved_low_codes = _integer("reserved_low_codes", reserved_low_codes, 0, full_scale)
    if defects is not None and defects.prnu_gain.shape != image.shape:
        raise ValueError(f"defects are {defects.prnu_gain.shape}, image_e is {image.shape}")

    photo = image + sky * exposure
    dark = dark_rate * exposure
    if defects is not None:
        photo = photo * defects.prnu_gain
        dark = dark * defects.dark_multiplier
    signal = rng.poisson(photo + dark).astype(np.float64)                    # e⁻
    if read_noise > 0:
        signal += rng.normal(0.0, read_noise, image.shape)
    signal *= gain                                                            # ADU
    signal += offset
    np.rint(signal, out=signal)
    np.clip(signal, reserved_low_codes or 0, full_scale, out=signal)
    return signal.astype(np.uint16)
