"""lodestar.firmware.attitude: QUEST, q-method, ESOQ2, TRIAD, covariance, loss.

Ground truth comes from scipy (Rotation, align_vectors) and numpy (eigh, poly).  Convention:
each solver returns q = [x, y, z, w] (scalar last, w >= 0) with Rotation.from_quat(q).apply(r)
~ b, i.e. to_matrix(q) is Shuster's attitude matrix A (b = A r).
"""

import ast
import math
import pathlib
import time

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from lodestar import firmware
from lodestar.firmware import attitude
from lodestar.firmware import quaternion as Q

FIRMWARE = pathlib.Path(firmware.__file__).parent
SOLVERS = [attitude.quest, attitude.q_method, attitude.esoq2]
SOLVER_IDS = ["quest", "q_method", "esoq2"]


def _unit_rows(a):
    a = np.asarray(a, float)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def _sky(rng, n, fov_deg=None):
    """n inertial unit vectors: the whole sphere (fov None) or a square field fov_deg wide."""
    if fov_deg is None:
        return _unit_rows(rng.normal(size=(n, 3)))
    bore = Rotation.random(random_state=rng)
    h = math.tan(math.radians(fov_deg) / 2)
    cam = np.column_stack([rng.uniform(-h, h, n), rng.uniform(-h, h, n), np.ones(n)])
    return bore.apply(_unit_rows(cam))


def _perturb(rng, b, sigma):
    """Gaussian noise of per-axis std sigma (rad) perpendicular to each unit vector."""
    sigma = np.broadcast_to(np.asarray(sigma, float), (len(b),))
    g = rng.normal(size=b.shape)
    g -= np.sum(g * b, axis=1, keepdims=True) * b
    return _unit_rows(b + sigma[:, None] * g)


def _min_sin_separation(v):
    return min(np.linalg.norm(np.cross(v[i], v[j]))
               for i in range(len(v)) for j in range(i))


# --------------------------------------------------------------------------------------------
# Noise-free recovery
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("solver", SOLVERS, ids=SOLVER_IDS)
@pytest.mark.parametrize("fov", [None, 20.0, 8.0], ids=["sphere", "fov20", "fov8"])
def test_noise_free_recovery(solver, fov):
    rng = np.random.default_rng([SOLVER_IDS.index(solver.__name__), int(fov or 0)])
    worst = 0.0
    for n in range(2, 31):
        for _ in range(6):
            q = Rotation.random(random_state=rng).as_quat()
            r = _sky(rng, n, fov)
            if _min_sin_separation(r) < 1e-3:          # skip near-coincident stars (< 3.4')
                continue
            b = Rotation.from_quat(q).apply(r)
            w = rng.uniform(0.2, 5.0, n)
            got = solver(b, r, w)
            assert isinstance(got, list) and len(got) == 4 and got[3] >= 0.0
            assert abs(sum(c * c for c in got) - 1.0) < 1e-14
            worst = max(worst, Q.angle_between(got, q))
    assert worst < 1e-9, worst


def test_noise_free_recovery_triad_and_textbook_quest():
    """TRIAD everywhere; QUEST/ESOQ2 without the Rayleigh refinement lose accuracy as
    eps / gap^2 (gap ~ separation^2), so they get stars at least 2 deg apart."""
    rng = np.random.default_rng(11)
    for _ in range(300):
        q = Rotation.random(random_state=rng).as_quat()
        r = _sky(rng, int(rng.integers(2, 31)), 20.0)
        sep = _min_sin_separation(r)
        if sep < 1e-3:
            continue
        b = Rotation.from_quat(q).apply(r)
        assert Q.angle_between(attitude.triad(b[0], b[1], r[0], r[1]), q) < 1e-9
        if sep > math.sin(math.radians(2.0)):
            assert Q.angle_between(attitude.quest(b, r, refine=False), q) < 1e-9
            assert Q.angle_between(attitude.esoq2(b, r, refine=False), q) < 1e-9


