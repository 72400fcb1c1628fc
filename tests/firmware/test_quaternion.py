"""lodestar.firmware.quaternion against scipy's Rotation, in the lodestar convention.

q = [x, y, z, w] (scalar last) takes inertial vectors into the camera frame:
v_cam = Rotation.from_quat(q).apply(v_in) = to_matrix(q) v_in (Shuster's A, b = A r).
"""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from lodestar.firmware import quaternion as Q

RNG_SEED = 20240601


def _random_quats(rng, n):
    return Rotation.random(n, random_state=rng).as_quat()


def _special_quats():
    """Identity, 180 deg turns about each axis and diagonals, and tiny rotations."""
    out = [[0.0, 0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0],
           [0.0, 0.0, 0.0, -1.0]]
    for axis in ([1, 1, 0], [1, -1, 1], [0.3, -0.2, 0.9]):
        for angle in (math.pi, math.pi - 1e-7, 1e-9, 2.0):
            out.append(list(Rotation.from_rotvec(np.asarray(axis) / np.linalg.norm(axis)
                                                 * angle).as_quat()))
    return out


def _same_rotation(q1, q2, tol):
    q1, q2 = np.asarray(q1, float), np.asarray(q2, float)
    return min(np.max(np.abs(q1 - q2)), np.max(np.abs(q1 + q2))) <= tol


finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


# --------------------------------------------------------------------------------------------
# Matrix, rotation and products agree with scipy
# --------------------------------------------------------------------------------------------

def test_to_matrix_and_rotate_match_scipy():
    rng = np.random.default_rng(RNG_SEED)
    quats = list(_random_quats(rng, 300)) + _special_quats()
    for q in quats:
        ref = Rotation.from_quat(q)
        A = np.array(Q.to_matrix(list(q)))
        assert np.allclose(A, ref.as_matrix(), atol=1e-15, rtol=0)
        v = rng.normal(size=3)
        assert np.allclose(Q.rotate(q, v), ref.apply(v), atol=1e-14, rtol=0)
        assert np.allclose(Q.rotate(q, v), A @ v, atol=1e-14, rtol=0)


def test_non_unit_quaternion_is_normalised_implicitly():
    rng = np.random.default_rng(RNG_SEED + 1)
    for q in _random_quats(rng, 50):
        scale = rng.uniform(1e-3, 1e3)
        A = np.array(Q.to_matrix(list(q * scale)))
        assert np.allclose(A, Rotation.from_quat(q).as_matrix(), atol=1e-14, rtol=0)
        v = rng.normal(size=3)
        assert np.allclose(Q.rotate(q * scale, v), Rotation.from_quat(q).apply(v), atol=1e-13)


def test_matrix_is_shusters_attitude_matrix_of_the_conjugate():
    """Shuster's A(qbar) = (q4^2 - |q|^2) I + 2 q q^T - 2 q4 [q x] with qbar = conj(ours)."""
    rng = np.random.default_rng(RNG_SEED + 2)
    for q in _random_quats(rng, 50):
        qb = np.asarray(Q.conjugate(q))
        v, q4 = qb[:3], qb[3]
        cross = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        A_shuster = (q4 ** 2 - v @ v) * np.eye(3) + 2 * np.outer(v, v) - 2 * q4 * cross
        assert np.allclose(A_shuster, Q.to_matrix(q), atol=1e-15)


def test_multiply_is_composition():
    rng = np.random.default_rng(RNG_SEED + 3)
    qs = _random_quats(rng, 200)
    for p, q in zip(qs[:100], qs[100:]):
        pq = Q.multiply(p, q)
        ref = (Rotation.from_quat(p) * Rotation.from_quat(q)).as_quat()
        assert _same_rotation(pq, ref, 1e-15)
        v = rng.normal(size=3)
        assert np.allclose(Q.rotate(pq, v), Q.rotate(p, Q.rotate(q, v)), atol=1e-14)
        assert np.allclose(Q.to_matrix(pq), np.array(Q.to_matrix(p)) @ Q.to_matrix(q),
                           atol=1e-15)


