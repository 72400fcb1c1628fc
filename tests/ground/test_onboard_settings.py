"""Flight camera settings: the tuned thresholds, exposures and their registers."""

import math

import pytest

from lodestar import contract as C
from lodestar.ground.onboard import SETTINGS, camera_settings, detector_config
from lodestar.sim import presets, scene


def _sigma_adu(cam, t):
    return cam.gain_adu_per_e * math.sqrt(
        cam.read_noise_e ** 2 + (cam.dark_current_e_per_s + scene.SKY_E_PER_PX_S) * t)


def test_settings_per_preset():
    assert camera_settings("estcube2", "tuned") == {"exposure_s": None, "ksigma": 3.0,
                                                    "min_pixels": None}
    assert camera_settings("lohmann", "tuned") == {"exposure_s": 0.2, "ksigma": 3.0,
                                                   "min_pixels": 3}
    assert camera_settings("lohmann") == camera_settings("lohmann", "tuned")
    for preset in presets.PRESETS:
        assert camera_settings(preset, "preset") == {"exposure_s": None, "ksigma": None,
                                                     "min_pixels": None}
    with pytest.raises(ValueError, match="unknown settings 'best'"):
        camera_settings("lohmann", "best")
    assert set(SETTINGS) == {"preset", "tuned"}


def test_preset_settings_are_the_scene_registers():
    for preset in presets.PRESETS:
        cam = presets.load_preset(preset)
        assert detector_config(cam, camera_settings(preset, "preset")) == \
            scene.detector_config(cam)


def test_tuned_registers():
    cam = presets.load_preset("lohmann")
    cfg = detector_config(cam, camera_settings("lohmann"))
    assert cfg.background == scene.detector_config(cam, 0.2).background
    assert cfg.threshold == cfg.background + math.ceil(3 * _sigma_adu(cam, 0.2))
    assert cfg.min_pixels == 3
    cam = presets.load_preset("estcube2")
    cfg = detector_config(cam, camera_settings("estcube2"))
    plain = scene.detector_config(cam)
    assert cfg.background == plain.background and cfg.min_pixels == plain.min_pixels == 4
    assert cfg.threshold == cfg.background + math.ceil(3 * _sigma_adu(cam, cam.exposure_s))
    assert cfg.threshold < plain.threshold
    # an explicit exposure wins over the settings' and the preset's
    long = detector_config(cam, camera_settings("estcube2"), exposure_s=1.0)
    assert long.background == scene.detector_config(cam, 1.0).background
    assert long.threshold <= C.full_scale(cam.pixel_bits)
