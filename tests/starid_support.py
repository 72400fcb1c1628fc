"""Scoring shared by the star-identification tests."""

from lodestar.firmware import starid
from lodestar.ground.scenes import attitude_error_deg

MAX_ERR_DEG = 0.05
"""An accepted attitude further than this from the truth is a wrong solution."""


def outcome(sol, scene):
    """``"correct"``, ``"wrong"`` (attitude off or a star misnamed) or ``"no-solve"``."""
    if sol.status != starid.OK:
        return "no-solve"
    if attitude_error_deg(sol.q, scene.q) > MAX_ERR_DEG:
        return "wrong"
    if any(hip not in scene.components[o] for o, hip in sol.matches):
        return "wrong"
    return "correct"
