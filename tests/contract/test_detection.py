"""The contract's widths, limits and integer formulas, checked against first principles."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lodestar import contract as C
from lodestar.golden import DetectorConfig
from lodestar.golden.streaming import StreamingModel


def test_frame_limits_cover_the_cameras():
    assert C.MAX_WIDTH >= 4096 and C.MAX_HEIGHT >= 4096
    assert (1 << C.X_BITS) >= C.MAX_WIDTH > (1 << (C.X_BITS - 1))
    assert set(C.SENSOR_PIXEL_BITS.values()) | set(C.FILE_PIXEL_BITS) == set(C.PIXEL_BITS)


@pytest.mark.parametrize("pixel_bits", C.PIXEL_BITS)
def test_moment_widths_are_tight(pixel_bits):
    """Exact for EXACT_BLOB_PIXELS full-scale pixels at the far corner, and not wider."""
    widths = C.moment_widths(pixel_bits)
    fs = C.full_scale(pixel_bits)
    xm, ym = C.MAX_WIDTH - 1, C.MAX_HEIGHT - 1
    worst = {"s0": 1, "sx": xm, "sy": ym, "sxx": xm * xm, "syy": ym * ym, "sxy": xm * ym}
    for name, factor in worst.items():
        value = C.EXACT_BLOB_PIXELS * fs * factor
        assert value <= C.moment_max(pixel_bits)[name], name
        assert value > (1 << (widths[name] - 1)) - 1, f"{name} is wider than needed"


def test_register_map_is_consistent():
    addresses = [r.address for r in C.REGISTERS]
    assert len(set(addresses)) == len(addresses)
    for r in C.REGISTERS:
        assert 0 < r.bits <= C.REGISTER_WORD_BITS
        assert 0 <= r.reset < (1 << r.bits), r.name
    assert C.REGISTER_BY_NAME["mode"].bits >= C.bits_for(len(C.MODE_NAMES) - 1)
    assert (1 << C.REGISTER_BY_NAME["local_log2_window"].bits) > C.LOCAL_LOG2_WINDOW_MAX
    # the ST-16 baseline threshold is the reset value
    assert C.REGISTER_BY_NAME["threshold"].reset == 120


@pytest.mark.parametrize("pixel_bits", C.PIXEL_BITS)
def test_register_ranges_fit_their_fields(pixel_bits):
    for r in C.REGISTERS:
        low, high = C.register_range(r.name, pixel_bits)
        assert 0 <= low <= r.reset <= high < (1 << r.bits), r.name
    assert C.register_range("mode", pixel_bits) == (0, len(C.MODE_NAMES) - 1)
    assert C.register_range("local_log2_window", pixel_bits) == (C.LOCAL_LOG2_WINDOW_MIN,
                                                                 C.LOCAL_LOG2_WINDOW_MAX)
    for name in ("threshold", "background", "local_offset"):
        assert C.register_range(name, pixel_bits) == (0, C.full_scale(pixel_bits))
    assert C.register_range("max_pixels", pixel_bits) == (0, C.MAX_PIXELS_UNLIMITED)


def test_check_geometry():
    C.check_geometry(1, 1)
    C.check_geometry(C.MAX_WIDTH, C.MAX_HEIGHT, C.MAX_PIXEL_BITS)
    for width, height in ((0, 1), (1, 0), (C.MAX_WIDTH + 1, 1), (1, C.MAX_HEIGHT + 1)):
        with pytest.raises(ValueError, match="outside the contract"):
            C.check_geometry(width, height)
    with pytest.raises(ValueError, match="pixel_bits=14 is not one of"):
        C.check_geometry(64, 48, 14)


def _global_by_definition(pixels, kreg, pixel_bits):
    """T and B straight from the written definition (float-free, brute-force search)."""
    n, s1, s2 = len(pixels), sum(pixels), sum(p * p for p in pixels)
    b = s1 // n
    d = 0
    while (16 * n * (d + 1)) ** 2 <= kreg * kreg * (n * s2 - s1 * s1):
        d += 1
    return min(b + d, C.full_scale(pixel_bits)), b


def test_global_levels_hand_checked():
    # pixels 10, 10, 10, 30: mean 15, population sigma = sqrt(75) = 8.66
    # k = 3 -> D = floor(25.98) = 25 -> T = 40
    assert C.global_levels(4, 60, 1200, 3 * 16, 12) == (40, 15)
    # k = 1.5 -> floor(12.99) = 12
    assert C.global_levels(4, 60, 1200, 24, 12) == (27, 15)
    # flat frame: sigma 0, T = B = mean
    assert C.global_levels(6, 6 * 77, 6 * 77 * 77, 255, 10) == (77, 77)
    # clamped at full scale
    assert C.global_levels(2, 1023, 1023 * 1023, 255, 10) == (1023, 511)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.integers(0, 4095), min_size=1, max_size=40), st.integers(0, 255))
def test_global_levels_match_definition(pixels, kreg):
    n, s1, s2 = len(pixels), sum(pixels), sum(p * p for p in pixels)
    assert C.global_levels(n, s1, s2, kreg, 12) == _global_by_definition(pixels, kreg, 12)
    # and D is floor(k * sigma) (away from float rounding at integer boundaries)
    t, b = C.global_levels(n, s1, s2, kreg, 12)
    ksig = kreg / 16 * float(np.std(np.array(pixels, dtype=np.float64)))
    if abs(ksig - round(ksig)) > 1e-6 and b + ksig < 4095:
        assert t - b == math.floor(ksig)


def test_local_window_start_slides_inward():
    w, lg = 20, 3  # L = 8, window spans 9 columns
    starts = [C.local_window_start(x, w, lg) for x in range(w)]
    assert starts[:5] == [0, 0, 0, 0, 0]
    assert starts[5:16] == list(range(1, 12))
    assert starts[16:] == [11] * 4
    for x, s in enumerate(starts):
        assert s <= x <= s + 8 and 0 <= s and s + 8 <= w - 1


def test_passes_filters():
    assert C.passes_filters(6, 1000, 6, 1000, 10)
    assert not C.passes_filters(5, 5000, 6, 1000, 10)
    assert not C.passes_filters(6, 999, 6, 1000, 10)
    assert not C.passes_filters(11, 5000, 6, 1000, 10)


@pytest.mark.parametrize("height,width", [(h, w) for h in (2, 3) for w in range(1, 6)])
def test_max_open_blobs_is_the_exact_worst_case(height, width):
    """Exhaustively: no frame opens more than width//2 + 1 blobs, and some frame does."""
    peak = 0
    cfg = DetectorConfig(width=width, height=height)
    for bits in range(1 << (height * width)):
        mask = np.array([(bits >> i) & 1 for i in range(height * width)], dtype=np.uint16)
        model = StreamingModel(cfg)
        model.run((mask * 500).reshape(height, width), None)
        peak = max(peak, model.peak_open)
    assert peak == C.max_open_blobs(width)


def test_max_open_blobs_on_wide_stripes():
    """Vertical stripes with a new blob starting under them reach the bound at width 64."""
    w = 64
    frame = np.zeros((3, w), dtype=np.uint16)
    frame[0:2, 1::2] = 500   # w/2 open stripes (columns 1, 3, ..., 63)
    frame[1, 0] = 500        # a new blob starts at (0, 1): left dark, above dark
    model = StreamingModel(DetectorConfig(width=w, height=3))
    model.run(frame, None)
    assert model.peak_open == C.max_open_blobs(w) == 33
