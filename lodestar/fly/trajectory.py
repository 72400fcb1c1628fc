"""The spacecraft's attitude over time and the gyro that measures its rate.

Conventions (``docs/conventions.md``): scalar-last ``q`` with ``v_cam = A(q) v_icrs``; body
rates ``omega`` in rad/s in the camera frame, a fixed star's camera-frame direction moving as
``dv/dt = -omega x v``.  Every trajectory turns about one fixed camera-frame axis, so the
attitude is ``A(t) = R(-n theta(t)) A(0)`` exactly, ``theta`` the angle turned.

- ``rest``: no rate.
- ``slew``: the rate ``rate_deg_s``, held from t = 0 (a slew under way), or reached in a
  linear ramp over ``ramp_s`` and then held.
- ``spin``: a turn about the boresight (+z) at the norm of ``rate_deg_s`` (10 deg/s if zero).
"""

import math

import numpy as np
from scipy.spatial.transform import Rotation

TRAJECTORIES = ("rest", "slew", "spin")
SPIN_DEFAULT_DEG_S = 10.0
GYRO_BIAS_DEG_S = 0.005
"""The gyro model's bias per axis (deg/s; a MEMS rate sensor after calibration): an
estimate, drawn once per run with this standard deviation."""
GYRO_NOISE_DEG_S = 0.002
"""White noise of one gyro sample per axis (deg/s, 1 sigma): an estimate."""


class Trajectory:
    """``kind`` (:data:`TRAJECTORIES`) from attitude ``q0`` at t = 0 (s)."""

    def __init__(self, kind, q0, rate_deg_s=(0.0, 0.0, 0.0), ramp_s=0.0):
        if kind not in TRAJECTORIES:
            raise ValueError(f"--trajectory {kind!r} is not one of {', '.join(TRAJECTORIES)}")
        rate = np.radians(np.asarray(rate_deg_s, dtype=float))
        if rate.shape != (3,) or not np.all(np.isfinite(rate)):
            raise ValueError(f"--rate must be 3 finite numbers (deg/s), got {rate_deg_s!r}")
        if kind == "rest" and np.any(rate):
            raise ValueError("--rate must be 0 0 0 with --trajectory rest")
        if kind == "spin":
            rate = np.array([0.0, 0.0, np.linalg.norm(rate) or math.radians(SPIN_DEFAULT_DEG_S)])
        self.kind, self.q0, self.rate, self.ramp_s = kind, np.asarray(q0, float), rate, ramp_s
        self._a0 = Rotation.from_quat(self.q0)

    def _scale(self, t):
        """(the rate's fraction reached, the angle's fraction of rate x t) at ``t``."""
        if self.kind != "slew" or self.ramp_s <= 0 or t >= self.ramp_s:
            turned = t - self.ramp_s / 2 if self.kind == "slew" and self.ramp_s > 0 else t
            return 1.0, turned
        return t / self.ramp_s, t * t / (2 * self.ramp_s)

    def omega(self, t):
        """Body rate at ``t`` (rad/s, camera frame)."""
        return self.rate * self._scale(max(t, 0.0))[0]

    def attitude(self, t):
        """``q`` at ``t`` (s), scalar last."""
        turned = self._scale(max(t, 0.0))[1]
        return (Rotation.from_rotvec(-self.rate * turned) * self._a0).as_quat()


class Gyro:
    """Measured rate = true rate + a bias drawn once + white noise per sample (rad/s)."""

    def __init__(self, trajectory, seed=0, bias_deg_s=GYRO_BIAS_DEG_S,
                 noise_deg_s=GYRO_NOISE_DEG_S):
        self.trajectory = trajectory
        self.rng = np.random.default_rng(seed)
        self.bias = np.radians(bias_deg_s) * self.rng.standard_normal(3)
        self.noise = math.radians(noise_deg_s)

    def measure(self, t):
        w = self.trajectory.omega(t) + self.bias + self.noise * self.rng.standard_normal(3)
        return (float(w[0]), float(w[1]), float(w[2]))