def test_refinement_matters_for_two_close_stars():
    """Two stars 0.3 deg apart: refined QUEST/ESOQ2 stay with the q-method (eps / gap)."""
    rng = np.random.default_rng(17)
    worst = 0.0
    for _ in range(100):
        q = Rotation.random(random_state=rng).as_quat()
        bore = Rotation.random(random_state=rng)
        d = math.radians(0.3)
        r = bore.apply(_unit_rows([[0.0, 0.0, 1.0], [math.sin(d), 0.0, math.cos(d)]]))
        b = _perturb(rng, Rotation.from_quat(q).apply(r), 1e-5)
        ref = attitude.q_method(b, r)
        for solver in (attitude.quest, attitude.esoq2):
            worst = max(worst, Q.angle_between(solver(b, r), ref))
    assert worst < 1e-10, worst


@settings(deadline=None, max_examples=60)
@given(st.integers(0, 2 ** 32 - 1), st.integers(2, 30), st.sampled_from([None, 30.0, 10.0]))
def test_property_noise_free_recovery(seed, n, fov):
    rng = np.random.default_rng(seed)
    q = Rotation.random(random_state=rng).as_quat()
    r = _sky(rng, n, fov)
    assume(_min_sin_separation(r) > 3e-3)
    b = Rotation.from_quat(q).apply(r)
    for solver in SOLVERS:
        assert Q.angle_between(solver(b, r), q) < 1e-9


# --------------------------------------------------------------------------------------------
# Near 180 deg (QUEST's singularity) and near 0 deg (ESOQ2's M -> 0)
# --------------------------------------------------------------------------------------------

NEAR_180 = [math.pi, math.radians(179.999), math.pi - 1e-9, math.radians(170.0)]
NEAR_0 = [0.0, 1e-12, 1e-6, math.radians(0.001)]


@pytest.mark.parametrize("solver", SOLVERS + [lambda b, r: attitude.quest(b, r, refine=False)],
                         ids=SOLVER_IDS + ["quest_textbook"])
@pytest.mark.parametrize("angle", NEAR_180 + NEAR_0)
def test_near_180_and_near_0_rotations(solver, angle):
    rng = np.random.default_rng(int(angle * 1e6) % 1000 + 7)
    axes = list(np.eye(3)) + list(_unit_rows(rng.normal(size=(20, 3))))
    for i, axis in enumerate(axes):
        q = Rotation.from_rotvec(axis * angle).as_quat()
        r = _sky(rng, 2 + i % 6, [None, 20.0][i % 2])
        b = Rotation.from_quat(q).apply(r)
        assert Q.angle_between(solver(b, r), q) < 1e-9, (axis, angle)


def test_quest_uses_sequential_rotation_only_when_needed(monkeypatch):
    """The frame is turned for 180 deg, kept for small angles (|gamma| = psi' q4^2)."""
    calls = []
    real_flip = attitude._flip

    def spy(B, axis):
        calls.append(axis)
        return real_flip(B, axis)

    monkeypatch.setattr(attitude, "_flip", spy)
    rng = np.random.default_rng(3)
    r = _sky(rng, 5)
    for angle, turned in ((0.3, False), (math.radians(110), False), (math.pi, True),
                          (math.radians(130), True)):
        calls.clear()
        q = Rotation.from_rotvec([0.0, 0.6 * angle, 0.8 * angle]).as_quat()
        got = attitude.quest(Rotation.from_quat(q).apply(r), r)
        assert bool(calls) == turned
        assert Q.angle_between(got, q) < 1e-12


# --------------------------------------------------------------------------------------------
# Noisy data: QUEST = ESOQ2 = q-method = SVD (scipy align_vectors)
# --------------------------------------------------------------------------------------------

