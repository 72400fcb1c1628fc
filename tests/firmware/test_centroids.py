"""Tests of ``lodestar.firmware.centroids``: exact moments, shapes, the quality filter, and
the whole chain (simulated frame -> golden detector -> records -> stars) against truth."""

import json
import math
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lodestar import contract as C
from lodestar.firmware import centroids, packet
from lodestar.firmware.camera import Camera
from lodestar.golden import DetectorConfig, detect_frame
from lodestar.golden.starfield import star_frame
from lodestar.sim import presets, render, sensor
from lodestar.sim.goldenset import window_camera

GOLDEN_SMALL = Path(__file__).parents[1] / "data" / "golden_small"


# --------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------

def record_from_weights(weights, x0=0, y0=0, flags=0):
    """The record of a blob whose pixel weights are ``weights`` (2-D ints, 0 = not in the
    blob), its array origin at pixel ``(x0, y0)``."""
    ys, xs = np.nonzero(weights)
    w = [int(v) for v in weights[ys, xs]]
    xs = [int(v) + x0 for v in xs]
    ys = [int(v) + y0 for v in ys]
    return C.BlobRecord(
        n=len(w), nsat=0, s0=sum(w), sx=sum(a * x for a, x in zip(w, xs)),
        sy=sum(a * y for a, y in zip(w, ys)), sxx=sum(a * x * x for a, x in zip(w, xs)),
        syy=sum(a * y * y for a, y in zip(w, ys)),
        sxy=sum(a * x * y for a, x, y in zip(w, xs, ys)), xmin=min(xs), xmax=max(xs),
        ymin=min(ys), ymax=max(ys), peak=max(w), flags=flags)


def gaussian_weights(sigma_major, sigma_minor, angle, amplitude=2000.0, size=41):
    """Integer weights of an elliptical Gaussian centred in a ``size`` x ``size`` array."""
    c = (size - 1) / 2 + 0.3
    y, x = np.mgrid[0:size, 0:size]
    u = (x - c) * math.cos(angle) + (y - c) * math.sin(angle)
    v = -(x - c) * math.sin(angle) + (y - c) * math.cos(angle)
    g = amplitude * np.exp(-0.5 * ((u / sigma_major) ** 2 + (v / sigma_minor) ** 2))
    return np.rint(g).astype(np.int64)


def line_weights(length, angle, width=0.5, amplitude=1000.0, size=41):
    """Integer weights of a thin straight track (a cosmic ray, or a smeared sharp star)."""
    c = (size - 1) / 2
    y, x = np.mgrid[0:size, 0:size]
    u = (x - c) * math.cos(angle) + (y - c) * math.sin(angle)
    v = -(x - c) * math.sin(angle) + (y - c) * math.cos(angle)
    inside = np.clip(length / 2 + 0.5 - np.abs(u), 0, 1)
    g = amplitude * inside * np.exp(-0.5 * (v / width) ** 2)
    return np.rint(g).astype(np.int64)


def smeared_star_weights(sigma, dx, dy, amplitude=3000.0, size=61, steps=200):
    """Integer weights of a Gaussian star moved uniformly by ``(dx, dy)`` px."""
    c = (size - 1) / 2
    y, x = np.mgrid[0:size, 0:size]
    g = np.zeros((size, size))
    for t in np.linspace(-0.5, 0.5, steps):
        g += np.exp(-0.5 * ((x - c - t * dx) ** 2 + (y - c - t * dy) ** 2) / sigma ** 2)
    return np.rint(amplitude * g / steps).astype(np.int64)


def exact_moments(rec):
    """``(x, y, cxx, cyy, cxy)`` as Fractions."""
    s0 = Fraction(rec.s0)
    x, y = rec.sx / s0, rec.sy / s0
    return x, y, rec.sxx / s0 - x * x, rec.syy / s0 - y * y, rec.sxy / s0 - x * y


def star_records(seed=1, pixel_bits=12, **kwargs):
    frame, _ = star_frame(width=200, height=150, pixel_bits=pixel_bits, n_stars=40, seed=seed,
                          **kwargs)
    cfg = DetectorConfig(width=200, height=150, pixel_bits=pixel_bits, threshold=60,
                         background=40)
    return detect_frame(frame, cfg).blobs


def total(rejected):
    assert set(rejected) == set(centroids.REASONS)
    return sum(rejected.values())


# --------------------------------------------------------------------------------------
# Moments and shape
# --------------------------------------------------------------------------------------

