"""Noise-free rendering: flux, exact centroid truth, smear, rolling shutter, Dzamba's closed
form, frame edges and cosmic rays."""

import math

import numpy as np
import pytest
from scipy.special import ndtr

from lodestar.sim.render import (
    CosmicRay,
    _streak_pixels,
    add_cosmic_rays,
    dzamba_smeared_psf,
    render_stars,
)

T_E = 0.1


def linear(starts, velocities):
    """``positions(t)`` for straight constant-velocity tracks: (N, 2) px and px/s."""
    starts = np.asarray(starts, dtype=float)
    velocities = np.asarray(velocities, dtype=float)
    return lambda t: starts[:, None, :] + velocities[:, None, :] * np.asarray(t)[None, :, None]


def circular(centre, radius, phase, rate):
    """One source on a circle (px) at ``rate`` rad/s: a curved track (boresight roll)."""
    def positions(t):
        angle = phase + rate * np.asarray(t)
        return np.stack([centre[0] + radius * np.cos(angle),
                         centre[1] + radius * np.sin(angle)], axis=-1)[None]
    return positions


def pixel_centroid(image):
    """Discrete first moment ``(x, y)`` of an image (pixel centres at integer indices)."""
    ys, xs = np.indices(image.shape)
    return np.array([(image * xs).sum(), (image * ys).sum()]) / image.sum()


def pixel_masses(centre, sigma, size):
    """Mass of a unit 1-D Gaussian in each of pixels ``0 .. size - 1``."""
    return np.diff(ndtr((np.arange(size + 1) - 0.5 - centre) / sigma))


# --------------------------------------------------------------------------------------
# Static stars
# --------------------------------------------------------------------------------------


def test_static_star_is_the_exact_pixel_integrated_gaussian():
    """One sample in time: the image is exactly E * outer(P_y, P_x)."""
    image, truth = render_stars(40, 50, linear([[21.3, 17.8]], [[0, 0]]), [2500.0], 1.4, T_E)
    expected = 2500.0 * np.outer(pixel_masses(17.8, 1.4, 40), pixel_masses(21.3, 1.4, 50))
    assert np.allclose(image, expected, rtol=0, atol=1e-12)
    assert image.sum() == pytest.approx(2500.0, rel=1e-12)
    assert truth.centroid[0] == pytest.approx([21.3, 17.8], abs=1e-12)
    assert truth.in_frame_fraction[0] == pytest.approx(1.0, abs=1e-12)
    assert truth.electrons_in_frame[0] == pytest.approx(2500.0, rel=1e-12)


@pytest.mark.parametrize("sigma", [1.0, 1.7, 3.0])
@pytest.mark.parametrize("phase", [0.0, 0.13, 0.5, 0.77])
def test_static_pixel_centroid_matches_truth(sigma, phase):
    """A well-sampled (sigma >= 1) static star's discrete centroid is within 1e-3 px."""
    position = [30.0 + phase, 25.0 - 0.6 * phase]
    image, truth = render_stars(60, 64, linear([position], [[0, 0]]), [1e4], sigma, T_E)
    assert truth.centroid[0] == pytest.approx(position, abs=1e-12)
    assert np.abs(pixel_centroid(image) - position).max() < 1e-3


def test_undersampled_pixel_centroid_is_biased():
    """The 1e-3 px check above can fail: at sigma = 0.3 pixel phase biases the centroid."""
    image, truth = render_stars(20, 20, linear([[10.25, 10.0]], [[0, 0]]), [1e4], 0.3, T_E)
    assert truth.centroid[0, 0] == pytest.approx(10.25, abs=1e-12)
    assert abs(pixel_centroid(image)[0] - 10.25) > 0.01


def test_sources_add_linearly():
    starts, velocities = [[12.2, 14.6], [30.1, 20.4]], [[80.0, -20.0], [0.0, 0.0]]
    both, truth = render_stars(40, 48, linear(starts, velocities), [700.0, 300.0], 1.2, T_E)
    for i, e in enumerate((700.0, 300.0)):
        positions = linear(starts[i:i + 1], velocities[i:i + 1])
        one, alone = render_stars(40, 48, positions, [e], 1.2, T_E)
        assert truth.centroid[i] == pytest.approx(alone.centroid[0], abs=1e-6)
        both = both - one
    assert np.abs(both).max() < 1e-6 * 700.0