def test_noisy_solvers_agree_with_q_method_and_svd():
    rng = np.random.default_rng(2024)
    worst = {"quest": 0.0, "esoq2": 0.0, "svd": 0.0}
    for trial in range(400):
        n = 2 + trial % 29
        q = Rotation.random(random_state=rng).as_quat()
        r = _sky(rng, n, [None, 20.0, 10.0][trial % 3])
        if _min_sin_separation(r) < 1e-3:
            continue
        sig = rng.uniform(5e-6, 1e-3, n)
        b = _perturb(rng, Rotation.from_quat(q).apply(r), sig)
        w = 1.0 / sig ** 2
        ref = attitude.q_method(b, r, w)
        worst["quest"] = max(worst["quest"], Q.angle_between(attitude.quest(b, r, w), ref))
        worst["esoq2"] = max(worst["esoq2"], Q.angle_between(attitude.esoq2(b, r, w), ref))
        svd, _ = Rotation.align_vectors(b, r, weights=w)
        worst["svd"] = max(worst["svd"], Q.angle_between(svd.as_quat(), ref))
    assert worst["quest"] < 1e-10, worst
    assert worst["esoq2"] < 1e-10, worst
    assert worst["svd"] < 1e-10, worst


def test_solution_minimises_loss_and_loss_is_lambda0_minus_lambda_max():
    rng = np.random.default_rng(5)
    for _ in range(30):
        n = int(rng.integers(2, 12))
        q = Rotation.random(random_state=rng).as_quat()
        r = _sky(rng, n, 20.0)
        b = _perturb(rng, Rotation.from_quat(q).apply(r), 1e-3)
        w = rng.uniform(0.5, 3.0, n)
        K = np.array(attitude.davenport_k(b, r, w))
        lam_max = np.linalg.eigvalsh(K)[-1]
        for solver in SOLVERS:
            qs = solver(b, r, w)
            J = attitude.loss(qs, b, r, w)
            assert J == pytest.approx(w.sum() - lam_max, rel=1e-9, abs=1e-13 * w.sum())
            for _ in range(5):
                d = Rotation.from_rotvec(rng.normal(size=3) * 1e-4)
                assert attitude.loss((d * Rotation.from_quat(qs)).as_quat(), b, r, w) > J


def test_weights_are_scale_invariant_and_default_equal():
    rng = np.random.default_rng(6)
    r = _sky(rng, 7, 15.0)
    b = _perturb(rng, Rotation.random(random_state=rng).apply(r), 1e-4)
    w = rng.uniform(1, 2, 7)
    for solver in SOLVERS:
        assert Q.angle_between(solver(b, r, w), solver(b, r, 1e3 * w)) < 1e-13
        assert Q.angle_between(solver(b, r), solver(b, r, [2.0] * 7)) < 1e-13


def test_accepts_lists_tuples_numpy_and_non_unit_vectors():
    rng = np.random.default_rng(8)
    q = Rotation.random(random_state=rng).as_quat()
    r = _sky(rng, 4, 20.0)
    b = Rotation.from_quat(q).apply(r)
    scale = rng.uniform(0.1, 10, (4, 1))
    variants = [(b, r), (b.tolist(), r.tolist()), (tuple(map(tuple, b)), tuple(map(tuple, r))),
                (b * scale, r / scale)]
    for solver in SOLVERS:
        for bb, rr in variants:
            assert Q.angle_between(solver(bb, rr, (1, 2, 3, 4)), q) < 1e-12


# --------------------------------------------------------------------------------------------
# TRIAD
# --------------------------------------------------------------------------------------------

def test_triad_first_pair_exact():
    rng = np.random.default_rng(9)
    for _ in range(200):
        q = Rotation.random(random_state=rng).as_quat()
        r = _sky(rng, 2, 20.0)
        b = _perturb(rng, Rotation.from_quat(q).apply(r), [0.0, 1e-2])   # b2 noisy
        got = attitude.triad(b[0], b[1], r[0], r[1])
        assert np.allclose(Q.rotate(got, r[0]), b[0], atol=1e-15, rtol=0)
        # the second body vector lies in the plane of b1 and A r2, on the same side
        Ar2 = np.asarray(Q.rotate(got, r[1]))
        assert abs(np.dot(np.cross(b[0], b[1]), Ar2)) < 1e-14
        assert np.dot(np.cross(b[0], b[1]), np.cross(b[0], Ar2)) > 0
        assert got[3] >= 0.0