def test_moments_are_exact_for_golden_records():
    records = star_records(1) + star_records(2, pixel_bits=16, flux_range=(1e4, 1e7))
    assert len(records) > 40
    for rec in records:
        x, y, cxx, cyy, cxy, det = centroids.moments(rec)
        ex, ey, exx, eyy, exy = exact_moments(rec)
        assert x == pytest.approx(float(ex), rel=1e-15, abs=1e-12)
        assert y == pytest.approx(float(ey), rel=1e-15, abs=1e-12)
        assert cxx == float(exx) and cyy == float(eyy) and cxy == float(exy)
        assert det == pytest.approx(float(exx * eyy - exy * exy), rel=1e-12, abs=1e-300)


def wide_record(rec):
    """``rec`` as the flight decoder yields it (``packet.WideRecord``, moments in limbs)."""
    out = packet.WideRecord()
    for name in C.RECORD_NAMES:
        if name not in packet.WIDE:
            setattr(out, name, getattr(rec, name))
    for k, name in enumerate(packet.WIDE):
        v = getattr(rec, name)
        out.limbs[3 * k:3 * k + 3] = [v >> 30, (v >> 15) & 0x7FFF, v & 0x7FFF]
    return out


def test_wide_records_give_the_exact_moments_to_a_few_units_of_the_last_place():
    """A ``packet.WideRecord``'s moments come from small ints (``_limb_moments``): the
    centroid as the exact path's, the second moments within a few units of the last place of
    ``1 + c``; a blob with no width falls back to the exact path (the same values)."""
    records = star_records(1) + star_records(2, pixel_bits=16, flux_range=(1e4, 1e7))
    records.append(record_from_weights(gaussian_weights(6.0, 1.0, -0.7), 3000, 1900))
    fast = 0
    for rec in records:
        exact = centroids.moments(rec)
        got = centroids.moments(wide_record(rec))
        assert got[:2] == exact[:2]
        for a, b in zip(got[2:5], exact[2:5]):
            assert abs(a - b) <= 1e-14 * (1.0 + abs(b))
        assert got[5] == pytest.approx(exact[5], rel=1e-12)
        _, _, cxx, cyy, _, det = exact
        clear = cxx > 0.02 * (1 + cxx) and cyy > 0.02 * (1 + cyy) and det > 0.02 * cxx * cyy
        taken = centroids._limb_moments(rec.s0, wide_record(rec).limbs) is not None
        assert taken or not clear       # every blob with a width takes the small-int path
        fast += taken
    assert fast > 60
    row = record_from_weights(np.array([[5, 5, 5, 5]]), 10, 20)
    assert centroids._limb_moments(row.s0, wide_record(row).limbs) is None
    assert centroids.moments(wide_record(row)) == centroids.moments(row)
    huge = record_from_weights(np.array([[60000, 60000], [60000, 60000]]) * 1000, 4000, 4000)
    assert huge.sx >= 1 << 30           # beyond a small int: the exact path
    assert centroids.moments(wide_record(huge)) == centroids.moments(huge)


def test_moments_match_numpy_weighted_covariance():
    rng = np.random.default_rng(3)
    for _ in range(20):
        weights = rng.integers(0, 4000, (7, 9)) * (rng.random((7, 9)) < 0.7)
        rec = record_from_weights(weights, x0=int(rng.integers(0, 4000)),
                                  y0=int(rng.integers(0, 4000)))
        ys, xs = np.nonzero(weights)
        w = weights[ys, xs].astype(float)
        xs = xs + (rec.xmin - xs.min())
        ys = ys + (rec.ymin - ys.min())
        cov = np.cov(np.vstack([xs, ys]), aweights=w, bias=True)
        x, y, cxx, cyy, cxy, _ = centroids.moments(rec)
        assert (x, y) == pytest.approx((np.average(xs, weights=w), np.average(ys, weights=w)),
                                       abs=1e-9)
        assert (cxx, cyy, cxy) == pytest.approx((cov[0, 0], cov[1, 1], cov[0, 1]), abs=1e-6)
        smaj, smin, elong, orient = centroids.shape(cxx, cyy, cxy)
        evals, evecs = np.linalg.eigh(cov)
        assert (smin, smaj) == pytest.approx(tuple(np.sqrt(np.maximum(evals, 0))), abs=1e-6)
        major = evecs[:, 1]
        assert abs(math.sin(orient - math.atan2(major[1], major[0]))) < 1e-6
        assert elong == pytest.approx(smaj / smin)


@pytest.mark.parametrize("angle", np.linspace(-math.pi / 2 + 0.01, math.pi / 2, 9))
def test_shape_of_rotated_gaussian(angle):
    rec = record_from_weights(gaussian_weights(4.0, 1.5, angle))
    smaj, smin, elong, orient = centroids.shape(*centroids.moments(rec)[2:])
    assert smaj == pytest.approx(4.0, rel=2e-3)
    assert smin == pytest.approx(1.5, rel=2e-3)
    assert elong == pytest.approx(4.0 / 1.5, rel=4e-3)
    assert -math.pi / 2 < orient <= math.pi / 2
    assert abs(math.sin(orient - angle)) < 2e-3


