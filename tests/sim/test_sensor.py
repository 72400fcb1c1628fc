"""Sensor chain: noise statistics, fixed-pattern defects, quantisation, clipping, codes."""

import numpy as np
import pytest

from lodestar.sim.sensor import SensorDefects, expose

QUIET = {"sky_e_per_px_s": 0.0, "dark_current_e_per_s": 0.0, "read_noise_e": 0.0,
         "gain_adu_per_e": 1.0, "adc_offset_adu": 0.0, "pixel_bits": 12}


def frame(image, seed=0, exposure_s=0.1, **kwargs):
    return expose(image, np.random.default_rng(seed), exposure_s, **{**QUIET, **kwargs})


def test_flat_field_mean_and_variance():
    """Mean = offset + g (S + sky t + dark t); variance = g**2 (S + sky t + dark t + read**2)
    + 1/12 (rounding), on a 1000 x 1000 frame with 16-bit codes (no clipping)."""
    signal, sky, dark, read, gain, offset, t = 800.0, 300.0, 500.0, 6.0, 0.6, 120.0, 0.2
    codes = frame(np.full((1000, 1000), signal), seed=3, exposure_s=t, sky_e_per_px_s=sky,
                  dark_current_e_per_s=dark, read_noise_e=read, gain_adu_per_e=gain,
                  adc_offset_adu=offset, pixel_bits=16).astype(float)
    electrons = signal + (sky + dark) * t
    mean = offset + gain * electrons
    variance = gain**2 * (electrons + read**2) + 1 / 12
    assert codes.mean() == pytest.approx(mean, abs=5 * np.sqrt(variance / codes.size))
    assert codes.var() == pytest.approx(variance, rel=5 * np.sqrt(2 / codes.size))


def test_shot_noise_alone_is_poisson():
    codes = frame(np.full((800, 800), 3.0), seed=1).astype(float)
    assert codes.mean() == pytest.approx(3.0, abs=0.01)
    assert codes.var() == pytest.approx(3.0, rel=0.01)
    assert np.all(codes == np.round(codes)) and codes.min() == 0


def test_quantisation_rounds_to_nearest_code():
    zeros = np.zeros((4, 4))
    assert np.all(frame(zeros, adc_offset_adu=10.4) == 10)
    assert np.all(frame(zeros, adc_offset_adu=10.6) == 11)
    assert frame(zeros).dtype == np.uint16


def test_saturation_clips_at_full_scale():
    bright = np.full((50, 50), 1e6)
    assert np.all(frame(bright, pixel_bits=12) == 4095)
    assert np.all(frame(bright, pixel_bits=10) == 1023)
    unclipped = frame(bright, pixel_bits=10, gain_adu_per_e=0.001)          # 1000 +- 1 ADU
    assert 990 < unclipped.min() and unclipped.max() < 1010
    assert np.all(frame(np.zeros((5, 5)), adc_offset_adu=-50.0, read_noise_e=3.0) == 0)


def test_reserved_low_codes():
    dark = frame(np.zeros((100, 100)), read_noise_e=3.0, adc_offset_adu=2.0, pixel_bits=10,
                 reserved_low_codes=4)
    free = frame(np.zeros((100, 100)), read_noise_e=3.0, adc_offset_adu=2.0, pixel_bits=10)
    assert dark.min() == 4 and free.min() == 0
    assert np.array_equal(dark, np.maximum(free, 4))


def test_deterministic_per_noise_seed():
    image = np.full((64, 64), 40.0)
    kwargs = {"read_noise_e": 2.0, "sky_e_per_px_s": 10.0}
    assert np.array_equal(frame(image, seed=5, **kwargs), frame(image, seed=5, **kwargs))
    assert not np.array_equal(frame(image, seed=5, **kwargs), frame(image, seed=6, **kwargs))


def test_defects_deterministic_and_independent_of_noise_seed():
    a, b = SensorDefects.generate(64, 80, seed=11), SensorDefects.generate(64, 80, seed=11)
    c = SensorDefects.generate(64, 80, seed=12)
    for field in ("dark_multiplier", "prnu_gain", "hot_pixels"):
        assert np.array_equal(getattr(a, field), getattr(b, field))
    assert not np.array_equal(a.prnu_gain, c.prnu_gain)
    # Same defects, different noise: different frames; same noise, different defects: too.
    image = np.full((64, 80), 500.0)
    kwargs = {"dark_current_e_per_s": 100.0, "read_noise_e": 2.0}
    reference = frame(image, 1, defects=a, **kwargs)
    assert not np.array_equal(reference, frame(image, 2, defects=a, **kwargs))
    assert not np.array_equal(reference, frame(image, 1, defects=c, **kwargs))
    # A defects seed equal to a noise seed does not replay the noise stream.
    plain = np.random.default_rng(11).standard_normal((64, 80))
    assert abs(np.corrcoef(plain.ravel(), a.prnu_gain.ravel())[0, 1]) < 0.05


