"""Camera files (``lodestar.ground.camerafile``): written whole, never over an existing file
without ``force``, read back to the same camera, bad files refused with one line naming the
file, and the ``camera`` block is what the MCU's ``Camera.from_dict`` takes under
MicroPython."""

import json

import pytest

from lodestar.firmware.camera import Camera
from lodestar.ground import camerafile
from tests.firmware.mpy import lit

CAMERA = Camera(752, 480, 1438.6, 1426.9, 373.5, 240.2, k1=-0.378, k2=0.40, p1=-0.0022,
                p2=0.0004)


def test_round_trip(tmp_path):
    path = tmp_path / "cam.json"
    camerafile.write_camera_file(path, CAMERA, {"fx": 0.3}, {"frames": ["a.png"]})
    assert camerafile.read_camera_file(path).as_dict() == CAMERA.as_dict()
    doc = json.loads(path.read_text())
    assert doc["lodestar_camera"] == 1 and doc["sigma"] == {"fx": 0.3}
    assert doc["calibration"] == {"frames": ["a.png"]}
    assert sorted(tmp_path.iterdir()) == [path]           # no temporary file left


def test_never_overwrites_without_force(tmp_path):
    path = tmp_path / "cam.json"
    path.write_text("precious")
    with pytest.raises(ValueError, match="exists; give --force"):
        camerafile.write_camera_file(path, CAMERA)
    assert path.read_text() == "precious"
    camerafile.write_camera_file(path, CAMERA, force=True)
    assert camerafile.read_camera_file(path).fx == CAMERA.fx
    with pytest.raises(ValueError, match="must end in .json"):
        camerafile.write_camera_file(tmp_path / "cam.toml", CAMERA)


GOOD = {"lodestar_camera": 1, "camera": CAMERA.as_dict()}


@pytest.mark.parametrize("text, message", [
    ("", "not a JSON camera file"),
    ("\xff\xfe", "not a JSON camera file"),
    ("[1, 2]", "not a camera file"),
    (json.dumps({"camera": CAMERA.as_dict()}), "not a camera file"),
    (json.dumps(dict(GOOD, lodestar_camera=2)), "camera file version 2"),
    (json.dumps(dict(GOOD, camera=[1])), "must be an object"),
    (json.dumps(dict(GOOD, camera={"width": 752, "height": 480, "fx": 1000.0})),
     "fy is missing"),
    (json.dumps(dict(GOOD, camera=dict(CAMERA.as_dict(), k4=0.1))), "unknown camera"),
    (json.dumps(dict(GOOD, camera=dict(CAMERA.as_dict(), fx="1438"))),
     "fx must be a finite number"),
    (json.dumps(dict(GOOD, camera=dict(CAMERA.as_dict(), width=752.0))), "width must be"),
    (json.dumps(GOOD).replace("-0.378", "NaN"), "NaN is not a number"),
    (json.dumps(dict(GOOD, camera=dict(CAMERA.as_dict(), k1=-5.0))), "not invertible"),
    # issue 33: a traceback (RecursionError) before; fields no database serves passed
    ('{"lodestar_camera": 1, "camera": ' + "[" * 100000 + "]" * 100000 + "}",
     "not a JSON camera file \\(nested too deep\\)"),
    (json.dumps(dict(GOOD, camera=dict(CAMERA.as_dict(), fx=50.0, fy=50.0, k1=0.0))),
     "the camera's horizontal FOV 119.3 deg is outside the 1 .. 90 deg"),
    (json.dumps(dict(GOOD, camera=dict(CAMERA.as_dict(), fx=1e6, fy=1e6))),
     "the camera's horizontal FOV 0.04.* deg is outside the 1 .. 90 deg"),
])
def test_bad_files_are_refused_naming_the_file(tmp_path, text, message):
    path = tmp_path / "cam.json"
    path.write_bytes(text.encode("latin-1"))
    with pytest.raises(ValueError, match=message) as info:
        camerafile.read_camera_file(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_the_mcu_reads_the_camera_block(tmp_path, micropython):
    path = tmp_path / "cam.json"
    camerafile.write_camera_file(path, CAMERA, {"fx": 0.3}, {"rounds": 2})
    v = (0.11, -0.07, 1.0)
    script = f"""
import json
from lodestar.firmware.camera import Camera
cam = Camera.from_dict(json.loads({lit(path.read_text())})["camera"])
print("PIXEL", repr(cam.vector_to_pixel({lit(v)})))
"""
    code, out = micropython(script)
    assert code == 0, out
    x, y = CAMERA.vector_to_pixel(v)
    line = next(s for s in out.splitlines() if s.startswith("PIXEL"))
    got = [float(t) for t in line[6:].strip("() ").split(",")]
    assert abs(got[0] - x) < 1e-9 * x and abs(got[1] - y) < 1e-9 * y