def test_shape_edge_cases():
    assert centroids.shape(0.0, 0.0, 0.0) == (0.0, 0.0, 1.0, 0.0)          # single pixel
    row = record_from_weights(np.array([[5, 5, 5, 5]]), 10, 20)     # one row: no width
    smaj, smin, elong, orient = centroids.shape(*centroids.moments(row)[2:])
    assert smin == 0.0 and elong == math.inf and orient == 0.0
    assert smaj == pytest.approx(math.sqrt(1.25))
    col = record_from_weights(np.array([[5], [5], [5], [5]]), 10, 20)
    smaj, smin, elong, orient = centroids.shape(*centroids.moments(col)[2:])
    assert smin == 0.0 and orient == pytest.approx(math.pi / 2)


def test_minor_axis_accurate_for_long_thin_blobs():
    """``l2 = det / l1`` keeps the minor sigma accurate where ``l1 - root`` would cancel."""
    rec = record_from_weights(gaussian_weights(2000.0, 0.4, 0.3, size=401), 100, 100)
    _, _, cxx, cyy, cxy, det = centroids.moments(rec)
    exact = exact_moments(rec)
    a, b, c = exact[2], exact[4], exact[3]
    mean = (a + c) / 2
    # exact minor eigenvalue to double precision from the Fractions
    disc = float(((a - c) / 2) ** 2 + b * b)
    l1 = float(mean) + math.sqrt(disc)
    l2_exact = float(a * c - b * b) / l1
    assert centroids.shape(cxx, cyy, cxy, det)[1] == pytest.approx(math.sqrt(l2_exact), rel=1e-9)


# --------------------------------------------------------------------------------------
# Quality filter on crafted records
# --------------------------------------------------------------------------------------

STAR = record_from_weights(gaussian_weights(1.5, 1.5, 0.0, size=15), 100, 50)


def _with(rec, **changes):
    values = dict(zip(C.RECORD_NAMES, rec.as_tuple()))
    values.update(changes)
    return C.BlobRecord(**values)


def test_round_star_is_kept_with_its_measurements():
    stars, rejected = centroids.extract([STAR])
    assert total(rejected) == 0 and len(stars) == 1
    s = stars[0]
    x, y = centroids.moments(STAR)[:2]
    assert (s.x, s.y, s.flux, s.n, s.nsat, s.peak, s.index) == (
        x, y, STAR.s0, STAR.n, 0, STAR.peak, 0)
    assert s.sigma_major == pytest.approx(1.5, rel=0.02)
    assert s.elongation < 1.01
    assert s.as_tuple()[:3] == (s.x, s.y, s.flux)
    assert "Star(x=" in repr(s)


@pytest.mark.parametrize("changes, reason", [
    (dict(s0=0), "empty"),
    (dict(flags=C.BLOB_MOMENTS_SATURATED), "saturated"),
    (dict(sx=STAR.s0 * 200), "inconsistent"),                  # centroid right of the box
    (dict(sy=STAR.s0 * 10), "inconsistent"),                   # centroid above the box
    (dict(sxx=STAR.sx * STAR.sx // STAR.s0 - 1000), "inconsistent"),   # negative variance
    (dict(sxy=STAR.sxy * 2), "inconsistent"),                  # not positive semi-definite
    (dict(n=2), "hot_pixel"),
])
def test_rejection_reasons(changes, reason):
    stars, rejected = centroids.extract([_with(STAR, **changes)])
    assert stars == [] and rejected[reason] == 1 and total(rejected) == 1


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -5.0, -1, 0.0])
def test_bad_s0_is_empty(value):
    stars, rejected = centroids.extract([_with(STAR, s0=value)])
    assert stars == [] and rejected["empty"] == 1


@pytest.mark.parametrize("name", ["sx", "sy", "sxx", "syy", "sxy"])
def test_non_finite_moment_is_inconsistent(name):
    stars, rejected = centroids.extract([_with(STAR, **{name: float("nan")})])
    assert stars == [] and rejected["inconsistent"] == 1


def test_float_records_agree_with_int_records():
    as_float = _with(STAR, **{name: float(getattr(STAR, name)) for name in C.MOMENTS})
    a = centroids.extract([STAR])[0][0].as_tuple()
    b = centroids.extract([as_float])[0][0].as_tuple()
    assert b == pytest.approx(a, rel=1e-9)


