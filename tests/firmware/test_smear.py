"""Tests of ``lodestar.firmware.smear``: the attitude at an instant and the body rate fitted
together to matched stars seen by a rolling shutter, the chi-square of a rate difference and
the streaks' smear bound and whether they side with a given rate or the frame's."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.firmware import smear
from lodestar.firmware.tracking import propagate

ROW_TIME_S = 43.9e-6
EXPOSURE_S = 0.1
FOCAL_PX = 7300.0


def scene(rate_rad_s, n=20, noise_px=0.2, seed=1, ref=0.09):
    """``n`` stars within 10 deg of the boresight seen by a rolling shutter while turning at
    ``rate_rad_s``: ``(b, r, dts, q_ref)`` with ``q_ref`` the truth at ``ref`` s."""
    rng = np.random.default_rng(seed)
    q0 = Rotation.random(random_state=seed).as_quat()
    b, r, dts = [], [], []
    for _ in range(n):
        x, y = rng.uniform(-0.17, 0.17, 2)
        v_cam0 = np.array([x, y, 1.0]) / math.sqrt(1 + x * x + y * y)
        t = EXPOSURE_S / 2 + (y + 0.17) / 0.34 * 1944 * ROW_TIME_S
        r.append(tuple(Rotation.from_quat(q0).inv().apply(v_cam0)))
        qt = propagate(list(q0), rate_rad_s, t)
        v = Rotation.from_quat(qt).apply(r[-1]) + rng.normal(0, noise_px / FOCAL_PX, 3)
        b.append(tuple(v / np.linalg.norm(v)))
        dts.append(t - ref)
    return b, r, dts, propagate(list(q0), rate_rad_s, ref)


def error_rad(q, q_true):
    return (Rotation.from_quat(q) * Rotation.from_quat(q_true).inv()).as_rotvec()


@pytest.mark.parametrize("rate_deg_s", [(0.0, 0.0, 0.0), (1.0, -0.5, 0.0), (0.0, 0.0, 10.0)])
def test_rate_fit_recovers_attitude_and_rate_within_their_sigmas(rate_deg_s):
    rate = [math.radians(w) for w in rate_deg_s]
    b, r, dts, q_true = scene(rate)
    q_start = propagate(q_true, [0.0, 0.0, 1e-3], 1.0)        # 1 mrad off in roll
    q, omega, p, p_omega, s = smear.rate_fit(b, r, dts, [1.0] * len(b), q_start)
    err = error_rad(q, q_true)
    assert np.all(np.abs(err) < 5 * np.sqrt(np.diag(p)))
    assert np.all(np.abs(np.asarray(omega) - rate) < 5 * np.sqrt(np.diag(p_omega)))
    assert s * FOCAL_PX == pytest.approx(0.2, rel=0.5)
    assert smear.chi2_rate([w - x for w, x in zip(omega, rate)], p_omega) < \
        smear.rate_chi2_limit(len(b))


def test_rate_fit_sigma_covers_the_error_over_many_scenes():
    z = []
    for seed in range(20):
        rate = [math.radians(w) for w in (0.5, 0.3, 5.0)]
        b, r, dts, q_true = scene(rate, n=8, seed=seed)
        q, _omega, p, _p_omega, _s = smear.rate_fit(b, r, dts, [1.0] * 8, q_true)
        z.extend(error_rad(q, q_true) / np.sqrt(np.diag(p)))
    assert 0.6 < np.sqrt(np.mean(np.square(z))) < 1.6


def test_a_wrong_given_rate_shows_as_a_large_chi2():
    rate = [0.0, 0.0, math.radians(10.0)]
    b, r, dts, q_true = scene(rate, ref=0.0)
    # the stars turned to the reference by the opposite rate, as a wrong-sign gyro does
    turned = [tuple(Rotation.from_rotvec(-np.asarray(rate) * t).apply(v)) for v, t in
              zip(b, dts)]
    _q, rest, _p, p_omega, _s = smear.rate_fit(turned, r, dts, [1.0] * len(b), q_true)
    assert rest[2] == pytest.approx(2 * rate[2], rel=0.05)
    assert smear.chi2_rate(rest, p_omega) > smear.rate_chi2_limit(len(b))


def test_the_contradiction_limit_grows_as_the_stars_get_fewer():
    """``3 F(3, 2n - 8)`` at 1e-3: none below MIN_CHECK_STARS, 71 for 7 stars, the lower
    tabled row between rows, 17.3 from 64 stars on."""
    assert smear.rate_chi2_limit(smear.MIN_CHECK_STARS - 1) is None
    assert smear.rate_chi2_limit(7) == 71.1 and smear.rate_chi2_limit(8) == 47.5
    assert smear.rate_chi2_limit(11) == smear.rate_chi2_limit(10) == 32.4
    assert smear.rate_chi2_limit(200) == 17.3
    limits = [smear.rate_chi2_limit(n) for n in range(7, 80)]
    assert limits == sorted(limits, reverse=True)


def test_rate_fit_needs_stars_and_a_spread_of_instants():
    b, r, dts, q = scene([0.0, 0.0, 0.0])
    assert smear.rate_fit(b[:5], r[:5], dts[:5], [1.0] * 5, q) is None
    assert smear.rate_fit(b, r, [0.0] * len(b), [1.0] * len(b), q) is None
    fixed = smear.rate_fit(b, r, dts, [1.0] * len(b), q, sigma_rad=1e-4)
    assert fixed[4] == 1e-4
    floor = smear.rate_fit(b, r, dts, [1.0] * len(b), q, min_sigma_rad=1e-3)
    assert floor[4] == pytest.approx(1e-3)
    assert smear.chi2_rate([1.0, 0.0, 0.0], [[0.0] * 3] * 3) is None


def test_smear_bound_from_the_streaks_second_moments():
    assert smear.smear_bound_px([]) is None
    # the median excess (negative ones count as 0) plus the still frame's
    still = smear.smear_bound_px([(2.0, 2.0, 0.0), (2.1, 1.9, 0.0), (1.9, 2.0, 0.0)])
    assert still == pytest.approx(math.sqrt(12 * smear.STILL_ELONGATION_PX2))
    some = smear.smear_bound_px([(2.0, 2.0, 0.0), (2.1, 1.9, 0.0), (2.2, 1.9, 0.0)])
    assert some == pytest.approx(math.sqrt(12 * (2.1 ** 2 - 1.9 ** 2 + 1.0)))
    # a 20 px streak over a 2 px PSF: sigma_major^2 = 4 + 400 / 12
    streak = smear.smear_bound_px([(math.sqrt(4 + 400 / 12), 2.0, 0.0)] * 3)
    assert 20.0 < streak < 21.0


def test_smear_vector_is_the_pixel_motion_over_the_exposure():
    """A roll moves a star at radius r by r omega T tangentially; a rate about x moves the
    boresight along +y by f omega T (``dv/dt = -omega x v``)."""
    scale = FOCAL_PX * EXPOSURE_S
    v = (0.1, 0.0, 1.0)
    v = tuple(np.asarray(v) / np.linalg.norm(v))
    dx, dy = smear.smear_vector(v, (0.0, 0.0, 0.01), scale)
    assert abs(dx) < 1e-9 and dy == pytest.approx(-0.1 * FOCAL_PX * 0.01 * EXPOSURE_S)
    dx, dy = smear.smear_vector((0.0, 0.0, 1.0), (0.01, 0.0, 0.0), scale)
    assert abs(dx) < 1e-9 and dy == pytest.approx(FOCAL_PX * 0.01 * EXPOSURE_S)


def streak(u, psf=1.5):
    """The second moments ``(sigma_major, sigma_minor, orientation)`` of a star of PSF sigma
    ``psf`` smeared along ``u`` (px)."""
    length2 = u[0] * u[0] + u[1] * u[1]
    return math.sqrt(psf * psf + length2 / 12), psf, math.atan2(u[1], u[0])


def test_streaks_side_with_the_rate_that_explains_them():
    """Streaks 10 px long along x: a rate that makes them wins over a gyro that says the
    camera is still, and the reverse for round stars; a sign error ties, and a rate
    difference that moves the stars by less than their width is not visible."""
    scale = FOCAL_PX * EXPOSURE_S
    vs = [tuple(np.asarray(v) / np.linalg.norm(v)) for v in
          ([0.0, 0.0, 1.0], [0.05, 0.02, 1.0], [-0.04, 0.06, 1.0], [0.03, -0.05, 1.0])]
    rate = (0.0, -10.0 / scale, 0.0)            # 10 px along +x at the boresight
    still = (0.0, 0.0, 0.0)
    streaks = [(v, streak(smear.smear_vector(v, rate, scale))) for v in vs]
    round_ = [(v, streak((0.0, 0.0))) for v in vs]
    assert smear.streak_votes(streaks, still, rate, scale) == len(vs)
    assert smear.streak_votes(round_, still, rate, scale) == -len(vs)
    assert smear.streak_votes(streaks, (0.0, 10.0 / scale, 0.0), rate, scale) == 0
    assert smear.visible(round_, rate, scale)
    assert not smear.visible(round_, (0.0, -1.0 / scale, 0.0), scale)
    # a faint streak measured at 70 % of its length still counts for its rate
    short = [(v, streak((7.0, 0.0))) for v in vs]
    assert smear.explains(short[0][1], (10.0, 0.0)) and \
        not smear.explains(short[0][1], (0.0, 0.0))


def distorted(scene_out, k1):
    """The stars of a :func:`scene` displaced radially as a lens of ``k1`` (on the tangent
    plane, ``p (1 + k1 |p|^2)``) the model lacks."""
    b, r, dts, q = scene_out
    out = []
    for v in b:
        x, y = v[0] / v[2], v[1] / v[2]
        f = 1 + k1 * (x * x + y * y)
        u = np.array([x * f, y * f, 1.0])
        out.append(tuple(u / np.linalg.norm(u)))
    return out, r, dts, q


def test_radial_fit_finds_an_unmodelled_distortion_and_covers_the_truth():
    b, r, dts, q_true = distorted(scene([0.0, 0.0, 0.0], n=25, seed=3), -0.3)
    q, omega, p, _po, s, c, p_c = smear.radial_fit(b, r, dts, [1.0] * len(b), q_true, False)
    assert omega is None and smear.chi2_rate(c, p_c) > smear.RADIAL_CHI2
    assert np.all(np.abs(error_rad(q, q_true)) < 5 * np.sqrt(np.diag(p)))
    assert s * FOCAL_PX < 0.4
    # without a distortion the coefficients are noise
    b, r, dts, q_true = scene([0.0, 0.0, math.radians(2.0)], n=25, seed=3)
    q, omega, p, _po, _s, c, p_c = smear.radial_fit(b, r, dts, [1.0] * len(b), q_true, True)
    assert smear.chi2_rate(c, p_c) < smear.RADIAL_CHI2 and omega is not None
    assert smear.radial_fit(b[:7], r[:7], dts[:7], [1.0] * 7, q_true, False) is None


def test_the_checks_verdict_is_the_one_linear_solves():
    """``check``: the normal equations of the rate check from their structure equal the
    general ones at a zero rate, and the verdict from the Cholesky factor alone (the last
    unknowns and their chi-square) equals the one linear solve's (``rounds`` 0) with its
    covariance, for the rate and for the radial coefficients, to rounding."""
    b, r, dts, q = scene([0.0, 0.01, 0.0], n=12, seed=3)
    w = [0.5 + 0.1 * i for i in range(len(b))]
    tau = math.sqrt(sum(wi * t * t for wi, t in zip(w, dts)) / sum(w))
    fast = smear._normal_rate(b, r, dts, w, q, tau)
    general = smear._normal(b, r, dts, w, q, (0.0, 0.0, 0.0), tau, True, False, 1.0)
    for got, want in zip(fast, general):
        assert np.allclose(got, want, rtol=1e-12, atol=1e-15)
    x, chi2 = smear.check(b, r, dts, w, q, True, False)
    _q, omega, _p, p_omega, _s = smear.rate_fit(b, r, dts, w, q, rounds=0)
    assert np.allclose(x, omega, rtol=1e-9) and chi2 > 1.0
    assert chi2 == pytest.approx(smear.chi2_rate(omega, p_omega), rel=1e-9)
    for rate in (True, False):
        x, chi2 = smear.check(b, r, dts if rate else [0.0] * len(b), w, q, rate, True)
        fit = smear.radial_fit(b, r, dts if rate else [0.0] * len(b), w, q, rate, rounds=0)
        assert np.allclose(x, fit[5], rtol=1e-9)
        assert chi2 == pytest.approx(smear.chi2_rate(fit[5], fit[6]), rel=1e-9)
    assert smear.check(b[:5], r[:5], dts[:5], w[:5], q, True, False) is None
    assert smear.check(b, r, dts, w, q, True, False, sigma_rad=0.0)[1] is None
