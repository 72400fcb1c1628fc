"""Seed analyses that are exact: Schumann's cluster count and false-blob probability."""

import numpy as np
import pytest

from lodestar.sim import analyses


@pytest.mark.parametrize("size,fixed", [(1, 1), (2, 2), (3, 6), (4, 19), (5, 63), (6, 216)])
def test_fixed_polyomino_counts(size, fixed):
    # OEIS A001168: fixed polyominoes
    assert analyses.cluster_shapes_through_pixel(size) == size * fixed


def test_schumann_1296_and_false_blob_probability():
    assert analyses.cluster_shapes_through_pixel(6) == 1296
    p = 0.00135  # the thesis' rounded 3-sigma tail
    assert analyses.false_blob_probability(p) == pytest.approx(7.84e-15, rel=1e-3)
    assert analyses.gaussian_tail(3.0) == pytest.approx(0.0013499, rel=1e-4)
    # the thesis' erratum: a 2-sigma tail gives 1.8e-7, not 7.84e-15
    assert analyses.false_blob_probability(analyses.gaussian_tail(2.0)) == \
        pytest.approx(1.8e-7, rel=0.05)


def test_bad_arguments():
    with pytest.raises(ValueError, match="size must be >= 1"):
        analyses.cluster_shapes_through_pixel(0)
    with pytest.raises(ValueError, match="p must be a probability"):
        analyses.false_blob_probability(1.5)


def test_dzamba_static_availability():
    """Dzamba L1632: > 99.9 % of attitudes see >= 3 stars of V <= 5.75 within 7.5 deg."""
    from lodestar.sim import catalogue
    rng = np.random.default_rng(1)
    stars = catalogue.load().brighter_than(5.75).unit_vectors()
    fraction, sigma = analyses.availability(stars, 3, 20000, rng, half_fov_deg=7.5)
    assert fraction > 0.999 and sigma < 2e-4
    # a much smaller field cannot reach it: the count is doing real work
    assert analyses.availability(stars, 3, 4000, rng, half_fov_deg=3.0)[0] < 0.9


def test_schumann_availability_brackets_87_percent():
    """Schumann L505: ~87 % of the sky has >= 3 stars of V <= 4.5 in the ESTCube-2 field.
    The full MT9P031 field (20.2 x 15.2 deg) gives more, the lens' rated 17.2 x 13 deg less."""
    from lodestar.sim import catalogue, presets
    from lodestar.sim.goldenset import window_camera
    stars = catalogue.load().brighter_than(4.5).unit_vectors()
    cam = presets.load_preset("estcube2")
    lens = window_camera(cam, (193, 142, 2206, 1660))
    full, _ = analyses.availability(stars, 3, 3000, np.random.default_rng(2), camera=cam)
    rated, _ = analyses.availability(stars, 3, 3000, np.random.default_rng(3), camera=lens)
    assert rated < 0.87 < full
    assert 0.75 < rated and full < 0.96


def test_stars_in_view_by_hand():
    stars = np.array([[0.0, 0.0, 1.0], [np.sin(0.1), 0.0, np.cos(0.1)], [1.0, 0.0, 0.0]])
    counts = analyses.stars_in_view(stars, np.array([[0.0, 0.0, 1.0]]), half_fov_deg=6.0)
    assert counts.tolist() == [2]
    with pytest.raises(ValueError, match="exactly one of"):
        analyses.stars_in_view(stars, stars, half_fov_deg=5.0, camera=object())