def test_hot_pixels_are_rejected():
    single = record_from_weights(np.array([[3000]]), 5, 5)
    pair = record_from_weights(np.array([[3000, 2000]]), 5, 5)
    # sharper than any PSF: a bright pixel with faint neighbours (sigma 0.06 px)
    sharp = record_from_weights(np.array([[0, 10, 0], [10, 5000, 10], [0, 10, 0]]), 5, 5)
    stars, rejected = centroids.extract([single, pair, sharp])
    assert stars == [] and rejected["hot_pixel"] == 3
    stars, rejected = centroids.extract([single, pair, sharp], min_pixels=1, min_sigma_px=0.0)
    assert len(stars) == 2 and rejected["cosmic_ray"] == 1        # the pair is a 1-D track
    assert centroids.extract([sharp], min_sigma_px=0.05)[0]


def test_lohmann_like_sharp_star_is_kept():
    """A PSF of sigma 0.6 px (the Lohmann lens) passes the default sharpness limit."""
    rec = record_from_weights(gaussian_weights(0.6, 0.6, 0.0, amplitude=3000, size=9))
    stars, _ = centroids.extract([rec])
    assert len(stars) == 1 and stars[0].sigma_minor > centroids.DEFAULT_MIN_SIGMA_PX


@pytest.mark.parametrize("angle", [0.0, 0.4, -1.2, math.pi / 2])
def test_cosmic_ray_and_smear(angle):
    length = 14.0
    track = record_from_weights(line_weights(length, angle), 300, 200)
    smear = (length * math.cos(angle), length * math.sin(angle))
    _, rejected = centroids.extract([track])
    assert rejected["cosmic_ray"] == 1
    # the expected smear explains it, in either sense
    for sense in (1, -1):
        stars, _ = centroids.extract([track], expected_smear_px=(sense * smear[0],
                                                                 sense * smear[1]))
        assert len(stars) == 1
        assert abs(math.sin(stars[0].orientation - angle)) < 0.01
    # ... and as a function of position
    calls = []

    def smear_at(x, y):
        calls.append((x, y))
        return smear
    assert len(centroids.extract([track], expected_smear_px=smear_at)[0]) == 1
    assert calls and calls[0] == pytest.approx(centroids.moments(track)[:2])
    # a third of a longer expected track alone: a cosmic ray along the smear as likely as
    # a piece of a track; with another piece of the same track, joined to it (below)
    for wrong in [(-smear[1], smear[0]), (smear[0] * 3, smear[1] * 3),
                  (smear[0] / 3, smear[1] / 3),
                  (0.0, 0.0), (float("nan"), 1.0)]:
        _, rejected = centroids.extract([track], expected_smear_px=wrong)
        assert rejected["cosmic_ray"] == 1, wrong
    assert centroids.extract([track], expected_smear_px=lambda x, y: None)[1]["cosmic_ray"] == 1


def test_smeared_star_kept_only_with_expected_smear():
    dx, dy = 24.0, -10.0
    rec = record_from_weights(smeared_star_weights(1.2, dx, dy), 500, 400)
    smaj, smin, elong, orient = centroids.shape(*centroids.moments(rec)[2:])
    assert elong > centroids.DEFAULT_MAX_ELONGATION
    assert math.sqrt(12 * (smaj ** 2 - smin ** 2)) == pytest.approx(math.hypot(dx, dy), rel=0.02)
    assert centroids.extract([rec])[1]["cosmic_ray"] == 1
    stars, _ = centroids.extract([rec], expected_smear_px=(dx, dy))
    assert len(stars) == 1
    assert (stars[0].x - 500 - 30, stars[0].y - 400 - 30) == pytest.approx((0, 0), abs=0.01)


