"""Stellar photometry: photo-electrons per star and the limiting magnitude (Dzamba 2013).

Units: aperture ``D`` in millimetres (metres inside the formulas), pixel pitch in
micrometres, exposure in seconds, slew rate in degrees per second, signals in electrons
(e⁻), magnitudes in Johnson V.  Every function broadcasts over numpy arrays and returns a
numpy float (or array); invalid inputs raise ``ValueError`` naming the argument.

* Signal (Dzamba Eqs 4.3-4.4, after Reed 1993)::

      S_e = 1/4 * eta * t_e * pi * D**2 * phi0 * 10**(-0.4 m)

  with ``phi0 = 1.8e10`` photons m⁻² s⁻¹ for a V = 0 star.
* Read-noise-limited threshold magnitude (Dzamba Eq 5.7 **with the 1/4 of S_e restored**;
  the thesis prints the denominator as ``(eta t_e pi D**2 phi0)**2``, which makes ``m_t``
  ``1.25 log10(16) = 1.51`` mag too faint)::

      m_t = -5/4 log10[ alpha_p (pi alpha_p gamma_p + 2 F# D tan(omega t_e)) R_t**2 sigma_e**2
                        / (gamma_p (eta t_e pi D**2 phi0 / 4)**2) ]

  i.e. ``S_e(m_t) = R_t sigma_e sqrt(M_total)`` (Eq 5.6) with ``M_total`` from Eq 5.4.
"""

import numpy as np

PHI0_V0 = 1.8e10
"""Photon flux of a V = 0 star in the V band, photons m⁻² s⁻¹ (Dzamba Eq 4.4)."""


def _checked(name, value, ok, requirement):
    """``value`` as a float64 array; ``ValueError`` unless finite and ``ok(array)`` holds."""
    array = np.asarray(value, dtype=np.float64)
    if not (np.all(np.isfinite(array)) and np.all(ok(array))):
        raise ValueError(f"{name} must be finite and {requirement}, got {value!r}")
    return array


def _scalar_or_array(array):
    """A 0-d result as a numpy float, anything else unchanged."""
    return array[()] if array.ndim == 0 else array


def photo_electrons(vmag, aperture_mm, exposure_s, qe, phi0=PHI0_V0):
    """Photo-electrons ``S_e`` (e⁻) collected from a star of V magnitude ``vmag``.

    ``aperture_mm``: entrance-pupil diameter D (mm, > 0); ``exposure_s``: t_e (s, >= 0);
    ``qe``: quantum efficiency eta in (0, 1]; ``phi0``: photons m⁻² s⁻¹ at V = 0.
    Dzamba Eqs 4.3-4.4: ``S_e = eta t_e pi D**2 phi0 10**(-0.4 m) / 4``.
    """
    magnitude = _checked("vmag", vmag, lambda a: True, "a real number")
    diameter_m = _checked("aperture_mm", aperture_mm, lambda a: a > 0, "> 0") * 1e-3
    exposure = _checked("exposure_s", exposure_s, lambda a: a >= 0, ">= 0")
    efficiency = _checked("qe", qe, lambda a: (a > 0) & (a <= 1), "in (0, 1]")
    flux0 = _checked("phi0", phi0, lambda a: a > 0, "> 0")
    signal = (0.25 * efficiency * exposure * np.pi * diameter_m**2 * flux0
              * 10.0 ** (-0.4 * magnitude))
    return _scalar_or_array(signal)


def track_length_px(f_number, aperture_mm, pixel_um, rate_deg_s, exposure_s):
    """Cross-axis smear length ``s_o = F# D tan(omega t_e) / gamma_p`` in pixels (Eq 5.3).

    ``rate_deg_s``: cross-boresight slew rate omega (deg/s, >= 0, with omega t_e < 90 deg).
    """
    focal_mm = (_checked("f_number", f_number, lambda a: a > 0, "> 0")
                * _checked("aperture_mm", aperture_mm, lambda a: a > 0, "> 0"))
    pitch_mm = _checked("pixel_um", pixel_um, lambda a: a > 0, "> 0") * 1e-3
    exposure = _checked("exposure_s", exposure_s, lambda a: a >= 0, ">= 0")
    rate = _checked("rate_deg_s", rate_deg_s, lambda a: a >= 0, ">= 0")
    angle_deg = rate * exposure
    if np.any(angle_deg >= 90.0):
        raise ValueError(f"rate_deg_s * exposure_s must be < 90 deg, got {angle_deg!r}")
    return _scalar_or_array(focal_mm * np.tan(np.radians(angle_deg)) / pitch_mm)


def smeared_pixel_count(psf_radius_px, track_px):
    """Pixels under a smeared star, ``M_total = pi alpha_p**2 + 2 alpha_p s_o`` (Eq 5.4).

    ``psf_radius_px``: static PSF radius alpha_p (px, > 0); ``track_px``: smear s_o (px, >= 0).
    Like Eq 5.7 this uses ``pi alpha_p**2`` without the ceiling of Eq 5.2.
    """
    radius = _checked("psf_radius_px", psf_radius_px, lambda a: a > 0, "> 0")
    track = _checked("track_px", track_px, lambda a: a >= 0, ">= 0")
    return _scalar_or_array(np.pi * radius**2 + 2.0 * radius * track)


def limiting_magnitude(aperture_mm, f_number, pixel_um, read_noise_e, qe, exposure_s,
                       rate_deg_s=0.0, psf_radius_px=5.0, snr=10.0, phi0=PHI0_V0):
    """Threshold magnitude ``m_t`` (V mag) of Dzamba Eq 5.7 with the 1/4 restored.

    The faintest star whose signal reaches ``snr`` (R_t) times the read noise summed over the
    ``M_total`` smeared-PSF pixels: ``S_e(m_t) = R_t sigma_e sqrt(M_total)``.
    ``aperture_mm``: D (mm); ``f_number``: F#; ``pixel_um``: gamma_p (µm);
    ``read_noise_e``: sigma_e (e⁻ rms per pixel, > 0); ``qe``: eta; ``exposure_s``: t_e (s,
    > 0); ``rate_deg_s``: cross-axis slew omega (deg/s); ``psf_radius_px``: alpha_p (px).
    """
    noise = _checked("read_noise_e", read_noise_e, lambda a: a > 0, "> 0")
    ratio = _checked("snr", snr, lambda a: a > 0, "> 0")
    _checked("exposure_s", exposure_s, lambda a: a > 0, "> 0")
    track = track_length_px(f_number, aperture_mm, pixel_um, rate_deg_s, exposure_s)
    pixels = smeared_pixel_count(psf_radius_px, track)
    zero_mag_signal = photo_electrons(0.0, aperture_mm, exposure_s, qe, phi0)
    return _scalar_or_array(np.asarray(
        -1.25 * np.log10(pixels * ratio**2 * noise**2 / zero_mag_signal**2)))