def test_conjugate_is_inverse():
    rng = np.random.default_rng(RNG_SEED + 4)
    for q in _random_quats(rng, 50):
        assert Q.conjugate(q) == [-q[0], -q[1], -q[2], q[3]]
        assert _same_rotation(Q.multiply(q, Q.conjugate(q)), [0, 0, 0, 1], 1e-15)
        assert _same_rotation(Q.conjugate(q), Rotation.from_quat(q).inv().as_quat(), 1e-15)


# --------------------------------------------------------------------------------------------
# from_matrix (Shepperd)
# --------------------------------------------------------------------------------------------

def test_from_matrix_round_trip_all_branches():
    rng = np.random.default_rng(RNG_SEED + 5)
    quats = list(_random_quats(rng, 500)) + _special_quats()
    branches = set()
    for q in quats:
        A = Rotation.from_quat(q).as_matrix()
        got = Q.from_matrix(A.tolist())
        assert isinstance(got, list) and len(got) == 4
        assert got[3] >= 0.0
        assert abs(sum(c * c for c in got) - 1.0) < 1e-15
        assert _same_rotation(got, q, 2e-15), (q, got)
        assert np.allclose(Q.to_matrix(got), A, atol=2e-15)
        tr = np.trace(A)
        branches.add(int(np.argmax([tr, A[0, 0], A[1, 1], A[2, 2]])))
    assert branches == {0, 1, 2, 3}


def test_from_matrix_matches_scipy_canonical():
    rng = np.random.default_rng(RNG_SEED + 6)
    for q in _random_quats(rng, 100):
        A = Rotation.from_quat(q).as_matrix()
        ref = Rotation.from_matrix(A).as_quat(canonical=True)
        got = Q.from_matrix(A)
        assert np.allclose(got, ref, atol=1e-15) or abs(ref[3]) < 1e-12


def test_from_matrix_accuracy_near_180_deg():
    """The 180 deg case is where the trace formula alone loses every digit."""
    rng = np.random.default_rng(RNG_SEED + 7)
    for _ in range(100):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        for angle in (math.pi, math.pi - 1e-9, math.pi - 1e-4):
            q = Rotation.from_rotvec(axis * angle).as_quat()
            got = Q.from_matrix(Rotation.from_quat(q).as_matrix())
            assert Q.angle_between(got, q) < 1e-14


@pytest.mark.parametrize("m, match", [
    ([[1, 0, 0], [0, 1, 0]], "3 rows"),
    ([[1, 0, 0], [0, 1], [0, 0, 1]], "row 1 must have 3"),
    ([[1, 0, 0], [0, float("nan"), 0], [0, 0, 1]], r"\[1\]\[1\] is not finite"),
    ([[1, 0, 0], [0, 1, 0], [0, 0, float("inf")]], r"\[2\]\[2\] is not finite"),
    ([[1, 0, 0], [0, 1, 0], [0, 0, -1]], "not a rotation"),          # reflection
    ([[2, 0, 0], [0, 2, 0], [0, 0, 2]], "not a rotation"),           # scaled
    ([[1, 1e-3, 0], [0, 1, 0], [0, 0, 1]], "not a rotation"),        # sheared
])
def test_from_matrix_rejects_non_rotations(m, match):
    with pytest.raises(ValueError, match=match):
        Q.from_matrix(m)


# --------------------------------------------------------------------------------------------
# normalise, canonical, angle_between, axis-angle, vector helpers
# --------------------------------------------------------------------------------------------

def test_normalise_and_canonical():
    q = Q.normalise([0.0, 0.0, 3.0, -4.0])
    assert q == pytest.approx([0.0, 0.0, 0.6, -0.8], abs=1e-16)
    assert Q.canonical([0.0, 0.0, 3.0, -4.0]) == pytest.approx([0.0, 0.0, -0.6, 0.8], abs=1e-16)
    assert Q.canonical(np.array([1.0, 2.0, 2.0, 4.0])) == pytest.approx([0.2, 0.4, 0.4, 0.8])


