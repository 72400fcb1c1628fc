"""Photometry: Dzamba's photo-electron count (Eqs 4.3-4.4) and corrected limiting magnitude."""

import math

import numpy as np
import pytest

from lodestar.sim.photometry import (
    PHI0_V0,
    limiting_magnitude,
    photo_electrons,
    smeared_pixel_count,
    track_length_px,
)

# Dzamba (2013) Tables 5.1-5.2: (F#, D mm, pixel um, read noise e-) of reference designs 1-4,
# and the digest's corrected m_t at 0 and 1 deg/s (eta = 0.5, t_e = 0.1 s, alpha_p = 5 px,
# R_t = 10).
DESIGNS = {
    1: ((1.2, 12.0, 2.2, 3.5), (6.29, 5.80)),
    2: ((1.0, 12.0, 2.2, 3.5), (6.29, 5.86)),
    3: ((1.4, 35.0, 5.5, 13.0), (7.19, 6.60)),
    4: ((0.95, 52.0, 5.5, 13.0), (8.05, 7.45)),
}


def test_zero_magnitude_by_hand():
    """V = 0, D = 13 mm, t = 0.1 s, eta = 0.5: 1/4 * 0.5 * 0.1 * pi * 0.013**2 * 1.8e10."""
    by_hand = 0.25 * 0.5 * 0.1 * math.pi * 0.013**2 * 1.8e10
    assert by_hand == pytest.approx(119459.06, abs=0.01)
    assert photo_electrons(0.0, 13.0, 0.1, 0.5) == pytest.approx(by_hand, rel=1e-12)


def test_quarter_factor_and_pogson_scaling():
    full_disc = 0.5 * 0.1 * math.pi * 0.013**2 * PHI0_V0          # without the 1/4
    assert photo_electrons(0.0, 13.0, 0.1, 0.5) == pytest.approx(full_disc / 4, rel=1e-12)
    digest = {5.0: 1195, 5.75: 599, 7.0: 189}                      # Dzamba digest section 5
    got = photo_electrons(np.array(list(digest)), 13.0, 0.1, 0.5)
    assert np.allclose(got, list(digest.values()), atol=0.5)
    assert photo_electrons(5.75, 12.0, 0.1, 0.5) == pytest.approx(510, abs=0.5)
    ratio = photo_electrons(2.5, 13, 0.1, 0.5) / photo_electrons(0, 13, 0.1, 0.5)
    assert ratio == pytest.approx(0.1)


def test_broadcasts_and_scalars():
    out = photo_electrons([[0.0], [5.0]], [10.0, 20.0], 0.1, 0.5)
    assert out.shape == (2, 2)
    assert out[0, 1] == pytest.approx(4 * out[0, 0])
    assert np.ndim(photo_electrons(1.0, 10.0, 0.1, 0.5)) == 0
    assert photo_electrons(1.0, 10.0, 0.0, 0.5) == 0.0


@pytest.mark.parametrize("name, kwargs", [
    ("exposure_s", {"exposure_s": -0.1}),
    ("aperture_mm", {"aperture_mm": 0.0}),
    ("aperture_mm", {"aperture_mm": -3.0}),
    ("qe", {"qe": 0.0}),
    ("qe", {"qe": 1.2}),
    ("vmag", {"vmag": float("nan")}),
    ("exposure_s", {"exposure_s": [0.1, float("nan")]}),
    ("phi0", {"phi0": 0.0}),
])
def test_bad_inputs_name_the_argument(name, kwargs):
    args = {"vmag": 5.0, "aperture_mm": 13.0, "exposure_s": 0.1, "qe": 0.5, **kwargs}
    with pytest.raises(ValueError, match=name):
        photo_electrons(**args)


