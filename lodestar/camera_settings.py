"""How each camera preset is run in flight: exposure and the detector's fixed-threshold
registers, shared by ``lodestar demo`` and the campaigns (``lodestar campaign --settings``).

Two sets (:data:`SETTINGS`):

* ``preset``: each camera as its preset and :func:`lodestar.sim.scene.detector_config` give
  it: the preset's exposure, ``T = B + 5 sigma`` of the dark-frame noise, ``min_pixels = 4``.
* ``tuned`` (the default): what a real configuration of the camera changes.

  - ``estcube2``: ``T = B + 3 sigma``.  At 1-2 deg/s a star's light is spread along a
    13-26 px streak (0.1 s exposure), its pixels fall to a few sigma and a 5-sigma threshold
    breaks the streak into fragments smaller than ``min_pixels``, which are filtered: a
    seeded 24-frame probe at 2 deg/s solved 9 frames at 5 sigma and 23 at 3 sigma.  Noise
    alone passes 3 sigma on 0.13 % of the pixels, ~7,000 single-pixel blobs per 5 Mpx
    frame that the detector measures and filters (``min_pixels = 4`` needs four
    4-connected pixels: about 1e-4 noise records per frame).
  - ``lohmann``: the preset's 24.3 ms exposure leaves no detectable star (a 0.6 px PSF puts
    35 % of the light on one pixel and 12 % on each arm of the "+", and a V = 3 star gives
    150 e- in 24 ms against 25 e- of read noise), so ``tuned`` uses 0.2 s (MT9V022
    R0x0B = 3950 rows of 50.6 us: the sensor stretches vertical blanking, 5 frames/s),
    Lohmann's own ``mu + 3 sigma`` threshold (Lohmann 2017 L578: 2 or 3 sigma) and
    ``min_pixels = 3``, the firmware's hot-pixel filter (``firmware.centroids``
    ``DEFAULT_MIN_PIXELS``): four pixels need three arms of the "+" above threshold, about
    three times the light.

Units: exposure in seconds, thresholds in ADU of the camera's pixel width.
"""

import math

SETTINGS = {
    "preset": {},
    "tuned": {"estcube2": {"ksigma": 3.0},
              "lohmann": {"exposure_s": 0.2, "ksigma": 3.0, "min_pixels": 3}},
}
"""Camera settings per preset (module docstring): ``exposure_s`` (s), ``ksigma`` (the
fixed threshold ``T = B + ceil(ksigma sigma)``) and ``min_pixels`` (the detector's
register)."""

DEFAULT_SETTINGS = "tuned"


def camera_settings(preset, settings=DEFAULT_SETTINGS):
    """``{"exposure_s", "ksigma", "min_pixels"}`` of a preset under ``settings`` (a key of
    :data:`SETTINGS`); None for a value the preset and ``detector_config`` decide.  Raises
    ``ValueError`` for unknown settings."""
    if settings not in SETTINGS:
        raise ValueError(f"unknown settings {settings!r} (known: {', '.join(SETTINGS)})")
    values = {"exposure_s": None, "ksigma": None, "min_pixels": None}
    values.update(SETTINGS[settings].get(preset, {}))
    return values


def detector_config(cam, settings, exposure_s=None):
    """The golden detector's registers for ``cam`` under ``settings`` (from
    :func:`camera_settings`) at ``exposure_s`` (s; default the settings', then the
    preset's): :func:`lodestar.sim.scene.detector_config` with ``min_pixels`` and, for
    ``ksigma``, ``T = B + max(ceil(ksigma sigma), 1)`` where sigma is the dark-frame noise
    of that function's model (read noise, dark current and sky)."""
    from lodestar import contract as C
    from lodestar.sim import scene

    t = exposure_s or settings["exposure_s"] or cam.exposure_s
    changes = {}
    if settings["min_pixels"] is not None:
        changes["min_pixels"] = settings["min_pixels"]
    cfg = scene.detector_config(cam, t, **changes)
    if settings["ksigma"] is not None:
        dark_e = (cam.dark_current_e_per_s + scene.SKY_E_PER_PX_S) * t
        sigma_adu = cam.gain_adu_per_e * math.sqrt(cam.read_noise_e ** 2 + dark_e)
        step = max(int(math.ceil(settings["ksigma"] * sigma_adu)), 1)
        cfg = cfg.replace(threshold=min(cfg.background + step, C.full_scale(cam.pixel_bits)))
    return cfg
