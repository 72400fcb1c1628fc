"""Scene assembly: stars land where the camera model puts them, truth is exact, bad input fails."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.golden import detect_frame
from lodestar.sim import attitude, catalogue, presets, scene
from lodestar.sim.goldenset import window_camera

CAM = window_camera(presets.load_preset("estcube2"), (976, 732, 640, 480))
Q = attitude.from_radec_roll(83.8, -5.4, 10.0)


def _quiet(cam):
    """The same camera without noise sources, for geometric checks."""
    import dataclasses
    return dataclasses.replace(cam, read_noise_e=0.0, dark_current_e_per_s=0.0)


def test_static_truth_is_the_projected_catalogue_position():
    sim = scene.simulate(CAM, Q, seed=3, sky_e_per_px_s=0.0)
    cat = catalogue.load()
    stars = [s for s in sim.truth["sources"] if s["kind"] == "star"]
    assert len(stars) > 10
    for s in stars[:20]:
        v = cat.unit_vectors()[cat.by_hip(s["hip"])]
        x, y, _ = CAM.project(Rotation.from_quat(Q).apply(v))
        if s["electrons_in_frame"] > 0.999 * s["electrons"]:
            assert (s["x"], s["y"]) == pytest.approx((float(x), float(y)), abs=1e-6)


def test_rates_smear_along_the_predicted_track():
    """A rotation about camera +x moves stars towards +y (dv/dt = -omega x v) at
    v = f omega px/s.  With the rolling shutter row r exposes over [r t_row, r t_row + t_e],
    so a star starting at row y0 is seen at times with mean (t_e/2 + t_row y0)/(1 - v t_row)
    and its truth centroid moves by v times that."""
    rate = np.radians(1.0)
    sim = scene.simulate(_quiet(CAM), Q, (1.0, 0.0, 0.0), exposure_s=0.1, seed=4,
                         sky_e_per_px_s=0.0)
    rest = scene.simulate(_quiet(CAM), Q, exposure_s=0.1, seed=4, sky_e_per_px_s=0.0)
    moved = {s["hip"]: s for s in sim.truth["sources"] if s["kind"] == "star"}
    v = CAM.fy_px * rate
    checked = 0
    for s in rest.truth["sources"]:
        m = moved.get(s["hip"])
        if m is None or m["electrons_in_frame"] < 0.999 * m["electrons"] or \
                s["electrons_in_frame"] < 0.999 * s["electrons"]:
            continue
        t_mean = (0.05 + CAM.row_time_s * s["y"]) / (1 - v * CAM.row_time_s)
        assert m["y"] - s["y"] == pytest.approx(v * t_mean, rel=0.02)
        assert m["x"] - s["x"] == pytest.approx(0.0, abs=0.2)
        checked += 1
    assert checked >= 5


def test_detected_centroids_match_truth_at_rest():
    sim = scene.simulate(CAM, Q, seed=5)
    res = detect_frame(sim.frame, scene.detector_config(CAM))
    xs = np.array([s["x"] for s in sim.truth["sources"]])
    ys = np.array([s["y"] for s in sim.truth["sources"]])
    bright = [b for b in res.blobs if b.nsat == 0 and b.s0 > 40000]
    assert bright
    for b in bright:           # well above threshold: noise and threshold cuts stay small
        assert np.hypot(xs - b.sx / b.s0, ys - b.sy / b.s0).min() < 0.1


def test_extras_and_determinism():
    extras = scene.Extras(false_stars=3, planets=(("Mars", 84.0, -5.0, -1.0),), cosmic_rays=5)
    a = scene.simulate(CAM, Q, seed=6, extras=extras)
    b = scene.simulate(CAM, Q, seed=6, extras=extras)
    c = scene.simulate(CAM, Q, seed=7, extras=extras)
    assert np.array_equal(a.frame, b.frame) and a.truth == b.truth
    assert not np.array_equal(a.frame, c.frame)
    kinds = [s["kind"] for s in a.truth["sources"]]
    assert kinds.count("false_star") == 3 and len(a.truth["cosmic_rays"]) == 5
    assert a.frame.dtype == np.uint16 and a.frame.shape == (480, 640)


@pytest.mark.parametrize("kwargs,match", [
    ({"q": [np.nan, 0, 0, 1]}, "NaN|finite|unit"),
    ({"q": [0, 0, 0, 2]}, "unit"),
    ({"omega_deg_s": (1, 2)}, "omega_deg_s must be 3 finite numbers"),
    ({"omega_deg_s": (1, np.inf, 0)}, "omega_deg_s must be 3 finite numbers"),
    ({"exposure_s": -0.1}, "exposure_s must be > 0"),
])
def test_bad_input(kwargs, match):
    args = {"cam": CAM, "q": Q}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        scene.simulate(**args)


def test_unknown_preset():
    with pytest.raises(ValueError, match="unknown camera preset 'st16'"):
        presets.load_preset("st16")


def test_visible_track_of_a_smeared_star():
    # turning about camera y, every star moves along its row: a straight track through its
    # centroid, as long as the rate times the exposure in pixels
    cam = CAM
    rate = 2.0
    sim = scene.simulate(cam, Q, (0.0, rate, 0.0), 0.1, seed=3, mag_limit=7.0)
    moved = [s for s in sim.truth["sources"] if s["kind"] == "star" and
             20 < s["x"] < cam.width - 60 and 20 < s["y"] < cam.height - 20]
    assert moved
    length = np.radians(rate * 0.1) * cam.fx_px
    for s in moved:
        track = np.array(s["track"])
        assert track.shape == (scene.TRACK_POINTS, 2)
        mid = track[scene.TRACK_POINTS // 2]
        assert np.hypot(mid[0] - s["x"], mid[1] - s["y"]) < 1.0
        # rolling shutter: seen during its own row's exposure, so the track spans the
        # exposure, not the readout
        assert np.hypot(*(track[-1] - track[0])) == pytest.approx(length, rel=0.1)
    rest = scene.simulate(cam, Q, (0.0, 0.0, 0.0), 0.1, seed=3, mag_limit=7.0)
    for s in rest.truth["sources"]:
        if s["track"]:
            assert np.ptp(np.array(s["track"]), axis=0) == pytest.approx([0.0, 0.0], abs=1e-9)
