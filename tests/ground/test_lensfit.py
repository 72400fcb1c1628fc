"""The lens of a frame solved as a pinhole, fitted from its matched stars
(``lodestar.ground.lensfit``): a known ``k1`` is recovered with an honest 1-sigma, non-square
pixels and ``k2`` are taken only when significant, stars spanning too little radius (or too
few) keep the pinhole, and the attitude's sigma grows with what the lens fit leaves open."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.ground import calibrate, lensfit
from lodestar.sim import attitude


def _pairs(camera, n, sigma_px, seed, radius_px=None):
    """``(xy, v, q0)``: ``n`` random stars in view of ``camera`` (within ``radius_px`` of the
    centre when given), their pixels from the model plus Gaussian noise, catalogue unit
    vectors at a random attitude, and that attitude a little off (the first pinhole
    solve's)."""
    rng = np.random.default_rng(seed)
    q = attitude.random_attitude(rng)
    if radius_px is None:
        xy = np.column_stack((rng.uniform(5, camera.width - 5, n),
                              rng.uniform(5, camera.height - 5, n)))
    else:
        r, a = radius_px * np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
        xy = np.column_stack((camera.cx + r * np.cos(a), camera.cy + r * np.sin(a)))
    v_cam = np.array([camera.pixel_to_vector(float(x), float(y)) for x, y in xy])
    v = Rotation.from_quat(q).inv().apply(v_cam)
    noisy = calibrate.project(calibrate.camera_params(camera), v_cam) + \
        rng.normal(0.0, sigma_px, xy.shape)
    q0 = (Rotation.from_rotvec(rng.normal(0, 1e-3, 3)) * Rotation.from_quat(q)).as_quat()
    return noisy, v, q0


ESTCUBE2 = (2592, 1944, 7272.727272727273)


@pytest.mark.parametrize("k1", [-0.4, -0.1, 0.2])
def test_a_known_k1_is_recovered_from_matched_directions(k1):
    """estcube2's frame (normalised corner radius 0.22), 25 stars with 0.15 px noise: ``k1``
    within 4 sigma of the truth with sigma below 0.01, the focal length within 4 sigma,
    square pixels and no ``k2`` kept (both tried from 25 stars), the camera carrying the
    fit."""
    w, h, f = ESTCUBE2
    truth = lensfit.pinhole(w, h, f, k1)
    xy, v, q0 = _pairs(truth, 25, 0.15, seed=int(10 - 10 * k1))
    fit = lensfit.fit_lens(xy, v, q0, lensfit.pinhole(w, h, f * 1.003))
    assert fit is not None
    assert abs(fit.k1 - k1) < 4 * fit.sigma_k1 and fit.sigma_k1 < 0.01
    assert abs(fit.f_px - f) < 4 * fit.sigma_f_px
    assert fit.free == ("fx", "k1") and fit.k2 is None and fit.aspect == 1.0
    assert fit.camera.k1 == fit.k1 and fit.camera.fx == fit.camera.fy == fit.f_px
    assert fit.n_stars == 25 and fit.spread_px <= lensfit.MAX_SIGMA_PX
    assert all(s >= 1.0 for s in fit.inflation)
    assert set(fit.as_dict()) >= {"k1", "sigma_k1", "f_px", "sigma_inflation"}


def test_non_square_pixels_and_k2_only_when_significant():
    """lohmann's lens (fy/fx 0.992, k1 -0.37, k2 +0.31) from 60 stars (0.05 px): fy apart
    from fx and k2 are kept, each within 4 sigma of the truth (a radial lens of square
    pixels keeps neither: the first test)."""
    truth = calibrate.camera_from_params(752, 480, [1438.33, 1426.67, 375.5, 239.5, -0.3686,
                                                    0.3148, 0.0, 0.0, 0.0])
    xy, v, q0 = _pairs(truth, 60, 0.05, seed=3)
    fit = lensfit.fit_lens(xy, v, q0, lensfit.pinhole(752, 480, 1432.0))
    assert fit.free == ("fx", "fy", "k1", "k2")
    assert abs(fit.aspect - 1426.67 / 1438.33) < 4 * fit.sigma_aspect
    assert abs(fit.k1 + 0.3686) < 4 * fit.sigma_k1 and abs(fit.k2 - 0.3148) < 4 * fit.sigma_k2


def test_stars_spanning_too_little_radius_or_too_few_keep_the_pinhole():
    """Stars within 300 px of the centre of estcube2's frame (normalised radius 0.04) leave
    k1 undetermined (its correction's 1-sigma extrapolated to the corner beyond 10 px):
    None; so do fewer than :data:`lensfit.MIN_STARS` stars anywhere."""
    w, h, f = ESTCUBE2
    truth = lensfit.pinhole(w, h, f, -0.3)
    xy, v, q0 = _pairs(truth, 25, 0.15, seed=5, radius_px=300)
    assert len(xy) == 25
    assert lensfit.fit_lens(xy, v, q0, lensfit.pinhole(w, h, f)) is None
    xy, v, q0 = _pairs(truth, lensfit.MIN_STARS - 1, 0.15, seed=6)
    assert lensfit.fit_lens(xy, v, q0, lensfit.pinhole(w, h, f)) is None


def test_an_undetermined_decentring_widens_the_attitude_sigma():
    """The same stars through a lens with tangential p1 -0.0023 (lohmann's): the fit leaves
    p1, p2 out, and the attitude's inflation across the boresight counts them free, so it
    exceeds that of the radial lens alone (here by more than 1.5x)."""
    params = [1432.0, 1432.0, 375.5, 239.5, -0.3, 0.0, 0.0, -0.0023, 0.0003]
    truth = calibrate.camera_from_params(752, 480, params)
    xy, v, q0 = _pairs(truth, 12, 0.1, seed=8)
    fit = lensfit.fit_lens(xy, v, q0, lensfit.pinhole(752, 480, 1432.0))
    pairs = calibrate.FramePairs("f", xy, v, np.arange(len(xy)), q0, len(xy))
    radial = calibrate.fit_camera([pairs], lensfit.pinhole(752, 480, 1432.0),
                                  free=("fx", "k1"), one_focal=True)
    held = np.linalg.pinv(radial.jac[:, 2:].T @ radial.jac[:, 2:])
    alone = np.linalg.pinv(radial.jac.T @ radial.jac)[2:, 2:]
    assert fit.inflation[0] > 1.5 * np.sqrt(alone[0, 0] / held[0, 0])