# --------------------------------------------------------------------------------------
# Moving stars, global shutter
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("velocity", [[300.0, 0.0], [0.0, -250.0], [400.0, 330.0], [-633.0, 40.0]])
def test_smeared_flux_is_conserved_and_truth_is_track_midpoint(velocity):
    start = np.array([70.3, 66.9])
    image, truth = render_stars(140, 150, linear([start], [velocity]), [5000.0], 1.3, T_E)
    assert image.min() >= 0.0
    assert image.sum() == pytest.approx(5000.0, rel=1e-9)
    assert truth.electrons_in_frame[0] == pytest.approx(5000.0, rel=1e-9)
    midpoint = start + 0.5 * T_E * np.array(velocity)
    assert truth.centroid[0] == pytest.approx(midpoint, abs=1e-9)
    assert np.abs(pixel_centroid(image) - midpoint).max() < 1e-3


@pytest.mark.parametrize("row_time", [0.0, 2e-4])
@pytest.mark.parametrize("track", ["line", "arc"])
@pytest.mark.parametrize("sigma", [0.5, 1.2, 2.5])
def test_quadrature_converges_against_tenfold_finer_reference(row_time, track, sigma):
    """Default step (0.1 min(sigma, 1) px of motion) vs 10x finer: < 2e-4 of the peak pixel,
    < 1e-4 px in centroid, and the error falls like step**2."""
    positions = (linear([[20.3, 30.7]], [[250.0, 130.0]]) if track == "line"
                 else circular((48.0, 45.0), 25.0, 0.3, 3.0))
    step = 0.1 * min(sigma, 1.0)
    default, truth = render_stars(96, 96, positions, [1.0], sigma, T_E, row_time)
    finer, _ = render_stars(96, 96, positions, [1.0], sigma, T_E, row_time, max_step_px=step / 3)
    reference, exact = render_stars(96, 96, positions, [1.0], sigma, T_E, row_time,
                                    max_step_px=step / 10)
    error = np.abs(default - reference).max() / reference.max()
    assert error < 2e-4
    assert np.abs(finer - reference).max() / reference.max() < error / 5
    assert np.abs(truth.centroid - exact.centroid).max() < 1e-4
    assert default.sum() == pytest.approx(reference.sum(), rel=1e-6)


def test_static_frame_uses_one_time_sample():
    calls = []

    def positions(t):
        calls.append(len(t))
        return np.broadcast_to([[[5.0, 6.0]]], (1, len(t), 2))

    render_stars(16, 16, positions, [1.0], 1.0, T_E, 1e-3)
    assert calls == [17]                        # the probe only; the render uses t = 0


def test_refines_until_steps_are_small():
    calls = []
    inner = linear([[10.0, 10.0]], [[500.0, 0.0]])    # 50 px in 0.1 s

    def positions(t):
        calls.append(len(t))
        return inner(t)

    render_stars(32, 80, positions, [1.0], 2.0, T_E, max_step_px=0.1)
    assert calls[-1] - 1 >= 500 and calls[-1] - 1 <= 1.2 * 500


# --------------------------------------------------------------------------------------
# Rolling shutter
# --------------------------------------------------------------------------------------


def test_rolling_shutter_shift_along_rows():
    """Motion along x only: row r sees the star during [r t_row, r t_row + t_e], so its mean
    x is x0 + v_x (r t_row + t_e / 2).  Weighting rows by the (time-independent) row masses,
    whose mean row is y0, the centroid is x0 + v_x (t_e / 2 + t_row y0): shifted from the
    global-shutter midpoint by exactly v_x * t_row * y0, with y unchanged."""
    x0, y0, vx, row_time = 30.4, 52.35, 630.0, 43.9e-6
    positions = linear([[x0, y0]], [[vx, 0.0]])
    rolling, truth = render_stars(100, 120, positions, [1e4], 1.5, T_E, row_time)
    _, global_truth = render_stars(100, 120, positions, [1e4], 1.5, T_E)
    shift = truth.centroid[0] - global_truth.centroid[0]
    assert shift[0] == pytest.approx(vx * row_time * y0, abs=1e-8)
    assert shift[1] == pytest.approx(0.0, abs=1e-9)
    assert rolling.sum() == pytest.approx(1e4, rel=1e-9)
    assert np.abs(pixel_centroid(rolling) - truth.centroid[0]).max() < 1e-3


@pytest.mark.parametrize("vy", [400.0, -400.0])
def test_rolling_shutter_along_columns_stretches_exposure(vy):
    """Motion along y: the star at y(t) = y0 + v_y t is in row y(t) while that row exposes,
    i.e. while y(t) t_row <= t <= y(t) t_row + t_e, so t (1 - v_y t_row) runs over
    [y0 t_row, y0 t_row + t_e]: it is exposed for t_e / (1 - v_y t_row) around the mean time
    (y0 t_row + t_e / 2) / (1 - v_y t_row), and its centroid is y0 + v_y times that."""
    x0, y0, row_time = 40.2, 60.6, 1e-4
    _, truth = render_stars(128, 96, linear([[x0, y0]], [[0.0, vy]]), [1.0], 1.3, T_E, row_time)
    k = vy * row_time
    mean_time = (y0 * row_time + T_E / 2) / (1 - k)
    assert truth.electrons_in_frame[0] == pytest.approx(1 / (1 - k), rel=1e-6)
    assert truth.centroid[0] == pytest.approx([x0, y0 + vy * mean_time], abs=2e-6)