def test_broken_track_is_joined_into_one_star():
    # a smeared star whose track a threshold cut in two: the joined star has the moments of
    # the whole track, exactly (the pieces' sums add), and the brightest piece's index
    dx, dy = 24.0, -10.0
    w = smeared_star_weights(1.2, dx, dy)
    whole = record_from_weights(w, 500, 400)
    c = (w.shape[0] - 1) / 2
    y, x = np.mgrid[0:w.shape[0], 0:w.shape[1]]
    along = (x - c) * dx + (y - c) * dy
    gap = np.abs(along) < 0.08 * (dx * dx + dy * dy)            # the cut across the middle
    left = record_from_weights(np.where((along < 0) & ~gap, w, 0), 500, 400)
    right = record_from_weights(np.where((along > 0) & ~gap, w, 0), 500, 400)
    noise = record_from_weights(gaussian_weights(1.2, 1.2, 0.0, size=11), 800, 100)
    stars, rejected = centroids.extract([noise, left, right], expected_smear_px=(dx, dy))
    assert len(stars) == 2 and rejected["fragment"] == 1 and total(rejected) == 1
    joined = [s for s in stars if s.parts is not None][0]
    assert joined.parts == [1, 2] and joined.flux == left.s0 + right.s0
    assert joined.index == (1 if left.s0 >= right.s0 else 2)
    assert joined.n == left.n + right.n
    assert (joined.x, joined.y) == pytest.approx((500 + c, 400 + c), abs=0.05)
    kept = whole.s0 - left.s0 - right.s0        # the gap's light is lost, the rest is exact
    assert kept > 0
    sx = left.sx + right.sx
    assert joined.x == pytest.approx(sx / (left.s0 + right.s0), abs=1e-9)
    _smaj, smin, _e, _orient = centroids.shape(*centroids.moments(whole)[2:])
    assert joined.sigma_minor == pytest.approx(smin, rel=0.1)
    assert math.tan(joined.orientation) == pytest.approx(dy / dx, abs=0.02)
    # without a known smear, or across the smear, nothing is joined
    stars, rejected = centroids.extract([left, right])
    assert rejected["fragment"] == 0 and all(s.parts is None for s in stars)
    stars, rejected = centroids.extract([left, right], expected_smear_px=(-dy, dx))
    assert rejected["fragment"] == 0
    # two stars further apart along the smear than its length stay apart
    far = record_from_weights(np.where((along > 0) & ~gap, w, 0), 560, 375)
    stars, rejected = centroids.extract([left, far], expected_smear_px=(dx, dy))
    assert rejected["fragment"] == 0 and len(stars) == 2


def test_broken_track_centred_on_its_extent():
    # a cut off the middle of a track (a third of it from one end, a fifth of it wide)
    # leaves more light on one side: the joined star lies at the middle of the pieces'
    # extent along the smear, where the star was at mid-exposure, not at their light's mean
    # (the firmware before this rule: 3 px off along this 60 px track)
    dx, dy = 48.0, -36.0
    w = smeared_star_weights(1.5, dx, dy, size=81)
    c = (w.shape[0] - 1) / 2
    y, x = np.mgrid[0:w.shape[0], 0:w.shape[1]]
    along = ((x - c) * dx + (y - c) * dy) / (dx * dx + dy * dy)      # -0.5 .. 0.5
    gap = np.abs(along - 0.2) < 0.1
    left = record_from_weights(np.where((along < 0.2) & ~gap, w, 0), 500, 400)
    right = record_from_weights(np.where((along > 0.2) & ~gap, w, 0), 500, 400)
    stars, rejected = centroids.extract([left, right], expected_smear_px=(dx, dy))
    assert len(stars) == 1 and rejected["fragment"] == 1
    mean_x = (left.sx + right.sx) / (left.s0 + right.s0)
    assert abs(mean_x - 500 - c) > 2.0                 # the light's mean is off
    assert (stars[0].x, stars[0].y) == pytest.approx((500 + c, 400 + c), abs=0.3)


def _groups_by_every_pair(stars, smear, across_px):
    """The groups :func:`centroids.join_fragments` forms, by testing every pair (its rule)."""
    groups = [{i} for i in range(len(stars))]
    for i, a in enumerate(stars):
        dx, dy = smear(a.x, a.y)
        length = math.hypot(dx, dy)
        ux, uy = dx / length, dy / length
        for j in range(i + 1, len(stars)):
            b = stars[j]
            ex, ey = b.x - a.x, b.y - a.y
            if abs(ex * ux + ey * uy) <= length + 1.0 and \
                    abs(ex * uy - ey * ux) <= across_px + a.sigma_minor + b.sigma_minor:
                gi = next(g for g in groups if i in g)
                gj = next(g for g in groups if j in g)
                if gi is not gj:
                    gi |= gj
                    groups.remove(gj)
    return sorted(sorted(g) for g in groups)