def test_triad_is_order_sensitive_and_matches_noise_free_truth():
    rng = np.random.default_rng(10)
    q = Rotation.random(random_state=rng).as_quat()
    r = _sky(rng, 2, 20.0)
    b = _perturb(rng, Rotation.from_quat(q).apply(r), 1e-3)
    q12 = attitude.triad(b[0], b[1], r[0], r[1])
    q21 = attitude.triad(b[1], b[0], r[1], r[0])
    assert np.allclose(Q.rotate(q21, r[1]), b[1], atol=1e-15)
    assert Q.angle_between(q12, q21) > 1e-5


# --------------------------------------------------------------------------------------------
# QUEST polynomial
# --------------------------------------------------------------------------------------------

def test_quest_polynomial_hand_check():
    """b = r = x, y with weights 1/2: B = diag(.5, .5, 0), S = diag(1, 1, 0), sigma = 1, z = 0,
    K = diag(0, 0, -1, 1); a = 1 - tr adj S = 0, b = 1, c = d = 0, so
    psi = l^4 - l^2 = [1, 0, -1, 0, 0] (eigenvalues 1, -1, 0, 0)."""
    v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    K = attitude.davenport_k(v, v, [0.5, 0.5])
    assert K == [[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0],
                 [0.0, 0.0, 0.0, 1.0]]
    assert attitude.quest_polynomial(v, v, [0.5, 0.5]) == [1.0, 0.0, -1.0, 0.0, 0.0]


def test_quest_polynomial_equals_numpy_poly_and_c_is_8_det_b():
    rng = np.random.default_rng(12)
    for _ in range(100):
        n = int(rng.integers(2, 15))
        r = _sky(rng, n, [None, 20.0][_ % 2])
        b = _perturb(rng, Rotation.random(random_state=rng).apply(r), 0.05)
        w = rng.uniform(0.1, 2.0, n)
        K = np.array(attitude.davenport_k(b, r, w))
        assert np.allclose(K, K.T, atol=0) and abs(np.trace(K)) < 1e-14
        ref = np.poly(K)
        got = attitude.quest_polynomial(b, r, w)
        assert np.allclose(got, ref, rtol=1e-11, atol=1e-13 * w.sum() ** 4)
        B = np.array(attitude.profile_matrix(b, r, w))
        assert np.allclose(B, (w[:, None, None] * b[:, :, None] * r[:, None, :]).sum(0))
        assert -got[3] == pytest.approx(8 * np.linalg.det(B), rel=1e-10, abs=1e-14)


def test_davenport_k_eigenvector_is_shusters_quaternion():
    rng = np.random.default_rng(13)
    q = Rotation.random(random_state=rng).as_quat()
    r = _sky(rng, 6)
    b = Rotation.from_quat(q).apply(r)
    vals, vecs = np.linalg.eigh(np.array(attitude.davenport_k(b, r)))
    assert Q.angle_between(Q.conjugate(list(vecs[:, -1])), q) < 1e-12
    assert vals[-1] == pytest.approx(6.0)


# --------------------------------------------------------------------------------------------
# Covariance
# --------------------------------------------------------------------------------------------

def test_covariance_formula():
    rng = np.random.default_rng(14)
    r = _sky(rng, 6, 20.0)
    b = Rotation.random(random_state=rng).apply(r)
    sig = rng.uniform(1e-5, 5e-5, 6)
    P = np.array(attitude.covariance(b, r, sig))
    F = sum((np.eye(3) - np.outer(v, v)) / s ** 2 for v, s in zip(b, sig))
    assert np.allclose(P, np.linalg.inv(F), rtol=1e-12, atol=0)
    assert np.allclose(P, P.T, rtol=0, atol=0) and np.all(np.linalg.eigvalsh(P) > 0)
    assert np.allclose(attitude.covariance(b, r, 3 * sig), 9 * P, rtol=1e-12)
    # r only validated
    assert attitude.covariance(b, None, sig) == attitude.covariance(b, r, sig)
    cross, roll = attitude.sigmas_cross_roll(P)
    assert cross == pytest.approx(math.sqrt((P[0, 0] + P[1, 1]) / 2))
    assert roll == pytest.approx(math.sqrt(P[2, 2]))


