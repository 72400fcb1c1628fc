"""Tests of ``lodestar.firmware.screen``: residual and brightness outliers among a
solution's matches, and each match's leverage in the fit."""

import numpy as np

from lodestar.firmware import screen


def test_residual_outliers_against_the_median_noise():
    rng = np.random.default_rng(5)
    chi2s = list(rng.chisquare(2, 30))          # unit-variance residuals over two axes
    assert screen.residual_outliers(chi2s) == []
    chi2s[7] = 40.0                             # a 6.3-sigma residual
    assert screen.residual_outliers(chi2s) == [7]
    assert screen.residual_outliers([1.0, 1.0, 1.0, 100.0]) == []     # too few to judge
    assert screen.residual_outliers([0.0] * 6 + [1.0]) == []           # no noise scale


def test_brightness_outliers_contradict_the_sky_order():
    mags = [2.0, 3.0, 3.5, 4.0, 4.2, 4.5, 5.0, 5.5]
    fluxes = [100.0, 80.0, 60.0, 50.0, 40.0, 30.0, 20.0, 10.0]
    assert screen.brightness_outliers(fluxes, mags) == []
    # the second brightest observed named as a V 8 star: five of six fainter ones are
    # catalogue stars more than 2 mag brighter
    named = list(mags)
    named[1] = 8.0
    assert screen.brightness_outliers(fluxes, named) == [1]
    # magnitude noise within the slack, or too few contradictions, is no outlier
    assert screen.brightness_outliers(fluxes, [2.0, 4.9, 3.5, 4.0, 4.2, 4.5, 5.0, 5.5]) == []
    assert screen.brightness_outliers([100.0, 80.0, 60.0, 50.0], [2.0, 8.0, 3.0, 3.1]) == []
    assert screen.brightness_outliers([0.0] + fluxes[1:], [9.0] + mags[1:]) == []


def unit(x, y):
    v = np.array([x, y, 1.0])
    return tuple(v / np.linalg.norm(v))


def test_leverages_are_each_match_share_of_the_fit():
    """Equal weights on a ring: every star ``1/n`` of the cross axes and ``1/(2n)`` of the
    roll; a heavy star takes most of both, a star at the centre none of the roll; the shares
    sum to 1.5 (two cross axes over a star's two axes, plus roll on one of them)."""
    ring = [unit(0.1 * np.cos(a), 0.1 * np.sin(a)) for a in np.linspace(0, 2 * np.pi, 8,
                                                                            endpoint=False)]
    h = screen.leverages(ring, [1.0] * 8)
    assert np.allclose(h, 1 / 8 + 1 / 16, rtol=1e-3)
    heavy = screen.leverages(ring, [10.0] + [1.0] * 7)
    assert heavy[0] > 0.6 and heavy[0] > 4 * max(heavy[1:])
    centre = screen.leverages([unit(0.0, 0.0)] + ring, [1.0] * 9)
    assert abs(centre[0] - 1 / 9) < 1e-3
    assert abs(sum(screen.leverages(ring, list(range(1, 9)))) - 1.5) < 1e-2
    assert screen.leverages([], []) == []
