"""Simulated estcube2 frames for the flight-pipeline tests: ``lodestar.sim.scene.simulate``
(full 2592 x 1944 frames, the catalogue to V 8) -> the golden detector with
``scene.detector_config`` -> ``lodestar.ground.codec.encode``.  Cached per test session, so the
pipeline, tracking and solve tests share one set of frames and one flight database.
"""

import functools
import math

import numpy as np

from lodestar.firmware.camera import Camera
from lodestar.firmware.database import Database
from lodestar.golden import detect_frame
from lodestar.ground import codec
from lodestar.ground.database import build_database
from lodestar.sim import attitude, scene
from lodestar.sim.presets import load_preset

N_REST = 20
N_MOVING = 10
RATE_DEG_S = 1.0
SEED = 2024
MAX_ERR_DEG = 0.05
"""An accepted attitude further than this from the truth is *wrong*."""


class Frame:
    """One simulated frame: ``packet`` bytes, ``records`` (the golden blobs), truth ``q``
    (scalar last, at the start of row 0's exposure), ``omega`` (rad/s, camera frame) and
    the truth ``sources``."""

    def __init__(self, name, packet_bytes, records, q, omega, sources):
        self.name = name
        self.packet = packet_bytes
        self.records = records
        self.q = q
        self.omega = omega
        self.sources = sources

    @property
    def moving(self):
        return any(self.omega)


@functools.lru_cache(maxsize=None)
def sim_camera():
    return load_preset("estcube2")


def firmware_camera(cam=None):
    cam = cam or sim_camera()
    return Camera(cam.width, cam.height, cam.fx_px, cam.fy_px, cam.cx, cam.cy, cam.k1, cam.k2,
                  cam.k3, cam.p1, cam.p2)


@functools.lru_cache(maxsize=None)
def flight_image():
    """The estcube2 flight database image (V <= 6.0, the defaults)."""
    return build_database(camera=sim_camera(), mag_limit=6.0)


@functools.lru_cache(maxsize=None)
def flight_database():
    return Database(flight_image())


def simulate_frame(q, omega_deg_s, seed, name="frame", velocity_km_s=None):
    """A :class:`Frame` at attitude ``q`` (``velocity_km_s``: the observer's, ICRS, for
    aberrated stars)."""
    cam = sim_camera()
    sim = scene.simulate(cam, q, omega_deg_s, seed=seed, velocity_km_s=velocity_km_s)
    result = detect_frame(sim.frame, scene.detector_config(cam))
    return Frame(name, codec.encode(result), list(result.blobs), np.asarray(q, dtype=float),
                 [math.radians(w) for w in omega_deg_s], sim.truth["sources"])


@functools.lru_cache(maxsize=None)
def frames(n_rest=N_REST, n_moving=N_MOVING, seed=SEED):
    """``n_rest`` frames at rest and ``n_moving`` at ``RATE_DEG_S`` about a random axis, at
    uniformly random attitudes (deterministic)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n_rest + n_moving):
        q = attitude.random_attitude(rng)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        omega = (0.0, 0.0, 0.0) if i < n_rest else tuple(float(a) for a in RATE_DEG_S * axis)
        out.append(simulate_frame(q, omega, seed + i, name="frame{}".format(i)))
    return tuple(out)


@functools.lru_cache(maxsize=None)
def mirrored_packet(frame, flip):
    """The packet of ``frame`` (a frame of :func:`frames`) re-rendered and read out mirrored:
    ``flip`` ``"x"`` reverses the columns, ``"y"`` the rows."""
    cam = sim_camera()
    index = frames().index(frame)
    sim = scene.simulate(cam, frame.q, [math.degrees(w) for w in frame.omega],
                         seed=SEED + index)
    image = sim.frame[:, ::-1] if flip == "x" else sim.frame[::-1, :]
    return codec.encode(detect_frame(np.ascontiguousarray(image), scene.detector_config(cam)))


def tracker(**kwargs):
    """A ``StarTracker`` for estcube2 over the flight database."""
    from lodestar.firmware.pipeline import StarTracker
    from lodestar.firmware.settings import Settings
    cam = sim_camera()
    options = dict(exposure_s=cam.exposure_s, row_time_s=cam.row_time_s)
    options.update(kwargs)
    return StarTracker(flight_database(), firmware_camera(), Settings(**options))