def test_covariance_narrow_field_roll_is_worse():
    """Stars within a few degrees of the boresight: roll is poorly determined."""
    rng = np.random.default_rng(15)
    cam = _unit_rows(np.column_stack([rng.uniform(-0.1, 0.1, 10), rng.uniform(-0.1, 0.1, 10),
                                      np.ones(10)]))
    cross, roll = attitude.sigmas_cross_roll(attitude.covariance(cam, cam, [1e-5] * 10))
    assert roll > 5 * cross
    assert cross == pytest.approx(1e-5 / math.sqrt(10), rel=0.05)


def test_covariance_monte_carlo_matches_quest_scatter():
    """2000 QUEST solutions with perpendicular Gaussian noise on b: the scatter of the error
    rotation vector (rotvec of A_est A_true^T, camera axes) matches P within 10 % (std)."""
    rng = np.random.default_rng(777)
    truth = Rotation.random(random_state=rng)
    n = 8
    cam = _unit_rows(np.column_stack([rng.uniform(-0.15, 0.15, n),
                                      rng.uniform(-0.15, 0.15, n), np.ones(n)]))
    r = truth.inv().apply(cam)
    sig = rng.uniform(2e-5, 6e-5, n)
    w = 1.0 / sig ** 2
    P = np.array(attitude.covariance(cam, r, sig))
    start = time.perf_counter()
    errors = np.empty((2000, 3))
    for k in range(len(errors)):
        b = _perturb(rng, cam, sig)
        est = Rotation.from_quat(attitude.quest(b, r, w))
        errors[k] = (est * truth.inv()).as_rotvec()
    assert time.perf_counter() - start < 10.0
    C = np.cov(errors.T)
    assert np.allclose(np.sqrt(np.diag(C)), np.sqrt(np.diag(P)), rtol=0.10, atol=0)
    cross, roll = attitude.sigmas_cross_roll(P)
    cross_mc, roll_mc = attitude.sigmas_cross_roll(C.tolist())
    assert cross_mc == pytest.approx(cross, rel=0.10)
    assert roll_mc == pytest.approx(roll, rel=0.10)
    assert roll > 3 * cross                     # the narrow-field signature
    # whole matrix: the whitened scatter P^-1/2 C P^-1/2 is close to the identity
    L = np.linalg.cholesky(P)
    Li = np.linalg.inv(L)
    assert np.all(np.abs(np.linalg.eigvalsh(Li @ C @ Li.T) - 1.0) < 0.2)
    assert np.all(np.abs(errors.mean(axis=0)) < 4 * np.sqrt(np.diag(P) / len(errors)))


# --------------------------------------------------------------------------------------------
# Loss
# --------------------------------------------------------------------------------------------

def test_loss_matches_definition():
    rng = np.random.default_rng(16)
    r = _sky(rng, 5)
    b = _perturb(rng, r, 0.1)
    q = Rotation.random(random_state=rng).as_quat()
    w = rng.uniform(0.5, 2, 5)
    A = Rotation.from_quat(q).as_matrix()
    ref = 0.5 * np.sum(w * np.sum((b - r @ A.T) ** 2, axis=1))
    assert attitude.loss(q, b, r, w) == pytest.approx(ref, rel=1e-13)
    assert attitude.loss(q, b[:1], r[:1]) == pytest.approx(0.5 * np.sum((b[0] - A @ r[0]) ** 2))
    assert attitude.loss(q, Rotation.from_quat(q).apply(r), r, w) < 1e-28


# --------------------------------------------------------------------------------------------
# Bad inputs
# --------------------------------------------------------------------------------------------