# --------------------------------------------------------------------------------------
# Frame edges
# --------------------------------------------------------------------------------------


def test_star_on_frame_edge_reports_half_and_truncated_mean():
    sigma = 1.6
    def render_at(x, y):
        return render_stars(30, 30, linear([[x, y]], [[0, 0]]), [800.0], sigma, T_E)

    edge, edge_truth = render_at(-0.5, 14.2)
    corner, corner_truth = render_at(29.5, -0.5)
    assert edge_truth.in_frame_fraction[0] == pytest.approx(0.5, abs=1e-12)
    assert corner_truth.in_frame_fraction[0] == pytest.approx(0.25, abs=1e-12)
    assert edge.sum() == pytest.approx(400.0, rel=1e-12)
    assert corner_truth.electrons_in_frame[0] == pytest.approx(200.0, rel=1e-12)
    half_normal_mean = sigma * math.sqrt(2 / math.pi)
    assert edge_truth.centroid[0] == pytest.approx([-0.5 + half_normal_mean, 14.2], abs=1e-9)
    assert corner_truth.centroid[0] == pytest.approx(
        [29.5 - half_normal_mean, -0.5 + half_normal_mean], abs=1e-9)


def test_partially_outside_moving_star_fraction():
    """A star sliding out through x = -1/2 at constant speed: the in-frame fraction is the
    time average of Phi((x(t) + 1/2) / sigma), integrated here independently.  The default
    step (0.1 px) leaves a quadrature error of ~5e-6; 0.01 px brings it to ~5e-8."""
    x0, vx, sigma = 2.0, -60.0, 1.2
    positions = linear([[x0, 10.0]], [[vx, 0.0]])
    t = np.linspace(0.0, T_E, 200001)
    expected = np.trapezoid(ndtr((x0 + vx * t + 0.5) / sigma), t) / T_E
    assert 0.2 < expected < 0.9
    for step, tolerance in ((None, 1e-5), (0.01, 1e-7)):
        image, truth = render_stars(20, 24, positions, [1.0], sigma, T_E, max_step_px=step)
        assert truth.in_frame_fraction[0] == pytest.approx(expected, abs=tolerance)
        assert image.sum() == pytest.approx(truth.electrons_in_frame[0], rel=1e-12)


def test_star_outside_frame_lands_nothing():
    image, truth = render_stars(20, 20, linear([[-40.0, 5.0], [10.0, 10.0]], [[0, 0], [0, 0]]),
                                [100.0, 100.0], 1.0, T_E)
    assert truth.in_frame_fraction[0] == 0.0 and truth.electrons_in_frame[0] == 0.0
    assert np.all(np.isnan(truth.centroid[0]))
    assert image.sum() == pytest.approx(100.0, rel=1e-12)


# --------------------------------------------------------------------------------------
# Dzamba's closed form (Eqs 4.11-4.18, corrected)
# --------------------------------------------------------------------------------------


def test_dzamba_closed_form_matches_point_sampled_renderer():
    start, smear, sigma = (14.3, 20.6), (31.0, 9.5), 1.4
    image, _ = render_stars(48, 64, linear([start], [np.divide(smear, T_E)]), [3000.0], sigma,
                            T_E, max_step_px=0.004, pixel_response="point")
    ys, xs = np.indices(image.shape)
    closed = dzamba_smeared_psf(xs, ys, *start, *smear, sigma, T_E, 3000.0)
    assert np.abs(image - closed).max() < 1e-6 * closed.max()


def test_dzamba_closed_form_integrated_over_pixels_matches_area_renderer():
    start, smear, sigma = (10.8, 22.1), (25.0, -14.0), 1.1
    image, _ = render_stars(40, 48, linear([start], [np.divide(smear, T_E)]), [3000.0], sigma,
                            T_E, max_step_px=0.004)
    nodes, weights = np.polynomial.legendre.leggauss(10)
    ys, xs = np.indices(image.shape)
    area = sum(wa * wb * dzamba_smeared_psf(xs + a / 2, ys + b / 2, *start, *smear, sigma,
                                            T_E, 3000.0)
               for a, wa in zip(nodes, weights) for b, wb in zip(nodes, weights)) / 4
    assert np.abs(image - area).max() < 1e-6 * area.max()