def test_defect_statistics_and_parameter_independence():
    d = SensorDefects.generate(400, 500, seed=2, dsnu=0.3, prnu=0.02, hot_fraction=1e-3,
                               hot_dark_factor=80.0)
    cold = np.ones(d.dark_multiplier.shape, dtype=bool)
    cold[d.hot_pixels[:, 1], d.hot_pixels[:, 0]] = False
    assert len(d.hot_pixels) == 200 and len({tuple(p) for p in d.hot_pixels}) == 200
    assert np.all(d.dark_multiplier[~cold] == 80.0)
    assert d.dark_multiplier[cold].min() > 0
    assert d.dark_multiplier[cold].mean() == pytest.approx(1.0, abs=0.01)
    assert d.dark_multiplier[cold].std() == pytest.approx(0.3, rel=0.05)
    assert d.prnu_gain.mean() == pytest.approx(1.0, abs=1e-3)
    assert d.prnu_gain.std() == pytest.approx(0.02, rel=0.02)
    other = SensorDefects.generate(400, 500, seed=2, dsnu=0.3, prnu=0.02, hot_fraction=0.0)
    assert np.array_equal(other.prnu_gain, d.prnu_gain) and len(other.hot_pixels) == 0


def test_hot_pixels_are_bright_where_listed():
    d = SensorDefects.generate(100, 120, seed=7, dsnu=0.1, prnu=0.0, hot_fraction=2e-3,
                               hot_dark_factor=200.0)
    codes = frame(np.zeros((100, 120)), seed=3, exposure_s=1.0, dark_current_e_per_s=5.0,
                  read_noise_e=2.0, defects=d, pixel_bits=16).astype(float)
    hot = codes[d.hot_pixels[:, 1], d.hot_pixels[:, 0]]
    assert len(hot) == 24
    assert hot.min() > 700                      # 1000 e- expected, Poisson sigma ~32
    mask = np.ones(codes.shape, dtype=bool)
    mask[d.hot_pixels[:, 1], d.hot_pixels[:, 0]] = False
    assert codes[mask].max() < 40 and codes[mask].mean() == pytest.approx(5.0, abs=0.2)


def test_prnu_scales_signal_and_sky():
    d = SensorDefects.generate(300, 300, seed=1, prnu=0.05, hot_fraction=0.0)
    codes = frame(np.full((300, 300), 9000.0), seed=4, sky_e_per_px_s=10000.0, defects=d,
                  pixel_bits=16).astype(float)
    expected = 10000.0 * d.prnu_gain
    residual = codes - expected
    assert abs(residual.mean()) < 1.0 and residual.std() == pytest.approx(100.0, rel=0.05)


@pytest.mark.parametrize("name, kwargs", [
    ("exposure_s", {"exposure_s": -1.0}),
    ("pixel_bits", {"pixel_bits": 0}),
    ("pixel_bits", {"pixel_bits": 17}),
    ("pixel_bits", {"pixel_bits": 12.5}),
    ("gain_adu_per_e", {"gain_adu_per_e": 0.0}),
    ("read_noise_e", {"read_noise_e": -1.0}),
    ("sky_e_per_px_s", {"sky_e_per_px_s": float("nan")}),
    ("dark_current_e_per_s", {"dark_current_e_per_s": -2.0}),
    ("reserved_low_codes", {"reserved_low_codes": 5000}),
    ("image_e", {"image": -np.ones((4, 4))}),
    ("defects", {"defects": SensorDefects.generate(3, 3, seed=0)}),
])
def test_bad_inputs(name, kwargs):
    image = kwargs.pop("image", np.zeros((4, 4)))
    with pytest.raises(ValueError, match=name):
        frame(image, **kwargs)


@pytest.mark.parametrize("name, kwargs", [
    ("seed", {"seed": -1}), ("dsnu", {"dsnu": -0.1}), ("prnu", {"prnu": float("nan")}),
    ("hot_fraction", {"hot_fraction": 1.5}), ("height", {"height": 0}),
])
def test_bad_defect_parameters(name, kwargs):
    with pytest.raises(ValueError, match=name):
        SensorDefects.generate(**{"height": 8, "width": 8, "seed": 0, **kwargs})