NAN, INF = float("nan"), float("inf")
GOOD_B = [[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.0, 0.1, 1.0]]
GOOD_R = [[1.0, 0.0, 0.0], [1.0, 0.1, 0.0], [1.0, 0.0, 0.1]]

BAD_INPUTS = [
    (GOOD_B[:1], GOOD_R[:1], None, "at least 2 vector pairs, got 1"),
    ([], [], None, "at least 2 vector pairs, got 0"),
    (GOOD_B, GOOD_R[:2], None, "same number of vectors, got 3 and 2"),
    ([[0, 0, 1], [0, 0, 2], [0, 0, -1]], GOOD_R, None, r"all body \(b\) vectors are parallel"),
    (GOOD_B, [[1, 0, 0], [-3, 0, 0], [2, 0, 0]], None, r"all reference \(r\) vectors are par"),
    ([[0, 0, 1], [0, 1e-9, 1], [0, 0, 1]], GOOD_R, None, "unobservable"),
    ([[0, 0, 1], [0, NAN, 1], [0, 0, 1]], GOOD_R, None, r"b\[1\] is not finite"),
    (GOOD_B, [[1, 0, 0], [1, 0, 0], [INF, 0, 0]], None, r"r\[2\] is not finite"),
    (GOOD_B, [[1, 0, 0], [0, 0, 0], [0, 1, 0]], None, r"r\[1\] is a zero vector"),
    ([[0, 0, 1], [0, 1], [1, 0, 0]], GOOD_R, None, r"b\[1\] must have 3 components, got 2"),
    ([[0, 0, 1], 5, [1, 0, 0]], GOOD_R, None, r"b\[1\] must be a sequence"),
    ([[0, 0, 1], [0, "x", 1], [1, 0, 0]], GOOD_R, None, r"b\[1\] must hold numbers"),
    (None, GOOD_R, None, "b must be a sequence"),
    (GOOD_B, GOOD_R, [1, -1, 1], r"w\[1\] = -1.0 must be positive"),
    (GOOD_B, GOOD_R, [1, 0, 1], r"w\[1\] = 0.0 must be positive"),
    (GOOD_B, GOOD_R, [1, 1, NAN], r"w\[2\] = nan must be positive"),
    (GOOD_B, GOOD_R, [1, 1, INF], r"w\[2\] = inf must be positive"),
    (GOOD_B, GOOD_R, [1, 1], r"w must have one entry per vector pair \(3\), got 2"),
    (GOOD_B, GOOD_R, [1e308, 1e308, 1e308], "sum of weights is not finite"),
]


@pytest.mark.parametrize("solver", SOLVERS, ids=SOLVER_IDS)
@pytest.mark.parametrize("b, r, w, match", BAD_INPUTS)
def test_bad_inputs_raise(solver, b, r, w, match):
    with pytest.raises(ValueError, match=match):
        solver(b, r, w)


def test_good_inputs_of_the_bad_input_table_work():
    for solver in SOLVERS:
        q = solver(GOOD_B, GOOD_R)
        assert attitude.loss(q, GOOD_B, GOOD_R) < 0.05


@pytest.mark.parametrize("args, match", [
    (([0, 0, 1], [0, 0, 2], [1, 0, 0], [0, 1, 0]), "two body vectors are parallel"),
    (([0, 0, 1], [0, 1, 0], [1, 0, 0], [-1, 0, 0]), "two reference vectors are parallel"),
    (([0, 0, NAN], [0, 1, 0], [1, 0, 0], [0, 1, 0]), "b1 is not finite"),
    (([0, 0, 1], [0, 1, 0], [1, 0, 0], [0, 0, 0]), "r2 is a zero vector"),
    (([0, 0, 1], [0, 1, 0], [1, 0], [0, 1, 0]), "r1 must have 3 components"),
])
def test_triad_bad_inputs(args, match):
    with pytest.raises(ValueError, match=match):
        attitude.triad(*args)


