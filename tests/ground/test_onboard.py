"""The flight pipeline on the ground: the database is built once, then read from the cache
(and said so), and a detection result reaches the firmware through the packet codec."""

import io
import math

import pytest

from lodestar.firmware.settings import DEFAULT_TOLERANCE_PX
from lodestar.golden import detect_frame
from lodestar.ground import codec, onboard
from lodestar.ground.solve import make_camera
from lodestar.sim import attitude, scene
from lodestar.sim.presets import load_preset


def test_database_is_built_then_read_from_the_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("LODESTAR_CACHE_DIR", str(tmp_path / "cache"))
    camera = make_camera(640, 480, 15.0)
    log = io.StringIO()
    db, path = onboard.star_database(camera, 5.0, label="test camera", log=log)
    assert path.parent == tmp_path / "cache" and path.exists()
    assert "built the star database for test camera (FOV 15.00 x 11.28 deg, V <= 5" in \
        log.getvalue()
    assert f"{db.n_stars} stars; cached in {path}" in log.getvalue()
    log = io.StringIO()
    assert onboard.star_database(camera, 5.0, log=log)[1] == path
    assert f"read the star database from the cache {path}" in log.getvalue()
    assert onboard.star_database(camera, 5.0, log=None)[1] == path


def test_unwritable_cache_still_gives_a_database(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("LODESTAR_CACHE_DIR", str(blocker / "cache"))
    log = io.StringIO()
    db, path = onboard.star_database(make_camera(640, 480, 14.0), 5.0, log=log)
    assert path is None and db.n_stars > 0
    assert "not cached (cache directory not writable)" in log.getvalue()
    with pytest.raises(ValueError):
        onboard.star_database(make_camera(640, 480, 14.0), -3.0)   # no star that bright


def test_tolerance_follows_the_field_of_view():
    assert onboard.default_tolerance_px(make_camera(640, 480, 20.0)) == \
        DEFAULT_TOLERANCE_PX
    wide = make_camera(4096, 3072, 60.0)
    assert onboard.default_tolerance_px(wide) == pytest.approx(
        math.radians(60.0) / 1000 * wide.fx)
    assert onboard.default_tolerance_px(wide) > DEFAULT_TOLERANCE_PX


def test_process_solves_a_simulated_frame(tmp_path, monkeypatch):
    monkeypatch.setenv("LODESTAR_CACHE_DIR", str(tmp_path / "cache"))
    cam = load_preset("estcube2")
    q = attitude.from_radec_roll(83.8, -5.4, 10.0)
    sim = scene.simulate(cam, q, seed=1)
    det = detect_frame(sim.frame, scene.detector_config(cam))
    fw = onboard.firmware_camera(cam)
    assert (fw.width, fw.height, fw.cx, fw.fx) == (2592, 1944, cam.cx, cam.fx_px)
    db, _path = onboard.star_database(fw)
    data, res, timings = onboard.process(det, fw, db, exposure_s=cam.exposure_s)
    assert res.status_name == "OK", res.reason
    assert codec.decode(data) == det
    assert set(timings) == {"packet", "solve", "firmware"} and "identify" in timings["firmware"]
    ra, dec, roll = attitude.to_radec_roll(res.q)
    assert abs(ra - 83.8) < 0.01 and abs(dec + 5.4) < 0.01 and abs(roll - 10.0) < 0.05
    assert res.mode == "lost_in_space"
    # the flight loop's prior: tracking
    _data, tracked, _t = onboard.process(det, fw, db, exposure_s=cam.exposure_s,
                                         prior=list(q), dt=0.1)
    assert tracked.status_name == "OK" and tracked.mode == "tracking"
