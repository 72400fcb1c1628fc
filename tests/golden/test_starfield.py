"""The synthetic star frames: deterministic, in range, and with centroids where the truth is."""

import numpy as np
import pytest

from lodestar import contract as C
from lodestar.golden import DetectorConfig, detect_frame
from lodestar.golden.starfield import star_frame


def test_deterministic_and_in_range():
    a, stars_a = star_frame(200, 150, 10, n_stars=12, seed=5)
    b, stars_b = star_frame(200, 150, 10, n_stars=12, seed=5)
    c, _ = star_frame(200, 150, 10, n_stars=12, seed=6)
    assert a.dtype == np.uint16 and a.shape == (150, 200)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert [s.x for s in stars_a] == [s.x for s in stars_b]
    assert int(a.max()) <= C.full_scale(10)
    assert [s.flux for s in stars_a] == sorted((s.flux for s in stars_a), reverse=True)


def test_flux_is_integrated_over_pixels():
    """Without noise the frame holds the whole flux (erf integration, not centre samples)."""
    frame, (star,) = star_frame(64, 64, 16, n_stars=1, seed=1, sigma=0.7, background=0,
                                read_noise=0, flux_range=(5e4, 5e4), gain=1e6)
    assert abs(int(frame.sum()) - star.flux) < 0.01 * star.flux


def test_detected_centroids_match_truth():
    frame, stars = star_frame(400, 300, 12, n_stars=20, seed=3, flux_range=(2e4, 1e5))
    cfg = DetectorConfig(width=400, height=300, threshold=120, background=40, min_pixels=6)
    blobs = detect_frame(frame, cfg).blobs
    assert len(blobs) >= 18
    for b in blobs:
        d = min(np.hypot(s.x - b.sx / b.s0, s.y - b.sy / b.s0) for s in stars)
        assert d < 0.2


@pytest.mark.parametrize("kwargs", [{"pixel_bits": 9}, {"sigma": 0}, {"read_noise": -1}])
def test_bad_parameters(kwargs):
    with pytest.raises(ValueError):
        star_frame(32, 32, **{"pixel_bits": 12, **kwargs})