@pytest.mark.parametrize("sigmas, match", [
    ([1e-5, 0.0, 1e-5], r"sigmas\[1\] = 0.0 must be positive"),
    ([1e-5, -1e-5, 1e-5], r"sigmas\[1\] = -1e-05 must be positive"),
    ([1e-5, NAN, 1e-5], r"sigmas\[1\] = nan must be positive"),
    ([1e-5, 1e-5], r"sigmas must have one entry per vector pair \(3\), got 2"),
    ([1e-5, 1e-200, 1e-5], r"sigmas\[1\] = 1e-200 is too small"),
])
def test_covariance_bad_inputs(sigmas, match):
    with pytest.raises(ValueError, match=match):
        attitude.covariance(GOOD_B, GOOD_R, sigmas)
    with pytest.raises(ValueError, match="parallel"):
        attitude.covariance([[0, 0, 1]] * 3, GOOD_R, [1e-5] * 3)


@pytest.mark.parametrize("P, match", [
    ([[1, 0, 0], [0, 1, 0]], "3x3"),
    ([[1, 0, 0], [0, 1], [0, 0, 1]], "row 1 must have 3"),
    ([[1, 0, 0], [0, -1, 0], [0, 0, 1]], r"P\[1\]\[1\] = -1.0 must be finite and >= 0"),
    ([[1, 0, 0], [0, 1, 0], [0, 0, NAN]], r"P\[2\]\[2\] = nan"),
])
def test_sigmas_cross_roll_bad_inputs(P, match):
    with pytest.raises(ValueError, match=match):
        attitude.sigmas_cross_roll(P)


# --------------------------------------------------------------------------------------------
# MCU constraints: source subset and an actual MicroPython run
# --------------------------------------------------------------------------------------------

FORBIDDEN_MODULES = {"numpy", "scipy", "typing", "dataclasses", "itertools", "functools",
                     "collections", "abc", "enum", "fractions", "decimal", "statistics"}
MODULES = ["geometry.py", "quaternion.py", "attitude.py"]


