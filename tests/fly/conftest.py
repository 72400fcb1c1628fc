"""Fixtures of the twin's tests: a small window of the estcube2 camera (640 x 480 with the
same 20.2 deg horizontal field and the lens's aperture, so the sky and the stars' brightness
stay those of the flight camera while a frame renders and detects in a fraction of the
time), its golden gateware engine and a short loop on it.  Its pixels are 4.05 times the
flight camera's, so an attitude is wrong beyond 60" scaled as much (:data:`WRONG_ARCSEC`):
the same 2.1 px the flight camera's 60" are."""

import dataclasses

import numpy as np
import pytest

from lodestar.fly import golden_top, trajectory, twin
from lodestar.hdl.boards import BOARDS
from lodestar.sim import attitude, presets

SMALL = (640, 480)
WRONG_ARCSEC = 60.0 * 2592 / SMALL[0]


@pytest.fixture(scope="session")
def small_camera():
    base = presets.load_preset("estcube2")
    cam = presets.pinhole("estcube2", 20.2, *SMALL)
    return dataclasses.replace(cam, aperture_mm=base.aperture_mm)


def golden_engine(cam):
    board = BOARDS["estcube2"]
    return golden_top.GoldenTop(cam.width, cam.height, cam.pixel_bits, board.record_capacity,
                                None, 0x21)


def make_twin(cam, engine=None, kind="rest", rate=(0.0, 0.0, 0.0), faults=(), seed=0,
              fault_frame=20, micropython=None):
    q0 = attitude.random_attitude(np.random.default_rng(seed))
    path = trajectory.Trajectory(kind, q0, rate)
    return twin.Twin(cam, engine or golden_engine(cam), path, trajectory.Gyro(path, seed),
                     faults, fault_frame, seed, wrong_arcsec=WRONG_ARCSEC,
                     micropython=micropython)
