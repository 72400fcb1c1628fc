"""Lens calibration from stars (``lodestar.ground.calibrate``): the vectorised model is the
firmware's, the joint fit recovers a known camera from noisy pairs with honest 1-sigma and
drops gross outliers, and on simulated ``lohmann`` frames (about 14 px of barrel
distortion) a start without distortion at the nominal FOV ends with the preset's
coefficients within 3 sigma."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.ground import calibrate, imagesolve
from lodestar.sim import attitude
from tests.ground import lohmann_frames

CHI2_8_P001 = 26.12
"""99.9 % quantile of chi-square with 8 degrees of freedom (the default free parameters)."""


def _deviation(fit, truth):
    """``(per-parameter deviation / sigma, joint chi-square)`` of the free parameters."""
    names = fit.cov_names
    index = calibrate.INTRINSICS.index
    delta = np.array([fit.params[index(n)] - truth[index(n)] for n in names])
    z = {n: d / fit.sigma[n] for n, d in zip(names, delta)}
    return z, float(delta @ np.linalg.solve(fit.cov, delta))


def test_project_is_the_firmware_model():
    cam = calibrate.camera_from_params(752, 480, [1438.3, 1426.7, 371.2, 243.9, -0.3686, 0.3148,
                                            0.05, -0.0023, 0.0003])
    rng = np.random.default_rng(3)
    xy = np.column_stack((rng.uniform(-0.5, 751.5, 200), rng.uniform(-0.5, 479.5, 200)))
    v = np.array([cam.pixel_to_vector(float(x), float(y)) for x, y in xy])
    got = calibrate.project(calibrate.camera_params(cam), v * rng.uniform(0.5, 2.0, (200, 1)))
    want = np.array([cam.vector_to_pixel(tuple(u)) for u in v])
    assert np.max(np.abs(got - want)) < 1e-9
    assert np.max(np.abs(got - xy)) < 1e-6


def _synthetic_frames(camera, n_frames, n_stars, sigma_px, seed):
    """Pairs of random directions in view of ``camera`` at random attitudes, pixels from the
    model plus Gaussian noise."""
    rng = np.random.default_rng(seed)
    params = calibrate.camera_params(camera)
    frames = []
    for k in range(n_frames):
        q = attitude.random_attitude(rng)
        xy = np.column_stack((rng.uniform(5, camera.width - 5, n_stars),
                              rng.uniform(5, camera.height - 5, n_stars)))
        v_cam = np.array([camera.pixel_to_vector(float(x), float(y)) for x, y in xy])
        v = Rotation.from_quat(q).inv().apply(v_cam)
        noisy = calibrate.project(params, v_cam) + rng.normal(0.0, sigma_px, xy.shape)
        # the solver's attitude is a little off: the fit must not depend on it
        q0 = (Rotation.from_rotvec(rng.normal(0, 1e-3, 3)) * Rotation.from_quat(q)).as_quat()
        frames.append(calibrate.FramePairs(f"f{k}", noisy, v, np.arange(n_stars), q0, n_stars))
    return frames


def test_fit_recovers_a_known_camera_and_rejects_outliers():
    truth_cam = lohmann_frames.truth_camera()
    truth = calibrate.camera_params(truth_cam)
    frames = _synthetic_frames(truth_cam, 5, 30, 0.1, seed=7)
    for k, j in ((0, 3), (2, 11), (4, 20)):                # three wrong matches
        frames[k].xy[j] += (4.0, -3.0)
    fit = calibrate.fit_camera(frames, lohmann_frames.start_camera())
    z, chi2 = _deviation(fit, truth)
    assert max(abs(v) for v in z.values()) < 3.0, z
    assert chi2 < CHI2_8_P001
    assert fit.n_rejected == 3
    assert not fit.inlier[[3, 2 * 30 + 11, 4 * 30 + 20]].any()
    assert 0.08 < fit.scale_px < 0.12
    # the fitted distortion is worth something: the camera is not the start's
    assert abs(fit.camera.k1 - truth_cam.k1) < 0.05 and fit.sigma["k1"] < 0.02


def test_fit_one_focal_and_fixed_parameters():
    truth_cam = calibrate.camera_from_params(752, 480, [1430.0, 1430.0, 375.5, 239.5, -0.3, 0.2, 0,
                                                        0, 0])
    frames = _synthetic_frames(truth_cam, 4, 25, 0.05, seed=8)
    fit = calibrate.fit_camera(frames, lohmann_frames.start_camera(), free=("fx", "k1", "k2"),
                         one_focal=True)
    assert fit.camera.fx == fit.camera.fy
    assert abs(fit.camera.fx - 1430.0) < 4 * fit.sigma["fx"]
    assert (fit.camera.cx, fit.camera.p1) == (375.5, 0.0)
    assert set(fit.sigma) == {"fx", "fy", "k1", "k2"}
    start = calibrate.fit_camera(frames, lohmann_frames.start_camera(), free=(),
                           reject_sigma=math.inf)
    assert start.scale_px > 20 * fit.scale_px


def test_too_few_pairs_is_a_clear_error():
    frames = _synthetic_frames(lohmann_frames.truth_camera(), 1, 6, 0.1, seed=9)
    with pytest.raises(calibrate.CalibrationError, match="too few matched stars: 6 pairs"):
        calibrate.fit_camera(frames, lohmann_frames.start_camera())


def test_match_records_refuses_ambiguous_and_shared_stars():
    class Stars:                                   # the catalogue interface match_records uses
        def __init__(self, v):
            self._v = v

        def unit_vectors(self):
            return self._v

    cam = lohmann_frames.truth_camera()
    pix = [(100.0, 100.0), (300.0, 200.0), (303.0, 200.0), (500.0, 300.0)]
    v = np.array([cam.pixel_to_vector(x, y) for x, y in pix])
    q = np.array([0.0, 0.0, 0.0, 1.0])
    records = np.array([(100.4, 99.8),            # star 0
                        (300.2, 200.0),           # star 1, but star 2 is 3 px away: ambiguous
                        (499.5, 300.0), (500.5, 300.0)])   # two records for star 3: neither
    got = calibrate.match_records(records, cam, q, Stars(v), 2.0)
    assert got == [(0, 0)]
    # a star far outside the field (tan 1.4), where the polynomial folds back into the frame
    cam = calibrate.camera_from_params(752, 480, [1438.0, 1427.0, 375.5, 239.5, -0.5, 0, 0, 0, 0])
    far = np.array([[1.4, 0.0, 1.0]]) / np.linalg.norm([1.4, 0.0, 1.0])
    assert cam.fold_radius() < 1.4 and cam.vector_to_pixel(far[0]) is None
    folded = calibrate.project(calibrate.camera_params(cam), far)[0]
    assert cam.in_frame(*folded)
    assert calibrate.match_records(np.array([folded]), cam, q, Stars(far), 2.0) == []


def _sky_image(seed):
    """A small 10-bit frame of a few blobs (never solved: the tests stop before)."""
    rng = np.random.default_rng(seed)
    frame = rng.integers(60, 80, (48, 64)).astype(np.uint16)
    return imagesolve.SkyImage(frame, 10, "png", 64, 48, 1, [])


def test_rounds_are_capped_and_duplicate_frames_refused(monkeypatch):
    """Issue 33: ``--rounds 100000`` ran for hours; the same frame four times (another path,
    a link, a copy) halved every 1-sigma.  Both refused before any solve."""
    def no_solve(*args, **kwargs):
        raise AssertionError("solved")

    monkeypatch.setattr(calibrate, "frame_pairs", no_solve)
    start = lohmann_frames.start_camera()
    one = [("a.png", _sky_image(1))]
    for rounds in (0, calibrate.MAX_ROUNDS + 1, 100000, 2.0, True):
        with pytest.raises(ValueError,
                           match=f"--rounds must be an int in 1..{calibrate.MAX_ROUNDS}"):
            calibrate.calibrate(one, start, rounds=rounds)
    same = [("a.png", _sky_image(1)), ("b.png", _sky_image(2)), ("copy.png", _sky_image(1))]
    with pytest.raises(calibrate.CalibrationError,
                       match="copy.png is the same frame as a.png: give each frame once"):
        calibrate.calibrate(same, start)


def test_rounds_stop_once_the_camera_settles(monkeypatch):
    """The convergence stop: once a coarse round leaves the camera where the previous one
    did, the next round is the last; ``rounds`` reports the rounds run."""
    truth_cam = lohmann_frames.truth_camera()
    pairs = {f"f{k}": f for k, f in enumerate(_synthetic_frames(truth_cam, 4, 30, 0.1, 11))}
    solved = []

    def frame_pairs(name, image, camera, *args, **kwargs):
        solved.append(name)
        return pairs[name]

    monkeypatch.setattr(calibrate, "frame_pairs", frame_pairs)
    images = [(name, _sky_image(k)) for k, name in enumerate(pairs)]
    result = calibrate.calibrate(images, lohmann_frames.start_camera(),
                                 rounds=calibrate.MAX_ROUNDS)
    assert result.rounds < calibrate.MAX_ROUNDS and len(solved) == 4 * result.rounds
    assert result.fit.free == calibrate.DEFAULT_FREE            # the last round fitted all
    assert abs(result.camera.k1 - truth_cam.k1) < 4 * result.sigma["k1"]
    two = calibrate.calibrate(images, lohmann_frames.start_camera(), rounds=2)
    assert two.rounds == 2


@pytest.fixture(scope="module")
def lohmann_calibration(tmp_path_factory):
    paths = lohmann_frames.write_frames(tmp_path_factory.mktemp("lohmann"))
    images = [(p.name, imagesolve.read_image(p)) for p in paths]
    return calibrate.calibrate(images, lohmann_frames.start_camera(), ksigma=lohmann_frames.KSIGMA)


def test_calibration_recovers_the_lohmann_lens(lohmann_calibration):
    result = lohmann_calibration
    # every frame identified; lohmann's frames of 5-8 stars mostly leave a bound beyond
    # issue 33's 180" with their residuals' Student-t tail (IMPRECISE: named right, the
    # attitude loose); the calibration uses the matches either way
    statuses = [f["status"] for f in result.frames]
    assert set(statuses) <= {"OK", "IMPRECISE"} and statuses.count("OK") >= 2
    z, chi2 = _deviation(result.fit, calibrate.camera_params(lohmann_frames.truth_camera()))
    assert set(z) == set(calibrate.DEFAULT_FREE)
    assert max(abs(v) for v in z.values()) < 3.0, z
    assert chi2 < CHI2_8_P001, (chi2, z)
    # the distortion is measured, not just bounded: k1 to better than 5 % of itself
    assert result.sigma["k1"] < 0.05 * abs(lohmann_frames.truth_camera().k1)


def test_calibration_residuals_before_and_after(lohmann_calibration):
    before, after = lohmann_calibration.before, lohmann_calibration.after
    assert before["n"] == after["n"] >= 60
    assert before["rms_px"] > 1.5 and after["rms_px"] < 0.25
    assert after["max_px"] < 4 * after["rms_px"]
    # a pixel of this camera spans about 143 arcsec
    assert 120 < after["rms_arcsec"] / after["rms_px"] < 160
    assert before["rms_arcsec"] > 8 * after["rms_arcsec"]