@pytest.mark.parametrize("name", MODULES)
def test_firmware_source_is_micropython_subset(name):
    tree = ast.parse((FIRMWARE / name).read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                assert alias.name.split(".")[0] not in FORBIDDEN_MODULES, alias.name
                assert alias.name == "math", alias.name
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 1 or node.module in ("math", "array"), ast.dump(node)
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id == "math":
            assert node.attr not in ("isclose", "fsum", "prod", "dist", "isqrt", "comb"), node.attr
        elif isinstance(node, (ast.AnnAssign, ast.NamedExpr, ast.JoinedStr, ast.AsyncFunctionDef,
                               ast.ClassDef, ast.Lambda, ast.Yield)):
            pytest.fail("%s uses %s (line %d)" % (name, type(node).__name__, node.lineno))
        elif isinstance(node, ast.arguments):
            assert not node.kwonlyargs and node.vararg is None and node.kwarg is None
            assert all(a.annotation is None for a in node.args)
        elif isinstance(node, ast.FunctionDef):
            assert node.returns is None    # and no decorator but the native marker
            assert all(isinstance(d, ast.Name) and d.id == "native" for d in node.decorator_list)


SMOKE = r"""
import sys, math
from lodestar.firmware import attitude, geometry as G, quaternion as Q
assert sys.implementation.name == "micropython"
q = Q.normalise([0.1, -0.7, 0.3, 0.6])
r = [G.normalise_vector(v) for v in ([1.0, 0.2, 0.1], [0.1, 1.0, -0.3], [0.2, 0.1, 1.0],
                                     [-0.5, 0.5, 0.6])]
for angle in (0.0, 1e-9, 1.0, math.pi - 1e-7, math.pi):
    qt = Q.multiply(q, Q.from_axis_angle([0.3, -0.2, 0.9], angle)) if angle else q
    b = [Q.rotate(qt, v) for v in r]
    for f in (attitude.quest, attitude.q_method, attitude.esoq2):
        e = Q.angle_between(f(b, r, [1, 2, 3, 4]), qt)
        assert e < 1e-12, (angle, e)
    assert Q.angle_between(attitude.triad(b[0], b[1], r[0], r[1]), qt) < 1e-12
    assert Q.angle_between(Q.from_matrix(Q.to_matrix(qt)), qt) < 1e-14
P = attitude.covariance(b, r, [1e-5] * 4)
cross, roll = attitude.sigmas_cross_roll(P)
assert 1e-6 < cross < 1e-4 and 1e-6 < roll < 1e-4
assert attitude.loss(q, b, r) >= 0.0
assert len(attitude.quest_polynomial(b, r)) == 5
try:
    attitude.quest(b[:1], r[:1])
    raise AssertionError("no error")
except ValueError as e:
    assert "at least 2" in str(e)
try:
    attitude.esoq2(b, r, [1, 1, float("nan"), 1])
    raise AssertionError("no error")
except ValueError as e:
    assert "w[2]" in str(e)
print("MICROPYTHON-OK", G.EPS)
"""


def test_modules_run_under_micropython(micropython):
    code, out = micropython(SMOKE)
    assert code == 0 and "MICROPYTHON-OK" in out, out


# --------------------------------------------------------------------------------------------
# Gauss-Newton refinement
# --------------------------------------------------------------------------------------------

def test_refine_from_a_nearby_attitude_agrees_with_q_method():
    rng = np.random.default_rng(11)
    worst = 0.0
    for trial in range(200):
        n = 2 + trial % 20
        q = Rotation.random(random_state=rng).as_quat()
        r = _sky(rng, n, [20.0, 10.0, 60.0][trial % 3])
        if _min_sin_separation(r) < 1e-3:
            continue
        sig = rng.uniform(5e-6, 1e-3, n)
        b = _perturb(rng, Rotation.from_quat(q).apply(r), sig)
        w = (1.0 / sig ** 2).tolist()
        start = (Rotation.from_rotvec(rng.normal(size=3) * math.radians(0.3) / math.sqrt(3))
                 * Rotation.from_quat(q)).as_quat()
        got = attitude.refine(start.tolist(), b.tolist(), r.tolist(), w)
        assert got[3] >= 0.0
        worst = max(worst, Q.angle_between(got, attitude.q_method(b, r, w)))
    # it stops after a step below 10 arcsec: what is left is that times the step and the
    # residuals (up to 1e-3): 5.5e-8 at most here
    assert worst < 1e-7, worst


def test_refine_uses_the_weights_and_takes_one_step_from_the_optimum():
    rng = np.random.default_rng(12)
    r = _sky(rng, 8, 20.0)
    b = _perturb(rng, r, 1e-3)
    w = rng.uniform(0.1, 10.0, 8).tolist()
    best = attitude.q_method(b, r, w)
    assert Q.angle_between(attitude.refine(best, b, r, w), best) < 1e-12
    assert Q.angle_between(attitude.refine(best, b, r, w, max_iterations=1), best) < 1e-12
    assert Q.angle_between(attitude.refine(best, b, r), attitude.q_method(b, r)) < 1e-7
    assert Q.angle_between(attitude.refine(best, b, r), best) > 1e-6       # the weights matter


def test_refine_rejects_what_it_cannot_solve():
    rng = np.random.default_rng(13)
    r = _sky(rng, 5, 20.0).tolist()
    q = [0.0, 0.0, 0.0, 1.0]
    with pytest.raises(ValueError, match="at least 2"):
        attitude.refine(q, r[:1], r[:1])
    with pytest.raises(ValueError, match="one entry per"):
        attitude.refine(q, r, r[:4])
    with pytest.raises(ValueError, match="unobservable"):
        attitude.refine(q, [r[0], r[0]], [r[0], r[0]])
    with pytest.raises(ValueError, match="unobservable"):
        attitude.refine(q, r, [[math.nan] * 3] * 5)
    far = Rotation.from_rotvec([0.0, 0.0, 3.0]).apply(np.array(r)).tolist()
    with pytest.raises(ValueError, match="no convergence"):
        attitude.refine(q, far, r, max_iterations=2)
