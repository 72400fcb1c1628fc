"""``lodestar calibrate``: six simulated ``lohmann`` frames and a start without distortion
give a camera file that ``solve --camera`` and ``db build --camera`` take, and that solves
the frames with more stars and a tenth of the residual; bad input exits 2 with one line
naming the file or frame."""

import json

import numpy as np
import pytest

from lodestar.cli import main
from lodestar.firmware.database import Database
from lodestar.golden.starfield import star_frame
from lodestar.ground.camerafile import read_camera_file
from lodestar.ground.solve import camera_fov_deg
from lodestar.sim import imageio
from tests.ground import lohmann_frames

KSIGMA = ["--ksigma", str(lohmann_frames.KSIGMA)]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return [str(p) for p in lohmann_frames.write_frames(tmp_path_factory.mktemp("frames"))]


@pytest.fixture(scope="module")
def fov():
    return str(lohmann_frames.nominal_fov_deg())


def _error(capsys):
    err = [line for line in capsys.readouterr().err.splitlines()
           if line.startswith("lodestar calibrate: error:")]
    assert len(err) == 1
    return err[0]


def test_calibrate_writes_a_camera_file_solve_and_db_build_take(frames, fov, tmp_path,
                                                                capsys):
    out = tmp_path / "camera.json"
    assert main(["calibrate", *frames, "--fov", fov, *KSIGMA, "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "residuals before" in text and "residuals after" in text and "wrote" in text
    camera = read_camera_file(out)
    truth = lohmann_frames.truth_camera()
    assert abs(camera.k1 - truth.k1) < 0.05 and abs(camera.fx - truth.fx) < 5
    doc = json.loads(out.read_text())
    after = doc["calibration"]["residuals"]["after"]
    assert after["rms_px"] < 0.25 < 1.5 < doc["calibration"]["residuals"]["before"]["rms_px"]

    def solve(*camera_args, code=0):
        assert main(["solve", frames[0], *camera_args, *KSIGMA, "--json"]) == code
        return json.loads(capsys.readouterr().out)

    # as a pinhole the lens leaves a roll too loose to be an attitude (IMPRECISE: its
    # 5-sigma bound beyond max_error_arcsec); calibrated, it solves, tight
    start, calibrated = solve("--fov", fov, code=1), solve("--camera", str(out))
    assert start["status"] == "IMPRECISE" and "max_error_arcsec" in start["reason"]
    assert start["ra_deg"] is None and start["matches"] == []
    assert calibrated["status"] == "OK" and calibrated["camera"] == f"camera file {out}"
    assert len(calibrated["matches"]) >= 8
    assert 5 * calibrated["sigma_roll_arcsec"] < 143.0          # within a pixel (143")

    db = tmp_path / "db.bin"
    assert main(["db", "build", "--camera", str(out), "--density", "30", "10", "--mag",
                 "none", "-o", str(db)]) == 0
    fov_h, fov_v = camera_fov_deg(camera)
    info = Database(db.read_bytes())
    assert abs(np.degrees(info.fov_h) - fov_h) < 1e-3
    assert abs(np.degrees(info.fov_v) - fov_v) < 1e-3

    # an existing camera file is kept unless --force
    before = out.read_bytes()
    assert main(["calibrate", *frames, "--fov", fov, "-o", str(out)]) == 2
    assert "exists; give --force" in _error(capsys) and out.read_bytes() == before
    # nor is an input ever the output
    assert main(["calibrate", frames[0], "--camera", str(out), "-o", str(out),
                 "--force"]) == 2
    assert "is an input of this command" in _error(capsys)


def test_frames_that_do_not_solve_are_named(frames, fov, tmp_path, capsys):
    frame, _ = star_frame(width=752, height=480, pixel_bits=10, n_stars=12, seed=5,
                          sigma=1.2)
    noise = tmp_path / "not_the_sky.png"
    noise.write_bytes(imageio.frame_png(frame))
    out = tmp_path / "camera.json"
    assert main(["calibrate", *frames, str(noise), "--fov", fov, *KSIGMA,
                 "-o", str(out)]) == 2
    line = _error(capsys)
    assert "1 of 7 frames do not solve" in line and "not_the_sky.png" in line
    assert not out.exists()
    assert main(["calibrate", *frames, str(noise), "--fov", fov, *KSIGMA, "--skip-unsolved",
                 "--rounds", "2", "-o", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    statuses = {f["name"]: f["status"] for f in report["calibration"]["frames"]}
    assert statuses[str(noise)] == "not used" and out.exists()


@pytest.mark.parametrize("extra, message", [
    (["--camera", "{bad}"], "not a JSON camera file"),
    (["--fov", "30", "--camera", "{good}"], "give one camera"),
    (["--fov", "30", "-o", "{dir}/c.toml"], "must end in .json"),
    (["--fov", "30", "--rounds", "0"], "--rounds must be an int in 1..10"),
    (["--fov", "30", "--rounds", "100000"], "--rounds must be an int in 1..10, got 100000"),
    (["{frame}", "--fov", "30"], "is the same frame as"),          # the same file twice
    (["--fov", "30", "--tolerance", "nan"], "--tolerance must be a positive number"),
    (["--fov", "30", "--ksigma", "-1"], "--ksigma must be a positive number"),
    (["--preset", "estcube2"], "the estcube2 camera 2592x1944"),
])
def test_bad_input_exits_2_with_one_line(frames, tmp_path, capsys, extra, message):
    bad = tmp_path / "bad.json"
    bad.write_text("{ not json")
    good = tmp_path / "good.json"
    good.write_text(json.dumps({"lodestar_camera": 1,
                                "camera": lohmann_frames.truth_camera().as_dict()}))
    extra = [a.format(bad=bad, good=good, dir=tmp_path, frame=frames[0]) for a in extra]
    argv = ["calibrate", frames[0], *extra]
    if "-o" not in extra:
        argv += ["-o", str(tmp_path / "cam.json")]
    assert main(argv) == 2
    assert message in _error(capsys)


def test_one_frame_has_too_few_stars(frames, fov, tmp_path, capsys):
    assert main(["calibrate", frames[1], "--fov", fov, *KSIGMA, "--rounds", "1",
                 "-o", str(tmp_path / "cam.json")]) == 2
    assert "too few matched stars" in _error(capsys)


def test_frames_of_different_sizes(frames, tmp_path, capsys):
    small = tmp_path / "small.png"
    frame = np.full((240, 376), 70, np.uint16)
    frame[100:103, 200:203] = 400
    small.write_bytes(imageio.frame_png(frame))
    assert main(["calibrate", frames[0], str(small), "--fov", "30",
                 "-o", str(tmp_path / "cam.json")]) == 2
    assert "frames of one camera needed" in _error(capsys)