def test_joining_tests_the_pairs_every_pair_test_would():
    """The x-sorted window finds exactly the groups of the every-pair rule, in the order of
    their first pieces: random crowded fields, short and long smears, and a pair further
    apart in x than the track is long (joined across it)."""
    rng = np.random.default_rng(5)
    fields = [([(10.0, 10.0, 3.0), (14.9, 5.1, 3.0)], 1.0, 1.0)]
    for _ in range(150):
        n = int(rng.integers(1, 31))
        scale = 30.0 if rng.random() < 0.5 else 2.0
        fields.append(([(float(x), float(y), float(sm)) for x, y, sm in
                        zip(rng.uniform(0, 80, n), rng.uniform(0, 80, n),
                            rng.uniform(0.1, 4.0, n))],
                       float(rng.uniform(-scale, scale)), float(rng.uniform(-scale, scale))))
    for points, dx, dy in fields:
        if math.hypot(dx, dy) < 0.5:
            dx = 1.0

        def smear(x, y, dx=dx, dy=dy):
            return dx * (1.0 + x / 1000.0), dy

        stars = [centroids.Star(x, y, 100 + i, 2.0, sm, 1.5, 0.0, 9, 0, 50, i)
                 for i, (x, y, sm) in enumerate(points)]
        central = [(1.0, 1.0, 0.0)] * len(stars)
        out = centroids.join_fragments(stars, central, smear, centroids.DEFAULT_JOIN_ACROSS_PX)
        got = sorted(sorted(s.parts) if s.parts else [s.index] for s in out)
        assert got == _groups_by_every_pair(stars, smear, centroids.DEFAULT_JOIN_ACROSS_PX)
        firsts = [min(s.parts) if s.parts else s.index for s in out]
        assert firsts == sorted(firsts)
    assert len(centroids.join_fragments(*[[centroids.Star(x, y, 100, 2.0, sm, 1.5, 0.0, 9, 0, 50, i)
                                    for i, (x, y, sm) in enumerate(fields[0][0])]],
                                 [(1.0, 1.0, 0.0)] * 2, lambda x, y: (1.0, 1.0))) == 1


def test_unseen_track_of_a_piece():
    # the whole track: nothing unseen; 60 % of it: a fifth of the track each way
    dx, dy = 24.0, -10.0
    length = math.hypot(dx, dy)
    w = smeared_star_weights(1.2, dx, dy)
    c = (w.shape[0] - 1) / 2
    y, x = np.mgrid[0:w.shape[0], 0:w.shape[1]]
    along = ((x - c) * dx + (y - c) * dy) / length
    whole = record_from_weights(w, 500, 400)
    half = record_from_weights(np.where(along > -0.1 * length, w, 0), 700, 600)
    dot = record_from_weights(gaussian_weights(1.2, 1.2, 0.0, size=11), 800, 100)
    stars, _ = centroids.extract([whole, half, dot], expected_smear_px=(dx, dy))
    by_index = {s.index: s for s in stars}
    assert by_index[0].unseen == pytest.approx(0.0, abs=0.3)
    assert by_index[1].unseen == pytest.approx(length / 5, abs=0.6)
    assert by_index[2].unseen == pytest.approx(length / 2, abs=0.3)     # a round piece
    # the piece's centroid sits within its unseen track of the star's position
    assert abs((by_index[1].x - 700 - c) * dx + (by_index[1].y - 600 - c) * dy) / length \
        <= by_index[1].unseen + 0.5
    # without a smear nothing is unseen
    assert all(s.unseen == 0.0 for s in centroids.extract([half, dot])[0])


def test_unseen_px_formula():
    # a line of length l on an isotropic PSF: sigma_major^2 - sigma_minor^2 = l^2 / 12
    smaj = math.sqrt(1 + 16 / 12)                        # l = 4 px on a 1 px PSF
    assert centroids.unseen_px(smaj, 1.0, 0.0, (10.0, 0.0)) == pytest.approx(3.0)
    assert centroids.unseen_px(smaj, 1.0, math.pi, (-10.0, 0.0)) == pytest.approx(3.0)
    # measured along the smear only: a piece across it shows none of the track
    assert centroids.unseen_px(smaj, 1.0, math.pi / 2, (10.0, 0.0)) == pytest.approx(5.0)
    assert centroids.unseen_px(smaj, 1.0, 0.0, (3.0, 0.0)) == 0.0           # longer than the smear
    assert centroids.unseen_px(smaj, 1.0, 0.0, None) == 0.0
    assert centroids.unseen_px(smaj, 1.0, 0.0, (float("nan"), 0.0)) == 0.0


def test_smear_consistent_tolerances():
    smaj, smin = math.sqrt(1 + 100 / 12), 1.0        # a 10 px smear on a 1 px PSF
    assert centroids.smear_consistent(smaj, smin, 0.0, (10.0, 0.0))
    assert centroids.smear_consistent(smaj, smin, 0.3, (10.0, 0.0))
    assert not centroids.smear_consistent(smaj, smin, 0.4, (10.0, 0.0))
    assert centroids.smear_consistent(smaj, smin, 0.4, (10.0, 0.0), angle_tol=0.45)
    assert centroids.smear_consistent(smaj, smin, math.pi / 2 - 0.1, (0.0, -10.0))
    assert centroids.smear_consistent(smaj, smin, -math.pi / 2 + 0.1, (0.0, 10.0))
    assert centroids.smear_consistent(smaj, smin, 0.0, (19.0, 0.0))
    assert not centroids.smear_consistent(smaj, smin, 0.0, (21.0, 0.0))
    assert centroids.smear_consistent(smaj, smin, 0.0, (5.1, 0.0))
    assert not centroids.smear_consistent(smaj, smin, 0.0, (4.9, 0.0))
    assert not centroids.smear_consistent(smaj, smin, 0.0, None)
    # a part of a longer track: any shorter length, the same direction and upper bound
    assert not centroids.smear_consistent(smaj, smin, 0.0, (60.0, 0.0))
    assert centroids.smear_consistent(smaj, smin, 0.0, (60.0, 0.0), partial=True)
    assert not centroids.smear_consistent(smaj, smin, 0.4, (60.0, 0.0), partial=True)
    assert not centroids.smear_consistent(smaj, smin, 0.0, (4.9, 0.0), partial=True)


