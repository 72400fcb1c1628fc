"""lodestar.firmware.geometry: vector helpers, the finite test and Rodrigues' rotation."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.firmware import geometry as G
from lodestar.firmware import quaternion as Q


def test_vector_helpers():
    u, v = [1.0, 2.0, 3.0], [-4.0, 0.5, 2.0]
    assert G.dot(u, v) == pytest.approx(np.dot(u, v))
    assert G.cross(u, v) == pytest.approx(tuple(np.cross(u, v)))
    assert G.norm(u) == pytest.approx(np.linalg.norm(u))
    assert G.triple(u, v, [0.3, -1.0, 2.0]) == pytest.approx(
        np.dot(np.cross(u, v), [0.3, -1.0, 2.0]))
    assert G.normalise_vector(u) == pytest.approx(list(np.asarray(u) / np.linalg.norm(u)))
    assert G.unit(u) == pytest.approx(tuple(np.asarray(u) / np.linalg.norm(u)))
    with pytest.raises(ValueError, match="zero vector"):
        G.normalise_vector([0, 0, 0])
    with pytest.raises(ValueError, match="not finite"):
        G.normalise_vector([0, float("nan"), 1])
    with pytest.raises(ValueError, match="3 components"):
        G.normalise_vector([0, 1])
    for bad in ([0, 0, 0], [0, float("nan"), 1], [float("inf"), 0, 1]):
        assert G.unit(bad) is None


def test_finite_and_numbers():
    for x in (0, -3, 1.5, 1e308):
        assert G.finite(x) and G.is_number(x)
    for x in (float("nan"), float("inf"), -float("inf")):
        assert not G.finite(x) and not G.is_number(x)
    for x in (True, None, "1", [1.0]):
        assert not G.is_number(x)
    assert G.vector3([1, 2, 3]) == (1.0, 2.0, 3.0)
    for bad in (None, [1, 2], [1, 2, float("nan")], [1, True, 2], "abc", 5):
        assert G.vector3(bad) is None


def test_eps_is_double_on_cpython():
    assert G.EPS == 2.0 ** -52


def test_chord_and_angle_are_accurate_at_small_angles():
    for a in (1e-9, 1e-4, 0.3, 2.0, math.pi):
        u = (1.0, 0.0, 0.0)
        v = (math.cos(a), math.sin(a), 0.0)
        assert G.chord(u, v) == pytest.approx(2.0 * math.sin(0.5 * a), rel=1e-12)
        assert G.angle(u, v) == pytest.approx(a, rel=1e-9)


def test_matrix_products_and_residuals():
    rng = np.random.default_rng(1)
    q = Rotation.random(random_state=rng).as_quat()
    m = Q.matrix(q)
    r = rng.normal(size=3)
    b = rng.normal(size=3)
    want = Rotation.from_quat(q).apply(r)
    assert G.mat_vec(m, r) == pytest.approx(tuple(want), abs=1e-12)
    assert G.residual2(m, b, r) == pytest.approx(float(np.sum((b - want) ** 2)), abs=1e-12)


def test_rotate_about_matches_scipy():
    rng = np.random.default_rng(2)
    for _ in range(20):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(-4, 4)
        v = rng.normal(size=3)
        want = Rotation.from_rotvec(angle * axis).apply(v)
        assert G.rotate_about(tuple(v), tuple(axis), angle) == pytest.approx(tuple(want),
                                                                            abs=1e-12)


def test_is_number_takes_subclasses_and_rejects_bools():
    class Count(int):
        pass

    assert G.is_number(1) and G.is_number(-2.5) and G.is_number(Count(3))
    assert G.is_number(np.float64(0.25))            # a float subclass
    assert not G.is_number(np.float32(0.25))        # not an int or float
    assert not G.is_number(True) and not G.is_number(float("nan"))
    assert not G.is_number(float("inf"))
    assert not G.is_number("1") and not G.is_number(None)


def test_is_number_refuses_integers_no_float_holds():
    """An int a float (the MCU's float32) cannot hold is not a number: ``float()`` of it
    would raise or be infinite."""
    class Count(int):
        pass

    largest = int(G.MAX_INT)
    assert G.is_number(largest) and G.is_number(-largest) and G.MAX_INT < 3.4029e38
    for big in (largest + 1, -largest - 1, 10 ** 400, Count(10 ** 400)):
        assert not G.is_number(big), big
    assert G.vector3([10 ** 400, 0, 0]) is None


def test_vector3_of_a_sequence_that_fails_to_read_is_none():
    class Unreadable:
        def __len__(self):
            return 3

        def __getitem__(self, i):
            raise RuntimeError("unreadable")

    assert G.vector3(Unreadable()) is None
