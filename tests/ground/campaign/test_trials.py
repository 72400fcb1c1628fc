"""Campaign trials: seeds, rate axes, detector settings and the verdict of a solution."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.firmware import status as S
from lodestar.firmware.pipeline import Result
from lodestar.ground.campaign import runner, trials
from lodestar.ground.onboard import camera_settings
from lodestar.ground.truth import WRONG_ARCSEC, attitude_error_arcsec
from lodestar.sim import presets


def test_seed_depends_on_campaign_study_preset_trial_not_level():
    s = trials.trial_seed(0, "rate", "estcube2", 5)
    assert s == trials.trial_seed(0, "rate", "estcube2", 5) and 0 <= s < 2 ** 63
    others = {trials.trial_seed(1, "rate", "estcube2", 5), trials.trial_seed(0, "limiting",
                                                                             "estcube2", 5),
              trials.trial_seed(0, "rate", "lohmann", 5), trials.trial_seed(0, "rate", "estcube2",
                                                                            6)}
    assert s not in others and len(others) == 4
    assert trials.task_key(("rate", "lohmann", "1.5", 7)) == "rate/lohmann/1.5/7"


def test_rate_axes():
    rng = np.random.default_rng(0)
    for _ in range(20):
        w = trials.rate_vector(rng, 2.0, "cross")
        assert w[2] == 0 and np.linalg.norm(w) == pytest.approx(2.0)
        assert np.linalg.norm(trials.rate_vector(rng, 2.0, "random")) == pytest.approx(2.0)
        assert abs(trials.rate_vector(rng, 2.0, "roll")[2]) == 2.0
    with pytest.raises(ValueError, match="unknown rate axis"):
        trials.rate_vector(rng, 1.0, "diagonal")


class FakeFrame:
    def __init__(self, q, omega_rad_s=(0.0, 0.0, 0.0)):
        self.q = q
        self.omega_rad_s = list(omega_rad_s)
        self.truth = {"sources": []}


def test_verdict_tells_wrong_from_failed():
    q = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_quat()
    frame = FakeFrame(q)
    failed = trials.verdict(Result(S.NO_MATCH), [], frame)
    assert failed["status"] == "NO_MATCH" and not failed["solved"] and not failed["wrong"]
    res = Result(S.OK)
    res.sigma_cross_arcsec, res.sigma_roll_arcsec = 1.0, 10.0
    # beyond WRONG_ARCSEC a solution is wrong unless its covariance covers the error
    for angle, sigma, wrong, imprecise in ((WRONG_ARCSEC * 0.9, 1.0, False, False),
                                           (WRONG_ARCSEC * 1.1, 1.0, True, False),
                                           (WRONG_ARCSEC * 1.1, WRONG_ARCSEC, False, True)):
        res.sigma_cross_arcsec = sigma
        res.q = list((Rotation.from_rotvec([0, math.radians(angle / 3600), 0]) *
                      Rotation.from_quat(q)).as_quat())
        out = trials.verdict(res, [], frame)
        assert out["solved"] and out["wrong"] is wrong and out["imprecise"] is imprecise
        assert out["status"] == ("WRONG" if wrong else "OK")
        assert out["error_arcsec"][1] == pytest.approx(angle, rel=1e-6)
        assert out["sigma_arcsec"] == [sigma, 10.0]


def test_verdict_keeps_an_imprecise_attitude_apart():
    """An ``IMPRECISE`` result is not solved, but its attitude's error (at its instant) and
    sigmas are kept under ``loose``; a result without an attitude has none."""
    q = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_quat()
    frame = FakeFrame(q)
    res = Result(S.IMPRECISE)
    res.q = list((Rotation.from_rotvec([0, 0, math.radians(300 / 3600)]) *
                  Rotation.from_quat(q)).as_quat())
    res.sigma_cross_arcsec, res.sigma_roll_arcsec = 2.0, 80.0
    out = trials.verdict(res, [], frame)
    assert out["status"] == "IMPRECISE" and not out["solved"] and not out["wrong"]
    assert out["error_arcsec"] is None
    assert out["loose"]["error_arcsec"][2] == pytest.approx(300.0, rel=1e-6)
    assert out["loose"]["sigma_arcsec"] == [2.0, 80.0]
    assert "loose" not in trials.verdict(Result(S.NO_MATCH), [], frame)


def test_verdict_judges_the_attitude_at_its_instant():
    """A solution reporting ``t_epoch_s`` is compared with the truth turned by the frame's rate
    to that instant: right there, wrong against the start of the exposure."""
    q = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_quat()
    frame = FakeFrame(q, (0.0, 0.0, math.radians(10.0)))
    res = Result(S.OK)
    res.sigma_cross_arcsec, res.sigma_roll_arcsec = 1.0, 10.0
    res.q = trials.truth_at(frame, 0.09)
    res.t_epoch_s = 0.09
    out = trials.verdict(res, [], frame)
    assert not out["wrong"] and out["t_epoch_s"] == 0.09 and out["error_arcsec"][2] < 1e-6
    res.t_epoch_s = 0.0
    assert trials.verdict(res, [], frame)["wrong"]
    assert trials.truth_at(frame, None) is q


def test_tracking_prior_is_the_truth_before_turned_by_its_error():
    """The flight loop's prior: the truth ``dt`` before the frame, off by about
    ``TRACK_PRIOR_ERROR_ARCSEC`` (across per axis, in roll), the same for the same seed."""
    q = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_quat()
    frame = FakeFrame(q, (0.0, 0.0, math.radians(30.0)))
    cross, roll = [], []
    for seed in range(200):
        prior = trials.tracking_prior(frame, 0.1, np.random.default_rng(seed))
        e = attitude_error_arcsec(prior, trials.truth_at(frame, -0.1))
        cross += [e["x"], e["y"]]
        roll.append(e["roll"])
    assert np.std(cross) == pytest.approx(trials.TRACK_PRIOR_ERROR_ARCSEC[0], rel=0.2)
    assert np.std(roll) == pytest.approx(trials.TRACK_PRIOR_ERROR_ARCSEC[1], rel=0.2)
    again = trials.tracking_prior(frame, 0.1, np.random.default_rng(0))
    assert np.allclose(again, trials.tracking_prior(frame, 0.1, np.random.default_rng(0)))
    # 0.1 s at 30 deg/s turns it by 3 deg: far from the frame's own truth at 0
    assert abs(attitude_error_arcsec(again, q)["roll"]) > 3600.0


def test_no_gyro_applies_to_the_rate_study():
    assert runner.make_config("rate", ["estcube2"], gyro=False)["gyro"] is False
    with pytest.raises(ValueError, match="--no-gyro applies to the rate study"):
        runner.make_config("accuracy", ["estcube2"], gyro=False)


def test_noise_trial_identifies_at_small_noise():
    config = {"camera": camera_settings("lohmann", "tuned"), "axis": "cross",
              "method": "pyramid"}
    out = trials.falsestars_trial("lohmann", "noise", 11, config)
    assert set(out) == set(trials.METHODS)
    for method in trials.METHODS:
        assert set(out[method]) == {f"{s:g}" for s in trials.NOISE_PX}
        assert out[method]["0"]["status"] == "OK" and out[method]["0"]["wrong_matches"] == 0
    with pytest.raises(ValueError, match="unknown falsestars level"):
        trials.falsestars_trial("lohmann", "other", 11, config)


@pytest.mark.parametrize("fov", trials.FOVS_DEG)
def test_fov_camera_keeps_the_sensor_and_f_number(fov):
    base = presets.load_preset("estcube2")
    cam = trials.fov_camera("estcube2", fov)
    assert cam.fov_deg()[0] == pytest.approx(fov, abs=1e-9)
    assert (cam.width, cam.height, cam.pixel_pitch_um, cam.read_noise_e, cam.psf_sigma_px) == \
        (base.width, base.height, base.pixel_pitch_um, base.read_noise_e, base.psf_sigma_px)
    assert cam.f_number == pytest.approx(base.f_number)
    # the same sensor behind a lens of 4x the aperture sees 5 log10(4) = 3.01 mag deeper
    shift = trials.fov_render_limit("estcube2", cam) - trials.RENDER_MAG_LIMIT
    assert shift == pytest.approx(5 * math.log10(cam.aperture_mm / base.aperture_mm))
    assert (shift > 0) == (fov < base.fov_deg()[0])


def test_fov_trial_solves_a_wide_field_with_its_own_database():
    config = {"camera": camera_settings("estcube2", "tuned"), "axis": "cross",
              "method": "pyramid"}
    out = trials.fov_trial("estcube2", "30", 5, config)
    assert out["status"] == "OK" and out["wrong_matches"] == 0 and out["n_matches"] >= 8
    assert out["solve_ms"] > 0
    # the 30 deg database holds fewer stars than the 20 deg one of the same density
    assert out["db_stars"] < trials.fov_trial("estcube2", "20", 5, config)["db_stars"]