def test_brightest_kept_in_order():
    records = star_records(4)
    stars, rejected = centroids.extract(records, max_stars=None)
    assert len(stars) > 10
    fluxes = [s.flux for s in stars]
    assert fluxes == sorted(fluxes, reverse=True)
    top, rejected_top = centroids.extract(records, max_stars=5)
    assert [s.as_tuple() for s in top] == [s.as_tuple() for s in stars[:5]]
    assert rejected_top["excess"] == len(stars) - 5
    assert len(top) + total(rejected_top) == len(records)
    assert centroids.extract(records, max_stars=0)[0] == []
    # ties keep record order
    twins = [STAR, _with(STAR, xmin=0, xmax=999, sx=STAR.sx + 7 * STAR.s0,
                         sxx=STAR.sxx + 14 * STAR.sx + 49 * STAR.s0,
                         sxy=STAR.sxy + 7 * STAR.sy), STAR]
    stars, _ = centroids.extract(twins)
    assert [s.index for s in stars] == [0, 1, 2]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.fixed_dictionaries({
    name: st.one_of(st.integers(-5, 1 << 60), st.floats(allow_nan=True, allow_infinity=True))
    for name in C.RECORD_NAMES}), max_size=6), st.integers(0, 8))
def test_never_raises_and_counts_add_up(fields, max_stars):
    records = [C.BlobRecord(**f) for f in fields]
    stars, rejected = centroids.extract(records, max_stars=max_stars,
                                 expected_smear_px=(3.0, 4.0))
    assert len(stars) + total(rejected) == len(records)
    assert len(stars) <= max_stars
    for s in stars:
        assert all(math.isfinite(v) for v in s.as_tuple() if v != s.elongation)


def test_overflowing_float_moments_are_inconsistent():
    huge = _with(STAR, s0=1e-300, sx=1e-298, sy=5e-299, sxx=1e308, syy=1e308, sxy=0.0,
                 xmin=0, xmax=1000, ymin=0, ymax=1000)
    assert centroids.moments(huge) is None
    assert centroids.extract([huge])[1]["inconsistent"] == 1


# --------------------------------------------------------------------------------------
# Whole chain on simulated frames: stars kept, cosmic rays and hot pixels rejected
# --------------------------------------------------------------------------------------

def _segment_distance(start, end, p):
    """Distance from point ``p`` to each segment ``start[i] -> end[i]`` (arrays (N, 2))."""
    d = end - start
    length2 = np.maximum(np.sum(d * d, axis=1), 1e-12)
    t = np.clip(np.sum((p - start) * d, axis=1) / length2, 0.0, 1.0)
    return np.hypot(*(start + t[:, None] * d - p).T)


def simulate(sigma, velocity, exposure=0.1, seed=0, n_rays=6, n_hot=12, width=320,
             height=240):
    """A frame of well-separated stars moving at ``velocity`` px/s (track centred on the
    truth centroid at mid-exposure), cosmic rays and saturated hot pixels placed clear of the
    star tracks; returns ``(records, star_centroids, ray_midpoints, hot_pixels)``."""
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.linspace(40, width - 40, 5), np.linspace(40, height - 40, 4))
    xy = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-5, 5, (gx.size, 2))
    electrons = np.exp(rng.uniform(np.log(2e4), np.log(8e4), len(xy)))
    v = np.asarray(velocity, dtype=float)
    starts, ends = xy - v * exposure / 2, xy + v * exposure / 2

    def positions(t):
        return xy[:, None, :] + v[None, None, :] * (t[None, :, None] - exposure / 2)

    image, truth = render.render_stars(height, width, positions, electrons, sigma, exposure)
    clear = 6 * sigma + 4
    rays = []
    while len(rays) < n_rays:
        scratch = np.zeros_like(image)
        ray = render.add_cosmic_rays(scratch, rng, 1, length_px=(6.0, 15.0),
                                     electrons=(3000.0, 8000.0))[0]
        ends_ok = [np.min(_segment_distance(starts, ends, np.array(p))) > clear
                   for p in (ray.start, ray.end)]
        mid = (np.array(ray.start) + np.array(ray.end)) / 2
        if all(ends_ok) and np.min(_segment_distance(starts, ends, mid)) > clear:
            image += scratch
            rays.append(mid)
    hot = []
    while len(hot) < n_hot:
        p = rng.integers(0, (width, height))
        if np.min(_segment_distance(starts, ends, p)) > clear:
            image[p[1], p[0]] += 1e5                # saturates: a hot pixel
            hot.append(p)
    frame = sensor.expose(image, rng, exposure, 5.0, 20.0, 3.0, 1.0, 100.0, 12)
    cfg = DetectorConfig(width=width, height=height, pixel_bits=12, threshold=125,
                         background=100, min_pixels=1)
    return detect_frame(frame, cfg).blobs, truth.centroid, np.array(rays), np.array(hot)


