"""Trajectories turn the camera frame as ``dv/dt = -omega x v`` (docs/conventions.md), and the
gyro adds a fixed bias and white noise."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.fly import trajectory

Q0 = Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_quat()


def _v(q, v):
    return Rotation.from_quat(q).apply(v)


@pytest.mark.parametrize("kind, rate, ramp", [("slew", (0.2, 0.5, -0.1), 0.0),
                                              ("slew", (0.0, 1.0, 0.0), 1.0),
                                              ("spin", (0.0, 0.0, 0.0), 0.0)])
def test_a_star_moves_as_minus_omega_cross_v(kind, rate, ramp):
    path = trajectory.Trajectory(kind, Q0, rate, ramp)
    star = np.array([0.3, -0.2, 0.93])
    star /= np.linalg.norm(star)
    for t in (0.0, 0.4, 2.0):
        dt = 1e-4
        v0, v1 = _v(path.attitude(t), star), _v(path.attitude(t + dt), star)
        w = path.omega(t + dt / 2)
        assert np.allclose((v1 - v0) / dt, -np.cross(w, (v0 + v1) / 2), atol=1e-6)
    assert np.allclose(path.attitude(0.0), Q0)


def test_spin_is_about_the_boresight_and_rest_refuses_a_rate():
    spin = trajectory.Trajectory("spin", Q0, (3.0, 4.0, 0.0))
    assert np.allclose(spin.omega(1.0), np.radians([0, 0, 5.0]))
    assert np.allclose(trajectory.Trajectory("spin", Q0).omega(0.0)[2], np.radians(10.0))
    assert not np.any(trajectory.Trajectory("rest", Q0).omega(3.0))
    with pytest.raises(ValueError, match="rest"):
        trajectory.Trajectory("rest", Q0, (0.0, 0.1, 0.0))
    with pytest.raises(ValueError, match="--trajectory"):
        trajectory.Trajectory("tumble", Q0)
    with pytest.raises(ValueError, match="--rate"):
        trajectory.Trajectory("slew", Q0, (0.0, float("nan"), 0.0))


def test_slew_ramps_to_its_rate():
    path = trajectory.Trajectory("slew", Q0, (0.0, 1.0, 0.0), ramp_s=2.0)
    assert np.allclose(path.omega(1.0), np.radians([0, 0.5, 0]))
    assert np.allclose(path.omega(5.0), np.radians([0, 1.0, 0]))


def test_gyro_bias_is_fixed_and_noise_white():
    path = trajectory.Trajectory("slew", Q0, (0.0, 0.5, 0.0))
    gyro = trajectory.Gyro(path, seed=3)
    samples = np.array([gyro.measure(t) for t in np.linspace(0, 10, 4000)])
    err = samples - path.omega(0.0)
    assert np.allclose(err.mean(axis=0), gyro.bias, atol=3e-6)
    assert err.std(axis=0) == pytest.approx([np.radians(trajectory.GYRO_NOISE_DEG_S)] * 3,
                                            rel=0.1)
    assert np.allclose(trajectory.Gyro(path, seed=3).bias, gyro.bias)
