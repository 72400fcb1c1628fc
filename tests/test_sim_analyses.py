"""Seed analyses that are exact: Schumann's cluster count and false-blob probability."""

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