def test_dzamba_normalisation_and_static_limit():
    sigma, electrons = 1.5, 1000.0
    ys, xs = np.mgrid[-60:61, -60:61].astype(float)
    smeared = dzamba_smeared_psf(xs, ys, -10.0, 3.0, 20.0, -6.0, sigma, T_E, electrons)
    assert smeared.sum() == pytest.approx(electrons, rel=1e-9)       # divided by t_e
    static = dzamba_smeared_psf(xs, ys, 1.0, 2.0, 0.0, 0.0, sigma, T_E, electrons)
    r2 = (xs - 1) ** 2 + (ys - 2) ** 2
    gaussian = electrons / (2 * np.pi * sigma**2) * np.exp(-r2 / (2 * sigma**2))
    assert np.allclose(static, gaussian, rtol=1e-14, atol=0)
    for tiny in (1e-4, 1e-7):                      # both sides of the omega -> 0 switch
        nearly = dzamba_smeared_psf(xs, ys, 1.0, 2.0, tiny, tiny, sigma, T_E, electrons)
        assert np.abs(nearly - gaussian).max() < 1e-4 * gaussian.max()


# --------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name, kwargs", [
    ("sigma_px", {"sigma_px": 0.0}),
    ("exposure_s", {"exposure_s": -0.1}),
    ("exposure_s", {"exposure_s": 0.0}),
    ("row_time_s", {"row_time_s": -1e-5}),
    ("height", {"height": 0}),
    ("electrons", {"electrons": [-1.0]}),
    ("pixel_response", {"pixel_response": "bilinear"}),
    ("max_step_px", {"max_step_px": float("nan")}),
    ("positions", {"positions": lambda t: np.zeros((2, len(t), 2))}),
    ("positions", {"positions": lambda t: np.full((1, len(t), 2), np.nan)}),
])
def test_bad_inputs(name, kwargs):
    args = {"height": 10, "width": 10, "positions": linear([[5, 5]], [[0, 0]]),
            "electrons": [1.0], "sigma_px": 1.0, "exposure_s": 0.1, **kwargs}
    with pytest.raises(ValueError, match=name):
        render_stars(**args)


# --------------------------------------------------------------------------------------
# Cosmic rays
# --------------------------------------------------------------------------------------


def test_cosmic_rays_deposit_their_stated_electrons():
    image = np.zeros((60, 80))
    rays = add_cosmic_rays(image, np.random.default_rng(4), 25)
    assert len(rays) == 25 and all(isinstance(r, CosmicRay) for r in rays)
    assert image.sum() == pytest.approx(sum(r.electrons for r in rays), rel=1e-12)
    for ray in rays:
        start, end = np.array(ray.start), np.array(ray.end)
        assert 1.0 <= np.hypot(*(end - start)) <= 10.0
        assert 500.0 <= ray.electrons <= 5000.0
        for point in (start, end):
            assert -0.5 <= point[0] <= 79.5 and -0.5 <= point[1] <= 59.5


def test_cosmic_ray_is_sharp_and_shares_by_path_length():
    """One streak on its own: every lit pixel is crossed by the segment, and a horizontal
    streak along a pixel row splits its charge by the length inside each pixel."""
    image = np.zeros((30, 30))
    (ray,) = add_cosmic_rays(image, np.random.default_rng(9), 1)
    start, end = np.array(ray.start), np.array(ray.end)
    ys, xs = np.nonzero(image)
    s = np.linspace(0, 1, 20001)[:, None]
    crossed = {tuple(p) for p in np.floor(start + s * (end - start) + 0.5).astype(int)}
    assert {(x, y) for x, y in zip(xs, ys)} == crossed
    rows, cols, fractions = _streak_pixels(np.array([2.2, 5.0]), np.array([3.0, 0.0]))
    assert list(cols) == [2, 3, 4, 5] and set(rows) == {5}
    assert fractions == pytest.approx(np.array([0.3, 1.0, 1.0, 0.7]) / 3.0)


def test_cosmic_rays_are_deterministic_per_rng():
    a, b = np.zeros((40, 40)), np.zeros((40, 40))
    add_cosmic_rays(a, np.random.default_rng(1), 5)
    add_cosmic_rays(b, np.random.default_rng(1), 5)
    assert np.array_equal(a, b)
    with pytest.raises(ValueError, match="count"):
        add_cosmic_rays(a, np.random.default_rng(1), -1)
    with pytest.raises(ValueError, match="image_e"):
        add_cosmic_rays(np.zeros((8, 8)), np.random.default_rng(1), 1)
