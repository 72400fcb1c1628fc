"""Camera presets: loading, the cited numbers, completeness of the sources, bad names."""

import dataclasses
import json
import math
from importlib import resources

import pytest

from lodestar.sim.camera import Camera
from lodestar.sim.presets import DEFAULT_PRESET, PRESETS, load_preset, pinhole

CAMERA_FIELDS = [f.name for f in dataclasses.fields(Camera) if f.name not in ("name", "meta")]


def raw_presets():
    path = resources.files("lodestar.sim").joinpath("data/presets.json")
    return json.loads(path.read_text("utf-8"))


def test_names_and_default():
    assert set(PRESETS) == {"estcube2", "lohmann"}
    assert DEFAULT_PRESET == "estcube2"
    assert load_preset().name == "estcube2"
    assert load_preset() == load_preset("estcube2")


@pytest.mark.parametrize("name", PRESETS)
def test_every_field_is_explicit_and_cited(name):
    entry = raw_presets()[name]
    assert sorted(entry["camera"]) == sorted(CAMERA_FIELDS)
    assert sorted(entry["source"]) == sorted(CAMERA_FIELDS)
    assert all(isinstance(t, str) and len(t) > 5 for t in entry["source"].values())
    cam = load_preset(name)
    assert cam.meta["source"] == entry["source"]
    assert {"sensor", "lens", "board", "fpga", "reserved_low_codes"} <= set(cam.meta)


def test_estcube2_numbers():
    cam = load_preset("estcube2")
    assert (cam.width, cam.height, cam.pixel_bits) == (2592, 1944, 12)
    assert cam.pixel_pitch_um == 2.2 and cam.focal_length_mm == 16.0
    assert cam.f_number == pytest.approx(1.2, abs=1e-12)
    assert cam.aperture_mm == pytest.approx(13.33, abs=0.01)
    assert cam.fx_px * cam.pixel_pitch_um * 1e-3 == pytest.approx(16.0, abs=1e-9)
    assert cam.fy_px == cam.fx_px
    assert (cam.cx, cam.cy) == ((2592 - 1) / 2, (1944 - 1) / 2)
    assert (cam.k1, cam.k2, cam.k3, cam.p1, cam.p2) == (0, 0, 0, 0, 0)
    assert (cam.shutter, cam.row_time_s) == ("rolling", 43.9e-6)
    assert (cam.read_noise_e, cam.gain_adu_per_e, cam.qe) == (3.5, 7.0, 0.5)
    # Dzamba's 7 counts/e- leaves a 12-bit full scale of only ~585 e-
    assert cam.full_scale_adu / cam.gain_adu_per_e == pytest.approx(585, abs=0.5)
    assert cam.exposure_s == 0.1
    assert cam.meta["fpga"].endswith("EP4CE22")
    assert cam.meta["reserved_low_codes"] == 0


def test_lohmann_numbers():
    cam = load_preset("lohmann")
    assert (cam.width, cam.height, cam.pixel_bits) == (752, 480, 10)
    assert cam.pixel_pitch_um == 6.0 and cam.focal_length_mm == 8.5
    assert cam.f_number == pytest.approx(1.3, abs=1e-12)
    # calibrated focal lengths 8.63 mm and 8.56 mm (Lohmann L859)
    assert cam.fx_px * cam.pixel_pitch_um * 1e-3 == pytest.approx(8.63, abs=1e-9)
    assert cam.fy_px * cam.pixel_pitch_um * 1e-3 == pytest.approx(8.56, abs=1e-9)
    assert (cam.k1, cam.k2, cam.k3, cam.p1, cam.p2) == (-0.3686, 0.3148, 0.0, -0.0023, 0.0003)
    assert (cam.cx, cam.cy) == (375.5, 239.5)
    assert cam.shutter == "global"
    assert cam.meta["board"] == "Terasic DE2-115"
    assert cam.meta["reserved_low_codes"] == 4       # MT9V022 codes 0-3 read as 4
    assert cam.adc_offset_adu < cam.full_scale_adu


def test_unknown_preset_lists_known_ones():
    with pytest.raises(ValueError, match=r"unknown camera preset 'st16'; known presets: "
                                         r"estcube2, lohmann"):
        load_preset("st16")


def test_cameras_are_immutable():
    cam = load_preset("lohmann")
    with pytest.raises(dataclasses.FrozenInstanceError):
        cam.fx_px = 1000.0
    with pytest.raises(TypeError):
        cam.meta["board"] = "other"
    assert load_preset("lohmann").meta["board"] == "Terasic DE2-115"


@pytest.mark.parametrize("name", PRESETS)
def test_pinhole_keeps_the_sensor_and_f_number_at_the_asked_fov(name):
    base = load_preset(name)
    cam = pinhole(name, 12.0, 1024, 768)
    assert (cam.width, cam.height) == (1024, 768)
    assert math.degrees(2 * math.atan(cam.width / 2 / cam.fx_px)) == pytest.approx(12.0)
    assert cam.fx_px == cam.fy_px and (cam.cx, cam.cy) == (511.5, 383.5)
    assert (cam.k1, cam.k2, cam.k3, cam.p1, cam.p2) == (0.0,) * 5
    assert cam.f_number == pytest.approx(base.f_number)
    assert cam.pixel_pitch_um == base.pixel_pitch_um and cam.exposure_s == base.exposure_s
    full = pinhole(name, 20.0)
    assert (full.width, full.height) == (base.width, base.height)