def test_track_and_pixel_count_design_1():
    """Eq 5.3-5.4: F# D tan(omega t_e) / gamma_p = 14.4 mm * tan(0.1 deg) / 2.2 um."""
    track = track_length_px(1.2, 12.0, 2.2, 1.0, 0.1)
    assert track == pytest.approx(14.4 * math.tan(math.radians(0.1)) / 2.2e-3, rel=1e-12)
    assert track == pytest.approx(11.42, abs=0.01)
    assert smeared_pixel_count(5.0, track) == pytest.approx(193, abs=0.5)   # digest: 193 px


@pytest.mark.parametrize("design", sorted(DESIGNS))
def test_limiting_magnitude_reproduces_digest(design):
    (f_number, aperture, pixel, noise), expected = DESIGNS[design]
    for rate, m_t in zip((0.0, 1.0), expected):
        got = limiting_magnitude(aperture, f_number, pixel, noise, 0.5, 0.1, rate_deg_s=rate)
        assert got == pytest.approx(m_t, abs=0.006)


def eq_5_7(aperture_mm, f_number, pixel_um, noise, eta, t_e, rate, alpha, snr, quarter):
    """Dzamba Eq 5.7 written out as printed (``quarter=False``) or corrected."""
    d, gamma = aperture_mm * 1e-3, pixel_um * 1e-6
    s0 = eta * t_e * math.pi * d**2 * PHI0_V0 * (0.25 if quarter else 1.0)
    smear = 2 * f_number * d * math.tan(math.radians(rate * t_e))
    pixels = alpha * (math.pi * alpha * gamma + smear)
    return -1.25 * math.log10(pixels * snr**2 * noise**2 / (gamma * s0**2))


def test_matches_written_out_equation_and_erratum_size():
    for rate in (0.0, 0.5, 1.0, 2.0):
        got = limiting_magnitude(12.0, 1.2, 2.2, 3.5, 0.5, 0.1, rate, psf_radius_px=5, snr=10)
        corrected = eq_5_7(12, 1.2, 2.2, 3.5, 0.5, 0.1, rate, 5, 10, True)
        assert got == pytest.approx(corrected, abs=1e-12)
        printed = eq_5_7(12, 1.2, 2.2, 3.5, 0.5, 0.1, rate, 5, 10, False)
        assert printed - got == pytest.approx(1.25 * math.log10(16), abs=1e-12)   # 1.51 mag
    assert eq_5_7(12, 1.2, 2.2, 3.5, 0.5, 0.1, 1.0, 5, 10, False) == pytest.approx(7.31, abs=0.006)


def test_limiting_magnitude_trends():
    """Fainter with a bigger aperture, brighter with slew, read noise and a higher SNR."""
    base = limiting_magnitude(12.0, 1.2, 2.2, 3.5, 0.5, 0.1)
    assert limiting_magnitude(24.0, 1.2, 2.2, 3.5, 0.5, 0.1) > base
    assert limiting_magnitude(12.0, 1.2, 2.2, 3.5, 0.5, 0.1, rate_deg_s=2.0) < base
    noisier = limiting_magnitude(12.0, 1.2, 2.2, 7.0, 0.5, 0.1)
    assert noisier == pytest.approx(base - 2.5 * math.log10(2))
    assert limiting_magnitude(12.0, 1.2, 2.2, 3.5, 0.5, 0.1, snr=20.0) < base


@pytest.mark.parametrize("name, kwargs", [
    ("read_noise_e", {"read_noise_e": 0.0}),
    ("rate_deg_s", {"rate_deg_s": -1.0}),
    ("exposure_s", {"exposure_s": 0.0}),
    ("f_number", {"f_number": float("nan")}),
    ("psf_radius_px", {"psf_radius_px": 0.0}),
    ("rate_deg_s", {"rate_deg_s": 1000.0}),
])
def test_limiting_magnitude_bad_inputs(name, kwargs):
    args = {"aperture_mm": 12.0, "f_number": 1.2, "pixel_um": 2.2, "read_noise_e": 3.5,
            "qe": 0.5, "exposure_s": 0.1, **kwargs}
    with pytest.raises(ValueError, match=name):
        limiting_magnitude(**args)
