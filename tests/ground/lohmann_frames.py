"""Simulated frames of the ``lohmann`` preset (752 x 480, k1 = -0.37: about 14 px of barrel
distortion at the frame's edge) for the calibration tests: the flight exposure of
``lodestar.ground.onboard.SETTINGS`` at random attitudes, written as the 16-bit PNG files
``lodestar simulate`` writes, and the starting camera of a user who knows only the nominal
field of view (a distortion-free pinhole with the preset's horizontal FOV)."""

import numpy as np

from lodestar.ground import onboard, solve
from lodestar.ground.files import write_atomic
from lodestar.sim import attitude, imageio, scene
from lodestar.sim.presets import load_preset

N_FRAMES = 6
SEED = 15
KSIGMA = 3.0
"""Detection offset of the tests' solves (the flight settings' ``mu + 3 sigma``)."""


def truth_camera():
    """The firmware camera the frames are rendered with."""
    return onboard.firmware_camera(load_preset("lohmann"))


def nominal_fov_deg():
    """The preset's horizontal FOV edge to edge, deg."""
    return solve.camera_fov_deg(truth_camera())[0]


def start_camera():
    """A distortion-free pinhole with the nominal FOV, centred: the calibration's start."""
    cam = truth_camera()
    return solve.make_camera(cam.width, cam.height, nominal_fov_deg())


def write_frames(folder, n=N_FRAMES, seed=SEED):
    """Render ``n`` frames into ``folder``; returns their paths."""
    cam = load_preset("lohmann")
    exposure = onboard.camera_settings("lohmann")["exposure_s"]
    rng = np.random.default_rng(seed)
    paths = []
    for i in range(n):
        sim = scene.simulate(cam, attitude.random_attitude(rng), exposure_s=exposure,
                             seed=seed * 100 + i)
        path = folder / f"lohmann_{i}.png"
        write_atomic(path, imageio.frame_png(sim.frame))
        paths.append(path)
    return paths