@pytest.mark.parametrize("bad, match", [
    ([0.0, 0.0, 0.0, 0.0], "zero"),
    ([float("nan"), 0.0, 0.0, 1.0], "not finite"),
    ([0.0, float("inf"), 0.0, 1.0], "not finite"),
    ([1e200, 1e200, 0.0, 1.0], "not finite"),     # |q|^2 overflows
    ([0.0, 0.0, 1.0], "4 components"),
])
def test_bad_quaternions_raise(bad, match):
    for f in (Q.normalise, Q.to_matrix, Q.canonical, lambda q: Q.rotate(q, [1, 0, 0]),
              lambda q: Q.angle_between(q, [0, 0, 0, 1])):
        with pytest.raises(ValueError, match=match):
            f(bad)


def test_unit_quaternion_is_none_for_anything_but_four_usable_numbers():
    class Unreadable:
        def __len__(self):
            return 4

        def __getitem__(self, i):
            raise RuntimeError("unreadable")

    assert Q.unit_quaternion([0, 0, 3, -4]) == pytest.approx([0.0, 0.0, -0.6, 0.8])
    for bad in (None, "junk", [0, 0, 0, 0], [float("nan"), 0, 0, 1], [0, 0, 1],
                [10 ** 400, 0, 0, 1], Unreadable()):
        assert Q.unit_quaternion(bad) is None, bad


def test_angle_between_matches_scipy_and_is_accurate_for_tiny_angles():
    rng = np.random.default_rng(RNG_SEED + 8)
    qs = _random_quats(rng, 200)
    for p, q in zip(qs[:100], qs[100:]):
        ref = (Rotation.from_quat(q) * Rotation.from_quat(p).inv()).magnitude()
        assert Q.angle_between(p, q) == pytest.approx(ref, abs=1e-14)
        assert Q.angle_between(p, -q) == pytest.approx(ref, abs=1e-14)   # q ~ -q
    q = qs[0]
    for tiny in (1e-15, 1e-12, 1e-9, 1e-6):
        axis = rng.normal(size=3)
        d = Rotation.from_rotvec(axis / np.linalg.norm(axis) * tiny)
        q2 = (d * Rotation.from_quat(q)).as_quat()
        assert Q.angle_between(q, q2) == pytest.approx(tiny, rel=1e-6, abs=3e-16)
    assert Q.angle_between([0, 0, 0, 1], [1, 0, 0, 0]) == pytest.approx(math.pi, abs=1e-15)


def test_from_axis_angle_matches_scipy():
    rng = np.random.default_rng(RNG_SEED + 9)
    for _ in range(50):
        axis = rng.normal(size=3)
        angle = rng.uniform(-7, 7)
        ref = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_quat()
        assert _same_rotation(Q.from_axis_angle(axis, angle), ref, 1e-15)
    with pytest.raises(ValueError, match="zero vector"):
        Q.from_axis_angle([0, 0, 0], 1.0)
    with pytest.raises(ValueError, match="angle is not finite"):
        Q.from_axis_angle([0, 0, 1], float("nan"))


@settings(deadline=None, max_examples=200)
@given(st.tuples(finite, finite, finite, finite), st.tuples(finite, finite, finite))
def test_property_rotate_matrix_and_round_trip(qt, v):
    q = np.asarray(qt)
    assume(np.linalg.norm(q) > 1e-3)
    ref = Rotation.from_quat(q)
    assert np.allclose(Q.rotate(list(q), list(v)), ref.apply(v), atol=1e-14)
    assert np.allclose(Q.to_matrix(q), ref.as_matrix(), atol=1e-14)
    back = Q.from_matrix(Q.to_matrix(q))
    assert Q.angle_between(back, q) < 1e-14
    assert back[3] >= 0.0