def _nearest(points, x, y):
    return float(np.min(np.hypot(points[:, 0] - x, points[:, 1] - y)))


@pytest.mark.parametrize("sigma, velocity", [
    (2.0, (0.0, 0.0)), (0.6, (0.0, 0.0)), (2.0, (250.0, 0.0)), (2.0, (-300.0, 200.0)),
    (0.8, (0.0, 150.0)), (1.2, (180.0, 180.0)),
])
def test_simulated_frame(sigma, velocity):
    records, stars_true, rays, hot = simulate(sigma, velocity, seed=int(sigma * 10))
    smear = (velocity[0] * 0.1, velocity[1] * 0.1)
    stars, rejected = centroids.extract(records, max_stars=None, expected_smear_px=smear)
    assert len(stars) + total(rejected) == len(records)
    # every kept blob is a star, measured to a fraction of a pixel (noise decides where a
    # long faint track crosses the threshold) ...
    tolerance = 0.25 + 0.01 * math.hypot(*smear)
    for s in stars:
        assert _nearest(stars_true, s.x, s.y) < tolerance, s
    # ... and every star is found
    assert len(stars) == len(stars_true)
    # the cosmic rays and hot pixels are rejected
    assert rejected["cosmic_ray"] >= len(rays) - 1
    assert rejected["hot_pixel"] >= len(hot)
    # without the rate, long smears read as cosmic rays
    if math.hypot(*smear) > 20:
        blind, rejected_blind = centroids.extract(records, max_stars=None)
        assert len(blind) < len(stars) and rejected_blind["cosmic_ray"] > rejected["cosmic_ray"]


def _golden_case(name):
    doc = json.loads((GOLDEN_SMALL / (name + ".json")).read_text())
    truth = doc["truth"]
    cam = window_camera(presets.load_preset(truth["spec"]["preset"]),
                        tuple(truth["spec"]["window"]))
    fw_cam = Camera.from_dict(dict(width=cam.width, height=cam.height, fx=cam.fx_px,
                                   fy=cam.fy_px, cx=cam.cx, cy=cam.cy, k1=cam.k1, k2=cam.k2,
                                   k3=cam.k3, p1=cam.p1, p2=cam.p2))
    records = [C.BlobRecord(**r) for r in doc["expected"]["records"]]
    return truth, fw_cam, records


@pytest.mark.parametrize("name", ["estcube2_hot_cosmic", "lohmann_dense_1dps",
                                  "estcube2_orion_saturated", "estcube2_dense_rest"])
def test_golden_small_frames(name):
    """The committed golden frames: kept blobs are sources (stars or false stars), blobs on
    the cosmic rays are rejected; the expected smear comes from the truth's body rate."""
    truth, cam, records = _golden_case(name)
    omega = [math.radians(w) for w in truth["omega_deg_s"]]

    def smear(x, y):
        return cam.smear_px(x, y, omega, truth["exposure_s"])
    stars, rejected = centroids.extract(records, max_stars=None, expected_smear_px=smear)
    sources = np.array([[s["x"], s["y"]] for s in truth["sources"]])
    rays = np.array([[(r["start"][0] + r["end"][0]) / 2, (r["start"][1] + r["end"][1]) / 2]
                     for r in truth["cosmic_rays"]]).reshape(-1, 2)
    kept = {s.index for s in stars}
    for s in stars:
        assert _nearest(sources, s.x, s.y) < 3.0
    n_ray_blobs = 0
    for index, rec in enumerate(records):
        x, y = centroids.moments(rec)[:2]
        if len(rays) and _nearest(rays, x, y) < 3.0 and _nearest(sources, x, y) > 3.0:
            n_ray_blobs += 1
            assert index not in kept
    assert n_ray_blobs >= len(rays) - 1
    assert len(stars) >= 0.45 * len(records) and len(stars) >= 2
